"""jaxanim.retargeting's motion export (issue 59, item 2): the trainers' formats read back with
independent code.

References: MuJoCo 4's ``mj_kinematics`` (body poses) and ``mj_differentiatePos`` (velocities) on the same
MJCF file, scipy's ``Rotation`` / ``Slerp`` (rotation differences, resampling), plain ``numpy.loadtxt``,
``numpy.load`` (no pickle) and ``pickle``. Adapters: the csv and GMR store quaternions **xyzw** (scipy's
order), MuJoCo and ``body_quat_w`` **wxyz**; converted explicitly below.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from jaxanim import JaxanimError, robots
from jaxanim.retargeting import (
    FORMATS,
    format_suffix,
    qvel_from_qpos,
    resample_qpos,
    write_motion,
)

from .conftest import SHARED_DATA
from .helpers import assert_close

mujoco = pytest.importorskip("mujoco")

_ATOL_FK = 1e-9  # m, and quaternion entries: the written poses against MuJoCo's FK (measured: 7e-16)
_ATOL_QVEL = 1e-12  # rad/s, m/s: qvel against mj_differentiatePos (measured: 5.3e-15 on speeds up to 13)
_ATOL_BODY_VEL = 1e-12  # rad/s, m/s: against differences of MuJoCo's xpos / xquat (measured: 3.4e-14)
_ATOL_SLERP = 1e-12
_FPS, _T = 30.0, 12
_G1 = SHARED_DATA / "robots" / "unitree_g1" / "g1.xml"
_KEYS = ["humanoid", "g1"]


def _path(key: str) -> str:
    if key == "g1":
        if not _G1.is_file():
            pytest.skip(f"the G1 model is not at {_G1} (shared data sits beside the clone in CI)")
        return str(_G1)
    return str(robots.default_robot_path())


def _clip(model, seed: int) -> np.ndarray:
    """``[T, nq]`` a smooth clip: the root moving and turning (yaw past 90 degrees, some roll and pitch),
    every hinge swinging inside its range."""
    rng = np.random.default_rng(seed)
    t = np.arange(_T) / _FPS
    q = np.tile(model.qpos0, (_T, 1))
    q[:, 0:3] = [0.1, -0.2, 0.8] + np.outer(t, [0.9, 0.3, -0.1]) + 0.05 * np.sin(np.outer(t, [3.0, 2.0, 5.0]))
    euler = np.stack([0.3 + 4.0 * t, 0.2 * np.sin(3 * t), 0.15 * np.cos(4 * t)], axis=1)  # z, y, x
    q[:, 3:7] = Rotation.from_euler("ZYX", euler).as_quat(scalar_first=True)
    for j in range(model.njnt):
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE:
            lo, hi = model.jnt_range[j] if model.jnt_limited[j] else (-1.0, 1.0)
            mid, amp = 0.5 * (lo + hi), 0.4 * (hi - lo)
            q[:, model.jnt_qposadr[j]] = mid + amp * np.sin(rng.uniform(2, 6) * t + rng.uniform(0, 2 * np.pi))
    return q


def _pairs(T: int):
    """The documented scheme, written out: ``(a, b, span)`` per frame."""
    return [(max(t - 1, 0), min(t + 1, T - 1), max(min(t + 1, T - 1) - max(t - 1, 0), 1)) for t in range(T)]


def _written(key: str, tmp: str):
    """The clip, the three files written and read back, and MuJoCo's FK of what was read."""
    path = _path(key)
    model = mujoco.MjModel.from_xml_path(path)
    robot = robots.load_robot(path)
    q = _clip(model, seed=7)
    files = {}
    for fmt in ("csv", "beyondmimic", "gmr"):
        files[fmt] = f"{tmp}/{key}{format_suffix(fmt)}"
        write_motion(files[fmt], robot, q, _FPS, fmt)
    csv = np.loadtxt(files["csv"], delimiter=",")
    bm = dict(np.load(files["beyondmimic"]))  # no allow_pickle: every array is a plain one
    with open(files["gmr"], "rb") as f:
        gmr = pickle.load(f)
    # MuJoCo's FK of the written poses: root from the csv (xyzw -> wxyz), the joints from joint_pos
    assert model.nq == 7 + bm["joint_pos"].shape[1], "the test robots are a free root and hinges"
    data = mujoco.MjData(model)
    xpos, xquat, xmat, qpos_read = [], [], [], []
    for t in range(_T):
        data.qpos[:] = np.concatenate([csv[t, 0:3], csv[t, [6, 3, 4, 5]], bm["joint_pos"][t]])
        qpos_read.append(data.qpos.copy())
        mujoco.mj_kinematics(model, data)
        xpos.append(data.xpos.copy()), xquat.append(data.xquat.copy()), xmat.append(data.xmat.reshape(-1, 3, 3).copy())
    mj = {"xpos": np.array(xpos), "xquat": np.array(xquat), "xmat": np.array(xmat), "qpos": np.array(qpos_read)}
    return model, robot, q, csv, bm, gmr, mj


@pytest.fixture(scope="module", params=_KEYS)
def written(request, tmp_path_factory):
    return _written(request.param, str(tmp_path_factory.mktemp(request.param)))


def _same_rotation(name, actual, expected, atol):
    """wxyz quaternions ``[..., 4]`` equal up to sign."""
    actual, expected = np.asarray(actual), np.asarray(expected)
    err = np.minimum(np.abs(actual - expected).max(-1), np.abs(actual + expected).max(-1))
    assert err.max() <= atol, f"field: {name}: max error {err.max():.3g} > {atol}"


def test_beyondmimic_poses_are_mujocos_fk(written):
    model, _, q, _, bm, _, mj = written
    T, nb = _T, model.nbody - 1
    assert set(bm) == {"fps", "joint_pos", "joint_vel", "body_pos_w", "body_quat_w", "body_lin_vel_w",
                       "body_ang_vel_w", "body_names"}
    assert bm["fps"].shape == (1,) and bm["fps"][0] == _FPS
    for k, shape in [("joint_pos", (T, model.nq - 7)), ("joint_vel", (T, model.nv - 6)), ("body_pos_w", (T, nb, 3)),
                     ("body_quat_w", (T, nb, 4)), ("body_lin_vel_w", (T, nb, 3)), ("body_ang_vel_w", (T, nb, 3))]:
        assert bm[k].shape == shape and bm[k].dtype == np.float64, k
    assert list(bm["body_names"]) == [model.body(b).name for b in range(1, model.nbody)]
    assert_close("joint_pos", bm["joint_pos"], q[:, 7:], atol=1e-15)
    assert_close("body_pos_w", bm["body_pos_w"], mj["xpos"][:, 1:], atol=_ATOL_FK)
    _same_rotation("body_quat_w", bm["body_quat_w"], mj["xquat"][:, 1:], _ATOL_FK)


def test_qvel_is_mujocos_differentiate_pos(written):
    model, robot, q, *_ = written
    qn = q.copy()
    qn[:, 3:7] /= np.linalg.norm(qn[:, 3:7], axis=1, keepdims=True)
    expected = np.zeros((_T, model.nv))
    for t, (a, b, span) in enumerate(_pairs(_T)):
        mujoco.mj_differentiatePos(model, expected[t], span / _FPS, qn[a], qn[b])
    qvel = qvel_from_qpos(robot, q, _FPS)
    assert qvel.shape == (_T, model.nv) and qvel.dtype == np.float64
    assert_close("qvel", qvel, expected, atol=_ATOL_QVEL)
    assert_close("joint_vel", written[4]["joint_vel"], expected[:, 6:], atol=_ATOL_QVEL)


def test_qvel_of_one_frame_is_zero(written):
    model, robot, q, *_ = written
    np.testing.assert_array_equal(qvel_from_qpos(robot, q[:1], _FPS), np.zeros((1, model.nv)))


def test_body_velocities_are_differences_of_mujocos_poses(written):
    _, _, _, _, bm, _, mj = written
    xpos, R = mj["xpos"][:, 1:], Rotation.from_quat(mj["xquat"][:, 1:], scalar_first=True)
    lin, ang = np.zeros_like(xpos), np.zeros_like(xpos)
    for t, (a, b, span) in enumerate(_pairs(_T)):
        lin[t] = (xpos[b] - xpos[a]) * _FPS / span
        ang[t] = (R[b] * R[a].inv()).as_rotvec() * _FPS / span  # the world-frame rotation difference
    assert_close("body_lin_vel_w", bm["body_lin_vel_w"], lin, atol=_ATOL_BODY_VEL)
    assert_close("body_ang_vel_w", bm["body_ang_vel_w"], ang, atol=_ATOL_BODY_VEL)


def test_gmr_pickle_as_gmr_writes_it(written):
    model, _, q, _, _, gmr, mj = written
    assert set(gmr) == {"fps", "root_pos", "root_rot", "dof_pos", "local_body_pos", "link_body_list"}
    assert gmr["fps"] == 30 and isinstance(gmr["fps"], int)  # GMR writes its rate as an int (30)
    assert gmr["link_body_list"] == [model.body(b).name for b in range(1, model.nbody)]
    for k, shape in [("root_pos", (_T, 3)), ("root_rot", (_T, 4)), ("dof_pos", (_T, model.nq - 7)),
                     ("local_body_pos", (_T, model.nbody - 1, 3))]:
        assert gmr[k].shape == shape and gmr[k].dtype == np.float64, k
    assert_close("root_pos", gmr["root_pos"], q[:, 0:3], atol=1e-15)
    _same_rotation("root_rot (xyzw -> wxyz)", gmr["root_rot"][:, [3, 0, 1, 2]], q[:, 3:7], 1e-15)
    assert_close("dof_pos", gmr["dof_pos"], q[:, 7:], atol=1e-15)
    # GMR's local_body_pos: FK with the root at the origin, unrotated = the root body's frame
    root = model.jnt_bodyid[0]
    local = np.einsum("tij,tbi->tbj", mj["xmat"][:, root], mj["xpos"][:, 1:] - mj["xpos"][:, root, None])
    assert_close("local_body_pos", gmr["local_body_pos"], local, atol=_ATOL_FK)


def test_csv_columns_and_rows(written):
    model, _, q, csv, *_ = written
    assert csv.shape == (_T, model.nq)  # no header row: every line is numbers
    assert_close("csv root position", csv[:, 0:3], q[:, 0:3], atol=0.0)
    assert_close("csv joints", csv[:, 7:], q[:, 7:], atol=0.0)  # %.17g: the float64 round trip


def test_csv_quaternion_order_and_header(tmp_path):
    robot = robots.load_robot(robots.default_robot_path())
    q = np.tile(np.asarray(robot.qpos0), (2, 1))
    q[:, 3:7] = 2.0 * np.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])  # 90 degrees about z, not unit
    write_motion(tmp_path / "a.csv", robot, q, 30, "csv")
    rows = np.loadtxt(tmp_path / "a.csv", delimiter=",")
    assert_close("csv root quaternion (x, y, z, w)", rows[:, 3:7], [[0.0, 0.0, 0.5**0.5, 0.5**0.5]] * 2, atol=1e-15)
    write_motion(tmp_path / "b.csv", robot, q, 30, "csv", csv_header=True)
    lines = (tmp_path / "b.csv").read_text().splitlines()
    joints = [n for n, t in zip(robot.jnt_names, robot.jnt_types) if t == "hinge"]
    assert lines[0].split(",") == ["root_x", "root_y", "root_z", "root_qx", "root_qy", "root_qz", "root_qw"] + joints
    assert_close("csv with header", np.loadtxt(tmp_path / "b.csv", delimiter=",", skiprows=1), rows, atol=0.0)
    assert (tmp_path / "a.csv").read_text().splitlines()[0] != lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "b.csv"]  # no temporary file left


def test_resample_slerps_against_scipy(written):
    model, robot, q, *_ = written
    balls = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_BALL]
    assert not balls  # the quaternion checked below is the root's
    # doubling: originals at even frames, the slerp / mean of neighbours at odd ones
    up = resample_qpos(robot, q, _FPS, 2 * _FPS)
    assert up.shape == (2 * _T - 1, model.nq)
    R = Rotation.from_quat(q[:, 3:7], scalar_first=True)
    mid = np.array([Slerp([0.0, 1.0], R[t:t + 2])(0.5).as_quat(scalar_first=True) for t in range(_T - 1)])
    _same_rotation("doubled: odd frames' root quaternion", up[1::2, 3:7], mid, _ATOL_SLERP)
    assert_close("doubled: odd frames' additive coordinates", np.delete(up[1::2], np.s_[3:7], 1),
                 np.delete(0.5 * (q[:-1] + q[1:]), np.s_[3:7], 1), atol=1e-14)
    _same_rotation("doubled: even frames' root quaternion", up[::2, 3:7], q[:, 3:7], 1e-15)
    # 30 -> 50 fps: floor(11 * 50 / 30) + 1 = 19 frames at k / 50 s, against scipy over the whole track
    times = np.arange(_T) / _FPS
    out = resample_qpos(robot, q, _FPS, 50)
    tk = np.arange(19) / 50.0
    assert out.shape == (19, model.nq)
    _same_rotation("50 fps root quaternion", out[:, 3:7], Slerp(times, R)(tk).as_quat(scalar_first=True), _ATOL_SLERP)
    lin = np.stack([np.interp(tk, times, q[:, i]) for i in range(model.nq)], axis=1)
    assert_close("50 fps additive coordinates", np.delete(out, np.s_[3:7], 1), np.delete(lin, np.s_[3:7], 1), atol=1e-14)
    assert_close("50 fps unit quaternions", np.linalg.norm(out[:, 3:7], axis=1), np.ones(19), atol=1e-15)
    # same rate: the clip itself
    assert_close("same rate", resample_qpos(robot, q, _FPS, _FPS), q, atol=1e-15)


def test_resample_makes_quaternion_signs_continuous():
    robot = robots.load_robot(robots.default_robot_path())
    q = np.tile(np.asarray(robot.qpos0), (4, 1))
    q[:, 3:7] = Rotation.from_euler("z", [[0.0], [0.1], [0.2], [0.3]]).as_quat(scalar_first=True)
    q[2, 3:7] *= -1  # the same rotation, the other sign
    out = resample_qpos(robot, q, 10, 20)
    assert (np.sum(out[1:, 3:7] * out[:-1, 3:7], axis=1) > 0).all()
    _same_rotation("sign-flipped input", out[::2, 3:7], q[:, 3:7], 1e-15)
    assert_close("midpoint yaw", Rotation.from_quat(out[3, 3:7], scalar_first=True).as_rotvec(), [0, 0, 0.15], atol=1e-15)


def test_formats_and_suffixes():
    assert FORMATS == ("npz", "csv", "beyondmimic", "gmr")
    assert [format_suffix(f) for f in FORMATS] == [".npz", ".csv", ".npz", ".pkl"]
    with pytest.raises(JaxanimError, match=r"format: unknown motion format 'bvh'.*'csv', 'beyondmimic', 'gmr'"):
        format_suffix("bvh")


def test_bad_input_names_the_argument(tmp_path):
    robot = robots.load_robot(robots.default_robot_path())
    q = np.tile(np.asarray(robot.qpos0), (3, 1))
    out = tmp_path / "x.csv"
    nan = q.copy()
    nan[1, 9] = np.nan
    cases = [
        (lambda: write_motion(out, robot, nan, 30, "csv"), r"qpos: expected finite values, got nan at frame 1, coordinate 9"),
        (lambda: write_motion(out, robot, q[:, :-1], 30, "csv"), r"qpos: expected shape \(T, nq\) = \(T, 36\)"),
        (lambda: write_motion(out, robot, q[0], 30, "csv"), r"qpos: expected shape"),
        (lambda: write_motion(out, robot, q[:0], 30, "csv"), r"qpos: expected at least one frame"),
        (lambda: write_motion(out, robot, q, 30, "bvh"), r"format: unknown motion format 'bvh'; valid formats"),
        (lambda: write_motion(out, robot, q, 30, "npz"), r"format: 'npz' .* written by the command line"),
        (lambda: write_motion(out, robot, q, 0, "csv"), r"fps: expected a finite number > 0"),
        (lambda: write_motion(out, robot, q, float("nan"), "gmr"), r"fps: expected a finite number > 0"),
        (lambda: write_motion(out, "robot", q, 30, "csv"), r"robot: expected a jaxanim.robots.Robot"),
        (lambda: qvel_from_qpos(robot, nan, 30), r"qpos: expected finite values"),
        (lambda: qvel_from_qpos(robot, q, -1), r"fps: expected a finite number > 0"),
        (lambda: resample_qpos(robot, q, 30, True), r"new_fps: expected a finite number > 0"),
    ]
    zero = q.copy()
    zero[0, 3:7] = 0.0
    cases.append((lambda: write_motion(out, robot, zero, 30, "csv"), r"qpos: the quaternion at coordinates 3\.\.6 of frame 0"))
    for call, match in cases:
        with pytest.raises(JaxanimError, match=match):
            call()
    assert not any(tmp_path.iterdir())  # nothing written


def test_formats_that_need_a_free_root():
    arm = robots.robot_from_mujoco(mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><joint type='hinge'/><geom size='0.1'/>"
        "<body pos='0 0 0.3'><joint type='ball'/><geom size='0.1'/></body></body></worldbody></mujoco>"))
    q = np.tile(np.asarray(arm.qpos0), (2, 1))
    for fmt, match in [("csv", r"robot: the 'csv' format .* joint 1 .* is a ball joint"),
                       ("beyondmimic", r"robot: the 'beyondmimic' format .* ball joint")]:
        with pytest.raises(JaxanimError, match=match):
            write_motion("never.npz", arm, q, 30, fmt)
    hinge = robots.robot_from_mujoco(mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><joint type='hinge'/><geom size='0.1'/></body></worldbody></mujoco>"))
    with pytest.raises(JaxanimError, match=r"robot: the 'gmr' format needs a robot whose first joint is a free joint"):
        write_motion("never.pkl", hinge, np.zeros((2, 1)), 30, "gmr")
