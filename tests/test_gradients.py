"""``jax.grad`` through forward kinematics and through the IK solution matches central finite
differences (issue 12's gradient line; the DARE's is in test_lqr, a rollout's through contact in
test_physics_gradients).

The IK solution's derivative is the implicit one of the least-squares minimizer
(solvers._implicit): the loop is not differentiated. The problems have a unique minimizer (a
regularization and a fixed root translation), and the solves run to a tight tolerance so that the
finite differences (steps 1e-3 and 5e-4, Richardson-extrapolated) resolve the solution's change.
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
    grad = np.asarray(jax.jit(jax.grad(f))(v))
    fd = _central(jax.jit(f), v, 1e-6)
    np.testing.assert_allclose(grad, fd, rtol=_RTOL, atol=1e-8)


def test_ik_solution_gradient_matches_finite_differences():
    skel = small_skeleton()
    q0, t0 = random_pose(skel, 0)
    goal = jitted_fk(skel, random_pose(skel, 1)[0], t0).end_site_positions[0]  # one program, not op by op
    weights = jnp.arange(q0.size, dtype=q0.dtype).reshape(q0.shape) / 10.0
    solver = solvers.LevenbergMarquardt(rtol=1e-13, atol=1e-15, max_steps=200)

    def f(g, regularization):
        sol = ik.solve_ik(skel, ik.Target(skel.end_site_names[0], position=g), q0, t0, solver=solver,
                          regularization=regularization, stop_at_tolerance=False, root_translation="fixed")
        return jnp.sum(sol.rotations * weights)

    grad_f, value_f = jax.jit(jax.grad(f)), jax.jit(f)  # one program each for both regularizations
    for regularization in (1e-3, 1e-1):  # a nearly zero residual at the optimum, and a clearly nonzero one
        reg = jnp.asarray(regularization)
        grad = np.asarray(grad_f(goal, reg))
        # step 1e-2 (Richardson: truncation O(eps^4)): the solves stop about 1e-9 from the optimum
        # along the weakly regularized directions, differently in each program's rounding, and the
        # differences divide that by the step (1e-3 left 1.5e-5 relative, 1e-2 leaves 2e-6)
        fd = _central(lambda g: value_f(g, reg), goal, 1e-2, richardson=True)
        assert np.abs(fd).max() > 1e-2  # the solution does depend on the target
        np.testing.assert_allclose(grad, fd, rtol=_RTOL, atol=1e-8, err_msg=f"regularization {regularization}")


def test_ilqr_solution_gradient_matches_finite_differences():
    """A damped pendulum driven towards upright, differentiated in the start state and a cost weight
    passed in ``args``: through the optimal controls, the optimal cost and the final state."""
    T, h = 30, 0.05

    def dynamics(x, u, t, args):
        th, w = x
        return jnp.stack([th + h * w, w + h * (-9.81 * jnp.sin(th) + u[0] - 0.1 * w)])

    def cost(x, u, t, args):
        return 0.5 * args * (x[0] - jnp.pi) ** 2 * h + 0.5 * 0.1 * u[0] ** 2 * h

    def f(p):
        sol = solvers.ilqr(dynamics, cost, p[:2], jnp.zeros((T, 1)), args=p[2], terminal_cost=None, rtol=1e-14)
        return jnp.sum(sol.us[:, 0] * jnp.linspace(1.0, 2.0, T)) + 0.3 * sol.cost + jnp.sum(sol.xs[-1])

    p = jnp.array([0.3, -0.2, 2.0])
    grad = np.asarray(jax.jit(jax.grad(f))(p))
    fd = _central(jax.jit(f), p, 1e-3, richardson=True)
    assert np.abs(fd).min() > 1e-3
    # iLQR stops on the predicted decrease (< 16 eps J), which leaves the controls ~1e-7 from the
    # optimum: over steps of 1e-3 that is ~1e-4 of noise in the differences, hence 1e-3 here
    np.testing.assert_allclose(grad, fd, rtol=1e-3, atol=1e-8)


def test_a_solve_that_did_not_converge_has_a_nan_derivative():
    """The implicit derivative holds only at a minimizer: a least-squares solve or an iLQR that ran out
    of steps gives NaN, never a plausible number; the same solves converged give finite ones."""

    def residual(y, a):
        return jnp.stack([y[0] ** 2 - a, 10.0 * (y[1] - y[0] ** 2), jnp.sin(y[0] * y[1])])

    def ls(a, steps):
        sol = solvers.least_squares(residual, solvers.LevenbergMarquardt(max_steps=steps), jnp.array([3.0, -2.0]), a)
        return sol.value[0], sol.result

    for steps, ok in ((2, False), (200, True)):
        _, result = ls(2.0, steps)
        assert (result == solvers.RESULTS.successful) == ok
        g = jax.grad(lambda a: ls(a, steps)[0])(2.0)
        assert np.isfinite(float(g)) == ok, (steps, g)

    def dynamics(x, u, t, args):
        return jnp.stack([x[0] + 0.05 * x[1], x[1] + 0.05 * (-9.81 * jnp.sin(x[0]) + u[0])])

    def cost(x, u, t, args):
        return 0.5 * args * (x[0] - jnp.pi) ** 2 + 0.05 * u[0] ** 2

    for steps, ok in ((1, False), (500, True)):
        def f(w, steps=steps):
            return jnp.sum(solvers.ilqr(dynamics, cost, jnp.array([0.3, 0.0]), jnp.zeros((30, 1)), args=w,
                                        max_steps=steps).us)
        g = jax.grad(f)(2.0)
        assert np.isfinite(float(g)) == ok, (steps, g)
