"""Tests of solvers.ilqr and solvers.ddp: LQ exactness against solvers.lqr, the Crocoddyl unicycle
reference, vmap against a loop (with a diverging element), fixed-step against adaptive mode, and
bad input."""

from __future__ import annotations

import functools
import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import solvers
from solvers import RESULTS, problems

from .conftest import shared_data_dir
from .helpers import count_traces

_ATOL_LQ = 1e-9  # iLQR/DDP after one iteration vs LQR
_RTOL_COST_REF = 5e-12  # cost vs Crocoddyl: they agree to 4e-14 (iLQR) / 5e-14 (DDP); 100x margin
# Trajectories vs Crocoddyl: they agree to 1.6e-6 (us) and 1.9e-7 (xs). The minimum is flat, so the
# two solvers' stopping tests (ours on the expected decrease, Crocoddyl's th_stop = 1e-12 on its
# own) leave the controls ~sqrt(cost tolerance) apart; a tighter bound would test the stopping rules.
_ATOL_TRAJ_REF = 1e-5

SOLVERS = {"ilqr": solvers.ilqr, "ddp": solvers.ddp}


# --------------------------------------------------------------------------------------------
# LQ problem: iLQR/DDP must equal LQR after one iteration.
# --------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=None)
def _lq_data(T=8, n=3, m=2):
    rng = np.random.default_rng(0)
    A = np.eye(n) + 0.3 * rng.standard_normal((T, n, n))
    B = rng.standard_normal((T, n, m))
    c = 0.1 * rng.standard_normal((T, n))
    G = rng.standard_normal((T, n, n))
    Q = G @ np.swapaxes(G, 1, 2) / n
    H = rng.standard_normal((T, m, m))
    R = H @ np.swapaxes(H, 1, 2) / m + np.eye(m)
    S = 0.1 * rng.standard_normal((T, m, n))
    q = rng.standard_normal((T, n))
    r = rng.standard_normal((T, m))
    QT = np.eye(n) * 2.0
    qT = rng.standard_normal(n)
    x0 = rng.standard_normal(n)
    return dict(A=A, B=B, c=c, Q=Q, R=R, S=S, q=q, r=r, QT=QT, qT=qT, x0=x0)


def _lq_dynamics(x, u, t, a):
    return a["A"][t] @ x + a["B"][t] @ u + a["c"][t]


def _lq_cost(x, u, t, a):
    return (
        0.5 * x @ a["Q"][t] @ x + 0.5 * u @ a["R"][t] @ u + u @ a["S"][t] @ x + a["q"][t] @ x + a["r"][t] @ u
    )


def _lq_terminal(x, a):
    return 0.5 * x @ a["QT"] @ x + a["qT"] @ x


@pytest.mark.parametrize("name", ["ilqr", "ddp"])
def test_lq_one_iteration_equals_lqr(name):
    d = {k: jnp.asarray(v) for k, v in _lq_data().items()}
    ref = solvers.lqr(d["A"], d["B"], d["Q"], d["R"], d["QT"], d["x0"], S=d["S"], q=d["q"], r=d["r"], qT=d["qT"], c=d["c"])
    assert ref.result == RESULTS.successful
    us0 = jnp.zeros(ref.us.shape)
    solve = SOLVERS[name]
    one = solve(_lq_dynamics, _lq_cost, d["x0"], us0, terminal_cost=_lq_terminal, args=d, max_steps=1)
    for field in ("xs", "us", "Ks", "ks", "cost"):
        np.testing.assert_allclose(
            getattr(one, field), getattr(ref, field), atol=_ATOL_LQ, rtol=0, err_msg=f"{name}: {field}"
        )
    assert one.result == RESULTS.max_steps_reached  # one step taken, convergence not yet confirmed
    if name == "ddp":  # (DDP's adaptive loop is covered by the unicycle test; saves a compile)
        return
    full = solve(_lq_dynamics, _lq_cost, d["x0"], us0, terminal_cost=_lq_terminal, args=d)
    assert full.result == RESULTS.successful
    assert int(full.stats["num_steps"]) == 2  # the step, then the confirmation
    np.testing.assert_allclose(full.us, ref.us, atol=_ATOL_LQ, rtol=0, err_msg=f"{name}: us")
    assert float(full.stats["grad_norm"]) < 1e-9


# --------------------------------------------------------------------------------------------
# Crocoddyl unicycle reference (shared data).
# --------------------------------------------------------------------------------------------


# The unicycle of solvers.problems is Crocoddyl's ActionModelUnicycle: cost
# 0.5 * (w0^2 |x|^2 + w1^2 |u|^2) per knot (README of ddp_refs.json: not multiplied by dt).
_UNICYCLE = problems.unicycle()
_unicycle_dynamics = _UNICYCLE.dynamics
_unicycle_cost = _UNICYCLE.cost
_unicycle_terminal = _UNICYCLE.terminal_cost


def _unicycle_args(dt=0.1, w=(10.0, 1.0)):
    return problems.unicycle(dt=dt, state_weight=w[0], control_weight=w[1]).args


def _unicycle_ref():
    refs = json.loads((shared_data_dir() / "ddp" / "ddp_refs.json").read_text())
    return next(p for p in refs["problems"] if p["model"] == "unicycle")


# The reference problem is the one of the batching tests below (T = 20, x0 = (-1, -1, 1), dt = 0.1,
# weights 10 / 1): solved with their max_steps (it converges in 9 iterations), iLQR's compiled
# solve is theirs (one iLQR program fewer, ~1.4 s of compilation).
_MAX_STEPS = 40


@pytest.mark.parametrize("name", ["ilqr", "ddp"])
def test_unicycle_matches_crocoddyl(name):
    ref = _unicycle_ref()
    args = _unicycle_args(ref["dt"], ref["cost_weights"])
    sol = SOLVERS[name](
        _unicycle_dynamics,
        _unicycle_cost,
        jnp.asarray(ref["x0"]),
        jnp.zeros((ref["T"], 2)),
        terminal_cost=_unicycle_terminal,
        args=args,
        max_steps=_MAX_STEPS,
    )
    assert sol.result == RESULTS.successful, RESULTS[sol.result]
    np.testing.assert_allclose(sol.cost, ref["optimal_cost"], rtol=_RTOL_COST_REF, err_msg=f"{name}: cost")
    np.testing.assert_allclose(sol.xs, np.asarray(ref["xs"]), atol=_ATOL_TRAJ_REF, rtol=0, err_msg=f"{name}: xs")
    np.testing.assert_allclose(sol.us, np.asarray(ref["us"]), atol=_ATOL_TRAJ_REF, rtol=0, err_msg=f"{name}: us")
    # Cost history: starts at the initial cost, never increases, ends at the final cost.
    hist = np.asarray(sol.stats["cost_history"])
    assert np.all(np.diff(hist) <= 1e-12 * hist[0]), "cost_history: increased"
    np.testing.assert_allclose(hist[-1], sol.cost, rtol=0, atol=0, err_msg="cost_history: padding")
    # At the optimum the policy reproduces the controls along the trajectory.
    u_policy = jnp.einsum("tmn,tn->tm", sol.Ks, sol.xs[:-1]) + sol.ks
    np.testing.assert_allclose(u_policy, sol.us, atol=_ATOL_TRAJ_REF, rtol=0, err_msg=f"{name}: Ks, ks")


def test_unicycle_matches_live_crocoddyl():
    # The stored reference above, recomputed by the installed Crocoddyl (ActionModelUnicycle,
    # SolverDDP): the same problem, so the same optimum.
    crocoddyl = pytest.importorskip(
        "crocoddyl", reason="Crocoddyl is not installed (it is in the test extra): no live comparison"
    )
    ref = _unicycle_ref()
    model = crocoddyl.ActionModelUnicycle()
    model.dt = ref["dt"]
    model.costWeights = np.asarray(ref["cost_weights"], dtype=np.float64)
    x0 = np.asarray(ref["x0"], dtype=np.float64)
    ddp = crocoddyl.SolverDDP(crocoddyl.ShootingProblem(x0, [model] * ref["T"], model))
    ddp.th_stop = 1e-12
    assert ddp.solve([], [], 100), "crocoddyl: not converged"
    sol = solvers.ilqr(
        _unicycle_dynamics, _unicycle_cost, jnp.asarray(x0), jnp.zeros((ref["T"], 2)),
        terminal_cost=_unicycle_terminal, args=_unicycle_args(ref["dt"], ref["cost_weights"]), max_steps=_MAX_STEPS,
    )
    np.testing.assert_allclose(sol.cost, ddp.cost, rtol=_RTOL_COST_REF, err_msg="cost")
    np.testing.assert_allclose(sol.xs, np.asarray(ddp.xs), atol=_ATOL_TRAJ_REF, rtol=0, err_msg="xs")
    np.testing.assert_allclose(sol.us, np.asarray(ddp.us), atol=_ATOL_TRAJ_REF, rtol=0, err_msg="us")


@pytest.mark.parametrize("name", ["ilqr", "ddp"])
def test_second_eager_call_does_not_retrace(name):
    # Same callbacks, shapes and static options, new values of x0, us_init and args: the compiled
    # solve (the one of test_unicycle_matches_crocoddyl) is reused, also through options=.
    ref = _unicycle_ref()
    solve = SOLVERS[name]
    kw = dict(terminal_cost=_unicycle_terminal)
    first = solve(_unicycle_dynamics, _unicycle_cost, jnp.asarray(ref["x0"]), jnp.zeros((ref["T"], 2)),
                  args=_unicycle_args(ref["dt"], ref["cost_weights"]), max_steps=_MAX_STEPS, **kw)
    x0, us0 = jnp.asarray(ref["x0"]) * 0.5, jnp.asarray(np.full((ref["T"], 2), 0.1))
    args = _unicycle_args(ref["dt"], (5.0, 2.0))
    options = solvers.ILQROptions(max_steps=_MAX_STEPS, atol=1e-12)
    with count_traces() as traces:
        second = solve(_unicycle_dynamics, _unicycle_cost, x0, us0, args=args, max_steps=_MAX_STEPS, **kw)
        third = solve(_unicycle_dynamics, _unicycle_cost, x0, us0, args=args, options=options, **kw)
    assert traces[0] == 0, f"{name}: {traces[0]} traces on the second call"
    assert first.result == second.result == RESULTS.successful
    for field in ("xs", "us", "Ks", "ks", "cost"):
        np.testing.assert_array_equal(getattr(third, field), getattr(second, field), err_msg=f"options: {field}")
    with pytest.raises(ValueError, match="options: given together with max_steps"):
        solve(_unicycle_dynamics, _unicycle_cost, x0, us0, args=args, options=options, max_steps=5, **kw)


# --------------------------------------------------------------------------------------------
# Batching and modes (own unicycle instance: no shared data needed).
# --------------------------------------------------------------------------------------------

_T_SMALL = 20


def _solve_unicycle(x0, fixed_steps=False, max_steps=_MAX_STEPS):
    return solvers.ilqr(
        _unicycle_dynamics,
        _unicycle_cost,
        x0,
        jnp.zeros((_T_SMALL, 2)),
        terminal_cost=_unicycle_terminal,
        args=_unicycle_args(),
        max_steps=max_steps,
        fixed_steps=fixed_steps,
    )


def _fields(sol):
    return dict(xs=sol.xs, us=sol.us, cost=sol.cost, result=sol.result._value, num_steps=sol.stats["num_steps"])


def test_vmap_equals_loop_with_diverging_element():
    # 1024 initial states (acceptance), one of them NaN; the loop checks a spread sample of them.
    rng = np.random.default_rng(7)
    x0s = np.concatenate([[[-1.0, -1.0, 1.0]], rng.uniform(-1.0, 1.0, (1023, 3))])
    x0s[2] = [np.nan, 0.0, 0.0]
    x0s = jnp.asarray(x0s)
    batched = jax.jit(jax.vmap(lambda x0: _fields(_solve_unicycle(x0))))(x0s)
    for i in [*range(8), *range(8, 1024, 61)]:  # 24 of the 1024 (each single solve is a call)
        single = _fields(_solve_unicycle(x0s[i]))
        if i == 2:
            assert int(single["result"]) == RESULTS.nonfinite._value
            continue
        for key, value in single.items():
            np.testing.assert_allclose(batched[key][i], value, atol=1e-10, rtol=0, err_msg=f"element {i}: {key}")
    # Element 0 is the reference problem (converges); others with a lateral offset converge only
    # linearly (it is nearly uncontrollable), so some may still be running at max_steps. Only the
    # NaN element is nonfinite, and it did not abort the batch.
    results = np.asarray(batched["result"])
    assert results[0] == RESULTS.successful._value
    assert results[2] == RESULTS.nonfinite._value
    others = np.delete(results, 2)
    assert np.all((others == RESULTS.successful._value) | (others == RESULTS.max_steps_reached._value))
    assert np.mean(others == RESULTS.successful._value) > 0.3  # 45 % converge within 40 iterations
    assert np.all(np.isfinite(np.delete(np.asarray(batched["cost"]), 2)))


def test_fixed_steps_equals_adaptive():
    x0 = jnp.array([-1.0, -1.0, 1.0])
    adaptive = _solve_unicycle(x0)
    fixed = _solve_unicycle(x0, fixed_steps=True)
    assert adaptive.result == RESULTS.successful
    assert fixed.result == RESULTS.successful
    assert int(fixed.stats["num_steps"]) == int(adaptive.stats["num_steps"]) < 40
    for field in ("xs", "us", "Ks", "ks", "cost"):
        np.testing.assert_allclose(getattr(fixed, field), getattr(adaptive, field), atol=1e-12, rtol=0, err_msg=field)
    np.testing.assert_allclose(
        fixed.stats["cost_history"], adaptive.stats["cost_history"], atol=1e-12, rtol=0, err_msg="cost_history"
    )


def test_throw_raises_on_failure():
    with pytest.raises(eqx.EquinoxRuntimeError):
        solvers.ilqr(
            _unicycle_dynamics,
            _unicycle_cost,
            jnp.array([jnp.nan, 0.0, 0.0]),
            jnp.zeros((_T_SMALL, 2)),
            terminal_cost=_unicycle_terminal,
            args=_unicycle_args(),
            throw=True,
        )


def test_bad_input_raises():
    args = _unicycle_args()
    us = jnp.zeros((_T_SMALL, 2))
    with pytest.raises(ValueError, match=r"x0: expected shape \(n,\)"):
        solvers.ilqr(_unicycle_dynamics, _unicycle_cost, jnp.zeros((3, 1)), us, args=args)
    with pytest.raises(ValueError, match=r"us_init: expected shape \(T, m\)"):
        solvers.ilqr(_unicycle_dynamics, _unicycle_cost, jnp.zeros(3), jnp.zeros(4), args=args)
    with pytest.raises(ValueError, match=r"dynamics: expected .* shape \(n,\) = \(3,\), got \(2,\)"):
        solvers.ilqr(lambda x, u, t, a: x[:2], _unicycle_cost, jnp.zeros(3), us, args=args)
    with pytest.raises(ValueError, match=r"cost: expected .* scalar"):
        solvers.ilqr(_unicycle_dynamics, lambda x, u, t, a: x, jnp.zeros(3), us, args=args)
    with pytest.raises(ValueError, match=r"bounds: expected u_min of shape \(m,\) = \(2,\), got \(3,\)"):
        solvers.ilqr(_unicycle_dynamics, _unicycle_cost, jnp.zeros(3), us, args=args, bounds=(jnp.zeros(3), 1.0))
    with pytest.raises(ValueError, match="u_min <= u_max"):
        solvers.ilqr(_unicycle_dynamics, _unicycle_cost, jnp.zeros(3), us, args=args, bounds=(1.0, -1.0))


# --------------------------------------------------------------------------------------------
# Box-DDP.
# --------------------------------------------------------------------------------------------


def test_box_ddp_unicycle_against_lbfgsb_and_clipping():
    scipy_optimize = pytest.importorskip("scipy.optimize")
    x0 = jnp.array([-1.0, -1.0, 1.0])
    args = _unicycle_args()
    lo, hi = jnp.array([-2.0, -1.5]), jnp.array([2.0, 1.5])
    sol = solvers.ddp(
        _unicycle_dynamics, _unicycle_cost, x0, jnp.zeros((_T_SMALL, 2)), terminal_cost=_unicycle_terminal,
        args=args, bounds=(lo, hi),
    )
    assert sol.result == RESULTS.successful, RESULTS[sol.result]
    us = np.asarray(sol.us)
    assert np.all(us >= np.asarray(lo)) and np.all(us <= np.asarray(hi)), "us: outside the bounds"
    assert np.any(us == np.asarray(hi)) or np.any(us == np.asarray(lo)), "us: no bound active"
    assert float(sol.stats["grad_norm"]) < 1e-4  # acceptance: |dJ/du| < 1e-4 at the stop

    @jax.jit
    def total(u):
        def step(x, data):
            u_t, t = data
            return _unicycle_dynamics(x, u_t, t, args), _unicycle_cost(x, u_t, t, args)

        xT, costs = jax.lax.scan(step, x0, (u, jnp.arange(_T_SMALL)))
        return jnp.sum(costs) + _unicycle_terminal(xT, args)

    value_and_grad = jax.jit(jax.value_and_grad(lambda u: total(u.reshape(_T_SMALL, 2))))
    np.testing.assert_allclose(total(sol.us), sol.cost, rtol=1e-12, err_msg="cost")
    # Independent reference: L-BFGS-B on the single-shooting problem.
    ref = scipy_optimize.minimize(
        lambda u: tuple(np.asarray(v) for v in value_and_grad(jnp.asarray(u))),
        np.zeros(2 * _T_SMALL),
        jac=True,
        method="L-BFGS-B",
        bounds=list(zip(np.tile(np.asarray(lo), _T_SMALL), np.tile(np.asarray(hi), _T_SMALL))),
        options=dict(ftol=1e-15, gtol=1e-10, maxiter=2000),
    )
    np.testing.assert_allclose(sol.cost, ref.fun, rtol=1e-8, err_msg="cost vs L-BFGS-B")
    assert float(sol.cost) <= ref.fun + 1e-9 * abs(ref.fun)
    # Better than clipping the unconstrained optimum.
    free = _solve_unicycle(x0)
    clipped = jnp.clip(free.us, lo[None], hi[None])
    assert float(sol.cost) < float(total(clipped))


# --------------------------------------------------------------------------------------------
# A cost that is not convex in u.
# --------------------------------------------------------------------------------------------


def _nc_dynamics(x, u, t, a):
    return x + 0.1 * jnp.concatenate([u, u[:1] ** 2])


def _nc_cost(x, u, t, a):
    return 0.5 * x @ x + (u[0] ** 2 - 1.0) ** 2  # a double well in u: l_uu = -4 at u = 0


def _nc_terminal(x, a):
    return 5.0 * x @ x


_NC_T = 10
_NC_X0 = np.array([1.0, -0.5])


@jax.jit
def _nc_local_minimum_check(us):
    """``(total cost, max |gradient|, min Hessian eigenvalue)`` of the single-shooting cost at ``us``
    [T], in one program shared by both solvers (eager, the derivatives of the scan compile op by op)."""

    def total(us):
        def step(x, ut):
            return _nc_dynamics(x, ut[0], ut[1], None), _nc_cost(x, ut[0], ut[1], None)

        xT, costs = jax.lax.scan(step, jnp.asarray(_NC_X0), (us.reshape(_NC_T, 1), jnp.arange(_NC_T)))
        return jnp.sum(costs) + _nc_terminal(xT, None)

    return total(us), jnp.max(jnp.abs(jax.grad(total)(us))), jnp.min(jnp.linalg.eigvalsh(jax.hessian(total)(us)))


@pytest.mark.parametrize("name", ["ilqr", "ddp"])
def test_cost_not_convex_in_u_is_regularised(name):
    x0 = jnp.asarray(_NC_X0)
    sol = SOLVERS[name](_nc_dynamics, _nc_cost, x0, jnp.zeros((_NC_T, 1)), terminal_cost=_nc_terminal, max_steps=100)
    assert sol.result == RESULTS.successful, RESULTS[sol.result]
    assert np.all(np.isfinite(np.asarray(sol.us))) and np.isfinite(float(sol.cost))
    assert float(sol.cost) < float(sol.stats["cost_history"][0])
    # A local minimum of the single-shooting cost: zero gradient, positive-definite Hessian.
    total, grad_max, eig_min = _nc_local_minimum_check(sol.us.ravel())
    np.testing.assert_allclose(total, sol.cost, rtol=1e-12)
    assert float(grad_max) < 1e-4
    assert float(eig_min) > 0
