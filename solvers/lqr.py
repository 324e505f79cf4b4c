r"""Linear-quadratic regulators: finite-horizon LQR, and the discrete / continuous algebraic Riccati equations.

**Finite horizon** (:func:`lqr`): the general time-varying LQ problem that iLQR and DDP solve at
every iteration,

.. math::
    \min_{u_0..u_{T-1}} \sum_{t=0}^{T-1} \Big(\tfrac12 x_t^\top Q_t x_t + \tfrac12 u_t^\top R_t u_t
        + u_t^\top S_t x_t + q_t^\top x_t + r_t^\top u_t\Big) + \tfrac12 x_T^\top Q_T x_T + q_T^\top x_T
    \quad\text{s.t.}\quad x_{t+1} = A_t x_t + B_t u_t + c_t,\ x_0 \text{ given}.

It is solved by backward induction on the value function
``V_t(x) = 0.5 x' P_t x + p_t' x + v_t`` (``P_T = Q_T``, ``p_T = q_T``, ``v_T = 0``). With
``P, p, v`` those of step ``t+1`` and ``z = P c_t + p``, the Q-function of step ``t`` has::

    Q_xx = Q_t + A' P A      Q_uu = R_t + B' P B      Q_ux = S_t + B' P A
    q_x  = q_t + A' z        q_u  = r_t + B' z

and the minimizer over ``u`` is the affine policy ``u_t = K_t x_t + k_t`` with
``K_t = -Q_uu^{-1} Q_ux`` and ``k_t = -Q_uu^{-1} q_u`` (one Cholesky factorization of ``Q_uu`` per
step). Then ``P_t = Q_xx + Q_ux' K_t``, ``p_t = q_x + Q_ux' k_t`` and
``v_t = v + c' (0.5 P c + p) + 0.5 q_u' k_t``. A forward ``lax.scan`` rolls the policy out from
``x0``. **Sign convention: the finite-horizon gain is applied with a plus sign,
``u = K x + k``** (as in trajax; Crocoddyl, scipy and the textbooks apply ``-K``), so for a plain
regulator ``K_t`` is minus the textbook gain ``(R_t + B_t'P_{t+1}B_t)^{-1} B_t'P_{t+1}A_t``.

The infinite-horizon equations (:func:`solvers.dare`, :func:`solvers.care`) are in ``_riccati``.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._checks import _all_finite, _as_float, _check_shape, _common_dtype, _fmt, _sym
from ._linalg import cho_solve, cholesky, dot, einsum, matmul, mm
from ._results import RESULTS

__all__ = ["LQRSolution", "lqr"]


# --------------------------------------------------------------------------------------------
# Result container.
# --------------------------------------------------------------------------------------------


class LQRSolution(eqx.Module):
    """The solution of a finite-horizon LQ problem (:func:`lqr`).

    The optimal policy is ``u_t = Ks[t] @ x_t + ks[t]`` (**plus** sign; see the module docstring),
    optimal from *any* state ``x_t``, not only along ``xs``. The optimal cost-to-go from ``x`` at
    step ``t`` is ``0.5 x' Ps[t] x + ps[t]' x + vs[t]``.

    Attributes:
        xs: ``[T+1, n]`` the optimal state trajectory from ``x0`` (``xs[0] = x0``).
        us: ``[T, m]`` the optimal controls.
        Ks: ``[T, m, n]`` feedback gains, ``Ks[t] = -Q_uu^{-1} Q_ux``.
        ks: ``[T, m]`` feed-forward terms, ``ks[t] = -Q_uu^{-1} q_u``.
        Ps: ``[T+1, n, n]`` value-function Hessians (symmetric; ``Ps[T] = QT``).
        ps: ``[T+1, n]`` value-function gradients at ``x = 0`` (``ps[T] = qT``).
        vs: ``[T+1]`` value-function constants (``vs[T] = 0``).
        cost: the total cost of ``(xs, us)``; equals ``0.5 x0' Ps[0] x0 + ps[0]' x0 + vs[0]``.
        result: :class:`~solvers.RESULTS`: ``successful``, or ``not_positive_definite`` when
            some ``Q_uu`` is not positive definite or a non-finite value appeared (the other
            fields are then meaningless and may be NaN). Per element under ``jax.vmap``.
    """

    xs: Float[Array, "T+1 n"]
    us: Float[Array, "T m"]
    Ks: Float[Array, "T m n"]
    ks: Float[Array, "T m"]
    Ps: Float[Array, "T+1 n n"]
    ps: Float[Array, "T+1 n"]
    vs: Float[Array, " T+1"]
    cost: Float[Array, ""]
    result: RESULTS


# --------------------------------------------------------------------------------------------
# Finite-horizon LQR.
# --------------------------------------------------------------------------------------------


def lqr(
    A: Float[ArrayLike, "T n n"],
    B: Float[ArrayLike, "T n m"],
    Q: Float[ArrayLike, "T n n"],
    R: Float[ArrayLike, "T m m"],
    QT: Float[ArrayLike, "n n"],
    x0: Float[ArrayLike, " n"],
    *,
    S: Float[ArrayLike, "T m n"] | None = None,
    q: Float[ArrayLike, "T n"] | None = None,
    r: Float[ArrayLike, "T m"] | None = None,
    qT: Float[ArrayLike, " n"] | None = None,
    c: Float[ArrayLike, "T n"] | None = None,
    throw: bool = False,
) -> LQRSolution:
    r"""Solve a finite-horizon, time-varying LQ problem with cross and affine terms.

    Minimizes ``sum_{t<T} [0.5 x_t'Q_t x_t + 0.5 u_t'R_t u_t + u_t'S_t x_t + q_t'x_t + r_t'u_t]
    + 0.5 x_T'QT x_T + qT'x_T`` subject to ``x_{t+1} = A_t x_t + B_t u_t + c_t`` from ``x0``, by the
    backward Riccati recursion of the module docstring (``lax.scan``, one Cholesky factorization
    of ``Q_uu = R_t + B_t'P_{t+1}B_t`` per step) and a forward rollout of the policy
    ``u_t = K_t x_t + k_t`` (**plus** sign). The problem has a unique minimizer when every
    ``Q_uu`` is positive definite (e.g. ``R_t`` positive definite and the stage costs convex);
    ``Q_t`` need not be. Only the symmetric parts of ``Q_t``, ``R_t`` and ``QT`` matter and are used.

    Time-invariant data must be stacked by the caller (``jnp.broadcast_to(A, (T, n, n))``). Solves
    one problem; batch with ``jax.vmap``.

    Args:
        A: ``[T, n, n]`` state-transition matrices.
        B: ``[T, n, m]`` control matrices.
        Q: ``[T, n, n]`` state-cost Hessians of the stages ``t = 0..T-1``.
        R: ``[T, m, m]`` control-cost Hessians.
        QT: ``[n, n]`` terminal state-cost Hessian.
        x0: ``[n]`` initial state.
        S: optional ``[T, m, n]`` cross terms (the stage cost has ``u'S x``, not ``2 u'S x``).
            Default zero.
        q: optional ``[T, n]`` linear state costs. Default zero.
        r: optional ``[T, m]`` linear control costs. Default zero.
        qT: optional ``[n]`` linear terminal cost. Default zero.
        c: optional ``[T, n]`` dynamics offsets. Default zero.
        throw: if true, raise (``equinox.EquinoxRuntimeError`` with the result's message) unless
            the solve succeeds. Under ``vmap`` one failing element raises for the whole batch.

    Returns:
        An :class:`LQRSolution` ``(xs, us, Ks, ks, Ps, ps, vs, cost, result)``.

    Raises:
        ValueError: an argument has the wrong shape (the message names it and gives the expected
            and actual shapes) or is complex. Raised in Python, before anything is computed.
        equinox.EquinoxRuntimeError: ``throw=True`` and some ``Q_uu`` is not positive definite.
    """
    x0 = _as_float("x0", x0)
    if x0.ndim != 1 or x0.shape[0] == 0:
        raise ValueError(f"x0: expected shape (n,) with n >= 1, got {_fmt(x0.shape)}")
    n = x0.shape[0]
    A = _as_float("A", A)
    if A.ndim != 3 or A.shape[0] == 0:
        raise ValueError(f"A: expected shape (T, n, n) with T >= 1 and n = {n} (from x0), got {_fmt(A.shape)}")
    T = A.shape[0]
    B = _as_float("B", B)
    if B.ndim != 3 or B.shape[-1] == 0:
        raise ValueError(f"B: expected shape (T, n, m) = ({T}, {n}, m) with m >= 1, got {_fmt(B.shape)}")
    sizes = dict(T=T, n=n, m=B.shape[-1])
    _check_shape("A", A, ("T", "n", "n"), sizes)
    _check_shape("B", B, ("T", "n", "m"), sizes)
    Q = _as_float("Q", Q)
    _check_shape("Q", Q, ("T", "n", "n"), sizes)
    R = _as_float("R", R)
    _check_shape("R", R, ("T", "m", "m"), sizes)
    QT = _as_float("QT", QT)
    _check_shape("QT", QT, ("n", "n"), sizes)
    optional = {}
    for name, value, dims in (
        ("S", S, ("T", "m", "n")),
        ("q", q, ("T", "n")),
        ("r", r, ("T", "m")),
        ("qT", qT, ("n",)),
        ("c", c, ("T", "n")),
    ):
        if value is not None:
            value = _as_float(name, value)
            _check_shape(name, value, dims, sizes)
        optional[name] = value
    dtype = _common_dtype(A, B, Q, R, QT, x0, *optional.values())

    def fill(name, dims):
        v = optional[name]
        return jnp.zeros(tuple(sizes[d] for d in dims), dtype) if v is None else v.astype(dtype)

    return _lqr(
        A.astype(dtype), B.astype(dtype), Q.astype(dtype), R.astype(dtype), QT.astype(dtype), x0.astype(dtype),
        fill("S", ("T", "m", "n")), fill("q", ("T", "n")), fill("r", ("T", "m")), fill("qT", ("n",)),
        fill("c", ("T", "n")), throw,
    )


@eqx.filter_jit
def _lqr(A, B, Q, R, QT, x0, S, q, r, qT, c, throw) -> LQRSolution:
    n = x0.shape[0]
    symT = lambda M: 0.5 * (M + jnp.swapaxes(M, -1, -2))  # noqa: E731
    Q, R, QT = symT(Q), symT(R), _sym(QT)

    def backward(carry, data):
        P, p, v = carry  # value function of step t+1
        A_t, B_t, Q_t, R_t, S_t, q_t, r_t, c_t = data
        z = mm(P, c_t) + p
        PA = mm(P, A_t)
        Quu = _sym(R_t + mm(B_t.T, mm(P, B_t)))
        Qux = S_t + mm(B_t.T, PA)
        Qxx = Q_t + mm(A_t.T, PA)
        qx = q_t + mm(A_t.T, z)
        qu = r_t + mm(B_t.T, z)
        L = cholesky(Quu)
        ok = _all_finite(L)
        Kk = -cho_solve(L, jnp.concatenate([Qux, qu[:, None]], axis=1))
        K, k = Kk[:, :n], Kk[:, n]
        P_t = _sym(Qxx + mm(Qux.T, K))
        p_t = qx + mm(Qux.T, k)
        v_t = v + jnp.sum(c_t * (0.5 * mm(P, c_t) + p)) + 0.5 * jnp.sum(qu * k)
        return (P_t, p_t, v_t), (K, k, P_t, p_t, v_t, ok)

    zero = jnp.zeros((), x0.dtype)
    _, (Ks, ks, Ps, ps, vs, ok) = jax.lax.scan(backward, (QT, qT, zero), (A, B, Q, R, S, q, r, c), reverse=True)
    Ps = jnp.concatenate([Ps, QT[None]], axis=0)
    ps = jnp.concatenate([ps, qT[None]], axis=0)
    vs = jnp.concatenate([vs, zero[None]], axis=0)

    def forward(x, data):
        A_t, B_t, c_t, K, k = data
        u = mm(K, x) + k
        return mm(A_t, x) + mm(B_t, u) + c_t, (x, u)

    xT, (xs, us) = jax.lax.scan(forward, x0, (A, B, c, Ks, ks))
    xs = jnp.concatenate([xs, xT[None]], axis=0)
    X = xs[:-1]
    cost = (
        0.5 * einsum("ti,tij,tj->", X, Q, X)
        + 0.5 * einsum("ti,tij,tj->", us, R, us)
        + einsum("ti,tij,tj->", us, S, X)
        + jnp.sum(q * X)
        + jnp.sum(r * us)
        + 0.5 * dot(matmul(xT, QT), xT)
        + dot(qT, xT)
    )
    good = jnp.all(ok) & _all_finite(Ks, ks, Ps, ps, xs, us, cost)
    result = RESULTS.where(good, RESULTS.successful, RESULTS.not_positive_definite)
    if throw:
        xs = result.error_if(xs, result != RESULTS.successful)
    return LQRSolution(xs=xs, us=us, Ks=Ks, ks=ks, Ps=Ps, ps=ps, vs=vs, cost=cost, result=result)

