"""The retargeting map found from the shapes of the clip and the robot (issue 58 item 3): the hand-written
maps found again (the shipped walk onto the shipped humanoid, the CMU clip onto the G1 and onto
dm_control's CMU humanoids), Romeo's links, the same maps with every name scrambled and in other BVH
dialects, left and right from geometry (a mirrored clip swaps them), a Z-up source, the errors, and
``jaxanim retarget-map``."""

from __future__ import annotations

import dataclasses
import functools
import json
import warnings

import numpy as np
import pytest

import jaxanim
from jaxanim import retargeting, robots
from jaxanim.app import main

from .conftest import shared_data_dir
from .helpers import CMU_TO_CMU, CMU_TO_G1

pytest.importorskip("mujoco")

#: Romeo (URDF, meshes missing, so no collision geometry): the feet are the sole frames; of the two links at the
#: elbow (LElbowRollLink, LElbowYawLink) the deeper; the wrist is the last moving link (l_gripper is fixed).
CMU_TO_ROMEO = {
    "root": {"source": "Hips", "target": "base_link"},
    "pairs": [
        {"source": "LeftFoot", "target": "l_sole", "foot": True, "orientation_weight": 0.5},
        {"source": "RightFoot", "target": "r_sole", "foot": True, "orientation_weight": 0.5},
        {"source": "LeftLeg", "target": "LKneePitchLink", "orientation_weight": 0.0},
        {"source": "RightLeg", "target": "RKneePitchLink", "orientation_weight": 0.0},
        {"source": "Spine1", "target": "torso", "orientation_weight": 0.5},
        {"source": "LeftForeArm", "target": "LElbowYawLink", "position_weight": 0.5, "orientation_weight": 0.01},
        {"source": "RightForeArm", "target": "RElbowYawLink", "position_weight": 0.5, "orientation_weight": 0.01},
        {"source": "LeftHand", "target": "l_wrist", "position_weight": 0.5, "orientation_weight": 0.1},
        {"source": "RightHand", "target": "r_wrist", "position_weight": 0.5, "orientation_weight": 0.1},
    ],
}
#: dm_control's 2020 CMU walker: the same bodies, but a site is named "lwrist" too; it stands Y-up (no free joint).
CMU_TO_V2020 = {**CMU_TO_CMU, "pairs": [
    {**p, "target": "body:lwrist"} if p["target"] == "lwrist" else p for p in CMU_TO_CMU["pairs"]]}

CMU_BVH = "bvh/cmu_01_01_trim300.bvh"
G1 = "robots/unitree_g1/g1.xml"
CMU_HUMANOID = "robots/cmu_humanoid/humanoid_CMU.xml"
V2020 = "robots/cmu_humanoid/humanoid_CMU_V2020.xml"
ROMEO = "robots/romeo/romeo_small.urdf"

#: Other BVH dialects, as renamings of the shipped walk's joints (the same skeleton under their names).
LAFAN1 = {"Chest": "Spine2", "LeftToeBase": "LeftToe", "RightToeBase": "RightToe"}
MIXAMO = {"Chest": "Spine2"}  # then every name gets the "mixamorig:" prefix
GAMES105 = {
    "Hips": "RootJoint", "Spine": "pelvis_lowerback", "Chest": "lowerback_torso", "Neck": "torso_head",
    "Head": "head_top", **{f"{side}{a}": f"{s}{b}" for side, s in (("Left", "l"), ("Right", "r")) for a, b in (
        ("Shoulder", "Torso_Clavicle"), ("Arm", "Shoulder"), ("ForeArm", "Elbow"), ("Hand", "Wrist"), ("UpLeg", "Hip"),
        ("Leg", "Knee"), ("Foot", "Ankle"), ("ToeBase", "ToeJoint"))},
}


@functools.cache
def _robot(rel: str | None = None, floating_base: bool = False) -> robots.Robot:
    """A robot loaded once per module run (its zero-pose FK then compiles once)."""
    path = robots.default_robot_path() if rel is None else shared_data_dir() / rel
    with warnings.catch_warnings():  # Romeo's URDF names mesh files that are not shipped; loading says so
        warnings.simplefilter("ignore", UserWarning)
        return robots.load_robot(path, floating_base=floating_base)


@functools.cache
def _skeleton(rel: str | None = None) -> jaxanim.Skeleton:
    return jaxanim.read_bvh(jaxanim.default_clip_path() if rel is None else shared_data_dir() / rel)[0]


def _rebuilt(skel: jaxanim.Skeleton, *, names=None, offsets=None, end_site_offsets=None) -> jaxanim.Skeleton:
    return jaxanim.Skeleton(tuple(skel.names if names is None else names), skel.parents,
                            np.asarray(skel.offsets) if offsets is None else offsets, skel.channels,
                            skel.end_site_parents,
                            np.asarray(skel.end_site_offsets) if end_site_offsets is None else end_site_offsets)


def _without(skel: jaxanim.Skeleton, drop: set[str]) -> jaxanim.Skeleton:
    """The skeleton without the joints ``drop`` (and their subtrees' End Sites); their children must be dropped too."""
    keep = [j for j, n in enumerate(skel.names) if n not in drop]
    new = {j: k for k, j in enumerate(keep)}
    ends = [e for e, p in enumerate(skel.end_site_parents) if p in new]
    return jaxanim.Skeleton(tuple(skel.names[j] for j in keep), tuple(new.get(skel.parents[j], -1) for j in keep),
                            np.asarray(skel.offsets)[keep], tuple(skel.channels[j] for j in keep),
                            tuple(new[skel.end_site_parents[e]] for e in ends), np.asarray(skel.end_site_offsets)[ends])


def _pairs(mapping) -> list[tuple]:
    """A map's content, order included: root, up, and each pair's names, foot flag and weights."""
    m = retargeting.load_mapping(mapping) if isinstance(mapping, dict) else mapping
    return [(m.root_source, m.root_target, m.source_up, m.auto_scale)] + list(zip(
        m.sources, m.targets, m.feet, np.asarray(m.position_weight).tolist(), np.asarray(m.orientation_weight).tolist()))


def _renamed(mapping: dict, source: dict, target: dict) -> dict:
    """``mapping`` with its source joints and robot bodies renamed (a ``body:`` prefix dropped)."""
    def tgt(name):
        return target[name.removeprefix("body:")]
    return {"root": {"source": source[mapping["root"]["source"]], "target": tgt(mapping["root"]["target"])},
            "pairs": [{**p, "source": source[p["source"]], "target": tgt(p["target"])} for p in mapping["pairs"]]}


def test_the_shipped_walk_onto_the_shipped_humanoid_is_the_shipped_map():
    found = retargeting.auto_map(_skeleton(), _robot())
    assert isinstance(found, retargeting.RetargetMap)
    assert _pairs(found) == _pairs(retargeting.load_mapping(retargeting.default_mapping_path()))


@pytest.mark.parametrize(("rel", "floating_base", "expected"), [
    (G1, False, CMU_TO_G1), (CMU_HUMANOID, False, CMU_TO_CMU), (V2020, False, CMU_TO_V2020),
    (ROMEO, True, CMU_TO_ROMEO),
], ids=["g1", "cmu_humanoid", "cmu_humanoid_v2020", "romeo"])
def test_the_cmu_clip_onto_each_robot_is_the_hand_map(rel, floating_base, expected):
    """The G1 faces +X, dm_control's CMU humanoid -Y with splayed legs (and a body, a joint and a site named
    "root"), its V2020 walker stands Y-up without a free joint, Romeo has no collision geometry."""
    mapping = retargeting.auto_map_dict(_skeleton(CMU_BVH), _robot(rel, floating_base))
    assert _pairs(mapping) == _pairs(expected)
    assert set(mapping) == {"root", "pairs", "source_up", "scale"}
    assert all(set(p) == {"source", "target", "foot", "position_weight", "orientation_weight"} for p in mapping["pairs"])
    assert json.loads(json.dumps(mapping)) == mapping


def test_names_are_not_needed():
    """Every source joint, robot body and site renamed to a meaningless name, in a shuffled order: the same map
    (dm_control's CMU humanoid, which faces -Y; its renamed robot compiles its FK once more, so only this one)."""
    skel, robot, expected = _skeleton(CMU_BVH), _robot(CMU_HUMANOID), CMU_TO_CMU
    rng = np.random.default_rng(58)
    source = dict(zip(skel.names, (f"j{k}" for k in rng.permutation(skel.num_joints))))
    target = dict(zip(robot.body_names, (f"b{k}" for k in rng.permutation(robot.num_bodies))))
    scrambled = dataclasses.replace(robot, body_names=tuple(target[n] for n in robot.body_names),
                                    site_names=tuple(f"s{k}" for k in range(robot.num_sites)))
    found = retargeting.auto_map_dict(_rebuilt(skel, names=[source[n] for n in skel.names]), scrambled)
    assert _pairs(found) == _pairs(_renamed(expected, source, target))


@pytest.mark.parametrize(("renames", "prefix"), [(LAFAN1, ""), (MIXAMO, "mixamorig:"), (GAMES105, "")],
                         ids=["lafan1", "mixamo", "games105"])
def test_other_bvh_dialects(renames, prefix):
    skel, robot = _skeleton(), _robot()
    source = {n: prefix + renames.get(n, n) for n in skel.names}
    found = retargeting.auto_map_dict(_rebuilt(skel, names=[source[n] for n in skel.names]), robot)
    shipped = json.loads(retargeting.default_mapping_path().read_text())
    assert _pairs(found) == _pairs(_renamed(shipped, source, {n: n for n in robot.body_names}))


def test_left_and_right_come_from_the_geometry():
    """The walk mirrored (X negated): its Left joints now lie on the right, and drive the right side."""
    skel, robot = _skeleton(), _robot()
    flip = np.array([-1.0, 1.0, 1.0])
    mirrored = _rebuilt(skel, offsets=np.asarray(skel.offsets) * flip,
                        end_site_offsets=np.asarray(skel.end_site_offsets) * flip)
    found = retargeting.auto_map_dict(mirrored, robot)
    swap = {n: n.replace("left_", "@").replace("right_", "left_").replace("@", "right_") for n in robot.body_names}
    shipped = json.loads(retargeting.default_mapping_path().read_text())
    assert sorted(_pairs(found)[1:]) == sorted(_pairs(_renamed(shipped, {n: n for n in skel.names}, swap))[1:])
    assert ("LeftFoot", "right_ankle_roll_link", True, 1.0, 0.5) in _pairs(found)


def test_a_z_up_source():
    """The walk turned Z-up, facing +X (BVH's Y -> Z, Z -> X): source_up "z", the same pairs."""
    skel, robot = _skeleton(), _robot()
    turn = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    found = retargeting.auto_map_dict(_rebuilt(skel, offsets=np.asarray(skel.offsets) @ turn.T,
                                               end_site_offsets=np.asarray(skel.end_site_offsets) @ turn.T), robot)
    shipped = json.loads(retargeting.default_mapping_path().read_text())
    assert found["source_up"] == "z"
    assert _pairs(found)[1:] == _pairs(shipped)[1:]


LEFT_LEG = {"LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase"}
ARMS = {f"{s}{j}" for s in ("Left", "Right") for j in ("Shoulder", "Arm", "ForeArm", "Hand")}


@pytest.mark.parametrize(("drop", "match"), [
    (LEFT_LEG, r"the skeleton has fewer than two legs: only the branch through 'RightUpLeg' reaches down"),
    (ARMS, r"the skeleton has no arms: no joint outside the legs has two branches that go sideways"),
    ({"LeftToeBase", "RightToeBase"}, r"the skeleton's feet do not show which way it faces: .*'LeftFoot'"),
], ids=["one_leg", "no_arms", "no_toes"])
def test_a_tree_that_is_not_a_humanoid_is_named(drop, match):
    with pytest.raises(jaxanim.JaxanimError, match=match):
        retargeting.auto_map(_without(_skeleton(), drop), _robot())


def test_bad_arguments_are_named():
    with pytest.raises(jaxanim.JaxanimError, match=r"robot: expected a Robot"):
        retargeting.auto_map_dict(_skeleton(), "g1.xml")
    with pytest.raises(jaxanim.JaxanimError, match=r"skeleton: expected a Skeleton"):
        retargeting.auto_map_dict(None, _robot())


def test_the_retarget_map_command_writes_the_shipped_map(tmp_path, capsys):
    out = tmp_path / "m.json"
    assert main(["--no-compile-cache", "retarget-map", "--out", str(out)]) == 0
    assert "LeftFoot -> left_ankle_roll_link (foot)" in capsys.readouterr().out
    written = json.loads(out.read_text())
    assert len(out.read_text().splitlines()) == len(written["pairs"]) + 7  # a line per key and per pair
    assert _pairs(retargeting.load_mapping(out)) == _pairs(retargeting.load_mapping(retargeting.default_mapping_path()))
    assert main(["--no-compile-cache", "retarget-map", "--out", str(tmp_path / "m.txt")]) == 2
    assert "expected a .json file" in capsys.readouterr().err
