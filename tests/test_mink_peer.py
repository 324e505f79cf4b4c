"""The mink retargeting peer (``benchmarks/peers/mink_retarget.py``, GMR's per-frame loop) on the Unitree G1.

Reference (independent of mink): MuJoCo's own ``mj_kinematics`` of a known smooth joint trajectory gives the
target poses; mink must bring every body of the robot back to where that trajectory put it, and keep each
hinge inside its ``jnt_range`` even when the targets ask for more.
"""

from __future__ import annotations

import functools
import pathlib

import numpy as np
import pytest

import jaxanim
from benchmarks.peers import mink_retarget as mr

from .conftest import SHARED_DATA, shared_data_dir

mink = pytest.importorskip("mink")
mujoco = pytest.importorskip("mujoco")

_ATOL_BODY = 2e-3   # m, every body's position (measured: 6e-7 m one stage, 4e-5 m GMR's two)
_ATOL_LIMIT = 1e-9  # rad, outside jnt_range (ConfigurationLimit keeps 5 % of the gap each step)
_G1 = SHARED_DATA / "robots" / "unitree_g1" / "g1.xml"
_TARGETS = ("pelvis", "left_ankle_roll_link", "right_ankle_roll_link", "left_knee_link", "right_knee_link",
            "torso_link", "left_elbow_link", "right_elbow_link", "left_wrist_yaw_link", "right_wrist_yaw_link")
# GMR's smplx_to_g1 pattern: stage 1 orientations (positions on the pelvis and feet), stage 2 both
_GMR_POS = np.array([[100, 100, 100, 0, 0, 0, 0, 0, 0, 0], [100, 100, 100, 10, 10, 0, 10, 10, 10, 10]], float)
_GMR_ROT = np.array([[10] * 10, [5, 50, 50, 5, 5, 10, 5, 5, 5, 5]], float)


@functools.cache
def _g1():
    shared_data_dir()
    return mujoco.MjModel.from_xml_path(str(_G1))


def _trajectory(model, frames: int = 20, fps: float = 30.0, amplitude: float = 0.15, seed: int = 0) -> np.ndarray:
    """``[frames, nq]``: every hinge swings sinusoidally inside its range about the standing pose; the pelvis
    sways a few cm about its ``qpos0`` height and yaws by up to 0.2 rad."""
    rng = np.random.default_rng(seed)
    lo, hi = model.jnt_range[1:, 0], model.jnt_range[1:, 1]
    centre = np.clip(model.qpos0[7:], lo + amplitude + 0.02, hi - amplitude - 0.02)
    freq, phase = rng.uniform(0.3, 1.0, centre.size), rng.uniform(0.0, 2 * np.pi, centre.size)
    t = np.arange(frames) / fps
    q = np.tile(model.qpos0, (frames, 1))
    q[:, 7:] = centre + amplitude * np.sin(2 * np.pi * freq * t[:, None] + phase)
    q[:, 0] = 0.1 * np.sin(2 * np.pi * 0.4 * t)
    q[:, 2] = model.qpos0[2] + 0.02 * np.sin(2 * np.pi * 0.5 * t)
    yaw = 0.2 * np.sin(2 * np.pi * 0.3 * t)
    q[:, 3], q[:, 6] = np.cos(yaw / 2), np.sin(yaw / 2)
    return q


def _all_bodies(model) -> list[str]:
    return [model.body(i).name for i in range(1, model.nbody)]


def _assert_within_ranges(model, qpos):
    lo, hi = model.jnt_range[1:, 0], model.jnt_range[1:, 1]
    worst = np.maximum(lo - qpos[:, 7:], qpos[:, 7:] - hi).max()
    assert worst <= _ATOL_LIMIT, f"qpos: a hinge is {worst:.3g} rad outside its jnt_range"


def test_the_robots_have_a_free_joint():
    """All three robots have one free joint on their root body, which retargeting moves."""
    shared_data_dir()
    paths = [_G1, SHARED_DATA / "robots" / "cmu_humanoid" / "humanoid_CMU.xml",
             pathlib.Path(jaxanim.__file__).parent / "data" / "humanoid.xml"]
    for path in paths:
        model = mujoco.MjModel.from_xml_path(str(path))
        free = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
        assert len(free) == 1 and model.jnt_bodyid[free[0]] == 1, f"{path.name}: free joints {free}"


@pytest.mark.parametrize("stages", ["one", "gmr"])
def test_recovers_mujoco_fk_targets(stages):
    """20 frames of targets from MuJoCo's FK: every body (not only the 10 targets) within 2 mm, ranges kept."""
    model = _g1()
    q_true = _trajectory(model)
    pos, quat = mr.frame_poses(model, q_true, _TARGETS)
    pw, ow = (100.0, 10.0) if stages == "one" else (_GMR_POS, _GMR_ROT)
    qpos, seconds = mr.mink_retarget(str(_G1), _TARGETS, pos, quat, pw, ow, qpos_init=model.qpos0)
    assert qpos.shape == q_true.shape and seconds > 0
    want, _ = mr.frame_poses(model, q_true, _all_bodies(model))
    got, _ = mr.frame_poses(model, qpos, _all_bodies(model))
    err = np.linalg.norm(got - want, axis=-1)
    worst = np.unravel_index(err.argmax(), err.shape)
    assert err.max() < _ATOL_BODY, (f"body position: {err.max() * 1e3:.3f} mm at frame {worst[0]}, body "
                                    f"{_all_bodies(model)[worst[1]]}")
    _assert_within_ranges(model, qpos)


def test_keeps_joint_ranges_when_targets_exceed_them():
    """Targets made with the ankle rolls at +-0.4 rad and the knees at -0.3 rad (ranges +-0.26, >= -0.087):
    mink stays inside every range, the ankle rolls and knees end at their limits."""
    model = _g1()
    q = _trajectory(model, frames=10)
    names = [model.joint(j).name for j in range(model.njnt)]
    adr = {n: model.jnt_qposadr[names.index(n)] for n in names}
    q[:, adr["left_ankle_roll_joint"]], q[:, adr["right_ankle_roll_joint"]] = 0.4, -0.4
    q[:, adr["left_knee_joint"]] = q[:, adr["right_knee_joint"]] = -0.3
    pos, quat = mr.frame_poses(model, q, _TARGETS)
    qpos, _ = mr.mink_retarget(model, _TARGETS, pos, quat, 100.0, 10.0, qpos_init=model.qpos0)
    _assert_within_ranges(model, qpos)
    last = qpos[-1]
    assert last[adr["left_ankle_roll_joint"]] > 0.25 and last[adr["right_ankle_roll_joint"]] < -0.25
    assert last[adr["left_knee_joint"]] < -0.08 and last[adr["right_knee_joint"]] < -0.08


def test_site_targets_and_positions_only():
    """Sites become ``frame_type="site"`` tasks; without orientations the positions are still met."""
    model = _g1()
    names = ("pelvis", "left_foot", "right_foot", "left_wrist_yaw_link", "right_wrist_yaw_link")
    assert mr.frame_types(model, names) == ("body", "site", "site", "body", "body")
    q_true = _trajectory(model, frames=5)
    pos, _ = mr.frame_poses(model, q_true, names)
    qpos, _ = mr.mink_retarget(model, names, pos, None, 100.0, 0.0, qpos_init=q_true[0])
    got, _ = mr.frame_poses(model, qpos, names)
    assert np.abs(got - pos).max() < _ATOL_BODY, "site/body target positions"


def test_batch_runs_clips_one_after_another():
    """Each clip of the batch equals its own run (each starts from its own ``qpos_init``)."""
    model = _g1()
    clips = [_trajectory(model, frames=6, seed=s) for s in (1, 2)]
    poses = [mr.frame_poses(model, q, _TARGETS) for q in clips]
    inits = np.stack([q[0] for q in clips])
    out, seconds = mr.mink_retarget_batch(model, _TARGETS, [p for p, _ in poses], [r for _, r in poses],
                                          _GMR_POS, _GMR_ROT, qpos_init=inits)
    assert len(out) == 2 and seconds > 0
    for b, (p, r) in enumerate(poses):
        single, _ = mr.mink_retarget(model, _TARGETS, p, r, _GMR_POS, _GMR_ROT, qpos_init=inits[b])
        np.testing.assert_array_equal(out[b], single, err_msg=f"clip {b}")


def test_bad_input_raises():
    model = _g1()
    pos, quat = mr.frame_poses(model, model.qpos0[None], _TARGETS)
    with pytest.raises(ValueError, match="'nose' is neither a body nor a site.*pelvis"):
        mr.mink_retarget(model, ("nose",), pos[:, :1], quat[:, :1], 1.0, 1.0)
    with pytest.raises(ValueError, match=r"positions: expected shape \(T, K, 3\) = \(T, 10, 3\), got \(1, 9, 3\)"):
        mr.mink_retarget(model, _TARGETS, pos[:, 1:], quat, 1.0, 1.0)
    with pytest.raises(ValueError, match=r"qpos_init: expected shape \(nq,\) = \(36,\), got \(35,\)"):
        mr.mink_retarget(model, _TARGETS, pos, quat, 1.0, 1.0, qpos_init=model.qpos0[1:])
    with pytest.raises(ValueError, match="orientation_weights: must be zero when orientations is None"):
        mr.mink_retarget(model, _TARGETS, pos, None, 1.0, 1.0)
    with pytest.raises(ValueError, match="stage 0 has no task"):
        mr.mink_retarget(model, _TARGETS, pos, quat, 0.0, 0.0)
    arm = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body name="a"><joint type="hinge"/><geom size="0.1"/></body></worldbody></mujoco>')
    with pytest.raises(ValueError, match="no free joint"):
        mr.mink_retarget(arm, ("a",), np.zeros((1, 1, 3)), None, 1.0, 0.0)
