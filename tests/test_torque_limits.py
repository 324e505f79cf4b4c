"""Tests of the stable-PD torque limit (``StablePD.torque_limit``) in jaxanim.physics.step: against the
analytic spin-up of a sphere held at its center (a saturated joint applies exactly its bound), the
unbounded step (a bound no torque reaches changes nothing), and explicit PD with clipped torques at
4000 Hz (the continuous law the bounded stable PD discretizes); a batch of steps, whose limit passes run only on the
rows that need them, against the same steps one by one."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanim import JaxanimError, control, joints, physics, rigid
from jaxanim import rotations as rot

_R, _MASS = 0.1, 2.0


def _step_and_torques(model, state, spd, h):
    """``(physics.step(model, state, h, spd=spd), physics.spd_torques(...))`` from one solve (the
    public pair would solve twice, doubling these tests' compile time)."""
    return physics._step.step_and_torques(model, state, physics._step.control_for(model, spd=spd), h)


@functools.lru_cache(maxsize=None)
def _sphere():
    """One sphere on a ball joint to the world at its own center, no gravity: only its rotation moves."""
    bodies = rigid.make_bodies([("sphere", (_R,))], mass=[_MASS], gravity=(0.0, 0.0, 0.0))
    state = rigid.make_state(bodies, position=[[0.0, 1.0, 0.0]])
    J = joints.make_joints(bodies, state, [dict(type="ball", parent=None, child=0, anchor=(0.0, 1.0, 0.0))])
    return physics.make_model(bodies, J), state


@functools.partial(jax.jit, static_argnames="steps")
def _spin(model, state, spd, h, steps):
    def body(s, _):
        s_next, tau = _step_and_torques(model, s, spd, h)
        return s_next, (s.angular_velocity[0], tau[0])

    return jax.lax.scan(body, state, None, length=steps)[1]


def test_a_saturated_joint_applies_exactly_its_bound():
    """Target 2 rad about z, k_p = 1000: the implicit torque (~ k_p e / (1 + h k_d / I) >> 0.5 N m)
    is clipped to 0.5 N m about z, so the sphere spins up at exactly tau / I per second."""
    model, state = _sphere()
    inertia = 0.4 * _MASS * _R**2
    h, limit, steps = 0.01, 0.5, 20
    target = rot.axis_angle_to_quat(jnp.asarray([[0.0, 0.0, 1.0]]), jnp.asarray([2.0]))
    spd = physics.StablePD(target, jnp.asarray([1000.0]), jnp.asarray([10.0]), jnp.asarray([limit]))
    w, tau = _spin(model, state, spd, jnp.asarray(h), steps)
    n = np.arange(steps)
    np.testing.assert_allclose(w[:, 2], n * h * limit / inertia, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(w[:, :2], 0.0, atol=1e-12)
    np.testing.assert_allclose(tau, np.tile([0.0, 0.0, limit], (steps, 1)), atol=1e-9)
    # unbounded, the same stable PD applies far more (the public function)
    free = physics.spd_torques(model, state, h, spd=(target, 1000.0, 10.0))
    assert float(free[0, 2]) > 50 * limit
    np.testing.assert_allclose(physics.spd_torques(model, state, h, spd=spd), [[0.0, 0.0, limit]], atol=1e-9)


@functools.lru_cache(maxsize=None)
def _chain():
    bodies = rigid.make_bodies([("box", (0.1, 0.4, 0.1))] * 3, names=("a", "b", "c"))  # 4 kg each, gravity -y
    state = rigid.make_state(bodies, position=[[0, -0.2, 0], [0, -0.6, 0], [0, -1.0, 0]])
    J = joints.make_joints(bodies, state, [
        dict(type="ball", parent=None, child="a", anchor=(0, 0, 0)),
        dict(type="ball", parent="a", child="b", anchor=(0, -0.4, 0)),
        dict(type="ball", parent="b", child="c", anchor=(0, -0.8, 0)),
    ])
    targets = rot.axis_angle_to_quat(jnp.asarray([[0, 0, 1.0], [1, 0, 0.0], [0, 0, 1.0]]), jnp.asarray([1.2, 0.6, -0.7]))
    return physics.make_model(bodies, J), state, targets


@functools.partial(jax.jit, static_argnames="law")
def _chain_run(model, state, targets, kp, kd, limit, h, n, law):
    """Ten samples ``n`` steps apart of the bodies' orientations (``[10, 3, 4]``, the first at t = 0)
    and the largest torque norm per joint over the run, under bounded stable PD or clipped
    explicit PD (``h`` and ``n`` traced: one program per law for every rate)."""

    def one(s, peak):
        if law == "pd":
            tau = control.pd_joint_torques(model.joints, s, targets, kp, kd, max_torque=limit)
            s_next = physics.step(model, s, h, joint_torque=tau)
        else:
            s_next, tau = _step_and_torques(model, s, physics.StablePD(targets, kp, kd, limit), h)
        return s_next, jnp.maximum(peak, jnp.linalg.norm(tau, axis=-1))

    def sample(carry, _):
        s, peak = carry
        return jax.lax.fori_loop(0, n, lambda _, c: one(*c), (s, peak)), s.orientation

    (_, peak), q = jax.lax.scan(sample, (state, jnp.zeros(3)), None, length=10)
    return q, peak


def _chain_args(limit):
    model, state, targets = _chain()
    return model, state, targets, jnp.full(3, 300.0), jnp.full(3, 10.0), jnp.asarray(limit)


def test_a_bound_no_torque_reaches_changes_nothing():
    model, state, targets, kp, kd, _ = _chain_args(0.0)
    state = physics.step(model, state, 1 / 120, spd=(targets, kp, kd))  # moving
    bounded = physics.step(model, state, 1 / 120, spd=(targets, kp, kd, jnp.full(3, 1e6)))
    free = physics.step(model, state, 1 / 120, spd=(targets, kp, kd))
    for name in ("position", "orientation", "linear_velocity", "angular_velocity"):
        np.testing.assert_allclose(getattr(bounded, name), getattr(free, name), rtol=1e-12, atol=1e-12, err_msg=name)
    inf = physics.step(model, state, 1 / 120, spd=(targets, kp, kd, jnp.inf))
    np.testing.assert_allclose(inf.angular_velocity, free.angular_velocity, rtol=1e-12, atol=1e-12)


def test_a_batch_of_bounded_steps_equals_the_steps_one_by_one():
    """Under vmap the limit passes run only on the chains where a torque exceeds its bound
    (``solvers.repeat_while``: the unbounded step on all of them, the passes on 8 lanes): 160 chains,
    5 of them with bounds that bind, step for step the same states and torques as each chain stepped
    alone."""
    model, state, targets, kp, kd, _ = _chain_args(0.0)
    binding = jnp.asarray([20.0, 25.0, 30.0, 5.0, 40.0])
    limits = jnp.full((160, 3), 1e4).at[jnp.asarray([1, 40, 90, 130, 159]), 0].set(binding)

    @jax.jit
    def one(limit):
        s, tau = _step_and_torques(model, state, physics.StablePD(targets, kp, kd, limit), 1 / 120)
        return s.angular_velocity, tau

    w, tau = jax.jit(jax.vmap(one))(limits)
    norms = np.linalg.norm(np.asarray(tau), axis=-1)
    assert np.sum(np.any(norms >= np.asarray(limits) * (1 - 1e-9), axis=1)) == 5  # the five rows saturated
    for i in range(160):
        w_i, tau_i = one(limits[i])
        np.testing.assert_allclose(np.asarray(w[i]), np.asarray(w_i), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(np.asarray(tau[i]), np.asarray(tau_i), rtol=1e-12, atol=1e-12)


def _run(limit, rate, law="spd"):
    return _chain_run(*_chain_args(limit), jnp.asarray(1.0 / rate), jnp.asarray(rate // 10), law)


def test_bounded_stable_pd_stays_within_its_bounds_at_120_hz():
    """The top joint's 25 N m (below the ~55 N m that holding the chain at 1.2 rad takes) saturates
    and the others' 40 N m bind at the start: every torque applied stays within its bound."""
    limit = np.asarray([25.0, 40.0, 40.0])
    peak = np.asarray(_run(limit, 120)[1])
    assert np.all(peak <= limit * (1 + 1e-9)), peak
    assert peak[0] == pytest.approx(25.0, rel=1e-9)  # saturated, at the bound
    # np.full, not jnp.full: a weakly typed bound would compile the rollout a second time (2.8 s)
    assert np.all(np.asarray(_run(np.full(3, np.inf), 120)[1]) > 2 * limit)  # the bounds mattered


def test_bounded_stable_pd_converges_to_clipped_explicit_pd():
    """The law both discretize is tau = clip(k_p e - k_d w, 40 N m) on the top joint: the bounded
    stable PD's angle error to explicit PD at 8000 Hz (which starts at ~200 N m and saturates for
    the first 0.5 s) falls with the step, as a first-order method's does."""
    limit = jnp.asarray([40.0, jnp.inf, jnp.inf])
    q_ref = _run(limit, 8000, "pd")[0]  # t = 0, 0.1, ..., 0.9 s
    errors = [float(jnp.max(rot.quat_distance(_run(limit, rate)[0], q_ref))) for rate in (1000, 4000)]
    assert errors[1] < 0.1, errors
    assert errors[1] < 0.5 * errors[0], errors


def test_torque_limit_bad_input():
    model, state, targets, kp, kd, _ = _chain_args(0.0)
    with pytest.raises(JaxanimError, match="spd torque_limit: expected non-negative"):
        physics.step(model, state, 0.01, spd=(targets, kp, kd, -1.0))
    with pytest.raises(JaxanimError, match=r"spd torque_limit: expected a scalar or shape \(3,\)"):
        physics.step(model, state, 0.01, spd=(targets, kp, kd, jnp.ones(2)))
    with pytest.raises(JaxanimError, match=r"spd kp: expected a scalar or shape \(3,\)"):
        physics.step(model, state, 0.01, spd=(targets, jnp.ones(4), kd))
