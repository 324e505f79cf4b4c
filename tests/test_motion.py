"""Resampling and retargeting of clips."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxanim
from jaxanim import rotations as rot

from .conftest import shared_data_dir
from .helpers import assert_close, batched_fk, random_pose, shared_clip, small_skeleton


def _clip(skel, n=7, seed=0):
    """Random rotations; translations vary only on joints with position channels (as in a BVH)."""
    q, t = random_pose(skel, seed, n=n, scale=0.5)
    has_pos = jnp.asarray(skel.has_position_channels)[None, :, None]
    t = jnp.where(has_pos, t, jnp.broadcast_to(skel.offsets, t.shape))
    return jaxanim.Motion(q, t, jnp.asarray(1 / 30))


def test_resample_to_own_rate_is_identity():
    skel = small_skeleton()
    m = _clip(skel)
    out = jaxanim.resample(m, frame_time=float(m.frame_time))
    assert out.num_frames == m.num_frames
    assert_close("rotations", out.rotations, m.rotations, atol=1e-15)
    assert_close("translations", out.translations, m.translations, atol=1e-15)
    assert float(out.frame_time) == float(m.frame_time)


def test_resample_half_and_double_rate():
    skel = small_skeleton()
    m = _clip(skel, n=9)
    half = jaxanim.resample(m, fps=15.0)
    assert half.num_frames == 5
    assert_close("every other frame", half.rotations, m.rotations[::2], atol=1e-12)
    double = jaxanim.resample(m, fps=60.0)
    assert double.num_frames == 17
    assert_close("original frames kept", double.rotations[::2], m.rotations, atol=1e-12)
    # midpoints are slerp midpoints: equal angle to both neighbours, and unit norm
    mid = double.rotations[1::2]
    d0 = rot.quat_distance(mid, m.rotations[:-1])
    d1 = rot.quat_distance(mid, m.rotations[1:])
    assert_close("slerp midpoint equidistant", d0, d1, atol=1e-12)
    assert_close("unit", jnp.linalg.norm(mid, axis=-1), np.ones(mid.shape[:-1]), atol=1e-14)
    assert_close("translations lerp", double.translations[1::2], 0.5 * (m.translations[:-1] + m.translations[1:]), atol=1e-14)


def test_resample_at_vmap_equals_loop():
    skel = small_skeleton()
    ms = [_clip(skel, seed=s) for s in range(3)]
    stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *ms)
    frames = jnp.asarray([0.0, 0.5, 2.25, 6.0])
    # jitted, the vmap and the single clip (eager, each op would compile on its own)
    out = jax.jit(jax.vmap(jaxanim.resample_at, in_axes=(0, None)))(stacked, frames)
    one_clip = jax.jit(jaxanim.resample_at)
    for i, m in enumerate(ms):
        one = one_clip(m, frames)
        assert_close("rotations", out.rotations[i], one.rotations, atol=1e-15)


def test_resample_bad_input():
    m = _clip(small_skeleton())
    with pytest.raises(jaxanim.JaxanimError, match="exactly one of frame_time= or fps="):
        jaxanim.resample(m)
    with pytest.raises(jaxanim.JaxanimError, match="frame_time: expected a positive finite number"):
        jaxanim.resample(m, frame_time=-1.0)
    with pytest.raises(jaxanim.JaxanimError, match=r"frames: expected shape \(n,\)"):
        jaxanim.resample_at(m, jnp.zeros((2, 2)))
    with pytest.raises(jaxanim.JaxanimError, match=r"translations: expected shape \(frames, joints, 3\) = \(7, 6, 3\)"):
        jaxanim.Motion(m.rotations, m.translations[:, :, :2], m.frame_time)


def _a_pose(skel: jaxanim.Skeleton, joints: tuple[str, ...], angle: float) -> jaxanim.Skeleton:
    """The same tree with the offsets below ``joints`` turned by ``angle`` about z (an 'A-pose')."""
    off = np.array(skel.offsets)
    es = np.array(skel.end_site_offsets)
    Rz = np.asarray(rot.euler_to_matrix(jnp.array([angle, 0.0, 0.0]), "ZYX"))
    below = set()
    for j, p in enumerate(skel.parents):
        if skel.names[j] in joints or p in below:
            below.add(j)
    for j in below:
        if skel.names[j] not in joints:
            off[j] = Rz @ off[j]
    for e, p in enumerate(skel.end_site_parents):
        if p in below:
            es[e] = Rz @ es[e]
    return jaxanim.Skeleton(skel.names, skel.parents, jnp.asarray(off), skel.channels, skel.end_site_parents, jnp.asarray(es))


def _bone_directions(skel, out):
    """World direction of every non-zero bone (child joints and End Sites), per frame."""
    P = np.asarray(out.positions)
    E = np.asarray(out.end_site_positions)
    dirs = []
    for j, p in enumerate(skel.parents):
        if p >= 0 and np.linalg.norm(np.asarray(skel.offsets)[j]) > 1e-9:
            dirs.append(P[:, j] - P[:, p])
    for e, p in enumerate(skel.end_site_parents):
        if np.linalg.norm(np.asarray(skel.end_site_offsets)[e]) > 1e-9:
            dirs.append(E[:, e] - P[:, p])
    d = np.stack(dirs, 1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def test_retarget_preserves_bone_orientations_small():
    src = small_skeleton()
    dst = _a_pose(src, ("arm",), -0.7)
    m = _clip(src)
    out = jaxanim.retarget(m, src, dst)
    fk = batched_fk()  # jitted (an eager vmap compiles op by op)
    a, b = fk(src, m.rotations, m.translations), fk(dst, out.rotations, out.translations)
    assert_close("bone directions", _bone_directions(dst, b), _bone_directions(src, a), atol=1e-9)
    # and back again gives the original clip (up to quaternion sign)
    back = jaxanim.retarget(out, dst, src)
    assert_close("round trip", jnp.abs(jnp.sum(back.rotations * m.rotations, -1)), np.ones((7, 6)), atol=1e-12)


def test_retarget_shared_clip_a_pose_to_t_pose():
    shared_data_dir()
    skel, motion, _ = shared_clip("cmu_01_01_trim300")
    a_pose = _a_pose(skel, ("LeftArm", "RightArm"), 0.0)  # identity check first
    same = jaxanim.retarget(motion, skel, a_pose)
    assert_close("same rest pose", jnp.abs(jnp.sum(same.rotations * motion.rotations, -1)), np.ones(motion.rotations.shape[:2]), atol=1e-12)
    a_pose = _a_pose(_a_pose(skel, ("LeftArm",), -0.6), ("RightArm",), 0.6)
    out = jaxanim.retarget(motion, skel, a_pose)
    fk = batched_fk()
    A = fk(skel, motion.rotations, motion.translations)
    B = fk(a_pose, out.rotations, out.translations)
    assert_close("bone directions", _bone_directions(a_pose, B), _bone_directions(skel, A), atol=1e-9)


def test_retarget_bad_input():
    src = small_skeleton()
    other = jaxanim.Skeleton(("a", "b"), (-1, 0), jnp.zeros((2, 3)))
    m = _clip(src)
    with pytest.raises(jaxanim.JaxanimError, match="target: expected a skeleton with the same topology"):
        jaxanim.retarget(m, src, other)
    with pytest.raises(jaxanim.JaxanimError, match=r"alignment: expected shape \(joints, 4\) = \(6, 4\)"):
        jaxanim.retarget(m, src, src, alignment=jnp.zeros((5, 4)))


def test_retarget_vmap_equals_loop():
    src = small_skeleton()
    dst = _a_pose(src, ("arm",), -0.7)
    M = jaxanim.rest_alignment(src, dst)
    ms = [_clip(src, seed=s) for s in range(2)]
    stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *ms)
    out = jax.jit(jax.vmap(lambda m: jaxanim.retarget(m, src, dst, alignment=M)))(stacked)  # eager, op by op
    for i, m in enumerate(ms):
        assert_close("rotations", out.rotations[i], jaxanim.retarget(m, src, dst).rotations, atol=1e-15)
