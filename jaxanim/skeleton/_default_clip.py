"""The shipped default clip: a procedurally generated walk on a 21-joint humanoid.

The skeleton is in **meters**, **Y up**, the character faces **+Z** (its left is +X) and its rest
pose is a T-pose standing on the ground plane ``y = 0``. The root ``Hips`` has the six channels
``Xposition Yposition Zposition Zrotation Xrotation Yrotation``; every other joint has
``Zrotation Xrotation Yrotation``. End Sites sit on the head, the hands and the toes::

    Hips
    +- Spine - Chest - Neck - Head - [Head_End]
    |          +- LeftShoulder - LeftArm - LeftForeArm - LeftHand - [LeftHand_End]
    |          +- RightShoulder - RightArm - RightForeArm - RightHand - [RightHand_End]
    +- LeftUpLeg - LeftLeg - LeftFoot - LeftToeBase - [LeftToeBase_End]
    +- RightUpLeg - RightLeg - RightFoot - RightToeBase - [RightToeBase_End]

The motion is a periodic gait (one cycle per second, so a clip of a whole number of seconds loops
in place): hip, knee and ankle flexion curves in antiphase between the legs, arm swing opposite to
the legs with bent elbows, counter-rotating pelvis and chest, and a small lateral sway. The root
height is set every frame so that the lowest point of the feet (the heel, the toe joint or the toe
tip) touches the ground, which produces the pelvis bob, and the root moves forward at the constant
speed at which the planted foot does not slide on average (about 1.2 m/s). The leg curves are
smooth fits to rounded textbook joint angles of level walking. Everything is computed with NumPy
in float64 from closed-form curves, so the clip is deterministic.

The shipped file ``jaxanim/data/walk.bvh`` is ``make_default_clip()`` written with
:func:`jaxanim.write_bvh`; regenerate it with ``python -m jaxanim.skeleton._default_clip``.
"""

from __future__ import annotations

import atexit
import contextlib
import importlib.resources
import math
import os
import pathlib
import sys

import jax
import numpy as np

from .._errors import JaxanimError
from ._bvh import channels_to_motion, write_bvh
from ._skeleton import Motion, Skeleton

__all__ = ["default_clip_channels", "default_clip_path", "default_skeleton", "make_default_clip", "write_default_clip"]

_ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
_JOINT_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")

# Segment lengths (meters).
_HIP_WIDTH = 0.09  # hip joint from the pelvis center, sideways
_HIP_DROP = 0.06  # hip joint below the root
_THIGH = 0.44
_SHIN = 0.42
_TOE = (0.13, -0.07)  # toe joint from the ankle, (forward, up)
_TOE_TIP = 0.06  # toe End Site from the toe joint, forward
_HEEL = (-0.04, -0.07)  # virtual heel point from the ankle (forward, up); not a joint
_STAND_HEIGHT = _HIP_DROP + _THIGH + _SHIN - _HEEL[1]  # root height in the rest pose, heel on the ground

# name, parent, OFFSET in the parent frame (meters)
_JOINTS: tuple[tuple[str, str | None, tuple[float, float, float]], ...] = (
    ("Hips", None, (0.0, 0.0, 0.0)),
    ("Spine", "Hips", (0.0, 0.08, 0.0)),
    ("Chest", "Spine", (0.0, 0.18, 0.0)),
    ("Neck", "Chest", (0.0, 0.22, 0.0)),
    ("Head", "Neck", (0.0, 0.10, 0.0)),
    ("LeftShoulder", "Chest", (0.03, 0.18, 0.0)),
    ("LeftArm", "LeftShoulder", (0.15, 0.0, 0.0)),
    ("LeftForeArm", "LeftArm", (0.28, 0.0, 0.0)),
    ("LeftHand", "LeftForeArm", (0.25, 0.0, 0.0)),
    ("RightShoulder", "Chest", (-0.03, 0.18, 0.0)),
    ("RightArm", "RightShoulder", (-0.15, 0.0, 0.0)),
    ("RightForeArm", "RightArm", (-0.28, 0.0, 0.0)),
    ("RightHand", "RightForeArm", (-0.25, 0.0, 0.0)),
    ("LeftUpLeg", "Hips", (_HIP_WIDTH, -_HIP_DROP, 0.0)),
    ("LeftLeg", "LeftUpLeg", (0.0, -_THIGH, 0.0)),
    ("LeftFoot", "LeftLeg", (0.0, -_SHIN, 0.0)),
    ("LeftToeBase", "LeftFoot", (0.0, _TOE[1], _TOE[0])),
    ("RightUpLeg", "Hips", (-_HIP_WIDTH, -_HIP_DROP, 0.0)),
    ("RightLeg", "RightUpLeg", (0.0, -_THIGH, 0.0)),
    ("RightFoot", "RightLeg", (0.0, -_SHIN, 0.0)),
    ("RightToeBase", "RightFoot", (0.0, _TOE[1], _TOE[0])),
)
# joint, End Site OFFSET in the joint frame (meters); in joint order
_END_SITES: tuple[tuple[str, tuple[float, float, float]], ...] = (
    ("Head", (0.0, 0.18, 0.0)),
    ("LeftHand", (0.17, 0.0, 0.0)),
    ("RightHand", (-0.17, 0.0, 0.0)),
    ("LeftToeBase", (0.0, 0.0, _TOE_TIP)),
    ("RightToeBase", (0.0, 0.0, _TOE_TIP)),
)

_CYCLE_SECONDS = 1.0  # one gait cycle (two steps)


def default_skeleton() -> Skeleton:
    """The 21-joint humanoid of the default clip (meters, Y up, facing +Z, T-pose rest)."""
    names = tuple(n for n, _, _ in _JOINTS)
    parents = tuple(-1 if p is None else names.index(p) for _, p, _ in _JOINTS)
    offsets = np.array([o for _, _, o in _JOINTS], dtype=np.float64)
    channels = tuple(_ROOT_CHANNELS if p is None else _JOINT_CHANNELS for _, p, _ in _JOINTS)
    end_parents = tuple(names.index(j) for j, _ in _END_SITES)
    end_offsets = np.array([o for _, o in _END_SITES], dtype=np.float64)
    return Skeleton(names, parents, offsets, channels, end_parents, end_offsets)


# --- gait curves ----------------------------------------------------------------------------------
# Sagittal joint angles (degrees) of one leg at 0 %, 10 %, ..., 90 % of its gait cycle, counted from
# its heel strike; rounded textbook values for level walking (stance until toe-off near 60 %).
_GAIT_KEYFRAMES = {
    "hip_flexion": (30.0, 25.0, 17.0, 8.0, 0.0, -8.0, -4.0, 14.0, 26.0, 30.0),  # thigh forward
    "knee_flexion": (5.0, 17.0, 15.0, 8.0, 5.0, 14.0, 40.0, 63.0, 50.0, 18.0),  # shank back
    "ankle_dorsiflexion": (0.0, -5.0, 3.0, 8.0, 10.0, 5.0, -14.0, -3.0, 2.0, 1.0),  # toes up
}
_HARMONICS = 4  # the curves are the least-squares trigonometric fits of this degree (smooth)


def _gait_curve(name: str, p):
    """Joint angle ``name`` (degrees) at the cycle fractions ``p`` (periodic with period 1)."""
    keys = np.asarray(_GAIT_KEYFRAMES[name])
    c = np.fft.rfft(keys) / keys.size
    out = np.full(np.shape(p), c[0].real)
    for k in range(1, _HARMONICS + 1):
        out = out + 2.0 * (c[k].real * np.cos(2.0 * math.pi * k * p) - c[k].imag * np.sin(2.0 * math.pi * k * p))
    return out


def _leg_points(p):
    """Points of one leg at cycle fractions ``p``, relative to the root: ``{name: (forward, up)}``.

    The leg is planar: each joint rotates about the lateral axis and the angles add along the chain.
    """
    a1 = np.deg2rad(_gait_curve("hip_flexion", p))  # thigh from the downward vertical, forward > 0
    a2 = a1 - np.deg2rad(_gait_curve("knee_flexion", p))  # shank
    a3 = a2 + np.deg2rad(_gait_curve("ankle_dorsiflexion", p))  # foot (toes up > 0)

    def add(base, a, fwd, up):  # base + (fwd, up) rotated by a in the sagittal plane
        return base[0] + fwd * np.cos(a) - up * np.sin(a), base[1] + fwd * np.sin(a) + up * np.cos(a)

    hip = (np.zeros_like(a1), np.full_like(a1, -_HIP_DROP))
    ankle = add(add(hip, a1, 0.0, -_THIGH), a2, 0.0, -_SHIN)
    toe = add(ankle, a3, *_TOE)
    return {"heel": add(ankle, a3, *_HEEL), "toe": toe, "tip": add(toe, a3, _TOE_TIP, 0.0)}


def _foot_points(p_left):
    """``(forward, up)``, each ``[6, n]``: heel, toe and tip of the left then the right leg."""
    fwd, up = [], []
    for off in (0.0, 0.5):
        pts = _leg_points(p_left + off)
        fwd += [pts[k][0] for k in ("heel", "toe", "tip")]
        up += [pts[k][1] for k in ("heel", "toe", "tip")]
    return np.stack(fwd), np.stack(up)


def _root_height(p_left):
    """Root height that puts the lowest heel, toe joint or toe tip of either leg on the ground."""
    return -np.min(_foot_points(p_left)[1], axis=0)


def _walking_speed() -> float:
    """Forward speed (m/s) at which the lowest foot point does not slide on average over a cycle.

    The point touching the ground moves, relative to the root, with the forward velocity ``v_rel``
    (central differences in the cycle fraction); the root moves at ``-mean(v_rel)``.
    """
    p = np.arange(1000) / 1000.0
    h = 1e-6
    _, up = _foot_points(p)
    v_rel = (_foot_points(p + h)[0] - _foot_points(p - h)[0]) / (2.0 * h)  # meters per cycle
    lowest = np.argmin(up, axis=0)
    return float(-np.mean(v_rel[lowest, np.arange(p.size)]) / _CYCLE_SECONDS)


def default_clip_channels(num_frames: int = 120, fps: float = 30.0) -> np.ndarray:
    """The raw BVH channel values ``[frames, channels]`` of the default walk (float64, degrees).

    Args:
        num_frames: number of frames (>= 1).
        fps: frames per second (> 0).

    Returns:
        ``[num_frames, 66]`` channel values in the file order of :func:`default_skeleton`.
    """
    if isinstance(num_frames, bool) or not isinstance(num_frames, (int, np.integer)) or num_frames < 1:
        raise JaxanimError(f"num_frames: expected a positive integer, got {num_frames!r}")
    if not (isinstance(fps, (int, float, np.floating, np.integer)) and math.isfinite(fps) and fps > 0):
        raise JaxanimError(f"fps: expected a positive finite number, got {fps!r}")
    names = [n for n, _, _ in _JOINTS]
    t = np.arange(int(num_frames), dtype=np.float64) / float(fps)
    p_left = np.mod(t / _CYCLE_SECONDS, 1.0)  # left heel strike at p = 0
    p_right = np.mod(p_left + 0.5, 1.0)
    s = np.cos(2.0 * math.pi * p_left)  # +1 at left heel strike (left leg and right arm forward)
    c2 = np.cos(4.0 * math.pi * p_left)  # twice per cycle: once per step
    zero = np.zeros_like(t)

    rot = {n: [zero, zero, zero] for n in names}  # Z, X, Y rotation channels, degrees
    # Pelvis yaws with the legs (left hip forward at left heel strike); the chest counter-rotates.
    rot["Hips"] = [zero, zero, -5.0 * s]
    rot["Spine"] = [zero, 3.0 + 1.0 * c2, zero]  # slight forward lean, deeper at each heel strike
    rot["Chest"] = [zero, zero, 8.0 * s]
    rot["Neck"] = [zero, -2.0 - 1.0 * c2, -3.0 * s]  # keeps the head level and facing forward
    # Arms are lowered from the T-pose by the Z channel and swing about the lowered arm's Y axis,
    # opposite to the legs; a negative Y angle swings the left arm forward, a positive the right.
    lower = 84.0
    swing_l = 4.0 - 16.0 * s  # forward swing of the left arm, degrees
    swing_r = 4.0 + 16.0 * s
    rot["LeftArm"] = [np.full_like(t, -lower), zero, -swing_l]
    rot["RightArm"] = [np.full_like(t, lower), zero, swing_r]
    rot["LeftForeArm"] = [zero, zero, -(18.0 + 0.5 * swing_l)]  # elbows bend more when forward
    rot["RightForeArm"] = [zero, zero, 18.0 + 0.5 * swing_r]
    # Legs: the X channel pitches a leg joint; a positive angle moves the foot backwards.
    for side, p in (("Left", p_left), ("Right", p_right)):
        rot[f"{side}UpLeg"] = [zero, -_gait_curve("hip_flexion", p), zero]
        rot[f"{side}Leg"] = [zero, _gait_curve("knee_flexion", p), zero]
        rot[f"{side}Foot"] = [zero, -_gait_curve("ankle_dorsiflexion", p), zero]

    height = _root_height(p_left)
    sway = 0.02 * np.sin(2.0 * math.pi * p_left)  # towards the stance leg (the left is +X)
    columns = [sway, height, _walking_speed() * t] + rot["Hips"]
    for n in names[1:]:
        columns += rot[n]
    return np.stack(columns, axis=1)


def make_default_clip(num_frames: int = 120, fps: float = 30.0) -> tuple[Skeleton, Motion]:
    """The default clip: a procedural walk on the 21-joint humanoid of :func:`default_skeleton`.

    Meters, Y up, facing and walking towards +Z, T-pose rest, one gait cycle per second; see the
    module docstring. Arrays are float64 when ``jax_enable_x64`` is on, float32 otherwise.

    Args:
        num_frames: number of frames (>= 1); the default 120 frames at 30 fps is four cycles.
        fps: frames per second.

    Returns:
        ``(skeleton, motion)``.

    Raises:
        JaxanimError: ``num_frames`` or ``fps`` is not positive.
    """
    skeleton = default_skeleton()
    values = default_clip_channels(num_frames, fps)
    return skeleton, channels_to_motion(skeleton, values, np.float64(1.0 / float(fps)))


# --- the shipped file ------------------------------------------------------------------------------

_FILE_NAME = "walk.bvh"
_resource_stack = contextlib.ExitStack()
atexit.register(_resource_stack.close)


def default_clip_path() -> pathlib.Path:
    """Path of the shipped default clip ``jaxanim/data/walk.bvh`` (package data).

    Raises:
        JaxanimError: the file is missing from the installation.
    """
    ref = importlib.resources.files("jaxanim").joinpath("data", _FILE_NAME)
    if isinstance(ref, pathlib.Path):
        path = ref
    else:  # a zipped install: extract once for the life of the process
        path = _resource_stack.enter_context(importlib.resources.as_file(ref))
    if not path.is_file():
        raise JaxanimError(
            f"the shipped default clip is missing at {path}; regenerate it with `python -m jaxanim.skeleton._default_clip`"
        )
    return path


def write_default_clip(path: str | os.PathLike | None = None) -> pathlib.Path:
    """Write :func:`make_default_clip` (defaults, float64) as BVH; returns the path written.

    Switches ``jax_enable_x64`` on (and leaves it on, like the ``jaxanim`` command line): the file
    must not depend on the caller's precision.

    Args:
        path: where to write; default the package's ``jaxanim/data/walk.bvh``.
    """
    if path is None:
        path = pathlib.Path(str(importlib.resources.files("jaxanim").joinpath("data", _FILE_NAME)))
    if not jax.config.jax_enable_x64:
        jax.config.update("jax_enable_x64", True)
    skeleton, motion = make_default_clip()
    write_bvh(path, skeleton, motion)
    return pathlib.Path(path)


if __name__ == "__main__":
    out = write_default_clip(sys.argv[1] if len(sys.argv) > 1 else None)
    print(f"wrote {out}")
