"""Gauss-Newton with a backtracking (Armijo) line search, and the line search it shares with
gradient descent."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._checks import _all_finite, _check_int
from ._linalg import dot, matmul
from ._ls_base import (
    AbstractLeastSquaresSolver,
    _cost_change,
    _model,
    _placeholder,
    _State,
    _stats,
    _terminate,
    _tolerances,
)

_ARMIJO_C1 = 1e-4  # sufficient-decrease constant of the line search


def _line_search_state(problem, y, r, J, short_fat, rtol, atol, *, steepest, **status) -> _State:
    """The undamped state at ``y`` of the line-search solvers (Gauss-Newton and gradient descent)."""
    zero = jnp.zeros((), y.dtype)
    model = _model(problem, y, r, J, zero, None, short_fat, rtol, atol, steepest=steepest)
    return _State(**model, lam=zero, nu=zero, lam_scale=zero, diag=None, **status)


def _line_search_step(solver, problem, y, args, state, *, steepest: bool) -> tuple[Float[Array, " n"], _State]:
    """One backtracking (Armijo) line search along the pending step ``state.p``, then the new state.

    Tries ``clip(y + alpha p)`` for ``alpha = 1, 1/2, ..., 2^-max_backtracks`` until
    ``F(y + s) <= F(y) + c1 min(g^T s, 0)``; a non-finite trial point fails the test. When none
    passes (or ``p`` is not finite) ``y`` is kept and the state is marked stalled.

    With ``steepest`` (static) a trial point also passes Hager and Zhang's approximate Armijo test
    (2005, eq. 23), ``g_s^T s <= (2 c1 - 1) g^T s < 0`` with ``g_s`` the gradient at ``y + s``,
    when the cost change is below ``sqrt(eps) F(y)`` in magnitude. It is the Armijo test with
    ``F(y + s) - F(y)`` replaced by the trapezoid rule ``(g + g_s)^T s / 2`` (exact for a linear
    residual), computed from gradients, which are accurate where cost differences are rounding
    noise: without it a linearly convergent method stalls about ``sqrt(eps)`` from a minimum with
    a nonzero residual. Gauss-Newton's step jumps past that region and does not need it.
    """
    rtol, atol = _tolerances(solver, y.dtype)
    m, n = state.J.shape
    # from the placeholder (zero pending step): the first trial point, y itself, is the initial
    # linearization, taken
    first = state.placeholder

    def trial(alpha):
        y_t = problem.project(y + alpha * state.p)
        r_t, J_t = problem.linearize(y_t, args)
        finite = _all_finite(r_t, J_t)
        slope = jnp.minimum(dot(state.g, y_t - y), 0)
        dF = _cost_change(state.r, r_t)
        ok = finite & (dF <= _ARMIJO_C1 * slope)
        if steepest:
            flat = jnp.abs(dF) <= jnp.sqrt(jnp.finfo(y.dtype).eps) * state.cost
            slope_t = dot(matmul(r_t, J_t), y_t - y)
            ok = ok | (finite & flat & (slope < 0) & (slope_t <= (2 * _ARMIJO_C1 - 1) * slope))
        return y_t, r_t, J_t, ok | first, finite

    # alpha = 1, 1/2, ..., 2^-max_backtracks; the first trial runs inside the loop too, so
    # that fn and its Jacobian are traced (and compiled) once.
    def cond(c):
        k, _, (_, _, _, ok, _) = c
        return jnp.invert(ok) & (k <= solver.max_backtracks)

    def body(c):
        k, alpha, _ = c
        return k + 1, 0.5 * alpha, trial(alpha)

    no = jnp.array(False)
    init = (jnp.array(0), jnp.ones((), y.dtype), (y, state.r, state.J, no, no))
    _, _, (y_t, r_t, J_t, ok, finite) = jax.lax.while_loop(cond, body, init)
    accept = ok & state.step_ok
    y_new = jnp.where(accept, y_t, y)
    r = jnp.where(accept, r_t, state.r)
    J = jnp.where(accept, J_t, state.J)
    new_state = _line_search_state(
        problem, y_new, r, J, m < n, rtol, atol,
        steepest=steepest, stalled=jnp.invert(accept), stall_nonfinite=jnp.invert(finite),
        step_norm=jnp.max(jnp.abs(y_t - y)), placeholder=jnp.array(False),
    )
    return y_new, new_state


class _AbstractLineSearch(AbstractLeastSquaresSolver):
    """The fields and steps shared by :class:`GaussNewton` and :class:`GradientDescent`: one
    backtracking line search per iteration along the Gauss-Newton (``steepest = False``) or the
    projected gradient (``steepest = True``) direction."""

    steepest: ClassVar[bool]
    rtol: Float[Array, ""] = eqx.field(default=1e-8, converter=jnp.asarray)
    atol: Float[Array, ""] = eqx.field(default=1e-10, converter=jnp.asarray)
    max_steps: int = eqx.field(default=100, static=True)
    fixed_steps: bool = eqx.field(default=False, static=True)
    max_backtracks: int = eqx.field(default=8, static=True)

    def __check_init__(self):
        _check_int("max_steps", self.max_steps, 1)
        _check_int("max_backtracks", self.max_backtracks, 0)

    def init_placeholder(self, problem, y, args):
        return _placeholder(problem, y, args)

    def step(self, problem, y, args, state):
        return _line_search_step(self, problem, y, args, state, steepest=self.steepest)

    def terminate(self, problem, y, args, state):
        rtol, atol = _tolerances(self, y.dtype)
        return _terminate(state, rtol, atol, singular_stops=True)

    def postprocess(self, problem, y, args, state, result):
        return y, _stats(state)


class GaussNewton(_AbstractLineSearch):
    r"""Gauss-Newton with a backtracking (Armijo) line search.

    Each iteration solves ``J^T J p = -J^T r`` (or the minimum-norm form
    ``p = -J^T (J J^T)^{-1} r`` when ``m < n``) and tries ``y + alpha p`` (clipped into the box) for
    ``alpha = 1, 1/2, ..., 2^-max_backtracks`` until
    ``F(y + s) <= F(y) + c1 g^T s`` (``c1 = 1e-4``). Converges in one step on a linear problem
    with a full-rank Jacobian. Fails with ``RESULTS.singular`` when ``J^T J`` cannot be factorized
    or no step decreases the cost while the model predicts a decrease: use
    :class:`LevenbergMarquardt` then.

    Attributes:
        rtol: relative tolerance of the convergence test (array; sweepable under ``vmap``).
        atol: absolute tolerance of the convergence test (array).
        max_steps: the most iterations (static). Each iteration is one line search.
        fixed_steps: if true, run exactly ``max_steps`` iterations in a ``lax.scan`` (a finished
            problem is frozen, so the result equals the adaptive mode's when it converges in
            ``max_steps``); the status is read at the end. For batches under ``vmap``.
        max_backtracks: the most step halvings per line search (static).
    """

    steepest: ClassVar[bool] = False

