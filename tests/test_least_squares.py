"""solvers.least_squares: own Gauss-Newton / Levenberg-Marquardt and the optimistix / jaxopt adapters.

References: known minima (Rosenbrock, Beale, a linear problem via ``numpy.linalg.lstsq``),
``scipy.optimize.least_squares`` (``method='lm'`` and ``'trf'``, with bounds), ``lsq_linear``
(bounded linear problem) and closed forms (the exponential fit on a face of the box).
"""

import dataclasses
import functools
from collections.abc import Callable

import equinox as eqx
import hypothesis
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
import scipy.optimize

import solvers
from solvers import RESULTS, GaussNewton, JaxoptSolver, LevenbergMarquardt, OptimistixSolver, least_squares
from solvers._ls_base import _solve_normal
from solvers._ls_problem import _Problem

from .helpers import assert_close, count_traces

_ATOL_MIN = 1e-6  # distance to a known minimum, any backend (default-ish tolerances)
_ATOL_SCIPY = 1e-8  # own solvers against scipy, float64, tight tolerances
_TIGHT = dict(rtol=1e-12, atol=1e-14)

try:  # jaxopt is an optional extra
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import jaxopt  # noqa: F401
    HAVE_JAXOPT = True
except ImportError:  # pragma: no cover
    HAVE_JAXOPT = False
needs_jaxopt = pytest.mark.skipif(not HAVE_JAXOPT, reason="jaxopt not installed (pip install 'jaxanim[jaxopt]')")


# ---------------------------------------------------------------------------------------------
# Problem catalogue: residuals, analytic Jacobians, starts and known minima.
# ---------------------------------------------------------------------------------------------


def rosenbrock(y, args):
    return jnp.stack([10 * (y[1] - y[0] ** 2), 1 - y[0]])


def rosenbrock_jac(y, args):
    return jnp.stack([jnp.stack([-20 * y[0], jnp.ones_like(y[0]) * 10]), jnp.stack([-jnp.ones_like(y[0]), jnp.zeros_like(y[0])])])


_BEALE_C = np.array([1.5, 2.25, 2.625])


def beale(y, args):
    i = jnp.arange(1, 4)
    return jnp.asarray(_BEALE_C, y.dtype) - y[0] * (1 - y[1] ** i)


_T = np.linspace(0.0, 1.0, 20)
_DATA = 2.0 * np.exp(-1.5 * _T) + 0.01 * np.random.default_rng(0).normal(size=_T.shape)


def expfit(y, args):
    t = jnp.asarray(_T, y.dtype)
    return y[0] * jnp.exp(y[1] * t) - jnp.asarray(_DATA, y.dtype)


def expfit_jac(y, args):
    t = jnp.asarray(_T, y.dtype)
    e = jnp.exp(y[1] * t)
    return jnp.stack([e, y[0] * t * e], axis=1)


_A = np.random.default_rng(1).normal(size=(8, 3))
_B = np.random.default_rng(2).normal(size=8)


def linear(y, args):
    return jnp.asarray(_A, y.dtype) @ y - jnp.asarray(_B, y.dtype)


def _expfit_reference() -> np.ndarray:
    ref = scipy.optimize.least_squares(
        lambda y: y[0] * np.exp(y[1] * _T) - _DATA, [1.0, 0.0], method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15
    )
    return ref.x


@dataclasses.dataclass(frozen=True)
class Problem:
    name: str
    fn: Callable
    y0: tuple[float, ...]
    y_star: tuple[float, ...]
    jac: Callable | None = None

    def np_fn(self, y):
        return np.asarray(self.fn(jnp.asarray(y), None))

    @property
    def cost_star(self) -> float:
        r = self.np_fn(np.asarray(self.y_star))
        return 0.5 * float(r @ r)


PROBLEMS = {
    "rosenbrock": Problem("rosenbrock", rosenbrock, (-1.2, 1.0), (1.0, 1.0), rosenbrock_jac),
    "beale": Problem("beale", beale, (1.0, 0.0), (3.0, 0.5)),
    "expfit": Problem("expfit", expfit, (0.5, 1.0), tuple(_expfit_reference()), expfit_jac),
    "linear": Problem("linear", linear, (0.0, 0.0, 0.0), tuple(np.linalg.lstsq(_A, _B, rcond=None)[0])),
}

SOLVERS = {
    "gn": lambda: GaussNewton(**_TIGHT),
    "lm": lambda: LevenbergMarquardt(**_TIGHT),
    "lm-scaled": lambda: LevenbergMarquardt(scaling=True, **_TIGHT),
    "optx-lm": lambda: OptimistixSolver(optx.LevenbergMarquardt(rtol=1e-10, atol=1e-12), max_steps=256),
    "optx-gn": lambda: OptimistixSolver(optx.GaussNewton(rtol=1e-10, atol=1e-12), max_steps=256),
    "optx-dogleg": lambda: OptimistixSolver(optx.Dogleg(rtol=1e-10, atol=1e-12), max_steps=256),
    "jaxopt-lm": lambda: JaxoptSolver("LevenbergMarquardt", atol=1e-10, max_steps=256),
    "jaxopt-gn": lambda: JaxoptSolver("GaussNewton", rtol=1e-12, max_steps=256),
}
OWN = ("gn", "lm", "lm-scaled")


@functools.lru_cache(maxsize=None)
def solve(problem: str, solver: str, dtype=jnp.float64) -> solvers.Solution:
    """Solve a catalogue problem once per session (compilation is the expensive part)."""
    p = PROBLEMS[problem]
    return least_squares(p.fn, SOLVERS[solver](), jnp.asarray(p.y0, dtype))


def _solver_param(name):
    marks = [needs_jaxopt] if name.startswith("jaxopt") else []
    return pytest.param(name, marks=marks, id=name)


@pytest.mark.parametrize("solver", [_solver_param(s) for s in SOLVERS])
@pytest.mark.parametrize("problem", list(PROBLEMS))
def test_catalogue_reaches_known_minimum(problem, solver):
    p = PROBLEMS[problem]
    sol = solve(problem, solver)
    assert sol.result == RESULTS.successful, RESULTS[sol.result]
    assert_close(f"{problem}/{solver}: value", sol.value, p.y_star, atol=_ATOL_MIN)
    assert_close(f"{problem}/{solver}: cost", sol.stats["cost"], p.cost_star, atol=1e-10)
    assert sol.stats["num_steps"] <= 256


@pytest.mark.parametrize("solver", OWN)
@pytest.mark.parametrize("problem", list(PROBLEMS))
def test_own_solvers_match_scipy(problem, solver):
    p = PROBLEMS[problem]
    ref = scipy.optimize.least_squares(p.np_fn, np.asarray(p.y0), method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    sol = solve(problem, solver)
    assert_close(f"{problem}/{solver} vs scipy lm: x", sol.value, ref.x, atol=_ATOL_SCIPY)
    assert_close(f"{problem}/{solver} vs scipy lm: cost", sol.stats["cost"], ref.cost, atol=_ATOL_SCIPY)


def test_second_eager_call_does_not_retrace():
    # Same fn, shapes and static solver settings, a new y0 and a new solver instance (its
    # tolerances are arrays): the compiled solve of the catalogue test is reused.
    p = PROBLEMS["rosenbrock"]
    first = solve("rosenbrock", "lm")
    y0 = jnp.asarray([-1.0, 1.5])
    solver = SOLVERS["lm"]()
    with count_traces() as traces:
        sol = least_squares(p.fn, solver, y0)
    assert traces[0] == 0, f"{traces[0]} traces on the second call"
    assert sol.result == RESULTS.successful
    assert_close("value", sol.value, first.value, atol=_ATOL_SCIPY)


def test_gauss_newton_solves_a_linear_problem_in_one_step():
    sol = solve("linear", "gn")
    assert int(sol.stats["num_steps"]) == 1
    assert_close("value", sol.value, PROBLEMS["linear"].y_star, atol=1e-12)


def test_stats_and_cost_history():
    sol = solve("rosenbrock", "lm")
    p = PROBLEMS["rosenbrock"]
    hist = np.asarray(sol.stats["cost_history"])
    k = int(sol.stats["num_steps"])
    assert hist.shape == (SOLVERS["lm"]().max_steps + 1,)
    assert_close("cost_history[0]", hist[0], 0.5 * np.sum(p.np_fn(p.y0) ** 2), rtol=1e-14)
    assert np.all(np.diff(hist) <= 0), "the cost never increases"
    assert_close("cost_history padding", hist[k:], sol.stats["cost"], rtol=0)
    r = p.np_fn(np.asarray(sol.value))
    J = np.asarray(rosenbrock_jac(sol.value, None))
    assert_close("grad_norm", sol.stats["grad_norm"], np.max(np.abs(J.T @ r)), rtol=1e-10, atol=1e-300)
    assert float(sol.stats["damping"]) > 0
    assert float(solve("rosenbrock", "gn").stats["damping"]) == 0.0
    for key in ("num_steps", "cost", "grad_norm", "step_norm", "damping", "cost_history"):
        assert np.all(np.isfinite(np.asarray(sol.stats[key]))), key


# ---------------------------------------------------------------------------------------------
# Fixed-iteration mode.
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("problem", "solver"), [("rosenbrock", "gn"), ("expfit", "lm")])
def test_fixed_steps_equals_adaptive(problem, solver):
    """A finished problem is frozen inside the scan, so the fixed mode reproduces the adaptive one."""
    p = PROBLEMS[problem]
    adaptive = solve(problem, solver)
    fixed_solver = dataclasses.replace(SOLVERS[solver](), fixed_steps=True, max_steps=64)
    fixed = least_squares(p.fn, fixed_solver, jnp.asarray(p.y0))
    assert fixed.result == RESULTS.successful
    assert int(fixed.stats["num_steps"]) == int(adaptive.stats["num_steps"])
    assert_close("value", fixed.value, adaptive.value, atol=1e-14)
    assert_close("cost", fixed.stats["cost"], adaptive.stats["cost"], atol=1e-14)
    assert fixed.stats["cost_history"].shape == (65,)


# ---------------------------------------------------------------------------------------------
# Bounds.
# ---------------------------------------------------------------------------------------------


def _boxed(fn, lower, upper):
    """``fn`` that returns NaN outside the box: a successful solve never evaluated outside it."""

    def boxed(y, args):
        inside = jnp.all((y >= jnp.asarray(lower)) & (y <= jnp.asarray(upper)))
        return jnp.where(inside, fn(y, args), jnp.nan)

    return boxed


_EXP_LO, _EXP_HI = np.array([-np.inf, -np.inf]), np.array([np.inf, -2.0])
_ROS_LO, _ROS_HI = np.array([-2.0, -2.0]), np.array([0.5, 2.0])


@pytest.mark.parametrize(
    ("case", "solver"),
    [
        # unconstrained minimum b = -1.51 is outside b <= -2; start outside the box too
        (("expfit", expfit, (1.0, 0.0), _EXP_LO, _EXP_HI), "gn"),
        (("expfit", expfit, (1.0, 0.0), _EXP_LO, _EXP_HI), "lm-scaled"),
        # Rosenbrock with y0 <= 0.5: the minimum is (0.5, 0.25), cost 0.125
        (("rosenbrock", rosenbrock, (-1.2, 1.0), _ROS_LO, _ROS_HI), "gn"),
        (("rosenbrock", rosenbrock, (-1.2, 1.0), _ROS_LO, _ROS_HI), "lm"),
    ],
    ids=["expfit-gn", "expfit-lm-scaled", "rosenbrock-gn", "rosenbrock-lm"],
)
def test_bounds_end_on_the_face(case, solver):
    name, fn, y0, lo, hi = case
    sol = least_squares(_boxed(fn, lo, hi), SOLVERS[solver](), jnp.asarray(y0), bounds=(lo, hi))
    assert sol.result == RESULTS.successful, RESULTS[sol.result]
    value = np.asarray(sol.value)
    assert np.all(value >= lo) and np.all(value <= hi), "value inside the box"
    ref = scipy.optimize.least_squares(
        lambda y: np.asarray(fn(jnp.asarray(y), None)), np.clip(y0, lo, np.nextafter(hi, -np.inf)),
        method="trf", bounds=(lo, hi), xtol=1e-15, ftol=1e-15, gtol=1e-15,
    )
    assert_close(f"{name}/{solver} vs scipy trf: x", value, ref.x, atol=_ATOL_SCIPY)
    assert_close(f"{name}/{solver} vs scipy trf: cost", sol.stats["cost"], ref.cost, atol=_ATOL_SCIPY)
    if name == "expfit":  # on the face b = -2 the best a is a linear least-squares fit
        e = np.exp(-2.0 * _T)
        assert value[1] == -2.0
        assert_close("a on the face", value[0], (_DATA @ e) / (e @ e), atol=1e-12)
    else:
        assert value[0] == 0.5
        assert_close("rosenbrock face", value, [0.5, 0.25], atol=1e-12)
        assert_close("rosenbrock face cost", sol.stats["cost"], 0.125, atol=1e-14)


@pytest.mark.parametrize("solver", ["gn", "lm"])
def test_bounds_linear_matches_lsq_linear_and_clips_y0(solver):
    lo, hi = np.array([-0.1, -0.1, -0.1]), np.array([0.1, 0.1, 0.1])
    y0 = np.array([5.0, -5.0, 0.0])  # outside the box: clipped first
    bounds = (-0.1, 0.1) if solver == "gn" else (lo, hi)  # scalars broadcast
    sol = least_squares(_boxed(linear, lo, hi), SOLVERS[solver](), y0, bounds=bounds)
    ref = scipy.optimize.lsq_linear(_A, _B, bounds=(lo, hi), method="bvls", tol=1e-15)
    assert sol.result == RESULTS.successful, RESULTS[sol.result]
    assert_close("x vs lsq_linear", sol.value, ref.x, atol=_ATOL_SCIPY)
    assert np.all(np.asarray(sol.value) >= lo) and np.all(np.asarray(sol.value) <= hi)


# ---------------------------------------------------------------------------------------------
# Batching: vmap equals a Python loop; failures stay per element.
# ---------------------------------------------------------------------------------------------

_Y0_BATCH = np.array([[1.0, 1.0], [-1.2, 1.0], [0.9, 0.8], [2.0, -1.0]])
_BATCH_SOLVERS = {"lm-adaptive": LevenbergMarquardt(max_steps=8), "gn-fixed": GaussNewton(max_steps=4, fixed_steps=True)}


@functools.lru_cache(maxsize=None)
def batch_runs(name):
    """``(jitted single solve, vmapped solution)`` for a batch of Rosenbrock starts."""
    solver = _BATCH_SOLVERS[name]
    run = eqx.filter_jit(lambda y0: least_squares(rosenbrock, solver, y0))
    return run, jax.vmap(run)(jnp.asarray(_Y0_BATCH))


@pytest.mark.parametrize("name", list(_BATCH_SOLVERS))
def test_vmap_equals_loop(name):
    run, batched = batch_runs(name)
    for i, y0 in enumerate(_Y0_BATCH):
        single = run(jnp.asarray(y0))
        assert_close(f"value[{i}]", batched.value[i], single.value, atol=1e-13)
        assert bool((batched.result == single.result)[i]), f"result[{i}]"
        assert int(batched.stats["num_steps"][i]) == int(single.stats["num_steps"]), f"num_steps[{i}]"
        assert_close(f"cost_history[{i}]", batched.stats["cost_history"][i], single.stats["cost_history"], atol=1e-13)
    assert int(batched.stats["num_steps"][0]) == 0, "a start at the minimum takes no step"


@pytest.mark.parametrize("name", list(_BATCH_SOLVERS))
def test_max_steps_is_per_element(name):
    """One element that runs out of steps neither raises nor disturbs the others (throw=False)."""
    _, sols = batch_runs(name)
    ok = np.asarray(sols.result == RESULTS.successful)
    out_of_steps = np.asarray(sols.result == RESULTS.max_steps_reached)
    assert ok[0] and out_of_steps[1], (ok, out_of_steps)
    assert np.all(ok | out_of_steps)
    max_steps = _BATCH_SOLVERS[name].max_steps
    assert np.all(np.asarray(sols.stats["num_steps"])[out_of_steps] == max_steps)
    assert np.all(np.isfinite(np.asarray(sols.value)))


@pytest.mark.parametrize("solver", [_solver_param("optx-lm"), _solver_param("jaxopt-gn")])
def test_backends_vmap_per_element(solver):
    """The adapters return no backend state, so they batch; each element keeps its own result."""
    p = PROBLEMS["rosenbrock"]
    y0s = jnp.asarray([p.y0, [1.0, 1.0]])
    sols = jax.vmap(lambda y0: least_squares(p.fn, SOLVERS[solver](), y0))(y0s)
    single = solve("rosenbrock", solver)
    assert_close("value[0]", sols.value[0], single.value, atol=1e-12)
    assert int(sols.stats["num_steps"][0]) == int(single.stats["num_steps"])
    assert np.all(np.asarray(sols.result == RESULTS.successful))
    assert_close("values", sols.value, np.ones((2, 2)), atol=_ATOL_MIN)


def test_throw_raises():
    solver = LevenbergMarquardt(max_steps=8)
    y0s = jnp.asarray(_Y0_BATCH[:2])
    with pytest.raises(eqx.EquinoxRuntimeError, match="maximum number of steps"):
        least_squares(rosenbrock, solver, y0s[1], throw=True).value.block_until_ready()
    with pytest.raises(eqx.EquinoxRuntimeError, match="maximum number of steps"):
        jax.vmap(lambda y0: least_squares(rosenbrock, solver, y0, throw=True))(y0s).value.block_until_ready()
    assert least_squares(rosenbrock, solver, y0s[0], throw=True).result == RESULTS.successful


def test_lambda0_is_traced_and_sweepable():
    traces = []

    def fn(y, args):
        traces.append(1)
        return rosenbrock(y, args)

    y0 = jnp.asarray(PROBLEMS["rosenbrock"].y0)
    a = least_squares(fn, LevenbergMarquardt(lambda0=1e-3), y0)
    n = len(traces)
    b = least_squares(fn, LevenbergMarquardt(lambda0=1.0), y0)
    assert len(traces) == n, "a new lambda0 value must not retrace"
    assert int(a.stats["num_steps"]) != int(b.stats["num_steps"])
    sweep = jax.vmap(lambda lam: least_squares(rosenbrock, LevenbergMarquardt(lambda0=lam), y0))(jnp.logspace(-4, 1, 3))
    assert np.all(np.asarray(sweep.result == RESULTS.successful))
    assert_close("sweep values", sweep.value, np.ones((3, 2)), atol=_ATOL_MIN)


# ---------------------------------------------------------------------------------------------
# Non-finite values, singular systems, the user Jacobian.
# ---------------------------------------------------------------------------------------------


def test_nan_in_args_gives_nonfinite_and_y0():
    sol = least_squares(lambda y, a: y - a, GaussNewton(), jnp.zeros(2), jnp.array([1.0, jnp.nan]))
    assert sol.result == RESULTS.nonfinite
    assert_close("value", sol.value, [0.0, 0.0])
    assert int(sol.stats["num_steps"]) == 0
    for key, v in sol.stats.items():
        assert not np.any(np.isnan(np.asarray(v))), key


def test_residual_nan_everywhere_but_y0():
    def fn(y, args):
        return y - 2 + jnp.where(jnp.all(y == 0), 0.0, jnp.nan)

    sol = least_squares(fn, LevenbergMarquardt(), jnp.zeros(1))
    assert sol.result == RESULTS.nonfinite
    assert_close("value", sol.value, [0.0])


def test_gauss_newton_returns_last_finite_iterate():
    def fn(y, args):  # NaN beyond y = 1; the minimum y = 2 is not reachable
        return y - 2 + jnp.where(y[0] > 1, jnp.nan, 0.0)

    sol = least_squares(fn, GaussNewton(), jnp.zeros(1))
    assert sol.result == RESULTS.nonfinite
    assert_close("value", sol.value, [1.0])
    sol = least_squares(fn, LevenbergMarquardt(max_steps=30), jnp.zeros(1))
    assert sol.result != RESULTS.successful
    assert np.all(np.isfinite(np.asarray(sol.value))) and float(sol.value[0]) <= 1.0


def test_nan_jacobian_gives_nonfinite():
    sol = least_squares(rosenbrock, LevenbergMarquardt(), jnp.asarray([-1.2, 1.0]), jac=lambda y, a: jnp.full((2, 2), jnp.nan))
    assert sol.result == RESULTS.nonfinite
    assert_close("value", sol.value, [-1.2, 1.0])


def test_singular_gauss_newton_and_damped_lm():
    A = np.array([[1.0, 1.0], [1.0, 1.0], [2.0, 2.0]])  # rank 1
    b = np.array([1.0, 2.0, 3.0])

    def fn(y, args):
        return jnp.asarray(A) @ y - jnp.asarray(b)

    gn = least_squares(fn, GaussNewton(), jnp.zeros(2))
    assert gn.result == RESULTS.singular
    assert "LevenbergMarquardt" in RESULTS[gn.result]
    lm = least_squares(fn, LevenbergMarquardt(), jnp.zeros(2))
    assert lm.result == RESULTS.successful
    ref = np.linalg.lstsq(A, b, rcond=None)[0]  # minimum-norm solution: LM from 0 stays in range(A^T)
    assert_close("lm cost", lm.stats["cost"], 0.5 * np.sum((A @ ref - b) ** 2), atol=1e-10)
    assert_close("lm value", lm.value, ref, atol=1e-6)


def test_user_jacobian_equals_autodiff():
    p = PROBLEMS["rosenbrock"]
    auto = solve("rosenbrock", "lm")
    user = least_squares(p.fn, SOLVERS["lm"](), jnp.asarray(p.y0), jac=p.jac)
    assert int(user.stats["num_steps"]) == int(auto.stats["num_steps"])
    assert_close("value", user.value, auto.value, atol=1e-12)
    for name in ("rosenbrock", "expfit"):
        q = PROBLEMS[name]
        y = jnp.asarray(q.y_star) + 0.1
        assert_close(f"{name}: jac", q.jac(y, None), jax.jacfwd(lambda z: q.fn(z, None))(y), atol=1e-12)


def _rosenbrock_fused(y, args):
    return rosenbrock(y, args), rosenbrock_jac(y, args)


@pytest.mark.parametrize("solver", [_solver_param("optx-lm"), _solver_param("lm")])
def test_fused_residual_and_jacobian(solver):
    """``jac=True``: ``fn`` returns ``(r, J)``; same iterates as a separate ``jac``."""
    p = PROBLEMS["rosenbrock"]
    split = least_squares(p.fn, SOLVERS[solver](), jnp.asarray(p.y0), jac=rosenbrock_jac)
    fused = least_squares(_rosenbrock_fused, SOLVERS[solver](), jnp.asarray(p.y0), jac=True)
    assert int(fused.stats["num_steps"]) == int(split.stats["num_steps"])
    assert_close("value", fused.value, split.value, atol=1e-14)
    with pytest.raises(ValueError, match=r"with jac=True, expected fn\(y, args\) to return \(r, J\)"):
        least_squares(p.fn, SOLVERS[solver](), jnp.asarray(p.y0), jac=True)


@pytest.mark.parametrize("solver", [_solver_param("optx-lm"), _solver_param("jaxopt-lm"), _solver_param("lm")])
def test_backends_use_the_analytic_jacobian(solver):
    """``fn`` has no derivative (stop_gradient): only the user ``jac`` can make the solve succeed."""
    p = PROBLEMS["expfit"]

    def opaque(y, args):
        return jax.lax.stop_gradient(expfit(y, args))

    sol = least_squares(opaque, SOLVERS[solver](), jnp.asarray(p.y0), jac=expfit_jac)
    assert sol.result == RESULTS.successful, RESULTS[sol.result]
    assert_close("value", sol.value, p.y_star, atol=_ATOL_MIN)


def test_custom_jvp_residual_differentiates_args():
    """The backends' residual wrapper also propagates tangents of ``args`` (through ``fn``)."""

    def fn(y, a):
        return a["scale"] * expfit(y, None)

    def jac(y, a):
        return a["scale"] * expfit_jac(y, None)

    wrapped = _Problem(fn=fn, jac=jac, lower=None, upper=None, m=20).custom_jvp_residual()
    y = jnp.asarray([1.5, -1.0])
    scale = jnp.asarray(2.0)

    @jax.jit
    def derivatives(y, scale):
        args = {"scale": scale, "label": "static"}
        return (
            jax.jacfwd(lambda z: wrapped(z, args))(y),
            jax.jacrev(lambda z: wrapped(z, args))(y),
            jax.jacfwd(lambda s: wrapped(y, {"scale": s, "label": "static"}))(scale),
        )

    J_fwd, J_rev, d_scale = derivatives(y, scale)
    assert_close("d/dy forward", J_fwd, jac(y, {"scale": scale}), atol=1e-12)
    assert_close("d/dy reverse", J_rev, jac(y, {"scale": scale}), atol=1e-12)
    assert_close("d/dscale", d_scale, expfit(y, None), atol=1e-12)


_solve_normal_jit = jax.jit(_solve_normal, static_argnames="short_fat")


def test_short_fat_step_equals_normal_equations():
    """The m x m form -D^-1 J^T (J D^-1 J^T + lam I)^-1 r equals the n x n normal equations."""
    rng = np.random.default_rng(3)
    J = jnp.asarray(rng.normal(size=(2, 5)))
    r = jnp.asarray(rng.normal(size=2))
    g = J.T @ r
    weights = jnp.asarray(rng.uniform(0.5, 3.0, size=5))
    free = jnp.asarray([True, False, True, True, False])
    for lam, diag, mask in [(0.3, None, None), (1e-4, None, None), (0.3, None, free), (0.3, weights, None), (0.3, weights, free)]:
        lam = jnp.asarray(lam)
        a, tr_a = _solve_normal_jit(J, r, g, lam, diag, mask, short_fat=True)
        b, tr_b = _solve_normal_jit(J, r, g, lam, diag, mask, short_fat=False)
        label = f"lam={float(lam)}, weighted={diag is not None}, frozen={mask is not None}"
        assert_close(f"step, {label}", a, b, atol=1e-9)
        assert_close(f"trace, {label}", tr_a, tr_b, rtol=1e-12)
        A = np.asarray(J.T @ J) + float(lam) * np.diag(np.ones(5) if diag is None else np.asarray(diag))
        if mask is None:
            assert_close(f"dense solve, {label}", a, -np.linalg.solve(A, np.asarray(g)), atol=1e-9)
        else:
            assert np.all(np.asarray(a)[~np.asarray(mask)] == 0), "frozen variables do not move"
    p, _ = _solve_normal_jit(J, r, g, jnp.asarray(0.0), None, None, short_fat=True)  # Gauss-Newton: minimum norm
    assert_close("min-norm GN step", p, -np.linalg.pinv(np.asarray(J)) @ np.asarray(r), atol=1e-12)


def test_weights_resist_motion():
    """D = diag(w): a heavily weighted variable moves less while damping is large (one LM step)."""
    A = np.array([[1.0, 1.0]])
    fn = lambda y, args: jnp.asarray(A) @ y - 1.0  # noqa: E731
    step = least_squares(fn, LevenbergMarquardt(max_steps=1, lambda0=10.0, weights=jnp.array([1.0, 100.0])), jnp.zeros(2))
    assert float(step.value[0]) > 10 * float(step.value[1]) > 0
    sol = least_squares(fn, LevenbergMarquardt(weights=[1.0, 100.0]), jnp.zeros(2))
    assert sol.result == RESULTS.successful
    assert_close("residual", sol.stats["cost"], 0.0, atol=1e-14)
    with pytest.raises(ValueError, match=r"weights: expected shape \(n,\) = \(2,\) like y0, got \(3,\)"):
        least_squares(fn, LevenbergMarquardt(weights=jnp.ones(3)), jnp.zeros(2))
    with pytest.raises(ValueError, match="weights: expected positive"):
        LevenbergMarquardt(weights=jnp.array([1.0, 0.0]))


def test_underdetermined_problem_uses_min_norm_gauss_newton():
    A = np.random.default_rng(4).normal(size=(2, 4))
    b = np.array([1.0, -2.0])
    fn = lambda y, args: jnp.asarray(A) @ y - jnp.asarray(b)  # noqa: E731
    gn = least_squares(fn, GaussNewton(), jnp.zeros(4))
    assert gn.result == RESULTS.successful and int(gn.stats["num_steps"]) == 1
    assert_close("GN = pinv solution", gn.value, np.linalg.pinv(A) @ b, atol=1e-12)
    lm = least_squares(fn, LevenbergMarquardt(), jnp.zeros(4))
    assert lm.result == RESULTS.successful
    assert_close("LM = pinv solution", lm.value, np.linalg.pinv(A) @ b, atol=1e-7)


@hypothesis.settings(max_examples=8, deadline=None, derandomize=True)
@hypothesis.given(seed=st.integers(0, 2**31 - 1), scale=st.sampled_from([1e-3, 1.0, 1e3]))
def test_linear_least_squares_property(seed, scale):
    """Random (uniform, scaled) 8x3 problems through ``args``: one compile, GN and LM = lstsq."""
    rng = np.random.default_rng(seed)
    A = rng.uniform(-1, 1, size=(8, 3)) * scale
    b = rng.normal(size=8)
    ref = np.linalg.lstsq(A, b, rcond=None)[0]
    for solver in (_LINEAR_GN, _LINEAR_LM):
        sol = solver(jnp.zeros(3), (jnp.asarray(A), jnp.asarray(b)))
        assert sol.result == RESULTS.successful
        assert_close("x vs lstsq", sol.value, ref, atol=1e-7 * max(1.0, np.max(np.abs(ref))))


def _linear_args(y, args):
    A, b = args
    return A @ y - b


_LINEAR_GN = eqx.filter_jit(lambda y0, args: least_squares(_linear_args, GaussNewton(), y0, args))
_LINEAR_LM = eqx.filter_jit(lambda y0, args: least_squares(_linear_args, LevenbergMarquardt(), y0, args))


# ---------------------------------------------------------------------------------------------
# float32, bad input, inputs left alone.
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "solver",
    [
        GaussNewton(),
        LevenbergMarquardt(fixed_steps=True, max_steps=40),
        # optimistix 0.1.0 starts its trust-region scalars in float64 under x64: the adapter casts them
        OptimistixSolver(optx.LevenbergMarquardt(rtol=1e-5, atol=1e-7), max_steps=256),
        OptimistixSolver(optx.Dogleg(rtol=1e-5, atol=1e-7), max_steps=256),
        OptimistixSolver(optx.GaussNewton(rtol=1e-5, atol=1e-7), max_steps=256),
    ],
    ids=["gn", "lm-fixed", "optx-lm", "optx-dogleg", "optx-gn"],
)
@pytest.mark.parametrize("problem", ["rosenbrock", "expfit"])
def test_float32_no_nan(problem, solver):
    """float32 in, float32 out, with x64 on (as users mix): no NaN, the minimum to float32 accuracy."""
    p = PROBLEMS[problem]
    sol = least_squares(p.fn, solver, jnp.asarray(p.y0, jnp.float32))
    assert sol.value.dtype == jnp.float32
    for key, v in [("value", sol.value), *sol.stats.items()]:
        assert np.all(np.isfinite(np.asarray(v))), key
    assert sol.result == RESULTS.successful, RESULTS[sol.result]
    assert_close("value", sol.value, p.y_star, atol=2e-3)


def test_bad_shapes_name_the_argument():
    lm = LevenbergMarquardt()
    with pytest.raises(ValueError, match=r"y0: expected shape \(n,\).*got \(2, 1\)"):
        least_squares(rosenbrock, lm, jnp.zeros((2, 1)))
    with pytest.raises(ValueError, match=r"y0: expected shape \(n,\).*got \(\)"):
        least_squares(rosenbrock, lm, 1.0)
    with pytest.raises(ValueError, match=r"bounds: expected lower of shape \(n,\) = \(2,\), got \(3,\)"):
        least_squares(rosenbrock, lm, jnp.zeros(2), bounds=(jnp.zeros(3), jnp.ones(2)))
    with pytest.raises(ValueError, match=r"bounds: expected lower <= upper"):
        least_squares(rosenbrock, lm, jnp.zeros(2), bounds=(jnp.ones(2), jnp.zeros(2)))
    with pytest.raises(ValueError, match=r"bounds: expected a pair"):
        least_squares(rosenbrock, lm, jnp.zeros(2), bounds=jnp.zeros(2))
    with pytest.raises(ValueError, match=r"fn: expected .* shape \(m,\), got \(2, 2\)"):
        least_squares(lambda y, a: jnp.outer(y, y), lm, jnp.zeros(2))
    with pytest.raises(ValueError, match=r"jac: expected .* \(m, n\) = \(2, 2\), got \(2, 3\)"):
        least_squares(rosenbrock, lm, jnp.zeros(2), jac=lambda y, a: jnp.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"bounds: not supported by OptimistixSolver"):
        least_squares(rosenbrock, OptimistixSolver(optx.LevenbergMarquardt(1e-8, 1e-8)), jnp.zeros(2), bounds=(-1.0, 1.0))
    with pytest.raises(ValueError, match=r"solver: expected"):
        least_squares(rosenbrock, optx.LevenbergMarquardt(1e-8, 1e-8), jnp.zeros(2))
    with pytest.raises(ValueError, match=r"max_steps: expected an int >= 1"):
        GaussNewton(max_steps=0)
    with pytest.raises(ValueError, match=r"name: expected one of"):
        JaxoptSolver("Dogleg")


def test_inputs_are_not_modified():
    y0 = np.array([-1.2, 1.0])
    lo, hi = np.array([-2.0, -2.0]), np.array([0.5, 2.0])
    args = {"w": np.array([1.0, 2.0])}
    copies = [a.copy() for a in (y0, lo, hi, args["w"])]

    def fn(y, a):
        return rosenbrock(y, None) * a["w"]

    sol = least_squares(fn, LevenbergMarquardt(), y0, args, bounds=(lo, hi))
    assert sol.result == RESULTS.successful
    for orig, now in zip(copies, (y0, lo, hi, args["w"])):
        np.testing.assert_array_equal(orig, now)


def test_integer_y0_is_promoted():
    sol = least_squares(linear, GaussNewton(), np.zeros(3, dtype=np.int32))
    assert sol.value.dtype == jnp.float64
    assert_close("value", sol.value, PROBLEMS["linear"].y_star, atol=1e-12)
