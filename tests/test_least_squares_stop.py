"""solvers.least_squares, continued from test_least_squares.py (split to keep files under 700 lines): the
GradientDescent baseline (against numpy.linalg.lstsq, scipy and the box) and the early-stop criterion ``stop``
of the own solvers and of the optimistix / jaxopt adapters (against the backends run alone).
"""

import dataclasses
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
import scipy.optimize

import solvers
from solvers import RESULTS, LevenbergMarquardt, OptimistixSolver, _lanes, least_squares

from .helpers import assert_close
from .test_least_squares import (
    _A,
    _ATOL_SCIPY,
    _B,
    _DATA,
    _EXP_HI,
    _EXP_LO,
    _T,
    PROBLEMS,
    SOLVERS,
    _boxed,
    _linear_args,
    _solver_param,
    expfit,
    linear,
    rosenbrock,
    solve,
)

# ---------------------------------------------------------------------------------------------
# GradientDescent: the first-order (Jacobian-transpose) baseline.
# ---------------------------------------------------------------------------------------------

# GradientDescent stops on the pending gradient step, which underestimates the distance to the
# minimum by up to the condition number kappa of J^T J: with the tight tolerances (rtol 1e-12) the
# value is within ~kappa * 1e-12 * |y| of the minimum (kappa ~ 14 for the linear problem, ~ 7.5
# for the exponential fit), so 1e-9 leaves a wide margin; with the defaults (rtol 1e-8), 1e-6.
_ATOL_GD = 1e-9
_ATOL_GD_DEFAULT = 1e-6
_GD_TIGHT = dict(rtol=1e-12, atol=1e-14, max_steps=400)
_LINEAR_GD = eqx.filter_jit(
    lambda y0, args: least_squares(_linear_args, solvers.GradientDescent(**_GD_TIGHT), y0, args)
)
_LINEAR_GD_FIXED = eqx.filter_jit(
    lambda y0, args: least_squares(_linear_args, solvers.GradientDescent(**_GD_TIGHT, fixed_steps=True), y0, args)
)


def test_gradient_descent_linear_matches_lstsq_adaptive_and_fixed():
    """Nonzero-residual linear problem (kappa(A^T A) ~ 14): lstsq to 1e-8, both loop modes agree."""
    args = (jnp.asarray(_A), jnp.asarray(_B))
    ref = np.linalg.lstsq(_A, _B, rcond=None)[0]
    adaptive = _LINEAR_GD(jnp.zeros(3), args)
    fixed = _LINEAR_GD_FIXED(jnp.zeros(3), args)
    for mode, sol in (("adaptive", adaptive), ("fixed", fixed)):
        assert sol.result == RESULTS.successful, f"{mode}: {RESULTS[sol.result]}"
        assert_close(f"{mode}: x vs lstsq", sol.value, ref, atol=1e-8)
        assert_close(f"{mode}: cost", sol.stats["cost"], 0.5 * np.sum((_A @ ref - _B) ** 2), rtol=1e-14)
    k = int(adaptive.stats["num_steps"])
    assert 10 < k < _GD_TIGHT["max_steps"], "linear convergence: many steps where Gauss-Newton takes one"
    assert int(fixed.stats["num_steps"]) == k
    assert_close("fixed value", fixed.value, adaptive.value, atol=1e-14)
    assert_close("fixed cost_history", fixed.stats["cost_history"], adaptive.stats["cost_history"], atol=1e-14)
    hist = np.asarray(adaptive.stats["cost_history"])
    assert hist.shape == (_GD_TIGHT["max_steps"] + 1,)
    # the approximate Armijo test accepts steps whose cost change is rounding noise
    assert np.all(np.diff(hist) <= 8 * np.finfo(float).eps * hist[:-1]), "the cost never increases beyond rounding"
    assert set(adaptive.stats) == {"num_steps", "cost", "grad_norm", "step_norm", "damping", "cost_history",
                                  "stopped_early"}
    assert float(adaptive.stats["damping"]) == 0.0
    assert float(adaptive.stats["grad_norm"]) <= 1e-10


def test_gradient_descent_expfit_matches_scipy():
    """Nonlinear exponential fit with the analytic Jacobian: scipy's lm minimum to _ATOL_GD."""
    p = PROBLEMS["expfit"]  # y_star is scipy.optimize.least_squares(method="lm") at 1e-15 tolerances
    gd = solvers.GradientDescent(**_GD_TIGHT)
    sol = least_squares(p.fn, gd, jnp.asarray(p.y0), jac=p.jac)
    assert sol.result == RESULTS.successful, RESULTS[sol.result]
    assert_close("value vs scipy lm", sol.value, p.y_star, atol=_ATOL_GD)
    assert_close("cost vs scipy lm", sol.stats["cost"], p.cost_star, atol=1e-14)
    # rtol and atol are arrays: the default tolerances reuse the compiled solve
    loose = least_squares(p.fn, dataclasses.replace(gd, rtol=1e-8, atol=1e-10), jnp.asarray(p.y0), jac=p.jac)
    assert loose.result == RESULTS.successful, RESULTS[loose.result]
    assert_close("value vs scipy lm, default tolerances", loose.value, p.y_star, atol=_ATOL_GD_DEFAULT)
    assert int(loose.stats["num_steps"]) < int(sol.stats["num_steps"])


def test_gradient_descent_bounds_every_evaluation_in_the_box():
    """Bounded linear problem from outside the box: every point evaluated is inside; = lsq_linear."""
    lo, hi = np.full(3, -0.1), np.full(3, 0.1)
    seen = []

    def fn(y, args):
        jax.debug.callback(lambda v: seen.append(np.asarray(v)), y)
        return linear(y, args)

    y0 = np.array([5.0, -5.0, 0.0])  # outside the box: clipped first
    jac = lambda y, args: jnp.asarray(_A)  # noqa: E731
    sol = least_squares(fn, solvers.GradientDescent(**_GD_TIGHT), y0, jac=jac, bounds=(lo, hi))
    jax.block_until_ready(sol)
    ref = scipy.optimize.lsq_linear(_A, _B, bounds=(lo, hi), method="bvls", tol=1e-15)
    assert sol.result == RESULTS.successful, RESULTS[sol.result]
    assert_close("x vs lsq_linear", sol.value, ref.x, atol=_ATOL_GD)
    assert_close("cost vs lsq_linear", sol.stats["cost"], ref.cost, atol=1e-14)
    seen = np.stack(seen)
    assert len(seen) > int(sol.stats["num_steps"]), "one evaluation per trial point"
    assert np.all(seen >= lo) and np.all(seen <= hi), "every evaluated point lies in the box"


def test_gradient_descent_bounds_end_on_the_face():
    """Exponential fit with b <= -2 (the free minimum b = -1.51 is outside): scipy trf and the closed form."""
    fn = _boxed(expfit, _EXP_LO, _EXP_HI)
    y0 = (1.0, 0.0)
    sol = least_squares(fn, solvers.GradientDescent(**_GD_TIGHT), jnp.asarray(y0), bounds=(_EXP_LO, _EXP_HI))
    assert sol.result == RESULTS.successful, RESULTS[sol.result]
    value = np.asarray(sol.value)
    ref = scipy.optimize.least_squares(
        lambda y: np.asarray(expfit(jnp.asarray(y), None)), np.clip(y0, _EXP_LO, np.nextafter(_EXP_HI, -np.inf)),
        method="trf", bounds=(_EXP_LO, _EXP_HI), xtol=1e-15, ftol=1e-15, gtol=1e-15,
    )
    assert_close("x vs scipy trf", value, ref.x, atol=_ATOL_SCIPY)
    assert_close("cost vs scipy trf", sol.stats["cost"], ref.cost, atol=_ATOL_SCIPY)
    e = np.exp(-2.0 * _T)
    assert value[1] == -2.0
    assert_close("a on the face", value[0], (_DATA @ e) / (e @ e), atol=1e-12)


def test_gradient_descent_vmap_equals_loop():
    """A batch of linear problems through args; one (kappa ~ 8e6) runs out of steps, per element."""
    rng = np.random.default_rng(5)
    As = np.stack([_A, _A * np.array([1.0, 1.0, 1e-3]), rng.uniform(-1, 1, size=(8, 3)), _A])
    bs = np.stack([_B, _B, rng.normal(size=8), _A @ np.array([1.0, -2.0, 0.5])])  # the last: zero residual
    batched = jax.vmap(_LINEAR_GD, in_axes=(None, 0))(jnp.zeros(3), (jnp.asarray(As), jnp.asarray(bs)))
    expected = [RESULTS.successful, RESULTS.max_steps_reached, RESULTS.successful, RESULTS.successful]
    for i in range(len(As)):
        single = _LINEAR_GD(jnp.zeros(3), (jnp.asarray(As[i]), jnp.asarray(bs[i])))
        assert single.result == expected[i], f"result[{i}]: {RESULTS[single.result]}"
        assert bool((batched.result == single.result)[i]), f"batched result[{i}]"
        assert int(batched.stats["num_steps"][i]) == int(single.stats["num_steps"]), f"num_steps[{i}]"
        # batched and single matmuls round differently; over the 400 steps of the unconverged
        # ill-conditioned element that grows to ~1e-13
        assert_close(f"value[{i}]", batched.value[i], single.value, atol=1e-11)
        assert_close(f"cost_history[{i}]", batched.stats["cost_history"][i], single.stats["cost_history"], atol=1e-11)
        if expected[i] == RESULTS.successful:
            assert_close(f"value[{i}] vs lstsq", single.value, np.linalg.lstsq(As[i], bs[i], rcond=None)[0], atol=1e-8)
    assert int(batched.stats["num_steps"][1]) == _GD_TIGHT["max_steps"]


@pytest.mark.parametrize("fixed", [False, True], ids=["adaptive", "fixed"])
def test_stop_criterion_ends_the_solve_early(fixed):
    """``stop(y, r, args)`` ends the solve at the first iterate where it holds, as successful."""
    A = jnp.asarray(np.random.default_rng(3).normal(size=(6, 3)))
    b = jnp.asarray(np.random.default_rng(4).normal(size=6))

    def fn(y, args):
        return A @ jnp.sin(y) - b

    y0 = jnp.zeros(3)
    full = least_squares(fn, LevenbergMarquardt(fixed_steps=fixed, max_steps=50), y0)
    target = float(full.stats["cost"]) * 1.01 + 1e-9
    sol = least_squares(fn, LevenbergMarquardt(fixed_steps=fixed, max_steps=50), y0,
                        stop=lambda y, r, args: 0.5 * (r @ r) <= target)
    assert sol.result == RESULTS.successful
    k = int(sol.stats["num_steps"])
    assert k < int(full.stats["num_steps"])
    history = np.asarray(sol.stats["cost_history"])
    assert history[k] <= target and np.all(history[:k] > target)


# ---------------------------------------------------------------------------------------------
# The adapters on the project's driver: the backends' own iterates, and the user's stop.
# ---------------------------------------------------------------------------------------------

_ADAPTERS = ("optx-lm", "optx-gn", "optx-dogleg", "jaxopt-lm", "jaxopt-gn")


def _black_box(name: str, fn, y0, max_steps: tuple[int, ...]):
    """``[(value, num_steps)]`` of the backend's own entry point, configured as ``SOLVERS[name]``, one
    run per entry of ``max_steps``, all in one program (eager, jaxopt's ``run`` compiles its update
    and loop separately and its bookkeeping op by op: 37 programs for one run of jaxopt-lm)."""
    adapter = SOLVERS[name]()
    if name.startswith("optx"):
        def run(y0, steps):
            sol = optx.least_squares(fn, adapter.solver, y0, max_steps=steps, throw=False)
            return sol.value, sol.stats["num_steps"]
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import jaxopt

        def run(y0, steps):
            if adapter.name == "LevenbergMarquardt":
                backend = jaxopt.LevenbergMarquardt(
                    residual_fun=fn, maxiter=steps, damping_parameter=adapter.damping_parameter,
                    stop_criterion="grad-l2-norm", tol=adapter.atol, solver="cholesky", materialize_jac=True,
                    implicit_diff=False,
                )
            else:
                backend = jaxopt.GaussNewton(residual_fun=fn, maxiter=steps, tol=adapter.rtol, implicit_diff=False)
            params, state = backend.run(y0, None)
            return params, state.iter_num
    return jax.jit(lambda y0: [run(y0, steps) for steps in max_steps])(y0)


def _cost_at_most(y, r, target):
    """The early stop of the adapter tests: ``0.5 |r|^2 <= target`` (``target`` comes in ``args``)."""
    return 0.5 * (r @ r) <= target


def _rosenbrock_args(y, target):
    return rosenbrock(y, None)


@pytest.mark.parametrize("solver", [_solver_param(s) for s in _ADAPTERS])
def test_adapters_without_stop_equal_the_backends(solver):
    """Driven step by step through ``init``/``step``, an adapter takes the backend's own iterates:
    its value and step count are those of ``optx.least_squares`` / jaxopt's ``run``."""
    p = PROBLEMS["rosenbrock"]
    y0 = jnp.asarray(p.y0)
    sol = solve("rosenbrock", solver)
    [(value, num_steps)] = _black_box(solver, p.fn, y0, (256,))
    assert int(sol.stats["num_steps"]) == int(num_steps), solver
    assert_close(f"{solver}: value", sol.value, value, atol=1e-14)


@pytest.mark.parametrize("solver", [_solver_param(s) for s in _ADAPTERS])
def test_adapters_stop_at_the_first_iterate_meeting_stop(solver):
    """With ``stop``, an adapter ends at the first of the backend's iterates where it holds: the
    backend cut off after as many steps returns the same value and meets the stop, one step
    fewer does not (the cost of the accepted iterates never increases)."""
    p = PROBLEMS["rosenbrock"]
    y0 = jnp.asarray(p.y0)
    target = jnp.asarray(1e-3)
    sol = least_squares(_rosenbrock_args, SOLVERS[solver](), y0, target, stop=_cost_at_most)
    assert sol.result == RESULTS.successful, RESULTS[sol.result]
    k = int(sol.stats["num_steps"])
    assert 1 < k < int(solve("rosenbrock", solver).stats["num_steps"]), k
    assert float(sol.stats["cost"]) <= float(target)
    (at_k, _), (before, _) = _black_box(solver, p.fn, y0, (k, k - 1))
    assert_close(f"{solver}: value after {k} steps", sol.value, at_k, atol=1e-14)
    assert 0.5 * float(jnp.sum(p.fn(before, None) ** 2)) > float(target)
    # a stop that holds at y0 ends the solve there, before any step
    at_y0 = least_squares(_rosenbrock_args, SOLVERS[solver](), y0, jnp.asarray(1e3), stop=_cost_at_most)
    assert int(at_y0.stats["num_steps"]) == 0 and at_y0.result == RESULTS.successful
    assert_close("value at y0", at_y0.value, y0, atol=0)


@pytest.mark.parametrize("solver", [_solver_param("optx-lm"), _solver_param("jaxopt-lm")])
def test_adapters_stop_vmap_equals_loop_on_lanes(solver):
    """A batch larger than the lanes (the compacted loop): each element as solved alone."""
    n = _lanes.LANES + 16
    y0s = jnp.asarray(np.random.default_rng(7).uniform(-2.0, 2.0, size=(n, 2)))
    target = jnp.asarray(1e-4)
    one = jax.jit(lambda y0: least_squares(_rosenbrock_args, SOLVERS[solver](), y0, target, stop=_cost_at_most))
    batched = jax.jit(jax.vmap(one))(y0s)
    steps = np.asarray(batched.stats["num_steps"])
    assert np.all(np.asarray(batched.result == RESULTS.successful))
    assert np.all(np.asarray(batched.stats["cost"]) <= float(target))
    assert steps.min() < steps.max()  # the lanes have something to compact
    for i in range(n):
        single = one(y0s[i])
        assert int(single.stats["num_steps"]) == steps[i], f"num_steps[{i}]"
        assert_close(f"value[{i}]", batched.value[i], single.value, atol=1e-12)


def test_optimistix_best_so_far_returns_the_iterate_meeting_stop():
    """``optx.BestSoFarLeastSquares`` postprocesses to its best point so far; a solve ended by the
    user's stop returns the iterate that met it (and, without stop, what optimistix returns)."""
    p = PROBLEMS["rosenbrock"]
    y0 = jnp.asarray(p.y0)
    inner = optx.BestSoFarLeastSquares(optx.LevenbergMarquardt(rtol=1e-10, atol=1e-12))
    solver = OptimistixSolver(inner, max_steps=256)
    plain = least_squares(_rosenbrock_args, solver, y0, jnp.asarray(1e-3))
    ref = optx.least_squares(p.fn, inner, y0, max_steps=256, throw=False)
    assert int(plain.stats["num_steps"]) == int(ref.stats["num_steps"])
    assert_close("value", plain.value, ref.value, atol=1e-14)
    sol = least_squares(_rosenbrock_args, solver, y0, jnp.asarray(1e-3), stop=_cost_at_most)
    assert sol.result == RESULTS.successful and float(sol.stats["cost"]) <= 1e-3
    assert int(sol.stats["num_steps"]) < int(plain.stats["num_steps"])


def test_optimistix_adapter_keeps_implicit_derivatives():
    """The adapter runs under ``optx.ImplicitAdjoint`` as ``optx.least_squares`` does: the derivative
    of a linear least-squares solution with respect to the data is the pseudo-inverse."""
    solver = OptimistixSolver(optx.LevenbergMarquardt(rtol=1e-12, atol=1e-14), max_steps=64)
    A = jnp.asarray(_A)

    def value(b):
        return least_squares(lambda y, b_: A @ y - b_, solver, jnp.zeros(3), b).value

    assert_close("d value / d b", jax.jacrev(value)(jnp.asarray(_B)), np.linalg.pinv(_A), atol=1e-10)
