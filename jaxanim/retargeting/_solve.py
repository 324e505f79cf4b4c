r"""The retargeting solve: one least-squares problem over the whole clip, O(T) per iteration.

Variables: the robot's ``qpos`` at every frame, stepped in its tangent space (``nv`` numbers per frame:
hinges and slides additive, a free joint's translation additive in the world, rotations
``quat ⊗ exp(delta)`` with ``delta`` local, as in :func:`~jaxanim.ik.solve_ik_robot`).

Cost (``s`` the scale, ``v_t = (q_{t+1} ⊖ q_t) / dt``, ``a_t = (v_t - v_{t-1}) / dt``)::

    sum_t [ sum_k wp_k |p_k - p*_k|^2 + wo_k |log(R_k R*_k^T)|^2          matching (feet in stance: off)
          + w_plant (|p_f - anchor_f|^2 + |log(R_f A_f^T)|^2)            planted feet, stance frames
          + w_ground sum_points ground(z)^2                               no penetration (_ground)
          + w_posture |q_joints - q0_joints|^2 ]                          posture prior
    + sum_t [ w_v |v_t|^2 + w_a |a_t|^2 + w_vmax |v_t - clip(v_t, -vmax, vmax)|_joints^2 ] dt ...

(all halved; the velocity and acceleration terms are those of each dof, the last one only over the
hinges and slides). The joint ranges are hard bounds: every iterate is projected into them, and a
coordinate at a bound whose gradient points out of the range is held there for the step (projected
Gauss-Newton, Bertsekas 1982).

Each iteration linearizes every frame's residual (one batched kinematics and Jacobian pass) and
solves the Levenberg-Marquardt normal equations. Their matrix is Gauss-Newton's ``J'J`` plus the positive part
of the diagonal of the second-order term ``sum r d2r/dq_d^2`` over the position rows (a rotation dof swings a
point on a circle, ``d2p/dq^2 = axis x (axis x (p - anchor))``): where a point's target lies farther from the
axis than the point, ``J'J`` alone underestimates the cost's curvature and the steps overshoot (a wrist whose
matched point sits millimetres from its axis took a run of rejected steps). The negative part is left out, so
the matrix stays positive definite; the stationary points and the stopping rule are those of the cost. On
32 walk clips onto the G1: 13 -> 9 iterations per clip (script), the same cost to within the tolerance.
The foot points that the last step took below the ground from above its soft band join the step's model
with their depth (:func:`_step`). The equations' matrix
couples a frame with its two neighbours on each side (velocity: one, acceleration: two) through diagonal blocks;
:func:`solvers.block_pentadiagonal_solve` solves it in O(T) (frames paired into blocks of ``2 nv``, each
pair's inverse from its ``nv x nv`` blocks). In the smoothness terms the difference of
two root rotations is linearized as ``delta_{t+1} - delta_t`` (exact to first order in the per-frame rotation, which is
small at motion-capture frame rates).

The iterations run until converged, at most ``RetargetOptions.iterations``, in equinox's checkpointed
``while_loop``: it stops early and still has a reverse-mode derivative, so the result is differentiable
with respect to the weights and the scale (through the iterations taken).
"""

from __future__ import annotations

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import numpy as np

import solvers

from .. import rotations as rot
from .._errors import JaxanimError
from .._linalg import einsum, jit
from .._types import Array, Float
from ..robots._kinematics import dof_columns, world_frames, mm, surface_points, target_frames
from ._diagnostics import RetargetDiagnostics, diagnostics
from ..robots._tangent import tangent_difference, free_joint_of, TangentLayout, retract
from ._problem import RetargetProblem, prepared_robot
from ..robots._robot import Robot

__all__ = ["RetargetOptions", "RetargetResult", "solve_retarget"]


class RetargetOptions(eqx.Module):
    """Weights and settings of :func:`solve_retarget` (numbers are arrays: differentiable, and new
    values do not recompile; ``iterations`` is static).

    Attributes:
        iterations: the most Levenberg-Marquardt iterations over the whole clip (the solve stops
            earlier once converged; under ``vmap``, once every clip has).
        velocity_weight: ``w_v`` on every dof's velocity (in (rad/s)^-2 against the matching's m^-2:
            the default 1e-6 weighs a velocity of 1 rad/s like a matching error of 1 mm).
        acceleration_weight: ``w_a`` on every dof's acceleration.
        plant_weight: ``w_plant`` on the planted feet's position (and orientation, in rad).
        ground_weight: ``w_ground`` on each foot surface point below the ground.
        posture_weight: ``w_posture`` pulling the joints towards the zero pose (unmatched joints).
        max_joint_velocity: ``vmax`` of the hinges and slides (rad/s or m/s); ``inf``: none.
        velocity_limit_weight: ``w_vmax`` on the joint speed above ``vmax``.
        rtol: convergence: an accepted iteration changed the cost by at most ``rtol`` of it and its linear
            model predicted no more, or it moved no coordinate by more than ``xtol``.
        xtol: see ``rtol`` (rad or m).
    """

    iterations: int = eqx.field(static=True, default=200)
    velocity_weight: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=1e-6)
    acceleration_weight: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=1e-6)
    plant_weight: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=3e3)
    ground_weight: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=3e3)
    posture_weight: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=1e-4)
    max_joint_velocity: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=20.0)
    velocity_limit_weight: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=1e-2)
    rtol: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=1e-4)
    xtol: Float[Array, ""] = eqx.field(converter=jnp.asarray, default=1e-7)


class RetargetResult(eqx.Module):
    """The robot's clip (:func:`solve_retarget`, :func:`~jaxanim.retargeting.retarget`).

    Attributes:
        qpos: ``[T, nq]`` the robot's configurations (MuJoCo's order; padding frames repeat the last).
        fps: frames per second (the source's).
        result: :class:`solvers.RESULTS`: ``successful`` (converged), ``max_steps_reached`` or
            ``nonfinite``; per clip under ``vmap``.
        success: converged and every value finite.
        cost: the final cost.
        num_steps: iterations run.
        diagnostics: :class:`~jaxanim.retargeting.RetargetDiagnostics`, per frame.
    """

    qpos: Float[Array, "T nq"]
    fps: Float[Array, ""]
    result: solvers.RESULTS
    success: Array
    cost: Float[Array, ""]
    num_steps: Array
    diagnostics: RetargetDiagnostics


# --- one frame's residual ------------------------------------------------------------------------------


#: The length (m) over which the ground term softens (:func:`_ground`): exactly 0 a millimetre above the
#: ground, the depth itself a millimetre below, smooth between.
_GROUND_SOFTNESS = 1e-3


def _ground(h, eps):
    """The ground residual of a point at height ``h`` and its derivative: ``h`` below ``-eps``, 0 above
    ``eps`` and ``-(eps - h)^2 / (4 eps)`` between (continuous with its slope): a point on the ground
    costs ``eps / 4`` of height, one above ``eps`` nothing."""
    mid = jnp.clip(h, -eps, eps)
    r = jnp.where(h <= -eps, h, jnp.where(h >= eps, 0.0, -((eps - mid) ** 2) / (4 * eps)))
    slope = jnp.where(h <= -eps, 1.0, jnp.where(h >= eps, 0.0, (eps - mid) / (2 * eps)))
    return r, slope


def _sqrt(w):
    """``sqrt(w)`` with a zero derivative at ``w = 0`` (a weight of 0 switches a term off; the plain
    square root's infinite derivative there would make every gradient NaN)."""
    positive = w > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, w, 1.0)), 0.0)


class _Frame(eqx.Module):
    """One frame's targets and weights (the per-frame slice of a problem; vmapped). A foot's matching and planting
    terms never hold at once (its matching is off while it is planted), so each foot has one set of rows whose
    target and weight are the plant's in stance and the matching's otherwise."""

    p: Array  # [K, 3] position targets (a planted foot's: its anchor)
    R: Array  # [O, 3, 3] orientation targets of the targets ``prob.oriented`` (a planted foot's: its anchor's)
    wp: Array  # [K]
    wo: Array  # [O]
    w_ground: Array  # [F]
    w_posture: Array  # []


def _frame_residual(robot: Robot, prob: RetargetProblem, lay: TangentLayout, q, fr: _Frame):
    """``(r [m], J [m, nv], posture, ground, curvature [nv])`` of one frame: the posture term's rows are the
    identity on the joints' dofs (``w_posture`` times ``posture``), added by :func:`_frame_normal` without forming
    them. ``ground`` is every foot point's weighted height and height row ``(sqrt(w) h [P], sqrt(w) dh/dq [P, nv])``
    and whether the point is above the ground's soft band (``[P]`` bool: its row in ``J`` is zero).
    ``curvature`` is the positive part of the diagonal of ``sum_rows r d2r/dq_d^2`` over the position rows
    (matching and planted feet, ground; the ground's slope held), which :func:`_frame_normal` adds to ``J'J``.
    Orientation rows are those of ``prob.oriented`` only: a target whose orientation weight was 0 when the problem
    was prepared has none (on the G1's walk map 6 of 10 targets, 18 of the 80 rows)."""
    dtype = q.dtype
    kin = world_frames(robot, q, dtype)
    bodies, oriented = prob.bodies, np.asarray(prob.oriented, np.int64)
    points, R = target_frames(robot, kin[0], kin[1], bodies, prob.rows, dtype)
    pts_idx = [i for f in prob.foot_points for i in f]
    surface, height = surface_points(robot, kin[0], kin[1], pts_idx, dtype)
    e_ori = rot.matrix_to_rotvec(mm(R[oriented], jnp.swapaxes(fr.R, -1, -2)))
    sp, so = _sqrt(fr.wp)[:, None], _sqrt(fr.wo)[:, None]
    owner = np.asarray([f for f, idx in enumerate(prob.foot_points) for _ in idx])
    sg = _sqrt(fr.w_ground)[owner]
    ground, slope = _ground(height, _GROUND_SOFTNESS)
    posture = q[lay.joint_q] - robot.qpos0.astype(dtype)[lay.joint_q]
    r = jnp.concatenate([(sp * (points - fr.p)).ravel(), (so * e_ori).ravel(), sg * ground])
    dofs = np.arange(robot.nv)
    jacp, jacr = dof_columns(robot, kin, points, bodies, dofs, dtype)  # [K, nv, 3]
    jsp, jsr = dof_columns(robot, kin, surface, [robot.point_bodies[i] for i in pts_idx], dofs, dtype)  # [P, nv, 3]
    # the second-order term's diagonal over the position rows: a rotation dof turns a point about its axis,
    # d2p/dq^2 = axis x (axis x (p - anchor)) = axis x column (zero for slides and for dofs that do not move it)
    curvature = (einsum("kc,kdc->d", sp**2 * (points - fr.p), jnp.cross(jacr, jacp))
                 + einsum("p,pd->d", sg**2 * ground * slope, jnp.cross(jsr, jsp)[:, :, 2]))
    jacp, jacr = jnp.swapaxes(jacp, 1, 2), jnp.swapaxes(jacr, 1, 2)  # [K, 3, nv]
    jz = jsp[:, :, 2]  # [P, nv]
    Li = rot.left_jacobian_inverse(e_ori)
    Jo = sum(Li[:, :, c, None] * jacr[oriented][:, c, None, :] for c in range(3))
    J = jnp.concatenate([(sp[:, :, None] * jacp).reshape(-1, robot.nv), (so[:, :, None] * Jo).reshape(-1, robot.nv),
                         (sg * slope)[:, None] * jz])
    return r, J, posture, (sg * height, sg[:, None] * jz, slope == 0), jnp.maximum(curvature, 0.0)


def _frames(prob: RetargetProblem, opts: RetargetOptions, dtype) -> _Frame:
    """The per-frame targets and weights ``[T, ...]``: a planted foot's rows hold it at its anchor, flat."""
    mask = prob.mask.astype(dtype)
    contacts = prob.contacts.astype(dtype) * mask[:, None]  # [T, F]
    feet, oriented = np.asarray(prob.feet, np.int64), np.asarray(prob.oriented, np.int64)
    planted = jnp.zeros((prob.num_frames, len(prob.names)), dtype).at[:, feet].set(contacts)  # [T, K]
    keep = mask[:, None] * (1.0 - planted)
    plant = planted * opts.plant_weight.astype(dtype)
    foot_of = {k: f for f, k in enumerate(prob.feet)}  # a foot target's column among the feet
    anchor_p = prob.anchor_positions().astype(dtype)[:, np.asarray([foot_of.get(k, 0) for k in range(len(prob.names))])]
    p = jnp.where(planted[..., None] > 0, anchor_p, prob.target_positions().astype(dtype))
    anchor_q = prob.anchor_orientations.astype(dtype)[:, np.asarray([foot_of.get(k, 0) for k in oriented], np.int64)]
    R = jnp.where(planted[:, oriented, None, None] > 0, rot.quat_to_matrix(anchor_q),
                  rot.quat_to_matrix(prob.orientations.astype(dtype)[:, oriented]))
    wo = keep * prob.orientation_weight.astype(dtype)[None, :] + plant
    return _Frame(
        p=p, R=R, wp=keep * prob.position_weight.astype(dtype)[None, :] + plant, wo=wo[:, oriented],
        w_ground=jnp.broadcast_to(mask[:, None], contacts.shape) * opts.ground_weight.astype(dtype),
        w_posture=mask * opts.posture_weight.astype(dtype))


def _frame_normal(robot: Robot, prob: RetargetProblem, lay: TangentLayout, q, fr: _Frame):
    """``(cost, J'J [nv, nv], J'r [nv], ground)`` of one frame's terms (``ground``: :func:`_frame_residual`'s;
    ``J'J`` with the posture term and the second-order diagonal ``curvature`` added)."""
    r, J, posture, ground, curvature = _frame_residual(robot, prob, lay, q, fr)
    d = lay.joint_dofs
    JtJ = einsum("mi,mj->ij", J, J) + jnp.diag(curvature.at[d].add(fr.w_posture))
    Jtr = einsum("mi,m->i", J, r).at[d].add(fr.w_posture * posture)
    return 0.5 * (jnp.sum(r**2) + fr.w_posture * jnp.sum(posture**2)), JtJ, Jtr, ground


# --- the smoothness terms and the banded system ------------------------------------------------------------


def _pair_terms(lay: TangentLayout, q, prob: RetargetProblem, opts: RetargetOptions):
    """Velocity and velocity-limit terms (each pair ``t, t+1``: weight ``c [T-1, nv]``, offset ``o``:
    cost ``1/2 c (o + delta_{t+1} - delta_t)^2``) and acceleration terms (``a [T-2, nv]``, offset
    ``acc``, on ``delta_{t+2} - 2 delta_{t+1} + delta_t``), and their cost."""
    dtype = q.dtype
    fps = 1.0 / prob.frame_time.astype(dtype)
    valid = prob.mask.astype(dtype)
    dq = tangent_difference(lay, q[:-1], q[1:])  # [T-1, nv] per frame
    pair = (valid[:-1] * valid[1:])[:, None]
    c_v = pair * opts.velocity_weight.astype(dtype) * fps**2
    vmax = opts.max_joint_velocity.astype(dtype) / fps
    limited = np.zeros(lay.nv, bool)
    limited[lay.joint_dofs] = True
    excess = jnp.where(limited[None, :], dq - jnp.clip(dq, -vmax, vmax), 0.0)
    active = (excess != 0).astype(dtype)
    c_l = pair * active * opts.velocity_limit_weight.astype(dtype) * fps**2
    c = c_v + c_l
    o = (c_v * dq + c_l * excess) / jnp.where(c > 0, c, 1.0)
    ddq = dq[1:] - dq[:-1]
    a = (valid[:-2] * valid[1:-1] * valid[2:])[:, None] * opts.acceleration_weight.astype(dtype) * fps**4
    cost = 0.5 * (jnp.sum(c_v * dq**2) + jnp.sum(c_l * excess**2) + jnp.sum(a * ddq**2))
    return c, o, a, ddq, cost


def _gradient(Jtr, c, o, a, acc):
    """``[T, n]`` the gradient of the cost in the tangent coordinates."""
    g = Jtr.at[:-1].add(-c * o).at[1:].add(c * o)
    return g.at[:-2].add(a * acc).at[1:-1].add(-2 * a * acc).at[2:].add(a * acc)


def _normal_equations(JtJ, g, c, a, free, mu):
    """Diagonal blocks ``[T, n, n]``, the first and second off-diagonal (diagonal) bands and the
    gradient ``g [T, n]`` of the linearized cost, pinned coordinates (``free`` 0) removed."""
    T, n = g.shape
    d = jnp.zeros((T, n), g.dtype).at[:-1].add(c).at[1:].add(c)
    d = d.at[:-2].add(a).at[1:-1].add(4 * a).at[2:].add(a)
    e1 = (-c).at[:-1].add(-2 * a).at[1:].add(-2 * a) if T > 2 else -c  # H[t+1, t]
    e2 = a  # H[t+2, t]
    H = JtJ + jax.vmap(jnp.diag)(d)
    diag = jnp.diagonal(H, axis1=1, axis2=2)
    damp = mu * diag + mu * 1e-9 + 1e-12
    H = H + jax.vmap(jnp.diag)(damp)
    H = free[:, :, None] * H * free[:, None, :] + jax.vmap(jnp.diag)(1.0 - free)
    e1 = e1 * free[:-1] * free[1:]
    e2 = e2 * free[:-2] * free[2:]
    return H, e1, e2, g * free, damp * free


# --- the iteration ----------------------------------------------------------------------------------------


def _linearize(robot, prob, lay, q, frames, opts):
    """``(cost, J'J [T, n, n], J'r [T, n], pair terms, ground [T, ...])`` at ``q``."""
    local, JtJ, Jtr, ground = jax.vmap(lambda qt, fr: _frame_normal(robot, prob, lay, qt, fr))(q, frames)
    c, o, a, acc, smooth = _pair_terms(lay, q, prob, opts)
    return jnp.sum(local) + smooth, JtJ, Jtr, (c, o, a, acc), ground


def _free(lay: TangentLayout, rng, q, g, last, dtype):
    """``[T, nv]`` 1 for a coordinate that may move, 0 for one at a bound that its gradient pushes out,
    or that the last step computed at ``q`` (``last``; rejected, it is tried again) pushed out: the
    projection onto the range would have cut that step short of the model's, so the next one is
    solved with the coordinate held (a straight knee that the model would bend backwards to keep a
    planted foot still otherwise costs a rejection and a damping increase each iteration)."""
    free = jnp.ones(g.shape, dtype)
    if lay.scalar_dofs.size and lay.bounded.any():
        d, qa = lay.scalar_dofs[lay.bounded], lay.scalar_q[lay.bounded]
        lo, hi = rng[lay.bounded, 0], rng[lay.bounded, 1]
        x = q[:, qa]
        eps = 1e-10 + 1e-9 * (hi - lo)
        pinned = (((x <= (lo + eps)[None]) & ((g[:, d] > 0) | (last[:, d] < 0)))
                  | ((x >= (hi - eps)[None]) & ((g[:, d] < 0) | (last[:, d] > 0))))
        free = free.at[:, d].set(jnp.where(pinned, 0.0, 1.0))
    return free


def _initial(robot: Robot, prob: RetargetProblem, dtype):
    """Every frame at ``qpos0`` with the root's free joint on the root target."""
    q = jnp.broadcast_to(robot.qpos0.astype(dtype), (prob.num_frames, robot.nq))
    a = robot.jnt_qposadr[free_joint_of(robot, prob.bodies[0])]
    p = prob.target_positions().astype(dtype)[:, 0]
    return q.at[:, a:a + 3].set(p).at[:, a + 3:a + 7].set(prob.orientations.astype(dtype)[:, 0])


def _step(JtJ, g, c, a, free, mu, ground, touching):
    """``(delta [T, n], ok, predicted decrease, touching)``: the damped Gauss-Newton step, with the ground rows
    of the foot points ``touching`` ``[T, P]`` in its model; the returned ``touching`` are the points this step
    takes below the ground from above its soft band.

    A point above the ground's soft band has no row in the model (its residual and slope are 0 there), so a
    step may carry it well below the ground, where its cost grows fast: such steps were rejected and the
    damping raised several times a solve. The points that the last step (accepted or not) took below the
    ground therefore join this step's model with the rows ``sqrt(w) (h + dh/dq delta)``: their depth's square
    below the ground and, above it, a spring that holds them near the ground; a point leaves the set when the
    step with its row keeps it above the ground (an active set, updated once per step). The predicted
    decrease counts the points' model as one-sided."""
    hs, jz, outside = ground
    extra = (touching & outside).astype(g.dtype)
    H, e1, e2, rhs, damp = _normal_equations(JtJ + einsum("tp,tpi,tpj->tij", extra, jz, jz),
                                             g + einsum("tp,tpi->ti", extra * hs, jz), c, a, free, mu)
    delta, ok = solvers.block_pentadiagonal_solve(H, e1, e2, -rhs)
    h_new = hs + einsum("tpi,ti->tp", jz, delta)
    predicted = (0.5 * (jnp.sum(damp * delta**2) - jnp.sum(rhs * delta))
                 - 0.5 * jnp.sum(extra * (hs**2 - jnp.maximum(h_new, 0.0) ** 2)))
    return delta, ok, predicted, outside & (h_new < 0)


#: Clips per chunk of a batched solve (:func:`solvers.lane_map`, its reverse-mode form: the loop has no forward
#: mode). Under ``vmap`` the iterations of a larger batch run ``lax.map`` over chunks of this many clips: a clip is
#: already a wide problem (every frame's Jacobian, the banded solve over the frames), so batching more of them
#: vectorizes little, while a vmapped loop runs every clip until the slowest has converged and streams all their
#: blocks through the cache. Measured on the 2-core CPU, 32 clips of 120 frames on the G1: 3.8 s unchunked, 2.35 s
#: in chunks of 2 (1 and 4: 2.3-3.5 and 3.2 s). The values are the vmapped loop's to round-off (within 1e-10 in qpos).
RETARGET_LANES = 2

#: The most damping (relative to the diagonal) of a step that may end the iterations.
_CONVERGED_DAMPING = 1e-3


def _converged(accept, mu, cost, actual, predicted, delta, rtol, xtol):
    """Whether an iteration ends the solve. A step that large damping kept short says little about the optimum:
    only a nearly Gauss-Newton step counts (a clip once stopped with a foot 3 mm in the ground after a few
    rejections). The model's predicted decrease must be small as well as the actual one (MINPACK's test): a step
    that the model overrated, accepted for a round-off gain, once stopped a float32 clip of the benchmark after
    6 iterations with a foot 4 mm in the ground."""
    scale = rtol * jnp.maximum(cost, jnp.finfo(cost.dtype).tiny)
    return accept & (mu <= _CONVERGED_DAMPING) & (
        ((actual <= scale) & (predicted <= scale)) | (jnp.max(jnp.abs(delta)) <= xtol))


def _placeholder(prob, lay, q0, opts):
    """The linearization the loop starts from, before its first trip linearizes ``q0``: ``J'J`` the identity and
    every other term 0, so that the step computed from it (and discarded) is finite, in value and derivative.
    Built from the shapes (the smoothness terms' by ``eval_shape``, which does not trace the kinematics)."""
    T, n, dtype = q0.shape[0], lay.nv, q0.dtype
    P = sum(len(f) for f in prob.foot_points)
    zeros = lambda *shape: jnp.zeros(shape, dtype)  # noqa: E731
    pair = jax.eval_shape(lambda q: _pair_terms(lay, q, prob, opts), q0)
    pair = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), pair)
    return (zeros(), jnp.broadcast_to(jnp.eye(n, dtype=dtype), (T, n, n)), zeros(T, n), pair[:4],
            (zeros(T, P), zeros(T, P, n), jnp.zeros((T, P), bool)))


def _iterate(robot, prob, lay, rng, q0, frames, opts, dtype):
    """Levenberg-Marquardt steps of the whole clip from ``q0`` until converged (``opts.rtol``,
    ``opts.xtol``), at most ``opts.iterations``; returns ``(q, cost, converged, steps)``.

    The loop is equinox's checkpointed ``while_loop``: it stops early (under ``vmap``, when every
    clip of a chunk of :data:`RETARGET_LANES` has converged) and still has a reverse-mode derivative. Its first
    trip is the linearization at ``q0`` (its step, from :func:`_placeholder`, is discarded and not counted), as in
    :mod:`solvers`' least squares: the program then holds one linearization, the body's, instead of a second one
    before the loop (G1, the CMU clip: 7.3 -> 4.8 s to compile, 1.9 -> 1.45 s to trace and lower)."""
    cones = robot.jnt_range.astype(dtype)[lay.cone_joints, 1]
    rtol, xtol = opts.rtol.astype(dtype), opts.xtol.astype(dtype)

    def step(carry):
        q, lin, (mu, nu), (last, touching), _, _, k = carry  # k: trips so far, the first one not a step
        first = k == 0
        cost, JtJ, Jtr, (c, o, a, acc), ground = lin
        g = _gradient(Jtr, c, o, a, acc)
        free = _free(lay, rng, q, g, last, dtype)
        delta, ok, predicted, touched = _step(JtJ, g, c, a, free, mu, ground, touching)
        delta = jnp.where(ok & ~first, delta, 0.0)
        q_new = jax.vmap(lambda qt, dt: retract(lay, rng, qt, dt, cones))(q, delta)
        q_new = jnp.where(first, q, q_new)  # the first trip linearizes q0 itself
        lin_new = _linearize(robot, prob, lay, q_new, frames, opts)
        # Nielsen's damping update from the gain ratio: actual over the linear model's predicted decrease
        cost_new = lin_new[0]
        actual = cost - cost_new
        accept = first | (ok & jnp.isfinite(cost_new) & (actual > 0))
        rho = actual / jnp.maximum(predicted, jnp.finfo(dtype).tiny)
        pick = lambda a, b: jax.tree.map(lambda x, y: jnp.where(accept, x, y), a, b)  # noqa: E731
        converged = ~first & _converged(accept, mu, cost, actual, predicted, delta, rtol, xtol)
        mu_acc = mu * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * jnp.clip(rho, 0.0, 1.0) - 1.0) ** 3)
        mu_new, nu_new = (jnp.where(accept, jnp.maximum(mu_acc, 1e-9), jnp.minimum(mu * nu, 1e9)),
                          jnp.where(accept, 2.0, 2.0 * nu))
        mu, nu = jnp.where(first, mu, mu_new), jnp.where(first, nu, nu_new)
        last = jnp.where(first | ~(accept | (free > 0)), last, delta)  # rejected: a held coordinate stays held
        touching = jnp.where(first, touching, touched)
        return pick(q_new, q), pick(lin_new, lin), (mu, nu), (last, touching), converged, ~(ok | first), k + 1

    lin0 = _placeholder(prob, lay, q0, opts)
    damping = (jnp.asarray(1e-4, dtype), jnp.asarray(2.0, dtype))  # mu relative to J'J's diagonal
    held = (jnp.zeros_like(lin0[2]), jnp.zeros(lin0[4][0].shape, bool))  # the last step, the points it touched
    start = (q0, lin0, damping, held, jnp.asarray(False), jnp.asarray(False), jnp.asarray(0, jnp.int32))
    q, lin, _, _, converged, _, trips = eqxi.while_loop(lambda c: ~(c[4] | c[5]), step, start,
                                                     max_steps=opts.iterations + 1, kind="checkpointed")
    return q, lin[0], converged, trips - 1


@jit
def _solve(robot: Robot, prob: RetargetProblem, opts: RetargetOptions):
    dtype = prob.positions.dtype
    lay = TangentLayout(robot)
    rng = robot.jnt_range.astype(dtype)[lay.scalar_joints] if lay.scalar_dofs.size else jnp.zeros((0, 2), dtype)
    frames = _frames(prob, opts, dtype)
    cones = robot.jnt_range.astype(dtype)[lay.cone_joints, 1]
    q = jax.vmap(lambda q: retract(lay, rng, q, jnp.zeros(robot.nv, dtype), cones))(_initial(robot, prob, dtype))

    def iterate(q, prob):
        return _iterate(robot, prob, lay, rng, q, frames, opts, dtype)

    q, cost, converged, steps = solvers.lane_map(iterate, q, prob, lanes=RETARGET_LANES, reverse=True)
    finite = jnp.all(jnp.isfinite(q)) & jnp.isfinite(cost)
    result = solvers.RESULTS.where(~finite, solvers.RESULTS.nonfinite, solvers.RESULTS.where(
        converged, solvers.RESULTS.successful, solvers.RESULTS.max_steps_reached))
    return q, cost, result, finite & converged, steps


def _check_oriented(problem: RetargetProblem) -> None:
    """A concrete problem whose orientation weight is not 0 on a target without orientation rows is refused (the
    solve would ignore it); traced weights (under ``jit``, ``vmap`` or ``grad``) are not checked."""
    w = problem.orientation_weight
    if isinstance(w, jax.core.Tracer):
        return
    w = np.asarray(w).reshape(-1, len(problem.names))
    bad = [name for k, name in enumerate(problem.names) if k not in problem.oriented and np.any(w[:, k] != 0)]
    if bad:
        raise JaxanimError(f"problem.orientation_weight: not 0 on {bad}, whose orientation weight was 0 when the "
                           "problem was prepared, so the solve has no orientation rows for them; prepare the problem "
                           "again with the map's new weights")


def solve_retarget(robot: Robot, problem: RetargetProblem, options: RetargetOptions | None = None) -> RetargetResult:
    """Solve one prepared clip (:func:`~jaxanim.retargeting.prepare_retarget`); batch clips with ``jax.vmap``
    over :func:`~jaxanim.retargeting.stack_problems` (``in_axes=(None, 0, None)``). Jit-compiled once per
    robot, map and clip length; differentiable with respect to the problem's weights and scale and the
    options' weights. ``robot`` is the robot given to :func:`~jaxanim.retargeting.prepare_retarget`: the
    free joint and soles it added are added here too (:func:`~jaxanim.retargeting.prepared_robot`), and
    ``qpos`` is that robot's.
    """
    options = RetargetOptions() if options is None else options
    _check_oriented(problem)
    robot = prepared_robot(robot, problem)
    q, cost, result, success, steps = _solve(robot, problem, options)
    fps = 1.0 / problem.frame_time
    return RetargetResult(qpos=q, fps=fps, result=result, success=success, cost=cost,
                          num_steps=steps, diagnostics=diagnostics(robot, problem, q))
