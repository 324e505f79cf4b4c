"""Tests of solvers.problems: the swing-ups reach their goals (issue 4's acceptance), box-DDP against
clipping, the PD-servo tracking LQ problem against a dense least-squares solve of the notes'
equations, and bad input."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import solvers
from solvers import RESULTS, problems

_GRAD_TOL = 1e-4  # acceptance: every swing-up stops with |dJ/du|_inf below this
_ACROBOT_TERMINAL_ERROR = 0.01  # |x_T - goal| of the acrobot swing-up; the README claims ~0.007
_SWING_UP_STEPS = {"acrobot": 200, "pendulum": 100, "cart_pole": 300}


def _solve(name: str, method: str):
    problem = getattr(problems, name)()
    return problem, problem.solve(method, max_steps=_SWING_UP_STEPS[name])


@pytest.mark.parametrize("method", ["ilqr", "ddp"])
def test_acrobot_swing_up(method):
    # Sutton / Gym acrobot, Euler dt = 0.1, T = 50, weights 0.1 / 0.01 / 1000 (each with 1/2), from rest
    # hanging down with zero controls: the terminal state is within 0.01 of [pi, 0, 0, 0] (the README
    # says ~0.007: 0.00721 for both methods).
    problem, sol = _solve("acrobot", method)
    assert sol.result == RESULTS.successful, RESULTS[sol.result]
    err = float(jnp.linalg.norm(sol.xs[-1] - problem.goal))
    assert err < _ACROBOT_TERMINAL_ERROR, f"{method}: terminal error {err}"
    assert float(sol.stats["grad_norm"]) < _GRAD_TOL
    _, cost = problem.rollout(sol.us)
    np.testing.assert_allclose(cost, sol.cost, rtol=1e-12)


@pytest.mark.parametrize("method", ["ilqr", "ddp"])
@pytest.mark.parametrize("name, angle", [("pendulum", 0), ("cart_pole", 1)])
def test_swing_up_reaches_upright(name, angle, method):
    problem, sol = _solve(name, method)
    assert sol.result == RESULTS.successful, RESULTS[sol.result]
    assert abs(float(sol.xs[-1, angle]) - np.pi) < 0.1, f"{name}/{method}: final angle {float(sol.xs[-1, angle])}"
    assert float(sol.stats["grad_norm"]) < _GRAD_TOL
    hist = np.asarray(sol.stats["cost_history"])
    assert np.all(np.diff(hist) <= 1e-12 * hist[0]), "cost_history: increased"


def test_box_ddp_pendulum_pumps_within_bounds():
    # 3 N m is less than the m g l = 9.81 N m needed to hold the pendulum horizontal: the bounded
    # solution has to pump energy, which clipping the unconstrained solution does not do.
    u_max = 3.0
    problem = problems.pendulum(u_max=u_max)
    sol = problem.solve("ddp", max_steps=100)
    assert sol.result == RESULTS.successful, RESULTS[sol.result]
    us = np.asarray(sol.us)
    assert np.all(np.abs(us) <= u_max), "us: outside the bounds"
    assert np.sum(np.abs(us) == u_max) >= 5, "us: the bounds should be active"
    assert abs(float(sol.xs[-1, 0]) - np.pi) < 0.1
    assert float(sol.stats["grad_norm"]) < _GRAD_TOL
    free = problem.solve("ddp", max_steps=100, bounded=False)
    assert free.result == RESULTS.successful
    assert np.max(np.abs(np.asarray(free.us))) > u_max, "the unconstrained solution should exceed the bound"
    _, clipped_cost = problem.rollout(jnp.clip(free.us, -u_max, u_max))
    assert float(sol.cost) < 0.5 * float(clipped_cost)


def _servo_dense_solution(T, h, kp, kd, w, x0):
    """Minimize the notes' eq. 7.7 directly: simulate the update equations for unit controls
    (the problem is linear in the controls) and solve the least-squares problem with numpy."""

    def simulate(xbar):
        x, v = x0
        xs = [x]
        for n in range(T):
            v = v + h * (kp * (xbar[n] - x) - kd * v)
            x = x + h * v
            xs.append(x)
        return np.asarray(xs)

    base = simulate(np.zeros(T))
    M = np.stack([simulate(np.eye(T)[j]) - base for j in range(T)], axis=1)  # [T+1, T]
    target = np.sin(h * np.arange(T + 1))
    A = np.vstack([M, np.sqrt(w) * np.eye(T)])
    b = np.concatenate([target - base, np.zeros(T)])
    xbar = np.linalg.lstsq(A, b, rcond=None)[0]
    xs = simulate(xbar)
    return xbar, xs, np.sum((target - xs) ** 2) + w * np.sum(xbar**2)


def test_pd_servo_tracking_lqr_equals_dense_solve_and_one_ilqr_iteration():
    T, h, kp, kd, w, x0 = 60, 0.05, 100.0, 20.0, 1.0, (0.3, -0.2)
    lq = problems.pd_servo_tracking(T=T, h=h, kp=kp, kd=kd, w=w, x0=x0)
    sol = lq.solve()
    assert sol.result == RESULTS.successful
    xbar, xs, cost = _servo_dense_solution(T, h, kp, kd, w, x0)
    np.testing.assert_allclose(sol.us[:, 0], xbar, atol=1e-9, rtol=0, err_msg="controls vs dense solve")
    np.testing.assert_allclose(sol.xs[:, 0], xs, atol=1e-9, rtol=0, err_msg="positions vs dense solve")
    np.testing.assert_allclose(sol.cost + lq.constant, cost, rtol=1e-10, err_msg="cost vs dense solve")
    # One iLQR iteration on the same problem (the second only confirms convergence).
    it = lq.as_control_problem().solve("ilqr", max_steps=1)
    np.testing.assert_allclose(it.us, sol.us, atol=1e-9, rtol=0, err_msg="one iLQR iteration")
    np.testing.assert_allclose(it.cost, cost, rtol=1e-10, err_msg="iLQR cost (constant included)")


def test_double_integrator_is_solved_in_one_iteration():
    problem = problems.double_integrator(dim=2, T=30, x0=(1.0, -0.5, 0.0, 0.2))
    sol = problem.solve("ilqr")
    assert sol.result == RESULTS.successful
    assert int(sol.stats["num_steps"]) == 2  # one step, one confirmation
    dt = 0.1
    A1 = np.array([[1.0, dt], [0.0, 1.0]])
    B1 = np.array([[0.5 * dt**2], [dt]])
    # Coordinates ordered [p1, p2, v1, v2]: build the 4x4 system from the 1-D one.
    P = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], float)  # [p1 v1 p2 v2] -> [p1 p2 v1 v2]
    A = P @ np.kron(np.eye(2), A1) @ P.T
    B = P @ np.kron(np.eye(2), B1)
    T = 30
    ref = solvers.lqr(
        np.broadcast_to(A, (T, 4, 4)), np.broadcast_to(B, (T, 4, 2)), np.broadcast_to(np.eye(4), (T, 4, 4)),
        np.broadcast_to(0.1 * np.eye(2), (T, 2, 2)), 100.0 * np.eye(4), np.array([1.0, -0.5, 0.0, 0.2]),
    )
    np.testing.assert_allclose(sol.us, ref.us, atol=1e-10, rtol=0)
    np.testing.assert_allclose(sol.cost, ref.cost, rtol=1e-12)


def test_bad_input():
    with pytest.raises(ValueError, match="T: expected an int >= 1"):
        problems.pendulum(T=0)
    with pytest.raises(ValueError, match="mass: expected > 0"):
        problems.pendulum(mass=-1.0)
    with pytest.raises(ValueError, match="damping: expected >= 0"):
        problems.pendulum(damping=-0.1)
    with pytest.raises(ValueError, match=r"x0: expected a scalar or shape \(4,\)"):
        problems.cart_pole(x0=(0.0, 1.0))
    with pytest.raises(ValueError, match=r"us_init: expected shape \(T, m\) = \(50, 1\)"):
        problems.acrobot(us_init=np.zeros((50, 2)))
    with pytest.raises(ValueError, match="u_max: expected > 0"):
        problems.unicycle(u_max=(1.0, 0.0))
    with pytest.raises(ValueError, match="method: expected one of"):
        problems.unicycle().solve("newton")
