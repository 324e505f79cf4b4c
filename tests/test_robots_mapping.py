"""The retargeting map (jaxanim.retargeting.load_mapping / calibrate), issue 30: the JSON contract, its
errors, and the calibration against MuJoCo's own zero-pose kinematics and a NumPy rest pose."""

from __future__ import annotations

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxanim
from jaxanim import retargeting, robots

from .conftest import shared_data_dir

mujoco = pytest.importorskip("mujoco")

_Y_UP = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # BVH (Y up, facing +Z) -> robot axes
WALK_TO_G1 = {
    "root": {"source": "Hips", "target": "pelvis"},
    "pairs": [
        {"source": "LeftFoot", "target": "left_ankle_roll_link", "foot": True},
        {"source": "RightFoot", "target": "right_ankle_roll_link", "foot": True},
        {"source": "LeftHand", "target": "left_wrist_yaw_link", "position_weight": 0.5},
        {"source": "RightHand", "target": "right_wrist_yaw_link", "position_weight": 0.5},
        {"source": "Chest", "target": "site:imu_in_torso", "orientation_weight": 0.0},
    ],
}


@pytest.fixture(scope="module")
def setup():
    path = shared_data_dir() / "robots" / "unitree_g1" / "g1.xml"
    skel, _ = jaxanim.read_bvh(jaxanim.default_clip_path())
    return skel, robots.load_robot(path), path


def _mujoco_zero_pose(path):
    """Body and site world poses of the model at qpos0, by MuJoCo itself."""
    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    return model, data


def _rest_positions(skel):
    """World positions of the rest pose (identity rotations): the sums of the OFFSETs, in NumPy."""
    off = np.asarray(skel.offsets, np.float64)
    p = np.zeros_like(off)
    for j, a in enumerate(skel.parents):
        p[j] = off[j] + (p[a] if a >= 0 else 0.0)
    return p


def test_calibration_matches_mujoco_and_the_rest_pose(setup):
    skel, g1, path = setup
    cal = retargeting.calibrate(retargeting.load_mapping(WALK_TO_G1), skel, g1)
    model, data = _mujoco_zero_pose(path)
    body = lambda n: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, n)  # noqa: E731
    robot_height = data.xpos[body("pelvis"), 2] - min(data.xpos[body(f"{s}_ankle_roll_link"), 2]
                                                       for s in ("left", "right"))
    p = _rest_positions(skel)
    source_height = p[skel.index("Hips"), 1] - min(p[skel.index(f"{s}Foot"), 1] for s in ("Left", "Right"))
    np.testing.assert_allclose(float(cal.scale), robot_height / source_height, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(cal.axes), _Y_UP, atol=0)
    # the common pose, by MuJoCo: each offset takes the (turned) rest rotation of the source joint, the identity,
    # onto the robot's rotation there; a foot's onto its zero pose (the G1 stands on level soles)
    posed = mujoco.MjData(model)
    posed.qpos[:] = np.asarray(cal.qpos)
    mujoco.mj_kinematics(model, posed)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "imu_in_torso")
    want = [(data if p.get("foot") else posed).xmat[body(p["target"])].reshape(3, 3)
            if not p["target"].startswith("site:") else posed.site_xmat[site].reshape(3, 3) for p in WALK_TO_G1["pairs"]]
    for k, R in enumerate(want):
        O = np.asarray(jaxanim.rotations.quat_to_matrix(cal.offset[k]))
        np.testing.assert_allclose(_Y_UP @ O, R, atol=1e-12, err_msg=f"pair {k}")
    # the common pose is the rest pose (a T-pose) in the robot's proportions: the root where it was, the forearm
    # (elbow to wrist) along the source's, sideways, where the zero pose hangs it down
    np.testing.assert_allclose(np.asarray(cal.qpos[:7]), np.asarray(g1.qpos0[:7]), atol=0)
    for side in ("left", "right"):
        forearm = posed.xpos[body(f"{side}_wrist_yaw_link")] - posed.xpos[body(f"{side}_elbow_link")]
        src = _Y_UP @ (p[skel.index(f"{side.title()}Hand")] - p[skel.index(f"{side.title()}ForeArm")])
        cos = forearm @ src / np.linalg.norm(forearm) / np.linalg.norm(src)
        assert cos > np.cos(np.radians(10)), (side, np.degrees(np.arccos(cos)))
        down = data.xpos[body(f"{side}_wrist_yaw_link")] - data.xpos[body(f"{side}_elbow_link")]
        assert down @ src / np.linalg.norm(down) / np.linalg.norm(src) < np.cos(np.radians(60))


def test_calibration_frame_takes_the_clips_pose(setup):
    """``calibration_frame: k`` calibrates in the clip's frame k (its root's own frame): the rest pose's offsets
    when frame k is the rest pose, other ones for another pose, and it needs the clip."""
    skel, g1, _ = setup
    walk = jaxanim.read_bvh(jaxanim.default_clip_path())[1]
    data = json.loads(json.dumps(WALK_TO_G1))
    data["calibration_frame"] = 1
    m = retargeting.load_mapping(data)
    with pytest.raises(jaxanim.JaxanimError, match=r"calibration_frame: 1 names a frame of the clip"):
        retargeting.calibrate(m, skel, g1)
    with pytest.raises(jaxanim.JaxanimError, match=r"calibration_frame: 1 is past the clip's last frame \(0\)"):
        retargeting.calibrate(m, skel, g1, motion=jaxanim.skeleton.rest_motion(skel, 1))
    rest = retargeting.calibrate(retargeting.load_mapping(WALK_TO_G1), skel, g1)
    still = jaxanim.skeleton.rest_motion(skel, 2)
    turned = jaxanim.Motion(still.rotations.at[:, 0].set(jnp.asarray([np.cos(0.4), 0.0, np.sin(0.4), 0.0])),
                            still.translations.at[:, 0].add(3.0), still.frame_time)  # the root turned and moved: the same pose
    same = retargeting.calibrate(m, skel, g1, motion=turned)
    # the same goals to rounding; the IK stops at its tolerance, so its pose agrees to about 1e-7
    np.testing.assert_allclose(np.asarray(same.offset), np.asarray(rest.offset), atol=1e-6)
    other = retargeting.calibrate(m, skel, g1, motion=walk)
    assert np.max(np.abs(np.asarray(other.offset) - np.asarray(rest.offset))) > 1e-2


def test_the_calibration_ik_runs_once_for_the_same_robot_and_goals(setup, monkeypatch):
    """A dataset's clips of one skeleton calibrate alike: the IK's pose is kept by its inputs (the robot's
    numbers included), so the second calibration solves nothing and gives the same numbers, and a robot whose
    zero pose differs solves again."""
    from jaxanim.retargeting import _mapping

    skel, g1, _ = setup
    m = retargeting.load_mapping(WALK_TO_G1)
    monkeypatch.setattr(_mapping, "_COMMON_POSES", type(_mapping._COMMON_POSES)())
    solves = []
    solve = _mapping._solve_common_pose
    monkeypatch.setattr(_mapping, "_solve_common_pose", lambda *a: solves.append(1) or solve(*a))
    first = retargeting.calibrate(m, skel, g1)
    again = retargeting.calibrate(m, skel, g1)
    assert len(solves) == 1
    for a, b in zip(jax.tree.leaves(first), jax.tree.leaves(again)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    bent = jnp.asarray(g1.qpos0).at[-1].add(0.3)  # the last wrist joint: another robot to the IK
    retargeting.calibrate(m, skel, eqx.tree_at(lambda r: r.qpos0, g1, bent))
    assert len(solves) == 2


def test_given_offsets_and_scale_are_kept_and_the_file_form_parses(setup, tmp_path):
    skel, g1, _ = setup
    data = json.loads(json.dumps(WALK_TO_G1))
    data["scale"] = 0.5
    data["pairs"][2]["offset"] = [0.0, 1.0, 0.0, 0.0]
    path = tmp_path / "map.json"
    path.write_text(json.dumps(data), encoding="utf-8")
    m = retargeting.load_mapping(path)
    assert m.feet == (True, True, False, False, False) and m.targets[4] == "site:imu_in_torso"
    np.testing.assert_array_equal(np.asarray(m.position_weight), [1, 1, 0.5, 0.5, 1])
    np.testing.assert_array_equal(np.asarray(m.orientation_weight), [0.1, 0.1, 0.1, 0.1, 0.0])
    cal = retargeting.calibrate(m, skel, g1)
    assert float(cal.scale) == 0.5
    np.testing.assert_array_equal(np.asarray(cal.offset[2]), [0.0, 1.0, 0.0, 0.0])


def _with(**changes):
    data = json.loads(json.dumps(WALK_TO_G1))
    for key, value in changes.items():
        if key.startswith("pair0_"):
            data["pairs"][0][key[6:]] = value
        elif value is None:
            data.pop(key)
        else:
            data[key] = value
    return data


@pytest.mark.parametrize("data, match", [
    (_with(root=None), r"root: the root is not mapped"),
    (_with(pairs=[]), r"pairs: expected a non-empty list"),
    (_with(extra=1), r"unknown key\(s\) \['extra'\]"),
    (_with(source_up="x"), r"source_up: expected 'y' or 'z'"),
    (_with(scale=-1.0), r"scale: expected a positive number"),
    (_with(pair0_offset=[1.0, 1.0, 0.0, 0.0]), r"pairs\[0\].offset: expected a unit quaternion"),
    (_with(pair0_position_weight="heavy"), r"pairs\[0\].position_weight: expected a finite number"),
    (_with(pair0_sideways=True), r"pairs\[0\]: unknown key\(s\) \['sideways'\]"),
    ({"root": WALK_TO_G1["root"], "pairs": WALK_TO_G1["pairs"][2:]}, r"no pair is a foot"),
])
def test_bad_maps_name_the_key(data, match):
    with pytest.raises(jaxanim.JaxanimError, match=match):
        retargeting.load_mapping(data)


def test_names_and_feet_are_checked_against_the_skeleton_and_the_robot(setup, tmp_path):
    skel, g1, _ = setup
    with pytest.raises(jaxanim.JaxanimError, match=r"pairs\[0\].source: unknown source joint 'LeftPaw'; the "
                                                    r"skeleton's joints are \['Hips', 'Spine'"):
        retargeting.calibrate(retargeting.load_mapping(_with(pair0_source="LeftPaw")), skel, g1)
    with pytest.raises(jaxanim.JaxanimError, match=r"pairs\[0\].target: unknown body or site 'left_hoof'; valid "
                                                    r"names: \['world', 'pelvis'"):
        retargeting.calibrate(retargeting.load_mapping(_with(pair0_target="left_hoof")), skel, g1)
    with pytest.raises(jaxanim.JaxanimError, match=r"root.source: unknown source joint 'Pelvis'"):
        retargeting.calibrate(retargeting.load_mapping(_with(root={"source": "Pelvis", "target": "pelvis"})), skel, g1)
    hand_as_foot = _with()
    hand_as_foot["pairs"][2]["foot"] = True
    with pytest.raises(jaxanim.JaxanimError, match=r"pairs\[2\] is a foot, but in the source rest pose it is not "
                                                    r"below the root"):
        retargeting.calibrate(retargeting.load_mapping(hand_as_foot), skel, g1)
    bad = tmp_path / "bad.json"
    bad.write_text("{\"root\": ", encoding="utf-8")
    with pytest.raises(jaxanim.JaxanimError, match=r"bad.json: not valid JSON"):
        retargeting.load_mapping(bad)


def test_the_shipped_humanoid_and_map():
    """The package's own humanoid: MuJoCo compiles it, its soles stand on the ground at qpos0, its joints
    and bodies are named and ordered as the G1's (so a map serves both), and the shipped map of the walk
    calibrates on it and on the G1."""
    path = robots.default_robot_path()
    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    soles = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"{s}_foot") for s in ("left", "right")]
    np.testing.assert_allclose(data.site_xpos[soles, 2], 0.0, atol=1e-12)
    g1_path = shared_data_dir() / "robots" / "unitree_g1" / "g1.xml"
    g1_model = mujoco.MjModel.from_xml_path(str(g1_path))
    names = lambda m, kind, n: [mujoco.mj_id2name(m, kind, i) for i in range(n)]  # noqa: E731
    assert names(model, mujoco.mjtObj.mjOBJ_JOINT, model.njnt) == names(g1_model, mujoco.mjtObj.mjOBJ_JOINT,
                                                                         g1_model.njnt)
    assert names(model, mujoco.mjtObj.mjOBJ_BODY, model.nbody) == names(g1_model, mujoco.mjtObj.mjOBJ_BODY,
                                                                        g1_model.nbody)
    assert (model.nq, model.nv) == (36, 35)
    skel, _ = jaxanim.read_bvh(jaxanim.default_clip_path())
    m = retargeting.load_mapping(retargeting.default_mapping_path())
    for robot in (robots.load_robot(path), robots.load_robot(g1_path)):
        cal = retargeting.calibrate(m, skel, robot)
        assert 0.5 < float(cal.scale) < 1.0 and np.all(np.isfinite(np.asarray(cal.offset)))
