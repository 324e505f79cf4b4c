"""Motion-matching features of every frame of a clip.

The feature vector of a frame (Clavet's list; Holden's "Learned Motion Matching" layout) holds, in
the frame's **facing frame** (origin: the root projected on the ground; axes: the root's yaw only,
``z`` forward, ``y`` up):

============================  ====  =====================================================
block                          size  content
============================  ====  =====================================================
``root_velocity``                3   root linear velocity
``root_angular_velocity``        3   root angular velocity
``foot_positions``               6   left and right foot positions
``foot_velocities``              6   left and right foot velocities
``hand_positions`` (optional)    6   left and right hand positions
``hand_velocities`` (optional)   6   left and right hand velocities
``foot_contacts``                2   1 where a foot is low and slow, else 0
``trajectory_positions``        2T   ground position ``(x, z)`` of the facing origin at each future time
``trajectory_directions``       2T   facing direction ``(x, z)`` at each future time
============================  ====  =====================================================

with ``T`` future times (default 0.5, 1.0, 1.5 s). Velocities are central differences (one-sided at a
clip's ends). Positions and velocities are in file units (per second), angular velocities in rad/s.
The world is ``y``-up and the rest pose faces ``+z``.

The features are computed on the host from one batched forward kinematics per clip: a database is
built once.
"""

from __future__ import annotations

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import JaxanimError
from ..kinematics._fk import forward_kinematics
from ..rotations._numpy import quat_conj as _quat_conj
from ..rotations._numpy import quat_log as _quat_log
from ..rotations._numpy import quat_mul as _quat_mul
from ..skeleton._processing import facing_frame
from ..skeleton._skeleton import Motion, Skeleton

__all__ = ["FeatureOptions", "FeatureWeights", "FeatureLayout", "clip_features", "detect_feet", "detect_hands",
           "yaw_of"]


class FeatureWeights(eqx.Module):
    """Weight of each feature block; each block is first normalised by its standard deviation over the
    database (one deviation per block, the mean of its dimensions'), then multiplied by its weight.
    A weight of 0 removes a block from the distance."""

    root_velocity: float = eqx.field(default=1.0, converter=jnp.asarray)
    root_angular_velocity: float = eqx.field(default=1.0, converter=jnp.asarray)
    foot_positions: float = eqx.field(default=0.75, converter=jnp.asarray)
    foot_velocities: float = eqx.field(default=1.0, converter=jnp.asarray)
    hand_positions: float = eqx.field(default=0.5, converter=jnp.asarray)
    hand_velocities: float = eqx.field(default=0.5, converter=jnp.asarray)
    foot_contacts: float = eqx.field(default=0.5, converter=jnp.asarray)
    trajectory_positions: float = eqx.field(default=1.0, converter=jnp.asarray)
    trajectory_directions: float = eqx.field(default=1.5, converter=jnp.asarray)


class FeatureOptions(eqx.Module):
    """How features are computed.

    Attributes:
        weights: the block weights.
        trajectory_times: future times of the trajectory features, seconds (static).
        feet: ``(left, right)`` foot joint names (static); ``None`` detects them (:func:`detect_feet`).
        hands: ``(left, right)`` hand joint names (static); ``None`` detects them when ``use_hands``.
        use_hands: include the hand blocks (static; default off).
        contact_height: a foot is in contact below this height above the lowest foot height of the
            database (file units); ``None``: 5 % of the leg length (root to foot at rest).
        contact_speed: ... and slower than this (file units per second); ``None``: half a leg length
            per second.
    """

    weights: FeatureWeights = eqx.field(default_factory=FeatureWeights)
    trajectory_times: tuple[float, ...] = eqx.field(default=(0.5, 1.0, 1.5), static=True)
    feet: tuple[str, str] | None = eqx.field(default=None, static=True)
    hands: tuple[str, str] | None = eqx.field(default=None, static=True)
    use_hands: bool = eqx.field(default=False, static=True)
    contact_height: float | None = eqx.field(default=None, static=True)
    contact_speed: float | None = eqx.field(default=None, static=True)

    def __check_init__(self):
        times = self.trajectory_times
        if not times or any(not (math.isfinite(t) and t > 0) for t in times) or list(times) != sorted(set(times)):
            raise JaxanimError(f"trajectory_times: expected increasing positive seconds, got {times}")
        for name in ("feet", "hands"):
            v = getattr(self, name)
            if v is not None and (len(v) != 2 or not all(isinstance(x, str) for x in v)):
                raise JaxanimError(f"{name}: expected two joint names (left, right), got {v!r}")


class FeatureLayout(eqx.Module):
    """The static layout of a feature vector: block names, sizes and offsets; the joints used; the
    trajectory's future times and frame offsets."""

    blocks: tuple[tuple[str, int], ...] = eqx.field(static=True)
    feet: tuple[int, int] = eqx.field(static=True)
    hands: tuple[int, int] | None = eqx.field(static=True)
    trajectory_times: tuple[float, ...] = eqx.field(static=True)
    trajectory_frames: tuple[int, ...] = eqx.field(static=True)

    @property
    def size(self) -> int:
        return sum(n for _, n in self.blocks)

    def slice(self, name: str) -> slice:
        """Where block ``name`` sits in a feature vector."""
        start = 0
        for b, n in self.blocks:
            if b == name:
                return slice(start, start + n)
            start += n
        raise JaxanimError(f"unknown feature block {name!r}; blocks: {[b for b, _ in self.blocks]}")

    @property
    def trajectory_start(self) -> int:
        """Index of the first trajectory feature (the trajectory blocks come last)."""
        return self.slice("trajectory_positions").start


@functools.lru_cache(maxsize=64)
def _rest_positions_cached(skeleton_key) -> np.ndarray:
    parents, offsets = skeleton_key
    off = np.asarray(offsets, dtype=np.float64).reshape(-1, 3)
    p = np.zeros_like(off)
    for j, par in enumerate(parents):
        p[j] = off[j] + (p[par] if par >= 0 else 0.0)
    p[0] = 0.0  # the root at the origin
    return p


def _rest_positions(skeleton: Skeleton) -> np.ndarray:
    """World joint positions at rest (identity rotations, OFFSETs, the root at the origin)."""
    return _rest_positions_cached((skeleton.parents, tuple(np.asarray(skeleton.offsets, np.float64).ravel().tolist())))


def _leaves(skeleton: Skeleton) -> list[int]:
    has_child = set(p for p in skeleton.parents if p >= 0)
    return [j for j in range(skeleton.num_joints) if j not in has_child]


def _resolve(skeleton: Skeleton, names, what: str) -> tuple[int, int]:
    out = []
    for n in names:
        if n not in skeleton.names:
            raise JaxanimError(f"{what}: unknown joint {n!r}; valid joints: {list(skeleton.names)}")
        out.append(skeleton.names.index(n))
    return tuple(out)


def detect_feet(skeleton: Skeleton, names: tuple[str, str] | None = None) -> tuple[int, int]:
    """The ``(left, right)`` foot joints: on each side (``+x`` is left, ``-x`` right, the rest pose facing
    ``+z``), the lowest leaf at rest; the foot is that leaf's parent (the ankle above a toe) unless the
    parent is the root. ``names`` overrides the detection.

    Raises:
        JaxanimError: on an unknown name, or when no leaf lies below the root on one side.
    """
    if names is not None:
        return _resolve(skeleton, names, "feet")
    p = _rest_positions(skeleton)
    out = []
    for side, sign in (("left", 1.0), ("right", -1.0)):
        cands = [j for j in _leaves(skeleton) if sign * p[j, 0] > 1e-9 and p[j, 1] < 0.0]
        if not cands:
            raise JaxanimError(f"feet: found no leaf joint below the root on the {side} side (x {'>' if sign > 0 else '<'} 0)"
                               f" at rest; name them with feet=(left, right); joints: {list(skeleton.names)}")
        leaf = min(cands, key=lambda j: (p[j, 1], j))
        par = skeleton.parents[leaf]
        out.append(par if par > 0 else leaf)
    return tuple(out)


def detect_hands(skeleton: Skeleton, names: tuple[str, str] | None = None) -> tuple[int, int]:
    """The ``(left, right)`` hand joints: on each side, the leaf above the root at rest farthest from the
    centre line (the distal end of the arm chain). ``names`` overrides the detection.

    Raises:
        JaxanimError: on an unknown name, or when no leaf lies above the root on one side.
    """
    if names is not None:
        return _resolve(skeleton, names, "hands")
    p = _rest_positions(skeleton)
    out = []
    for side, sign in (("left", 1.0), ("right", -1.0)):
        cands = [j for j in _leaves(skeleton) if sign * p[j, 0] > 1e-9 and p[j, 1] > 0.0]
        if not cands:
            raise JaxanimError(f"hands: found no leaf joint above the root on the {side} side at rest; name them "
                               f"with hands=(left, right); joints: {list(skeleton.names)}")
        out.append(max(cands, key=lambda j: (sign * p[j, 0], -j)))
    return tuple(out)


def make_layout(skeleton: Skeleton, frame_time: float, options: FeatureOptions) -> FeatureLayout:
    """The feature layout of ``skeleton`` at ``frame_time`` under ``options``."""
    feet = detect_feet(skeleton, options.feet)
    hands = detect_hands(skeleton, options.hands) if options.use_hands else None
    T = len(options.trajectory_times)
    blocks = [("root_velocity", 3), ("root_angular_velocity", 3), ("foot_positions", 6), ("foot_velocities", 6)]
    if hands is not None:
        blocks += [("hand_positions", 6), ("hand_velocities", 6)]
    blocks += [("foot_contacts", 2), ("trajectory_positions", 2 * T), ("trajectory_directions", 2 * T)]
    frames = tuple(max(1, int(round(t / frame_time))) for t in options.trajectory_times)
    return FeatureLayout(tuple(blocks), feet, hands, tuple(float(t) for t in options.trajectory_times), frames)


def yaw_of(q) -> np.ndarray:
    """Yaw angle (about ``+y``, from ``+z`` towards ``+x``) of yaw-only wxyz quaternions."""
    q = np.asarray(q)
    return 2.0 * np.arctan2(q[..., 2], q[..., 0])


def _rotate_y(yaw: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``R_y(yaw) v`` for ``[..., 3]`` vectors (``yaw`` broadcasts over the leading axes)."""
    c, s = np.cos(yaw), np.sin(yaw)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([c * x + s * z, y, -s * x + c * z], axis=-1)


def _gradient(x: np.ndarray, dt: float) -> np.ndarray:
    """Central differences along frames, one-sided at the ends."""
    if x.shape[0] < 2:
        return np.zeros_like(x)
    return np.gradient(x, dt, axis=0)


def angular_velocity(q: np.ndarray, dt: float) -> np.ndarray:
    """``[frames, ..., 3]`` angular velocity of ``[frames, ..., 4]`` rotations, in the frame they map from
    (``log(q[f+1] q[f-1]^-1) / (2 dt)``: the world frame for global rotations, the parent's for local
    ones); one-sided at the ends."""
    F = q.shape[0]
    if F < 2:
        return np.zeros(q.shape[:-1] + (3,))
    nxt = np.concatenate([q[1:], q[-1:]], axis=0)
    prv = np.concatenate([q[:1], q[:-1]], axis=0)
    span = np.full((F,) + (1,) * (q.ndim - 1), 2.0 * dt)
    span[0] = span[-1] = dt
    return _quat_log(_quat_mul(nxt, _quat_conj(prv))) / span


_batched_fk = jax.jit(jax.vmap(forward_kinematics, in_axes=(None, 0, 0)))


class ClipFeatures(eqx.Module):
    """Everything a database keeps about one clip's frames (host arrays, float64)."""

    features: np.ndarray  # [F, D] raw
    searchable: np.ndarray  # [F] bool
    rotations: np.ndarray  # [F, J, 4] local; the root's in the facing frame
    translations: np.ndarray  # [F, J, 3] local; the root's in the facing frame
    angular_velocities: np.ndarray  # [F, J, 3] local
    root_velocity: np.ndarray  # [F, 3] of translations[:, 0]
    step_position: np.ndarray  # [F, 3] facing-origin displacement from the previous frame, in its facing frame
    step_yaw: np.ndarray  # [F] facing yaw change from the previous frame
    foot_height: np.ndarray  # [F, 2]
    foot_speed: np.ndarray  # [F, 2]
    ground_speed: np.ndarray  # [F] speed of the facing origin


def clip_features(skeleton: Skeleton, motion: Motion, layout: FeatureLayout) -> ClipFeatures:
    """The raw (unnormalised) features of every frame of one clip, with the contact block left at 0
    (it needs the database's thresholds: :func:`contacts`), and the playback data.

    Args:
        skeleton: the clip's skeleton.
        motion: the clip, ``F`` frames.
        layout: from :func:`make_layout`.

    Returns:
        :class:`ClipFeatures` (NumPy, float64).
    """
    dt = float(motion.frame_time)
    F = motion.num_frames
    fk = _batched_fk(skeleton, jnp.asarray(motion.rotations), jnp.asarray(motion.translations))
    P = np.asarray(fk.positions, dtype=np.float64)  # [F, J, 3]
    q_root = np.asarray(motion.rotations[:, 0], dtype=np.float64)
    q_face, origin = facing_frame(jnp.asarray(q_root), jnp.asarray(P[:, 0]))
    yaw = np.unwrap(yaw_of(np.asarray(q_face, np.float64)))
    origin = np.asarray(origin, np.float64)
    inv = -yaw[:, None]

    def local(v):  # world vectors [F, k, 3] -> facing frame
        return _rotate_y(inv, v)

    v_root = _gradient(P[:, 0], dt)
    w_root = angular_velocity(q_root, dt)
    feet = list(layout.feet)
    p_feet = local(P[:, feet] - origin[:, None])
    v_feet_w = _gradient(P[:, feet], dt)
    v_feet = local(v_feet_w)
    blocks = {
        "root_velocity": _rotate_y(-yaw, v_root),
        "root_angular_velocity": _rotate_y(-yaw, w_root),
        "foot_positions": p_feet.reshape(F, 6),
        "foot_velocities": v_feet.reshape(F, 6),
        "foot_contacts": np.zeros((F, 2)),
    }
    if layout.hands is not None:
        hands = list(layout.hands)
        blocks["hand_positions"] = local(P[:, hands] - origin[:, None]).reshape(F, 6)
        blocks["hand_velocities"] = local(_gradient(P[:, hands], dt)).reshape(F, 6)
    fut = np.stack([np.minimum(np.arange(F) + k, F - 1) for k in layout.trajectory_frames], axis=1)  # [F, T]
    d = _rotate_y(-yaw[:, None], origin[fut] - origin[:, None])  # [F, T, 3]
    rel = yaw[fut] - yaw[:, None]
    blocks["trajectory_positions"] = d[..., [0, 2]].reshape(F, -1)
    blocks["trajectory_directions"] = np.stack([np.sin(rel), np.cos(rel)], axis=-1).reshape(F, -1)
    features = np.concatenate([blocks[name] for name, _ in layout.blocks], axis=1)
    searchable = np.arange(F) + max(layout.trajectory_frames) <= F - 1

    rotations = np.array(motion.rotations, dtype=np.float64)
    half = 0.5 * yaw
    q_inv_face = np.stack([np.cos(half), np.zeros(F), -np.sin(half), np.zeros(F)], axis=-1)
    rotations[:, 0] = _quat_mul(q_inv_face, q_root)
    translations = np.array(motion.translations, dtype=np.float64)
    translations[:, 0] = _rotate_y(-yaw, P[:, 0] - origin)
    step = np.zeros((F, 3))
    step_yaw = np.zeros(F)
    if F > 1:
        step[1:] = _rotate_y(-yaw[:-1], origin[1:] - origin[:-1])
        step_yaw[1:] = np.diff(yaw)
        step[0], step_yaw[0] = step[1], step_yaw[1]
    ground_speed = np.linalg.norm(_gradient(origin, dt), axis=-1)
    return ClipFeatures(
        features=features, searchable=searchable, rotations=rotations, translations=translations,
        angular_velocities=angular_velocity(rotations, dt), root_velocity=_gradient(translations[:, 0], dt),
        step_position=step, step_yaw=step_yaw, foot_height=P[:, feet, 1],
        foot_speed=np.linalg.norm(v_feet_w, axis=-1), ground_speed=ground_speed)


def contact_thresholds(skeleton: Skeleton, layout: FeatureLayout, options: FeatureOptions) -> tuple[float, float]:
    """``(height, speed)`` thresholds above the lowest foot height (file units, per second)."""
    p = _rest_positions(skeleton)
    leg = float(np.mean([abs(p[j, 1] - p[0, 1]) for j in layout.feet])) or 1.0
    h = 0.05 * leg if options.contact_height is None else float(options.contact_height)
    v = 0.5 * leg if options.contact_speed is None else float(options.contact_speed)
    return h, v
