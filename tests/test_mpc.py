"""Tests of solvers.mpc / mpc_step: the receding-horizon controller of an LQ problem whose terminal
cost is the DARE solution is the DARE feedback (scipy), the jitted scan equals a Python loop of
warm-started mpc_step calls, vmap equals a loop, the pendulum is swung up and held, and plant=
simulates on another model (against a loop of mpc_step + that plant)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import solvers
from solvers import RESULTS, problems


def test_mpc_with_dare_terminal_cost_is_the_dare_feedback():
    # With Q_T = P (the DARE solution), the finite-horizon value is the infinite-horizon one at every
    # step, so the receding-horizon control is u = -K x exactly, K from scipy.
    scipy_linalg = pytest.importorskip("scipy.linalg")
    rng = np.random.default_rng(3)
    n, m, T = 3, 2, 8
    A = np.eye(n) + 0.2 * rng.standard_normal((n, n))
    B = rng.standard_normal((n, m))
    Q = np.diag([1.0, 0.5, 2.0])
    R = np.diag([0.3, 1.0])
    P = scipy_linalg.solve_discrete_are(A, B, Q, R)
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
    zeros = np.zeros
    lq = problems.LQProblem(
        A=jnp.broadcast_to(A, (T, n, n)), B=jnp.broadcast_to(B, (T, n, m)), Q=jnp.broadcast_to(Q, (T, n, n)),
        R=jnp.broadcast_to(R, (T, m, m)), QT=jnp.asarray(P), x0=jnp.asarray([1.0, -2.0, 0.5]),
        S=jnp.asarray(zeros((T, m, n))), q=jnp.asarray(zeros((T, n))), r=jnp.asarray(zeros((T, m))),
        qT=jnp.asarray(zeros(n)), c=jnp.asarray(zeros((T, n))), constant=jnp.asarray(0.0),
    )
    p = lq.as_control_problem()
    # Time-invariant data: the callbacks index arrays of length T at absolute times k + i >= T,
    # which JAX clamps to the last (identical) entry.
    sol = solvers.mpc(p.dynamics, p.cost, p.x0, p.us_init, steps=12, terminal_cost=p.terminal_cost, args=p.args)
    assert sol.result == RESULTS.successful
    assert np.all(np.asarray(sol.results) == RESULTS.successful._value)
    xs, us = np.asarray(sol.xs), np.asarray(sol.us)
    np.testing.assert_allclose(us, -xs[:-1] @ K.T, atol=1e-9, rtol=0, err_msg="u = -K x")
    np.testing.assert_allclose(xs[1:], xs[:-1] @ A.T + us @ B.T, atol=1e-12, rtol=0, err_msg="plant")
    # The plan cost at x_k is the DARE value 0.5 x_k' P x_k.
    np.testing.assert_allclose(sol.plan_costs, 0.5 * np.einsum("ki,ij,kj->k", xs[:-1], P, xs[:-1]), rtol=1e-9)


@pytest.fixture(scope="module")
def pendulum_mpc():
    problem = problems.pendulum(T=30)
    run = jax.jit(
        jax.vmap(
            lambda x0: solvers.mpc(
                problem.dynamics, problem.cost, x0, problem.us_init, steps=80, terminal_cost=problem.terminal_cost,
                args=problem.args, max_steps=8,
            )
        )
    )
    x0s = jnp.asarray([[0.0, 0.0], [0.4, -1.0], [-0.6, 0.5]])
    return problem, x0s, run(x0s)


def test_mpc_swings_the_pendulum_up_and_holds_it(pendulum_mpc):
    _, _, sol = pendulum_mpc
    xs = np.asarray(sol.xs)
    assert np.all(np.asarray(sol.result._value) == RESULTS.successful._value)
    assert np.all(np.abs(xs[:, -20:, 0] - np.pi) < 0.1), "not held upright over the last 20 steps"
    assert np.all(np.abs(xs[:, -1, 1]) < 0.1)
    # Warm starts: the first solve needs all 8 iterations, later ones (shifted plans) fewer.
    iters = np.asarray(sol.num_steps)
    assert np.all(iters[:, -10:] < iters[:, :1])


def test_mpc_equals_loop_of_warm_started_steps(pendulum_mpc):
    problem, x0s, batched = pendulum_mpc
    i = 1
    x, us_warm = x0s[i], problem.us_init
    for k in range(20):
        u, us_warm, plan = solvers.mpc_step(
            problem.dynamics, problem.cost, x, us_warm, k, terminal_cost=problem.terminal_cost, args=problem.args,
            max_steps=8,
        )
        np.testing.assert_allclose(u, batched.us[i, k], atol=1e-10, rtol=0, err_msg=f"step {k}: u")
        np.testing.assert_allclose(plan.cost, batched.plan_costs[i, k], rtol=1e-10, err_msg=f"step {k}: plan cost")
        np.testing.assert_allclose(us_warm[:-1], plan.us[1:], atol=0, rtol=0)
        x = problem.dynamics(x, u, k, problem.args)
        np.testing.assert_allclose(x, batched.xs[i, k + 1], atol=1e-10, rtol=0, err_msg=f"step {k}: x")


def _heavier_pendulum(x, u, t, args):
    """The plant of the model-mismatch test: the pendulum with a 30 % heavier bob (and a Python
    function of its own, so ``plant=`` is a different callable from the model's)."""
    return problems.pendulum().dynamics(x, u, t, {**args, "mass": 1.3 * args["mass"]})


def test_mpc_plant_is_a_different_model(pendulum_mpc):
    # README: `plant=` simulates the controls on a different model than the one planned with. The
    # closed loop then differs from the one without plant= (the fixture's), and equals a hand-written
    # loop of mpc_step (planning on the model) + the plant.
    problem, x0s, batched = pendulum_mpc
    i, steps = 1, 10
    sol = solvers.mpc(
        problem.dynamics, problem.cost, x0s[i], problem.us_init, steps=steps, terminal_cost=problem.terminal_cost,
        args=problem.args, plant=_heavier_pendulum, max_steps=8,
    )
    assert sol.result == RESULTS.successful
    gap = float(np.max(np.abs(np.asarray(sol.xs) - np.asarray(batched.xs[i, : steps + 1]))))
    assert gap > 1e-3, f"plant= had no effect on the closed loop (max |dx| = {gap})"
    x, us_warm = x0s[i], problem.us_init
    for k in range(steps):
        u, us_warm, _ = solvers.mpc_step(
            problem.dynamics, problem.cost, x, us_warm, k, terminal_cost=problem.terminal_cost, args=problem.args,
            max_steps=8,
        )
        np.testing.assert_allclose(u, sol.us[k], atol=1e-10, rtol=0, err_msg=f"step {k}: u")
        x = _heavier_pendulum(x, u, k, problem.args)
        np.testing.assert_allclose(x, sol.xs[k + 1], atol=1e-10, rtol=0, err_msg=f"step {k}: x")


def test_mpc_bad_input():
    problem = problems.pendulum(T=5)
    with pytest.raises(ValueError, match="steps: expected an int >= 1"):
        solvers.mpc(problem.dynamics, problem.cost, problem.x0, problem.us_init, steps=0)
    with pytest.raises(ValueError, match=r"us_init: expected shape \(T, m\)"):
        solvers.mpc(problem.dynamics, problem.cost, problem.x0, jnp.zeros(5), steps=3)
    with pytest.raises(ValueError, match="method: expected one of"):
        solvers.mpc(problem.dynamics, problem.cost, problem.x0, problem.us_init, steps=3, method="sqp")
