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
the legs with bent elbows, counter-rotating pelvis and chest, and a small lateral sway. The leg
curves are smooth fits to rounded textbook joint angles of level walking. The root moves forward at
a constant speed (about 1.2 m/s), and the feet are planted: each toe joint (the ball of the foot)
stays on the ground where it lands for the stance phase of its leg (10 % to 60 % of its cycle), the
hip and knee angles being solved analytically to reach it, the heel not below the ball and the toes
flat; in swing the toe travels to the next footprint on a minimum-jerk path with a 5 cm clearance.
The root height follows the lowest point of the feet on the original curves, lowered where a planted
foot would be out of reach (the pelvis bob). Everything is computed with NumPy in float64 from
closed-form curves, so the clip is deterministic; the stance foot does not slide (the median speed of
the lower toe joint is zero to round-off).

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


# --- planted feet ---------------------------------------------------------------------------------
# The angle curves alone make the stance foot skate: the textbook angles do not carry the foot
# backwards at exactly the root's constant speed. So the leg angles are corrected per frame. The toe
# joint (the ball of the foot, on the sole) is pinned at ground level where it lands, for the stance
# phase [_PIN_ON, _PIN_OFF] of its leg's cycle; the hip and knee are solved analytically (two-link IK
# in the plane of the original knee) to reach it, and the root is lowered where a pinned foot would
# be out of reach. In stance the foot keeps its world orientation with the pitch clamped so that the
# heel is not below the ball, and the toes stay level (the toe joint flexes when the heel rises). In
# swing the toe moves from one footprint to the next along a minimum-jerk path, with the original
# clearance above the line between them.
_PIN_ON, _PIN_OFF = 0.10, 0.60  # fractions of the leg's cycle (left heel strike at 0)
_BLEND = 0.08  # cycle fraction over which the foot and toe corrections fade out and in
_SWING_CLEARANCE = 0.05  # meters: the swinging foot's lowest point at mid-swing
_REACH = 0.995  # the root is lowered so that no ankle is farther than this fraction of the leg


def _raw_pose(t):
    """Root positions ``[n, 3]`` and the channel curves ``{joint: [Z, X, Y] degrees}`` before the
    feet are planted, at the times ``t`` (seconds)."""
    names = [n for n, _, _ in _JOINTS]
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
    sway = 0.02 * np.sin(2.0 * math.pi * p_left)  # towards the stance leg (the left is +X)
    root = np.stack([sway, _root_height(p_left), _walking_speed() * t], axis=1)
    return root, rot


def _euler_zxy(angles):
    """``Rz Rx Ry`` of the BVH channel values ``[..., (Z, X, Y)]`` in degrees: ``[..., 3, 3]``."""
    z, x, y = np.moveaxis(np.deg2rad(np.asarray(angles, dtype=np.float64)), -1, 0)
    cz, sz, cx, sx, cy, sy = np.cos(z), np.sin(z), np.cos(x), np.sin(x), np.cos(y), np.sin(y)
    return np.stack([
        np.stack([cz * cy - sz * sx * sy, -sz * cx, cz * sy + sz * sx * cy], -1),
        np.stack([sz * cy + cz * sx * sy, cz * cx, sz * sy - cz * sx * cy], -1),
        np.stack([-cx * sy, sx, cx * cy], -1),
    ], -2)


def _zxy_from_matrix(R):
    """The inverse of :func:`_euler_zxy` (degrees, X in [-90, 90]): ``[..., (Z, X, Y)]``."""
    x = np.arcsin(np.clip(R[..., 2, 1], -1.0, 1.0))
    z = np.arctan2(-R[..., 0, 1], R[..., 1, 1])
    y = np.arctan2(-R[..., 2, 0], R[..., 2, 2])
    return np.rad2deg(np.stack([z, x, y], -1))


def _rotation_between(a, b):
    """The smallest rotations ``[..., 3, 3]`` taking the unit vectors ``a`` to ``b`` (not opposite)."""
    v = np.cross(a, b)
    c = np.sum(a * b, axis=-1)[..., None, None]
    K = np.zeros(v.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    K = K - np.swapaxes(K, -1, -2)
    return np.eye(3) + K + K @ K / (1.0 + c)


def _level(R, w):
    """``R`` turned so that its forward axis (``R e_z``) is a ``w``-blend of itself and ``level(R e_z)``."""
    f = R @ np.array([0.0, 0.0, 1.0])
    g = f * np.array([1.0, 0.0, 1.0])
    g /= np.linalg.norm(g, axis=-1, keepdims=True)
    g = f + w[:, None] * (g - f)
    return _rotation_between(f, g / np.linalg.norm(g, axis=-1, keepdims=True)) @ R


_LEGS = (("Left", 1.0, 0.0), ("Right", -1.0, 0.5))  # side, sign of its hip's X offset, phase offset


def _leg_chain(R_hips, root, rot, side, sign):
    """World frames of one leg: ``(hip [n,3], R_thigh, R_shin, R_foot [n,3,3], toe [n,3])``."""
    R_th = R_hips @ _euler_zxy(np.stack(rot[f"{side}UpLeg"], -1))
    R_sh = R_th @ _euler_zxy(np.stack(rot[f"{side}Leg"], -1))
    R_ft = R_sh @ _euler_zxy(np.stack(rot[f"{side}Foot"], -1))
    hip = root + R_hips @ np.array([sign * _HIP_WIDTH, -_HIP_DROP, 0.0])
    ankle = hip + R_th @ np.array([0.0, -_THIGH, 0.0]) + R_sh @ np.array([0.0, -_SHIN, 0.0])
    return hip, R_th, R_sh, R_ft, ankle + R_ft @ np.array([0.0, _TOE[1], _TOE[0]])


def _original_toe(t, side, sign):
    """The toe joint of one leg of :func:`_raw_pose` (world, ``[n, 3]``)."""
    root, rot = _raw_pose(t)
    return _leg_chain(_euler_zxy(np.stack(rot["Hips"], -1)), root, rot, side, sign)[4]


def _toe_targets(t, side, sign, offset):
    """The planted toe path of one leg at the times ``t``: ``(ground [n, 3], clearance [n], w [n])``.

    ``ground`` is the toe's place on the ground (y = 0): its footprint in stance, a minimum-jerk path
    to the next footprint in swing. ``clearance`` is how high the foot's lowest point is lifted in
    swing (0 in stance, and from the heel strike on). ``w`` weighs the stance corrections of the
    foot's and the toes' orientations (1 in stance, fading over ``_BLEND`` in swing).
    """
    phase = t / _CYCLE_SECONDS + offset
    cycle = np.floor(phase - _PIN_ON)
    p = phase - cycle  # in [_PIN_ON, _PIN_ON + 1)
    t_on = (cycle + _PIN_ON - offset) * _CYCLE_SECONDS  # this cycle's landing
    t_next = t_on + _CYCLE_SECONDS
    ground = np.array([1.0, 0.0, 1.0])
    pin0, pin1 = _original_toe(t_on, side, sign) * ground, _original_toe(t_next, side, sign) * ground
    u = np.clip((p - _PIN_OFF) / (1.0 + _PIN_ON - _PIN_OFF), 0.0, 1.0)  # 0 at lift-off, 1 at landing
    s = u**3 * (10.0 - 15.0 * u + 6.0 * u**2)  # minimum jerk from one footprint to the next
    strike = (1.0 - _PIN_OFF) / (1.0 + _PIN_ON - _PIN_OFF)  # u of the heel strike
    clearance = _SWING_CLEARANCE * np.sin(math.pi * np.minimum(u / strike, 1.0)) ** 2
    gap = np.clip(np.minimum(p - _PIN_OFF, _PIN_ON + 1.0 - p) / _BLEND, 0.0, 1.0)
    w = np.where(p <= _PIN_OFF, 1.0, 1.0 - gap * gap * (3.0 - 2.0 * gap))
    return pin0 + s[:, None] * (pin1 - pin0), clearance, w


def _planted_leg(t, root, rot, side, sign, offset):
    """``(hip, ankle target, R_foot, R_toe, R_thigh, R_shin)`` of one planted leg (world frames)."""
    R_hips = _euler_zxy(np.stack(rot["Hips"], -1))
    hip, R_th, R_sh, R_ft, _ = _leg_chain(R_hips, root, rot, side, sign)
    target, clearance, w = _toe_targets(t, side, sign, offset)
    ey, ez = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
    f = R_ft @ ez  # the sole's forward axis; pointing up: the heel is below the ball
    f_new = f - w[:, None] * np.maximum(f @ ey, 0.0)[:, None] * ey
    R_ft = _rotation_between(f, f_new / np.linalg.norm(f_new, axis=-1, keepdims=True)) @ R_ft
    R_toe = _level(R_ft, w)
    # the toe joint's height: the foot's lowest point (heel, ball or tip) at the clearance
    heel = (R_ft @ ((_HEEL[0] - _TOE[0]) * ez))[:, 1]
    tip = (R_toe @ (_TOE_TIP * ez))[:, 1]
    target[:, 1] = clearance - np.minimum(np.minimum(heel, tip), 0.0)
    ankle = target - R_ft @ np.array([0.0, _TOE[1], _TOE[0]])
    return hip, ankle, R_ft, R_toe, R_th, R_sh


def _root_drop(p_left):
    """How far the root is lowered at the cycle fractions ``p_left`` so that every planted ankle is
    within ``_REACH`` of its leg's length; smooth and periodic (from a grid over one cycle, dilated
    then smoothed)."""
    n = 1000
    t = np.arange(n) / n * _CYCLE_SECONDS
    root, rot = _raw_pose(t)
    r = _REACH * (_THIGH + _SHIN)
    drop = np.zeros(n)
    for side, sign, offset in _LEGS:
        hip, ankle, *_ = _planted_leg(t, root, rot, side, sign, offset)
        d = ankle - hip
        horizontal = np.sum(d[:, [0, 2]] ** 2, axis=1)
        drop = np.maximum(drop, -d[:, 1] - np.sqrt(np.maximum(r * r - horizontal, 0.0)))
    drop = np.maximum(drop, 0.0)
    k = np.arange(-40, 41)  # dilate by 0.04 cycle, then a Gaussian of 0.012 cycle
    drop = np.max(np.stack([np.roll(drop, i) for i in k]), axis=0)
    g = np.exp(-0.5 * (k / 12.0) ** 2)
    drop = sum(gi * np.roll(drop, i) for i, gi in zip(k, g / g.sum()))
    return np.interp(np.mod(p_left, 1.0), np.arange(n + 1) / n, np.append(drop, drop[0]))


def _plant_feet(t, root, rot):
    """Replace ``rot``'s leg channels so that each toe joint follows :func:`_toe_targets`."""
    down = np.array([0.0, -1.0, 0.0])
    R_hips = _euler_zxy(np.stack(rot["Hips"], -1))
    for side, sign, offset in _LEGS:
        hip, ankle, R_ft, R_toe, R_th, R_sh = _planted_leg(t, root, rot, side, sign, offset)
        d = ankle - hip
        L = np.linalg.norm(d, axis=-1)
        if np.any(L > _THIGH + _SHIN - 1e-9):
            raise AssertionError(f"default clip: a planted {side} foot is out of reach")
        dhat = d / L[:, None]
        bend = R_th @ down  # the knee stays in the plane of the original thigh
        n = bend - np.sum(bend * dhat, -1, keepdims=True) * dhat
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        a = (_THIGH**2 - _SHIN**2 + L**2) / (2.0 * L)
        knee = hip + a[:, None] * dhat + np.sqrt(_THIGH**2 - a**2)[:, None] * n
        R_th_new = _rotation_between(R_th @ down, (knee - hip) / _THIGH) @ R_th
        R_sh_new = _rotation_between(R_sh @ down, (ankle - knee) / _SHIN) @ R_sh
        T = lambda R: np.swapaxes(R, -1, -2)  # noqa: E731
        for name, R in ((f"{side}UpLeg", T(R_hips) @ R_th_new), (f"{side}Leg", T(R_th_new) @ R_sh_new),
                        (f"{side}Foot", T(R_sh_new) @ R_ft), (f"{side}ToeBase", T(R_ft) @ R_toe)):
            rot[name] = list(np.moveaxis(_zxy_from_matrix(R), -1, 0))


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
    t = np.arange(int(num_frames), dtype=np.float64) / float(fps)
    root, rot = _raw_pose(t)
    root[:, 1] -= _root_drop(t / _CYCLE_SECONDS)
    _plant_feet(t, root, rot)
    columns = [root[:, 0], root[:, 1], root[:, 2]]
    for n, _, _ in _JOINTS:
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
