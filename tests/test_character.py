"""Tests of jaxanim.character on the CMU clip: 70 kg in ~20 bodies with ball joints at the skeleton's
joints, the unit inferred from the height, pose <-> state round trip against FK of the clip frame,
stable-PD targets, the MJCF export loaded by MuJoCo with the same masses, tracking the clip with
stable PD and the root force on the ground, and bad input."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxanim
from jaxanim import JaxanimError, character, contact, control, physics

from .conftest import shared_data_dir
from .helpers import jitted_fk as _fk
from .helpers import phys_cmu_character, xla_compiles




@pytest.fixture(scope="module")
def cmu():
    shared_data_dir()
    skel, _, q0, t0, char, state = phys_cmu_character()  # built with make_ground(); shared with test_balance
    return skel, q0, t0, char, state


def test_bodies_joints_and_units(cmu):
    skel, q0, t0, char, state = cmu
    bodies = char.model.bodies
    np.testing.assert_allclose(float(jnp.sum(bodies.mass)), 70.0, rtol=1e-12)
    assert 18 <= char.num_bodies <= 24
    assert char.model.joints.num_joints == char.num_bodies - 1
    assert set(char.model.joints.types) == {"ball"}
    # Unit: the rest pose is 1.7 m tall.
    rest = _fk(skel, skel.rest_rotations())
    pts = np.concatenate([np.asarray(rest.positions), np.asarray(rest.end_site_positions)])
    np.testing.assert_allclose((pts[:, 1].max() - pts[:, 1].min()) * char.unit, 1.7, rtol=1e-12)
    # Left and right limbs weigh the same (the CMU skeleton is nearly symmetric).
    m = dict(zip(bodies.names, np.asarray(bodies.mass)))
    for left, right in (("LeftUpLeg", "RightUpLeg"), ("LeftLeg", "RightLeg"), ("LeftArm", "RightArm")):
        np.testing.assert_allclose(m[left], m[right], rtol=0.1)
    assert m["LeftUpLeg"] > m["LeftLeg"] > m["LeftFoot"]
    # Feet are boxes; every joint sits on its bodies: zero separation at assembly.
    assert bodies.shapes[bodies.names.index("LeftFoot")] == "box"
    assert float(jnp.max(physics.joint_error(char.model, state))) < 1e-12


def test_pose_state_round_trip(cmu):
    skel, q0, t0, char, state = cmu
    q, t = character.character_pose(char, state, reference=q0)
    a = _fk(skel, q0, t0)
    b = _fk(skel, q, t)
    np.testing.assert_allclose(b.positions, a.positions, atol=1e-9)
    np.testing.assert_allclose(b.end_site_positions, a.end_site_positions, atol=1e-9)
    # Meters: a body's center lies on its bone, in the file's frame scaled by the unit.
    i = char.model.bodies.names.index("LeftLeg")
    j, k = skel.index("LeftLeg"), skel.index("LeftFoot")
    mid = 0.5 * (a.positions[j] + a.positions[k]) * char.unit
    np.testing.assert_allclose(state.position[i], mid, atol=1e-9)
    # Stable-PD targets of the assembly pose: zero joint errors there.
    e, _ = control.joint_errors(char.model.joints, state, character.spd_targets(char, q0, t0))
    assert float(jnp.max(jnp.abs(e))) < 1e-9


def test_mjcf_export_loads_in_mujoco_with_the_same_masses(cmu):
    mujoco = pytest.importorskip("mujoco")
    _, _, _, char, state = cmu
    m = mujoco.MjModel.from_xml_string(character.export_mjcf(char, state))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    assert m.nbody == char.num_bodies + 1
    np.testing.assert_allclose(m.body_mass[1:].sum(), 70.0, rtol=1e-12)
    order = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in char.model.bodies.names]
    np.testing.assert_allclose(d.xpos[order], state.position, atol=1e-9)
    np.testing.assert_allclose(m.body_mass[order], char.model.bodies.mass, rtol=1e-12)


def test_bad_input(cmu):
    skel = cmu[0]
    with pytest.raises(JaxanimError, match="total_mass: expected > 0"):
        character.build_character(skel, total_mass=0.0)
    with pytest.raises(JaxanimError, match="unit: expected > 0"):
        character.build_character(skel, unit=-1.0)
    with pytest.raises(JaxanimError, match=r"rotations: expected shape \(joints, 4\) = \(31, 4\)"):
        character.build_character(skel, jnp.zeros((30, 4)))


_DT_TRACK = 1 / 120


@pytest.fixture(scope="module")
def tracked(cmu):
    """The clip tracked 300 steps at 120 Hz (one compiled rollout, shared)."""
    _, _, _, char, state = cmu
    motion = jaxanim.read_bvh(shared_data_dir() / "bvh" / "cmu_01_01_trim300.bvh")[1]
    ctrl, args = character.tracking_controller(char, motion, _DT_TRACK)
    return motion, physics.rollout(char.model, state, _DT_TRACK, 300, controller=ctrl, controller_args=args)


def test_tracks_the_clip_with_stable_pd_and_the_root_force(cmu, tracked):
    skel, q0, t0, char, state = cmu
    motion, run = tracked
    dt = _DT_TRACK
    assert run.result == physics.SimResult.successful and int(run.num_steps) == 300
    # Joint error: the angle between each simulated joint's relative rotation and the clip's, at the
    # frame the controller tracked at that step.
    frames = jnp.clip(jnp.floor(jnp.arange(1, 301) * dt * motion.fps).astype(jnp.int32), 0, motion.num_frames - 1)

    @eqx.filter_jit  # one compiled program (an eager vmap compiles op by op)
    def errors_and_lowest(char, motion, trajectory, frames):
        targets = jax.vmap(lambda q, t: character.spd_targets(char, q, t))(motion.rotations, motion.translations)
        errors = jax.vmap(lambda s, f: jnp.linalg.norm(control.joint_errors(char.model.joints, s, targets[f])[0],
                                                       axis=-1))(trajectory, frames)
        lowest = jax.vmap(lambda s: jnp.min(contact.contact_geometry(char.model.ground, char.model.bodies, s)[2]))(trajectory)
        return errors, lowest

    errors, lowest = errors_and_lowest(char, motion, run.trajectory, frames)
    assert float(jnp.mean(errors)) < 0.1, f"mean joint error {float(jnp.mean(errors)):.3f} rad"
    # Standing on the ground (complementarity contact), joints together.
    assert float(jnp.min(lowest)) > -1e-3, f"sank {float(jnp.min(lowest))} m"
    assert float(jnp.max(physics.joint_error(char.model, run.final))) < 5e-3


def test_build_tracking_and_rollout_compile_once(cmu, tracked):
    """A second character built in another frame, tracking the clip played backwards with other
    gains (the same structure, new values): nothing is compiled again."""
    skel, *_ = cmu
    motion, first = tracked
    backwards = eqx.tree_at(lambda m: (m.rotations, m.translations), motion,
                            (motion.rotations[::-1], motion.translations[::-1]))
    with xla_compiles() as compiled:
        char, state = character.build_character(skel, motion.rotations[10], motion.translations[10],
                                                ground=contact.make_ground())
        ctrl, args = character.tracking_controller(char, backwards, _DT_TRACK, kp=400.0, kd=40.0)
        run = physics.rollout(char.model, state, _DT_TRACK, 300, controller=ctrl, controller_args=args)
    assert compiled == [], compiled
    assert run.result == physics.SimResult.successful
    assert float(jnp.max(jnp.abs(run.final.position - first.final.position))) > 0.1  # new values used
