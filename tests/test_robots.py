"""jaxanim.robots (issue 30, step 1): loading MJCF / URDF, FK, Jacobians and the centre of mass.

References (independent of jaxanim): MuJoCo 4.0.0's ``mj_kinematics``, ``mj_comPos``,
``mj_jacBody`` and ``mj_jacSite`` for the MJCF models, Pinocchio 4.0.0 for the URDF, both stored
in ``shared/data/robots/<model>.refs.npz`` (read in place, never copied), plus live MuJoCo and
Pinocchio on small models written here (ball and slide joints, a hinge ``ref``, several joints in one
body, a second tree, URDF continuous / prismatic / fixed joints).

Pinocchio's conventions differ from ours (MuJoCo's), so the URDF adapter converts explicitly:
its ``q`` stores the free flyer's quaternion **xyzw** (ours wxyz), its joints are in its own
depth-first order (matched here by joint name through ``joint_idx_q`` / ``joint_idx_v``), and its
free-flyer velocity is ``[linear, angular]`` **both in the root link's local frame**, whereas
our free joint's linear part is in world coordinates (angular local, as Pinocchio). With
``v_world = R_root v_local``, Pinocchio's three linear columns are ours times ``R_root``.
"""

from __future__ import annotations

import dataclasses
import functools
import re
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanim import robots
from jaxanim._errors import JaxanimError

from .conftest import SHARED_DATA, shared_data_dir
from .helpers import assert_close, count_traces

mujoco = pytest.importorskip("mujoco")

_ATOL_F64 = 1e-13  # m for positions, plain numbers for rotation and Jacobian entries (measured: 2.7e-15)
_ATOL_F32 = 2e-6  # measured on the G1: 4.2e-7
_ROBOTS = SHARED_DATA / "robots"
MJCF = {
    "g1": "unitree_g1/g1.xml",
    "cmu": "cmu_humanoid/humanoid_CMU.xml",
    "cmu2020": "cmu_humanoid/humanoid_CMU_V2020.xml",
}


def _refs(rel: str) -> dict:
    shared_data_dir()
    return dict(np.load(_ROBOTS / re.sub(r"\.(xml|urdf)$", ".refs.npz", rel)))


def _prefixed(kind: str, names) -> list[str]:
    return [f"{kind}:{n}" for n in names]


def _program(robot: robots.Robot, bodies: tuple[str, ...], sites: tuple[str, ...]):
    """FK, the body and site Jacobians and the centre of mass as one program over a batch (one
    compile per model: the four share their kinematics)."""

    def one(q):
        fk = robots.forward_kinematics(robot, q)
        return fk, robots.jacobian(robot, q, bodies), robots.jacobian(robot, q, sites), robots.center_of_mass(robot, q)

    return jax.jit(jax.vmap(one))


@functools.cache
def _mjcf(key: str, dtype: str = "float64"):
    """``(robot, refs, out)``: the model, its references and our values on the reference
    configurations followed by ``qpos0`` (row -1). Body Jacobians for the reference bodies, site
    Jacobians for every site."""
    ref = _refs(MJCF[key])
    robot = robots.load_robot(_ROBOTS / MJCF[key], dtype=dtype)
    q = np.concatenate([ref["qpos"], ref["qpos0"][None]], axis=0).astype(dtype)
    bodies = tuple(_prefixed("body", ref["jac_body_names"]))
    sites = tuple(_prefixed("site", robot.site_names))
    out = jax.device_get(_program(robot, bodies, sites)(q))
    return robot, ref, out


@functools.cache
def _mujoco_site_jacobians(key: str) -> tuple[np.ndarray, np.ndarray]:
    """Live ``mj_jacSite`` of every site on the reference configurations (the refs store some)."""
    m = mujoco.MjModel.from_xml_path(str(_ROBOTS / MJCF[key]))
    d = mujoco.MjData(m)
    qs = _refs(MJCF[key])["qpos"]
    jp = np.zeros((len(qs), m.nsite, 3, m.nv))
    jr = np.zeros_like(jp)
    for n, q in enumerate(qs):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        for s in range(m.nsite):
            mujoco.mj_jacSite(m, d, jp[n, s], jr[n, s], s)
    return jp, jr


# --- MJCF models against MuJoCo ----------------------------------------------------------------------


@pytest.mark.parametrize("key", sorted(MJCF))
def test_mjcf_structure_is_mujocos(key):
    robot, ref, _ = _mjcf(key)
    assert robot.body_names == tuple(ref["body_names"])
    assert robot.body_parents == (-1,) + tuple(int(p) for p in ref["body_parentid"][1:])
    assert robot.jnt_names == tuple(ref["jnt_names"]) and robot.jnt_types == tuple(ref["jnt_type"])
    assert robot.jnt_bodies == tuple(ref["jnt_bodyid"]) and robot.jnt_qposadr == tuple(ref["jnt_qposadr"])
    assert robot.jnt_dofadr == tuple(ref["jnt_dofadr"])
    assert robot.jnt_limited == tuple(bool(x) for x in ref["jnt_limited"])
    assert (robot.nq, robot.nv) == (int(ref["nq"]), int(ref["nv"]))
    assert robot.site_names == tuple(ref["site_names"]) and robot.site_bodies == tuple(ref["site_bodyid"])
    lim = np.asarray(robot.jnt_limited)
    assert_close("jnt_range (limited)", np.asarray(robot.jnt_range)[lim], ref["jnt_range"][lim])
    unbounded = np.asarray(robot.jnt_range)[~lim]
    assert np.all(unbounded == [-np.inf, np.inf]), "jnt_range (not limited): expected (-inf, inf)"
    assert_close("jnt_pos", robot.jnt_pos, ref["jnt_pos"])
    assert_close("jnt_axis", robot.jnt_axis, ref["jnt_axis"])
    assert_close("body_mass", robot.body_mass, ref["body_mass"])
    assert_close("qpos0", robot.qpos0, ref["qpos0"])
    assert robot.body_index(robot.body_names[-1]) == robot.num_bodies - 1


@pytest.mark.parametrize("key", sorted(MJCF))
def test_mjcf_fk_matches_mujoco_float64(key):
    _, ref, (fk, _, _, _) = _mjcf(key)
    for field in ("xpos", "xmat", "xipos", "site_xpos", "site_xmat"):
        assert_close(field, getattr(fk, field)[:-1], ref[field], atol=_ATOL_F64)
    sign = np.sign(np.sum(fk.xquat[:-1] * ref["xquat"], axis=-1, keepdims=True))  # q and -q: one rotation
    assert_close("xquat (up to sign)", fk.xquat[:-1] * sign, ref["xquat"], atol=_ATOL_F64)
    assert np.all(fk.xquat[..., 0] >= 0), "xquat: expected the canonical sign, w >= 0"
    assert_close("xpos at qpos0", fk.xpos[-1], ref["xpos0"], atol=_ATOL_F64)
    assert_close("xmat at qpos0", fk.xmat[-1], ref["xmat0"], atol=_ATOL_F64)


@pytest.mark.parametrize("key", sorted(MJCF))
def test_mjcf_jacobians_and_com_match_mujoco_float64(key):
    robot, ref, (_, (jacp, jacr), (site_jacp, site_jacr), com) = _mjcf(key)
    assert jacp.shape == (len(ref["qpos"]) + 1,) + ref["jac_body_jacp"].shape[1:]
    assert_close("jac_body_jacp", jacp[:-1], ref["jac_body_jacp"], atol=_ATOL_F64)
    assert_close("jac_body_jacr", jacr[:-1], ref["jac_body_jacr"], atol=_ATOL_F64)
    k = [robot.site_index(n) for n in ref["jac_site_names"]]
    assert_close("jac_site_jacp", site_jacp[:-1, k], ref["jac_site_jacp"], atol=_ATOL_F64)
    assert_close("jac_site_jacr", site_jacr[:-1, k], ref["jac_site_jacr"], atol=_ATOL_F64)
    live_p, live_r = _mujoco_site_jacobians(key)  # every site, live MuJoCo
    assert_close("site jacp (live mj_jacSite)", site_jacp[:-1], live_p, atol=_ATOL_F64)
    assert_close("site jacr (live mj_jacSite)", site_jacr[:-1], live_r, atol=_ATOL_F64)
    assert_close("center_of_mass", com[:-1], ref["subtree_com_root"], atol=_ATOL_F64)


def test_free_joint_columns_follow_mujocos_convention():
    """Free joint: the linear columns are the world axes (identity), the angular ones the base's
    ``xmat`` columns (angular velocity in the body frame), for every body."""
    robot, _, (fk, (jacp, jacr), _, _) = _mjcf("g1")
    pelvis = robot.body_index("pelvis")
    cols = robot.dof_slice("floating_base_joint")
    eye = np.broadcast_to(np.eye(3), jacp.shape[:2] + (3, 3))
    assert_close("jacp linear columns", jacp[:, :, :, cols][..., :3], eye)
    assert_close("jacr angular columns", jacr[:, :, :, cols][..., 3:],
                 np.broadcast_to(fk.xmat[:, pelvis][:, None], jacr.shape[:2] + (3, 3)), atol=1e-15)


def test_float32_matches_mujoco_to_1e_4():
    robot, ref, (fk, (jacp, jacr), _, com) = _mjcf("g1", "float32")
    assert robot.body_pos.dtype == jnp.float32 and robot.qpos0.dtype == jnp.float32
    assert fk.xpos.dtype == np.float32 and jacp.dtype == np.float32 and com.dtype == np.float32
    assert_close("xpos", fk.xpos[:-1], ref["xpos"], atol=_ATOL_F32)
    assert_close("xmat", fk.xmat[:-1], ref["xmat"], atol=_ATOL_F32)
    assert_close("site_xpos", fk.site_xpos[:-1], ref["site_xpos"], atol=_ATOL_F32)
    assert_close("jac_body_jacp", jacp[:-1], ref["jac_body_jacp"], atol=_ATOL_F32)
    assert_close("jac_body_jacr", jacr[:-1], ref["jac_body_jacr"], atol=_ATOL_F32)
    assert_close("center_of_mass", com[:-1], ref["subtree_com_root"], atol=_ATOL_F32)


# --- the URDF against Pinocchio -----------------------------------------------------------------------

ROMEO = "romeo/romeo_small.urdf"


def _pinocchio_to_ours(robot, ref, q_pin: np.ndarray) -> np.ndarray:
    """Pinocchio's q -> our qpos, by joint name; the free flyer's xyzw quaternion becomes wxyz."""
    q = np.zeros(robot.nq)
    for name, a in zip(ref["joint_names"], ref["joint_idx_q"]):
        s = robot.qpos_slice(str(name))
        if s.stop - s.start == 7:
            x, y, z, w = q_pin[a + 3 : a + 7]
            q[s] = np.r_[q_pin[a : a + 3], w, x, y, z]
        else:
            q[s] = q_pin[a]
    return q


@functools.cache
def _romeo():
    ref = _refs(ROMEO)
    with pytest.warns(UserWarning, match=r"romeo_small.urdf: 20 collision mesh\(es\) skipped"):  # absent meshes
        robot = robots.load_robot(_ROBOTS / ROMEO, floating_base=True)
    q = np.stack([_pinocchio_to_ours(robot, ref, x) for x in np.concatenate([ref["qpos"], ref["q_neutral"][None]])])
    out = jax.device_get(_program(robot, tuple(_prefixed("body", ref["jac_frame_names"])), ())(q))
    return robot, ref, out


def test_urdf_structure_and_ranges_match_pinocchio():
    robot, ref, _ = _romeo()
    assert (robot.nq, robot.nv) == (int(ref["nq"]), int(ref["nv"]))
    assert set(robot.body_names) == {"world"} | set(ref["link_names"])  # fixed links stay bodies
    assert set(robot.jnt_names) == set(ref["joint_names"])
    assert robot.jnt_names[0] == "root_joint" and robot.jnt_types[0] == "free" and not robot.jnt_limited[0]
    for name, lo, hi in zip(ref["joint_names"][1:], ref["joint_lower"][1:], ref["joint_upper"][1:]):
        j = robot.joint_index(str(name))
        assert robot.jnt_types[j] == "hinge" and robot.jnt_limited[j], name
        assert_close(f"jnt_range[{name}]", robot.jnt_range[j], [lo, hi])
    with pytest.warns(UserWarning, match="collision mesh"):
        fixed = robots.load_robot(_ROBOTS / ROMEO)  # no free flyer: the root link is fixed to the world
    assert (fixed.nq, fixed.nv) == (robot.nq - 7, robot.nv - 6) and "root_joint" not in fixed.jnt_names


def test_urdf_fk_and_jacobians_match_pinocchio_float64():
    robot, ref, (fk, (jacp, jacr), _, _) = _romeo()
    links = [robot.body_index(str(n)) for n in ref["link_names"]]
    assert_close("link_pos", fk.xpos[:-1, links], ref["link_pos"], atol=_ATOL_F64)
    assert_close("link_rot", fk.xmat[:-1, links], ref["link_rot"], atol=_ATOL_F64)
    assert_close("link_pos at q_neutral", fk.xpos[-1, links], ref["link_pos0"], atol=_ATOL_F64)
    assert_close("link_rot at q_neutral", fk.xmat[-1, links], ref["link_rot0"], atol=_ATOL_F64)
    # our columns -> Pinocchio's: reorder by joint name, then the free flyer's linear columns times R_root
    perm = np.zeros(robot.nv, dtype=np.int64)
    for name, a in zip(ref["joint_names"], ref["joint_idx_v"]):
        s = robot.dof_slice(str(name))
        perm[a : a + s.stop - s.start] = np.arange(s.start, s.stop)
    R_root = fk.xmat[:-1, robot.body_index("base_link")]
    for field, ours in (("jacp", jacp[:-1]), ("jacr", jacr[:-1])):
        ours = ours[..., perm].copy()
        ours[..., :3] = np.einsum("nkxa,nab->nkxb", ours[..., :3], R_root)
        assert_close(field, ours, ref[field], atol=_ATOL_F64)


_SMALL_URDF = """<robot name="small">
  <link name="base"><inertial><origin xyz="0 0 0.1"/><mass value="2"/>
    <inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><geometry><mesh filename="package://nowhere/base.stl"/></geometry></visual></link>
  <link name="wheel"/>
  <link name="rail"/>
  <link name="arm"><inertial><mass value="1"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><geometry><mesh filename="package://nowhere/arm.stl"/></geometry></collision></link>
  <link name="tool"/>
  <joint name="spin" type="continuous"><parent link="base"/><child link="wheel"/>
    <origin xyz="0.1 0 0.2" rpy="0.3 -0.2 0.1"/><axis xyz="0 0 1"/></joint>
  <joint name="push" type="prismatic"><parent link="base"/><child link="rail"/>
    <origin xyz="0 0.1 0" rpy="0 0.5 0"/><axis xyz="1 0 0"/>
    <limit lower="-0.1" upper="0.3" effort="1" velocity="1"/></joint>
  <joint name="bend" type="revolute"><parent link="rail"/><child link="arm"/>
    <origin xyz="0.2 0 0" rpy="0 0 0.7"/><axis xyz="0 0.6 0.8"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <joint name="tool_joint" type="fixed"><parent link="arm"/><child link="tool"/>
    <origin xyz="0.3 0 0" rpy="1 0 0"/></joint>
</robot>
"""


def test_small_urdf_continuous_prismatic_fixed_match_pinocchio(tmp_path):
    """Joint kinds the Romeo file lacks, links without inertia, meshes that do not exist."""
    pin = pytest.importorskip("pinocchio")
    path = tmp_path / "small.urdf"
    path.write_text(_SMALL_URDF)
    with pytest.warns(UserWarning, match=r"collision mesh\(es\) skipped"):  # meshes that do not exist
        robot = robots.load_robot(path, floating_base=True)
    assert robot.body_names == ("world", "base", "wheel", "rail", "arm", "tool")  # depth first, <joint> order
    assert robot.jnt_names == ("root_joint", "spin", "push", "bend")
    assert robot.jnt_types == ("free", "hinge", "slide", "hinge")
    assert robot.jnt_limited == (False, False, True, True)
    assert np.all(np.asarray(robot.jnt_range[1]) == [-np.inf, np.inf])
    pm = pin.buildModelFromXML(_SMALL_URDF, pin.JointModelFreeFlyer())
    pd = pm.createData()
    rng = np.random.default_rng(3)
    fk = jax.jit(jax.vmap(lambda q: robots.forward_kinematics(robot, q)))
    qs, expected = [], []
    for _ in range(4):
        quat = rng.normal(size=4)
        quat /= np.linalg.norm(quat)
        base, spin, push, bend = rng.uniform(-1, 1, 3), rng.uniform(-3, 3), rng.uniform(-0.1, 0.3), rng.uniform(-1, 1)
        qs.append(np.r_[base, quat, spin, push, bend])
        q_pin = np.zeros(pm.nq)  # Pinocchio: xyzw, and a continuous joint is (cos, sin)
        q_pin[:7] = np.r_[base, quat[1:], quat[0]]
        a = {n: pm.joints[pm.getJointId(n)].idx_q for n in ("spin", "push", "bend")}
        q_pin[a["spin"] : a["spin"] + 2] = np.cos(spin), np.sin(spin)
        q_pin[a["push"]], q_pin[a["bend"]] = push, bend
        pin.framesForwardKinematics(pm, pd, q_pin)
        expected.append([(pd.oMf[pm.getFrameId(n, pin.FrameType.BODY)].translation.copy(),
                          pd.oMf[pm.getFrameId(n, pin.FrameType.BODY)].rotation.copy()) for n in robot.body_names[1:]])
    out = jax.device_get(fk(np.asarray(qs)))
    assert_close("xpos", out.xpos[:, 1:], np.array([[p for p, _ in e] for e in expected]), atol=_ATOL_F64)
    assert_close("xmat", out.xmat[:, 1:], np.array([[R for _, R in e] for e in expected]), atol=_ATOL_F64)


# --- ball, slide, hinge ref, several joints per body, two trees: live MuJoCo ----------------------------

_TINY = """<mujoco model="tiny">
  <compiler angle="degree"/>
  <worldbody>
    <body name="base" pos="0.1 0.2 0.3" euler="10 20 30">
      <freejoint name="free"/>
      <inertial pos="0.01 0 0.02" mass="2" diaginertia="0.1 0.1 0.1"/>
      <site name="base_site" pos="0.05 0 0" euler="0 90 0"/>
      <body name="arm" pos="0 0.2 0" quat="1 0.2 0 0.1">
        <joint name="twist" type="hinge" axis="1 0 0" pos="0 0.05 0"/>
        <joint name="ball" type="ball" pos="0.01 0.02 0.03"/>
        <inertial pos="0 0.1 0" mass="1" diaginertia="0.01 0.01 0.01"/>
        <body name="slider" pos="0.3 0 0">
          <joint name="slide" type="slide" axis="1 1 0" range="-0.1 0.2" ref="0.05"/>
          <joint name="hinge_a" type="hinge" axis="0 0 1" pos="0.02 0 0" ref="15"/>
          <joint name="hinge_b" type="hinge" axis="0 1 1" pos="0 0.01 0" range="-30 60"/>
          <inertial pos="0.05 0 0" mass="0.5" diaginertia="0.01 0.01 0.01"/>
          <site name="tip" pos="0.1 0 0"/>
          <body name="fixed_child" pos="0 0 0.1" euler="0 0 45">
            <inertial pos="0 0 0.01" mass="0.2" diaginertia="0.001 0.001 0.001"/>
            <site name="fixed_tip" pos="0.05 0.05 0" quat="0.9 0.1 0.3 0"/>
          </body>
        </body>
      </body>
    </body>
    <body name="post" pos="1 0 0">
      <geom type="box" size=".1 .1 .1"/>
      <body name="flap" pos="0 0 0.2">
        <joint name="flap" type="hinge" axis="1 0 0"/><geom type="sphere" size="0.05" pos="0 0.1 0"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


@pytest.fixture(scope="module")
def tiny_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("tiny") / "tiny.xml"
    path.write_text(_TINY)
    return path


@pytest.fixture(scope="module")
def tiny(tiny_path):
    """``(robot, mj_model, qs)``: the tiny model and random configurations (quaternions not unit)."""
    robot = robots.load_robot(tiny_path)
    m = mujoco.MjModel.from_xml_string(_TINY)
    rng = np.random.default_rng(7)
    qs = np.tile(m.qpos0, (5, 1))
    for n in range(5):
        for j in range(m.njnt):
            a, t = m.jnt_qposadr[j], m.jnt_type[j]
            if t == mujoco.mjtJoint.mjJNT_FREE:
                qs[n, a : a + 7] = np.r_[rng.uniform(-1, 1, 3), 1.3 * rng.normal(size=4)]
            elif t == mujoco.mjtJoint.mjJNT_BALL:
                qs[n, a : a + 4] = 0.7 * rng.normal(size=4)
            else:
                qs[n, a] = rng.uniform(-2, 2)
    return robot, m, qs


def _frames(robot) -> tuple[str, ...]:
    """Every body but the world, then every site: the frames whose Jacobians the tiny model's tests take, in one
    call (one compiled program, batched or not, shared by the tests below)."""
    return tuple(robot.body_names[1:]) + tuple(robot.site_names)


@pytest.fixture(scope="module")
def tiny_batched(tiny):
    """Our values on the tiny model's configurations, batched by ``vmap``, as one compiled program: FK, the
    Jacobians of :func:`_frames`, the centre of mass and the base's subtree centre of mass."""
    robot, _, qs = tiny

    def one(q):
        return (robots.forward_kinematics(robot, q), robots.jacobian(robot, q, _frames(robot)),
                robots.center_of_mass(robot, q), robots.center_of_mass(robot, q, body="base"))

    return jax.device_get(jax.jit(jax.vmap(one))(qs))


def _mujoco_all(m, q, bodies, sites):
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    jb = [np.zeros((2, 3, m.nv)) for _ in bodies]
    js = [np.zeros((2, 3, m.nv)) for _ in sites]
    for b, J in zip(bodies, jb):
        mujoco.mj_jacBody(m, d, J[0], J[1], b)
    for s, J in zip(sites, js):
        mujoco.mj_jacSite(m, d, J[0], J[1], s)
    return d, np.array(jb), np.array(js)


def test_ball_slide_and_multi_joint_bodies_match_live_mujoco(tiny, tiny_batched):
    robot, m, qs = tiny
    assert robot.jnt_types == ("free", "hinge", "ball", "slide", "hinge", "hinge", "hinge")
    assert robot.jnt_limited == (False, False, False, True, False, True, False)
    fk, (jacp, jacr), com, com_base = tiny_batched
    nb = robot.num_bodies - 1  # the Jacobians' rows: the bodies, then the sites
    (jacp, sjacp), (jacr, sjacr) = (jacp[:, :nb], jacp[:, nb:]), (jacr[:, :nb], jacr[:, nb:])
    base = robot.body_index("base")
    for n, q in enumerate(qs):
        d, jb, js = _mujoco_all(m, q, range(1, m.nbody), range(m.nsite))
        assert_close(f"xpos[{n}]", fk.xpos[n], d.xpos, atol=_ATOL_F64)
        assert_close(f"xmat[{n}]", fk.xmat[n], d.xmat.reshape(-1, 3, 3), atol=_ATOL_F64)
        assert_close(f"xipos[{n}]", fk.xipos[n], d.xipos, atol=_ATOL_F64)
        assert_close(f"site_xpos[{n}]", fk.site_xpos[n], d.site_xpos, atol=_ATOL_F64)
        assert_close(f"site_xmat[{n}]", fk.site_xmat[n], d.site_xmat.reshape(-1, 3, 3), atol=_ATOL_F64)
        assert_close(f"jacp[{n}]", jacp[n], jb[:, 0], atol=_ATOL_F64)
        assert_close(f"jacr[{n}]", jacr[n], jb[:, 1], atol=_ATOL_F64)
        assert_close(f"site jacp[{n}]", sjacp[n], js[:, 0], atol=_ATOL_F64)
        assert_close(f"site jacr[{n}]", sjacr[n], js[:, 1], atol=_ATOL_F64)
        assert_close(f"center_of_mass[{n}] (subtree_com[0])", com[n], d.subtree_com[0], atol=_ATOL_F64)
        assert_close(f"center_of_mass(body='base')[{n}]", com_base[n], d.subtree_com[base], atol=_ATOL_F64)


@pytest.mark.parametrize("fn", ["forward_kinematics", "jacobian", "center_of_mass"])
def test_vmap_equals_a_python_loop(tiny, tiny_batched, fn):
    """The batched values are ``tiny_batched``'s (``vmap`` of the three, one program); each call of the loop
    is the unbatched program, which the tests below reuse."""
    robot, _, qs = tiny
    k, call = {
        "forward_kinematics": (0, lambda q: robots.forward_kinematics(robot, q)),
        "jacobian": (1, lambda q: robots.jacobian(robot, q, _frames(robot))),  # bodies and sites in one call
        "center_of_mass": (2, lambda q: robots.center_of_mass(robot, q)),
    }[fn]
    batched = tiny_batched[k]
    looped = [call(q) for q in qs]
    for n, single in enumerate(looped):
        for b, s in zip(jax.tree.leaves(batched), jax.tree.leaves(single), strict=True):
            assert_close(f"{fn}[{n}]", b[n], s, atol=1e-14)


def test_jacobian_columns_are_derivatives_of_the_positions(tiny):
    """``jacfwd`` of the body and site positions along each hinge and slide coordinate and the free
    joint's position equals that column of ``jacp``; the derivative is finite at ``qpos0`` (identity
    quaternions). One compiled ``jacfwd`` (eager, it compiled its ops one by one)."""
    robot, _, qs = tiny

    @jax.jit
    def dpositions(q):  # [bodies + sites, 3, nq], the rows of _frames
        return jax.jacfwd(lambda q: (lambda fk: jnp.concatenate([fk.xpos[1:], fk.site_xpos]))(
            robots.forward_kinematics(robot, q)))(q)

    for q in (jnp.asarray(qs[0]), robot.qpos0):
        dpos = np.asarray(dpositions(q))
        assert np.all(np.isfinite(dpos)), "d xpos, site_xpos / d qpos: not finite"
        jacp, _ = jax.device_get(robots.jacobian(robot, q, _frames(robot)))
        for j, t in enumerate(robot.jnt_types):
            a, d = robot.jnt_qposadr[j], robot.jnt_dofadr[j]
            n = {"hinge": 1, "slide": 1, "free": 3}.get(t, 0)
            if n:
                assert_close(f"jacp[{robot.jnt_names[j]}]", jacp[..., d : d + n], dpos[..., a : a + n], atol=1e-12)


def test_compiles_once_per_robot_structure(tiny, tiny_path):
    """New qpos values, and a robot loaded again from the same file, reuse the compiled programs (the tiny
    model's, which the tests above compiled: on the G1 the three programs took 2.8 s to compile)."""
    robot, _, qs = tiny
    calls = (
        lambda r, q: robots.forward_kinematics(r, q),
        lambda r, q: robots.jacobian(r, q, _frames(r)),
        lambda r, q: robots.center_of_mass(r, q),
    )
    for f in calls:
        jax.block_until_ready(f(robot, qs[0]))
    again = robots.load_robot(tiny_path)
    with count_traces() as traces:
        for f in calls:
            jax.block_until_ready(f(robot, qs[1]))
            jax.block_until_ready(f(again, jnp.asarray(qs[2])))
    assert traces == [0], f"retraced {traces[0]} times"


def test_every_product_states_precision_highest(tiny):
    robot, _, qs = tiny
    for name, f in (
        ("forward_kinematics", robots.forward_kinematics),
        ("jacobian", lambda r, q: robots.jacobian(r, q, ["tip"])),
        ("center_of_mass", robots.center_of_mass),
    ):
        text = jax.jit(f).lower(robot, qs[0].astype(np.float32)).as_text()
        dots = [line for line in text.splitlines() if re.search(r"stablehlo\.(dot_general|dot)\b", line)]
        assert dots or name != "center_of_mass", name  # FK and Jacobians multiply 3 x 3 blocks elementwise
        bad = [line for line in dots if "precision = [HIGHEST, HIGHEST]" not in line]
        assert not bad, f"{name}: {len(bad)} of {len(dots)} dots without precision HIGHEST"


# --- bad input ------------------------------------------------------------------------------------------


def test_wrong_qpos_shape_names_the_argument_and_nq(tiny):
    robot, _, qs = tiny
    for f in (robots.forward_kinematics, robots.center_of_mass, lambda r, q: robots.jacobian(r, q, ["tip"])):
        expected = f"qpos: expected shape (nq,) = ({robot.nq},), got ({robot.nq - 1},)"
        with pytest.raises(JaxanimError, match=re.escape(expected)):
            f(robot, qs[0, :-1])
    with pytest.raises(JaxanimError, match="robot: expected a jaxanim.robots.Robot"):
        robots.forward_kinematics("tiny", qs[0])


def test_unknown_names_list_the_valid_ones(tiny):
    robot, _, qs = tiny
    valid = r"valid names: \['world', 'base'.*'fixed_tip'\]"
    with pytest.raises(JaxanimError, match=r"unknown body or site 'hand'; " + valid):
        robots.jacobian(robot, qs[0], ["tip", "hand"])
    with pytest.raises(JaxanimError, match=r"unknown site 'arm'; valid names: \['base_site', 'tip', 'fixed_tip'\]"):
        robots.jacobian(robot, qs[0], ["site:arm"])
    with pytest.raises(JaxanimError, match=r"unknown body 'hand'; valid body names: \['world', 'base', 'arm'"):
        robot.body_index("hand")
    with pytest.raises(JaxanimError, match=r"unknown joint 'elbow'; valid joint names: \['free', 'twist', 'ball'"):
        robot.qpos_slice("elbow")
    with pytest.raises(JaxanimError, match=r"unknown site 'hand'"):
        robot.site_index("hand")
    with pytest.raises(JaxanimError, match=r"unknown body 'hand'"):
        robots.center_of_mass(robot, qs[0], body="hand")


def test_a_name_that_is_a_body_and_a_site_must_say_which():
    robot, ref, _ = _mjcf("cmu")  # a body, a joint and a site are all called "root"
    with pytest.raises(JaxanimError, match=r"'root' is both a body and a site; write 'body:root' or 'site:root'"):
        robots.jacobian(robot, ref["qpos"][0], ["lfoot", "root"])


def test_massless_bodies_have_no_centre_of_mass(tiny):
    robot, _, qs = tiny
    massless = eqx.tree_at(lambda r: r.body_mass, robot, jnp.zeros_like(robot.body_mass))
    with pytest.raises(eqx.EquinoxRuntimeError, match="the bodies have no mass"):
        jax.block_until_ready(robots.center_of_mass(massless, qs[0]))


def test_robot_checks_its_fields(tiny):
    robot = tiny[0]
    expected = f"qpos0: expected shape (nq,) = ({robot.nq},), got ({robot.nq - 1},)"
    with pytest.raises(JaxanimError, match=re.escape(expected)):
        dataclasses.replace(robot, qpos0=robot.qpos0[:-1])
    with pytest.raises(JaxanimError, match="body_parents: bodies must be topologically sorted"):
        dataclasses.replace(robot, body_parents=(-1, 0, 3, 2, 3, 0, 5))
    with pytest.raises(JaxanimError, match=r"jnt_types: unknown joint types \['planar'\]"):
        dataclasses.replace(robot, jnt_types=("planar",) + robot.jnt_types[1:])


def test_a_file_that_does_not_parse_names_its_path(tmp_path):
    bad = tmp_path / "broken.xml"
    bad.write_text("<mujoco><worldbody><body name='a'></worldbody></mujoco>")
    with pytest.raises(robots.RobotLoadError, match=re.escape(str(bad)) + ": not well-formed XML: mismatched tag"):
        robots.load_robot(bad)
    wrong = tmp_path / "wrong.xml"
    wrong.write_text("<mujoco><worldbody><body name='a'><joint type='spiral'/></body></worldbody></mujoco>")
    with pytest.raises(robots.RobotLoadError, match=re.escape(str(wrong)) + r": .*spiral") as info:
        robots.load_robot(wrong)
    assert isinstance(info.value, JaxanimError) and info.value.path == str(wrong)
    other = tmp_path / "other.xml"
    other.write_text("<sdf/>")
    with pytest.raises(robots.RobotLoadError, match=r"root element is <sdf>"):
        robots.load_robot(other)


def test_a_missing_file_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match=re.escape(str(tmp_path / "nope.urdf"))):
        robots.load_robot(tmp_path / "nope.urdf")


def test_without_mujoco_loading_says_which_extra_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "mujoco", None)  # `import mujoco` now raises ImportError
    with pytest.raises(ImportError, match=re.escape("pip install 'jaxanim[robots]'")):
        robots.load_robot(_ROBOTS / MJCF["g1"])


def test_floating_base(tmp_path):
    shared_data_dir()
    robot = robots.load_robot(_ROBOTS / MJCF["cmu2020"], floating_base=True)  # dm_control attaches it so
    assert (robot.jnt_names[0], robot.jnt_types[0], robot.nq, robot.nv) == ("root_joint", "free", 63, 62)
    with pytest.raises(robots.RobotLoadError, match="the root body 'pelvis' already has joints"):
        robots.load_robot(_ROBOTS / MJCF["g1"], floating_base=True)


def test_mesh_files_are_never_needed(tmp_path):
    path = tmp_path / "meshy.xml"
    path.write_text("""<mujoco><asset><mesh name="m" file="missing.stl"/>
      <texture name="t" type="2d" file="missing.png"/>
      <material name="mat" texture="t"/></asset><worldbody>
      <body name="a" pos="0 0 1"><freejoint/><geom type="mesh" mesh="m" material="mat"/><geom type="sphere" size="0.1"/>
        <body name="b" pos="0 0 0.5"><joint type="hinge"/><inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/>
          <geom type="mesh" mesh="m"/></body></body></worldbody></mujoco>""")
    with pytest.warns(UserWarning, match=r"took their mass from those geoms.*\['a'\]"):
        robot = robots.load_robot(path)
    assert robot.body_names == ("world", "a", "b") and robot.jnt_types == ("free", "hinge")
    assert_close("body_mass", robot.body_mass[2], 1.0)


# --- collision geometry ---------------------------------------------------------------------------------

_GEOM_NAMES = {int(getattr(mujoco.mjtGeom, f"mjGEOM_{t.upper()}")): t
               for t in ("sphere", "capsule", "box", "cylinder", "ellipsoid", "mesh")}


def _assert_geoms_are_mujocos(robot, model) -> None:
    keep = [g for g in range(model.ngeom) if model.geom_bodyid[g] > 0 and int(model.geom_type[g]) in _GEOM_NAMES]
    assert robot.geom_bodies == tuple(int(b) for b in model.geom_bodyid[keep]), "field: geom_bodies"
    assert robot.geom_types == tuple(_GEOM_NAMES[int(t)] for t in model.geom_type[keep]), "field: geom_types"
    for field in ("geom_size", "geom_pos", "geom_quat"):
        assert_close(field, getattr(robot, field), getattr(model, field)[keep])


@pytest.mark.parametrize("key", ["humanoid", "g1", "cmu"])
def test_geoms_are_mujocos(key):
    """The Robot's geoms are MuJoCo's ``model.geom_*`` (the shipped humanoid's capsules, boxes and spheres,
    the G1's spheres and cylinders, the CMU humanoid's capsules and ellipsoids; its floor plane, on the
    world, left out)."""
    path = robots.default_robot_path() if key == "humanoid" else shared_data_dir() / "robots" / MJCF[key]
    robot, model = robots.load_robot(path), mujoco.MjModel.from_xml_path(str(path))
    _assert_geoms_are_mujocos(robot, model)
    assert len(robot.geom_bodies) == sum(1 for g in range(model.ngeom) if model.geom_bodyid[g] > 0)
    kinds = {"humanoid": {"capsule", "box", "sphere"}, "g1": {"sphere", "cylinder"}, "cmu": {"capsule", "ellipsoid"}}
    assert kinds[key] <= set(robot.geom_types), robot.geom_types
    # the retargeting's robot edits keep them
    floating = robots.with_floating_base(robot) if robot.jnt_types[0] != "free" else robot
    more = robots.with_surface_points(floating, [1], [[0.0, 0.0, -0.1]])
    for r in (floating, more):
        assert (r.geom_bodies, r.geom_types) == (robot.geom_bodies, robot.geom_types)
        assert_close("geom_quat", r.geom_quat, robot.geom_quat)


def test_mesh_geoms_are_kept_and_planes_are_not(tiny):
    """A mesh given by its vertices (no file) is a geom of type "mesh"; planes are left out; the tiny model's
    box and sphere are MuJoCo's; a robot built without geoms has none."""
    xml = """<mujoco><asset><mesh name="wedge" vertex="0 0 0  0.2 0 0  0 0.1 0  0 0 0.3"/></asset><worldbody>
      <geom type="plane" size="1 1 0.1"/>
      <body name="a" pos="0 0 1"><freejoint/><geom type="mesh" mesh="wedge" pos="0.1 0 0"/>
        <geom type="cylinder" size="0.05 0.2" euler="0 90 0"/></body></worldbody></mujoco>"""
    robot = robots.robot_from_mujoco(mujoco.MjModel.from_xml_string(xml))
    assert robot.geom_types == ("mesh", "cylinder") and robot.geom_bodies == (1, 1)
    _assert_geoms_are_mujocos(robot, mujoco.MjModel.from_xml_string(xml))
    _assert_geoms_are_mujocos(tiny[0], tiny[1])
    bare = robots.Robot(**{f.name: getattr(tiny[0], f.name) for f in dataclasses.fields(tiny[0])
                           if not f.name.startswith("geom_")})  # the defaults: no geoms
    assert (bare.geom_bodies, bare.geom_types) == ((), ())
    assert (bare.geom_size.shape, bare.geom_pos.shape, bare.geom_quat.shape) == ((0, 3), (0, 3), (0, 4))


def test_robot_checks_its_geom_fields(tiny):
    robot = tiny[0]
    G = len(robot.geom_bodies)
    with pytest.raises(JaxanimError, match=re.escape(f"geom_quat: expected shape (geoms, 4) = ({G}, 4), got ({G}, 3)")):
        dataclasses.replace(robot, geom_quat=robot.geom_quat[:, :3])
    with pytest.raises(JaxanimError, match=r"geom_types: unknown geom types \['cone'\]; valid: \['sphere', "):
        dataclasses.replace(robot, geom_types=("cone",) + robot.geom_types[1:])
    with pytest.raises(JaxanimError, match=rf"geom_types: expected {G} entries \(one per geom in geom_bodies\)"):
        dataclasses.replace(robot, geom_types=robot.geom_types[1:])
    with pytest.raises(JaxanimError, match=r"geom_bodies: geom 0 is on body 0, expected 1 <= body < 7 \(not the world\)"):
        dataclasses.replace(robot, geom_bodies=(0,) + robot.geom_bodies[1:])


def test_host_body_frames_match_live_mujoco(tiny):
    """The NumPy FK of many frames (for writing results) against MuJoCo on the tiny model's free, ball, slide and
    multi-joint bodies, and its quaternions against MuJoCo's (``w >= 0``)."""
    from jaxanim.robots._host import body_frames_host
    from jaxanim.rotations._numpy import matrix_to_quat

    robot, m, qs = tiny
    xpos, xmat = body_frames_host(robot, qs)
    xquat = matrix_to_quat(xmat)
    for n, q in enumerate(qs):
        d = mujoco.MjData(m)
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        assert_close(f"xpos[{n}]", xpos[n], d.xpos, atol=_ATOL_F64)
        assert_close(f"xmat[{n}]", xmat[n], d.xmat.reshape(-1, 3, 3), atol=_ATOL_F64)
        mj_quat = d.xquat * np.where(d.xquat[:, :1] < 0, -1.0, 1.0)
        assert_close(f"xquat[{n}]", xquat[n], mj_quat, atol=_ATOL_F64)


@pytest.mark.parametrize("key", sorted(MJCF))
def test_host_body_frames_match_mujoco_on_the_shared_robots(key):
    from jaxanim.robots._host import body_frames_host

    path = shared_data_dir() / "robots" / MJCF[key]
    robot = robots.load_robot(path)
    m = mujoco.MjModel.from_xml_path(str(path))
    rng = np.random.default_rng(3)
    qs = np.tile(m.qpos0, (4, 1))
    qs[:, 7:] += rng.uniform(-1, 1, (4, m.nq - 7))
    qs[:, :7] = np.c_[rng.uniform(-1, 1, (4, 3)), rng.normal(size=(4, 4))]
    xpos, xmat = body_frames_host(robot, qs)
    d = mujoco.MjData(m)
    for n, q in enumerate(qs):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        assert_close(f"xpos[{n}]", xpos[n], d.xpos, atol=_ATOL_F64)
        assert_close(f"xmat[{n}]", xmat[n], d.xmat.reshape(-1, 3, 3), atol=_ATOL_F64)
