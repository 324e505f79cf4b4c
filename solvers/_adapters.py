"""Backend adapters: optimistix and jaxopt least-squares solvers behind :func:`solvers.least_squares`."""

import abc
import warnings
from typing import Any

import equinox as eqx
import jax.numpy as jnp
from equinox import AbstractVar
from jaxtyping import Array, Float, Int, PyTree

from ._checks import _all_finite, _check_int
from ._ls_problem import _Problem
from ._results import RESULTS, Solution


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
    r, J = problem.linearize(value, args)
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
    materialized Jacobian); Gauss-Newton stops when its step ``|p|_2 <= rtol`` (jaxopt's only
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

