"""A robot's dynamics in its joint coordinates (issue 60, item 1's free flight) against MuJoCo on the same
model: the mass matrix (``mj_fullM``), the bias forces (``qfrc_bias``), the passive forces
(``qfrc_passive``: damping and springs) and the accelerations (``qacc_smooth``, and ``mj_forward``'s
``qacc`` with the robot clear of the ground and inside its joint ranges), on a small model of every joint
kind written here and on the robot files as they are: the shipped humanoid, both CMU humanoids, the G1 and
the Romeo URDF with a free joint added."""

from __future__ import annotations

import dataclasses
import pathlib
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxanim
from jaxanim import robots

from .conftest import shared_data_dir

mujoco = pytest.importorskip("mujoco", reason="the references are MuJoCo's (jaxanim[robots])")

#: The README's claim: MuJoCo's numbers to 1e-10, relative to the largest entry.
RTOL = 1e-10

#: Every joint kind: a free base, a hinge and a limited ball on one body, a slide and two hinges on the next
#: (refs, ranges), springs toward a ``springref``, armature and damping, and gravity off the z axis.
_MODEL = """<mujoco model="dynamics">
  <compiler angle="degree"/>
  <option gravity="0.5 -1 -9"/>
  <worldbody>
    <body name="base" pos="0.1 0.2 1.3" euler="10 20 30">
      <freejoint name="free"/>
      <inertial pos="0.01 0 0.02" mass="2" diaginertia="0.1 0.2 0.3" quat="0.9 0.1 0.2 0.3"/>
      <body name="arm" pos="0 0.2 0" quat="1 0.2 0 0.1">
        <joint name="twist" type="hinge" axis="1 0 0" pos="0 0.05 0" armature="0.02" damping="0.3"
               stiffness="2" springref="10"/>
        <joint name="ball" type="ball" pos="0.01 0.02 0.03" range="0 70" armature="0.01" damping="0.2"
               stiffness="1"/>
        <inertial pos="0 0.1 0" mass="1" diaginertia="0.01 0.02 0.03"/>
        <body name="slider" pos="0.3 0 0">
          <joint name="slide" type="slide" axis="1 1 0" range="-0.1 0.2" ref="0.05" armature="0.1"
                 damping="2" stiffness="5" springref="0.1"/>
          <joint name="hinge_a" type="hinge" axis="0 0 1" pos="0.02 0 0" ref="15" damping="0.1"/>
          <joint name="hinge_b" type="hinge" axis="0 1 1" pos="0 0.01 0" range="-30 60" armature="0.03"
                 actuatorfrcrange="-1.5 1.5"/>
          <inertial pos="0.05 0 0" mass="0.5" diaginertia="0.01 0.01 0.02"/>
          <body name="fixed_child" pos="0 0 0.1" euler="0 0 45">
            <inertial pos="0 0 0.01" mass="0.2" diaginertia="0.001 0.002 0.001"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="m_twist" joint="twist" gear="3" ctrlrange="-1 1" forcerange="-2 2"/>
    <position name="p_slide" joint="slide" kp="50" kv="3" ctrlrange="-0.1 0.2"/>
    <velocity name="v_hinge_a" joint="hinge_a" kv="4"/>
    <motor name="m_hinge_b" joint="hinge_b" gear="2"/>
  </actuator>
</mujoco>
"""

_FILES = ("unitree_g1/g1.xml", "cmu_humanoid/humanoid_CMU.xml", "cmu_humanoid/humanoid_CMU_V2020.xml",
          "romeo/romeo_small.urdf")


def _random_state(model, rng):
    """A configuration inside every range (a ball within its cone), the free bodies lifted by 2 m, and random
    velocities and applied forces."""
    q = model.qpos0.copy()
    for j in range(model.njnt):
        a, kind, (lo, hi) = model.jnt_qposadr[j], model.jnt_type[j], model.jnt_range[j]
        limited = bool(model.jnt_limited[j])
        if kind == mujoco.mjtJoint.mjJNT_FREE:
            q[a:a + 3] += rng.normal(scale=0.3, size=3) + [0.0, 0.0, 2.0]
            quat = rng.normal(size=4)
            q[a + 3:a + 7] = quat / np.linalg.norm(quat)
        elif kind == mujoco.mjtJoint.mjJNT_BALL:
            axis = rng.normal(size=3)
            angle = rng.uniform(0, 0.8 * hi if limited else np.pi)
            q[a:a + 4] = np.r_[np.cos(angle / 2), np.sin(angle / 2) * axis / np.linalg.norm(axis)]
        else:
            q[a] = rng.uniform(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo)) if limited else q[a] + rng.normal()
    return q, rng.normal(size=model.nv), rng.normal(scale=5.0, size=model.nv)


def _mujoco_numbers(model, q, v, f):
    """MuJoCo's mass matrix, bias, passive forces, smooth and constrained accelerations; contact off (free
    flight), the actuators off (their forces are not modelled here: ctrl 0 of a position actuator pulls
    toward 0) and, where the file has dry friction, the qacc without it too (``qacc_free``)."""
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:], data.qfrc_applied[:] = q, v, f
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_ACTUATION
    mujoco.mj_forward(model, data)
    M = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, M)
    out = {"M": M, "bias": data.qfrc_bias.copy(), "passive": data.qfrc_passive.copy(),
           "qacc_smooth": data.qacc_smooth.copy(), "qacc": data.qacc.copy(), "nefc": int(data.nefc)}
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS
    mujoco.mj_forward(model, data)
    out["qacc_free"], out["nefc_free"] = data.qacc.copy(), int(data.nefc)
    model.opt.disableflags = 0
    return out


def _close(name, ours, ref):
    ours, ref = np.asarray(ours), np.asarray(ref)
    scale = max(np.abs(ref).max(), 1e-12)
    assert np.abs(ours - ref).max() <= RTOL * scale, f"{name}: {np.abs(ours - ref).max() / scale:.2e} relative"


def _check(robot, model, seed, states=3, parts=True):
    """``parts``: the mass matrix, bias and passive forces one by one too (a program each); without, the
    accelerations alone, which are wrong where any of them is."""
    rng = np.random.default_rng(seed)
    for _ in range(states):
        q, v, f = _random_state(model, rng)
        ref = _mujoco_numbers(model, q, v, f)
        if parts:
            _close("mass_matrix", robots.mass_matrix(robot, q), ref["M"])
            _close("bias_forces", robots.bias_forces(robot, q, v), ref["bias"])
            _close("passive_forces", robots.passive_forces(robot, q, v), ref["passive"])
        qacc = robots.forward_dynamics(robot, q, v, f)
        _close("forward_dynamics (qacc_smooth)", qacc, ref["qacc_smooth"])
        # free flight: clear of the ground, inside the ranges; no constraint is active without dry friction
        assert ref["nefc_free"] == 0
        _close("forward_dynamics (mj_forward's qacc, no dry friction)", qacc, ref["qacc_free"])
        if not np.any(model.dof_frictionloss):
            assert ref["nefc"] == 0
            _close("forward_dynamics (mj_forward's qacc)", qacc, ref["qacc"])


@pytest.fixture(scope="module")
def small():
    model = mujoco.MjModel.from_xml_string(_MODEL)
    return robots.robot_from_mujoco(model), model


def test_every_joint_kind_against_mujoco(small):
    robot, model = small
    assert robot.jnt_types == ("free", "hinge", "ball", "slide", "hinge", "hinge")
    assert robot.actuator_names == ("m_twist", "p_slide", "v_hinge_a", "m_hinge_b")
    np.testing.assert_allclose(np.asarray(robot.gravity), [0.5, -1.0, -9.0])
    assert np.any(model.jnt_stiffness) and np.any(model.dof_armature) and np.any(model.dof_damping)
    _check(robot, model, seed=0, states=5)


def _mujoco_actuated(model, q, v, f, ctrl):
    """MuJoCo's ``qfrc_actuator`` and ``qacc_smooth`` with the actuators on (contact off)."""
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:], data.qfrc_applied[:], data.ctrl[:] = q, v, f, ctrl
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    mujoco.mj_forward(model, data)
    model.opt.disableflags = 0
    return data.qfrc_actuator.copy(), data.qacc_smooth.copy()


@pytest.mark.parametrize("name", ("small", "unitree_g1/g1.xml", "cmu_humanoid/humanoid_CMU.xml"))
def test_actuators_against_mujoco(name, small):
    """Motors with gears, force and control ranges, position and velocity actuators and a joint's
    actuatorfrcrange (the small model); the G1's position actuators (kp, kv, the joints' force ranges) and the
    CMU humanoid's geared motors. Controls beyond their ranges, so that every clamp acts."""
    if name == "small":
        robot, model = small
    else:
        model = mujoco.MjModel.from_xml_path(str(shared_data_dir() / "robots" / name))
        robot = robots.robot_from_mujoco(model)
    assert robot.actuator_names and all(j >= 0 for j in robot.actuator_joints)
    rng = np.random.default_rng(3)
    for _ in range(2):
        q, v, f = _random_state(model, rng)
        lo, hi = model.actuator_ctrlrange.T
        ctrl = rng.uniform(np.where(model.actuator_ctrllimited, 1.5 * lo - 0.5 * hi, -3.0),
                           np.where(model.actuator_ctrllimited, 1.5 * hi - 0.5 * lo, 3.0))
        qfrc, qacc = _mujoco_actuated(model, q, v, f, ctrl)
        _close("actuator_forces", robots.actuator_forces(robot, q, v, ctrl), qfrc)
        _close("forward_dynamics with ctrl (qacc_smooth)", robots.forward_dynamics(robot, q, v, f, ctrl=ctrl), qacc)


def test_an_actuator_not_modelled_is_named():
    xml = _MODEL.replace('<velocity name="v_hinge_a" joint="hinge_a" kv="4"/>',
                         '<general name="filtered" joint="hinge_a" dyntype="filter" dynprm="0.1"/>')
    robot = robots.robot_from_mujoco(mujoco.MjModel.from_xml_string(xml))  # loads: kinematics need no actuators
    q, v = np.asarray(robot.qpos0), np.zeros(robot.nv)
    with pytest.raises(jaxanim.JaxanimError, match="filtered"):
        robots.actuator_forces(robot, q, v, np.zeros(4))
    with pytest.raises(jaxanim.JaxanimError, match="ctrl"):
        robots.actuator_forces(robots.robot_from_mujoco(mujoco.MjModel.from_xml_string(_MODEL)), q, v, np.zeros(3))


def test_vmap_equals_a_loop_and_float32_stays_float32(small):
    robot, model = small
    rng = np.random.default_rng(1)
    states = [_random_state(model, rng) for _ in range(4)]
    q, v, f = (np.stack(x) for x in zip(*states))
    batched = jax.vmap(robots.forward_dynamics, in_axes=(None, 0, 0, 0))(robot, q, v, f)
    for i in range(len(q)):
        np.testing.assert_allclose(np.asarray(batched[i]), np.asarray(robots.forward_dynamics(robot, q[i], v[i], f[i])),
                                   rtol=1e-12, atol=1e-12)
    robot32 = robots.robot_from_mujoco(model, dtype=jnp.float32)
    out = robots.forward_dynamics(robot32, q[0].astype(np.float32), v[0].astype(np.float32), f[0].astype(np.float32))
    assert out.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(out), np.asarray(batched[0]), rtol=1e-3, atol=1e-3 * np.abs(batched[0]).max())


@pytest.mark.parametrize("name", ("shipped humanoid",) + _FILES)
def test_robot_files_as_they_are_against_mujoco(name):
    if name == "shipped humanoid":
        path = pathlib.Path(robots.default_robot_path())
    else:
        path = shared_data_dir() / "robots" / name
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Romeo's absent collision meshes
        robot = robots.load_robot(path, floating_base=path.suffix == ".urdf")
    # MuJoCo's own model of the same file (the URDF's free joint added by MuJoCo's model editor)
    from jaxanim.robots import _load

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if path.suffix == ".urdf":
            spec = mujoco.MjSpec.from_string(_load._urdf_text(path.read_text(), path))
            spec.worldbody.first_body().add_freejoint(name="root_joint")
        else:
            spec = mujoco.MjSpec.from_file(str(path))
        model = _load._compile(spec, path)
    assert robot.nv == model.nv and robot.jnt_types == tuple(robots.robot_from_mujoco(model).jnt_types)
    _check(robot, model, seed=2, states=2, parts=False)


def test_a_fixed_robot_is_the_floating_one_held(small):
    """``with_floating_base`` adds six dofs without armature, damping or spring; the joints' block of the
    floating robot's mass matrix is the fixed robot's, which the world holds."""
    xml = _MODEL.replace('<freejoint name="free"/>', "")
    fixed = robots.robot_from_mujoco(mujoco.MjModel.from_xml_string(xml))
    floating = robots.with_floating_base(fixed)
    assert floating.nv == fixed.nv + 6 and np.all(np.asarray(floating.dof_armature)[:6] == 0)
    q = np.asarray(floating.qpos0)
    np.testing.assert_allclose(np.asarray(robots.mass_matrix(floating, q))[6:, 6:],
                               np.asarray(robots.mass_matrix(fixed, q[7:])), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(np.asarray(robots.passive_forces(floating, q, np.zeros(floating.nv)))[6:],
                               np.asarray(robots.passive_forces(fixed, q[7:], np.zeros(fixed.nv))), atol=1e-12)
    # the actuators keep their joints (one index further on: the free joint comes first)
    assert floating.actuator_names == fixed.actuator_names
    assert [floating.jnt_names[j] for j in floating.actuator_joints] == [fixed.jnt_names[j] for j in fixed.actuator_joints]
    ctrl = np.array([0.5, 0.05, 0.0, 3.0])
    v = np.linspace(-1.0, 1.0, floating.nv)
    np.testing.assert_allclose(np.asarray(robots.actuator_forces(floating, q, v, ctrl))[6:],
                               np.asarray(robots.actuator_forces(fixed, q[7:], v[6:], ctrl)), atol=1e-12)


def test_bad_input_is_named(small):
    robot, model = small
    q, v = np.asarray(robot.qpos0), np.zeros(robot.nv)
    with pytest.raises(jaxanim.JaxanimError, match="qvel"):
        robots.forward_dynamics(robot, q, np.zeros(robot.nv + 1))
    with pytest.raises(jaxanim.JaxanimError, match="qfrc_applied"):
        robots.forward_dynamics(robot, q, v, np.zeros(3))
    with pytest.raises(jaxanim.JaxanimError, match="qpos"):
        robots.mass_matrix(robot, q[:-1])
    bare = dataclasses.replace(robot, body_inertia=None)
    with pytest.raises(jaxanim.JaxanimError, match="body_inertia"):
        robots.bias_forces(bare, q, v)
