"""``jax.grad`` through forward kinematics and through the IK solution matches central finite
differences (issue 12's gradient line; the DARE's is in test_lqr, a rollout's through contact in
test_physics_gradients).

The IK solution's derivative is the implicit one of the least-squares minimizer
(solvers._implicit): the loop is not differentiated. The problems have a unique minimizer (a
regularization and a fixed root translation); a solve that stops before a minimizer has a NaN
derivative.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

import jaxanim
import solvers
from jaxanim import ik

from .helpers import jitted_fk, random_pose, small_skeleton

_RTOL = 1e-5


def _central(f, x, eps, richardson=False):
    """Central differences of ``f`` at ``x``; with ``richardson``, extrapolated from the steps ``eps``
    and ``eps / 2`` (error O(eps^4) instead of O(eps^2))."""
    x = np.asarray(x, np.float64)

    def one(h):
        out = []
        for i in range(x.size):
            d = np.zeros_like(x)
            d.flat[i] = h
            out.append((float(f(jnp.asarray(x + d))) - float(f(jnp.asarray(x - d)))) / (2 * h))
        return np.array(out).reshape(x.shape)

    return (4.0 * one(eps / 2) - one(eps)) / 3.0 if richardson else one(eps)


def test_fk_gradient_matches_finite_differences():
    skel = small_skeleton()
    q, t = random_pose(skel, 3)
    w = jnp.linspace(-1.0, 2.0, 3 * skel.num_joints).reshape(skel.num_joints, 3)

    def f(rotvecs):
        out = jaxanim.forward_kinematics(skel, jaxanim.rotations.rotvec_to_quat(rotvecs), t)
        return jnp.sum(out.positions * w) + jnp.sum(out.end_site_positions ** 2) + jnp.sum(out.rotations[:, 0, 1])

    v = jaxanim.rotations.quat_to_rotvec(q)
    value_and_grad = jax.jit(jax.value_and_grad(f))  # one program: the differences use its values
    grad = np.asarray(value_and_grad(v)[1])
    fd = _central(lambda x: value_and_grad(x)[0], v, 1e-6)
    np.testing.assert_allclose(grad, fd, rtol=_RTOL, atol=1e-8)


def test_ik_solution_gradient_matches_finite_differences():
    """As users call ``solve_ik``: the default solver and stopping rule (``stop_at_tolerance``), a
    regularization (the minimizer is unique), plain central differences of step 1e-3."""
    skel = small_skeleton()
    q0, t0 = random_pose(skel, 0)
    goal = jitted_fk(skel, random_pose(skel, 1)[0], t0).end_site_positions[0]  # one program, not op by op
    weights = jnp.arange(q0.size, dtype=q0.dtype).reshape(q0.shape) / 10.0

    def f(g, regularization):
        sol = ik.solve_ik(skel, ik.Target(skel.end_site_names[0], position=g), q0, t0,
                          regularization=regularization, root_translation="fixed")
        return jnp.sum(sol.rotations * weights)

    # one program for both regularizations, the derivative and the differences (its values): a
    # separate forward program took 1.1 s more to compile (suite baseline)
    value_and_grad = jax.jit(jax.value_and_grad(f))
    for regularization in (1e-3, 1e-1):  # a nearly zero residual at the optimum, and a clearly nonzero one
        reg = jnp.asarray(regularization)
        grad = np.asarray(value_and_grad(goal, reg)[1])
        fd = _central(lambda g: value_and_grad(g, reg)[0], goal, 1e-3)
        assert np.abs(fd).max() > 1e-2  # the solution does depend on the target
        np.testing.assert_allclose(grad, fd, rtol=_RTOL, atol=1e-8, err_msg=f"regularization {regularization}")


def test_ik_stopped_at_its_tolerance_has_a_nan_derivative():
    """Without a regularization the targets are met (``stop_at_tolerance``) before any minimizer is
    reached: ``stats["stopped_early"]`` says so and the derivative is NaN, not the minimizer's."""
    skel = small_skeleton()
    q0, t0 = random_pose(skel, 0)
    goal = jitted_fk(skel, random_pose(skel, 1)[0], t0).end_site_positions[0]

    def f(g, stop):
        sol = ik.solve_ik(skel, ik.Target(skel.end_site_names[0], position=g), q0, t0, stop_at_tolerance=stop,
                          root_translation="fixed")
        return jnp.sum(sol.rotations[:, 1:]), sol

    def solve_and_grad(stop):  # one program each: the solution (the forward pass) and the derivative
        (_, sol), grad = jax.jit(jax.value_and_grad(lambda g: f(g, stop), has_aux=True))(goal)
        return sol, np.asarray(grad)

    sol, grad = solve_and_grad(True)
    assert bool(sol.success) and bool(sol.stats["stopped_early"])
    assert np.isnan(grad).all()
    # run to the solver's own criterion the minimizer (not unique) gets a finite, minimum-norm derivative
    sol, grad = solve_and_grad(False)
    assert not bool(sol.stats["stopped_early"])
    assert np.isfinite(grad).all()


# A damped pendulum driven towards upright: iLQR's derivative in the start state and a cost weight
# (``p = [theta0, omega0, weight]``), the weight passed in ``args``.
_PEND_T, _PEND_H = 30, 0.05
_PEND_W_U = np.linspace(1.0, 2.0, _PEND_T)


def _pendulum_dynamics(x, u, t, args):
    th, w = x
    return jnp.stack([th + _PEND_H * w, w + _PEND_H * (-9.81 * jnp.sin(th) + u[0] - 0.1 * w)])


def _pendulum_cost(x, u, t, args):
    return 0.5 * args * (x[0] - jnp.pi) ** 2 * _PEND_H + 0.5 * 0.1 * u[0] ** 2 * _PEND_H


def _pendulum_solve(p, max_steps=100):
    return solvers.ilqr(_pendulum_dynamics, _pendulum_cost, p[:2], jnp.zeros((_PEND_T, 1)), args=p[2],
                        terminal_cost=None, rtol=1e-15, atol=0.0, max_steps=max_steps)


def _pendulum_outputs(us, xs_last, total_cost):
    return jnp.sum(us[:, 0] * _PEND_W_U) + 0.3 * total_cost + jnp.sum(xs_last)


def _pendulum_f(p, max_steps=100):
    sol = _pendulum_solve(p, max_steps)
    return _pendulum_outputs(sol.us, sol.xs[-1], sol.cost)


# one program per max_steps, shared by the two tests below
_pendulum_grad = jax.jit(jax.grad(_pendulum_f), static_argnums=1)
_PEND_P = np.array([0.3, -0.2, 2.0])


def test_ilqr_solution_gradient_matches_finite_differences():
    """Through the optimal controls, the optimal cost and the final state of the pendulum. The
    differences are those of the exact minimizer (iLQR's controls polished by Newton's method on
    the total cost, to rounding): iLQR's own stop leaves the controls about 1e-6 from it, which
    differences over a step of 1e-3 would magnify."""
    T = _PEND_T

    def rollout(us, p):
        def one(x, u_t):
            return _pendulum_dynamics(x, u_t[0], u_t[1], p[2]), _pendulum_cost(x, u_t[0], u_t[1], p[2])
        x_last, c = jax.lax.scan(one, p[:2], (us.reshape(T, 1), jnp.arange(T)))
        return x_last, jnp.sum(c)

    @jax.jit
    def exact(p):
        total = lambda v: rollout(v, p)[1]  # noqa: E731
        v = _pendulum_solve(p).us.ravel()
        for _ in range(3):
            v = v - jnp.linalg.solve(jax.hessian(total)(v), jax.grad(total)(v))
        return _pendulum_outputs(v.reshape(T, 1), *rollout(v, p))

    p = jnp.asarray(_PEND_P)
    grad = np.asarray(_pendulum_grad(p, 100))
    fd = _central(exact, p, 1e-3, richardson=True)
    assert np.abs(fd).min() > 1e-3
    np.testing.assert_allclose(grad, fd, rtol=_RTOL, atol=1e-8)


def test_a_solve_that_did_not_converge_has_a_nan_derivative():
    """The implicit derivative holds only at a minimizer: a least-squares solve or an iLQR that ran out
    of steps gives NaN, never a plausible number; the same solves converged give finite ones."""

    def residual(y, a):
        return jnp.stack([y[0] ** 2 - a, 10.0 * (y[1] - y[0] ** 2), jnp.sin(y[0] * y[1])])

    def ls(a, steps):
        sol = solvers.least_squares(residual, solvers.LevenbergMarquardt(max_steps=steps), jnp.array([3.0, -2.0]), a)
        return sol.value[0], sol.result

    for steps, ok in ((2, False), (200, True)):
        # the result comes with the derivative (one program per max_steps, no separate forward one)
        (_, result), g = jax.value_and_grad(lambda a: ls(a, steps), has_aux=True)(2.0)
        assert (result == solvers.RESULTS.successful) == ok
        assert np.isfinite(float(g)) == ok, (steps, g)

    # the pendulum of test_ilqr_solution_gradient_matches_finite_differences: one iteration does not
    # converge; run to convergence (the program of that test) every derivative is finite
    p = jnp.asarray(_PEND_P)
    for steps, ok in ((1, False), (100, True)):
        g = np.asarray(_pendulum_grad(p, steps))
        assert (np.isnan(g).all() if not ok else np.isfinite(g).all()), (steps, g)
