"""The conversion between BVH channel values and :class:`~jaxanim.Motion`.

Pure ``jax.numpy``, jittable and vmappable: joints are grouped by rotation order so that the
conversion costs a few vectorized calls, not one per joint. The conventions are those of
:mod:`jaxanim.skeleton._bvh` (rotation channels compose left-most outermost, position channels
replace the matching OFFSET components).
"""

from __future__ import annotations

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import rotations as _rotations
from .._errors import JaxanimError, check_float, check_shape
from .._types import Array, ArrayLike, Float
from ._skeleton import ROTATION_CHANNELS, Motion, Skeleton

__all__ = ["channels_to_motion", "motion_to_channels"]

_AXES = "XYZ"


# ------------------------------------------------------------------------------------------------
# Channel layout: index arrays shared by channels_to_motion and motion_to_channels
# ------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class _RotationGroup:
    order: str  # the joints' rotation axes in channel order, e.g. "ZXY", "Z" or "XY"
    joints: np.ndarray  # [n] joint indices
    cols: np.ndarray  # [n, len(order)] channel columns of those angles
    full_order: str  # a valid 3-axis order containing `order` (the inverse needs one)
    keep: np.ndarray  # [len(order)] which of the 3 angles of `full_order` are the listed ones


@dataclasses.dataclass(frozen=True)
class _Layout:
    num_channels: int
    num_joints: int
    groups: tuple[_RotationGroup, ...]
    identity_joints: np.ndarray  # [m] joints without rotation channels
    joint_inv_perm: np.ndarray  # [joints] position of each joint in the group concatenation
    trans_src: np.ndarray  # [3 * joints] index into concat([values, offsets.ravel()]) per component
    pos_src: np.ndarray  # [P] index into translations.reshape(3 * joints) per position column
    col_inv_perm: np.ndarray  # [channels] position of each file column in concat([pos, groups...])


def _complete_order(order: str) -> tuple[str, np.ndarray]:
    """A valid 3-axis order containing ``order`` and where its angles sit in it.

    One listed axis goes first, two listed axes go first and last, so the missing (zero) angle is
    in the middle, far from the gimbal singularity at a middle angle of +-90 degrees.
    """
    missing = "".join(a for a in _AXES if a not in order)
    if len(order) == 3:
        return order, np.arange(3)
    if len(order) == 2:
        return order[0] + missing + order[1], np.array([0, 2])
    return order + missing, np.array([0])


@functools.lru_cache(maxsize=256)
def _layout(channels: tuple[tuple[str, ...], ...]) -> _Layout:
    num_joints = len(channels)
    starts = np.cumsum([0] + [len(ch) for ch in channels])
    num_channels = int(starts[-1])
    by_order: dict[str, tuple[list[int], list[list[int]]]] = {}
    identity = []
    trans_src = num_channels + np.arange(3 * num_joints)
    pos_cols, pos_src = [], []
    for j, ch in enumerate(channels):
        order, cols = "", []
        for k, c in enumerate(ch):
            col = int(starts[j]) + k
            if c in ROTATION_CHANNELS:
                order += c[0]
                cols.append(col)
            else:
                a = _AXES.index(c[0])
                trans_src[3 * j + a] = col
                pos_cols.append(col)
                pos_src.append(3 * j + a)
        if order:
            js, cs = by_order.setdefault(order, ([], []))
            js.append(j)
            cs.append(cols)
        else:
            identity.append(j)
    groups = []
    concat_joints = []
    concat_cols = list(pos_cols)
    for order, (js, cs) in by_order.items():
        full_order, keep = _complete_order(order)
        groups.append(_RotationGroup(order, np.array(js), np.array(cs, dtype=np.int64), full_order, keep))
        concat_joints.extend(js)
        concat_cols.extend(np.array(cs).reshape(-1).tolist())
    concat_joints.extend(identity)
    joint_inv_perm = np.empty(num_joints, dtype=np.int64)
    joint_inv_perm[np.array(concat_joints, dtype=np.int64)] = np.arange(num_joints)
    col_inv_perm = np.empty(num_channels, dtype=np.int64)
    col_inv_perm[np.array(concat_cols, dtype=np.int64)] = np.arange(num_channels)
    return _Layout(
        num_channels=num_channels,
        num_joints=num_joints,
        groups=tuple(groups),
        identity_joints=np.array(identity, dtype=np.int64),
        joint_inv_perm=joint_inv_perm,
        trans_src=trans_src,
        pos_src=np.array(pos_src, dtype=np.int64),
        col_inv_perm=col_inv_perm,
    )


# ------------------------------------------------------------------------------------------------
# Channel values <-> Motion
# ------------------------------------------------------------------------------------------------


def channels_to_motion(
    skeleton: Skeleton,
    values: Float[ArrayLike, "frames channels"],
    frame_time: Float[ArrayLike, ""],
    *,
    degrees: bool = True,
) -> Motion:
    """Convert raw BVH channel values (file order) to a :class:`Motion`.

    For joint ``j`` with rotation channels ``(A, B, C)`` (any 0 to 3 distinct axes, in file order)
    and values ``(a, b, c)``: ``R_parent_joint = R_A(a) @ R_B(b) @ R_C(c)`` as a wxyz quaternion
    (identity without rotation channels). Its translation is its OFFSET with each position channel
    replacing the matching component (so ``Xposition Yposition Zposition`` replace it entirely).

    Pure ``jax.numpy`` and jitted; batch over clips with ``jax.vmap``.

    Args:
        skeleton: gives the channel layout and the OFFSETs.
        values: ``[frames, channels]`` channel values, joint by joint in file order
            (``channels = skeleton.num_channels``); positions in file units, angles in degrees (or
            radians if ``degrees=False``). Integers are promoted to floats.
        frame_time: scalar seconds per frame.
        degrees: whether the rotation channels are in degrees (BVH files are).

    Returns:
        A :class:`Motion` with ``rotations [frames, joints, 4]`` (wxyz),
        ``translations [frames, joints, 3]`` and ``frame_time``, in the promoted dtype of
        ``values`` and ``skeleton.offsets``.

    Raises:
        JaxanimError: ``values`` is not ``[frames, channels]`` or ``frame_time`` is not a scalar.
    """
    if not isinstance(skeleton, Skeleton):
        raise JaxanimError(f"skeleton: expected a Skeleton, got {type(skeleton).__name__}")
    values = values if isinstance(values, jax.core.Tracer) else np.asarray(values)
    check_float("values", values)
    check_shape("values", values, (None, skeleton.num_channels), what=f"(frames, channels) = (*, {skeleton.num_channels})")
    frame_time = jnp.asarray(frame_time)
    check_float("frame_time", frame_time)
    check_shape("frame_time", frame_time, (), what="() (a scalar)")
    dtype = jnp.result_type(values.dtype, skeleton.offsets.dtype, jnp.float32)
    if isinstance(values, jax.core.Tracer):  # under a transformation: one program of its shape
        return _channels_to_motion(skeleton.channels, skeleton.offsets, values.astype(dtype),
                                   frame_time.astype(dtype), bool(degrees))
    # concrete values: padded and cut on the host to a multiple of _PAD_FRAMES, one program for many lengths
    frames = values.shape[0]
    host = np.asarray(values, dtype)
    padded = np.concatenate([host, np.zeros((-frames % _PAD_FRAMES, host.shape[1]), dtype)])
    m = _channels_to_motion(skeleton.channels, skeleton.offsets, jax.device_put(padded), frame_time.astype(dtype),
                            bool(degrees))  # device_put: jnp.asarray compiles a program per shape (jax 0.10)
    return Motion(jax.device_put(np.asarray(m.rotations)[:frames]), jax.device_put(np.asarray(m.translations)[:frames]),
                  m.frame_time)


#: :func:`channels_to_motion` converts frames in blocks of this many (each frame on its own, so the zero frames
#: that fill the last block change nothing): a dataset's clips of many lengths compiled a program each.
_PAD_FRAMES = 64


# The jitted kernels take the channel layout (static), not the Skeleton, so that skeletons that
# differ only in names or End Sites share one compilation.
@eqx.filter_jit
def _channels_to_motion(
    channels: tuple[tuple[str, ...], ...], offsets: Array, values: Array, frame_time: Array, degrees: bool
) -> Motion:
    lay = _layout(channels)
    f, nj = values.shape[0], lay.num_joints
    quats = []
    for g in lay.groups:
        angles = values[:, g.cols]  # [F, n, k]
        quats.append(_rotations.euler_to_quat(angles, g.order, degrees=degrees))
    if lay.identity_joints.size:
        ident = jnp.array([1.0, 0.0, 0.0, 0.0], dtype=values.dtype)
        quats.append(jnp.broadcast_to(ident, (f, lay.identity_joints.size, 4)))
    rotations = jnp.concatenate(quats, axis=1)[:, lay.joint_inv_perm]
    offsets = jnp.broadcast_to(offsets.astype(values.dtype).reshape(1, 3 * nj), (f, 3 * nj))
    translations = jnp.concatenate([values, offsets], axis=1)[:, lay.trans_src].reshape(f, nj, 3)
    return Motion(rotations, translations, frame_time)


def motion_to_channels(
    skeleton: Skeleton,
    motion: Motion,
    *,
    degrees: bool = True,
) -> Float[Array, "frames channels"]:
    """Convert a :class:`Motion` to raw BVH channel values in file order (the inverse of
    :func:`channels_to_motion`).

    Position channels take the matching component of ``motion.translations``; translation
    components without a position channel (e.g. the OFFSET of an ordinary joint) are not stored.
    Rotation channels are the Euler angles of ``motion.rotations`` in the joint's channel order,
    in the canonical range of :func:`jaxanim.rotations.quat_to_euler` (middle angle in
    ``[-90, 90]``, outer ones in ``[-180, 180)``), so they may differ from the angles a clip was
    read from while describing the same rotation. A joint with one or two rotation channels gets
    the listed angles of a decomposition in a completed 3-axis order (listed axes first and last,
    missing axis in the middle): exact when the rotation is a product of the listed axes, a
    projection otherwise.

    Pure ``jax.numpy`` and jitted; batch over clips with ``jax.vmap``.

    Args:
        skeleton: gives the channel layout.
        motion: ``rotations [frames, joints, 4]`` (wxyz, normalized here) and
            ``translations [frames, joints, 3]``.
        degrees: return angles in degrees (as BVH files store them) rather than radians.

    Returns:
        ``[frames, channels]`` channel values (``channels = skeleton.num_channels``).

    Raises:
        JaxanimError: ``motion`` does not have one column per joint of ``skeleton``.
    """
    if not isinstance(skeleton, Skeleton):
        raise JaxanimError(f"skeleton: expected a Skeleton, got {type(skeleton).__name__}")
    if not isinstance(motion, Motion):
        raise JaxanimError(f"motion: expected a Motion, got {type(motion).__name__}")
    motion.check_skeleton(skeleton, "motion")
    check_float("motion.rotations", motion.rotations)
    check_float("motion.translations", motion.translations)
    return _motion_to_channels(skeleton.channels, motion.rotations, motion.translations, bool(degrees))


@eqx.filter_jit
def _motion_to_channels(
    channels: tuple[tuple[str, ...], ...], rotations: Array, translations: Array, degrees: bool
) -> Array:
    lay = _layout(channels)
    dtype = jnp.result_type(rotations.dtype, translations.dtype, jnp.float32)
    f, nj = rotations.shape[0], lay.num_joints
    pieces = [translations.astype(dtype).reshape(f, 3 * nj)[:, lay.pos_src]]
    for g in lay.groups:
        q = _rotations.quat_normalize(rotations[:, g.joints].astype(dtype))  # [F, n, 4]
        angles = _rotations.quat_to_euler(q, g.full_order, degrees=degrees)[..., g.keep]  # [F, n, k]
        pieces.append(angles.reshape(f, g.cols.size))
    return jnp.concatenate(pieces, axis=1)[:, lay.col_inv_perm]
