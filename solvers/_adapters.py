"""Backend adapters: optimistix and jaxopt least-squares solvers behind :func:`solvers.least_squares`."""

import abc
import warnings
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from equinox import AbstractVar
from jaxtyping import Array, Bool, Float, Int, PyTree

from ._checks import _all_finite, _check_int
from ._iterate import iterate
from ._linalg import dot, matmul
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
    stopped_early=False,
) -> Solution:
    """Common stats for the adapters; a non-finite value is replaced by ``y0``. ``stopped_early``: the user's
    ``stop`` ended the solve before the solver's own criterion held."""
    dtype = y0.dtype
    value = jnp.asarray(value).astype(dtype)
    ok = _all_finite(value)
    value = jnp.where(ok, value, y0)
    r, J = problem.linearize(value, args)
    r0 = problem.residual(y0, args)
    cost = 0.5 * dot(r, r)
    g = matmul(J.T, r)
    ok = ok & jnp.isfinite(cost) & _all_finite(g)
    result = RESULTS.where(ok, result, RESULTS.nonfinite)

    def finite_or_inf(x):
        return jnp.where(jnp.isfinite(x), x, jnp.inf)

    cost = finite_or_inf(cost)
    history = jnp.full((max_steps + 1,), cost).at[0].set(finite_or_inf(0.5 * dot(r0, r0)))
    stats = dict(
        num_steps=jnp.asarray(num_steps),
        cost=cost,
        grad_norm=finite_or_inf(jnp.max(jnp.abs(g))),
        step_norm=finite_or_inf(jnp.max(jnp.abs(step.astype(dtype)))),
        damping=finite_or_inf(jnp.asarray(damping, dtype)),
        cost_history=history,
        stopped_early=jnp.asarray(stopped_early, bool),
    )
    return Solution(value=value, result=result, stats=stats)


class _OptxLoop(eqx.Module):
    """The driver's state for an optimistix solve: optimistix's ``_iterate`` carry, plus the user's stop."""

    y: Float[Array, " n"]
    state: PyTree  # the array part of the optimistix solver state (its static part is closed over)
    terminate: Bool[Array, ""]  # optimistix's terminate
    result: Any  # optimistix's RESULTS
    user: Bool[Array, ""]  # the user's stop holds at y


def _scalar_as(dtype):
    """Cast a floating scalar array to ``dtype`` (other leaves unchanged)."""

    def cast(a):
        return a.astype(dtype) if a.ndim == 0 and jnp.issubdtype(a.dtype, jnp.floating) else a

    return cast


def _optx_primal(inputs):
    """optimistix's ``_iterate`` (``optimistix/_iterate.py``, 0.1.0) on :func:`solvers._iterate.iterate`.

    The same ``init``/``step``/``terminate``/``postprocess`` calls in the same order, so without
    ``stop`` the iterates are optimistix's; ``stop(y, r, args)`` (closure-converted) ends the solve
    too. Module-level and free of closures, as ``optx.ImplicitAdjoint`` requires.
    """
    import optimistix as optx
    from optimistix._misc import tree_allfinite
    from optimistix._solver.gauss_newton import _GaussNewtonState

    fn, solver, y0, args, options, max_steps, f_struct, aux_struct, tags, stop, _while_loop = inputs
    f_struct, aux_struct = f_struct.value, aux_struct.value
    state0 = solver.init(fn, y0, args, options, f_struct, aux_struct, tags)
    dynamic0, static = eqx.partition(state0, eqx.is_array)
    # optimistix 0.1.0 starts its scalars (the trust region's step size, Dogleg's norms) as `jnp.array(0.0 or
    # 1.0)`, float64 under x64, which then meet a float32 problem's residuals: they take y0's dtype here (the
    # steps then keep it)
    dynamic0 = jax.tree.map(_scalar_as(y0.dtype), dynamic0)

    def terminate(y, state):  # optimistix checks the iterate the step started from
        t, result = solver.terminate(fn, y, args, options, state, tags)
        return t, optx.RESULTS.where(tree_allfinite(y), result, optx.RESULTS.nonfinite)

    def user_stop(y, state):
        if stop is None:
            return jnp.array(False)
        if isinstance(state, _GaussNewtonState):  # Gauss-Newton, LM, Dogleg: r(y) is in the state
            r = state.f_info.residual
        else:
            r, _ = fn(y, args)
        return jnp.asarray(stop(y, r, args), bool)

    t0, result0 = terminate(y0, state0)
    # optimistix's first step only evaluates at y0, so r(y0) is not in the initial state: one evaluation
    user0 = jnp.array(False) if stop is None else jnp.asarray(stop(y0, fn(y0, args)[0], args), bool)
    init = _OptxLoop(y=y0, state=dynamic0, terminate=t0, result=result0, user=user0)

    def step(c: _OptxLoop) -> _OptxLoop:
        state = eqx.combine(static, c.state)
        y, new_state, _aux = solver.step(fn, c.y, args, options, state, tags)
        t, result = terminate(c.y, new_state)
        return _OptxLoop(
            y=y, state=eqx.filter(new_state, eqx.is_array), terminate=t, result=result, user=user_stop(y, new_state)
        )

    def done(c: _OptxLoop):
        return c.terminate | (c.result != optx.RESULTS.successful) | c.user

    # no non-finite guard: optimistix reports a non-finite iterate itself (`terminate` above)
    it = iterate(step, init, done=done, max_steps=max_steps, fixed_steps=False, finite=None)
    c = it.state
    state = eqx.combine(static, c.state)
    result = optx.RESULTS.where(
        (c.result == optx.RESULTS.successful) & jnp.invert(c.terminate), optx.RESULTS.nonlinear_max_steps_reached,
        c.result,
    )
    y, _, _ = solver.postprocess(fn, c.y, None, args, options, state, tags, result)
    # the iterate that met the user's stop, even where postprocess returns another (optx.BestSoFarLeastSquares)
    y = jnp.where(c.user, c.y, y)
    y_eval = getattr(state, "y_eval", None)
    step = jnp.zeros_like(y) if y_eval is None else y_eval - y
    damping = jnp.zeros((), y.dtype)
    if isinstance(solver, optx.LevenbergMarquardt):
        step_size = getattr(getattr(state, "search_state", None), "step_size", None)
        if step_size is not None:
            damping = jnp.asarray(1 / step_size, y.dtype)
    return y, (it.num_steps, result, c.user, step, damping)


class OptimistixSolver(_AbstractAdapter):
    """Adapter for an optimistix least-squares solver (``optx.LevenbergMarquardt``, ``GaussNewton``, ``Dogleg``).

    ``least_squares(fn, OptimistixSolver(optx.LevenbergMarquardt(rtol, atol)), y0, jac=jac)`` runs
    the optimistix solver's own ``init`` / ``step`` / ``terminate`` / ``postprocess`` (in the order
    of ``optx.least_squares``'s loop, under ``optx.ImplicitAdjoint``, so derivatives of the solution
    are implicit ones as there) on the project's driver :func:`solvers._iterate.iterate`, and returns
    the same :class:`Solution` as the own solvers (optimistix's state is never returned: it cannot
    be batched). Without ``stop`` the iterates, ``value`` and ``num_steps`` are those of
    ``optx.least_squares(..., throw=False)``; under ``jax.vmap`` on the CPU a batch runs on
    compacted lanes (it costs its mean step count, not its maximum). A user ``stop(y, r, args)``
    is checked at ``y0`` (one extra evaluation of ``fn``: optimistix's initial state holds no
    residual) and after every step on the accepted iterate and its residual, which
    ``GaussNewton``, ``LevenbergMarquardt`` and ``Dogleg`` keep in their state (other optimistix
    solvers: one evaluation of ``fn`` per step); when it holds the solve ends there as
    ``successful``. optimistix counts its first step, which only evaluates ``fn`` at ``y0``, in
    ``num_steps``. A user ``jac`` reaches optimistix through a ``jax.custom_jvp`` on the residual,
    so the analytic Jacobian is used, not autodiff of ``fn``. optimistix results map to
    :class:`RESULTS` (``nonlinear_max_steps_reached`` -> ``max_steps_reached``, non-finite ->
    ``nonfinite``, any linear-solver failure -> ``singular``). Statistics: ``step_norm`` is the step
    optimistix would try next, ``damping`` is ``1 / trust-region step size`` for
    ``optx.LevenbergMarquardt`` (0 otherwise), and ``cost_history`` holds the initial cost then the
    final cost (intermediate costs are not reported by optimistix). Bounds are not supported.
    float32 works with x64 on or off: optimistix 0.1.0 starts its trust-region scalars as
    ``jnp.array(1.0)``, float64 under x64, which ``optx.least_squares`` itself then cannot combine
    with a float32 problem ("Vector and operator structures do not match"); the adapter gives the
    solver state's floating scalars ``y0``'s dtype (the steps keep it). The adapter uses optimistix 0.1.0's internals
    (``_iterate``'s loop, ``NoneAux``/``OutAsArray``, the Gauss-Newton state), so it follows that
    version.

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
        import equinox.internal as eqxi
        import optimistix as optx
        from optimistix._least_squares import _rewrite_fn
        from optimistix._misc import NoneAux, OutAsArray

        # what optx.least_squares does before it iterates: the same wrapped, closure-converted fn
        fn = eqx.filter_closure_convert(OutAsArray(NoneAux(problem.custom_jvp_residual())), y0, args)
        f_struct, aux_struct = fn.out_struct
        stop = None
        if problem.stop is not None:
            stop = eqx.filter_closure_convert(problem.stop, y0, jnp.zeros(f_struct.shape, f_struct.dtype), args)
        inputs = (
            fn, self.solver, y0, args, dict(self.options or ()), self.max_steps,
            eqxi.Static(f_struct), eqxi.Static(aux_struct), frozenset(), stop,
        )
        value, (num_steps, r, user, step, damping) = optx.ImplicitAdjoint().apply(
            _optx_primal, _rewrite_fn, inputs, frozenset()
        )
        result = RESULTS.where(
            user | (r == optx.RESULTS.successful),
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
        early = user & (r == optx.RESULTS.nonlinear_max_steps_reached)  # optimistix's own test did not hold
        return _adapter_solution(problem, y0, args, value, result, num_steps, step, damping, self.max_steps, early)


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


class _JaxoptLoop(eqx.Module):
    """The driver's state for a jaxopt solve: jaxopt's ``(params, state)`` and the user's stop."""

    y: Float[Array, " n"]
    state: Any  # jaxopt's state (a NamedTuple of arrays)
    user: Bool[Array, ""]  # the user's stop holds at y


class JaxoptSolver(_AbstractAdapter):
    """Adapter for ``jaxopt.LevenbergMarquardt`` / ``jaxopt.GaussNewton`` (jaxopt is unmaintained: an extra).

    jaxopt is imported lazily when the solver runs. A user ``jac`` reaches jaxopt through the
    same ``jax.custom_jvp`` residual as for optimistix. The solver's own ``init_state`` / ``update``
    run on the project's driver :func:`solvers._iterate.iterate` as jaxopt's ``run`` does (one
    update, then updates while ``state.error > tol``, at most ``max_steps``), so without ``stop`` the
    iterates and ``num_steps`` are jaxopt's; under ``jax.vmap`` on the CPU a batch runs on
    compacted lanes. Convergence: Levenberg-Marquardt stops when ``|J^T r|_2 <= atol`` (jaxopt's
    ``'grad-l2-norm'`` criterion, Cholesky linear solves, materialized Jacobian); Gauss-Newton
    stops when its step ``|p|_2 <= rtol`` (jaxopt's only criterion; it solves the normal equations
    by CG and has no line search). A user ``stop(y, r, args)`` is checked at ``y0`` and after every
    update; Levenberg-Marquardt's state holds the residual at its iterate, Gauss-Newton's the one
    at the previous iterate, so with a ``stop`` Gauss-Newton evaluates ``fn`` once more per
    update. ``result`` is ``successful`` when jaxopt's criterion or the user's stop holds at the
    end, ``max_steps_reached`` otherwise and ``nonfinite`` if the value or cost is not finite (the
    value is then ``y0``). ``cost_history`` holds the initial and final costs only. Bounds are not
    supported. jaxopt's products, which state no precision of their own, are traced at
    ``HIGHEST`` (under ``jax.default_matmul_precision("highest")``; so are the residual's).

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
        # jaxopt 0.8.5's Levenberg-Marquardt states no precision on its products (J^T J, J^T r, the
        # gain ratio): traced under this context they are HIGHEST, as the library's own (it also
        # applies to a residual's products that state none)
        with jax.default_matmul_precision("highest"):
            return self._solve_highest(problem, y0, args)

    def _solve_highest(self, problem, y0, args):
        jaxopt = _import_jaxopt()
        fn = problem.custom_jvp_residual()
        lm = self.name == "LevenbergMarquardt"
        if lm:
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
        tol = self.atol if lm else self.rtol
        stop = problem.stop

        def user_stop(y, state):
            if stop is None:
                return jnp.array(False)
            # LM's state holds r at its (accepted) iterate; GN's holds r at the previous iterate
            r = state.residual if lm else problem.residual(y, args)
            return jnp.asarray(stop(y, r, args), bool)

        # jaxopt's `run`: one update unconditionally, then updates while `state.error > tol`,
        # at most `maxiter` in all
        state0 = solver.init_state(y0, args)
        first = solver.update(y0, state0, args)
        init = _JaxoptLoop(y=first.params, state=first.state, user=user_stop(first.params, first.state))
        if stop is not None:  # the user's stop also looks at y0, whose residual is in the initial state
            at_y0 = jnp.asarray(stop(y0, state0.residual, args), bool)
            state0 = jax.tree.map(lambda a, b: jnp.asarray(a, jnp.result_type(b)), state0, first.state)
            init = jax.tree.map(lambda a, b: jnp.where(at_y0, a, b), _JaxoptLoop(y=y0, state=state0, user=at_y0), init)

        def step(c: _JaxoptLoop) -> _JaxoptLoop:
            params, state = solver.update(c.y, c.state, args)
            return _JaxoptLoop(y=params, state=state, user=user_stop(params, state))

        it = iterate(
            step, init, done=lambda c: jnp.invert(c.state.error > tol) | c.user, max_steps=self.max_steps - 1,
            fixed_steps=False, finite=None,  # no guard: as jaxopt (the value is checked afterwards)
        )
        params, state = it.state.y, it.state.state
        converged = (state.error <= tol) | it.state.user
        result = RESULTS.where(converged, RESULTS.successful, RESULTS.max_steps_reached)
        damping = state.damping_factor if lm else jnp.zeros((), y0.dtype)
        return _adapter_solution(
            problem, y0, args, params, result, state.iter_num, state.delta, damping, self.max_steps,
            it.state.user & ~(state.error <= tol),
        )
