r"""Nonlinear least squares: Gauss-Newton, Levenberg-Marquardt, gradient descent; optimistix/jaxopt adapters.

Every solver minimises

.. math::  F(y) = \tfrac12 \lVert r(y) \rVert^2, \qquad r: \mathbb{R}^n \to \mathbb{R}^m,
           \quad \text{optionally subject to } \ell \le y \le u,

from ``y0`` and returns the same :class:`~solvers.Solution` ``(value, result, stats)``. Around the
iterate ``y`` with residual ``r`` and Jacobian ``J`` (``[m, n]``) the model is
``F(y + s) ~ F(y) + g^T s + 0.5 s^T J^T J s`` with gradient ``g = J^T r``; the step solves

.. math::  (J^T J + \lambda D)\, p = -J^T r,

with ``lambda = 0`` for Gauss-Newton and an adaptive ``lambda > 0`` for Levenberg-Marquardt
(``D = I``, a per-variable weight matrix ``W``, or Marquardt's ``D = diag(J^T J)``). When the
Jacobian is short and fat (``m < n``) the same step is computed in residual space,
``p = -D^{-1} J^T (J D^{-1} J^T + lambda I)^{-1} r`` (the course notes' eq. 4.8, generalised to a
diagonal ``D`` by the push-through identity): an ``m x m`` Cholesky factorisation instead of
``n x n``. For Gauss-Newton that is the minimum-norm step. The choice is made statically from the
shapes. :class:`GradientDescent` (the course notes' Jacobian-transpose method, a slow baseline)
steps along ``-g`` instead, by Buss's step length ``|g|^2 / |J g|^2``: the minimiser of the same
model along ``-g`` (the Cauchy step); no linear system is solved.

Bounds are handled by projection with an active set (projected Newton, Bertsekas 1982): a
variable at a bound whose gradient pushes outwards is frozen for the step (its row and column of
the normal equations are replaced by the identity and its step is zero), and every trial point is
clipped into the box, so every iterate satisfies the bounds exactly.

One driver, :func:`_iterate`, owns ``max_steps``, the non-finite check and the statistics; it runs
either a ``lax.while_loop`` with early exit (adaptive mode) or a ``lax.scan`` of exactly
``max_steps`` iterations in which finished problems are frozen (``fixed_steps=True``, for batches:
under ``jax.vmap`` a while loop runs until its slowest element anyway, and a scan has no
per-iteration predicate). Both modes give the same iterates.

Convergence (checked after every iteration, on the step ``s`` that would be taken next, its
predicted decrease ``pred = -(g^T s + 0.5 |J s|^2)`` and the projected gradient)::

    (all |s_i| <= atol + rtol |y_i|  and  pred <= atol + rtol * cost  and  lambda <= tr(J D^-1 J^T))
    or   |g_free|_inf <= atol

with ``rtol`` floored at ``4 eps`` of the dtype so that float32 can meet the default tolerances.
Because the test looks at the *next* step, the returned value is about one step, ``~rtol |y|``,
from the minimum (a test on the last step taken, as in optimistix, costs one more iteration). The
damping condition stops a step that is short only because ``lambda`` is huge (after many rejected
trials) from passing as convergence. For :class:`GradientDescent` ``s`` is the (projected)
gradient step and there is no damping condition; its docstring says what that implies for the
accuracy. When no acceptable step exists (the line search of Gauss-Newton or gradient descent
fails, or Levenberg-Marquardt rejects a step at the largest ``lambda``) the solve stops: as
``successful`` if the model predicts no decrease above the tolerance (converged to working
precision, the usual end in float32), ``nonfinite`` if the last trial point was not finite, and
``singular`` otherwise. Cost decreases are computed as ``0.5 (r_new - r).(r_new + r)``, free of
the cancellation in ``F_new - F``, so nonzero-residual problems converge to full precision.
The solvers are pure functions of their inputs: ``least_squares`` is ``eqx.filter_jit``-ed and can
be ``jax.vmap``-ed over ``y0``, ``args``, ``bounds`` and the solvers' array fields.
"""


import abc
import warnings
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np
from equinox import AbstractVar
from jaxtyping import Array, ArrayLike, Bool, Float, Int, PyTree

from ._results import RESULTS, Solution
from ._checks import _all_finite, _fmt, _tree_where

__all__ = [
    "AbstractLeastSquaresSolver",
    "GaussNewton",
    "GradientDescent",
    "JaxoptSolver",
    "LevenbergMarquardt",
    "OptimistixSolver",
    "least_squares",
]

ResidualFn = Callable[[Float[Array, " n"], Any], Float[Array, " m"]]
JacobianFn = Callable[[Float[Array, " n"], Any], Float[Array, "m n"]]

_ARMIJO_C1 = 1e-4  # sufficient-decrease constant of the Gauss-Newton line search


# --------------------------------------------------------------------------------------------
# The problem: residual, Jacobian and box, closed over by the solvers.
# --------------------------------------------------------------------------------------------


class _Problem(eqx.Module):
    """``fn``/``jac`` and the box of one solve (built inside the jitted function)."""

    fn: ResidualFn = eqx.field(static=True)
    jac: JacobianFn | bool | None = eqx.field(static=True)  # True: fn returns (r, J)
    lower: Float[Array, " n"] | None
    upper: Float[Array, " n"] | None
    m: int = eqx.field(static=True)
    stop: Callable | None = eqx.field(static=True, default=None)

    @property
    def bounded(self) -> bool:
        return self.lower is not None

    def residual(self, y: Float[Array, " n"], args: PyTree) -> Float[Array, " m"]:
        if self.jac is True:  # the Jacobian is dead code here: XLA removes it
            return jnp.asarray(self.fn(y, args)[0]).astype(y.dtype)
        return jnp.asarray(self.fn(y, args)).astype(y.dtype)

    def linearise(self, y: Float[Array, " n"], args: PyTree) -> tuple[Float[Array, " m"], Float[Array, "m n"]]:
        """``(r(y), J(y))``: one call of ``fn`` when it returns both (``jac=True``), the user's
        ``jac`` if given, else forward (``m >= n``) or reverse mode."""
        if self.jac is True:
            r, J = self.fn(y, args)
            return jnp.asarray(r).astype(y.dtype), jnp.asarray(J).astype(y.dtype)
        if self.jac is not None:
            return self.residual(y, args), jnp.asarray(self.jac(y, args)).astype(y.dtype)

        def f(z):
            rz = self.residual(z, args)
            return rz, rz

        jacobian = jax.jacfwd if self.m >= y.shape[0] else jax.jacrev
        J, r = jacobian(f, has_aux=True)(y)
        return r, J

    def project(self, y: Float[Array, " n"]) -> Float[Array, " n"]:
        return jnp.clip(y, self.lower, self.upper) if self.bounded else y

    def free(self, y: Float[Array, " n"], g: Float[Array, " n"]) -> Bool[Array, " n"] | None:
        """Variables not frozen: frozen = at a bound with the gradient pushing outwards."""
        if not self.bounded:
            return None
        frozen = ((y <= self.lower) & (g > 0)) | ((y >= self.upper) & (g < 0))
        return jnp.invert(frozen)

    def custom_jvp_residual(self) -> ResidualFn:
        """``fn`` for the backends: with a ``jax.custom_jvp`` that uses ``jac`` when one is given.

        Tangents with respect to ``y`` go through ``J(y) @ t_y``; tangents with respect to array
        leaves of ``args`` (only present when the caller differentiates through the solve) go
        through ``jax.jvp`` of ``fn``. Non-array leaves of ``args`` are closed over.
        """
        fn, jac = self.fn, self.jac
        if jac is None:
            return fn
        if jac is True:
            fused = fn
            fn = lambda y, args: fused(y, args)[0]  # noqa: E731
            jac = lambda y, args: fused(y, args)[1]  # noqa: E731

        def wrapped(y, args):
            dyn, static = eqx.partition(args, eqx.is_array)

            @jax.custom_jvp
            def res(y_, dyn_):
                return fn(y_, eqx.combine(dyn_, static))

            def res_jvp(primals, tangents):
                y_, dyn_ = primals
                t_y, t_dyn = tangents
                a = eqx.combine(dyn_, static)
                r = jnp.asarray(fn(y_, a))
                out = jnp.zeros_like(r)
                if not isinstance(t_y, jax.custom_derivatives.SymbolicZero):
                    out = out + jnp.asarray(jac(y_, a)).astype(r.dtype) @ t_y.astype(r.dtype)
                t_leaves = jax.tree.leaves(t_dyn, is_leaf=lambda x: isinstance(x, jax.custom_derivatives.SymbolicZero))
                if any(not isinstance(t, jax.custom_derivatives.SymbolicZero) for t in t_leaves):
                    t_dyn = jax.tree.map(
                        lambda t, p: jnp.zeros_like(p) if isinstance(t, jax.custom_derivatives.SymbolicZero) else t,
                        t_dyn,
                        dyn_,
                        is_leaf=lambda x: isinstance(x, jax.custom_derivatives.SymbolicZero),
                    )
                    _, r_dot = jax.jvp(lambda d: fn(y_, eqx.combine(d, static)), (dyn_,), (t_dyn,))
                    out = out + r_dot
                return r, out

            res.defjvp(res_jvp, symbolic_zeros=True)
            return res(y, dyn)

        return wrapped


# --------------------------------------------------------------------------------------------
# Linear algebra shared by Gauss-Newton and Levenberg-Marquardt.
# --------------------------------------------------------------------------------------------


def _solve_normal(
    J: Float[Array, "m n"],
    r: Float[Array, " m"],
    g: Float[Array, " n"],
    lam: Float[Array, ""],
    diag: Float[Array, " n"] | None,
    free: Bool[Array, " n"] | None,
    short_fat: bool,
) -> tuple[Float[Array, " n"], Float[Array, ""]]:
    r"""The (damped) Gauss-Newton step ``p`` with frozen variables held at zero, and ``tr(J_F D^{-1} J_F^T)``.

    ``short_fat`` (static): ``p = -D^{-1} J_F^T (J_F D^{-1} J_F^T + lam I_m)^{-1} r``, an ``m x m``
    system (equal to the ``n x n`` one by the push-through identity, for any positive diagonal
    ``D``); otherwise ``(J_F^T J_F + lam D_F) p = -g_F`` with identity rows for frozen variables.
    ``J_F`` is ``J`` with the frozen columns zeroed; ``diag=None`` means ``D = I``. The step is
    non-finite when the Cholesky factorisation fails. The trace (the sum of the curvatures
    ``(J^T J)_ii / D_ii``) comes from the matrix already formed, at no extra pass over ``J``.
    """
    dtype = J.dtype
    if free is not None:
        J = J * free.astype(dtype)[None, :]
        g = jnp.where(free, g, 0)
    if short_fat:
        m = J.shape[0]
        JD = J if diag is None else J / diag[None, :]  # J D^{-1}
        JDJ = JD @ J.T
        B = JDJ + lam * jnp.eye(m, dtype=dtype)
        u = jsl.cho_solve((jnp.linalg.cholesky(B), True), r)
        return -(JD.T @ u), jnp.trace(JDJ)
    JJ = J.T @ J
    curvature = jnp.diagonal(JJ)
    d = lam * jnp.ones_like(g) if diag is None else lam * diag
    if diag is not None:
        curvature = curvature / diag
    if free is not None:
        d = jnp.where(free, d, 1)
    A = JJ + jnp.diag(d)
    return -jsl.cho_solve((jnp.linalg.cholesky(A), True), g), jnp.sum(curvature)


def _cauchy_step(
    J: Float[Array, "m n"], g: Float[Array, " n"], g_norm: Float[Array, ""]
) -> Float[Array, " n"]:
    r"""Buss's Jacobian-transpose step ``p = -alpha g``, ``alpha = |g|^2 / |J g|^2``.

    ``g`` is the gradient with frozen variables already zeroed and ``g_norm = |g|_inf``. ``alpha``
    minimises the model ``g^T s + 0.5 |J s|^2`` along ``s = -alpha g`` (the Cauchy step). It does
    not depend on the scale of ``g``, so it is computed from ``g / |g|_inf``, which cannot overflow.
    The step is 0 when ``g = 0``, and non-finite only when ``J g`` underflows while ``g`` does not.
    """
    positive = g_norm > 0
    d = g / jnp.where(positive, g_norm, 1)
    Jd = J @ d
    JdJd = Jd @ Jd
    alpha = (d @ d) / jnp.where(positive, JdJd, 1)
    return jnp.where(positive, -alpha * g, 0)


def _cost_change(r: Float[Array, " m"], r_new: Float[Array, " m"]) -> Float[Array, ""]:
    """``F(y_new) - F(y) = 0.5 (r_new - r) . (r_new + r)``, without the cancellation of ``F_new - F``."""
    return 0.5 * ((r_new - r) @ (r_new + r))


class _State(eqx.Module):
    """Solver state at the iterate ``y`` (shared by all the own solvers)."""

    # linearisation at y
    r: Float[Array, " m"]
    J: Float[Array, "m n"]
    g: Float[Array, " n"]  # J^T r
    cost: Float[Array, ""]  # 0.5 |r|^2
    g_norm: Float[Array, ""]  # |g|_inf over the free variables
    # the pending step from y
    p: Float[Array, " n"]  # unprojected step (frozen variables 0)
    y_trial: Float[Array, " n"]  # clip(y + p)
    pred: Float[Array, ""]  # model decrease of y_trial - y
    step_ok: Bool[Array, ""]  # p is finite
    # damping (Levenberg-Marquardt; zeros for Gauss-Newton and gradient descent)
    lam: Float[Array, ""]
    nu: Float[Array, ""]
    lam_scale: Float[Array, ""]  # max_i (J^T J)_ii / D_i at y0: lambda lives in [eps, 1/eps] * lam_scale
    diag: Float[Array, " n"] | None  # D (None: the identity)
    # status
    converged: Bool[Array, ""]
    stalled: Bool[Array, ""]  # no acceptable step could be found
    stall_nonfinite: Bool[Array, ""]  # ... because the last trial point was non-finite
    step_norm: Float[Array, ""]  # |s|_inf of the last step tried


def _model(
    problem: _Problem,
    y: Float[Array, " n"],
    r: Float[Array, " m"],
    J: Float[Array, "m n"],
    lam: Float[Array, ""],
    diag: Float[Array, " n"] | None,
    short_fat: bool,
    rtol: Float[Array, ""],
    atol: Float[Array, ""],
    *,
    steepest: bool = False,
) -> dict[str, Array]:
    """Gradient, pending step, predicted decrease and the convergence test at ``y``.

    The step solves the (damped) normal equations, or with ``steepest`` (static; ``lam`` must be
    0) is the Cauchy step :func:`_cauchy_step`, for which the damping condition is void.
    """
    g = J.T @ r
    cost = 0.5 * (r @ r)
    free = problem.free(y, g)
    g_free = g if free is None else jnp.where(free, g, 0)
    g_norm = jnp.max(jnp.abs(g_free))
    if steepest:
        p = _cauchy_step(J, g_free, g_norm)
    else:
        p, curvature = _solve_normal(J, r, g, lam, diag, free, short_fat)
    step_ok = _all_finite(p)
    p = jnp.where(step_ok, p, 0)
    y_trial = problem.project(y + p)
    s = y_trial - y
    if problem.bounded:  # the projected step: evaluate the model
        Js = J @ s
        pred = -(g @ s) - 0.5 * (Js @ Js)
    else:  # (J^T J + lam D) p = -g gives |J p|^2 = -g.p - lam p.D.p: no pass over J (for the
        # Cauchy step p = -alpha g, lam = 0: |J p|^2 = alpha^2 |J g|^2 = alpha |g|^2 = -g.p as well)
        pDp = p @ p if diag is None else (p * diag) @ p
        pred = 0.5 * (lam * pDp - g @ p)
    small_step = jnp.all(jnp.abs(s) <= atol + rtol * jnp.abs(y))
    small_pred = pred <= atol + rtol * cost
    # A heavily damped step is short because of the damping, not because y is near a minimum:
    # trust the step test only while lambda is below the total curvature sum_i (J^T J)_ii / D_ii.
    trusted = jnp.array(True) if steepest else lam <= curvature
    converged = (step_ok & trusted & small_step & small_pred) | (g_norm <= atol)
    return dict(
        r=r, J=J, g=g, cost=cost, g_norm=g_norm, p=p, y_trial=y_trial, pred=pred, step_ok=step_ok, converged=converged
    )


def _tolerances(solver, dtype) -> tuple[Float[Array, ""], Float[Array, ""]]:
    eps = jnp.finfo(dtype).eps
    rtol = jnp.maximum(jnp.asarray(solver.rtol, dtype), 4 * eps)
    atol = jnp.asarray(solver.atol, dtype)
    return rtol, atol


# --------------------------------------------------------------------------------------------
# Solvers: abstract interface and the two final classes.
# --------------------------------------------------------------------------------------------


class AbstractLeastSquaresSolver(eqx.Module):
    """A least-squares method driven by :func:`least_squares` through ``init/step/terminate/postprocess``.

    Subclasses are final. They provide the fields ``rtol``, ``atol`` (arrays), ``max_steps``
    (static int) and ``fixed_steps`` (static bool); the driver owns the loop, ``max_steps``, the
    non-finite check and the statistics.
    """

    rtol: AbstractVar[Float[Array, ""]]
    atol: AbstractVar[Float[Array, ""]]
    max_steps: AbstractVar[int]
    fixed_steps: AbstractVar[bool]

    @abc.abstractmethod
    def init(self, problem: _Problem, y: Float[Array, " n"], args: PyTree) -> _State:
        """Linearise at ``y`` (already inside the box) and prepare the first step."""

    @abc.abstractmethod
    def step(
        self, problem: _Problem, y: Float[Array, " n"], args: PyTree, state: _State
    ) -> tuple[Float[Array, " n"], _State]:
        """One iteration: returns the next iterate (possibly ``y`` itself) and state."""

    @abc.abstractmethod
    def terminate(
        self, problem: _Problem, y: Float[Array, " n"], args: PyTree, state: _State
    ) -> tuple[Bool[Array, ""], RESULTS]:
        """``(stop, result)`` at ``y``; ``result`` only matters when ``stop``."""

    @abc.abstractmethod
    def postprocess(
        self, problem: _Problem, y: Float[Array, " n"], args: PyTree, state: _State, result: RESULTS
    ) -> tuple[Float[Array, " n"], dict[str, Array]]:
        """The value to return and the solver's statistics (``cost``, ``grad_norm``, ...)."""


def _terminate(state: _State, rtol, atol, *, singular_stops: bool) -> tuple[Bool[Array, ""], RESULTS]:
    # A stall (no acceptable step) counts as converged to working precision when the model
    # predicts nothing worth having; otherwise it is a failure.
    stall_result = RESULTS.where(
        state.stall_nonfinite,
        RESULTS.nonfinite,
        RESULTS.where(state.pred <= atol + rtol * state.cost, RESULTS.successful, RESULTS.singular),
    )
    stop = state.converged | state.stalled
    result = RESULTS.where(state.converged, RESULTS.successful, stall_result)
    if singular_stops:
        bad = jnp.invert(state.step_ok) & jnp.invert(state.converged)
        stop = stop | bad
        result = RESULTS.where(bad, RESULTS.singular, result)
    return stop, result


def _stats(state: _State) -> dict[str, Array]:
    def finite_or_inf(x):
        return jnp.where(jnp.isfinite(x), x, jnp.inf)

    return dict(
        cost=finite_or_inf(state.cost),
        grad_norm=finite_or_inf(state.g_norm),
        step_norm=finite_or_inf(state.step_norm),
        damping=finite_or_inf(state.lam),
    )


def _line_search_state(problem, y, r, J, short_fat, rtol, atol, *, steepest, **status) -> _State:
    """The undamped state at ``y`` of the line-search solvers (Gauss-Newton and gradient descent)."""
    zero = jnp.zeros((), y.dtype)
    model = _model(problem, y, r, J, zero, None, short_fat, rtol, atol, steepest=steepest)
    return _State(**model, lam=zero, nu=zero, lam_scale=zero, diag=None, **status)


def _line_search_init(solver, problem, y, args, *, steepest: bool) -> _State:
    r, J = problem.linearise(y, args)
    m, n = J.shape
    rtol, atol = _tolerances(solver, y.dtype)
    no = jnp.array(False)
    return _line_search_state(
        problem, y, r, J, m < n, rtol, atol,
        steepest=steepest, stalled=no, stall_nonfinite=no, step_norm=jnp.zeros((), y.dtype),
    )


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

    def trial(alpha):
        y_t = problem.project(y + alpha * state.p)
        r_t, J_t = problem.linearise(y_t, args)
        finite = _all_finite(r_t, J_t)
        slope = jnp.minimum(state.g @ (y_t - y), 0)
        dF = _cost_change(state.r, r_t)
        ok = finite & (dF <= _ARMIJO_C1 * slope)
        if steepest:
            flat = jnp.abs(dF) <= jnp.sqrt(jnp.finfo(y.dtype).eps) * state.cost
            slope_t = (r_t @ J_t) @ (y_t - y)
            ok = ok | (finite & flat & (slope < 0) & (slope_t <= (2 * _ARMIJO_C1 - 1) * slope))
        return y_t, r_t, J_t, ok, finite

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
        step_norm=jnp.max(jnp.abs(y_t - y)),
    )
    return y_new, new_state


class GaussNewton(AbstractLeastSquaresSolver):
    r"""Gauss-Newton with a backtracking (Armijo) line search.

    Each iteration solves ``J^T J p = -J^T r`` (or the minimum-norm form
    ``p = -J^T (J J^T)^{-1} r`` when ``m < n``) and tries ``y + alpha p`` (clipped into the box) for
    ``alpha = 1, 1/2, ..., 2^-max_backtracks`` until
    ``F(y + s) <= F(y) + c1 g^T s`` (``c1 = 1e-4``). Converges in one step on a linear problem
    with a full-rank Jacobian. Fails with ``RESULTS.singular`` when ``J^T J`` cannot be factorised
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

    rtol: Float[Array, ""] = eqx.field(default=1e-8, converter=jnp.asarray)
    atol: Float[Array, ""] = eqx.field(default=1e-10, converter=jnp.asarray)
    max_steps: int = eqx.field(default=100, static=True)
    fixed_steps: bool = eqx.field(default=False, static=True)
    max_backtracks: int = eqx.field(default=8, static=True)

    def __check_init__(self):
        _check_int("max_steps", self.max_steps, 1)
        _check_int("max_backtracks", self.max_backtracks, 0)

    def init(self, problem, y, args):
        return _line_search_init(self, problem, y, args, steepest=False)

    def step(self, problem, y, args, state):
        return _line_search_step(self, problem, y, args, state, steepest=False)

    def terminate(self, problem, y, args, state):
        rtol, atol = _tolerances(self, y.dtype)
        return _terminate(state, rtol, atol, singular_stops=True)

    def postprocess(self, problem, y, args, state, result):
        return y, _stats(state)


class LevenbergMarquardt(AbstractLeastSquaresSolver):
    r"""Levenberg-Marquardt with Nielsen's damping update.

    Each iteration solves ``(J^T J + lambda D) p = -J^T r`` (in residual space when ``m < n``),
    evaluates the trial point ``y + s`` (``s`` the step clipped into the box) and the gain ratio
    ``rho = (F(y) - F(y + s)) / pred(s)``, ``pred(s) = -(g^T s + 0.5 |J s|^2)``. The step is
    accepted when ``rho > 0``: then ``lambda *= max(1/3, 1 - (2 rho - 1)^3)``, ``nu = 2``;
    otherwise ``lambda *= nu``, ``nu *= 2`` (Nielsen 1999; Madsen, Nielsen & Tingleff, *Methods for
    non-linear least squares problems*, 2004, alg. 3.16). A trial point with a non-finite residual
    or Jacobian is rejected like a bad step, so the solver backs away from it; it fails with
    ``RESULTS.nonfinite`` only if no finite step remains. ``lambda`` is kept in
    ``[eps, 1/eps] * lambda_scale`` (``lambda_scale = max_i (J^T J)_ii / D_ii`` at ``y0``).

    Attributes:
        rtol: relative tolerance of the convergence test (array; sweepable under ``vmap``).
        atol: absolute tolerance of the convergence test (array).
        max_steps: the most iterations (static); rejected trial steps count.
        fixed_steps: if true, run exactly ``max_steps`` iterations in a ``lax.scan`` (see
            :class:`GaussNewton`).
        lambda0: initial damping *relative* to the curvature, ``lambda = lambda0 * lambda_scale``
            (Madsen-Nielsen's ``tau``; 1e-3 for a good start, up to 1 for a poor one). An array, so
            ``vmap`` can sweep it.
        scaling: if true, use Marquardt's scaling ``D = diag(J^T J)``, accumulated as the running
            maximum over accepted iterates (zero columns at ``y0`` get 1), instead of ``D = I``.
            Makes the method invariant to the scale of the variables.
        weights: optional ``[n]`` positive per-variable weights ``w``: ``D = diag(w)`` (the
            course notes' joint weight matrix ``W``: a variable with a large weight resists
            moving while the damping is large), or ``D = diag(w * J^T J)`` with ``scaling``. An
            array, so ``vmap`` can sweep it; the ``m x m`` form is kept for ``m < n``.
    """

    rtol: Float[Array, ""] = eqx.field(default=1e-8, converter=jnp.asarray)
    atol: Float[Array, ""] = eqx.field(default=1e-10, converter=jnp.asarray)
    max_steps: int = eqx.field(default=100, static=True)
    fixed_steps: bool = eqx.field(default=False, static=True)
    lambda0: Float[Array, ""] = eqx.field(default=1e-3, converter=jnp.asarray)
    scaling: bool = eqx.field(default=False, static=True)
    weights: Float[Array, " n"] | None = eqx.field(
        default=None, converter=lambda w: None if w is None else jnp.asarray(w)
    )

    def __check_init__(self):
        _check_int("max_steps", self.max_steps, 1)
        if self.weights is not None and not isinstance(self.weights, jax.core.Tracer):
            if self.weights.ndim != 1:
                raise ValueError(f"weights: expected shape (n,), got {_fmt(self.weights.shape)}")
            if not np.all(np.asarray(self.weights) > 0):
                raise ValueError("weights: expected positive per-variable weights")

    def _short_fat(self, m: int, n: int) -> bool:
        return m < n

    def init(self, problem, y, args):
        dtype = y.dtype
        eps = jnp.finfo(dtype).eps
        r, J = problem.linearise(y, args)
        m, n = J.shape
        rtol, atol = _tolerances(self, dtype)
        colsq = jnp.sum(J * J, axis=0)
        diag = jnp.where(colsq > 0, colsq, 1) if self.scaling else None
        if self.weights is not None:
            w = jnp.asarray(self.weights, dtype)
            diag = w if diag is None else diag * w
        lam_scale = jnp.max(colsq if diag is None else colsq / diag)
        lam_scale = jnp.where(jnp.isfinite(lam_scale) & (lam_scale > 0), lam_scale, 1)
        lam = jnp.clip(jnp.asarray(self.lambda0, dtype) * lam_scale, eps * lam_scale, lam_scale / eps)
        model = _model(problem, y, r, J, lam, diag, self._short_fat(m, n), rtol, atol)
        no = jnp.array(False)
        return _State(
            **model, lam=lam, nu=jnp.asarray(2, dtype), lam_scale=lam_scale, diag=diag,
            stalled=no, stall_nonfinite=no, step_norm=jnp.zeros((), dtype),
        )

    def step(self, problem, y, args, state):
        dtype = y.dtype
        eps = jnp.finfo(dtype).eps
        rtol, atol = _tolerances(self, dtype)
        m, n = state.J.shape
        y_t = state.y_trial
        r_t, J_t = problem.linearise(y_t, args)
        finite = _all_finite(r_t, J_t)
        valid = state.step_ok & (state.pred > 0)
        rho = -_cost_change(state.r, r_t) / jnp.where(valid, state.pred, 1)
        accept = finite & valid & (rho > 0)
        lam_max = state.lam_scale / eps
        lam_acc = jnp.maximum(state.lam * jnp.maximum(1 / 3, 1 - (2 * rho - 1) ** 3), eps * state.lam_scale)
        lam = jnp.where(accept, lam_acc, jnp.minimum(state.lam * state.nu, lam_max))
        nu = jnp.where(accept, 2, 2 * state.nu)
        stalled = jnp.invert(accept) & (state.lam >= lam_max)
        y_new = jnp.where(accept, y_t, y)
        r = jnp.where(accept, r_t, state.r)
        J = jnp.where(accept, J_t, state.J)
        diag = state.diag
        if self.scaling:
            colsq = jnp.sum(J * J, axis=0)
            if self.weights is not None:
                colsq = colsq * jnp.asarray(self.weights, dtype)
            diag = jnp.where(accept, jnp.maximum(diag, colsq), diag)
        model = _model(problem, y_new, r, J, lam, diag, self._short_fat(m, n), rtol, atol)
        new_state = _State(
            **model, lam=lam, nu=nu, lam_scale=state.lam_scale, diag=diag,
            stalled=stalled, stall_nonfinite=stalled & jnp.invert(finite),
            step_norm=jnp.max(jnp.abs(y_t - y)),
        )
        return y_new, new_state

    def terminate(self, problem, y, args, state):
        rtol, atol = _tolerances(self, y.dtype)
        return _terminate(state, rtol, atol, singular_stops=False)

    def postprocess(self, problem, y, args, state, result):
        return y, _stats(state)


class GradientDescent(AbstractLeastSquaresSolver):
    r"""Gradient descent (the Jacobian-transpose method) with Buss's step length: a baseline.

    Each iteration steps along the negative projected gradient ``-g``, ``g = J^T r`` (variables at
    an active bound whose gradient pushes outwards are held fixed), with Buss's step length
    ``alpha = |g|^2 / |J g|^2``, the exact minimiser of the Gauss-Newton model
    ``F + g^T s + 0.5 |J s|^2`` along ``-g`` (the Cauchy step; Buss 2004, *Introduction to inverse
    kinematics with Jacobian transpose, pseudoinverse and damped least squares methods*). The
    trial point ``y + alpha p`` is clipped into the box and accepted by the same backtracking
    (Armijo) line search as :class:`GaussNewton`: ``alpha`` is halved up to ``max_backtracks``
    times until ``F(y + s) <= F(y) + c1 g^T s`` (``c1 = 1e-4``), or, where the cost change is
    below ``sqrt(eps) F(y)`` and so mostly rounding, until the same test holds with the cost
    change estimated from the gradients at both ends (Hager and Zhang's approximate Armijo test;
    see :func:`_line_search_step`). Without it, the last linearly convergent steps towards a
    minimum with a nonzero residual cannot be told from rounding noise and the solve stalls
    ``~sqrt(eps)`` from it; with it, ``cost_history`` may rise by a few ulps near the end.

    A first-order method: it needs no linear solve, but converges only linearly, at a rate set by
    the condition number ``kappa`` of ``J^T J`` (about ``((kappa - 1) / (kappa + 1))^2`` per
    iteration on a linear problem), and takes thousands of iterations on a badly conditioned or
    curved problem such as Rosenbrock. It is meant as the course notes' baseline to compare
    :class:`GaussNewton` and :class:`LevenbergMarquardt` against, not for production solves.

    Convergence is tested after every iteration on the pending projected step
    ``s = clip(y - alpha g) - y`` and its predicted decrease ``pred = -(g^T s + 0.5 |J s|^2)``
    (``= 0.5 alpha |g|^2`` without bounds)::

        (all |s_i| <= atol + rtol |y_i|  and  pred <= atol + rtol * cost)  or  |g_free|_inf <= atol

    (``rtol`` floored at ``4 eps`` of the dtype). This is the Gauss-Newton test of the module
    docstring with the gradient step in place of the Gauss-Newton step and without the damping
    condition.
    Because the gradient step underestimates the distance to the minimum by up to ``kappa``,
    the returned value is within about ``kappa rtol |y|`` of the minimum (not ``rtol |y|``):
    tighten ``rtol`` accordingly. When no trial point passes the line search the solve stops as
    ``successful`` if ``pred <= atol + rtol * cost`` (working precision), ``nonfinite`` if the last
    trial point was not finite, and ``singular`` otherwise; ``singular`` also when ``alpha``
    overflows (``J g`` underflows to zero). The statistic ``damping`` is 0 (there is no damping;
    the step length is not reported).

    Attributes:
        rtol: relative tolerance of the convergence test (array; sweepable under ``vmap``).
        atol: absolute tolerance of the convergence test (array).
        max_steps: the most iterations (static). Each iteration is one line search.
        fixed_steps: if true, run exactly ``max_steps`` iterations in a ``lax.scan`` (see
            :class:`GaussNewton`).
        max_backtracks: the most step halvings per line search (static).
    """

    rtol: Float[Array, ""] = eqx.field(default=1e-8, converter=jnp.asarray)
    atol: Float[Array, ""] = eqx.field(default=1e-10, converter=jnp.asarray)
    max_steps: int = eqx.field(default=1000, static=True)
    fixed_steps: bool = eqx.field(default=False, static=True)
    max_backtracks: int = eqx.field(default=8, static=True)

    def __check_init__(self):
        _check_int("max_steps", self.max_steps, 1)
        _check_int("max_backtracks", self.max_backtracks, 0)

    def init(self, problem, y, args):
        return _line_search_init(self, problem, y, args, steepest=True)

    def step(self, problem, y, args, state):
        return _line_search_step(self, problem, y, args, state, steepest=True)

    def terminate(self, problem, y, args, state):
        rtol, atol = _tolerances(self, y.dtype)
        return _terminate(state, rtol, atol, singular_stops=True)

    def postprocess(self, problem, y, args, state, result):
        return y, _stats(state)


def _check_int(name: str, value, minimum: int) -> None:
    if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < minimum:
        raise ValueError(f"{name}: expected an int >= {minimum}, got {value!r}")


# --------------------------------------------------------------------------------------------
# The driver.
# --------------------------------------------------------------------------------------------


class _Carry(eqx.Module):
    y: Float[Array, " n"]
    state: _State
    num_steps: Int[Array, ""]
    done: Bool[Array, ""]
    result: RESULTS
    cost_history: Float[Array, " max_steps+1"]


def _iterate(solver: AbstractLeastSquaresSolver, problem: _Problem, y0: Float[Array, " n"], args: PyTree) -> Solution:
    """Run ``solver`` from ``y0`` (inside the box): the single loop behind every own solver."""
    max_steps = solver.max_steps

    # The non-finite check: at y0 here; afterwards the solvers' steps only ever accept trial
    # points whose residual and Jacobian are finite (a non-finite trial is a rejected step), so
    # every accepted state stays finite and `value` is always the last finite iterate.
    def terminate(y, state):
        done, result = solver.terminate(problem, y, args, state)
        if problem.stop is not None:  # the user's criterion: good enough, stop here as converged
            user = jnp.asarray(problem.stop(y, state.r, args), bool)
            done, result = done | user, RESULTS.where(user, RESULTS.successful, result)
        return done, result

    state0 = solver.init(problem, y0, args)
    stop0, result0 = terminate(y0, state0)
    finite0 = _all_finite(y0, state0.r, state0.J)
    carry = _Carry(
        y=y0,
        state=state0,
        num_steps=jnp.zeros((), jnp.int32),
        done=stop0 | jnp.invert(finite0),
        result=RESULTS.where(finite0, result0, RESULTS.nonfinite),
        cost_history=jnp.full((max_steps + 1,), state0.cost),
    )

    def body(c: _Carry) -> _Carry:
        y, state = solver.step(problem, c.y, args, c.state)
        done, result = terminate(y, state)
        k = c.num_steps + 1
        return _Carry(y, state, k, done, result, c.cost_history.at[k].set(state.cost))

    if solver.fixed_steps:

        def scan_body(c, _):
            return _tree_where(c.done, c, body(c)), None

        carry, _ = jax.lax.scan(scan_body, carry, None, length=max_steps)
    else:
        carry = jax.lax.while_loop(lambda c: jnp.invert(c.done) & (c.num_steps < max_steps), body, carry)

    result = RESULTS.where(carry.done, carry.result, RESULTS.max_steps_reached)
    value, stats = solver.postprocess(problem, carry.y, args, carry.state, result)
    steps = jnp.arange(max_steps + 1)
    history = jnp.where(steps <= carry.num_steps, carry.cost_history, carry.state.cost)
    stats = dict(stats, num_steps=carry.num_steps, cost_history=jnp.where(jnp.isfinite(history), history, jnp.inf))
    return Solution(value=value, result=result, stats=stats)


# --------------------------------------------------------------------------------------------
# Backend adapters.
# --------------------------------------------------------------------------------------------


class _AbstractAdapter(eqx.Module):
    """A third-party least-squares solver behind :func:`least_squares` (no bounds)."""

    max_steps: AbstractVar[int]

    @abc.abstractmethod
    def _solve(self, problem: _Problem, y0: Float[Array, " n"], args: PyTree) -> Solution:
        ...


def _adapter_solution(
    problem: _Problem,
    y0: Float[Array, " n"],
    args: PyTree,
    value: Float[Array, " n"],
    result: RESULTS,
    num_steps: Int[Array, ""],
    step: Float[Array, " n"],
    damping: Float[Array, ""],
    max_steps: int,
) -> Solution:
    """Common stats for the adapters; a non-finite value is replaced by ``y0``."""
    dtype = y0.dtype
    value = jnp.asarray(value).astype(dtype)
    ok = _all_finite(value)
    value = jnp.where(ok, value, y0)
    r, J = problem.linearise(value, args)
    r0 = problem.residual(y0, args)
    cost = 0.5 * (r @ r)
    g = J.T @ r
    ok = ok & jnp.isfinite(cost) & _all_finite(g)
    result = RESULTS.where(ok, result, RESULTS.nonfinite)

    def finite_or_inf(x):
        return jnp.where(jnp.isfinite(x), x, jnp.inf)

    cost = finite_or_inf(cost)
    history = jnp.full((max_steps + 1,), cost).at[0].set(finite_or_inf(0.5 * (r0 @ r0)))
    stats = dict(
        num_steps=jnp.asarray(num_steps),
        cost=cost,
        grad_norm=finite_or_inf(jnp.max(jnp.abs(g))),
        step_norm=finite_or_inf(jnp.max(jnp.abs(step.astype(dtype)))),
        damping=finite_or_inf(jnp.asarray(damping, dtype)),
        cost_history=history,
    )
    return Solution(value=value, result=result, stats=stats)


class OptimistixSolver(_AbstractAdapter):
    """Adapter for an optimistix least-squares solver (``optx.LevenbergMarquardt``, ``GaussNewton``, ``Dogleg``).

    ``least_squares(fn, OptimistixSolver(optx.LevenbergMarquardt(rtol, atol)), y0, jac=jac)`` runs
    ``optx.least_squares(..., throw=False)`` and returns the same :class:`Solution` as the own
    solvers (optimistix's state is never returned: it cannot be batched). A user ``jac`` reaches
    optimistix through a ``jax.custom_jvp`` on the residual, so the analytic Jacobian is used, not
    autodiff of ``fn``. optimistix results map to :class:`RESULTS` (``nonlinear_max_steps_reached``
    -> ``max_steps_reached``, non-finite -> ``nonfinite``, any linear-solver failure ->
    ``singular``). Statistics: ``step_norm`` is the step optimistix would try next, ``damping``
    is ``1 / trust-region step size`` for ``optx.LevenbergMarquardt`` (0 otherwise), and
    ``cost_history`` holds the initial cost then the final cost (intermediate costs are not
    reported by optimistix). Bounds are not supported. Known limitation of optimistix 0.1.0:
    with ``jax_enable_x64`` on, ``optx.LevenbergMarquardt`` and ``optx.Dogleg`` fail to trace for a
    float32 ``y0`` (a float64 damping term meets float32 residuals); float32 works with x64 off.

    Attributes:
        solver: the optimistix solver instance.
        max_steps: the most iterations (static).
        options: passed to ``optx.least_squares`` as ``options`` (e.g. ``{"jac": "bwd"}``); stored
            as a hashable tuple of items (it is static).
    """

    solver: Any
    max_steps: int = eqx.field(default=100, static=True)
    options: tuple[tuple[str, Any], ...] | None = eqx.field(
        default=None, static=True, converter=lambda o: None if o is None else tuple(sorted(dict(o).items()))
    )

    def __check_init__(self):
        import optimistix as optx

        if not isinstance(self.solver, optx.AbstractLeastSquaresSolver):
            raise ValueError(
                f"solver: expected an optimistix least-squares solver (optx.LevenbergMarquardt, "
                f"optx.GaussNewton, optx.Dogleg, ...), got {type(self.solver).__name__}"
            )
        _check_int("max_steps", self.max_steps, 1)

    def _solve(self, problem, y0, args):
        import optimistix as optx

        fn = problem.custom_jvp_residual()
        sol = optx.least_squares(
            fn, self.solver, y0, args, options=dict(self.options or ()), max_steps=self.max_steps, throw=False
        )
        r = sol.result
        result = RESULTS.where(
            r == optx.RESULTS.successful,
            RESULTS.successful,
            RESULTS.where(
                r == optx.RESULTS.nonlinear_max_steps_reached,
                RESULTS.max_steps_reached,
                RESULTS.where(
                    (r == optx.RESULTS.nonfinite) | (r == optx.RESULTS.nonfinite_input),
                    RESULTS.nonfinite,
                    RESULTS.singular,
                ),
            ),
        )
        y_eval = getattr(sol.state, "y_eval", None)
        step = jnp.zeros_like(y0) if y_eval is None else y_eval - sol.value
        damping = jnp.zeros((), y0.dtype)
        if isinstance(self.solver, optx.LevenbergMarquardt):
            step_size = getattr(getattr(sol.state, "search_state", None), "step_size", None)
            if step_size is not None:
                damping = 1 / step_size
        return _adapter_solution(
            problem, y0, args, sol.value, result, sol.stats["num_steps"], step, damping, self.max_steps
        )


def _import_jaxopt():
    try:
        with warnings.catch_warnings():
            # jaxopt announces on import that it is no longer maintained.
            warnings.simplefilter("ignore", DeprecationWarning)
            warnings.simplefilter("ignore", UserWarning)
            warnings.simplefilter("ignore", FutureWarning)
            import jaxopt
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(
            "JaxoptSolver needs the optional dependency jaxopt: install jaxanim[jaxopt] "
            "(pip install 'jaxanim[jaxopt]')"
        ) from exc
    return jaxopt


_JAXOPT_NAMES = ("LevenbergMarquardt", "GaussNewton")


class JaxoptSolver(_AbstractAdapter):
    """Adapter for ``jaxopt.LevenbergMarquardt`` / ``jaxopt.GaussNewton`` (jaxopt is unmaintained: an extra).

    jaxopt is imported lazily when the solver runs. A user ``jac`` reaches jaxopt through the
    same ``jax.custom_jvp`` residual as for optimistix. Convergence: Levenberg-Marquardt stops when
    ``|J^T r|_2 <= atol`` (jaxopt's ``'grad-l2-norm'`` criterion, Cholesky linear solves,
    materialised Jacobian); Gauss-Newton stops when its step ``|p|_2 <= rtol`` (jaxopt's only
    criterion; it solves the normal equations by CG and has no line search). ``result`` is
    ``successful`` when that criterion holds at the end, ``max_steps_reached`` otherwise and
    ``nonfinite`` if the value or cost is not finite (the value is then ``y0``).
    ``cost_history`` holds the initial and final costs only. Bounds are not supported.

    Attributes:
        name: ``"LevenbergMarquardt"`` or ``"GaussNewton"`` (static).
        rtol: step tolerance of Gauss-Newton (static float).
        atol: gradient tolerance of Levenberg-Marquardt (static float).
        max_steps: jaxopt's ``maxiter`` (static).
        damping_parameter: jaxopt's initial relative damping (LM only).
    """

    name: str = eqx.field(default="LevenbergMarquardt", static=True)
    rtol: float = eqx.field(default=1e-8, static=True)
    atol: float = eqx.field(default=1e-10, static=True)
    max_steps: int = eqx.field(default=100, static=True)
    damping_parameter: float = eqx.field(default=1e-3, static=True)

    def __check_init__(self):
        if self.name not in _JAXOPT_NAMES:
            raise ValueError(f"name: expected one of {_JAXOPT_NAMES}, got {self.name!r}")
        _check_int("max_steps", self.max_steps, 1)

    def _solve(self, problem, y0, args):
        jaxopt = _import_jaxopt()
        fn = problem.custom_jvp_residual()
        if self.name == "LevenbergMarquardt":
            solver = jaxopt.LevenbergMarquardt(
                residual_fun=fn,
                maxiter=self.max_steps,
                damping_parameter=self.damping_parameter,
                stop_criterion="grad-l2-norm",
                tol=self.atol,
                solver="cholesky",
                materialize_jac=True,
                implicit_diff=False,
                jit=True,
            )
        else:
            solver = jaxopt.GaussNewton(
                residual_fun=fn, maxiter=self.max_steps, tol=self.rtol, implicit_diff=False, jit=True
            )
        params, state = solver.run(y0, args)
        converged = state.error <= (self.atol if self.name == "LevenbergMarquardt" else self.rtol)
        result = RESULTS.where(converged, RESULTS.successful, RESULTS.max_steps_reached)
        damping = state.damping_factor if self.name == "LevenbergMarquardt" else jnp.zeros((), y0.dtype)
        return _adapter_solution(
            problem, y0, args, params, result, state.iter_num, state.delta, damping, self.max_steps
        )


# --------------------------------------------------------------------------------------------
# The public function.
# --------------------------------------------------------------------------------------------


def least_squares(
    fn: ResidualFn,
    solver: AbstractLeastSquaresSolver | OptimistixSolver | JaxoptSolver,
    y0: Float[ArrayLike, " n"],
    args: PyTree = None,
    *,
    jac: JacobianFn | bool | None = None,
    bounds: tuple[Float[ArrayLike, " n"], Float[ArrayLike, " n"]] | None = None,
    stop: Callable[[Array, Array, PyTree], Bool[ArrayLike, ""]] | None = None,
    throw: bool = False,
) -> Solution:
    r"""Minimise ``0.5 * |fn(y, args)|^2`` over ``y`` (optionally in a box) from ``y0``.

    Solves one problem; batch with ``jax.vmap`` over ``y0``, ``args``, ``bounds`` or the solver's
    array fields (``fn`` and ``jac`` are closed-over callables). With ``throw=False`` (the default)
    every element keeps its own ``result`` and one failing element never aborts a batch; check
    ``sol.result == RESULTS.successful``. The solve is compiled once per ``fn``/``jac`` object,
    shapes and static solver settings: pass the same function objects (not fresh lambdas) to reuse
    it; array data belong in ``args``.

    Args:
        fn: the residual function ``fn(y, args) -> r``, ``y`` of shape ``[n]``, ``r`` of shape ``[m]``
            (with ``jac=True``: ``fn(y, args) -> (r, J)``).
        solver: :class:`GaussNewton`, :class:`LevenbergMarquardt`, :class:`GradientDescent`,
            :class:`OptimistixSolver` or :class:`JaxoptSolver`.
        y0: ``[n]`` the initial guess (integer input is converted to the default float dtype;
            the solve runs in ``y0``'s dtype). It is clipped into the box first.
        args: any pytree passed through to ``fn`` and ``jac``.
        jac: optional ``jac(y, args) -> J``, ``[m, n]``, ``J_ij = d r_i / d y_j``. Default:
            ``jax.jacfwd`` of ``fn`` when ``m >= n``, ``jax.jacrev`` otherwise. The backends get it
            through a ``jax.custom_jvp`` on ``fn``. ``jac=True`` (scipy's convention): ``fn``
            returns the residual and its Jacobian together, and each linearisation calls it once.
        bounds: optional ``(lower, upper)``, each ``[n]`` (or a scalar), ``-inf``/``inf`` for free
            variables; own solvers only. Every iterate satisfies ``lower <= y <= upper`` exactly.
        stop: optional early-stop criterion ``stop(y, r, args) -> bool`` on an iterate and its
            residual (no extra evaluation of ``fn``), checked at ``y0`` and after every step; when
            it holds the solve ends there with ``RESULTS.successful`` (e.g. IK: every target within
            its tolerance, as in closed-loop IK). Own solvers only.
        throw: if true, raise (through ``RESULTS.error_if``, an ``equinox.EquinoxRuntimeError``
            whose message is the result's advice) unless the solve succeeds. Under ``vmap`` one
            failing element raises for the whole batch.

    Returns:
        A :class:`Solution` ``(value [n], result, stats)``; see :class:`~solvers.Solution` for the
        statistics. ``value`` is never NaN when ``y0`` is finite: on ``RESULTS.nonfinite`` it is
        the last finite iterate.

    Raises:
        ValueError: ``y0`` is not 1-D, ``bounds`` do not match ``y0`` or ``lower > upper``,
            ``fn`` does not return a 1-D array, ``jac`` does not return ``[m, n]``, or bounds were
            given (or ``stop``) to a backend adapter. Raised in Python, before anything is computed.
        equinox.EquinoxRuntimeError: ``throw=True`` and the solve failed.
    """
    if not isinstance(solver, (AbstractLeastSquaresSolver, _AbstractAdapter)):
        raise ValueError(
            "solver: expected GaussNewton, LevenbergMarquardt, GradientDescent, OptimistixSolver or JaxoptSolver, "
            f"got {type(solver).__name__}"
        )
    y0 = jnp.asarray(y0)
    if jnp.issubdtype(y0.dtype, jnp.complexfloating):
        raise ValueError(f"y0: expected a real array, got dtype {y0.dtype}")
    if not jnp.issubdtype(y0.dtype, jnp.floating):
        y0 = y0.astype(jnp.result_type(float))
    if y0.ndim != 1 or y0.shape[0] == 0:
        raise ValueError(f"y0: expected shape (n,) with n >= 1, got {_fmt(y0.shape)}")
    n = y0.shape[0]
    weights = getattr(solver, "weights", None)
    if weights is not None and weights.shape != (n,):
        raise ValueError(f"weights: expected shape (n,) = ({n},) like y0, got {_fmt(weights.shape)}")
    lower = upper = None
    if bounds is not None:
        if isinstance(solver, _AbstractAdapter):
            raise ValueError(
                f"bounds: not supported by {type(solver).__name__}; use GaussNewton, LevenbergMarquardt or "
                "GradientDescent"
            )
        if not (isinstance(bounds, (tuple, list)) and len(bounds) == 2):
            raise ValueError(
                f"bounds: expected a pair (lower, upper) of shape (n,) = ({n},), got {type(bounds).__name__}"
            )
        lower, upper = (jnp.asarray(b, y0.dtype) for b in bounds)
        for name, b in (("lower", lower), ("upper", upper)):
            if b.shape not in ((), (n,)):
                raise ValueError(f"bounds: expected {name} of shape (n,) = ({n},), got {_fmt(b.shape)}")
        lower = jnp.broadcast_to(lower, (n,))
        upper = jnp.broadcast_to(upper, (n,))
        if not isinstance(lower, jax.core.Tracer) and not isinstance(upper, jax.core.Tracer):
            if np.any(np.asarray(lower) > np.asarray(upper)):
                raise ValueError("bounds: expected lower <= upper for every variable")
    if stop is not None and isinstance(solver, _AbstractAdapter):
        raise ValueError(
            f"stop: not supported by {type(solver).__name__}; use GaussNewton, LevenbergMarquardt or GradientDescent"
        )
    return _least_squares(fn, jac, solver, y0, args, lower, upper, stop, throw)


@eqx.filter_jit
def _least_squares(fn, jac, solver, y0, args, lower, upper, stop, throw) -> Solution:
    n = y0.shape[0]
    out = eqx.filter_eval_shape(fn, y0, args)
    if jac is True:
        if not (isinstance(out, tuple) and len(out) == 2):
            raise ValueError(f"fn: with jac=True, expected fn(y, args) to return (r, J), got {type(out).__name__}")
        out, jout = out
    shape = getattr(out, "shape", None)
    if shape is None or len(shape) != 1:
        got = _fmt(shape) if shape is not None else type(out).__name__
        raise ValueError(f"fn: expected fn(y, args) to return residuals of shape (m,), got {got}")
    m = shape[0]
    if jac is not None:
        if jac is not True:
            jout = eqx.filter_eval_shape(jac, y0, args)
        jshape = getattr(jout, "shape", None)
        if jshape is None or tuple(jshape) != (m, n):
            got = _fmt(jshape) if jshape is not None else type(jout).__name__
            raise ValueError(f"jac: expected jac(y, args) to return shape (m, n) = ({m}, {n}), got {got}")
    problem = _Problem(fn=fn, jac=jac, lower=lower, upper=upper, m=m, stop=stop)
    if isinstance(solver, _AbstractAdapter):
        sol = solver._solve(problem, y0, args)
    else:
        sol = _iterate(solver, problem, problem.project(y0), args)
    if throw:
        sol = eqx.tree_at(
            lambda s: s.value, sol, sol.result.error_if(sol.value, sol.result != RESULTS.successful)
        )
    return sol
