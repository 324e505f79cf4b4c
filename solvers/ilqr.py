r"""Iterative LQR and differential dynamic programming for discrete-time optimal control.

Both solvers minimise, over the controls ``u_0..u_{T-1}`` (single shooting from ``x0``),

.. math::
    J = \sum_{t=0}^{T-1} \ell(x_t, u_t, t) + \ell_T(x_T), \qquad x_{t+1} = f(x_t, u_t, t),

with user callbacks ``dynamics(x, u, t, args) -> x_next``, ``cost(x, u, t, args) -> scalar`` and
``terminal_cost(x, args) -> scalar``. Every iteration

1. **linearises** the dynamics (``A_t = f_x``, ``B_t = f_u``) and **quadratises** the cost
   (``l_x, l_u, l_xx, l_uu, l_ux``) along the nominal trajectory with ``jax.jacfwd`` /
   ``jax.hessian``, ``vmap``-ed over time;
2. runs the **backward pass** (``lax.scan``) on the value function ``V_t(x_t + dx) ~ V + V_x dx +
   0.5 dx' V_xx dx`` (``V_x, V_xx`` at ``T`` from ``l_T``)::

       Q_x  = l_x + A' V_x'          Q_u  = l_u + B' V_x'
       Q_xx = l_xx + A' V_xx' A      Q_uu = l_uu + B' V_xx' B      Q_ux = l_ux + B' V_xx' A
       K = -(Q_uu + mu I)^{-1} Q_ux,  k = -(Q_uu + mu I)^{-1} Q_u
       V_x  = Q_x + K' Q_uu k + K' Q_u + Q_ux' k
       V_xx = Q_xx + K' Q_uu K + K' Q_ux + Q_ux' K

   (primes: step ``t+1``; the value update is Tassa, Erez & Todorov 2012, eq. 11, exact for the
   regularised gains). **DDP** (:func:`ddp`) adds the second-order dynamics terms
   ``d^2 (V_x' . f) / d(x, u)^2`` to ``Q_xx, Q_uu, Q_ux``: one ``jax.hessian`` of the scalar
   ``V_x' . f(x, u)`` per step (a Hessian-vector contraction; the ``n x (n+m) x (n+m)`` tensor of
   ``f`` is never formed). When those terms make some ``Q_uu + mu I`` indefinite (typically far
   from a minimum, where ``V_x`` is large) the backward pass is first redone without them (an
   iLQR pass) before ``mu`` is raised, so DDP starts like iLQR instead of throttling its steps
   with a huge ``mu``, and keeps its quadratic convergence near a minimum. ``mu`` follows the Levenberg-Marquardt schedule of Tassa et al.
   (``mu_min = 1e-6``, factor ``Delta_0 = 2``): it grows when a Cholesky factorisation of
   ``Q_uu + mu I`` fails (the backward pass is retried) or the line search fails, and shrinks
   after every accepted step, to exactly 0 below ``mu_min``;
3. runs the **forward pass** ``u_t = ubar_t + alpha k_t + K_t (x_t - xbar_t)`` with a
   backtracking line search ``alpha = 1, 1/2, ..., 2^-10``, accepting the first step whose actual
   decrease is at least ``0.1`` of the expected decrease
   ``-(alpha sum k'Q_u + 0.5 alpha^2 sum k'Q_uu k)`` (the Armijo-like test of Tassa et al.).

**Box-DDP** (``bounds=(u_min, u_max)``, Tassa, Mansard & Todorov 2014): the backward pass gets
``k_t`` from the box QP ``min 0.5 k'(Q_uu + mu I)k + Q_u'k`` s.t. ``u_min <= ubar_t + k <= u_max``,
solved by projected Newton (:func:`_box_qp`); the rows of ``K_t`` of clamped controls are zero and
the free rows use ``Q_uu`` restricted to the free controls. The forward pass clips the controls,
and the gradient test uses the projected gradient (components held at a bound whose gradient
pushes outwards are dropped).

The solve has **converged** when, after a backward pass at the current trajectory, the expected
decrease of the full step is at most ``atol + rtol |J|`` (a relative-cost-decrease test on the
step that would be taken next, trusted only while ``mu`` is not larger than the curvature of
``Q_uu``), or when the gradient of ``J`` with respect to the controls (the adjoint/costate
gradient ``l_u + B' lambda_{t+1}``) has infinity norm at most ``atol``. On a linear-quadratic
problem the first iteration gives the exact LQR solution (:func:`solvers.lqr`); the second
confirms convergence.

Iterations run in a ``lax.while_loop`` (adaptive) or, with ``fixed_steps=True``, in a
``lax.scan`` of exactly ``max_steps`` iterations in which a finished problem is frozen (same
iterates; for large batches, where a while loop runs until its slowest element anyway). Both
functions solve one problem and are ``eqx.filter_jit``-ed; batch them with ``jax.vmap``, where
each element keeps its own ``result`` and a diverging element never aborts the batch
(``throw=False``, the default).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int, PyTree

from ._results import RESULTS
from ._checks import _all_finite, _as_float, _fmt, _sym, _tree_where
from ._linalg import cho_solve, cholesky, mm

__all__ = ["TrajectorySolution", "ddp", "ilqr"]

Dynamics = Callable[[Float[Array, " n"], Float[Array, " m"], Int[Array, ""], Any], Float[Array, " n"]]
StageCost = Callable[[Float[Array, " n"], Float[Array, " m"], Int[Array, ""], Any], Float[Array, ""]]
TerminalCost = Callable[[Float[Array, " n"], Any], Float[Array, ""]]

_MU_MIN = 1e-6  # below this the regularisation snaps to 0 (Tassa et al. 2012)
_MU_MAX = 1e10  # above this the solve gives up (RESULTS.no_descent)
_DELTA0 = 2.0  # the regularisation schedule's base factor
_ACCEPT = 0.1  # line search: accept when actual >= _ACCEPT * expected decrease
_ALPHA_MIN_EXPONENT = 10  # step sizes 1, 1/2, ..., 2^-10
_BACKWARD_RETRIES = 64  # regularisation increases tried within one backward pass


class TrajectorySolution(eqx.Module):
    """The result of :func:`ilqr` or :func:`ddp`.

    Attributes:
        xs: ``[T+1, n]`` the state trajectory, the rollout of ``us`` from ``x0`` (``xs[0] = x0``).
            When the initial rollout is not finite (``result == RESULTS.nonfinite``) it is that
            rollout, unchanged.
        us: ``[T, m]`` the controls.
        Ks: ``[T, m, n]`` feedback gains of the last backward pass.
        ks: ``[T, m]`` feed-forward terms of the last backward pass, in the absolute convention
            of :func:`solvers.lqr`: the policy is ``u_t = Ks[t] @ x_t + ks[t]`` (**plus** sign;
            ``ks[t] = ubar_t + k_t - K_t xbar_t`` for the nominal trajectory of that pass). After
            convergence that pass was made at ``(xs, us)``, so the policy reproduces ``us`` along
            ``xs`` to the tolerance and is the local optimal feedback around it.
        cost: the total cost ``J`` of ``(xs, us)``.
        result: a :class:`~solvers.RESULTS` code, per element under ``jax.vmap``:
            ``successful``, ``max_steps_reached``, ``nonfinite`` (the initial rollout or cost is
            not finite) or ``no_descent`` (the regularisation reached its maximum).
        stats: arrays:

            - ``num_steps`` (int): iterations (backward passes) performed, including the last
              one that confirms convergence.
            - ``cost_history``: ``[max_steps + 1]``; entry ``k`` is the cost after ``k``
              iterations (entry 0 the initial cost), padded with the final cost.
            - ``grad_norm``: ``max_t |dJ/du_t|_inf`` at ``(xs, us)`` (adjoint gradient).
            - ``expected_decrease``: the expected decrease of the full step of the last
              backward pass.
            - ``regularisation``: ``mu`` at the end.
            - ``step_size``: ``alpha`` of the last accepted step (0 if none).
    """

    xs: Float[Array, "T+1 n"]
    us: Float[Array, "T m"]
    Ks: Float[Array, "T m n"]
    ks: Float[Array, "T m"]
    cost: Float[Array, ""]
    result: RESULTS
    stats: dict[str, Array]


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
        """Linearised dynamics and quadratised cost along ``(xs, us)``, vmapped over time."""
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
        """One backward pass with regularisation ``mu``: ``(Ks, ks, dV1, dV2, ok, curvature)``.

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


# --------------------------------------------------------------------------------------------
# The iteration.
# --------------------------------------------------------------------------------------------


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
    f = lambda k: 0.5 * (k @ (H @ k)) + g @ k  # noqa: E731
    tol = 64 * jnp.finfo(dtype).eps

    def free_of(k):
        grad = g + H @ k
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
        armijo = fs <= fk + 1e-4 * ((cands - k[None, :]) @ grad)
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


class _State(eqx.Module):
    xs: Array
    us: Array
    cost: Array
    Ks: Array
    ks: Array  # absolute feed-forward of the last backward pass
    mu: Array
    delta: Array
    expected: Array  # expected decrease of the full step of the last backward pass
    alpha: Array
    num_steps: Array
    history: Array
    converged: Array
    failed: Array  # the regularisation exceeded its maximum


def _increase(mu, delta):
    delta = jnp.maximum(_DELTA0, delta * _DELTA0)
    return jnp.maximum(_MU_MIN, mu * delta), delta


def _decrease(mu, delta):
    delta = jnp.minimum(1 / _DELTA0, delta / _DELTA0)
    mu = mu * delta
    return jnp.where(mu > _MU_MIN, mu, 0.0).astype(mu.dtype), delta


def _iteration(problem: _Problem, x0, args, rtol, atol, s: _State) -> _State:
    dtype = s.xs.dtype
    ex = problem.expand(s.xs, s.us, args)
    g_norm = jnp.max(jnp.abs(problem.projected(problem.gradient(ex), s.us)))

    # Backward pass, retried while Q_uu + mu I is not PD: DDP first retries without its
    # second-order terms (far from a minimum they can make Q_uu indefinite; raising mu until they
    # are swamped would throttle the steps), then with a larger regularisation.
    def bw_cond(c):
        i, mu, delta, second, out = c
        return ~out[4] & (mu <= _MU_MAX) & (i < _BACKWARD_RETRIES)

    def bw_body(c):
        i, mu, delta, second, _ = c
        drop = second > 0
        mu_up, delta_up = _increase(mu, delta)
        mu = jnp.where(drop, mu, mu_up)
        delta = jnp.where(drop, delta, delta_up)
        second = jnp.zeros_like(second)
        return i + 1, mu, delta, second, problem.backward(s.xs, s.us, ex, mu, args, second)

    second0 = jnp.asarray(1.0 if problem.second_order else 0.0, dtype)
    first = problem.backward(s.xs, s.us, ex, s.mu, args, second0)
    _, mu, delta, _, (Ks, ks, dV1, dV2, ok, curvature) = jax.lax.while_loop(
        bw_cond, bw_body, (jnp.array(0), s.mu, s.delta, second0, first)
    )
    ok = ok & (mu <= _MU_MAX)
    Ks = jnp.where(ok, Ks, 0)
    ks = jnp.where(ok, ks, 0)
    expected = jnp.where(ok, -(dV1 + dV2), 0)
    trusted = mu <= curvature
    converged = (ok & trusted & (expected <= atol + rtol * jnp.abs(s.cost))) | (g_norm <= atol)
    ks_abs = s.us + ks - jnp.einsum("tmn,tn->tm", Ks, s.xs[:-1])

    # Line search on the feed-forward.
    def ls_cond(c):
        j, accepted, _ = c
        return ~accepted & (j <= _ALPHA_MIN_EXPONENT)

    def ls_body(c):
        j, _, _ = c
        alpha = jnp.asarray(0.5, dtype) ** j
        xs_new, us_new, J = problem.closed_loop(x0, s.xs, s.us, Ks, ks, alpha, args)
        exp_a = -(alpha * dV1 + alpha**2 * dV2)
        accepted = jnp.isfinite(J) & _all_finite(xs_new, us_new) & (s.cost - J >= _ACCEPT * exp_a) & (exp_a > 0)
        return j + 1, accepted, (xs_new, us_new, J, alpha)

    init = (s.xs, s.us, s.cost, jnp.zeros((), dtype))
    search = ok & ~converged
    j0 = jnp.where(search, 0, _ALPHA_MIN_EXPONENT + 1)
    _, accepted, (xs_new, us_new, J, alpha) = jax.lax.while_loop(ls_cond, ls_body, (j0, jnp.array(False), init))
    accepted = accepted & search

    mu_dec, delta_dec = _decrease(mu, delta)
    mu_inc, delta_inc = _increase(mu, delta)
    mu_next = jnp.where(accepted, mu_dec, jnp.where(converged, mu, mu_inc))
    delta_next = jnp.where(accepted, delta_dec, jnp.where(converged, delta, delta_inc))
    failed = ~converged & ~accepted & (~ok | (mu_next > _MU_MAX))
    new = _State(
        xs=jnp.where(accepted, xs_new, s.xs),
        us=jnp.where(accepted, us_new, s.us),
        cost=jnp.where(accepted, J, s.cost),
        Ks=jnp.where(ok, Ks, s.Ks),
        ks=jnp.where(ok, ks_abs, s.ks),
        mu=mu_next,
        delta=delta_next,
        expected=expected,
        alpha=jnp.where(accepted, alpha, s.alpha),
        num_steps=s.num_steps + 1,
        history=s.history,
        converged=converged,
        failed=failed,
    )
    cost_now = new.cost
    history = new.history.at[new.num_steps].set(cost_now)
    return eqx.tree_at(lambda z: z.history, new, history)


def _done(s: _State):
    return s.converged | s.failed | ~jnp.isfinite(s.cost)


def _solve(problem, x0, us, args, rtol, atol, max_steps, fixed_steps, throw) -> TrajectorySolution:
    dtype = x0.dtype
    T, m = us.shape
    n = x0.shape[0]
    eps = jnp.finfo(dtype).eps
    rtol = jnp.maximum(jnp.asarray(1e-13 if rtol is None else rtol, dtype), 16 * eps)
    atol = jnp.asarray(atol, dtype)
    xs, J = problem.rollout(x0, us, args)
    finite0 = jnp.isfinite(J) & _all_finite(xs)
    s0 = _State(
        xs=xs,
        us=us,
        cost=J,
        Ks=jnp.zeros((T, m, n), dtype),
        ks=us,
        mu=jnp.zeros((), dtype),
        delta=jnp.ones((), dtype),
        expected=jnp.zeros((), dtype),
        alpha=jnp.zeros((), dtype),
        num_steps=jnp.array(0),
        history=jnp.full((max_steps + 1,), J),
        converged=jnp.array(False),
        failed=jnp.array(False),
    )
    body = lambda s: _iteration(problem, x0, args, rtol, atol, s)  # noqa: E731
    if fixed_steps:

        def scan_body(s, _):
            return _tree_where(_done(s), s, body(s)), None

        s, _ = jax.lax.scan(scan_body, s0, None, length=max_steps)
    else:
        s = jax.lax.while_loop(lambda s: ~_done(s) & (s.num_steps < max_steps), body, s0)

    history = jnp.where(jnp.arange(max_steps + 1) > s.num_steps, s.cost, s.history)
    ex = problem.expand(s.xs, s.us, args)
    grad_norm = jnp.max(jnp.abs(problem.projected(problem.gradient(ex), s.us)))
    result = RESULTS.where(
        ~finite0,
        RESULTS.nonfinite,
        RESULTS.where(
            s.converged,
            RESULTS.successful,
            RESULTS.where(s.failed, RESULTS.no_descent, RESULTS.max_steps_reached),
        ),
    )
    xs_out = s.xs
    if throw:
        xs_out = result.error_if(xs_out, result != RESULTS.successful)
    stats = dict(
        num_steps=s.num_steps,
        cost_history=history,
        grad_norm=grad_norm,
        expected_decrease=s.expected,
        regularisation=s.mu,
        step_size=s.alpha,
    )
    return TrajectorySolution(xs=xs_out, us=s.us, Ks=s.Ks, ks=s.ks, cost=s.cost, result=result, stats=stats)


@eqx.filter_jit
def _solve_jit(problem, x0, us, args, rtol, atol, max_steps, fixed_steps, throw):
    n = x0.shape[0]
    T, m = us.shape
    t0 = jnp.array(0)
    out = eqx.filter_eval_shape(problem.dynamics, x0, us[0], t0, args)
    if getattr(out, "shape", None) != (n,):
        got = _fmt(out.shape) if hasattr(out, "shape") else type(out).__name__
        raise ValueError(f"dynamics: expected dynamics(x, u, t, args) to return shape (n,) = ({n},), got {got}")
    out = eqx.filter_eval_shape(problem.cost, x0, us[0], t0, args)
    if getattr(out, "shape", None) != ():
        got = _fmt(out.shape) if hasattr(out, "shape") else type(out).__name__
        raise ValueError(f"cost: expected cost(x, u, t, args) to return a scalar, shape (), got {got}")
    if problem.terminal_cost is not None:
        out = eqx.filter_eval_shape(problem.terminal_cost, x0, args)
        if getattr(out, "shape", None) != ():
            got = _fmt(out.shape) if hasattr(out, "shape") else type(out).__name__
            raise ValueError(f"terminal_cost: expected terminal_cost(x, args) to return a scalar, shape (), got {got}")
    return _solve(problem, x0, us, args, rtol, atol, max_steps, fixed_steps, throw)


def _entry(second_order, dynamics, cost, x0, us_init, terminal_cost, args, bounds, max_steps, fixed_steps, rtol, atol, throw):
    x0 = _as_float("x0", x0)
    if x0.ndim != 1 or x0.shape[0] == 0:
        raise ValueError(f"x0: expected shape (n,) with n >= 1, got {_fmt(x0.shape)}")
    us = _as_float("us_init", us_init)
    if us.ndim != 2 or us.shape[0] == 0 or us.shape[1] == 0:
        raise ValueError(f"us_init: expected shape (T, m) with T >= 1 and m >= 1, got {_fmt(us.shape)}")
    if not isinstance(max_steps, (int, np.integer)) or isinstance(max_steps, bool) or max_steps < 1:
        raise ValueError(f"max_steps: expected an int >= 1, got {max_steps!r}")
    dtype = jnp.result_type(x0.dtype, us.dtype)
    m = us.shape[1]
    lower = upper = None
    if bounds is not None:
        if not (isinstance(bounds, (tuple, list)) and len(bounds) == 2):
            raise ValueError(f"bounds: expected a pair (u_min, u_max) of shape (m,) = ({m},), got {type(bounds).__name__}")
        lower, upper = (jnp.asarray(b, dtype) for b in bounds)
        for name, b in (("u_min", lower), ("u_max", upper)):
            if b.shape not in ((), (m,)):
                raise ValueError(f"bounds: expected {name} of shape (m,) = ({m},), got {_fmt(b.shape)}")
        lower = jnp.broadcast_to(lower, (m,))
        upper = jnp.broadcast_to(upper, (m,))
        if not isinstance(lower, jax.core.Tracer) and not isinstance(upper, jax.core.Tracer):
            if np.any(np.asarray(lower) > np.asarray(upper)):
                raise ValueError("bounds: expected u_min <= u_max for every control")
        us = jnp.clip(us.astype(dtype), lower[None], upper[None])
    problem = _Problem(
        dynamics=dynamics, cost=cost, terminal_cost=terminal_cost, second_order=second_order, lower=lower, upper=upper
    )
    return _solve_jit(
        problem, x0.astype(dtype), us.astype(dtype), args, rtol, atol, int(max_steps), bool(fixed_steps), bool(throw)
    )


_ARGS_DOC = """
    Args:
        dynamics: ``dynamics(x, u, t, args) -> x_next``, ``[n]``; discrete time, ``t`` an int
            array (the step index).
        cost: ``cost(x, u, t, args) -> scalar``, the stage cost, summed over ``t = 0..T-1``.
        x0: ``[n]`` the initial state.
        us_init: ``[T, m]`` the initial controls (``T`` the horizon).
        terminal_cost: optional ``terminal_cost(x, args) -> scalar`` added at ``x_T``.
        args: any pytree passed to the callbacks (``vmap`` over it to batch problems).
        bounds: optional ``(u_min, u_max)``, each ``[m]`` or a scalar (``-inf``/``inf`` for
            free controls): box-DDP. ``us_init`` is clipped into the box, the backward pass solves
            a box QP for ``k_t`` and the forward pass clips, so every iterate is feasible.
        max_steps: the most iterations (static int >= 1).
        fixed_steps: if true, run exactly ``max_steps`` iterations in a ``lax.scan``, freezing the
            problem once it has finished (same iterates as the adaptive ``lax.while_loop``).
        rtol: relative tolerance on the expected cost decrease (default ``1e-13``, floored at
            ``16 eps`` of the dtype).
        atol: absolute tolerance on the expected decrease and on ``max_t |dJ/du_t|_inf``.
        throw: if true, raise unless the solve succeeds (under ``vmap``: if any element fails).

    Returns:
        A :class:`TrajectorySolution` ``(xs, us, Ks, ks, cost, result, stats)``.

    Raises:
        ValueError: ``x0``/``us_init`` have the wrong shape or are complex, a callback returns the
            wrong shape, ``bounds`` do not match ``m`` or ``u_min > u_max``, or ``max_steps`` is
            not a positive int. Raised before the solve runs.
        equinox.EquinoxRuntimeError: ``throw=True`` and the solve failed.
"""


def ilqr(
    dynamics: Dynamics,
    cost: StageCost,
    x0: Float[ArrayLike, " n"],
    us_init: Float[ArrayLike, "T m"],
    *,
    terminal_cost: TerminalCost | None = None,
    args: PyTree = None,
    bounds: tuple[Float[ArrayLike, " m"], Float[ArrayLike, " m"]] | None = None,
    max_steps: int = 100,
    fixed_steps: bool = False,
    rtol: float | None = None,
    atol: float = 1e-12,
    throw: bool = False,
) -> TrajectorySolution:
    return _entry(False, dynamics, cost, x0, us_init, terminal_cost, args, bounds, max_steps, fixed_steps, rtol, atol, throw)


def ddp(
    dynamics: Dynamics,
    cost: StageCost,
    x0: Float[ArrayLike, " n"],
    us_init: Float[ArrayLike, "T m"],
    *,
    terminal_cost: TerminalCost | None = None,
    args: PyTree = None,
    bounds: tuple[Float[ArrayLike, " m"], Float[ArrayLike, " m"]] | None = None,
    max_steps: int = 100,
    fixed_steps: bool = False,
    rtol: float | None = None,
    atol: float = 1e-12,
    throw: bool = False,
) -> TrajectorySolution:
    return _entry(True, dynamics, cost, x0, us_init, terminal_cost, args, bounds, max_steps, fixed_steps, rtol, atol, throw)


ilqr.__doc__ = (
    """Minimise a discrete-time optimal-control problem by iterative LQR (first-order dynamics).

    See the module docstring for the algorithm, the regularisation, the line search and the
    convergence test. Solves one problem; batch with ``jax.vmap`` (``throw=False`` and
    ``sol.result == RESULTS.successful`` give a per-element status). Compiled once per callback
    objects, shapes and static settings: pass the same function objects, and data in ``args``.
"""
    + _ARGS_DOC
)
ddp.__doc__ = (
    """Minimise a discrete-time optimal-control problem by differential dynamic programming.

    As :func:`ilqr`, plus the second-order dynamics terms ``d^2 (V_x' . f) / d(x, u)^2`` in the
    backward pass (one Hessian of a scalar per time step, no dense 3-tensor). Converges
    quadratically near a minimum; more work per iteration than iLQR.
"""
    + _ARGS_DOC
)
