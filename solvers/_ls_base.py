"""What the own least-squares solvers share: the (damped) normal equations, the solver state, the
local model and its convergence test, the abstract solver, and the run on the iteration driver."""

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
from equinox import AbstractVar
from jaxtyping import Array, Bool, Float, PyTree

from ._checks import _all_finite
from ._iterate import iterate
from ._linalg import dot, matmul
from ._ls_problem import _Problem
from ._results import RESULTS, Solution


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
    non-finite when the Cholesky factorization fails. The trace (the sum of the curvatures
    ``(J^T J)_ii / D_ii``) comes from the matrix already formed, at no extra pass over ``J``.
    """
    dtype = J.dtype
    if free is not None:
        J = J * free.astype(dtype)[None, :]
        g = jnp.where(free, g, 0)
    if short_fat:
        m = J.shape[0]
        JD = J if diag is None else J / diag[None, :]  # J D^{-1}
        JDJ = matmul(JD, J.T)
        B = JDJ + lam * jnp.eye(m, dtype=dtype)
        u = jsl.cho_solve((jnp.linalg.cholesky(B), True), r)
        return -matmul(JD.T, u), jnp.trace(JDJ)
    JJ = matmul(J.T, J)
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
    minimizes the model ``g^T s + 0.5 |J s|^2`` along ``s = -alpha g`` (the Cauchy step). It does
    not depend on the scale of ``g``, so it is computed from ``g / |g|_inf``, which cannot overflow.
    The step is 0 when ``g = 0``, and non-finite only when ``J g`` underflows while ``g`` does not.
    """
    positive = g_norm > 0
    d = g / jnp.where(positive, g_norm, 1)
    Jd = matmul(J, d)
    JdJd = dot(Jd, Jd)
    alpha = dot(d, d) / jnp.where(positive, JdJd, 1)
    return jnp.where(positive, -alpha * g, 0)


def _cost_change(r: Float[Array, " m"], r_new: Float[Array, " m"]) -> Float[Array, ""]:
    """``F(y_new) - F(y) = 0.5 (r_new - r) . (r_new + r)``, without the cancellation of ``F_new - F``."""
    return 0.5 * dot(r_new - r, r_new + r)


class _State(eqx.Module):
    """Solver state at the iterate ``y`` (shared by all the own solvers)."""

    # linearization at y
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
    # the placeholder before the first linearization (``init_placeholder``): the coming step is
    # the initial linearization
    placeholder: Bool[Array, ""]


def _placeholder(problem: _Problem, y: Float[Array, " n"], args: PyTree, **fields) -> _State:
    """The state at ``y`` before its linearization: zero residual, Jacobian, step and damping (or
    ``fields``), a trial point ``y`` itself and ``inf`` cost and gradient norm (what is reported if
    ``y`` is not finite and the loop never starts)."""
    dtype = y.dtype
    r, J = jax.eval_shape(problem.linearize, y, args)
    n = J.shape[1]
    zero, no = jnp.zeros((), dtype), jnp.array(False)
    state = dict(
        r=jnp.zeros(r.shape, dtype), J=jnp.zeros(J.shape, dtype), g=jnp.zeros(n, dtype), cost=jnp.asarray(jnp.inf, dtype),
        g_norm=jnp.asarray(jnp.inf, dtype), p=jnp.zeros(n, dtype), y_trial=y, pred=zero, step_ok=jnp.array(True),
        lam=zero, nu=zero, lam_scale=zero, diag=None, converged=no, stalled=no, stall_nonfinite=no, step_norm=zero,
    )
    return _State(**{**state, **fields}, placeholder=jnp.array(True))


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
    g = matmul(J.T, r)
    cost = 0.5 * dot(r, r)
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
        Js = matmul(J, s)
        pred = -dot(g, s) - 0.5 * dot(Js, Js)
    else:  # (J^T J + lam D) p = -g gives |J p|^2 = -g.p - lam p.D.p: no pass over J (for the
        # Cauchy step p = -alpha g, lam = 0: |J p|^2 = alpha^2 |J g|^2 = alpha |g|^2 = -g.p as well)
        pDp = dot(p, p) if diag is None else dot(p * diag, p)
        pred = 0.5 * (lam * pDp - dot(g, p))
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


class AbstractLeastSquaresSolver(eqx.Module):
    """A least-squares method driven by :func:`least_squares` through
    ``init_placeholder/step/terminate/postprocess``.

    Subclasses are final. They provide the fields ``rtol``, ``atol`` (arrays), ``max_steps``
    (static int) and ``fixed_steps`` (static bool); the driver owns the loop, ``max_steps``, the
    non-finite check and the statistics.
    """

    rtol: AbstractVar[Float[Array, ""]]
    atol: AbstractVar[Float[Array, ""]]
    max_steps: AbstractVar[int]
    fixed_steps: AbstractVar[bool]

    @abc.abstractmethod
    def init_placeholder(self, problem: _Problem, y: Float[Array, " n"], args: PyTree) -> _State:
        """The state at ``y`` (already inside the box) before its linearization: the first ``step``
        from it is the initial linearization, so the compiled program holds the residual and its
        Jacobian once, in the loop."""

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


# --------------------------------------------------------------------------------------------
# The run: a solver on the iteration driver.
# --------------------------------------------------------------------------------------------


class _Loop(eqx.Module):
    """The loop state of a least-squares solve: the iterate, the solver's state at it, and its status."""

    y: Float[Array, " n"]
    state: _State
    stop: Bool[Array, ""]  # the solver's (or the user's) test says the solve ends here
    result: RESULTS  # how it ends, when `stop`
    early: Bool[Array, ""]  # the user's test holds here and the solver's own does not


def _run(solver: AbstractLeastSquaresSolver, problem: _Problem, y0: Float[Array, " n"], args: PyTree) -> Solution:
    """Run ``solver`` from ``y0`` (inside the box) on :func:`solvers._iterate.iterate`.

    The solvers start from :meth:`~AbstractLeastSquaresSolver.init_placeholder`: the loop's
    first iteration is the initial linearization (not counted in ``num_steps``, and not recorded in
    ``cost_history``), so the residual and its Jacobian appear once in the compiled program (the
    IK solve on the CMU skeleton compiles in 2.5 s instead of 3.4 s).

    The non-finite guard looks at the iterate, its residual and Jacobian. At ``y0`` it may stop the
    solve (``RESULTS.nonfinite``); afterwards it never does, because the solvers' steps only
    accept trial points whose residual and Jacobian are finite (a non-finite trial is a rejected
    step), so ``value`` is always the last finite iterate.
    """

    def loop(y, state) -> _Loop:
        stop, result = solver.terminate(problem, y, args, state)
        early = jnp.array(False)
        if problem.stop is not None:  # the user's criterion: good enough, stop here as converged
            user = jnp.asarray(problem.stop(y, state.r, args), bool)
            early = user & ~(stop & (result == RESULTS.successful))
            stop, result = stop | user, RESULTS.where(user, RESULTS.successful, result)
        return _Loop(y=y, state=state, stop=stop, result=result, early=early)

    def step(c: _Loop) -> _Loop:
        return loop(*solver.step(problem, c.y, args, c.state))

    # the loop's first iteration is the initial linearization: one step more, not counted
    init = _Loop(y=y0, state=solver.init_placeholder(problem, y0, args), stop=jnp.array(False),
                 result=RESULTS.successful, early=jnp.array(False))
    it = iterate(
        step,
        init,
        done=lambda c: c.stop,
        max_steps=solver.max_steps + 1,
        fixed_steps=solver.fixed_steps,
        finite=lambda c: _all_finite(c.y, c.state.r, c.state.J),
        record=lambda c: c.state.cost,
    )
    c = it.state
    result = RESULTS.where(
        it.nonfinite, RESULTS.nonfinite, RESULTS.where(it.done, c.result, RESULTS.max_steps_reached)
    )
    value, stats = solver.postprocess(problem, c.y, args, c.state, result)
    history = it.history[1:]
    history = jnp.where(jnp.isfinite(history), history, jnp.inf)
    stats = dict(stats, num_steps=jnp.maximum(it.num_steps - 1, 0), cost_history=history,
                 stopped_early=c.early & (result == RESULTS.successful))
    return Solution(value=value, result=result, stats=stats)
