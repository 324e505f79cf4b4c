"""Clip utilities: resampling to a new frame rate and retargeting between rest poses."""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .. import rotations as rot
from .._errors import JaxanimError, check_shape
from .._types import Array, Float
from ._skeleton import Motion, Skeleton


def resample_at(motion: Motion, frames: Float[Array, " n"]) -> Motion:
    """Sample a clip at fractional frame indices (jittable, vmappable).

    Rotations are interpolated with :func:`jaxanim.rotations.slerp` between the two neighboring
    frames, translations linearly; indices are clamped to ``[0, num_frames - 1]``.

    Args:
        motion: the clip.
        frames: ``[n]`` fractional frame indices (frame ``k`` is at time ``k * frame_time``).

    Returns:
        A :class:`Motion` with ``n`` frames and the same ``frame_time`` (set it as you need).
    """
    check_shape("frames", frames, (None,), what="(n,)")
    F = motion.num_frames
    dtype = motion.rotations.dtype
    u = jnp.clip(jnp.asarray(frames, dtype=dtype), 0.0, F - 1)
    i0 = jnp.clip(jnp.floor(u).astype(jnp.int32), 0, max(F - 2, 0))
    i1 = jnp.minimum(i0 + 1, F - 1)
    a = u - i0.astype(dtype)
    q0, q1 = motion.rotations[i0], motion.rotations[i1]
    t0, t1 = motion.translations[i0], motion.translations[i1]
    q = rot.slerp(q0, q1, a[:, None])
    t = t0 + a[:, None, None] * (t1 - t0)
    return Motion(q, t, motion.frame_time)


# one program per clip shape (op by op, each of its ~50 ops compiled for every new shape)
_resample_at_jit = eqx.filter_jit(resample_at)


def resample(motion: Motion, frame_time: float | None = None, *, fps: float | None = None) -> Motion:
    """Resample a clip to a new frame rate (slerp for rotations, lerp for translations).

    The new clip starts at the first frame and covers the same duration; its length is
    ``floor(duration / frame_time) + 1``. Resampling to the clip's own rate is the identity.
    The output length depends on the rates, so call this outside ``jit``; use
    :func:`resample_at` inside.

    Args:
        motion: the clip.
        frame_time: the new seconds per frame, or
        fps: the new frames per second (give exactly one of the two).

    Returns:
        The resampled :class:`Motion`.

    Raises:
        JaxanimError: not exactly one of ``frame_time`` / ``fps``, a new rate that is not a positive
            finite number, or a clip whose own ``frame_time`` is not.
    """
    if (frame_time is None) == (fps is None):
        raise JaxanimError("resample: give exactly one of frame_time= or fps=")
    if fps is not None and not (math.isfinite(float(fps)) and float(fps) > 0):
        raise JaxanimError(f"fps: expected a positive finite number of frames per second, got {fps}")
    new_dt = float(frame_time) if frame_time is not None else 1.0 / float(fps)
    if not (math.isfinite(new_dt) and new_dt > 0):
        raise JaxanimError(f"frame_time: expected a positive finite number, got {new_dt}")
    motion.check_frame_time("motion")
    old_dt = float(motion.frame_time)
    ratio = new_dt / old_dt
    n = int(math.floor((motion.num_frames - 1) / ratio + 1e-9)) + 1
    frames = np.arange(n, dtype=np.float64) * ratio
    out = _resample_at_jit(motion, jnp.asarray(frames, dtype=motion.rotations.dtype))
    return Motion(out.rotations, out.translations, jnp.asarray(new_dt, dtype=motion.rotations.dtype))


def _kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Rotation M minimizing sum |M src_i - dst_i|^2 (rows are unit directions)."""
    H = src.T @ dst
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    D = np.diag([1.0, 1.0, d])
    return Vt.T @ D @ U.T


def _min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation matrix taking unit direction a to unit direction b."""
    return np.asarray(rot.quat_to_matrix(rot.rotation_between(jnp.asarray(a), jnp.asarray(b))))


def rest_alignment(source: Skeleton, target: Skeleton, *, eps: float = 1e-9) -> Float[Array, "joints 4"]:
    """Per-joint rotations ``M_j`` that turn the target's rest bones onto the source's.

    ``M_j`` maps the directions of joint ``j``'s child bones (child joints and End Sites) in the
    target rest pose onto those of the source rest pose: the smallest rotation for one bone, the
    least-squares (Kabsch) rotation for several. Zero-length bones are ignored; a joint with no
    usable bone inherits its parent's ``M``. Computed on the host from concrete offsets.

    Args:
        source, target: skeletons of the same topology (same parents and End Site parents).
        eps: length below which a bone counts as zero-length.

    Returns:
        ``[joints, 4]`` wxyz quaternions ``M_j``.
    """
    _check_same_topology(source, target)
    J = source.num_joints
    children: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in range(J)]
    offA, offB = np.asarray(source.offsets, np.float64), np.asarray(target.offsets, np.float64)
    for j, p in enumerate(source.parents):
        if p >= 0:
            children[p].append((offA[j], offB[j]))
    esA, esB = np.asarray(source.end_site_offsets, np.float64), np.asarray(target.end_site_offsets, np.float64)
    for e, p in enumerate(source.end_site_parents):
        children[p].append((esA[e], esB[e]))
    M = np.zeros((J, 3, 3))
    for j in range(J):
        pairs = [(a, b) for a, b in children[j] if np.linalg.norm(a) > eps and np.linalg.norm(b) > eps]
        if not pairs:
            p = source.parents[j]
            M[j] = M[p] if p >= 0 else np.eye(3)
            continue
        A = np.stack([a / np.linalg.norm(a) for a, _ in pairs])
        B = np.stack([b / np.linalg.norm(b) for _, b in pairs])
        if len(pairs) == 1 or np.linalg.matrix_rank(A, tol=1e-6) < 2 or np.linalg.matrix_rank(B, tol=1e-6) < 2:
            M[j] = _min_rotation(B.mean(0) / np.linalg.norm(B.mean(0)), A.mean(0) / np.linalg.norm(A.mean(0)))
        else:
            M[j] = _kabsch(B, A)
    return rot.matrix_to_quat(jnp.asarray(M, dtype=source.offsets.dtype))


def _check_same_topology(source: Skeleton, target: Skeleton) -> None:
    if source.parents != target.parents or source.end_site_parents != target.end_site_parents:
        raise JaxanimError(
            "target: expected a skeleton with the same topology as source (same parents and End Sites), "
            f"got {target.num_joints} joints / {target.num_end_sites} End Sites vs "
            f"{source.num_joints} / {source.num_end_sites}, or a different tree"
        )


def retarget(
    motion: Motion,
    source: Skeleton,
    target: Skeleton,
    *,
    alignment: Float[Array, "joints 4"] | None = None,
    root_scale: float = 1.0,
) -> Motion:
    """Retarget a clip between two skeletons of the same topology but different rest poses.

    Every bone keeps its global orientation: with ``M_j`` from :func:`rest_alignment`, the target's
    global rotations are ``R_world_joint^B = R_world_joint^A M_j``, hence local rotations
    ``R_parent_joint^B = M_parent(j)^T R_parent_joint^A M_j`` (``M_parent = I`` for the root). Joints without position
    channels take the target's OFFSETs; position-channel values (the root translation) are scaled
    by ``root_scale``.

    Args:
        motion: clip on the ``source`` skeleton.
        source, target: the two skeletons.
        alignment: ``[joints, 4]`` precomputed ``M_j`` (default: :func:`rest_alignment`, computed on
            the host; pass it explicitly to call this under ``jit``).
        root_scale: factor for the root translation, e.g. the ratio of leg lengths.

    Returns:
        The clip on the ``target`` skeleton.
    """
    _check_same_topology(source, target)
    motion.check_skeleton(source, "motion")
    J = source.num_joints
    if alignment is None:
        alignment = rest_alignment(source, target)
    check_shape("alignment", alignment, (J, 4), what=f"(joints, 4) = ({J}, 4)")
    dtype = motion.rotations.dtype
    M = jnp.asarray(alignment, dtype=dtype)
    M_par = jnp.concatenate([rot.quat_identity((1,), dtype), M[jnp.asarray(source.parents[1:], dtype=jnp.int32)]], axis=0) if J > 1 else rot.quat_identity((1,), dtype)
    q = rot.quat_multiply(rot.quat_multiply(rot.quat_conjugate(M_par)[None], motion.rotations), M[None])
    q = rot.quat_canonical(q)
    has_pos = np.asarray(target.has_position_channels)
    t = jnp.where(
        jnp.asarray(has_pos)[None, :, None],
        motion.translations * jnp.asarray(root_scale, dtype=dtype),
        target.offsets.astype(dtype)[None],
    )
    return Motion(q, t, motion.frame_time)
