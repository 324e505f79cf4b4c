"""What a retargeted clip is judged by, per frame: matching error, planted feet (slide, height,
penetration), joint ranges and speeds, jitter. The same measures serve any robot clip of a prepared
problem (the benchmark applies them to the per-frame peer's)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import rotations as rot
from .._types import Array, Bool, Float
from ..robots._kinematics import world_frames, mm, surface_points, target_frames
from ._problem import RetargetProblem, prepared_robot
from ..robots._robot import Robot
from ..robots._tangent import tangent_difference, TangentLayout

__all__ = ["RetargetDiagnostics", "diagnostics", "summary"]

#: A coordinate within this of a bound counts as a limit hit (rad or m).
LIMIT_HIT = 1e-6


class RetargetDiagnostics(eqx.Module):
    """Per-frame measures of a robot clip against its problem (``T`` frames, ``K`` targets with the
    root first, ``F`` feet). Speeds are forward differences (0 at the last frame), accelerations central
    ones (0 at the ends).

    Attributes:
        position_error: ``[T, K]`` distance of each target's body / site to its matching target, m.
        orientation_error: ``[T, K]`` angle to its orientation target, rad.
        contacts: ``[T, F]`` the source's stance frames.
        foot_slide: ``[T, F]`` horizontal speed of each foot while the source's foot stays down (this
            frame and the next), m/s; 0 elsewhere.
        foot_height: ``[T, F]`` height of each foot's lowest surface point above the ground, m.
        penetration: ``[T, F]`` depth of that point below the ground, m (0 above).
        range_violation: ``[T]`` the largest distance of a limited coordinate outside its range (of a
            limited ball: its angle beyond its cone).
        limit_hits: ``[T]`` how many limited coordinates sit on a bound.
        joint_speed: ``[T]`` the largest hinge / slide speed, rad/s or m/s.
        jitter: ``[T]`` the mean |acceleration| of the hinges and slides, rad/s^2.
        mask: ``[T]`` the clip's frames (``False``: padding).
    """

    position_error: Float[Array, "T K"]
    orientation_error: Float[Array, "T K"]
    contacts: Bool[Array, "T F"]
    foot_slide: Float[Array, "T F"]
    foot_height: Float[Array, "T F"]
    penetration: Float[Array, "T F"]
    range_violation: Float[Array, " T"]
    limit_hits: Array
    joint_speed: Float[Array, " T"]
    jitter: Float[Array, " T"]
    mask: Bool[Array, " T"]


def _frame_measures(robot: Robot, prob: RetargetProblem, q, p_target, R_target):
    dtype = q.dtype
    R_world, p_world, *_ = world_frames(robot, q, dtype)
    points, R = target_frames(robot, R_world, p_world, prob.bodies, prob.rows, dtype)
    pos_err = jnp.linalg.norm(points - p_target, axis=-1)
    ori_err = jnp.linalg.norm(rot.matrix_to_rotvec(mm(R, jnp.swapaxes(R_target, -1, -2))), axis=-1)
    lowest = jnp.stack([jnp.min(surface_points(robot, R_world, p_world, idx, dtype)[1]) for idx in prob.foot_points])
    return pos_err, ori_err, points[np.asarray(prob.feet)], lowest


@eqx.filter_jit
def diagnostics(robot: Robot, problem: RetargetProblem, qpos: Float[Array, "T nq"]) -> RetargetDiagnostics:
    """The per-frame measures of the robot clip ``qpos`` for ``problem`` (one clip; ``vmap`` for more);
    ``robot`` as given to :func:`~jaxanim.retargeting.prepare_retarget` (or its :func:`prepared_robot`)."""
    robot = prepared_robot(robot, problem)
    dtype = qpos.dtype
    prob = problem
    fps = 1.0 / prob.frame_time.astype(dtype)
    mask = prob.mask
    p_t = prob.target_positions().astype(dtype)
    R_t = rot.quat_to_matrix(prob.orientations.astype(dtype))
    pos_err, ori_err, feet, lowest = jax.vmap(lambda q, p, R: _frame_measures(robot, prob, q, p, R))(qpos, p_t, R_t)
    contacts = prob.contacts & mask[:, None]
    down = contacts[:-1] & contacts[1:]
    speed = jnp.linalg.norm(feet[1:, :, :2] - feet[:-1, :, :2], axis=-1) * fps
    slide = jnp.concatenate([jnp.where(down, speed, 0.0), jnp.zeros((1, len(prob.feet)), dtype)])
    lay = TangentLayout(robot)
    lim = lay.scalar_joints[lay.bounded] if lay.scalar_dofs.size else np.zeros(0, int)
    if lim.size:
        x = qpos[:, lay.scalar_q[lay.bounded]]
        rng = robot.jnt_range.astype(dtype)[lim]
        lo, hi = rng[None, :, 0], rng[None, :, 1]
        violation = jnp.max(jnp.maximum(jnp.maximum(lo - x, x - hi), 0.0), axis=1)
        hits = jnp.sum((x <= lo + LIMIT_HIT) | (x >= hi - LIMIT_HIT), axis=1)
    else:
        violation, hits = jnp.zeros(prob.num_frames, dtype), jnp.zeros(prob.num_frames, jnp.int32)
    if lay.cone_blocks.size:  # limited balls: MuJoCo's angle from the identity against jnt_range[:, 1]
        qi = lay.rot_q[lay.cone_blocks][:, None] + np.arange(4)
        angle = jnp.linalg.norm(rot.quat_to_rotvec(qpos[:, qi]), axis=-1)
        over = jnp.max(jnp.maximum(angle - robot.jnt_range.astype(dtype)[lay.cone_joints, 1][None], 0.0), axis=1)
        violation = jnp.maximum(violation, over)
    valid_pair = (mask[:-1] & mask[1:])[:, None]
    v = jnp.where(valid_pair, tangent_difference(lay, qpos[:-1], qpos[1:]) * fps, 0.0)[:, lay.joint_dofs]
    joint_speed = jnp.concatenate([jnp.max(jnp.abs(v), axis=1, initial=0.0), jnp.zeros(1, dtype)])
    acc = jnp.where(valid_pair[1:] & valid_pair[:-1], (v[1:] - v[:-1]) * fps, 0.0)
    jitter = jnp.concatenate([jnp.zeros(1, dtype), jnp.mean(jnp.abs(acc), axis=1) if lay.joint_dofs.size
                              else jnp.zeros(acc.shape[0], dtype), jnp.zeros(1, dtype)])
    maskf = mask.astype(dtype)
    return RetargetDiagnostics(
        position_error=pos_err * maskf[:, None], orientation_error=ori_err * maskf[:, None], contacts=contacts,
        foot_slide=slide, foot_height=lowest, penetration=jnp.maximum(-lowest, 0.0) * maskf[:, None],
        range_violation=violation * maskf, limit_hits=hits * mask, joint_speed=joint_speed, jitter=jitter, mask=mask)


def summary(diag: RetargetDiagnostics, position_weight=None) -> dict[str, float]:
    """One clip's diagnostics in a few numbers (host floats), over its frames:

    ``foot_slide`` (m/s) the median horizontal foot speed over the stance frames; ``penetration`` (m)
    the deepest foot point below the ground; ``lowest_foot`` (m) the lowest foot point; ``range_violation``
    the largest; ``limit_hits`` frames x coordinates on a bound; ``matching_error`` (m) the mean
    distance to the position targets (those with ``position_weight > 0`` when given, the root and the
    feet included); ``orientation_error`` (rad) the mean over all targets; ``jitter`` (rad/s^2) the mean
    |joint acceleration|; ``joint_speed`` (rad/s) the largest.
    """
    m = np.asarray(diag.mask, bool)
    pe = np.asarray(diag.position_error)[m]
    if position_weight is not None:
        pe = pe[:, np.asarray(position_weight) > 0]
    down = np.asarray(diag.contacts)[m][:-1] & np.asarray(diag.contacts)[m][1:]
    slides = np.asarray(diag.foot_slide)[m][:-1][down]
    inner = m.copy()
    idx = np.flatnonzero(m)
    inner[idx[:1]] = inner[idx[-1:]] = False
    return {
        "foot_slide": float(np.median(slides)) if slides.size else 0.0,
        "penetration": float(np.max(np.asarray(diag.penetration)[m], initial=0.0)),
        "lowest_foot": float(np.min(np.asarray(diag.foot_height)[m])),
        "range_violation": float(np.max(np.asarray(diag.range_violation)[m], initial=0.0)),
        "limit_hits": int(np.sum(np.asarray(diag.limit_hits)[m])),
        "matching_error": float(np.mean(pe)),
        "orientation_error": float(np.mean(np.asarray(diag.orientation_error)[m])),
        "jitter": float(np.mean(np.asarray(diag.jitter)[inner])) if inner.any() else 0.0,
        "joint_speed": float(np.max(np.asarray(diag.joint_speed)[m], initial=0.0)),
    }
