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
    grad = np.asarray(jax.jit(jax.grad(f))(v))
    fd = _central(jax.jit(f), v, 1e-6)
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

    grad_f, value_f = jax.jit(jax.grad(f)), jax.jit(f)  # one program each for both regularizations
    for regularization in (1e-3, 1e-1):  # a nearly zero residual at the optimum, and a clearly nonzero one
        reg = jnp.asarray(regularization)
        grad = np.asarray(grad_f(goal, reg))
        fd = _central(lambda g: value_f(g, reg), goal, 1e-3)
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


def test_ilqr_solution_gradient_matches_finite_differences():
    """A damped pendulum driven towards upright, differentiated in the start state and a cost weight
    passed in ``args``: through the optimal controls, the optimal cost and the final state. The
    differences are those of the exact minimizer (iLQR's controls polished by Newton's method on
    the total cost, to rounding): iLQR's own stop leaves the controls about 1e-6 from it, which
    differences over a step of 1e-3 would magnify."""
    T, h = 30, 0.05
    w_u = jnp.linspace(1.0, 2.0, T)

    def dynamics(x, u, t, args):
        th, w = x
        return jnp.stack([th + h * w, w + h * (-9.81 * jnp.sin(th) + u[0] - 0.1 * w)])

    def cost(x, u, t, args):
        return 0.5 * args * (x[0] - jnp.pi) ** 2 * h + 0.5 * 0.1 * u[0] ** 2 * h

    def solve(p):
        return solvers.ilqr(dynamics, cost, p[:2], jnp.zeros((T, 1)), args=p[2], terminal_cost=None,
                            rtol=1e-15, atol=0.0)

    def outputs(us, xs_last, total_cost):
        return jnp.sum(us[:, 0] * w_u) + 0.3 * total_cost + jnp.sum(xs_last)

    def rollout(us, p):
        def one(x, u_t):
            return dynamics(x, u_t[0], u_t[1], p[2]), cost(x, u_t[0], u_t[1], p[2])
        x_last, c = jax.lax.scan(one, p[:2], (us.reshape(T, 1), jnp.arange(T)))
        return x_last, jnp.sum(c)

    @jax.jit
    def exact(p):
        total = lambda v: rollout(v, p)[1]  # noqa: E731
        v = solve(p).us.ravel()
        for _ in range(3):
            v = v - jnp.linalg.solve(jax.hessian(total)(v), jax.grad(total)(v))
        return outputs(v.reshape(T, 1), *rollout(v, p))

    def f(p):
        sol = solve(p)
        return outputs(sol.us, sol.xs[-1], sol.cost)

    p = jnp.array([0.3, -0.2, 2.0])
    grad = np.asarray(jax.jit(jax.grad(f))(p))
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
