r"""Inverse kinematics on a :class:`Robot`: targets on bodies and sites, joint ranges as hard
bounds, a floating base; the nonlinear least-squares problem of the skeleton IK
(``jaxanim/ik/_problem.py``) in MuJoCo's coordinates.

Objective::

    F(y) = 1/2 sum_i w_i (|p_i(y) - p*_i|^2 + |log(R_i(y) R*_i^T)|^2) + 1/2 lambda sum_d w_d y_d^2

Variables. ``y`` is a tangent increment of ``qpos`` around a reference configuration ``q_ref``
(by default the start), one number per velocity coordinate (dof) that is not frozen, in MuJoCo's
dof order:

* a hinge or slide: ``qpos = q_ref + y`` (rad or m);
* a free joint's translation: ``qpos[0:3] = q_ref[0:3] + y[0:3]`` (world frame, m);
* a free joint's or a ball joint's rotation: ``quat = quat_ref ⊗ exp(delta)`` with ``delta`` a
  rotation vector in the body's **local** frame (MuJoCo's angular velocity of these joints).

So ``y = 0`` is the reference and the regularizer ``sqrt(lambda w_d) y_d`` pulls towards it. The
Jacobian is exact: the geometric Jacobian columns of :func:`~jaxanim.robots.jacobian` (MuJoCo's
``cdof``), with each rotational block times the SO(3) right Jacobian ``J_r(delta)``
(``d(quat_ref ⊗ exp(delta)) = local angular velocity J_r(delta) d delta``), and orientation rows
times ``J_l^{-1}(e)`` of the world-frame error ``e = log(R R*^T)``. One kinematics pass gives the
residual and its Jacobian (``least_squares(..., jac=True)``). A ball joint's columns are MuJoCo's
(the axes of its body's frame), which are those of the frame just after the ball: MuJoCo allows no
rotational joint after a ball in the same body, and a slide does not turn the frame.

Bounds. A limited hinge or slide (``jnt_limited``) bounds its coordinate to ``jnt_range`` as a box
on ``y`` (``range - q_ref``) given to the solver, so every iterate is inside the range and the start
is clipped into it. A limited ball joint keeps MuJoCo's cone (its rotation from the identity at most
``jnt_range[1]``): the map from ``y`` to ``qpos`` turns a rotation outside the cone back onto it about
the same axis, with the exact derivative of that projection in the Jacobian (zero along the axis'
angle, so the solver sees the cone's boundary as flat). Unlimited joints and free joints are unbounded.

Compiling once. The structure (robot tree and names, target names and kinds, frozen joints,
static solver settings, whether there is a regularizer) keys one ``eqx.filter_jit``-ed core;
targets, start and reference configurations, weights and tolerances are arrays and do not
retrace.

The robot's kinematics and its tangent layout come from :mod:`jaxanim.robots`. A target is any
object with ``site`` (a name), ``position`` (``[3]`` or ``None``), ``orientation`` (``[4]`` wxyz or
``None``) and ``weight`` (scalar), which :class:`jaxanim.ik.Target` is.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import solvers

from .. import rotations as rot
from .._errors import JaxanimError, check_float, check_shape
from .._linalg import own_kernel
from .._types import Array, Float
from ..robots._kinematics import (
    check_qpos,
    dof_columns,
    kinematic_plan,
    mm,
    target_frames,
    target_rows,
    world_frames,
)
from ..robots._robot import Robot
from ..robots._tangent import TangentLayout, retract_and_jacobian, tangent_difference
from ..rotations._matrices import angle_between_matrices

#: The default ``position_tolerance``: 10 micrometres (robots are in metres).
_POSITION_TOLERANCE = 1e-5


class RobotIKSolution(eqx.Module):
    """Result of :func:`solve_ik_robot` (the status fields of :class:`jaxanim.ik.IKSolution`).

    Attributes:
        qpos: ``[nq]`` the solved configuration (quaternions unit, continuous with the reference's
            sign; limited hinges and slides inside their ranges).
        result: :class:`solvers.RESULTS`, per element under ``vmap``.
        stats: the solver's statistics (``num_steps``, ``cost``, ...).
        position_errors: ``[targets]`` distance to each position target, m (0 where none).
        orientation_errors: ``[targets]`` angle to each orientation target, rad (0 where none).
        success: scalar bool: the solver converged **and** every target is within its tolerance. An
            unreachable target gives ``False`` with ``result`` successful (the least-squares-closest
            configuration the solver found).
    """

    qpos: Float[Array, " nq"]
    result: solvers.RESULTS
    stats: dict
    position_errors: Float[Array, " targets"]
    orientation_errors: Float[Array, " targets"]
    success: Array


# --- static layout --------------------------------------------------------------------------------


class _Layout(eqx.Module):
    """One problem's static structure: its variables (the robot's :class:`~jaxanim.robots._tangent.TangentLayout`
    without the frozen joints, the one the retargeting solve uses) and where each target sits."""

    tangent: TangentLayout = eqx.field(static=True)
    bodies: tuple[int, ...] = eqx.field(static=True)  # per target: its body
    rows: tuple[int, ...] = eqx.field(static=True)  # per target: row in [xpos (bodies); site_xpos (sites)]
    has_pos: tuple[bool, ...] = eqx.field(static=True)
    has_ori: tuple[bool, ...] = eqx.field(static=True)

    @property
    def bounded(self) -> bool:
        """Some variable is a limited hinge or slide."""
        return bool(self.tangent.bounded.any())


def _check_targets(robot: Robot, targets) -> tuple:
    """One problem's targets (``jaxanim.ik.Target`` or alike), validated before tracing."""
    if _is_target(targets):
        targets = (targets,)
    if not isinstance(targets, Sequence) or not targets or not all(_is_target(t) for t in targets):
        raise JaxanimError("targets: expected a non-empty sequence of jaxanim.ik.Target (name of a robot body or site)")
    for t in targets:
        if t.position is None and t.orientation is None:
            raise JaxanimError(f"targets: the target for {t.site!r} has neither a position nor an orientation")
        if t.position is not None:
            check_shape(f"targets[{t.site!r}].position", t.position, (3,))
        if t.orientation is not None:
            check_shape(f"targets[{t.site!r}].orientation", t.orientation, (4,))
        check_shape(f"targets[{t.site!r}].weight", t.weight, ())
    return tuple(targets)


def _is_target(t) -> bool:
    return all(hasattr(t, a) for a in ("site", "position", "orientation", "weight")) and isinstance(t.site, str)


def _layout(robot: Robot, targets: tuple, frozen) -> _Layout:
    frozen = (frozen,) if isinstance(frozen, str) else tuple(frozen)
    frozen_joints = set()
    for name in frozen:
        try:
            frozen_joints.add(robot.joint_index(name))
        except JaxanimError as e:
            raise JaxanimError(f"frozen: {e}") from None
    tangent = TangentLayout(robot, tuple(sorted(frozen_joints)))
    if not tangent.nv:
        raise JaxanimError("frozen: every joint is frozen (or the robot has none): nothing can move")
    bodies, rows = [], []
    for i, t in enumerate(targets):
        try:
            (b,), (r,) = target_rows(robot, (t.site,))
        except JaxanimError as e:
            raise JaxanimError(f"targets[{i}]: {str(e).removeprefix('names: ')}") from None
        bodies += [b]
        rows += [r]
    return _Layout(tangent, tuple(bodies), tuple(rows), tuple(t.position is not None for t in targets),
                   tuple(t.orientation is not None for t in targets))


# --- one problem's data, the pose map, the residual --------------------------------------------------


class _Data(eqx.Module):
    """Everything :func:`_residual` and :func:`_stop` need besides ``y``."""

    robot: Robot
    layout: _Layout
    targets: tuple
    q_ref: Array  # [nq], unit quaternions
    reg_w: Array | None  # [n] lambda w_d, None: no regularizer rows
    position_tolerance: Array
    orientation_tolerance: Array


def _qpos(y, data: _Data):
    """``(qpos [nq], J_rot [blocks, 3, 3])`` of the variables ``y``: ``q_ref ⊕ y``
    (:func:`~jaxanim.robots._tangent.retract_and_jacobian`): limited coordinates clipped into their range
    (which only removes rounding: the solver keeps ``y`` in the box), a limited ball turned back onto its
    cone where ``quat_ref ⊗ exp(delta)`` leaves it. ``J_rot`` maps ``d delta`` to each rotation block's local
    angular velocity: ``J_r(delta)``, times the cone's projection."""
    lay, robot = data.layout.tangent, data.robot
    rng = robot.jnt_range.astype(y.dtype)[lay.scalar_joints]
    return retract_and_jacobian(lay, rng, data.q_ref, y, robot.jnt_range.astype(y.dtype)[lay.cone_joints, 1])


def _frames(robot: Robot, lay: _Layout, qpos, dtype):
    """Target points ``[K, 3]``, target frames ``[K, 3, 3]`` (body: ``xmat``; site: ``site_xmat``) and
    the kinematics they came from."""
    kin = world_frames(robot, qpos, dtype)
    points, R = target_frames(robot, kin[0], kin[1], lay.bodies, lay.rows, dtype)
    return points, R, kin


def _jacobian(robot: Robot, lay: _Layout, kin, points, J_rot, dtype):
    """``(jacp, jacr)`` ``[K, 3, n]``: the geometric Jacobian columns of the variables' dofs
    (:func:`~jaxanim.robots.jacobian`'s), rotation blocks times ``J_rot`` (:func:`_qpos`)."""
    jacp, jacr = dof_columns(robot, kin, points, lay.bodies, tuple(lay.tangent.var_dofs.tolist()), dtype)
    if lay.tangent.rot_dofs.size:  # column d of a rotation block <- sum_c column c J_rot[c, d]
        cols = lay.tangent.rot_dofs  # [nb, 3]
        Jr = J_rot  # [nb, 3, 3]

        def blocks(jac):
            blk = jac[:, cols, :]  # [K, nb, 3 (c), 3 (xyz)]
            return jac.at[:, cols, :].set(sum(blk[:, :, c, None, :] * Jr[None, :, c, :, None] for c in range(3)))

        jacp, jacr = blocks(jacp), blocks(jacr)
    return jnp.swapaxes(jacp, 1, 2), jnp.swapaxes(jacr, 1, 2)


def _errors_and_rows(lay, targets, points, R, jacp, jacr, dtype):
    """Residual ``sqrt(w) (p - p*)`` and ``sqrt(w) log(R R*^T)`` per target (position block, then
    orientation block, in target order) and their rows; each kind is computed for all its targets at
    once, then put in order by a static gather."""
    pos = [i for i, h in enumerate(lay.has_pos) if h]
    ori = [i for i, h in enumerate(lay.has_ori) if h]
    sqrt_w = jnp.sqrt(jnp.stack([jnp.asarray(t.weight, dtype) for t in targets]))
    res, rows = [], []
    if pos:
        ip = np.asarray(pos)
        goal = jnp.stack([jnp.asarray(targets[i].position, dtype) for i in pos])
        res.append(sqrt_w[ip, None] * (points[ip] - goal))
        rows.append(sqrt_w[ip, None, None] * jacp[ip])
    if ori:
        io = np.asarray(ori)
        R_goal = rot.quat_to_matrix(jnp.stack([jnp.asarray(targets[i].orientation, dtype) for i in ori]))
        e = rot.matrix_to_rotvec(mm(R[io], jnp.swapaxes(R_goal, -1, -2)))  # world frame
        e = own_kernel(e)  # computed once, not inside each entry of its left Jacobian below
        res.append(sqrt_w[io, None] * e)
        Li = rot.left_jacobian_inverse(e)
        rows.append(sqrt_w[io, None, None] * sum(Li[:, :, c, None] * jacr[io, c, None, :] for c in range(3)))
    order, kp = [], len(pos)
    for i in range(len(targets)):
        order += ([pos.index(i)] if i in pos else []) + ([kp + ori.index(i)] if i in ori else [])
    order = np.asarray(order)
    r = jnp.concatenate(res)[order].reshape(-1)
    return r, jnp.concatenate(rows)[order].reshape(r.shape[0], -1)


def _residual(y, data: _Data):
    """``(r [m], J [m, n])`` of one problem (the residual of ``least_squares(jac=True)``)."""
    dtype = y.dtype
    robot, lay = data.robot, data.layout
    q, J_rot = _qpos(y, data)
    points, R, kin = _frames(robot, lay, q, dtype)
    jacp, jacr = _jacobian(robot, lay, kin, points, J_rot, dtype)
    r, J = _errors_and_rows(lay, data.targets, points, R, jacp, jacr, dtype)
    if data.reg_w is not None:
        sqrt_w = jnp.sqrt(data.reg_w)
        r = jnp.concatenate([r, sqrt_w * y])
        J = jnp.concatenate([J, jnp.diag(sqrt_w)], axis=0)
    return r, J


def _stop(y, r, data: _Data):
    """Every target's block (``sqrt(w)`` times its error) within ``sqrt(w)`` times its tolerance."""
    dtype = r.dtype
    ok, k = jnp.array(True), 0
    for t, hp, ho in zip(data.targets, data.layout.has_pos, data.layout.has_ori):
        for present, tol in ((hp, data.position_tolerance), (ho, data.orientation_tolerance)):
            if present:
                bound = jnp.sqrt(jnp.asarray(t.weight, dtype)) * tol.astype(dtype)
                ok = ok & (jnp.sqrt(jnp.sum(r[k : k + 3] ** 2)) <= bound)
                k += 3
    return ok


def target_errors(targets, points, R, dtype):
    """``(position errors [K], orientation errors [K])`` of ``targets`` (:class:`jaxanim.ik.Target` s) from each
    target's point ``points [K, 3]`` and frame ``R [K, 3, 3]``, zero where a target has none; each kind for all
    its targets at once. The angle of ``R R*^T`` (its rotation vector's norm) comes from
    :func:`~jaxanim.rotations._matrices.angle_between_matrices`, whose kernels compile several times faster than
    a rotation vector's. The final check of this solve and of the skeleton IK's (``jaxanim.ik``)."""
    K = len(targets)
    pe, oe = jnp.zeros((K,), dtype), jnp.zeros((K,), dtype)
    pos = np.asarray([i for i, t in enumerate(targets) if t.position is not None], dtype=np.int64)
    ori = np.asarray([i for i, t in enumerate(targets) if t.orientation is not None], dtype=np.int64)
    if pos.size:
        goal = jnp.stack([jnp.asarray(targets[i].position, dtype) for i in pos])
        pe = pe.at[pos].set(jnp.linalg.norm(points[pos] - goal, axis=-1))
    if ori.size:
        goal = rot.quat_to_matrix(jnp.stack([jnp.asarray(targets[i].orientation, dtype) for i in ori]))
        oe = oe.at[ori].set(angle_between_matrices(R[ori], goal))
    return pe, oe


# --- the solve ---------------------------------------------------------------------------------------


def _normalize_quats(robot: Robot, q):
    plan = kinematic_plan(robot)
    idx = [plan.q_quat[j] for j in range(robot.num_joints) if plan.ball[j] or plan.free[j]]
    if not idx:
        return q
    idx = np.asarray(idx)
    return q.at[idx].set(rot.quat_normalize(q[idx]))


@eqx.filter_jit
def _solve(robot, layout, targets, qpos, reference, reg, weights, solver, ptol, otol, stop_at_tolerance, throw):
    """The compiled core of :func:`solve_ik_robot` (one trace per structure)."""
    dtype = qpos.dtype
    q0 = _normalize_quats(robot, qpos)
    q_ref = q0 if reference is None else _normalize_quats(robot, jnp.asarray(reference, dtype))
    w = jnp.ones(robot.nv, dtype) if weights is None else jnp.asarray(weights, dtype)
    tan = layout.tangent
    w_var = w[tan.var_dofs]
    reg_w = None if reg is None else jnp.asarray(reg, dtype) * w_var
    data = _Data(robot, layout, targets, q_ref, reg_w, jnp.asarray(ptol, dtype), jnp.asarray(otol, dtype))
    n = tan.nv
    # the start in the variables: additive offsets and local rotation vectors from the reference
    y0 = tangent_difference(tan, q_ref, q0)
    bounds = None
    if layout.bounded:  # limited hinges / slides: range - q_ref (unlimited rows are +-inf)
        sv, qa = tan.scalar_dofs, tan.scalar_q
        rng = robot.jnt_range.astype(dtype)[tan.scalar_joints]
        lower = jnp.full(n, -jnp.inf, dtype).at[sv].set(rng[:, 0] - q_ref[qa])
        upper = jnp.full(n, jnp.inf, dtype).at[sv].set(rng[:, 1] - q_ref[qa])
        bounds = (lower, upper)
    solver = solvers.LevenbergMarquardt() if solver is None else solver
    if weights is not None and isinstance(solver, solvers.LevenbergMarquardt):
        # joint weights as the damping metric W of Levenberg-Marquardt (the notes' eq. 4.10)
        solver = eqx.tree_at(lambda s: s.weights, solver, w_var, is_leaf=lambda x: x is None)
    stop = _stop if stop_at_tolerance else None
    sol = solvers.least_squares(_residual, solver, y0, data, jac=True, bounds=bounds, stop=stop, throw=throw)

    def finish(value, data):  # the configuration and its target errors, by a kinematics pass
        q, _ = _qpos(value, data)
        points, R, _ = _frames(data.robot, data.layout, q, dtype)
        return (q,) + target_errors(data.targets, points, R, dtype)

    q, pe, oe = solvers.lane_map(finish, sol.value, data, chunks=not getattr(solver, "fixed_steps", False))
    success = ((sol.result == solvers.RESULTS.successful) & jnp.all(pe <= data.position_tolerance)
               & jnp.all(oe <= data.orientation_tolerance))
    return RobotIKSolution(q, sol.result, sol.stats, pe, oe, success)


def solve_ik_robot(
    robot: Robot,
    targets,
    qpos: Float[Array, " nq"],
    *,
    reference: Float[Array, " nq"] | None = None,
    frozen: Sequence[str] = (),
    regularization: float | Float[Array, ""] = 0.0,
    joint_weights: Float[Array, " nv"] | None = None,
    solver: solvers.AbstractLeastSquaresSolver | None = None,
    position_tolerance: float | Float[Array, ""] | None = None,
    orientation_tolerance: float | Float[Array, ""] = 1e-4,
    stop_at_tolerance: bool = True,
    throw: bool = False,
) -> RobotIKSolution:
    """Solve one IK problem on a robot; batch with ``jax.vmap``. Also ``jaxanim.ik.solve_ik(robot, ...)``.

    Minimizes ``1/2 sum_i w_i (|p_i - p*_i|^2 + |log(R_i R*_i^T)|^2) + lambda/2 sum_d w_d y_d^2``
    over the tangent increment ``y`` of ``qpos`` around ``reference`` (see the module docstring:
    hinges and slides additive, a free joint's translation additive in the world frame, free and
    ball rotations ``quat_ref ⊗ exp(delta)`` with ``delta`` in the body frame, as MuJoCo's
    velocities), with the exact Jacobian and a bounded solver: every iterate keeps each limited hinge
    and slide inside ``jnt_range`` (the start is clipped into it) and each limited ball inside its cone
    (MuJoCo's: the rotation angle at most ``jnt_range[1]``). Compiled once per structure (robot, target names and kinds, ``frozen``, static solver
    settings, whether ``regularization`` is the literal 0): new targets, ``qpos``, ``reference``,
    weights or tolerances reuse it.

    Args:
        robot: the robot.
        targets: :class:`jaxanim.ik.Target` s whose name is a body or a site of the robot (``"body:x"``
            / ``"site:x"`` where a name is both); ``position`` ``[3]`` is the world position of the
            body's origin or the site (m), ``orientation`` ``[4]`` the wxyz world orientation of its
            frame (``xmat`` / ``site_xmat``).
        qpos: ``[nq]`` the start configuration (MuJoCo's order; quaternions need not be unit).
        reference: ``[nq]`` the configuration the variables are measured from and the regularizer
            pulls towards, and where frozen joints stay (default: ``qpos``).
        frozen: joint names that keep their reference values (a free joint's name fixes the base).
        regularization: ``lambda``; the literal default ``0`` removes the regularizer's rows (a
            damped least-squares solve from the start, with the cheap ``m x m`` steps when there
            are fewer target rows than variables). Any other value, or an array, keeps them.
        joint_weights: ``[nv]`` per-dof stiffness ``w_d`` (default ones): the regularizer's weights and
            the damping metric ``W`` of ``LevenbergMarquardt``.
        solver: a :mod:`solvers` least-squares solver (default ``LevenbergMarquardt()``); with
            limited joints it must take bounds (``LevenbergMarquardt``, ``GaussNewton``,
            ``GradientDescent``).
        position_tolerance: distance (m) within which a position target counts as met for
            ``success`` (default ``1e-5``).
        orientation_tolerance: angle (rad) within which an orientation target counts as met.
        stop_at_tolerance: stop as soon as every target is within its tolerance; ``False``: solve the
            (regularized) least-squares problem to the solver's own tolerances.
        throw: raise on failure instead of reporting it in ``result`` (use ``False`` under vmap).

    Returns:
        :class:`RobotIKSolution` ``(qpos, result, stats, position_errors, orientation_errors, success)``.

    Raises:
        JaxanimError: a wrong shape (``qpos``, ``reference``, ``joint_weights``, a target's arrays), an
            unknown or ambiguous body / site / joint name (listing the valid ones), or nothing left to
            move; raised in Python before anything is computed.
    """
    qpos, _ = check_qpos(robot, qpos)  # in the robot's and qpos's dtypes promoted together
    targets = _check_targets(robot, targets)
    layout = _layout(robot, targets, frozen)
    if reference is not None:
        check_shape("reference", reference, (robot.nq,), what=f"(nq,) = ({robot.nq},)")
        check_float("reference", reference)
    if joint_weights is not None:
        check_shape("joint_weights", joint_weights, (robot.nv,), what=f"(nv,) = ({robot.nv},)")
        if isinstance(solver, solvers.LevenbergMarquardt) and solver.weights is not None:
            raise JaxanimError("joint_weights: the solver already has weights; give one or the other")
    if solver is not None and not isinstance(solver, solvers.AbstractLeastSquaresSolver) and layout.bounded:
        raise JaxanimError(
            f"solver: the robot has limited joints (hard bounds), which {type(solver).__name__} does not take; "
            "use LevenbergMarquardt, GaussNewton or GradientDescent, or freeze the limited joints"
        )
    no_reg = isinstance(regularization, (int, float)) and not isinstance(regularization, bool) and regularization == 0
    reg = None if no_reg else jnp.asarray(regularization)
    if reg is not None:
        check_shape("regularization", reg, ())
    ptol = jnp.asarray(_POSITION_TOLERANCE if position_tolerance is None else position_tolerance)
    otol = jnp.asarray(orientation_tolerance)
    check_shape("position_tolerance", ptol, ())
    check_shape("orientation_tolerance", otol, ())
    weights = None if joint_weights is None else jnp.asarray(joint_weights)
    reference = None if reference is None else jnp.asarray(reference)
    return _solve(robot, layout, targets, qpos, reference, reg, weights, solver, ptol, otol,
                  bool(stop_at_tolerance), bool(throw))
