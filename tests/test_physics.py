"""Tests of jaxanim.joints / jaxanim.physics: a double pendulum of capsules with ball joints (drift,
energy, first-order convergence to MuJoCo on the exported MJCF), a chain with every joint type
against MuJoCo, internal joint torques conserving momentum, vmap against a loop, and bad input."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanim import JaxanimError, _linalg, joints, physics, rigid
from jaxanim import rotations as rot

_DRIFT_TOL = 1e-4  # acceptance: joint separation over 10 s at dt = 1/600, meters
_R, _L = 0.05, 0.4  # capsule radius and cap-center distance
_HALF = _L / 2 + _R  # center to tip


def _capsule_toward(direction):
    return rot.rotation_between(jnp.array([0.0, 0.0, 1.0]), jnp.asarray(direction, float))


@functools.lru_cache(maxsize=None)
def _double_pendulum():
    bodies = rigid.make_bodies([("capsule", (_R, _L)), ("capsule", (_R, _L))], names=("upper", "lower"))
    d1 = np.array([np.sin(0.6), -np.cos(0.6), 0.0])
    d2 = np.array([0.0, -np.cos(0.5), np.sin(0.5)])  # out of the first link's plane: 3-D motion
    elbow = 2 * _HALF * d1
    state = rigid.make_state(
        bodies, position=np.stack([_HALF * d1, elbow + _HALF * d2]),
        orientation=jnp.stack([_capsule_toward(d1), _capsule_toward(d2)]),
    )
    J = joints.make_joints(bodies, state, [
        dict(name="shoulder", type="ball", parent=None, child="upper", anchor=(0.0, 0.0, 0.0)),
        dict(name="elbow", type="ball", parent="upper", child="lower", anchor=elbow),
    ])
    return physics.make_model(bodies, J), state


@jax.jit
def _energies(model, traj):
    return jax.vmap(lambda s: rigid.kinetic_energy(model.bodies, s) + rigid.potential_energy(model.bodies, s))(traj)


@jax.jit
def _joint_errors(model, traj):
    return jax.vmap(lambda s: physics.joint_error(model, s))(traj)


def _energy(model, traj):
    return np.asarray(_energies(model, traj))  # one compiled program (an eager vmap compiles op by op)


# The 10 s run's rollout (6000 steps of 1/600 s, a record every 10): the convergence test reads its
# records at 1 s for three steps (dt is traced), so one compiled rollout serves all the pendulum runs.
_STEPS, _EVERY = 6000, 10


def _mujoco_positions(model, state, dt, seconds):
    mujoco = pytest.importorskip("mujoco")
    m = mujoco.MjModel.from_xml_string(physics.to_mjcf(model, state, dt=dt))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    np.testing.assert_allclose(d.xpos[1:], state.position, atol=1e-12, err_msg="MJCF: initial body positions")
    np.testing.assert_allclose(np.abs(np.sum(d.xquat[1:] * np.asarray(state.orientation), axis=1)), 1.0, atol=1e-12,
                               err_msg="MJCF: initial body orientations")
    for _ in range(int(round(seconds / dt))):
        mujoco.mj_step(m, d)
    return d.xpos[1:].copy()


def test_double_pendulum_drift_and_energy_over_10_s():
    model, state = _double_pendulum()
    dt = 1 / 600
    run = physics.rollout(model, state, dt, _STEPS, record_every=_EVERY)
    assert run.result == physics.SimResult.successful and int(run.num_steps) == 6000
    traj = run.trajectory
    drift = np.asarray(_joint_errors(model, traj))
    assert drift.max() < _DRIFT_TOL, f"joint separation {drift.max():.2e} m"
    E = _energy(model, traj)
    E0 = float(rigid.kinetic_energy(model.bodies, state) + rigid.potential_energy(model.bodies, state))
    scale = float(np.sum(model.bodies.mass)) * 9.81 * 2 * _HALF  # m g (size): the energy being exchanged
    # The scheme is first order and not symplectic with constraints: the energy stays within a few
    # percent of the exchanged energy (no blow-up), and decays rather than grows.
    assert np.max(np.abs(E - E0)) < 0.05 * scale
    assert E[-1] <= E0 + 1e-3 * scale


def test_double_pendulum_converges_to_mujoco_at_first_order():
    model, state = _double_pendulum()
    seconds = 1.0
    ref = _mujoco_positions(model, state, 1 / 19200, seconds)
    errors = []
    for dt in (1 / 300, 1 / 600, 1 / 1200):
        n = int(round(seconds / dt))
        assert n % _EVERY == 0 and n <= _STEPS
        # The state after n steps: the run's record n / _EVERY (the steps after it do not change it).
        final = jax.tree.map(lambda x: x[n // _EVERY - 1],
                             physics.rollout(model, state, dt, _STEPS, record_every=_EVERY).trajectory)
        errors.append(np.max(np.abs(np.asarray(final.position) - ref)))
    ratios = np.asarray(errors[:-1]) / np.asarray(errors[1:])
    assert np.all((ratios > 1.6) & (ratios < 2.5)), f"errors {errors}: not first order"
    assert errors[-1] < 1e-3


def test_chain_of_every_joint_type_matches_mujoco():
    # world -hinge- a -universal- b -fixed- c -ball- d, boxes, tilted so that every joint moves.
    sizes = [(0.1, 0.3, 0.08), (0.08, 0.3, 0.1), (0.12, 0.2, 0.06), (0.1, 0.25, 0.1)]
    bodies = rigid.make_bodies([("box", s) for s in sizes], names=("a", "b", "c", "d"))
    ys = [-0.15, -0.45, -0.70, -0.925]
    quats = [rot.axis_angle_to_quat(jnp.asarray(ax), ang) for ax, ang in
             (((0.0, 0.0, 1.0), 0.4), ((1.0, 0.0, 0.0), 0.3), ((0.0, 1.0, 0.0), 0.2), ((1.0, 1.0, 0.0), 0.5))]
    xs = np.array([[0.02 * i, y, 0.01 * i] for i, y in enumerate(ys)])
    state = rigid.make_state(bodies, position=xs, orientation=jnp.stack(quats))
    J = joints.make_joints(bodies, state, [
        dict(type="hinge", parent=None, child="a", anchor=(0.0, 0.0, 0.0), axis=(0.3, 0.0, 1.0)),
        dict(type="universal", parent="a", child="b", anchor=(0.02, -0.3, 0.01), axis=(1.0, 0.0, 0.0),
             axis2=(0.0, 0.0, 1.0)),
        dict(type="fixed", parent="b", child="c", anchor=(0.03, -0.6, 0.02)),
        dict(type="ball", parent="c", child="d", anchor=(0.05, -0.8, 0.03)),
    ])
    model = physics.make_model(bodies, J)
    seconds, dt = 0.5, 1 / 1200
    ref = _mujoco_positions(model, state, 1 / 24000, seconds)
    n = int(round(seconds / dt))
    final = physics.rollout(model, state, dt, n, record_every=n).final
    err = np.max(np.abs(np.asarray(final.position) - ref))
    moved = np.max(np.abs(ref - np.asarray(state.position)))
    assert moved > 0.05, "the chain should swing"
    assert err < 5e-3 * moved / 0.05, f"position error {err:.2e} m vs MuJoCo"
    assert np.max(np.asarray(physics.joint_error(model, final))) < 1e-4


def test_joint_torques_are_internal():
    # Two boxes joined by a ball joint, no gravity: an internal joint torque changes neither the
    # linear nor the angular momentum, but spins the bodies in opposite senses.
    bodies = rigid.make_bodies([("box", (0.2, 0.4, 0.2)), ("box", (0.2, 0.3, 0.2))], gravity=(0.0, 0.0, 0.0))
    state = rigid.make_state(bodies, position=[[0.0, 0.2, 0.0], [0.0, -0.15, 0.0]],
                             linear_velocity=[[0.1, 0.0, 0.0], [0.0, 0.0, -0.2]])
    model = physics.make_model(bodies, joints.make_joints(bodies, state, [
        dict(type="ball", parent=0, child=1, anchor=(0.0, 0.0, 0.0))]))
    P0 = rigid.linear_momentum(bodies, state)
    L0 = rigid.angular_momentum(bodies, state)
    s = state
    for _ in range(300):
        s = physics.step(model, s, 1 / 600, joint_torque=[[0.0, 0.0, 0.05]])
    np.testing.assert_allclose(rigid.linear_momentum(bodies, s), P0, atol=1e-12)
    # Exactly conserved but for the constraint impulse's moment about the anchors' O(h^2) separation.
    np.testing.assert_allclose(rigid.angular_momentum(bodies, s), L0, atol=1e-6 * float(jnp.linalg.norm(L0)))
    free = state
    for _ in range(300):
        free = physics.step(model, free, 1 / 600)
    spin = np.asarray(s.angular_velocity - free.angular_velocity)[:, 2]
    assert spin[1] > 0.05 and spin[0] < -0.05, f"torque +tau on the child, -tau on the parent: {spin}"


def _pendulum_step(torque):
    """One step of the double pendulum with joint torques ``[2, 3]``: the function jitted by the two tests below."""
    model, state = _double_pendulum()
    return physics.step(model, state, 1 / 600, joint_torque=torque)


# jaxanim._linalg.jit's jit with the classic emitters set explicitly (whatever the jaxlib version). Module-level, so
# that the vmap and the loop of test_step_vmap_equals_loop are the compiler-option test's "vmap" and "direct"
# programs (2 compilations, ~2 s, fewer).
_classic_step = _linalg._jit_with({_linalg._FLAG: False}, _pendulum_step)
_TORQUES = np.random.default_rng(1).standard_normal((3, 2, 3))
_FIELDS = ("position", "orientation", "linear_velocity", "angular_velocity")


def _unstack(batched):
    return [jax.tree.map(lambda x, i=i: x[i], batched) for i in range(_TORQUES.shape[0])]


def test_step_vmap_equals_loop():
    torques = jnp.asarray(_TORQUES)
    batched = jax.vmap(_classic_step)(torques)  # eager vmap and single steps: one program each (the jit's)
    for i in range(3):
        single = _classic_step(torques[i])
        for name in _FIELDS:
            np.testing.assert_allclose(getattr(batched, name)[i], getattr(single, name), atol=1e-13, err_msg=name)


def test_bad_input():
    model, state = _double_pendulum()
    bodies = model.bodies
    with pytest.raises(JaxanimError, match="type: expected one of"):
        joints.make_joints(bodies, state, [dict(type="slider", parent=None, child="upper", anchor=(0, 0, 0))])
    with pytest.raises(JaxanimError, match=r"unknown body 'arm'; bodies are \['upper', 'lower'\]"):
        joints.make_joints(bodies, state, [dict(type="ball", parent="arm", child="upper", anchor=(0, 0, 0))])
    with pytest.raises(JaxanimError, match="perpendicular"):
        joints.make_joints(bodies, state, [dict(type="universal", parent=None, child="upper", anchor=(0, 0, 0),
                                                axis=(1, 0, 0), axis2=(1, 1, 0))])
    with pytest.raises(JaxanimError, match="already the child of a joint"):
        joints.make_joints(bodies, state, [dict(type="ball", parent=None, child="upper", anchor=(0, 0, 0)),
                                           dict(type="ball", parent="lower", child="upper", anchor=(0, 0, 0))])
    with pytest.raises(JaxanimError, match=r"joint_torque: expected shape \(J, 3\) = \(2, 3\)"):
        physics.step(model, state, 0.01, joint_torque=np.zeros((3, 3)))
    with pytest.raises(JaxanimError, match="erp: expected a value in"):
        physics.make_model(bodies, model.joints, erp=1.5)
    with pytest.raises(JaxanimError, match="num_steps: expected a multiple of record_every"):
        physics.rollout(model, state, 0.01, 10, record_every=3)
    for dt in (-0.01, 0.0, float("nan"), float("inf")):  # time backwards, or NaN in every state
        with pytest.raises(JaxanimError, match="dt: expected a positive finite number of seconds"):
            physics.step(model, state, dt)
        with pytest.raises(JaxanimError, match="dt: expected a positive finite number of seconds"):
            physics.rollout(model, state, dt, 10)


def test_the_simulators_compiler_option_gives_the_same_steps_under_every_transformation(monkeypatch):
    """jaxanim._linalg.jit: the simulator's entry points compile with the classic XLA:CPU emitters (unless XLA_FLAGS
    names the flag, as this suite's does) where they are the program's top level, directly or under an eager vmap
    or jvp, and as plain jits under a caller's jax.jit or grad (which reject compiler options on a nested jit).
    A step of the double pendulum is the one of XLA's default emitters, to round-off, in every case."""
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=true")
    assert _linalg._options() == {}
    monkeypatch.delenv("XLA_FLAGS")
    if tuple(jax.__version_info__[:2]) == (0, 10):
        assert _linalg._options() == {_linalg._FLAG: False}
    classic = _classic_step
    default = jax.jit(_pendulum_step, compiler_options={_linalg._FLAG: True})
    tau = jnp.asarray(_TORQUES)
    programs = classic.lower(tau[0]).compile().compiled, default.lower(tau[0]).compile()
    assert programs[0].as_text() != programs[1].as_text()  # the option reaches XLA
    seen = []
    monkeypatch.setattr(_linalg, "_top_level", lambda real=_linalg._top_level: seen.append(real()) or seen[-1])
    expected = [default(t) for t in tau]

    def aux(t):  # the step's states as the auxiliary output of the gradient of a sum
        s = classic(t)
        return jnp.sum(s.angular_velocity), s

    runs = {
        "direct": lambda: [classic(t) for t in tau],
        "vmap": lambda: _unstack(jax.vmap(classic)(tau)),
        "jvp": lambda: [jax.jvp(classic, (t,), (jnp.ones_like(t),))[0] for t in tau],
        "jit": lambda: _unstack(jax.jit(jax.vmap(classic))(tau)),
        "grad": lambda: [jax.grad(aux, has_aux=True)(t)[1] for t in tau],
    }
    for name, run in runs.items():
        seen.clear()
        got = run()
        assert seen and all(seen) == (name in ("direct", "vmap", "jvp")), (name, seen)
        assert len(got) == len(expected), name
        for g, e in zip(got, expected):
            for field in _FIELDS:
                np.testing.assert_allclose(np.asarray(getattr(g, field)), np.asarray(getattr(e, field)), rtol=0,
                                           atol=1e-12, err_msg=f"{name}: {field}")
