"""Retargeting onto the robot files users have, as they are (issue 58, item 2): URDF collision geometry kept
(primitives, meshes resolved through ``package://`` and ``ROS_PACKAGE_PATH``, missing meshes skipped with one
warning), a free joint added where the root has none, and a footprint for feet without geometry.

References: the URDF text itself, parsed here with ElementTree (collision origins and sizes), the STL files read
here with numpy (mesh vertices), and the README's diagnostics thresholds for the retargeted clips. The URDF robots
come straight from their packages: Romeo from ``../shared/data/robots`` (its collision meshes are absent) and TALOS
and the G1 from PyPI's ``example-robot-data`` wheel (the test extra), with their meshes.
"""

from __future__ import annotations

import importlib.metadata
import json
import pathlib
import re
import warnings
import xml.etree.ElementTree as ET

import jax
import numpy as np
import pytest

import jaxanim
from jaxanim import retargeting, robots

from .conftest import shared_data_dir

#: What the README claims for a retargeted clip (as tests/test_robots_retarget.py).
SLIDE = 1e-3  # m/s, median stance slide
PENETRATION = 1e-3  # m
RANGE = 1e-6

ROMEO_MAP = {
    "root": {"source": "Hips", "target": "body"},
    "pairs": [
        {"source": "LeftFoot", "target": "l_sole", "foot": True, "orientation_weight": 0.5},
        {"source": "RightFoot", "target": "r_sole", "foot": True, "orientation_weight": 0.5},
        {"source": "LeftLeg", "target": "LKneePitchLink", "orientation_weight": 0.0},
        {"source": "RightLeg", "target": "RKneePitchLink", "orientation_weight": 0.0},
        {"source": "Chest", "target": "torso", "orientation_weight": 0.5},
        {"source": "LeftForeArm", "target": "LElbowYawLink", "position_weight": 0.5, "orientation_weight": 0.01},
        {"source": "RightForeArm", "target": "RElbowYawLink", "position_weight": 0.5, "orientation_weight": 0.01},
        {"source": "LeftHand", "target": "l_wrist", "position_weight": 0.5, "orientation_weight": 0.1},
        {"source": "RightHand", "target": "r_wrist", "position_weight": 0.5, "orientation_weight": 0.1},
    ],
}

TALOS_MAP = {
    "root": {"source": "Hips", "target": "base_link"},
    "pairs": [
        {"source": "LeftFoot", "target": "leg_left_6_link", "foot": True, "orientation_weight": 0.5},
        {"source": "RightFoot", "target": "leg_right_6_link", "foot": True, "orientation_weight": 0.5},
        {"source": "LeftLeg", "target": "leg_left_4_link", "orientation_weight": 0.0},
        {"source": "RightLeg", "target": "leg_right_4_link", "orientation_weight": 0.0},
        {"source": "Chest", "target": "torso_2_link", "orientation_weight": 0.5},
        {"source": "LeftForeArm", "target": "arm_left_4_link", "position_weight": 0.5, "orientation_weight": 0.01},
        {"source": "RightForeArm", "target": "arm_right_4_link", "position_weight": 0.5, "orientation_weight": 0.01},
        {"source": "LeftHand", "target": "arm_left_7_link", "position_weight": 0.5, "orientation_weight": 0.1},
        {"source": "RightHand", "target": "arm_right_7_link", "position_weight": 0.5, "orientation_weight": 0.1},
    ],
}


def _romeo_path() -> pathlib.Path:
    return shared_data_dir() / "robots" / "romeo" / "romeo_small.urdf"


def _package_robot(rel: str) -> pathlib.Path:
    """A URDF of the example-robot-data wheel (the test extra), as installed."""
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed (pip install -e '.[test]')")
    path = pathlib.Path(dist.locate_file(f"cmeel.prefix/share/example-robot-data/robots/{rel}"))
    if not path.is_file():
        pytest.skip(f"{rel} is not in the installed example-robot-data")
    return path


def _load_quiet(path, **kw) -> robots.Robot:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return robots.load_robot(path, **kw)


def _stl_vertices(path: pathlib.Path) -> np.ndarray:
    """The vertices of a binary or ASCII STL file (numpy only)."""
    data = path.read_bytes()
    n = int(np.frombuffer(data[80:84], "<u4")[0]) if len(data) >= 84 else -1
    if len(data) == 84 + 50 * n:
        tri = np.frombuffer(data[84:], np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]))
        return tri["v"].reshape(-1, 3).astype(np.float64)
    return np.array(re.findall(rb"vertex\s+(\S+)\s+(\S+)\s+(\S+)", data), np.float64)


def _body_points(robot: robots.Robot, name: str) -> tuple[np.ndarray, np.ndarray]:
    b = robot.body_index(name)
    idx = [i for i, pb in enumerate(robot.point_bodies) if pb == b]
    return np.asarray(robot.point_pos, np.float64)[idx], np.asarray(robot.point_radius, np.float64)[idx]


def test_urdf_sphere_collisions_are_kept_as_written():
    """The G1's URDF (its package's, as it is) collides through spheres under each foot: they are the foot's
    surface points, at their ``<origin>``, with their radius."""
    path = _package_robot("g1_description/urdf/g1_29dof_rev_1_0.urdf")
    robot = _load_quiet(path)
    link = next(e for e in ET.parse(path).getroot().iter("link") if e.get("name") == "left_ankle_roll_link")
    spheres = [(np.array(c.find("origin").get("xyz").split(), float), float(c.find("geometry/sphere").get("radius")))
               for c in link.findall("collision") if c.find("geometry/sphere") is not None]
    assert len(spheres) == 4
    pos, radius = _body_points(robot, "left_ankle_roll_link")
    order = np.lexsort(pos.T)
    want = np.array([s[0] for s in spheres])
    np.testing.assert_allclose(pos[order], want[np.lexsort(want.T)], atol=1e-12)
    np.testing.assert_allclose(radius, [s[1] for s in spheres], atol=1e-12)


def test_urdf_mesh_collisions_resolve_through_package_paths():
    """TALOS's feet collide through STL meshes named ``package://example-robot-data/...``: resolved against the
    URDF's parent folders, the foot's points are the mesh's extreme vertices (its lowest among them)."""
    path = _package_robot("talos_data/robots/talos_reduced.urdf")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # every mesh of this package resolves: no warning
        robot = robots.load_robot(path)
    link = next(e for e in ET.parse(path).getroot().iter("link") if e.get("name") == "leg_left_6_link")
    mesh = link.find("collision/geometry/mesh")
    stl = path.parents[3] / mesh.get("filename").removeprefix("package://example-robot-data/")
    vertices = _stl_vertices(stl) * np.array(mesh.get("scale", "1 1 1").split(), float)
    origin = link.find("collision/origin")
    assert origin is None or np.allclose(np.array(origin.get("xyz", "0 0 0").split(), float), 0.0)
    pos, radius = _body_points(robot, "leg_left_6_link")
    assert 4 <= len(pos) <= 9 and np.all(radius == 0)
    # its underside: the extreme vertex along each downward direction (MuJoCo stores mesh vertices in float32)
    for u in [(x, y, -1.0) for x in (-1, 0, 1) for y in (-1, 0, 1)]:
        assert abs(np.max(pos @ u) - np.max(vertices @ u)) < 1e-6, u
    assert abs(np.min(pos[:, 2]) - np.min(vertices[:, 2])) < 1e-6
    gap = np.min(np.linalg.norm(pos[:, None] - vertices[None], axis=-1), axis=1)  # each point is a vertex
    assert np.max(gap) < 1e-6


def test_package_path_from_ros_package_path_and_missing_meshes_warn_once(tmp_path, monkeypatch):
    """A ``package://`` mesh found through ``ROS_PACKAGE_PATH`` gives its vertices; a missing one and a format
    MuJoCo does not read are skipped, both named in one warning; primitives stay."""
    mesh_dir = tmp_path / "ws" / "my_robot" / "meshes"
    mesh_dir.mkdir(parents=True)
    corners = np.array([[x, y, z] for x in (-0.1, 0.1) for y in (-0.05, 0.05) for z in (-0.02, 0.0)])
    faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1), (2, 3, 7), (2, 7, 6), (0, 2, 6),
             (0, 6, 4), (1, 5, 7), (1, 7, 3)]
    tri = np.zeros(len(faces), np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]))
    tri["v"] = corners[np.array(faces)]
    (mesh_dir / "foot.stl").write_bytes(b"\0" * 80 + np.uint32(len(faces)).tobytes() + tri.tobytes())  # binary STL
    (mesh_dir / "shin.dae").write_text("<COLLADA/>")
    urdf = tmp_path / "robot" / "robot.urdf"
    urdf.parent.mkdir()
    urdf.write_text("""<robot name="r">
  <link name="base"><inertial><mass value="1"/><inertia ixx="1" iyy="1" izz="1" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><geometry><box size="0.2 0.2 0.2"/></geometry></collision></link>
  <joint name="hip" type="revolute"><parent link="base"/><child link="shin"/><origin xyz="0 0 -0.1"/>
    <axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <link name="shin"><inertial><mass value="1"/><inertia ixx="1" iyy="1" izz="1" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><geometry><mesh filename="package://my_robot/meshes/shin.dae"/></geometry></collision>
    <collision><geometry><mesh filename="package://my_robot/meshes/gone.stl"/></geometry></collision></link>
  <joint name="ankle" type="revolute"><parent link="shin"/><child link="foot"/><origin xyz="0 0 -0.4"/>
    <axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <link name="foot"><inertial><mass value="1"/><inertia ixx="1" iyy="1" izz="1" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0.03 0 0"/><geometry><mesh filename="package://my_robot/meshes/foot.stl"/></geometry>
    </collision></link>
</robot>""")
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(tmp_path / "ws"))
    with pytest.warns(UserWarning) as record:
        robot = robots.load_robot(urdf)
    assert len(record) == 1
    message = str(record[0].message)
    assert "2 collision mesh(es) skipped" in message and "gone.stl (not found)" in message
    assert "shin.dae (a .dae file, which MuJoCo does not read)" in message
    pos, _ = _body_points(robot, "foot")
    bottom = corners[corners[:, 2] < -0.01] + [0.03, 0, 0]  # the underside of the box-shaped mesh
    np.testing.assert_allclose(pos[np.lexsort(pos.T)], bottom[np.lexsort(bottom.T)], atol=1e-6)
    assert len(_body_points(robot, "base")[0]) == 8 and len(_body_points(robot, "shin")[0]) == 0
    monkeypatch.delenv("ROS_PACKAGE_PATH")
    with pytest.warns(UserWarning, match=r"3 collision mesh\(es\) skipped.*foot.stl \(not found\)"):
        robots.load_robot(urdf)


def test_with_floating_base_equals_loading_with_one():
    path = _romeo_path()
    added, loaded = robots.with_floating_base(_load_quiet(path)), _load_quiet(path, floating_base=True)
    for field in added.__dataclass_fields__:
        a, b = getattr(added, field), getattr(loaded, field)
        if isinstance(a, (tuple, int, str)):
            assert a == b, field
        else:
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=field)
    assert added.jnt_names[0] == "root_joint" and added.nq == 38
    with pytest.raises(jaxanim.JaxanimError, match="already has joints"):
        robots.with_floating_base(added)


def test_a_foot_without_geometry_stands_on_its_frame():
    """Romeo's feet collide through absent meshes: each stands on its sole frame, with the map's footprint, or
    a default from the leg length that a warning states."""
    romeo = _load_quiet(_romeo_path())
    sized = json.loads(json.dumps(ROMEO_MAP))
    sized["pairs"][0]["sole"] = {"size": [0.22, 0.1]}
    sized["pairs"][1]["sole"] = {"size": [0.22, 0.1]}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with_soles, added = retargeting.with_soles(romeo, retargeting.load_mapping(sized))
    assert len(added) == 8 and len(with_soles.point_bodies) == len(romeo.point_bodies) + 8
    for foot in ("l_sole", "r_sole"):  # the sole targets are bodies: the corners sit in their frames
        pos, radius = _body_points(with_soles, foot)
        np.testing.assert_allclose(np.sort(np.abs(pos), axis=0), [[0.11, 0.05, 0.0]] * 4, atol=1e-12)
        assert pos[:, 0].min() < 0 < pos[:, 0].max() and pos[:, 1].min() < 0 < pos[:, 1].max()
        assert np.all(radius == 0)
    with pytest.warns(UserWarning, match=r"the feet \['l_sole 0\.\d+ x 0\.\d+ m', 'r_sole .*leg length"):
        retargeting.with_soles(romeo, retargeting.load_mapping(ROMEO_MAP))
    with pytest.raises(jaxanim.JaxanimError, match=r"pairs\[0\]\.sole"):
        retargeting.load_mapping({**sized, "pairs": [{**sized["pairs"][0], "sole": {"size": [0.2]}}]})


def _check_clip(summary) -> None:
    assert summary["foot_slide"] <= SLIDE, summary
    assert summary["penetration"] <= PENETRATION, summary
    assert summary["range_violation"] <= RANGE, summary


def test_cli_retargets_the_shared_urdf_as_it_is(tmp_path, capsys):
    """``jaxanim retarget --robot romeo_small.urdf --map MAP.json``: a URDF with no free joint and feet whose
    collision meshes are absent, as shipped. The free joint comes first in qpos; ``--fixed-base`` refuses it."""
    from jaxanim.app import main

    map_path = tmp_path / "romeo.json"
    map_path.write_text(json.dumps(ROMEO_MAP))
    out = tmp_path / "romeo.npz"
    code = main(["--no-compile-cache", "retarget", "--robot", str(_romeo_path()), "--map", str(map_path),
                 "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "collision mesh(es) skipped" in captured.err and "adds one, 'root_joint'" in captured.err
    with np.load(out) as z:
        assert z["qpos"].shape == (120, 38) and str(z["joint_names"][0]) == "root_joint"
        assert bool(z["success"]) and np.all(np.isfinite(z["qpos"]))
    slide = re.search(r"stance foot slide \(median\) ([\d.]+) mm/s, penetration ([\d.]+) mm", captured.out)
    violation = re.search(r"joint-range violation ([\d.e+-]+),", captured.out)
    _check_clip({"foot_slide": float(slide[1]) * 1e-3, "penetration": float(slide[2]) * 1e-3,
                 "range_violation": float(violation[1])})
    code = main(["--no-compile-cache", "retarget", "--robot", str(_romeo_path()), "--map", str(map_path),
                 "--out", str(tmp_path / "fixed.npz"), "--fixed-base"])
    assert code != 0 and "--fixed-base" in capsys.readouterr().err
    assert not (tmp_path / "fixed.npz").exists()


def test_a_mesh_footed_urdf_stands_on_its_meshes():
    """TALOS as its package ships it (mesh feet, no free joint): the problem adds the free joint and no sole, and
    each foot target stands at the height of its mesh's lowest vertex (the STL read here) above the ground."""
    path = _package_robot("talos_data/robots/talos_reduced.urdf")
    robot = _load_quiet(path)
    skel, walk = jaxanim.read_bvh(jaxanim.default_clip_path())
    problem = retargeting.prepare_retarget(skel, walk, robot, TALOS_MAP)
    assert problem.floating and problem.added_points == ()
    assert retargeting.prepared_robot(robot, problem).jnt_names[0] == "root_joint"
    link = next(e for e in ET.parse(path).getroot().iter("link") if e.get("name") == "leg_left_6_link")
    mesh = link.find("collision/geometry/mesh")
    stl = path.parents[3] / mesh.get("filename").removeprefix("package://example-robot-data/")
    lowest = np.min(_stl_vertices(stl)[:, 2] * float(mesh.get("scale", "1 1 1").split()[2]))
    fk = robots.forward_kinematics(robot, robot.qpos0)
    R = np.asarray(fk.xmat)[robot.body_index("leg_left_6_link")]
    assert np.allclose(R, np.eye(3), atol=1e-9)  # the foot is level in the zero pose: its height is its mesh's
    # its sole is rounded (its underside's points lie within 9 mm of the lowest): the plane fitted through them
    # tilts by a fraction of a degree, which moves the height by about a millimetre (1.2 mm)
    np.testing.assert_allclose(np.asarray(problem.foot_height), [-lowest] * 2, atol=2e-3)


def test_cli_retargets_the_v2020_walker_that_lies_in_its_zero_pose(tmp_path, capsys):
    """dm_control's V2020 CMU walker, as it is: no free joint, and its zero pose stands along +Y (dm_control turns
    it when it attaches it to an arena). ``--map auto`` finds its map, retargeting adds the free joint and turns
    its zero pose up (``retargeting.upright``), and the clip meets the README's thresholds."""
    from jaxanim.app import main

    path = shared_data_dir() / "robots" / "cmu_humanoid" / "humanoid_CMU_V2020.xml"
    robot = robots.with_floating_base(robots.load_robot(path))
    skel, _ = jaxanim.read_bvh(jaxanim.default_clip_path())
    mapping = retargeting.auto_map(skel, robot)
    stood = retargeting.upright(robot, mapping)
    for r, up in ((robot, 1), (stood, 2)):  # the root above the feet: along +Y, then along +Z
        fk = robots.forward_kinematics(r, r.qpos0)
        feet = np.mean([np.asarray(fk.xpos)[r.body_index(t)] for t, f in zip(mapping.targets, mapping.feet) if f], 0)
        v = np.asarray(fk.xpos)[r.body_index(mapping.root_target.removeprefix("body:"))] - feet
        assert v[up] > 0.9 * np.linalg.norm(v), (up, v)
    np.testing.assert_array_equal(np.asarray(stood.qpos0[7:]), np.asarray(robot.qpos0[7:]))  # the joints as they were
    g1 = robots.load_robot(shared_data_dir() / "robots" / "unitree_g1" / "g1.xml")
    assert retargeting.upright(g1, retargeting.load_mapping(retargeting.default_mapping_path())) is g1
    out = tmp_path / "v2020.npz"
    code = main(["--no-compile-cache", "retarget", "--robot", str(path), "--map", "auto", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    slide = re.search(r"stance foot slide \(median\) ([\d.]+) mm/s, penetration ([\d.]+) mm", captured.out)
    violation = re.search(r"joint-range violation ([\d.e+-]+),", captured.out)
    _check_clip({"foot_slide": float(slide[1]) * 1e-3, "penetration": float(slide[2]) * 1e-3,
                 "range_violation": float(violation[1])})


def test_retarget_map_prints_a_urdfs_missing_meshes_as_a_warning(tmp_path, capsys):
    """``jaxanim retarget-map --robot romeo_small.urdf``: the meshes that are not shipped are one warning line
    on stderr (not a Python warning), and the map is written."""
    from jaxanim.app import main

    out = tmp_path / "romeo.json"
    assert main(["--no-compile-cache", "retarget-map", "--robot", str(_romeo_path()), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "warning:" in err and "collision mesh" in err
    assert json.loads(out.read_text())["root"]["target"]
