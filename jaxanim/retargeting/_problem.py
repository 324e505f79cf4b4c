"""One clip's retargeting problem, prepared on the host: what :func:`solve_retarget` needs as arrays.

:func:`prepare_retarget` runs the source's forward kinematics, turns every mapped joint into a target
in the robot's frame (the map's axes; positions relative to the source's ground, not yet scaled, so
that the scale stays a differentiable array), detects the source's stance phases
(:func:`jaxanim.kinematics.detect_foot_contacts`) and computes one anchor per stance phase and foot:
the mean of the foot's path over the phase (horizontal) and the mean heading of its target
orientation, with the foot flat (its zero-pose tilt). Clips are padded to a common length with a
mask (:func:`stack_problems`), so a batch of clips is one ``vmap``.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import JaxanimError
from .._linalg import einsum
from .._types import Array, Bool, Float
from ..kinematics._contacts import contacts_from_positions, resolve_feet, true_runs
from ..kinematics._host import clip_frames_host
from ..rotations._numpy import matrix_to_quat, quat_to_matrix
from ..skeleton._skeleton import Motion, Skeleton
from ..robots._kinematics import target_rows
from ._mapping import Calibration, RetargetMap, _standing_feet, calibrate, load_mapping, upright, with_soles
from ..robots._robot import Robot, with_floating_base, with_surface_points
from ..robots._tangent import free_joint_of

__all__ = ["RetargetProblem", "prepare_retarget", "prepared_robot", "stack_problems"]


class RetargetProblem(eqx.Module):
    """One clip's retargeting problem (:func:`prepare_retarget`). Names and indices static, numbers
    arrays; ``K`` targets (the root first, then the map's pairs), ``F`` feet, ``T`` frames (padded).

    Attributes:
        names: ``[K]`` the robot bodies / sites matched (static).
        bodies, rows: ``[K]`` each target's body and its row in ``[xpos; site_xpos]`` (static).
        feet: ``[F]`` the target index of each foot pair (static).
        foot_points: ``[F]`` the robot's surface points of each foot: its body's and its descendants'
            (indices into ``Robot.point_pos``; static).
        oriented: the targets with orientation terms (static): the feet and those whose orientation weight
            was not 0 when the problem was prepared. A weight that was 0 then stays off: the solve has no rows
            for it (:func:`solve_retarget` refuses a problem whose weight was set later).
        positions: ``[T, K, 3]`` the source joints in the robot's axes, above the source's ground, in
            source units (the target is ``scale * positions + lift * z``).
        orientations: ``[T, K, 4]`` wxyz world orientation targets (``axes R_source offset``).
        position_weight, orientation_weight: ``[K]`` the matching weights (the root's are 1).
        scale: the human-to-robot scale.
        contacts: ``[T, F]`` the source's stance frames of each foot.
        anchors: ``[T, F, 2]`` the unscaled horizontal anchor of the stance phase a frame is in.
        anchor_orientations: ``[T, F, 4]`` the planted foot's wxyz orientation in that phase.
        stance_height: ``[F]`` the source foot's median height in its stance frames (source units).
        foot_height: ``[F]`` the robot foot target's height above its lowest surface point, standing
            flat (its zero pose), m.
        mask: ``[T]`` the clip's frames (``False``: padding).
        frame_time: seconds per frame.
        axes: ``[3, 3]`` the source's world axes in the robot's (:class:`Calibration`).
        ground: the source's ground height along the robot's up axis (its lowest foot joint over the
            clip, source units).
        floating: whether the preparation gave the robot a free joint (static; :func:`prepared_robot`).
        added_points: the sole points the preparation gave feet without collision geometry, ``((body,
            (x, y, z)), ...)`` in the bodies' frames (static; :func:`prepared_robot`).
        robot_points: the number of surface points of the robot as prepared (static).
    """

    names: tuple[str, ...] = eqx.field(static=True)
    bodies: tuple[int, ...] = eqx.field(static=True)
    rows: tuple[int, ...] = eqx.field(static=True)
    feet: tuple[int, ...] = eqx.field(static=True)
    foot_points: tuple[tuple[int, ...], ...] = eqx.field(static=True)
    oriented: tuple[int, ...] = eqx.field(static=True)
    positions: Float[Array, "T K 3"]
    orientations: Float[Array, "T K 4"]
    position_weight: Float[Array, " K"]
    orientation_weight: Float[Array, " K"]
    scale: Float[Array, ""]
    contacts: Bool[Array, "T F"]
    anchors: Float[Array, "T F 2"]
    anchor_orientations: Float[Array, "T F 4"]
    stance_height: Float[Array, " F"]
    foot_height: Float[Array, " F"]
    mask: Bool[Array, " T"]
    frame_time: Float[Array, ""]
    axes: Float[Array, "3 3"]
    ground: Float[Array, ""]
    floating: bool = eqx.field(static=True, default=False)
    added_points: tuple[tuple[int, tuple[float, float, float]], ...] = eqx.field(static=True, default=())
    robot_points: int = eqx.field(static=True, default=-1)

    @property
    def num_frames(self) -> int:
        return self.positions.shape[-3]

    @property
    def lift(self) -> Array:
        """The height added to the scaled source: its stance feet land at the robot's foot heights."""
        return jnp.mean(self.foot_height) - self.scale * jnp.mean(self.stance_height)

    def target_positions(self) -> Float[Array, "T K 3"]:
        """The position targets in the robot's frame, m: ``scale * positions + lift * z``."""
        return (self.scale * self.positions).at[..., 2].add(self.lift)

    def in_robot_frame(self, positions: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
        """Source world positions (any joints, source units) in the robot's frame, m, as the targets
        are placed: turned by ``axes``, above ``ground``, scaled and lifted."""
        p = einsum("xy,...y->...x", self.axes.astype(positions.dtype), positions).at[..., 2].add(-self.ground)
        return (self.scale * p).at[..., 2].add(self.lift)

    def anchor_positions(self) -> Float[Array, "T F 3"]:
        """The planted feet's positions, m: the scaled anchor at the foot's standing height."""
        h = jnp.broadcast_to(self.foot_height, self.anchors.shape[:-1])[..., None]
        return jnp.concatenate([self.scale * self.anchors, h], axis=-1)


def _yaw(R: np.ndarray) -> np.ndarray:
    return np.arctan2(R[..., 1, 0], R[..., 0, 0])


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _device(x, dtype=None):
    """A host array on the device: ``jax.device_put`` (``jnp.asarray`` of a NumPy array compiled a small program
    for every new shape)."""
    return jax.device_put(np.asarray(x, dtype))


def _with_root(mapping: RetargetMap) -> RetargetMap:
    """The map with its root as pair 0 (weights 1; its offset computed)."""
    one = jnp.ones(1, mapping.position_weight.dtype)
    return RetargetMap(
        root_source=mapping.root_source, root_target=mapping.root_target,
        sources=(mapping.root_source,) + mapping.sources, targets=(mapping.root_target,) + mapping.targets,
        feet=(False,) + mapping.feet, source_up=mapping.source_up, auto_scale=mapping.auto_scale,
        given_offsets=(False,) + mapping.given_offsets, sole_size=(None,) + mapping.sole_size,
        calibration_frame=mapping.calibration_frame,
        position_weight=jnp.concatenate([one, mapping.position_weight]),
        orientation_weight=jnp.concatenate([one, mapping.orientation_weight]),
        offset=jnp.concatenate([jnp.asarray([[1.0, 0.0, 0.0, 0.0]], mapping.offset.dtype), mapping.offset]),
        scale=mapping.scale)


def _floating(robot: Robot, root_body: int, fixed_base: bool) -> tuple[Robot, bool]:
    """The robot with a free joint on its root body where the root target is not moved by one."""
    if free_joint_of(robot, root_body) is not None:
        return robot, False
    if fixed_base:
        raise JaxanimError(
            f"robot: the root target {robot.body_names[root_body]!r} is not moved by a free joint and fixed_base=True "
            "(--fixed-base) keeps the robot fixed, so it cannot follow the clip through the world; leave fixed_base "
            "off to add a free joint 'root_joint' on the root body, or load it with load_robot(path, "
            "floating_base=True)")
    if robot.body_parents[root_body] != 0 and root_body in robot.jnt_bodies:
        raise JaxanimError(f"robot: the root target {robot.body_names[root_body]!r} is moved by joints but by no free "
                           "joint; map the root to the robot's root body")
    return with_floating_base(robot), True


def prepared_robot(robot: Robot, problem: RetargetProblem) -> Robot:
    """The robot as ``problem`` was prepared on it, what :func:`solve_retarget` solves on and the result's
    ``qpos`` is laid out for: with the free joint ``"root_joint"`` on its root body where
    :func:`prepare_retarget` added one (first in ``qpos``), and the sole points it gave feet without
    collision geometry. A robot that has them already is returned as it is.

    Raises:
        JaxanimError: if ``robot`` is not the one the problem was prepared on (another count of surface points).
    """
    if problem.floating and free_joint_of(robot, problem.bodies[0]) is None:
        robot = with_floating_base(robot)
    n, k = len(robot.point_bodies), len(problem.added_points)
    if problem.robot_points >= 0 and n != problem.robot_points:
        if k and n == problem.robot_points - k:
            robot = with_surface_points(robot, [b for b, _ in problem.added_points], [x for _, x in problem.added_points])
        else:
            raise JaxanimError(f"robot: {n} surface points, but the problem was prepared on a robot with "
                               f"{problem.robot_points}; pass the robot it was prepared with")
    return robot


def prepare_retarget(
    skeleton: Skeleton,
    motion: Motion,
    robot: Robot,
    mapping,
    *,
    calibration: Calibration | None = None,
    contacts=None,
    length: int | None = None,
    fixed_base: bool = False,
) -> RetargetProblem:
    """The retargeting problem of one clip (host work: forward kinematics, contacts, anchors).

    Args:
        skeleton, motion: the source clip (any BVH dialect); not modified.
        robot: the robot, with a floating base (a free joint moving the root target).
        mapping: a :class:`RetargetMap`, or a JSON path / dict for :func:`load_mapping`.
        calibration: the axes, scale and offsets (default :func:`calibrate` of the map).
        contacts: ``[frames, feet]`` the source's stance frames, one column per foot pair in map order
            (default :func:`~jaxanim.kinematics.detect_foot_contacts` on the feet's source joints).
        length: pad to this many frames (default: the clip's), for batching clips of different
            lengths.
        fixed_base: refuse a robot whose root target is not moved by a free joint, instead of adding
            one (:func:`~jaxanim.robots.with_floating_base`, named ``"root_joint"``, first in ``qpos``).

    A foot whose robot body has no collision geometry stands on its target's frame
    (:func:`with_soles`). :func:`prepared_robot` gives the robot with the free joint and soles that
    the problem was prepared on.

    Raises:
        JaxanimError: bad names in the map (listing the valid ones), a fixed robot with ``fixed_base``,
            a clip with NaN or inf, ``contacts`` of the wrong shape, ``length`` shorter than the clip.
    """
    mapping = mapping if isinstance(mapping, RetargetMap) else load_mapping(mapping)
    if not isinstance(skeleton, Skeleton) or not isinstance(motion, Motion):
        raise JaxanimError("skeleton, motion: expected a Skeleton and a Motion (jaxanim.read_bvh)")
    motion.check_skeleton(skeleton, "motion")
    motion.check_finite("motion")
    T = motion.num_frames
    full = _with_root(mapping)
    bodies, rows = target_rows(robot, full.targets)
    robot, floating = _floating(robot, bodies[0], bool(fixed_base))
    robot = upright(robot, full)  # only the zero pose's root turns (the solve sets the root from the clip)
    robot, added = with_soles(robot, full)
    calib = calibrate(full, skeleton, robot, motion=motion) if calibration is None else calibration
    offsets = np.asarray(calib.offset, np.float64)
    if calibration is not None:  # a user's calibration has the pairs only: compute the root's
        if offsets.shape[0] != mapping.num_pairs:
            raise JaxanimError(f"calibration: expected offsets for the {mapping.num_pairs} pairs, got {offsets.shape[0]}")
        offsets = np.concatenate([np.asarray(calibrate(full, skeleton, robot, motion=motion).offset, np.float64)[:1],
                                  offsets])
    K = len(full.targets)
    length = T if length is None else int(length)
    if length < T:
        raise JaxanimError(f"length: {length} is shorter than the clip ({T} frames)")
    pad = length - T

    def padded(x, fill=None):
        x = np.asarray(x)
        if not pad:
            return x
        tail = np.repeat(x[-1:], pad, axis=0) if fill is None else np.full((pad,) + x.shape[1:], fill, x.dtype)
        return np.concatenate([x, tail])

    axes = np.asarray(calib.axes, np.float64)
    src = [skeleton.names.index(n) for n in full.sources]
    # the source's kinematics on the host (a compiled program would cost seconds per clip length)
    R_fk, P_fk = clip_frames_host(skeleton, motion.rotations, motion.translations)
    P = P_fk[:, src] @ axes.T  # [T, K, 3] in the robot's axes
    R = axes @ R_fk[:, src]  # [T, K, 3, 3]
    R_target = R @ quat_to_matrix(offsets / np.linalg.norm(offsets, axis=-1, keepdims=True))
    feet_k = [k for k in range(K) if full.feet[k]]
    foot_names = tuple(full.sources[k] for k in feet_k)
    up = 1 if mapping.source_up == "y" else 2
    if contacts is None:  # detect_foot_contacts's, from the positions above
        motion.check_frame_time("motion")
        _, idx = resolve_feet(skeleton, foot_names, up)
        contacts = contacts_from_positions(skeleton, idx, P_fk[:, idx], float(motion.frame_time),
                                           up, None, None, None)
    contacts = np.asarray(contacts)
    if contacts.shape != (T, len(feet_k)):
        raise JaxanimError(f"contacts: expected shape (frames, feet) = ({T}, {len(feet_k)}), got {contacts.shape}")
    contacts = contacts.astype(bool)
    ground = P[:, feet_k, 2].min()
    P[..., 2] -= ground
    # the robot's feet standing flat: their orientation and the height of each foot target above its sole
    dtype = robot.qpos0.dtype
    foot_points, R_flat, foot_height = _standing_feet(robot, [bodies[k] for k in feet_k], [rows[k] for k in feet_k])
    anchors = np.zeros((T, len(feet_k), 2))
    anchor_R = np.broadcast_to(np.eye(3), (T, len(feet_k), 3, 3)).copy()
    stance_height = np.zeros(len(feet_k))
    for f, k in enumerate(feet_k):
        R0 = R_flat[f]
        runs = true_runs(contacts[:, f])
        for a, b in runs:
            anchors[a:b, f] = P[a:b, k, :2].mean(axis=0)
            heading = _yaw(R_target[a:b, k] @ R0.T)
            anchor_R[a:b, f] = _rot_z(np.arctan2(np.sin(heading).mean(), np.cos(heading).mean())) @ R0
        stance = contacts[:, f]
        stance_height[f] = np.median(P[stance, k, 2]) if stance.any() else P[:, k, 2].min()
    return RetargetProblem(
        names=full.targets, bodies=bodies, rows=rows, feet=tuple(feet_k), foot_points=tuple(foot_points),
        oriented=tuple(k for k in range(K) if full.feet[k] or float(full.orientation_weight[k]) != 0.0),
        positions=_device(padded(P), dtype), orientations=_device(matrix_to_quat(padded(R_target)), dtype),
        position_weight=_device(full.position_weight, dtype),
        orientation_weight=_device(full.orientation_weight, dtype),
        scale=_device(calib.scale, dtype), contacts=_device(padded(contacts, False)),
        anchors=_device(padded(anchors), dtype), anchor_orientations=_device(matrix_to_quat(padded(anchor_R)), dtype),
        stance_height=_device(stance_height, dtype), foot_height=_device(foot_height, dtype),
        mask=_device(np.arange(length) < T), frame_time=_device(float(motion.frame_time), dtype),
        axes=_device(axes, dtype), ground=_device(ground, dtype), floating=floating, added_points=added,
        robot_points=len(robot.point_bodies))


def stack_problems(problems: Sequence[RetargetProblem]) -> RetargetProblem:
    """Stack problems of one robot and map, padded to one length (``prepare_retarget(..., length=)``),
    along a new leading axis: the input of ``jax.vmap(solve_retarget, ...)``."""
    problems = list(problems)
    if not problems:
        raise JaxanimError("problems: expected at least one RetargetProblem")
    first = problems[0]
    for i, p in enumerate(problems):
        if not isinstance(p, RetargetProblem):
            raise JaxanimError(f"problems[{i}]: expected a RetargetProblem, got {type(p).__name__}")
        if ((p.names, p.feet, p.foot_points, p.oriented, p.floating, p.added_points)
                != (first.names, first.feet, first.foot_points, first.oriented, first.floating, first.added_points)):
            raise JaxanimError(f"problems[{i}]: prepared with another robot or map than problems[0]")
        if p.num_frames != first.num_frames:
            raise JaxanimError(f"problems[{i}]: {p.num_frames} frames, problems[0] has {first.num_frames}; pad them to "
                               "one length with prepare_retarget(..., length=)")
    return jax.tree.map(lambda *x: jnp.stack(x), *problems)
