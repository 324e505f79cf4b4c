"""Foot contacts of a clip: the frames where each foot is on the ground (low and slow).

Computed on the host (NumPy) from one batched forward kinematics of the clip: the runs of contact
frames are data-dependent, and a clip is prepared once. :func:`jaxanim.ik.clean_foot_contacts`
plants the feet of those frames; :func:`jaxanim.retargeting.retarget` plants the robot's.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import numpy as np

from .._errors import JaxanimError
from ..skeleton._skeleton import Motion, Skeleton
from ._fk import forward_kinematics

__all__ = ["detect_foot_contacts", "foot_joints"]


def _rest_positions(skeleton: Skeleton) -> np.ndarray:
    """World joint positions of the rest pose (identity rotations, OFFSETs), ``[joints, 3]``: each joint's
    OFFSET added to its parent's position, on the host (the same numbers as the FK of the rest pose, whose
    program compiled for every new skeleton: 1.4 s of a command's run)."""
    offsets = np.asarray(skeleton.offsets, np.float64)
    positions = np.zeros_like(offsets)
    for j, p in enumerate(skeleton.parents):  # parents come before their children
        positions[j] = offsets[j] + (positions[p] if p >= 0 else 0.0)
    return positions


def foot_joints(skeleton: Skeleton, *, up: int = 1, count: int = 2) -> tuple[str, ...]:
    """The feet of a skeleton: its ``count`` lowest leaf joints in the rest pose (joints without
    child joints; an End Site does not count as a child), in joint order.

    On a humanoid these are the toe joints (or the ankles of a skeleton without toes).

    Raises:
        JaxanimError: the tree has fewer than ``count`` leaf joints, or ``up`` is not 0, 1 or 2.
    """
    if up not in (0, 1, 2):
        raise JaxanimError(f"up: expected the index of the up axis, 0, 1 or 2, got {up!r}")
    has_child = set(p for p in skeleton.parents if p >= 0)
    leaves = [j for j in range(skeleton.num_joints) if j not in has_child]
    if len(leaves) < count:
        raise JaxanimError(f"the skeleton has {len(leaves)} leaf joints, fewer than the {count} feet asked for")
    height = _rest_positions(skeleton)[:, up]
    lowest = sorted(leaves, key=lambda j: (height[j], j))[:count]
    return tuple(skeleton.names[j] for j in sorted(lowest))


def _leg_length(skeleton: Skeleton, feet: Sequence[int], up: int) -> float:
    """Rest height of the root above the lowest foot: the scale of the default thresholds."""
    pos = _rest_positions(skeleton)
    length = float(pos[0, up] - min(pos[j, up] for j in feet))
    return length if length > 0 else float(np.sum(np.abs(np.asarray(skeleton.offsets))))


def resolve_feet(skeleton: Skeleton, feet, up: int) -> tuple[tuple[str, ...], list[int]]:
    """The foot joints' names and indices: ``feet`` checked, or :func:`foot_joints` when ``None``
    (internal interface: also used by :mod:`jaxanim.ik`)."""
    if feet is None:
        feet = foot_joints(skeleton, up=up)
    elif isinstance(feet, str):
        feet = (feet,)
    feet = tuple(str(f) for f in feet)
    if not feet:
        raise JaxanimError("feet: expected at least one joint name")
    unknown = [f for f in feet if f not in skeleton.names]
    if unknown:
        raise JaxanimError(f"feet: unknown joint names {unknown}; the skeleton's joints are {list(skeleton.names)}")
    return feet, [skeleton.index(f) for f in feet]


@eqx.filter_jit
def clip_positions(skeleton: Skeleton, motion: Motion):
    """``[frames, joints, 3]`` world joint positions of every frame (one batched FK; internal interface:
    also used by :mod:`jaxanim.ik` and the command line)."""
    return jax.vmap(lambda q, t: forward_kinematics(skeleton, q, t).positions)(motion.rotations, motion.translations)


def detect_foot_contacts(
    skeleton: Skeleton,
    motion: Motion,
    feet: Sequence[str] | str | None = None,
    *,
    up: int = 1,
    ground: float | None = None,
    height: float | None = None,
    speed: float | None = None,
) -> tuple[tuple[str, ...], np.ndarray]:
    """Frames where each foot is on the ground: low **and** slow.

    A foot touches in frame ``f`` when its height above the ground is at most ``height`` and its
    speed (central differences, 3-D) at most ``speed``.

    Args:
        skeleton, motion: the clip.
        feet: foot joint names (default :func:`foot_joints`: the two lowest leaf joints at rest).
        up: the index of the up axis (BVH: 1, Y up).
        ground: the ground's height (default: the lowest foot height of the clip).
        height: in file units (default ``0.06 L``, ``L`` the rest height of the root above the
            lowest foot: about 5 cm on an adult).
        speed: in file units per second (default ``0.5 L`` per second, about 0.45 m/s).

    Returns:
        ``(feet, contacts)``: the foot names and a ``[frames, feet]`` bool NumPy array.

    Raises:
        JaxanimError: the clip does not match the skeleton, or its ``frame_time`` is not a positive
            finite number (the speeds would be meaningless).
    """
    motion.check_skeleton(skeleton, "motion")
    motion.check_frame_time("motion")
    feet, idx = resolve_feet(skeleton, feet, up)
    P = np.asarray(clip_positions(skeleton, motion))[:, idx]  # [F, feet, 3]
    return feet, contacts_from_positions(skeleton, idx, P, float(motion.frame_time), up, ground, height, speed)


def contacts_from_positions(skeleton, idx, P, dt, up, ground, height, speed):
    """``[frames, feet]`` stance of the feet ``idx`` from joint positions ``P`` (low and slow: the
    thresholds of :func:`detect_foot_contacts`; internal interface: also used by :mod:`jaxanim.ik`)."""
    scale = _leg_length(skeleton, idx, up)
    height = 0.06 * scale if height is None else float(height)
    speed = 0.5 * scale if speed is None else float(speed)
    for name, value in (("height", height), ("speed", speed)):
        if not value > 0:
            raise JaxanimError(f"{name}: expected a positive threshold, got {value!r}")
    h = P[..., up]
    ground = float(h.min()) if ground is None else float(ground)
    v = np.linalg.norm(np.gradient(P, dt, axis=0), axis=-1) if P.shape[0] > 1 else np.zeros(h.shape)
    return (h - ground <= height) & (v <= speed)


def true_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[(start, stop), ...]`` of the runs of True in a 1-D bool array (``stop`` exclusive)."""
    m = np.concatenate([[False], mask, [False]])
    edges = np.flatnonzero(m[1:] != m[:-1])
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist()))
