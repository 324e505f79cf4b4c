"""The retargeting map: which source joint drives which robot body or site, and its calibration.

The JSON contract (issue 30)::

    {"root": {"source": "Hips", "target": "pelvis"},
     "pairs": [{"source": "LeftFoot", "target": "left_ankle_roll_link", "foot": true,
                "position_weight": 1.0, "orientation_weight": 0.1, "offset": [w, x, y, z]}, ...],
     "source_up": "y",          # or "z" (default "y", BVH's)
     "scale": "auto"}           # or a number (default "auto")

Each pair may give ``position_weight`` (default 1), ``orientation_weight`` (default 0.1; 0: the
pair matches the position only) and ``offset``; ``foot`` marks the pairs whose stance is planted. A
foot whose robot body has no collision geometry on it or below it (a URDF whose meshes are missing)
stands on its target's frame: the sole is that frame's x-y plane, with a footprint of
``"sole": {"size": [length, width]}`` (m, along the frame's x and y) centred on its origin, or by
default ``0.3 x 0.12`` of the robot's leg length (the root target's height above the foot target in
the zero pose), which a warning states.
Everything else is computed by :func:`calibrate`: the source's world axes in the robot's
(``source_up``: a Y-up source's Y becomes the robot's Z, a Z-up source keeps its axes; then the
source is turned about up so that its pairs, seen from above, line up with the robot's in the zero
pose: the least-squares turn of each pair's horizontal offset from the root, so a robot that faces
-Y at ``qpos0``, as dm_control's CMU humanoid does, needs no more than one that faces +X), the
human-to-robot ``scale`` and each pair's rotation ``offset`` from the source's rest pose and the
robot's zero pose (``qpos0``): with ``C`` the axes' rotation, a source joint's world rotation ``R``
drives its target's as ``C R offset``, so ``offset = (C R_rest)^T R_zero``.

``scale: "auto"`` is the ratio of the two stances' heights, each the root's height above the
lowest foot pair along up: for a robot whose zero pose stands straight (the G1 does), the ratio of
leg lengths; a little less where the zero pose splays the legs (dm_control's CMU humanoid, by 20
degrees).
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Mapping as MappingABC

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _tree
from .. import rotations as rot
from .._errors import JaxanimError
from .._types import Array, Float
from ..kinematics._fk import forward_kinematics as skeleton_fk
from ..skeleton._skeleton import Skeleton
from ..robots._kinematics import world_frames, surface_points, target_frames, target_rows, forward_kinematics
from ..robots._robot import Robot, with_surface_points

__all__ = ["Calibration", "RetargetMap", "calibrate", "load_mapping", "with_soles"]

#: A Y-up source (BVH: facing +Z, +X on its left) in the robot's axes (facing +X, +Y on its left, Z up).
_Y_UP = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
_UP_AXES = {"y": _Y_UP, "z": np.eye(3)}
_TOP_KEYS = {"root", "pairs", "source_up", "scale"}
_PAIR_KEYS = {"source", "target", "foot", "position_weight", "orientation_weight", "offset", "sole"}


class RetargetMap(eqx.Module):
    """A parsed retargeting map (:func:`load_mapping`): names and flags static, numbers arrays.

    Attributes:
        root_source, root_target: the source joint and the robot body of the root.
        sources, targets: the pairs' source joints and robot bodies / sites (``"body:x"`` /
            ``"site:x"`` where a name is both).
        feet: whether each pair is a foot (planted in its stance phases).
        source_up: ``"y"`` or ``"z"``.
        auto_scale: whether ``scale`` is computed (:func:`calibrate`).
        given_offsets: whether each pair's ``offset`` was given (else computed).
        sole_size: each pair's ``"sole": {"size": [length, width]}`` (m), or ``None``.
        position_weight, orientation_weight: ``[pairs]`` weights of the matching terms.
        offset: ``[pairs, 4]`` wxyz rotation offsets (identity where not given).
        scale: the human-to-robot scale (``nan`` when ``auto_scale``).
    """

    root_source: str = eqx.field(static=True)
    root_target: str = eqx.field(static=True)
    sources: tuple[str, ...] = eqx.field(static=True)
    targets: tuple[str, ...] = eqx.field(static=True)
    feet: tuple[bool, ...] = eqx.field(static=True)
    source_up: str = eqx.field(static=True)
    auto_scale: bool = eqx.field(static=True)
    given_offsets: tuple[bool, ...] = eqx.field(static=True)
    sole_size: tuple[tuple[float, float] | None, ...] = eqx.field(static=True)
    position_weight: Float[Array, " pairs"]
    orientation_weight: Float[Array, " pairs"]
    offset: Float[Array, "pairs 4"]
    scale: Float[Array, ""]

    @property
    def num_pairs(self) -> int:
        return len(self.sources)


class Calibration(eqx.Module):
    """What :func:`calibrate` computed for one source skeleton and robot.

    Attributes:
        axes: ``[3, 3]`` the source's world axes in the robot's (``p_robot = axes @ p_source``).
        scale: human-to-robot scale (source units to metres of the robot).
        offset: ``[pairs, 4]`` wxyz rotation offsets: a pair's target rotation is
            ``axes R_source offset``.
    """

    axes: Float[Array, "3 3"]
    scale: Float[Array, ""]
    offset: Float[Array, "pairs 4"]


def _number(where: str, value, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise JaxanimError(f"mapping: {where}: expected a finite number, got {value!r}")
    if value < 0 or (positive and value == 0):
        raise JaxanimError(f"mapping: {where}: expected a {'positive' if positive else 'non-negative'} number, "
                           f"got {value!r}")
    return float(value)


def _sole(where: str, value) -> tuple[float, float]:
    size = value.get("size") if isinstance(value, MappingABC) and set(value) == {"size"} else None
    if not isinstance(size, (list, tuple)) or len(size) != 2:
        raise JaxanimError(f'mapping: {where}: expected {{"size": [length, width]}} (m), got {value!r}')
    return (_number(f"{where}.size[0]", size[0], positive=True), _number(f"{where}.size[1]", size[1], positive=True))


def _name(where: str, value) -> str:
    if not isinstance(value, str) or not value:
        raise JaxanimError(f"mapping: {where}: expected a name (a non-empty string), got {value!r}")
    return value


def load_mapping(mapping) -> RetargetMap:
    """Parse a retargeting map: a JSON file's path, or the dict it holds (see the module docstring).

    Raises:
        JaxanimError: naming the key at fault: an unknown key, a missing or unmapped root, no pairs,
            a pair without ``source`` / ``target``, a weight that is negative or not a number, an
            offset that is not a unit quaternion, or a bad ``source_up`` / ``scale``.
    """
    if isinstance(mapping, (str, os.PathLike)):
        try:
            with open(mapping, encoding="utf-8") as f:
                mapping = json.load(f)
        except json.JSONDecodeError as exc:
            raise JaxanimError(f"mapping: {os.fspath(mapping)}: not valid JSON: {exc}") from None
    if not isinstance(mapping, MappingABC):
        raise JaxanimError(f"mapping: expected a JSON object (a dict), got {type(mapping).__name__}")
    unknown = sorted(set(mapping) - _TOP_KEYS)
    if unknown:
        raise JaxanimError(f"mapping: unknown key(s) {unknown}; valid: {sorted(_TOP_KEYS)}")
    root = mapping.get("root")
    if not isinstance(root, MappingABC) or "source" not in root or "target" not in root:
        raise JaxanimError('mapping: root: the root is not mapped; expected {"root": {"source": SOURCE_JOINT, '
                           '"target": ROBOT_BODY}}')
    pairs = mapping.get("pairs")
    if not isinstance(pairs, (list, tuple)) or not pairs:
        raise JaxanimError("mapping: pairs: expected a non-empty list of {\"source\": ..., \"target\": ...}")
    up = mapping.get("source_up", "y")
    if up not in _UP_AXES:
        raise JaxanimError(f"mapping: source_up: expected 'y' or 'z', got {up!r}")
    scale = mapping.get("scale", "auto")
    auto = scale == "auto"
    scale = np.nan if auto else _number("scale", scale, positive=True)
    sources, targets, feet, wp, wo, offsets, given, soles = [], [], [], [], [], [], [], []
    for i, p in enumerate(pairs):
        where = f"pairs[{i}]"
        if not isinstance(p, MappingABC):
            raise JaxanimError(f"mapping: {where}: expected an object, got {p!r}")
        bad = sorted(set(p) - _PAIR_KEYS)
        if bad:
            raise JaxanimError(f"mapping: {where}: unknown key(s) {bad}; valid: {sorted(_PAIR_KEYS)}")
        sources.append(_name(f"{where}.source", p.get("source")))
        targets.append(_name(f"{where}.target", p.get("target")))
        foot = p.get("foot", False)
        if not isinstance(foot, bool):
            raise JaxanimError(f"mapping: {where}.foot: expected true or false, got {foot!r}")
        feet.append(foot)
        wp.append(_number(f"{where}.position_weight", p.get("position_weight", 1.0)))
        wo.append(_number(f"{where}.orientation_weight", p.get("orientation_weight", 0.1)))
        if "offset" in p:
            q = np.asarray(p["offset"], dtype=np.float64) if isinstance(p["offset"], (list, tuple)) else None
            if q is None or q.shape != (4,) or not np.all(np.isfinite(q)) or abs(np.linalg.norm(q) - 1) > 1e-6:
                raise JaxanimError(f"mapping: {where}.offset: expected a unit quaternion [w, x, y, z], got "
                                   f"{p['offset']!r}")
            offsets.append(q)
            given.append(True)
        else:
            offsets.append(np.array([1.0, 0.0, 0.0, 0.0]))
            given.append(False)
        soles.append(_sole(f"{where}.sole", p["sole"]) if "sole" in p else None)
    if not any(feet):
        raise JaxanimError('mapping: pairs: no pair is a foot ("foot": true); the feet are what is planted')
    return RetargetMap(
        root_source=_name("root.source", root["source"]), root_target=_name("root.target", root["target"]),
        sources=tuple(sources), targets=tuple(targets), feet=tuple(feet), source_up=up, auto_scale=auto,
        given_offsets=tuple(given), sole_size=tuple(soles), position_weight=jnp.asarray(wp), orientation_weight=jnp.asarray(wo),
        offset=jnp.asarray(np.stack(offsets)), scale=jnp.asarray(scale),
    )


def _source_index(skeleton: Skeleton, where: str, name: str) -> int:
    if name not in skeleton.names:
        raise JaxanimError(f"mapping: {where}: unknown source joint {name!r}; the skeleton's joints are "
                           f"{list(skeleton.names)}")
    return skeleton.names.index(name)


def _target_row(robot: Robot, where: str, name: str) -> int:
    try:
        return target_rows(robot, (name,))[1][0]
    except JaxanimError as exc:
        message = str(exc)
        raise JaxanimError(f"mapping: {where}: {message.removeprefix('names: ')}") from None


def _heading(p_src, src_root, src, p_rob, rob_root, rob) -> np.ndarray:
    """``[3, 3]`` the turn about up that lines the source's pairs up with the robot's, seen from above:
    the angle that best maps each pair's horizontal offset from the root in the rest pose onto the
    same pair's in the zero pose (least squares, Kabsch's in the plane). A map whose pairs mirror each
    other left to right, on a source and a robot that face the same way, gives exactly no turn."""
    a = p_src[src, :2] - p_src[src_root, :2]
    b = p_rob[rob, :2] - p_rob[rob_root, :2]
    c, s = np.sum(a * b), np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    if np.hypot(c, s) == 0.0:
        return np.eye(3)
    angle = np.arctan2(s, c)
    return np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]])


@eqx.filter_jit
def _zero_pose_feet(robot: Robot, bodies: tuple[int, ...], rows: tuple[int, ...], points: tuple[tuple[int, ...], ...]):
    """The zero pose's frames of the foot targets and each foot's surface points and their heights, in one
    compiled program (op by op, with a compile per operation, they took seconds)."""
    dtype = robot.qpos0.dtype
    R_world, p_world, *_ = world_frames(robot, robot.qpos0, dtype)
    frames = target_frames(robot, R_world, p_world, list(bodies), list(rows), dtype)
    return frames, tuple(surface_points(robot, R_world, p_world, idx, dtype) for idx in points)


_rest_fk = eqx.filter_jit(skeleton_fk)
#: Rotation matrices to canonical quaternions, compiled (op by op it compiled each operation per new shape).
_canonical_quat = jax.jit(lambda R: rot.quat_canonical(rot.matrix_to_quat(R)))


#: The default footprint of a foot without collision geometry, as fractions of the robot's leg length
#: (an adult's foot is about 0.26 m long and 0.1 m wide for a leg of about 0.9 m).
SOLE_FRACTIONS = (0.3, 0.12)


def _footless(robot: Robot, bodies) -> list[int]:
    """The indices (into ``bodies``) of the foot targets with no surface point on their body or below it."""
    below = _tree.subtree(robot.body_parents)
    return [k for k, body in enumerate(bodies) if not any(below[body, b] for b in robot.point_bodies)]


def with_soles(robot: Robot, mapping: RetargetMap, *, warn: bool = True) -> tuple[Robot, tuple]:
    """The robot with a footprint on each foot pair that has no collision geometry on it or below it.

    The footprint's four corners lie in the foot target's frame at ``(+-length / 2, +-width / 2, 0)``
    (its x-y plane is the sole), put on the target's body; the size is the pair's ``"sole"`` or, with a
    warning, :data:`SOLE_FRACTIONS` of the leg length (the root target's height above the foot target at
    the zero pose).

    Returns:
        ``(robot, added)``: the robot (the same object when no foot needs a sole) and the points added,
        ``((body, (x, y, z)), ...)`` in the bodies' frames.
    """
    feet = [i for i, foot in enumerate(mapping.feet) if foot]
    bodies, rows = target_rows(robot, [mapping.targets[i] for i in feet])
    bare = _footless(robot, bodies)
    if not bare:
        return robot, ()
    root_body, root_row = target_rows(robot, (mapping.root_target,))
    (p, R), _ = _zero_pose_feet(robot, tuple(int(b) for b in bodies) + root_body, tuple(int(r) for r in rows) + root_row,
                                ())
    p, R = np.asarray(p, np.float64), np.asarray(R, np.float64)
    zero = forward_kinematics(robot, robot.qpos0)
    xpos, xmat = np.asarray(zero.xpos, np.float64), np.asarray(zero.xmat, np.float64)
    added, defaulted = [], []
    for k in bare:
        i, body = feet[k], bodies[k]
        size = mapping.sole_size[i]
        if size is None:
            leg = float(p[-1, 2] - p[k, 2])
            if not leg > 0:  # not below the root: calibrate names the pair
                continue
            size = (SOLE_FRACTIONS[0] * leg, SOLE_FRACTIONS[1] * leg)
            defaulted.append(f"{mapping.targets[i]} {size[0]:.3f} x {size[1]:.3f} m")
        corners = np.array([[x * size[0] / 2, y * size[1] / 2, 0.0] for x in (-1, 1) for y in (-1, 1)])
        in_body = (p[k] + corners @ R[k].T - xpos[body]) @ xmat[body]  # the target frame's corners in its body's
        added += [(int(body), tuple(float(c) for c in point)) for point in in_body]
    if defaulted and warn:
        warnings.warn(f"robot {robot.name!r}: the feet {defaulted} have no collision geometry; each stands on its "
                      f'target\'s frame with a footprint of {SOLE_FRACTIONS[0]} x {SOLE_FRACTIONS[1]} of the leg length; '
                      'give the foot pair "sole": {"size": [length, width]} (m) to set it', stacklevel=3)
    if not added:
        return robot, ()
    robot = with_surface_points(robot, [b for b, _ in added], [x for _, x in added])
    return robot, tuple(added)


def _standing_feet(robot: Robot, bodies, rows) -> tuple[tuple[tuple[int, ...], ...], np.ndarray, np.ndarray]:
    """Each foot target standing flat: ``(points, R [F, 3, 3], height [F])``.

    ``points`` are the foot's surface points (its body's and its descendants', indices into
    ``Robot.point_pos``). Flat is the zero pose's orientation of the target tilted by the least
    rotation that levels the plane fitted through those points (their lowest surface, least squares):
    a robot whose zero pose splays its legs, as dm_control's CMU humanoid does by 20 degrees, still
    plants its soles flat, and one that stands on level soles (the G1) keeps its zero pose. ``height``
    is the target's height above the lowest point of the levelled foot (m).
    """
    below = _tree.subtree(robot.body_parents)
    points = []
    for body in bodies:
        idx = tuple(i for i, b in enumerate(robot.point_bodies) if below[body, b])
        if not idx:
            raise JaxanimError(f"robot: the foot {robot.body_names[body]!r} has no collision geometry on it or below "
                               "it, so its sole and the ground cannot be found (retargeting.with_soles gives it one)")
        points.append(idx)
    (p_zero, R_zero), surfaces = _zero_pose_feet(robot, tuple(int(b) for b in bodies), tuple(int(r) for r in rows),
                                                 tuple(points))
    p_zero, R_zero = np.asarray(p_zero, np.float64), np.asarray(R_zero, np.float64)
    flat, heights = [], []
    for k, idx in enumerate(points):
        world, h = (np.asarray(x, np.float64) for x in surfaces[k])
        radius = world[:, 2] - h
        xy = world[:, :2] - world[:, :2].mean(axis=0)
        slope = np.linalg.lstsq(xy, h - h.mean(), rcond=1e-9)[0]
        n = np.array([-slope[0], -slope[1], 1.0]) / np.hypot(np.hypot(*slope), 1.0)
        level = np.eye(3)
        if np.linalg.norm(slope) > 1e-12:  # the least rotation taking n onto +z
            axis = np.cross(n, [0.0, 0.0, 1.0])
            level = np.asarray(rot.rotvec_to_matrix(jnp.asarray(axis / np.linalg.norm(axis) * np.arccos(n[2]))))
        levelled = (world - p_zero[k]) @ level.T  # about the target, which the levelling does not move
        flat.append(level @ R_zero[k])
        heights.append(-float(np.min(levelled[:, 2] - radius)))
    return tuple(points), np.stack(flat) if flat else np.zeros((0, 3, 3)), np.asarray(heights)


def calibrate(mapping: RetargetMap, skeleton: Skeleton, robot: Robot) -> Calibration:
    """The axes, scale and rotation offsets of ``mapping`` for ``skeleton`` and ``robot``, from the
    skeleton's rest pose (identity rotations, OFFSETs) and the robot's zero pose (``qpos0``).

    Given offsets and a given scale are kept; the others are computed (see the module docstring).

    Raises:
        JaxanimError: an unknown source joint or robot body / site (the valid names listed), or a
            foot pair that is not below the root in either pose.
    """
    if not isinstance(mapping, RetargetMap):
        raise JaxanimError(f"mapping: expected a RetargetMap (retargeting.load_mapping), got {type(mapping).__name__}")
    src = [_source_index(skeleton, f"pairs[{i}].source", n) for i, n in enumerate(mapping.sources)]
    src_root = _source_index(skeleton, "root.source", mapping.root_source)
    tgt = [_target_row(robot, f"pairs[{i}].target", n) for i, n in enumerate(mapping.targets)]
    tgt_root = _target_row(robot, "root.target", mapping.root_target)
    rest = _rest_fk(skeleton, skeleton.rest_rotations(), skeleton.offsets)
    zero = forward_kinematics(robot, robot.qpos0)
    p_rob = np.concatenate([np.asarray(zero.xpos, np.float64), np.asarray(zero.site_xpos, np.float64)])
    R_rob = np.concatenate([np.asarray(zero.xmat, np.float64), np.asarray(zero.site_xmat, np.float64)])
    axes = _heading(np.asarray(rest.positions, np.float64) @ _UP_AXES[mapping.source_up].T, src_root, src,
                    p_rob, tgt_root, tgt) @ _UP_AXES[mapping.source_up]
    p_src = np.asarray(rest.positions, np.float64) @ axes.T  # in the robot's axes
    R_src = axes @ np.asarray(rest.rotations, np.float64)
    heights = []
    for p, root, rows, what in ((p_src, src_root, src, "source rest pose"), (p_rob, tgt_root, tgt, "robot zero pose")):
        for i, foot in enumerate(mapping.feet):
            if foot and not p[rows[i], 2] < p[root, 2]:
                raise JaxanimError(f"mapping: pairs[{i}] is a foot, but in the {what} it is not below the root "
                                   f"({mapping.sources[i] if p is p_src else mapping.targets[i]} at height "
                                   f"{p[rows[i], 2]:.4g}, the root at {p[root, 2]:.4g})")
        heights.append(p[root, 2] - min(p[rows[i], 2] for i, foot in enumerate(mapping.feet) if foot))
    scale = heights[1] / heights[0] if mapping.auto_scale else float(mapping.scale)
    given = np.asarray(mapping.offset, np.float64)
    feet = [i for i, foot in enumerate(mapping.feet) if foot]
    robot, _ = with_soles(robot, mapping)  # a foot without geometry stands on its target's frame
    R_pair = R_rob[tgt]
    R_pair[feet] = _standing_feet(robot, target_rows(robot, [mapping.targets[i] for i in feet])[0], [tgt[i] for i in feet])[1]
    M = np.swapaxes(R_src[src], -1, -2) @ R_pair  # each pair's offset, computed in one call
    computed = np.asarray(_canonical_quat(jnp.asarray(M)), np.float64)
    offsets = [given[i] if mapping.given_offsets[i] else computed[i] for i in range(mapping.num_pairs)]
    dtype = robot.qpos0.dtype
    return Calibration(axes=jnp.asarray(axes, dtype), scale=jnp.asarray(scale, dtype),
                       offset=jnp.asarray(np.stack(offsets), dtype))
