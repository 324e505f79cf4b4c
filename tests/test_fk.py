"""Forward kinematics against the shared references (scipy / bvhio / Blender) and its inverse."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxanim
from jaxanim import rotations as rot
from jaxanim.kinematics._fk import site_transforms_sequential

from .conftest import shared_bvh_files, shared_data_dir
from .helpers import assert_close, batched_fk, jitted_fk, random_pose, shared_clip, small_skeleton

_RTOL_FK64 = 1e-9  # relative to the largest |position| of the clip
_RTOL_FK32 = 1e-4
_ATOL_ROT64 = 1e-12
_ATOL_ROT32 = 1e-5
_ATOL_INV = 1e-12

STEMS = shared_bvh_files() or ["<shared data absent>"]


@pytest.mark.parametrize("stem", STEMS)
def test_fk_matches_reference_every_frame_float64(stem):
    shared_data_dir()
    skel, motion, ref = shared_clip(stem)
    out = batched_fk()(skel, motion.rotations, motion.translations)
    scale = np.abs(ref["positions"]).max()
    assert_close("positions", out.positions, ref["positions"], atol=_RTOL_FK64 * scale)
    assert_close("rotations", out.rotations, ref["rotations"], atol=_ATOL_ROT64)
    assert_close("end_site_positions", out.end_site_positions, ref["end_site_positions"], atol=_RTOL_FK64 * scale)
    assert list(skel.end_site_names) == list(ref["end_site_names"])


@pytest.mark.parametrize("stem", STEMS)
def test_host_fk_matches_reference_every_frame(stem):
    """The NumPy kinematics that prepares retargeting problems (kinematics._host): the same references."""
    from jaxanim.kinematics._host import clip_frames_host

    shared_data_dir()
    skel, motion, ref = shared_clip(stem)
    rotations, translations = np.asarray(motion.rotations), np.asarray(motion.translations)
    R, p = clip_frames_host(skel, motion.rotations, motion.translations)
    scale = np.abs(ref["positions"]).max()
    assert_close("positions", p, ref["positions"], atol=_RTOL_FK64 * scale)
    assert_close("rotations", R, ref["rotations"], atol=_ATOL_ROT64)
    np.testing.assert_array_equal(np.asarray(motion.rotations), rotations)  # not modified
    np.testing.assert_array_equal(np.asarray(motion.translations), translations)


@pytest.mark.parametrize("stem", STEMS)
def test_fk_matches_reference_float32(stem):
    shared_data_dir()
    skel, motion, ref = shared_clip(stem)
    # converted on the host (eager astype compiles a program per array shape)
    skel32 = jax.tree_util.tree_map(lambda x: jnp.asarray(np.asarray(x, np.float32)), skel)
    q32, t32 = (jnp.asarray(np.asarray(x, np.float32)) for x in (motion.rotations, motion.translations))
    out = batched_fk()(skel32, q32, t32)
    assert out.positions.dtype == jnp.float32
    scale = np.abs(ref["positions"]).max()
    assert_close("positions", out.positions, ref["positions"], atol=_RTOL_FK32 * scale)
    assert_close("rotations", out.rotations, ref["rotations"], atol=_ATOL_ROT32)
    assert_close("end_site_positions", out.end_site_positions, ref["end_site_positions"], atol=_RTOL_FK32 * scale)


@pytest.mark.parametrize("stem", STEMS[:1])
def test_fk_agrees_with_bvhio_and_blender_check_frames(stem):
    shared_data_dir()
    skel, motion, ref = shared_clip(stem)
    out = batched_fk()(skel, motion.rotations, motion.translations)
    k = ref["check_frames"]
    scale = np.abs(ref["positions"]).max()
    for tool in ("bvhio", "blender"):
        assert_close(f"positions_{tool}", np.asarray(out.positions)[k], ref[f"positions_{tool}"], atol=1e-5 * scale)
        assert_close(f"rotations_{tool}", np.asarray(out.rotations)[k], ref[f"rotations_{tool}"], atol=1e-5)


def test_fk_two_link_analytic():
    """A planar chain: p2 = R(a) l1 + R(a + b) l2 (absolute angles are the cumulative sums)."""
    skel = jaxanim.Skeleton(("a", "b", "c"), (-1, 0, 1), jnp.array([[0.0, 0, 0], [1.0, 0, 0], [0.5, 0, 0]]))
    a, b = 0.3, -1.1
    q = rot.euler_to_quat(jnp.array([[a, 0, 0], [b, 0, 0], [0, 0, 0]]), "ZYX")
    out = jaxanim.forward_kinematics(skel, q)
    expect = np.array([np.cos(a) + 0.5 * np.cos(a + b), np.sin(a) + 0.5 * np.sin(a + b), 0.0])
    assert_close("positions[2]", out.positions[2], expect, atol=1e-14)


def test_quaternion_and_matrix_inputs_agree():
    skel = small_skeleton()
    q, t = random_pose(skel, 0)
    a = jitted_fk(skel, q, t)  # jitted (eager FK compiles each op)
    b = jitted_fk(skel, rot.quat_to_matrix(q), t)
    for f in ("rotations", "positions", "end_site_positions"):
        assert_close(f, getattr(a, f), getattr(b, f), atol=1e-14)


def test_vmap_equals_loop_and_nested_vmap():
    skel = small_skeleton()
    q, t = random_pose(skel, 1, n=6)
    # jitted, the vmap and the single-pose FK (eager, each op would compile on its own); the poses are
    # sliced and reshaped on the host (eager indexing and reshapes compile a program each)
    out = batched_fk()(skel, q, t)
    qs, ts = np.asarray(q), np.asarray(t)
    got = {f: np.asarray(getattr(out, f)) for f in ("positions", "rotations", "end_site_positions")}
    for i in range(6):
        one = jitted_fk(skel, jnp.asarray(qs[i]), jnp.asarray(ts[i]))
        for f, batched in got.items():
            assert_close(f, batched[i], getattr(one, f), atol=1e-14)
    nested = jax.jit(jax.vmap(batched_fk(), in_axes=(None, 0, 0)))(
        skel, jnp.asarray(qs.reshape(2, 3, -1, 4)), jnp.asarray(ts.reshape(2, 3, -1, 3))
    )
    assert_close("nested positions", np.asarray(nested.positions).reshape(got["positions"].shape), got["positions"],
                 atol=1e-14)


def test_default_translations_are_offsets():
    skel = small_skeleton()
    q = skel.rest_rotations()
    out = jaxanim.forward_kinematics(skel, q)
    # rest pose: global positions are cumulative offsets
    cum = np.zeros((skel.num_joints, 3))
    off = np.asarray(skel.offsets)
    for j, p in enumerate(skel.parents):
        cum[j] = off[j] + (cum[p] if p >= 0 else 0)
    assert_close("positions", out.positions, cum, atol=1e-15)


def test_wrong_shapes_name_the_argument():
    skel = small_skeleton()
    q, t = random_pose(skel, 2)
    with pytest.raises(jaxanim.JaxanimError, match=r"rotations: expected shape \(joints, 4\) = \(6, 4\)"):
        jaxanim.forward_kinematics(skel, q[:5], t)
    with pytest.raises(jaxanim.JaxanimError, match=r"translations: expected shape \(joints, 3\) = \(6, 3\), got \(6, 4\)"):
        jaxanim.forward_kinematics(skel, q, q)
    with pytest.raises(jaxanim.JaxanimError, match="skeleton: expected a jaxanim.Skeleton"):
        jaxanim.forward_kinematics(q, q, t)
    with pytest.raises(jaxanim.JaxanimError, match=r"global_positions: expected shape \(joints, 3\)"):
        jaxanim.global_to_local(skel, rot.quat_to_matrix(q), t[:2])
    with pytest.raises(jaxanim.JaxanimError, match=r"masses: expected shape \(joints,\) = \(6,\)"):
        jaxanim.center_of_mass(skel, q, t, jnp.ones(5))
    with pytest.raises(jaxanim.JaxanimError, match=r"offsets: expected shape \(joints, 3\) = \(3, 3\)"):
        jaxanim.Skeleton(("a", "b", "c"), (-1, 0, 1), jnp.zeros((2, 3)))
    with pytest.raises(jaxanim.JaxanimError, match="topologically sorted"):
        jaxanim.Skeleton(("a", "b", "c"), (-1, 2, 0), jnp.zeros((3, 3)))


def test_inputs_not_modified():
    skel = small_skeleton()
    q, t = random_pose(skel, 3)
    qn, tn, offn = np.array(q), np.array(t), np.array(skel.offsets)
    jaxanim.forward_kinematics(skel, q, t)
    jaxanim.global_to_local(skel, rot.quat_to_matrix(q), t)
    jaxanim.center_of_mass(skel, q, t, jnp.ones(6))
    np.testing.assert_array_equal(np.asarray(q), qn)
    np.testing.assert_array_equal(np.asarray(t), tn)
    np.testing.assert_array_equal(np.asarray(skel.offsets), offn)


@pytest.mark.parametrize("stem", STEMS[:2])
def test_global_to_local_inverts_fk(stem):
    shared_data_dir()
    skel, motion, _ = shared_clip(stem)
    g2l = jax.jit(jax.vmap(jaxanim.global_to_local, in_axes=(None, 0, 0)))
    fk = batched_fk()
    out = fk(skel, motion.rotations, motion.translations)
    q_loc, t_loc = g2l(skel, out.rotations, out.positions)
    scale = float(np.abs(np.asarray(motion.translations)).max())
    assert_close("translations", t_loc, motion.translations, atol=_ATOL_INV * max(scale, 1.0) * 10)
    same = np.abs(np.sum(np.asarray(q_loc) * np.asarray(motion.rotations), axis=-1))
    assert_close("|<q_loc, q>|", same, np.ones_like(same), atol=_ATOL_INV)
    back = fk(skel, q_loc, t_loc)
    assert_close("FK(global_to_local(FK)) positions", back.positions, out.positions, atol=_ATOL_INV * max(scale, 1.0) * 10)
    assert_close("FK(global_to_local(FK)) rotations", back.rotations, out.rotations, atol=_ATOL_INV)


def test_global_to_local_vmap_equals_loop_small():
    skel = small_skeleton()
    q, t = random_pose(skel, 4, n=6)  # 6 poses: the batched FK of test_vmap_equals_loop_and_nested_vmap serves
    out = batched_fk()(skel, q, t)
    # jitted, the vmap and the single-pose call (eager, each op would compile on its own); sliced on the host
    qb, tb = (np.asarray(x) for x in jax.jit(jax.vmap(jaxanim.global_to_local, in_axes=(None, 0, 0)))(
        skel, out.rotations, out.positions))
    one = eqx.filter_jit(jaxanim.global_to_local)
    R, P, t = np.asarray(out.rotations), np.asarray(out.positions), np.asarray(t)
    for i in range(6):
        qi, ti = one(skel, jnp.asarray(R[i]), jnp.asarray(P[i]))
        assert_close("rotations", qb[i], qi, atol=1e-15)
        assert_close("translations", tb[i], ti, atol=1e-15)
        assert_close("translations vs input", ti, t[i], atol=1e-12)


def _numpy_fk(skel, q, t):
    """Hand-written FK in numpy (loop over the joints, wxyz quaternions to matrices by the formula)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q.T
    R_local = np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)
    t = np.asarray(t, dtype=np.float64)
    R_world, p_world = np.zeros_like(R_local), np.zeros_like(t)
    for j, p in enumerate(skel.parents):
        if p < 0:
            R_world[j], p_world[j] = R_local[j], t[j]
        else:
            R_world[j] = R_world[p] @ R_local[j]
            p_world[j] = p_world[p] + R_world[p] @ t[j]
    es = np.asarray(skel.end_site_offsets)
    p_end = np.stack([p_world[p] + R_world[p] @ es[e] for e, p in enumerate(skel.end_site_parents)])
    return R_world, p_world, p_end


def test_fk_and_center_of_mass_against_numpy():
    """Both against an independent numpy computation: a hand-written FK and the segment centers
    written out by hand for the small skeleton."""
    skel = small_skeleton()
    q, t = random_pose(skel, 5)
    masses = jnp.arange(1.0, 7.0)
    # jitted (eager, each op would compile on its own); the skeleton is a constant (center_of_mass
    # reads its offsets on the host)
    com = jax.jit(lambda q, t, m: jaxanim.center_of_mass(skel, q, t, m))(q, t, masses)
    out = jitted_fk(skel, q, t)
    R, P, P_end = _numpy_fk(skel, q, t)
    assert_close("rotations", out.rotations, R, atol=1e-14)
    assert_close("positions", out.positions, P, atol=1e-14)
    assert_close("end_site_positions", out.end_site_positions, P_end, atol=1e-14)
    # segment centers by hand: root -> mean(spine, leg)/2, spine -> mean(head, arm)/2, head -> End/2 ...
    off, es = np.asarray(skel.offsets), np.asarray(skel.end_site_offsets)
    c_local = np.array([
        0.5 * (off[1] + off[5]) / 2, 0.5 * (off[2] + off[3]) / 2, 0.5 * es[0], 0.5 * off[4], 0.5 * es[1], np.zeros(3)
    ])
    c_world = P + np.einsum("jab,jb->ja", R, c_local)
    m = np.arange(1.0, 7.0)
    assert_close("com", com, (m[:, None] * c_world).sum(0) / m.sum(), atol=1e-14)
    batched = jax.jit(jax.vmap(lambda q, t, m: jaxanim.center_of_mass(skel, q, t, m), in_axes=(0, 0, None)))(
        q[None], t[None], masses)
    assert_close("vmap com", batched[0], com, atol=1e-15)


def test_site_transforms_sequential_against_numpy():
    """The scanned FK of a few sites (a solve's final check) equals the hand-written numpy FK: joints and End
    Sites in any order, an End Site's rotation its joint's."""
    skel = small_skeleton()
    q, t = random_pose(skel, 7)
    J = skel.num_joints
    sites = (J + 1, 3, 0, J, 5)
    p, R = jax.jit(lambda q, t: site_transforms_sequential(skel, q, t, sites))(q, t)
    R_np, P_np, P_end = _numpy_fk(skel, q, t)
    P_all = np.concatenate([P_np, P_end])
    owner = [s if s < J else skel.end_site_parents[s - J] for s in sites]
    assert_close("site positions", p, P_all[list(sites)], atol=1e-14)
    assert_close("site rotations", R, R_np[owner], atol=1e-14)
