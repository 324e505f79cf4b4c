"""The retargeting map: which source joint drives which robot body or site, and its calibration.

The JSON contract (issue 30)::

    {"root": {"source": "Hips", "target": "pelvis"},
     "pairs": [{"source": "LeftFoot", "target": "left_ankle_roll_link", "foot": true,
                "position_weight": 1.0, "orientation_weight": 0.1, "offset": [w, x, y, z]}, ...],
     "source_up": "y",          # or "z" (default "y", BVH's)
     "scale": "auto",           # or a number (default "auto")
     "calibration_frame": 0}    # optional: calibrate in this frame of the clip (default: the rest pose)

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
human-to-robot ``scale`` and each pair's rotation ``offset`` in a common pose: the robot is brought
by IK, on the pairs' positions, into the source's rest pose (a T-pose, where the robot's zero pose
has its arms down) or the clip's frame ``calibration_frame``, and with ``C`` the axes' rotation, a
source joint's world rotation ``R`` drives its target's as ``C R offset``, so ``offset = (C
R_common)^T R_robot`` there; a foot's ``R_robot`` is its zero pose levelled (it stands flat).

``scale: "auto"`` is the ratio of the two stances' heights, each the root's height above the
lowest foot pair along up: for a robot whose zero pose stands straight (the G1 does), the ratio of
leg lengths; a little less where the zero pose splays the legs (dm_control's CMU humanoid, by 20
degrees).
"""

from __future__ import annotations

import collections
import dataclasses
import hashlib
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
from ..ik._robot import solve_ik_robot
from ..ik._targets import Target
from ..rotations._numpy import quat_exp, quat_mul, quat_to_matrix
from ..robots._robot import Robot, with_surface_points
from ..robots._tangent import free_joint_of

__all__ = ["Calibration", "RetargetMap", "calibrate", "load_mapping", "upright", "with_soles"]

#: A Y-up source (BVH: facing +Z, +X on its left) in the robot's axes (facing +X, +Y on its left, Z up).
_Y_UP = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
_UP_AXES = {"y": _Y_UP, "z": np.eye(3)}
_TOP_KEYS = {"root", "pairs", "source_up", "scale", "calibration_frame"}
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
        calibration_frame: the clip's frame that :func:`calibrate` takes as the common pose (``None``: the
            source's rest pose).
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
    calibration_frame: int | None = eqx.field(static=True)
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
        qpos: ``[nq]`` the robot in the common pose where the offsets were taken (``None`` in a
            calibration made by hand).
    """

    axes: Float[Array, "3 3"]
    scale: Float[Array, ""]
    offset: Float[Array, "pairs 4"]
    qpos: Float[Array, " nq"] | None = None


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
    frame = mapping.get("calibration_frame")
    if frame is not None and (isinstance(frame, bool) or not isinstance(frame, int) or frame < 0):
        raise JaxanimError(f"mapping: calibration_frame: expected a frame index (an int >= 0), got {frame!r}")
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
        given_offsets=tuple(given), sole_size=tuple(soles), calibration_frame=frame,
        position_weight=jnp.asarray(wp), orientation_weight=jnp.asarray(wo),
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


#: A zero pose whose root stands within this angle of straight above its feet is upright (the rest are turned).
_UPRIGHT = np.radians(45.0)


def upright(robot: Robot, mapping: RetargetMap) -> Robot:
    """The robot standing up: where its zero pose does not put the map's root above its feet (dm_control's
    V2020 CMU walker stands along +Y until it is attached to an arena), its free joint's part of ``qpos0``
    turned by the least rotation that takes the feet-to-root direction onto +Z; otherwise (or without a free
    joint on the root) the robot as it is. Only the zero pose changes, which the calibration reads: the
    solve sets the root from the clip."""
    feet = [mapping.targets[i] for i, foot in enumerate(mapping.feet) if foot]
    if not feet:
        return robot
    (root_body,), (root_row,) = target_rows(robot, (mapping.root_target,))
    rows = target_rows(robot, feet)[1]
    zero = forward_kinematics(robot, robot.qpos0)
    p = np.concatenate([np.asarray(zero.xpos, np.float64), np.asarray(zero.site_xpos, np.float64)])
    v = p[root_row] - p[list(rows)].mean(axis=0)
    n = float(np.linalg.norm(v))
    free = free_joint_of(robot, root_body)
    if n == 0.0 or v[2] >= np.cos(_UPRIGHT) * n or free is None:
        return robot
    axis = np.cross(v / n, [0.0, 0.0, 1.0])
    angle = np.arccos(np.clip(v[2] / n, -1.0, 1.0))
    axis = axis / np.linalg.norm(axis) if np.linalg.norm(axis) > 1e-12 else np.array([1.0, 0.0, 0.0])
    turn = quat_exp(angle * axis)  # wxyz, on the host
    a = robot.jnt_qposadr[free]
    q0 = np.asarray(robot.qpos0, np.float64).copy()
    q0[a:a + 3] = quat_to_matrix(turn) @ q0[a:a + 3]
    q0[a + 3:a + 7] = quat_mul(turn, q0[a + 3:a + 7])
    return dataclasses.replace(robot, qpos0=jnp.asarray(q0, robot.qpos0.dtype))


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


#: The calibration IK's pull of every joint towards ``qpos0`` (per rad^2, against m^2 of the targets): small,
#: so the pairs are reached, and enough to keep the redundant joints (a wrist's twist) at their zero.
_CALIBRATION_DAMPING = 1e-4
#: A pair whose zero-pose segment (from its anchor) is within this angle (rad) of the source's is left as it is,
#: and so is an anchor between pairs (a shoulder, a hip) within the second: the short segments from a pelvis to
#: its hips differ by the two bodies' proportions (the G1's by 24 degrees from the walk's), an arm hanging
#: down where the source holds it out by 90.
_SAME_DIRECTION = np.radians(20.0)
_SAME_ANCHOR = np.radians(45.0)
#: The calibration IK's weight on the root's dofs against the joints': it stays where it is (to ~1e-9 m).
_HELD = 1e8

#: The default footprint of a foot without collision geometry, as fractions of the robot's leg length
#: (an adult's foot is about 0.26 m long and 0.1 m wide for a leg of about 0.9 m).
SOLE_FRACTIONS = (0.3, 0.12)


def _footless(robot: Robot, bodies) -> list[int]:
    """The indices (into ``bodies``) of the foot targets with no surface point on their body or below it."""
    below = _tree.subtree(robot.body_parents)
    return [k for k, body in enumerate(bodies) if not any(below[body, b] for b in robot.point_bodies)]


def with_soles(robot: Robot, mapping: RetargetMap) -> tuple[Robot, tuple]:
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
    # one pass of the zero pose: the foot targets' frames, their bodies' frames (a body's row is its index), the root
    F, bodies = len(bodies), tuple(int(b) for b in bodies)
    (p, R), _ = _zero_pose_feet(robot, bodies + bodies + root_body, tuple(int(r) for r in rows) + bodies + root_row, ())
    p, R = np.asarray(p, np.float64), np.asarray(R, np.float64)
    xpos, xmat = p[F:2 * F], R[F:2 * F]
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
        in_body = (p[k] + corners @ R[k].T - xpos[k]) @ xmat[k]  # the target frame's corners in its body's
        added += [(int(body), tuple(float(c) for c in point)) for point in in_body]
    if defaulted:
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
    rotation that levels the plane fitted through those points (their lowest surface, least squares; a
    mesh's points are its underside):
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


#: The calibration IK's results by their inputs (:func:`_pose_key`), the most recent first: a dataset's clips of
#: one skeleton calibrate the same way, and each IK traced its program again (a quarter of a second per clip).
_COMMON_POSES: collections.OrderedDict[str, np.ndarray] = collections.OrderedDict()
_COMMON_POSES_KEPT = 32


def _pose_key(robot: Robot, names, goals, root_body: int) -> str:
    """A digest of everything the calibration IK depends on: the robot's structure and numbers, the targets."""
    h = hashlib.sha256()
    leaves, treedef = jax.tree_util.tree_flatten(robot)
    h.update(repr((str(treedef), tuple(names), int(root_body))).encode())
    for x in leaves:
        a = np.asarray(x)
        h.update(repr((a.dtype.str, a.shape)).encode() + np.ascontiguousarray(a).tobytes())
    h.update(np.ascontiguousarray(np.asarray(goals, np.float64)).tobytes())
    return h.hexdigest()


def _common_pose(robot: Robot, names, goals, root_body: int) -> np.ndarray:
    """``[nq]`` the robot brought by IK, on positions, to ``goals`` (its targets ``names``), its root kept
    at the zero pose and its joints pulled towards ``qpos0`` (the redundant ones, such as a wrist's
    twist, stay there); the zero pose itself when there is no goal. The same inputs give the same
    result again without an IK (:data:`_COMMON_POSES`)."""
    if not names:
        return np.asarray(robot.qpos0, np.float64)
    key = _pose_key(robot, names, goals, root_body)
    if key in _COMMON_POSES:
        _COMMON_POSES.move_to_end(key)
        return _COMMON_POSES[key].copy()
    q = _solve_common_pose(robot, names, goals, root_body)
    _COMMON_POSES[key] = q.copy()
    while len(_COMMON_POSES) > _COMMON_POSES_KEPT:
        _COMMON_POSES.popitem(last=False)
    return q


def _solve_common_pose(robot: Robot, names, goals, root_body: int) -> np.ndarray:
    free = free_joint_of(robot, root_body)
    dtype = robot.qpos0.dtype
    weights, frozen = np.ones(robot.nv), ()
    if free is not None and robot.jnt_names[free]:  # the root stays where it is
        frozen = (robot.jnt_names[free],)
    elif free is not None:  # a free joint without a name: its dofs held by the regularizer
        weights[robot.jnt_dofadr[free]:robot.jnt_dofadr[free] + 6] = _HELD
    targets = tuple(Target(n, position=jnp.asarray(g, dtype)) for n, g in zip(names, goals))
    sol = solve_ik_robot(robot, targets, robot.qpos0, frozen=frozen, regularization=_CALIBRATION_DAMPING,
                         joint_weights=jnp.asarray(weights, dtype))
    q = np.asarray(sol.qpos, np.float64)
    if not np.all(np.isfinite(q)):
        raise JaxanimError(f"calibrate: the IK into the common pose gave non-finite values ({sol.result})")
    return q


def _common_goals(skeleton: Skeleton, robot: Robot, pairs, p_c, p_rob, scale, root) -> tuple[np.ndarray, np.ndarray]:
    """``(goals [P, 3], away [P])``: where the calibration IK puts each pair's target, the source's pose in the
    robot's proportions, and whether it is away from there in the zero pose (the IK moves only those; the
    others keep their zero pose, so a leg already straight is not twisted about its length to shave
    millimetres off a knee whose offsets differ from the source's).

    ``pairs`` are ``(source joint, target row)`` and ``root`` the root's. A joint hangs from its source
    parent, placed on the robot at the pair whose source that parent is, else at the robot ancestor nearest
    to it (mapped by the scale, root on root): a shoulder, a hip, placed the same way in turn. Its goal is
    its anchor's goal plus the robot's anchor-to-target length along the source's parent-to-joint
    direction, so the limbs point as the source's do at the robot's lengths, whatever the proportions (a
    torso frame at the waist and a chest joint at the chest do not pull the pose apart). It is away when
    its anchor is, or when the robot can turn that segment (a joint lies between) and it points more than
    :data:`_SAME_DIRECTION` (:data:`_SAME_ANCHOR` for an anchor that is no pair) from the source's."""
    nb = robot.num_bodies
    body_of = [r if r < nb else robot.site_bodies[r - nb] for r in range(nb + robot.num_sites)]
    mapped = p_rob[root[1]] + scale * (p_c - p_c[root[0]])  # every source joint, root on the robot's root
    row_of = {j: r for j, r in pairs}
    row_of[root[0]] = root[1]
    pair_rows = {r for _, r in pairs}
    jointed = set(robot.jnt_bodies)
    jnt_pos = np.asarray(robot.jnt_pos, np.float64)
    placed: dict[tuple[int, int], tuple[np.ndarray, bool]] = {}

    def place(j: int, r: int) -> tuple[np.ndarray, bool]:
        if (j, r) in placed:
            return placed[(j, r)]
        parent = skeleton.parents[j]
        chain = _tree.ancestors(robot.body_parents, body_of[r])[1:]  # the world excluded
        if r < nb:
            chain = chain[:-1]  # a body hangs from above it; a site may hang from its own body
        if parent < 0 or r == root[1] or not chain:
            placed[(j, r)] = (p_rob[r], False)
            return placed[(j, r)]
        anchor = row_of.get(parent)
        if anchor is None or anchor == r:
            anchor = min(chain, key=lambda b: float(np.sum((p_rob[b] - mapped[parent]) ** 2)))
        at, moved = place(parent, anchor)
        d, v = p_c[j] - p_c[parent], p_rob[r] - p_rob[anchor]
        n, length = float(np.linalg.norm(d)), float(np.linalg.norm(v))
        between = _tree.ancestors(robot.body_parents, body_of[r])
        between = between[between.index(body_of[anchor]) + 1:] if body_of[anchor] in between else between
        # the segment turns when a joint lies between, or one on the target's body that moves the target: a
        # site, a slide, or an origin off the joint's axis (a hinge at its body's origin leaves it in place)
        own = [jnt for jnt, b in enumerate(robot.jnt_bodies) if b == body_of[r]]
        turns = any(b in jointed for b in between[:-1]) or any(
            r >= nb or robot.jnt_types[jnt] == "slide" or bool(np.any(jnt_pos[jnt] != 0)) for jnt in own)
        cos = float(d @ v) / (n * length) if n > 0 and length > 0 else 1.0
        limit = _SAME_DIRECTION if r in pair_rows else _SAME_ANCHOR  # a hip's offset is the body's shape, not its pose
        away = moved or (turns and cos < np.cos(limit))
        placed[(j, r)] = (at + length * d / n if away and n > 0 else p_rob[r], away)
        return placed[(j, r)]

    out = [place(j, r) for j, r in pairs]
    if not out:
        return np.zeros((0, 3)), np.zeros(0, bool)
    return np.stack([g for g, _ in out]), np.asarray([a for _, a in out])


def _source_pose(skeleton: Skeleton, mapping: RetargetMap, motion, rest):
    """The source's calibration pose: ``(positions [J, 3], rotations [J, 3, 3])`` of its rest pose, or of the
    clip's frame ``calibration_frame`` expressed in its root's frame (as the rest pose is)."""
    k = mapping.calibration_frame
    if k is None:
        return np.asarray(rest.positions, np.float64), np.asarray(rest.rotations, np.float64)
    if motion is None:
        raise JaxanimError(f"mapping: calibration_frame: {k} names a frame of the clip; calibrate(..., motion=clip)")
    if k >= motion.num_frames:
        raise JaxanimError(f"mapping: calibration_frame: {k} is past the clip's last frame ({motion.num_frames - 1})")
    fk = _rest_fk(skeleton, motion.rotations[k], motion.translations[k])
    p, R = np.asarray(fk.positions, np.float64), np.asarray(fk.rotations, np.float64)
    root = skeleton.names.index(mapping.root_source)
    return (p - p[root]) @ R[root], np.swapaxes(R[root], -1, -2) @ R


def calibrate(mapping: RetargetMap, skeleton: Skeleton, robot: Robot, *, motion=None) -> Calibration:
    """The axes, scale and rotation offsets of ``mapping`` for ``skeleton`` and ``robot``.

    The axes and the scale come from the skeleton's rest pose (identity rotations, OFFSETs) and the
    robot's zero pose (``qpos0``). The offsets come from a common pose: the robot is brought by IK, on
    the pairs' positions (scaled, its root kept where it is), into the source's rest pose, or into the
    clip's frame ``calibration_frame`` of the map, and each pair's offset is its rotation there
    relative to the source joint's; a foot's is its levelled zero pose's (it stands flat).

    Given offsets and a given scale are kept; the others are computed (see the module docstring).

    Args:
        mapping, skeleton, robot: the map (:func:`load_mapping`), the source skeleton and the robot.
        motion: the clip, for a map with ``calibration_frame``.

    Raises:
        JaxanimError: an unknown source joint or robot body / site (the valid names listed), a
            foot pair that is not below the root in either pose, or a ``calibration_frame`` without
            ``motion`` or past its end.
    """
    if not isinstance(mapping, RetargetMap):
        raise JaxanimError(f"mapping: expected a RetargetMap (retargeting.load_mapping), got {type(mapping).__name__}")
    src = [_source_index(skeleton, f"pairs[{i}].source", n) for i, n in enumerate(mapping.sources)]
    src_root = _source_index(skeleton, "root.source", mapping.root_source)
    tgt = [_target_row(robot, f"pairs[{i}].target", n) for i, n in enumerate(mapping.targets)]
    tgt_root = _target_row(robot, "root.target", mapping.root_target)
    robot = upright(robot, mapping)  # a robot that lies in its zero pose, stood up by its free joint
    rest = _rest_fk(skeleton, skeleton.rest_rotations(), skeleton.offsets)
    zero = forward_kinematics(robot, robot.qpos0)
    p_rob = np.concatenate([np.asarray(zero.xpos, np.float64), np.asarray(zero.site_xpos, np.float64)])
    axes = _heading(np.asarray(rest.positions, np.float64) @ _UP_AXES[mapping.source_up].T, src_root, src,
                    p_rob, tgt_root, tgt) @ _UP_AXES[mapping.source_up]
    p_src = np.asarray(rest.positions, np.float64) @ axes.T  # in the robot's axes
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
    # the common pose: the source's (rest pose or frame), the robot brought into it by IK on positions
    p_c, R_c = _source_pose(skeleton, mapping, motion, rest)
    p_c, R_c = p_c @ axes.T, axes @ R_c
    moving = [i for i in range(mapping.num_pairs) if tgt[i] != tgt_root]
    root_body = target_rows(robot, (mapping.root_target,))[0][0]
    goals, away = _common_goals(skeleton, robot, [(src[i], tgt[i]) for i in moving], p_c, p_rob, scale,
                                (src_root, tgt_root))
    q = _common_pose(robot, [mapping.targets[i] for i, a in zip(moving, away) if a], goals[away], root_body)
    posed = forward_kinematics(robot, jnp.asarray(q, robot.qpos0.dtype))
    R_pair = np.concatenate([np.asarray(posed.xmat, np.float64), np.asarray(posed.site_xmat, np.float64)])[tgt]
    R_pair[feet] = _standing_feet(robot, target_rows(robot, [mapping.targets[i] for i in feet])[0], [tgt[i] for i in feet])[1]
    M = np.swapaxes(R_c[src], -1, -2) @ R_pair  # each pair's offset, computed in one call
    computed = np.asarray(_canonical_quat(jnp.asarray(M)), np.float64)
    offsets = [given[i] if mapping.given_offsets[i] else computed[i] for i in range(mapping.num_pairs)]
    dtype = robot.qpos0.dtype
    return Calibration(axes=jnp.asarray(axes, dtype), scale=jnp.asarray(scale, dtype),
                       offset=jnp.asarray(np.stack(offsets), dtype), qpos=jnp.asarray(q, dtype))
