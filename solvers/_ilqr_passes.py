"""The passes of iLQR / DDP over a trajectory: rollouts, the expansion of the dynamics and the cost,
the adjoint gradient, the backward (Riccati) pass and the box QP of box-DDP (see :mod:`solvers.ilqr`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ._checks import _all_finite, _sym
from ._linalg import cho_solve, cholesky, dot, matmul, mm

Dynamics = Callable[[Float[Array, " n"], Float[Array, " m"], Int[Array, ""], Any], Float[Array, " n"]]
StageCost = Callable[[Float[Array, " n"], Float[Array, " m"], Int[Array, ""], Any], Float[Array, ""]]
TerminalCost = Callable[[Float[Array, " n"], Any], Float[Array, ""]]


class _Problem(eqx.Module):
    dynamics: Dynamics = eqx.field(static=True)
    cost: StageCost = eqx.field(static=True)
    terminal_cost: TerminalCost | None = eqx.field(static=True)
    second_order: bool = eqx.field(static=True)
    lower: Array | None = None  # [m] control bounds (box-DDP), or None
    upper: Array | None = None

    @property
    def bounded(self) -> bool:
        return self.lower is not None

    def clip(self, u):
        return jnp.clip(u, self.lower, self.upper) if self.bounded else u

    def f(self, x, u, t, args):
        return jnp.asarray(self.dynamics(x, u, t, args)).astype(x.dtype)

    def l(self, x, u, t, args):
        return jnp.asarray(self.cost(x, u, t, args)).astype(x.dtype)

    def lT(self, x, args):
        if self.terminal_cost is None:
            return jnp.zeros((), x.dtype)
        return jnp.asarray(self.terminal_cost(x, args)).astype(x.dtype)

    def rollout(self, x0, us, args):
        """Open-loop rollout: ``(xs [T+1, n], J)``."""
        T = us.shape[0]

        def step(x, data):
            u, t = data
            return self.f(x, u, t, args), (x, self.l(x, u, t, args))

        xT, (xs, ls) = jax.lax.scan(step, x0, (us, jnp.arange(T)))
        return jnp.concatenate([xs, xT[None]], axis=0), jnp.sum(ls) + self.lT(xT, args)

    def closed_loop(self, x0, xs, us, Ks, ks, alpha, args):
        """``u_t = ubar_t + alpha k_t + K_t (x_t - xbar_t)``: ``(xs_new, us_new, J)``."""
        T = us.shape[0]

        def step(x, data):
            xb, ub, K, k, t = data
            u = self.clip(ub + alpha * k + mm(K, x - xb))
            return self.f(x, u, t, args), (x, u, self.l(x, u, t, args))

        xT, (xs_new, us_new, ls) = jax.lax.scan(step, x0, (xs[:-1], us, Ks, ks, jnp.arange(T)))
        return jnp.concatenate([xs_new, xT[None]], axis=0), us_new, jnp.sum(ls) + self.lT(xT, args)

    def expand(self, xs, us, args):
        """Linearized dynamics and quadratized cost along ``(xs, us)``, vmapped over time."""
        n = xs.shape[1]
        T = us.shape[0]
        ts = jnp.arange(T)

        def stage(x, u, t):
            A, B = jax.jacfwd(self.f, argnums=(0, 1))(x, u, t, args)
            z = jnp.concatenate([x, u])
            lz = lambda z_: self.l(z_[:n], z_[n:], t, args)  # noqa: E731
            g = jax.grad(lz)(z)
            H = _sym(jax.hessian(lz)(z))
            return A, B, g[:n], g[n:], H[:n, :n], H[n:, n:], H[n:, :n]

        A, B, lx, lu, lxx, luu, lux = jax.vmap(stage)(xs[:-1], us, ts)
        xT = xs[-1]
        lTx = jax.grad(self.lT)(xT, args)
        lTxx = _sym(jax.hessian(self.lT)(xT, args))
        return dict(A=A, B=B, lx=lx, lu=lu, lxx=lxx, luu=luu, lux=lux, lTx=lTx, lTxx=lTxx)

    def gradient(self, ex):
        """``dJ/du_t = l_u + B' lambda_{t+1}`` by the adjoint (costate) recursion."""

        def step(lam, data):
            A, B, lx, lu = data
            return lx + mm(A.T, lam), lu + mm(B.T, lam)

        _, g = jax.lax.scan(step, ex["lTx"], (ex["A"], ex["B"], ex["lx"], ex["lu"]), reverse=True)
        return g

    def projected(self, g, us):
        """The gradient with the components at a bound that push outwards zeroed."""
        if not self.bounded:
            return g
        held = ((us <= self.lower[None]) & (g > 0)) | ((us >= self.upper[None]) & (g < 0))
        return jnp.where(held, 0, g)

    def backward(self, xs, us, ex, mu, args, second=1.0):
        """One backward pass with regularization ``mu``: ``(Ks, ks, dV1, dV2, ok, curvature)``.

        For DDP, ``second`` (0 or 1, may be traced) scales the second-order dynamics terms.
        """
        second_order = self.second_order
        n = xs.shape[1]
        m = us.shape[1]
        T = us.shape[0]
        eye = jnp.eye(m, dtype=xs.dtype)

        def step(carry, data):
            Vx, Vxx = carry
            A, B, lx, lu, lxx, luu, lux, x, u, t = data
            Qx = lx + mm(A.T, Vx)
            Qu = lu + mm(B.T, Vx)
            VA = mm(Vxx, A)
            Qxx = lxx + mm(A.T, VA)
            Quu = luu + mm(B.T, mm(Vxx, B))
            Qux = lux + mm(B.T, VA)
            if second_order:
                # The DDP terms, switched off (second = 0) for a Gauss-Newton (iLQR) pass.
                z = jnp.concatenate([x, u])
                H = jax.hessian(lambda z_: jnp.sum(Vx * self.f(z_[:n], z_[n:], t, args)))(z)
                H = second * _sym(H)
                Qxx = Qxx + H[:n, :n]
                Quu = Quu + H[n:, n:]
                Qux = Qux + H[n:, :n]
            Quu = _sym(Quu)
            L = cholesky(Quu + mu * eye)
            H = Quu + mu * eye
            ok = _all_finite(L)
            if self.bounded:
                k, free, L_free = _box_qp(jnp.where(ok, H, eye), Qu, self.lower - u, self.upper - u)
                K = -cho_solve(L_free, jnp.where(free[:, None], Qux, 0))
                K = jnp.where(free[:, None], K, 0)  # clamped directions get no feedback
            else:
                Kk = -cho_solve(L, jnp.concatenate([Qux, Qu[:, None]], axis=1))
                K, k = Kk[:, :n], Kk[:, n]
            Vx_new = Qx + mm(K.T, mm(Quu, k) + Qu) + mm(Qux.T, k)
            Vxx_new = _sym(Qxx + mm(K.T, mm(Quu, K) + Qux) + mm(Qux.T, K))
            dV1 = jnp.sum(k * Qu)
            dV2 = 0.5 * jnp.sum(k * mm(Quu, k))
            return (Vx_new, Vxx_new), (K, k, dV1, dV2, ok, jnp.max(jnp.diagonal(Quu)))

        data = (ex["A"], ex["B"], ex["lx"], ex["lu"], ex["lxx"], ex["luu"], ex["lux"], xs[:-1], us, jnp.arange(T))
        _, (Ks, ks, dV1, dV2, ok, curv) = jax.lax.scan(step, (ex["lTx"], ex["lTxx"]), data, reverse=True)
        ok = jnp.all(ok) & _all_finite(Ks, ks)
        return Ks, ks, jnp.sum(dV1), jnp.sum(dV2), ok, jnp.max(curv)


def _box_qp(H, g, lo, hi, max_iter: int = 32):
    """``min 0.5 k'Hk + g'k`` s.t. ``lo <= k <= hi`` by projected Newton (Tassa, Mansard & Todorov 2014).

    ``H`` must be positive definite. From ``k = clip(0)``, each iteration freezes the variables at
    a bound whose gradient pushes outwards, takes the Newton step over the free ones and a
    projected Armijo backtracking search along it. Returns ``(k, free, L_free)`` with ``free``
    the variables not clamped at the solution and ``L_free`` the Cholesky factor of ``H``
    restricted to them (identity rows/columns elsewhere), from which the feedback gains follow.
    """
    dtype = g.dtype
    m = g.shape[0]
    eye = jnp.eye(m, dtype=dtype)
    alphas = jnp.asarray(0.5, dtype) ** jnp.arange(24)
    f = lambda k: 0.5 * dot(k, matmul(H, k)) + dot(g, k)  # noqa: E731
    tol = 64 * jnp.finfo(dtype).eps

    def free_of(k):
        grad = g + matmul(H, k)
        clamped = ((k <= lo) & (grad > 0)) | ((k >= hi) & (grad < 0))
        return ~clamped, grad

    def factor(free):
        return cholesky(jnp.where(free[:, None] & free[None, :], H, eye))

    def cond(c):
        i, _, done = c
        return (i < max_iter) & ~done

    def body(c):
        i, k, _ = c
        free, grad = free_of(k)
        L = factor(free)
        d = -cho_solve(L, jnp.where(free, grad, 0))
        d = jnp.where(free, d, 0)
        fk = f(k)
        cands = jnp.clip(k[None, :] + alphas[:, None] * d[None, :], lo[None, :], hi[None, :])
        fs = jax.vmap(f)(cands)
        armijo = fs <= fk + 1e-4 * matmul(cands - k[None, :], grad)
        idx = jnp.argmax(armijo)
        k_new = jnp.where(jnp.any(armijo), cands[idx], k)
        scale = 1 + jnp.max(jnp.abs(g))
        small_grad = jnp.max(jnp.abs(jnp.where(free, grad, 0))) <= tol * scale
        small_change = jnp.max(jnp.abs(k_new - k)) <= tol * (1 + jnp.max(jnp.abs(k)))
        done = small_grad | small_change | ~jnp.any(armijo)
        return i + 1, k_new, done

    k0 = jnp.clip(jnp.zeros_like(g), lo, hi)
    _, k, _ = jax.lax.while_loop(cond, body, (jnp.array(0), k0, jnp.array(False)))
    free, _ = free_of(k)
    return k, free, factor(free)

