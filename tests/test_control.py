"""Tests of jaxanim.control and stable PD in jaxanim.physics.step: the notes' PD spring (m = 1,
k_p = 200, k_d = 20) simulated with semi-implicit Euler diverges above h = 0.0732 s with explicit PD
and above 0.273 s with the notes' stable PD, Tan's form does not, and the growth per step at
h = 0.1 is the spectral radius of the notes' analysis; an articulated chain under stable PD is
stable at 120 Hz, where explicit PD with the same gains needs 4000 Hz, and both settle to the same
pose."""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanim import JaxanimError, control, joints, physics, rigid
from jaxanim import rotations as rot

from .helpers import xla_compiles

_KP, _KD = 200.0, 20.0


@functools.lru_cache(maxsize=None)
def _spring_run():
    bodies = rigid.make_bodies([("sphere", (0.1,))], mass=[1.0], gravity=(0.0, 0.0, 0.0))

    @functools.partial(jax.jit, static_argnames=("law", "steps"))
    def run(h, law, steps):
        def body(s, _):
            x, v = s.position[0, 0], s.linear_velocity[0, 0]
            if law == "pd":
                f = control.pd_force(x, v, 0.0, _KP, _KD)
            else:
                f = control.stable_pd_force(x, v, 0.0, _KP, _KD, 1.0, h, form=law)
            s = rigid._momentum_step(bodies, s, jnp.zeros((1, 3)).at[0, 0].set(f), jnp.zeros((1, 3)), h)
            return s, jnp.stack([s.position[0, 0], s.linear_velocity[0, 0]])

        state = rigid.make_state(bodies, position=[[1.0, 0.0, 0.0]])
        return jax.lax.scan(body, state, None, length=steps)[1]

    return run


@pytest.mark.parametrize(
    "law, stable_h, unstable_h",
    [("pd", 0.072, 0.075), ("damping", 0.27, 0.28), ("full", 1.0, None)],
)
def test_pd_spring_stability_bounds(law, stable_h, unstable_h):
    run = _spring_run()
    xs = np.abs(np.asarray(run(stable_h, law, 400))[:, 0])
    assert xs[-1] < 1e-2, f"{law} at h = {stable_h}: |x| = {xs[-1]}"
    if unstable_h is not None:
        xs = np.abs(np.asarray(run(unstable_h, law, 400))[:, 0])
        assert xs[-1] > 1e2, f"{law} at h = {unstable_h}: |x| = {xs[-1]} should grow"


@pytest.mark.parametrize("law, radius", [("pd", 2.414), ("damping", 0.577), ("full", 0.447)])
def test_pd_spring_growth_per_step_is_the_spectral_radius(law, radius):
    # The simulated one-step map s_{n+1} = A s_n (fitted from the trajectory) has the spectral
    # radius of the notes' analysis at h = 0.1.
    S = np.asarray(_spring_run()(0.1, law, 12)).T  # [2, 12]: (x, v)
    A = S[:, 1:] @ np.linalg.pinv(S[:, :-1])
    np.testing.assert_allclose(np.max(np.abs(np.linalg.eigvals(A))), radius, rtol=2e-3)


@functools.lru_cache(maxsize=None)
def _chain():
    bodies = rigid.make_bodies([("box", (0.1, 0.4, 0.1))] * 3, names=("a", "b", "c"))  # 4 kg each
    state = rigid.make_state(bodies, position=[[0, -0.2, 0], [0, -0.6, 0], [0, -1.0, 0]])
    J = joints.make_joints(bodies, state, [
        dict(type="ball", parent=None, child="a", anchor=(0, 0, 0)),
        dict(type="ball", parent="a", child="b", anchor=(0, -0.4, 0)),
        dict(type="ball", parent="b", child="c", anchor=(0, -0.8, 0)),
    ])
    targets = rot.axis_angle_to_quat(jnp.asarray([[0, 0, 1.0], [1, 0, 0.0], [0, 0, 1.0]]), jnp.asarray([0.8, 0.6, -0.7]))
    return physics.make_model(bodies, J), state, targets


@functools.partial(jax.jit, static_argnames="law")
def _chain_final(model, state, targets, dt, num_steps, kp, kd, law):
    """``num_steps`` steps of ``dt`` (both traced: one compiled program per law for every run)."""

    def body(_, s):
        if law == "pd":
            tau = control.pd_joint_torques(model.joints, s, targets, kp, kd)
            return physics.step(model, s, dt, physics.Control(joint_torque=tau))
        return physics.step(model, s, dt, physics.Control(spd=physics.StablePD(targets, kp, kd)))

    return jax.lax.fori_loop(0, num_steps, body, state)


def _run_chain(dt, seconds, law, kp=300.0, kd=10.0):
    model, state, targets = _chain()
    final = _chain_final(model, state, targets, jnp.asarray(dt), jnp.asarray(int(round(seconds / dt))),
                         jnp.full(3, kp), jnp.full(3, kd), law)
    return model, final, targets


def test_articulated_stable_pd_is_stable_at_120_hz_where_pd_needs_4000_hz():
    _, spd, targets = _run_chain(1 / 120, 4.0, "spd")
    model, pd_coarse, _ = _run_chain(1 / 120, 1.0, "pd")
    _, pd_fine, _ = _run_chain(1 / 4000, 4.0, "pd")
    blown = np.asarray(pd_coarse.position)
    assert not np.all(np.abs(blown) < 1e3), "explicit PD at 120 Hz should blow up"
    assert np.all(np.isfinite(np.asarray(spd.position)))
    e_spd, w_spd = control.joint_errors(model.joints, spd, targets)
    e_pd, _ = control.joint_errors(model.joints, pd_fine, targets)
    # Both settle near the same gravity-loaded pose (gravity torque = k_p e).
    assert float(jnp.max(jnp.abs(w_spd))) < 0.1
    np.testing.assert_allclose(e_spd, e_pd, atol=0.02)
    assert 0.02 < float(jnp.max(jnp.linalg.norm(e_spd, axis=-1))) < 0.2


def test_pd_joint_torques_and_errors():
    model, state, targets = _chain()
    current = rot.quat_identity(3)
    e, w = control.joint_errors(model.joints, state, current)
    np.testing.assert_allclose(e, 0.0, atol=1e-15)
    tau = control.pd_joint_torques(model.joints, state, targets, jnp.full(3, 10.0), jnp.zeros(3))
    # The root joint's target is a rotation of 0.8 rad about z: torque 10 * 0.8 about z.
    np.testing.assert_allclose(tau[0], [0.0, 0.0, 8.0], atol=1e-12)
    clipped = control.pd_joint_torques(model.joints, state, targets, jnp.full(3, 10.0), jnp.zeros(3),
                                       max_torque=jnp.full(3, 2.0))
    np.testing.assert_allclose(jnp.linalg.norm(clipped, axis=-1), 2.0, rtol=1e-12)
    with pytest.raises(JaxanimError, match="form: expected 'damping' or 'full'"):
        control.stable_pd_force(0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 0.1, form="tan")
    with pytest.raises(JaxanimError, match=r"spd targets: expected shape \(J, 4\) = \(3, 4\)"):
        physics.step(model, state, 0.01, spd=(jnp.zeros((2, 4)), 1.0, 1.0))


def _pd_controller(state, step, args):
    model, _, targets = _chain()
    kp, kd = args
    return dict(joint_torque=control.pd_joint_torques(model.joints, state, targets, jnp.full(3, kp), jnp.full(3, kd)))


# The rollouts of the two tests below: one batch of characters under explicit PD, soft and stiff gains, 240 steps
# (2 s) recorded every 20, vmapped once, and characters of it rolled out alone with the same (unbatched) program.
# The batch is larger than ROLLOUT_LANES (one full chunk and a padded one). Sharing it saves two of the four rollout
# compilations the two tests had with their own step counts and batch sizes (~5 s of their ~11 s).
_SWEEP_STEPS, _SWEEP_EVERY = 240, 20


def _sweep_rollout(kp, kd, state=None):
    model, state0, _ = _chain()
    return physics.rollout(model, state0 if state is None else state, 1 / 120, _SWEEP_STEPS, record_every=_SWEEP_EVERY,
                           controller=_pd_controller, controller_args=(kp, kd))


@functools.lru_cache(maxsize=None)
def _gain_sweep():
    """``(kp, kd, runs)``: the vmapped rollouts; every fifth character (from index 3) stiff (k_p = 300, k_d = 10:
    unstable at 120 Hz), the others soft (k_p from 2 to 20, k_d = 0.5: stable)."""
    from jaxanim.physics._rollout import ROLLOUT_LANES

    count = ROLLOUT_LANES + 6
    kp = jnp.asarray(np.where(np.arange(count) % 5 == 3, 300.0, np.linspace(2.0, 20.0, count)))
    kd = jnp.asarray(np.where(np.arange(count) % 5 == 3, 10.0, 0.5))
    return kp, kd, jax.vmap(_sweep_rollout)(kp, kd)


def test_rollout_stops_a_blown_up_character_and_vmap_sweeps_gains():
    kp, kd, runs = _gain_sweep()
    model, state, _ = _chain()
    soft, stiff = 0, 3
    assert (float(kp[soft]), float(kd[soft]), float(kp[stiff]), float(kd[stiff])) == (2.0, 0.5, 300.0, 10.0)
    codes = np.asarray(runs.result._value)
    assert codes[soft] == physics.SimResult.successful._value and int(runs.num_steps[soft]) == _SWEEP_STEPS
    assert codes[stiff] == physics.SimResult.exploded._value and int(runs.num_steps[stiff]) < _SWEEP_STEPS
    assert np.all(np.isfinite(np.asarray(runs.final.position)))  # stopped at its last good state
    assert np.max(np.abs(np.asarray(runs.final.linear_velocity[stiff]))) <= 1e3
    for i in (soft, stiff):  # vmap = loop
        one = _sweep_rollout(kp[i], kd[i])
        assert int(one.result._value) == codes[i] and int(one.num_steps) == int(runs.num_steps[i])
        np.testing.assert_allclose(one.final.position, runs.final.position[i], atol=1e-9)
    # A NaN state is reported, not propagated.
    run = _sweep_rollout(kp[soft], kd[soft], _with_nan(state))  # the loop's compiled program above
    assert run.result == physics.SimResult.nonfinite and int(run.num_steps) == 0


def test_a_batch_past_the_rollout_chunk_equals_one_rollout_at_a_time():
    """Under ``vmap`` a batch larger than ``ROLLOUT_LANES`` runs in chunks (``solvers.lane_map``, padded at
    the end): every character keeps its own trajectory and status, in input order."""
    from jaxanim.physics._rollout import ROLLOUT_LANES

    model, state, _ = _chain()
    kp, kd, runs = _gain_sweep()
    count = kp.shape[0]
    assert count > ROLLOUT_LANES and count % ROLLOUT_LANES  # one full chunk and a padded one
    assert runs.trajectory.position.shape == (count, _SWEEP_STEPS // _SWEEP_EVERY) + state.position.shape
    codes = np.asarray(runs.result._value)
    assert 0 < np.sum(codes == physics.SimResult.exploded._value) < count
    for i in (0, 3, ROLLOUT_LANES - 1, ROLLOUT_LANES, count - 2, count - 1):
        one = _sweep_rollout(kp[i], kd[i])
        assert int(one.result._value) == codes[i] and int(one.num_steps) == int(runs.num_steps[i])
        np.testing.assert_allclose(one.trajectory.position, runs.trajectory.position[i], rtol=1e-12, atol=1e-12)


def _with_nan(state):
    return rigid.BodyState(position=state.position.at[1, 0].set(jnp.nan), orientation=state.orientation,
                           linear_velocity=state.linear_velocity, angular_velocity=state.angular_velocity,
                           time=state.time)


def test_servo_and_spd_with_zero_gains_do_nothing():
    model, state, targets = _chain()
    state = physics.step(model, state, 1 / 120)  # moving a little
    plain = physics.step(model, state, 1 / 120)
    servo = physics.step(model, state, 1 / 120, spd=(targets, 0.0, 0.0),
                         servo=(0, jnp.ones(3), jnp.asarray([1.0, 0, 0, 0]), 0.0, 0.0, 0.0, 0.0))
    for name in ("position", "orientation", "linear_velocity", "angular_velocity"):
        np.testing.assert_allclose(getattr(servo, name), getattr(plain, name), atol=1e-12, err_msg=name)


def test_control_module_dict_and_0_1_keywords_give_the_same_step():
    """A ``Control`` (with ``StablePD`` and ``Servo``), the 0.1 ``dict`` and the 0.1 keywords with
    tuples are one input: the same state to the bit."""
    model, state, targets = _chain()
    state = physics.step(model, state, 1 / 120)  # moving a little
    force = jnp.asarray([[0.0, 1.0, 0.0], [2.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    tau = jnp.asarray([[0.1, 0.0, 0.0], [0.0, 0.2, 0.0], [0.0, 0.0, 0.3]])
    spd = (targets, jnp.full(3, 50.0), 5.0)  # kd a scalar: broadcast to every joint
    servo = (0, jnp.asarray([0.0, -0.1, 0.05]), jnp.asarray([1.0, 0.1, 0, 0]), 100.0, 20.0, 30.0, 3.0)  # unnormalized q
    typed = physics.Control(force=force, joint_torque=tau, spd=physics.StablePD(*spd), servo=physics.Servo(*servo))
    runs = {
        "Control": physics.step(model, state, 1 / 120, typed),
        "dict": physics.step(model, state, 1 / 120, dict(force=force, joint_torque=tau, spd=spd, servo=servo)),
        "keywords": physics.step(model, state, 1 / 120, force=force, joint_torque=tau, spd=spd, servo=servo),
    }
    plain = physics.step(model, state, 1 / 120)
    for form, s in runs.items():
        for name in ("position", "orientation", "linear_velocity", "angular_velocity"):
            np.testing.assert_array_equal(getattr(s, name), getattr(runs["Control"], name), err_msg=f"{form}: {name}")
    assert float(jnp.max(jnp.abs(runs["Control"].linear_velocity - plain.linear_velocity))) > 1e-3  # it acted


def test_control_bad_input():
    model, state, targets = _chain()
    with pytest.raises(JaxanimError, match="control: give a Control or the keywords"):
        physics.step(model, state, 0.01, physics.Control(), force=jnp.zeros((3, 3)))
    with pytest.raises(JaxanimError, match=r"control: unknown key\(s\) \['forces'\]"):
        physics.step(model, state, 0.01, dict(forces=jnp.zeros((3, 3))))
    with pytest.raises(JaxanimError, match=r"joint_torque: expected shape \(J, 3\) = \(3, 3\)"):
        physics.step(model, state, 0.01, physics.Control(joint_torque=jnp.zeros((2, 3))))
    with pytest.raises(JaxanimError, match=r"spd targets: expected shape \(J, 4\) = \(3, 4\)"):
        physics.step(model, state, 0.01, physics.Control(spd=physics.StablePD(jnp.zeros((2, 4)), 1.0, 1.0)))
    with pytest.raises(JaxanimError, match=r"servo: body must be an int in \[0, 3\)"):
        physics.step(model, state, 0.01, physics.Control(servo=physics.Servo(3, jnp.zeros(3), targets[0], 1, 1, 1, 1)))
    with pytest.raises(JaxanimError, match=r"servo position: expected shape \(3,\)"):
        physics.step(model, state, 0.01, servo=(0, jnp.zeros(2), targets[0], 1.0, 1.0, 1.0, 1.0))
    with pytest.raises(JaxanimError, match="servo: expected Servo"):
        physics.step(model, state, 0.01, servo=(0, jnp.zeros(3)))


class _TypedPD(eqx.Module):
    """Explicit PD towards ``targets`` as a Module controller returning a ``Control`` (or, with
    ``as_dict``, the 0.1 ``dict``)."""

    targets: jax.Array
    as_dict: bool = eqx.field(static=True, default=False)

    def __call__(self, state, step, args):
        model = _chain()[0]
        kp, kd = args
        tau = control.pd_joint_torques(model.joints, state, self.targets, jnp.full(3, kp), jnp.full(3, kd))
        return dict(joint_torque=tau) if self.as_dict else physics.Control(joint_torque=tau)


def _gains(kp, kd):
    return jnp.asarray(kp), jnp.asarray(kd)  # arrays: a Python float would be static (a retrace per value)


def test_rollout_compiles_once_for_new_values_of_the_same_structure():
    """A second eager rollout with a new state, new controller arrays and new gains does not
    retrace; the 0.1 dict controller and the typed one give the same states."""
    model, state, targets = _chain()
    first = physics.rollout(model, state, 1 / 120, 24, controller=_TypedPD(targets),
                            controller_args=_gains(2.0, 0.5))
    with xla_compiles() as compiled:
        second = physics.rollout(model, first.final, 1 / 120, 24, controller=_TypedPD(targets[::-1]),
                                 controller_args=_gains(3.0, 0.6))
    assert not [c for c in compiled if "_rollout" in c], compiled
    assert float(jnp.max(jnp.abs(second.final.position - first.final.position))) > 1e-3  # new values used
    as_dict = physics.rollout(model, state, 1 / 120, 24, controller=_TypedPD(targets, as_dict=True),
                              controller_args=_gains(2.0, 0.5))
    np.testing.assert_array_equal(as_dict.trajectory.position, first.trajectory.position)
