"""Rigid-body dynamics of a robot in its joint coordinates: MuJoCo's mass matrix (``mj_fullM`` of ``qM``,
armature on the diagonal), bias forces (``qfrc_bias``: Coriolis, centrifugal and gravity), passive forces
(``qfrc_passive``: joint damping and springs) and the smooth forward dynamics (``qacc_smooth``: the
acceleration without constraints, as ``mj_forward`` gives it where no contact, limit or dry friction is
active).

Spatial vectors are taken at the world origin: a motion ``[w; v]`` is an angular velocity and the
velocity of the body point that passes through the origin, a force ``[n; f]`` a moment about the origin
and a force. Each dof ``d`` has its motion column ``S_d``: a hinge or a ball / free joint's rotational dof
``[a; p x a]`` (axis ``a`` through the anchor ``p``), a slide or a free joint's translation ``[0; a]``.
A body's velocity is the sum of the columns of the dofs that move it (their ancestor table,
:func:`~jaxanim.robots._kinematics.kinematic_plan`'s ``moves``), so the mass matrix is
``M = sum_b J_b' I_b J_b`` and the bias ``sum_b J_b' (I_b (dJ_b qvel - a_g) + v_b x* I_b v_b)``, with
``dS_d = V_d x S_d`` for the velocity ``V_d`` of the frame that carries the dof (its ancestors' dofs; a
free joint's translations are fixed in the world). Every step is one product over all bodies and dofs
(no loop over the tree), so a batch of robots is one ``vmap``.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg  # noqa: F401 (jax.scipy.linalg.cho_solve)
import numpy as np

from .. import rotations as rot
from .._errors import JaxanimError, check_float, check_shape
from .._linalg import einsum
from .._types import Array, Float
from ._kinematics import check_qpos, dof_axes, kinematic_plan, mm, world_frames
from ._robot import Robot
from ._tangent import TangentLayout, tangent_difference

__all__ = ["actuator_forces", "bias_forces", "forward_dynamics", "mass_matrix", "passive_forces"]

#: MuJoCo's default ``opt.gravity``, for a robot built without it.
DEFAULT_GRAVITY = (0.0, 0.0, -9.81)


def _motion_columns(robot: Robot, kin, dtype):
    """``S [nv, 6]``: each dof's spatial motion at the world origin (angular; linear)."""
    plan = kinematic_plan(robot)
    axis, anchor = dof_axes(robot, kin, range(robot.nv), dtype)
    rotational = plan.dof_rot[:, None]
    return jnp.concatenate([jnp.where(rotational, axis, 0.0),
                            jnp.where(rotational, jnp.cross(anchor, axis), axis)], axis=-1)


def _cross_motion(v, m):
    """``v x m`` of spatial motions ``[..., 6]``."""
    w, u = v[..., :3], v[..., 3:]
    return jnp.concatenate([jnp.cross(w, m[..., :3]), jnp.cross(w, m[..., 3:]) + jnp.cross(u, m[..., :3])], axis=-1)


def _cross_force(v, f):
    """``v x* f`` of a spatial motion and force ``[..., 6]``."""
    w, u = v[..., :3], v[..., 3:]
    return jnp.concatenate([jnp.cross(w, f[..., :3]) + jnp.cross(u, f[..., 3:]), jnp.cross(w, f[..., 3:])], axis=-1)


def _spatial_inertias(robot: Robot, kin, dtype):
    """``[bodies, 6, 6]``: each body's spatial inertia at the world origin, in world axes."""
    if robot.body_inertia is None:
        raise JaxanimError("robot: it has no body inertias (body_inertia is None); load it with "
                           "robots.load_robot or robots.robot_from_mujoco")
    R_world, p_world, _, _ = kin
    m = robot.body_mass.astype(dtype)
    R_i = mm(R_world, rot.quat_to_matrix(robot.body_iquat.astype(dtype)))  # principal axes in the world
    c = p_world + einsum("bij,bj->bi", R_world, robot.body_ipos.astype(dtype))  # the centres of mass
    I_c = einsum("bij,bj,bkj->bik", R_i, robot.body_inertia.astype(dtype), R_i)
    cx = jnp.swapaxes(jnp.cross(c[:, None, :], jnp.eye(3, dtype=dtype)[None]), 1, 2)  # column i: c x e_i
    top = jnp.concatenate([I_c - m[:, None, None] * mm(cx, cx), m[:, None, None] * cx], axis=-1)
    bottom = jnp.concatenate([-m[:, None, None] * cx, m[:, None, None] * jnp.eye(3, dtype=dtype)[None]], axis=-1)
    return jnp.concatenate([top, bottom], axis=-2)


def _prepare(robot: Robot, qpos, qvel=None):
    qpos, dtype = check_qpos(robot, qpos)
    if qvel is None:
        return qpos, None, dtype
    check_shape("qvel", qvel, (robot.nv,), what=f"(nv,) = ({robot.nv},)")
    check_float("qvel", qvel)
    return qpos, jnp.asarray(qvel).astype(dtype), dtype


def _dof_array(x, nv, dtype):
    return jnp.zeros(nv, dtype) if x is None else x.astype(dtype)


def _gravity(robot: Robot, dtype):
    return jnp.asarray(DEFAULT_GRAVITY, dtype) if robot.gravity is None else robot.gravity.astype(dtype)


def _mass_matrix(robot: Robot, S, I, dtype):
    moves = jnp.asarray(kinematic_plan(robot).moves, dtype)  # [B, nv]
    IS = einsum("bij,dj->bdi", I, S)  # [B, nv, 6]
    M = einsum("bd,be,di,bei->de", moves, moves, S, IS)
    return M + jnp.diag(_dof_array(robot.dof_armature, robot.nv, dtype))


def _bias(robot: Robot, S, I, qvel, dtype):
    plan = kinematic_plan(robot)
    moves = jnp.asarray(plan.moves, dtype)  # [B, nv]
    dof_body = np.asarray([robot.jnt_bodies[j] for j in plan.dof_joint], np.int64)
    # the dofs that carry dof d: those that move its body and come before it (a body's joints apply in order);
    # a ball's or a free joint's rotational axes are the body's own, turned by all three of its rotations, whose
    # terms cancel in the sum over them (v x v = 0), so none of the three carries another
    joint, rotational = np.asarray(plan.dof_joint, np.int64), plan.dof_rot
    same_turn = (joint[:, None] == joint[None, :]) & rotational[:, None] & rotational[None, :]
    carry = plan.moves[dof_body] & (np.arange(robot.nv)[None, :] < np.arange(robot.nv)[:, None]) & ~same_turn
    Sq = S * qvel[:, None]
    V_carry = einsum("de,ei->di", jnp.asarray(carry, dtype), Sq)
    dS = _cross_motion(V_carry, S)  # a free joint's translations: its carrier is the world, so 0
    V = einsum("bd,di->bi", moves, Sq)  # [B, 6] the bodies' velocities
    A = einsum("bd,di->bi", moves, dS * qvel[:, None])  # their accelerations at qacc = 0
    a_g = jnp.concatenate([jnp.zeros(3, dtype), _gravity(robot, dtype)])
    f = einsum("bij,bj->bi", I, A - a_g[None]) + _cross_force(V, einsum("bij,bj->bi", I, V))
    return einsum("di,bd,bi->d", S, moves, f)


def _passive(robot: Robot, qpos, qvel, dtype):
    out = -_dof_array(robot.dof_damping, robot.nv, dtype) * qvel
    if robot.jnt_stiffness is None or robot.qpos_spring is None:
        return out
    lay = TangentLayout(robot)
    if lay.rot_q.size:  # MuJoCo normalizes the quaternions first
        qi = lay.rot_q[:, None] + np.arange(4)
        qpos = qpos.at[qi].set(rot.quat_normalize(qpos[qi]))
    # each dof's displacement from the spring's rest: differences, a rotation's rotation vector of rest^-1 q
    # (MuJoCo's subQuat)
    stiffness = robot.jnt_stiffness.astype(dtype)[np.asarray(robot.dof_joints, np.int64)]
    return out - stiffness * tangent_difference(lay, robot.qpos_spring.astype(dtype), qpos)


def _actuation(robot: Robot, qpos, qvel, ctrl, dtype):
    """MuJoCo's ``qfrc_actuator`` of the modelled actuators (:class:`Robot`'s ``actuator_*``)."""
    joints = np.asarray(robot.actuator_joints, np.int64)
    a = np.asarray([robot.jnt_qposadr[j] for j in joints], np.int64)
    d = np.asarray([robot.jnt_dofadr[j] for j in joints], np.int64)
    gear, bias = robot.actuator_gear.astype(dtype), robot.actuator_bias.astype(dtype)
    ctrlrange, forcerange = robot.actuator_ctrlrange.astype(dtype), robot.actuator_forcerange.astype(dtype)
    length, velocity = gear * qpos[a], gear * qvel[d]
    u = jnp.clip(ctrl, ctrlrange[:, 0], ctrlrange[:, 1])
    force = robot.actuator_gain.astype(dtype) * u + bias[:, 0] + bias[:, 1] * length + bias[:, 2] * velocity
    force = jnp.clip(force, forcerange[:, 0], forcerange[:, 1])
    qfrc = jnp.zeros(robot.nv, dtype).at[d].add(gear * force)
    if robot.jnt_actfrcrange is None:
        return qfrc
    limit = robot.jnt_actfrcrange.astype(dtype)[np.asarray(robot.dof_joints, np.int64)]  # per dof, its joint's
    return jnp.clip(qfrc, limit[:, 0], limit[:, 1])


@eqx.filter_jit
def _actuated(robot: Robot, qpos, qvel, ctrl, dtype):
    return _actuation(robot, qpos, qvel, ctrl, dtype)


def _check_ctrl(robot: Robot, ctrl, dtype):
    unmodelled = [n for n, j in zip(robot.actuator_names, robot.actuator_joints) if j < 0]
    if unmodelled:
        raise JaxanimError(f"robot: its actuators {unmodelled} are not modelled (only those on a hinge or slide, "
                           "without activation dynamics, with a fixed gain: motor, position, velocity)")
    if robot.actuator_gear is None:
        raise JaxanimError("robot: it has no actuator parameters; load it with robots.load_robot or "
                           "robots.robot_from_mujoco")
    U = len(robot.actuator_names)
    check_shape("ctrl", ctrl, (U,), what=f"(actuators,) = ({U},)")
    check_float("ctrl", ctrl)
    return jnp.asarray(ctrl).astype(dtype)


def actuator_forces(robot: Robot, qpos: Float[Array, " nq"], qvel: Float[Array, " nv"],
                    ctrl: Float[Array, " actuators"]) -> Float[Array, " nv"]:
    """The actuators' generalized forces [nv] for the controls ``ctrl`` (MuJoCo's ``qfrc_actuator``):
    each actuator's ``ctrl`` clamped to its ``ctrlrange``, its force ``gain ctrl + bias`` (a ``motor``
    gives ``ctrl``, a ``position`` actuator ``kp (ctrl - qpos) - kv qvel``) clamped to its
    ``forcerange``, times its gear on its joint, and each joint's total clamped to its
    ``actuatorfrcrange``.

    Raises:
        JaxanimError: an actuator this library does not model (named), inputs of the wrong shape.
    """
    qpos, qvel, dtype = _prepare(robot, qpos, qvel)
    ctrl = _check_ctrl(robot, ctrl, dtype)
    if not robot.actuator_names:
        return jnp.zeros(robot.nv, dtype)
    return _actuated(robot, qpos, qvel, ctrl, dtype)


@eqx.filter_jit
def _dynamics(robot: Robot, qpos, qvel, dtype, what: str):
    """One program per robot and request: ``"mass"`` M, ``"bias"``, ``"passive"`` or ``"qacc"``."""
    if what == "passive":
        return _passive(robot, qpos, qvel, dtype)
    kin = world_frames(robot, qpos, dtype)
    S = _motion_columns(robot, kin, dtype)
    I = _spatial_inertias(robot, kin, dtype)
    if what == "mass":
        return _mass_matrix(robot, S, I, dtype)
    if what == "bias":
        return _bias(robot, S, I, qvel, dtype)
    M = _mass_matrix(robot, S, I, dtype)
    rhs = _passive(robot, qpos, qvel, dtype) - _bias(robot, S, I, qvel, dtype)
    return M, rhs


def mass_matrix(robot: Robot, qpos: Float[Array, " nq"]) -> Float[Array, "nv nv"]:
    """The joint-space mass matrix ``M(qpos)`` [nv, nv], armature included (MuJoCo's ``qM`` as
    ``mj_fullM`` expands it), in MuJoCo's velocity layout.

    Raises:
        JaxanimError: a robot without inertias, or ``qpos`` of the wrong shape.
    """
    qpos, _, dtype = _prepare(robot, qpos)
    if robot.nv == 0:
        return jnp.zeros((0, 0), dtype)
    return _dynamics(robot, qpos, jnp.zeros(robot.nv, dtype), dtype, "mass")


def bias_forces(robot: Robot, qpos: Float[Array, " nq"], qvel: Float[Array, " nv"]) -> Float[Array, " nv"]:
    """``C(qpos, qvel) qvel + g(qpos)`` [nv]: the generalized forces that hold the robot at zero
    acceleration against gravity, Coriolis and centrifugal effects (MuJoCo's ``qfrc_bias``).

    Raises:
        JaxanimError: a robot without inertias, or ``qpos`` / ``qvel`` of the wrong shape.
    """
    qpos, qvel, dtype = _prepare(robot, qpos, qvel)
    if robot.nv == 0:
        return jnp.zeros(0, dtype)
    return _dynamics(robot, qpos, qvel, dtype, "bias")


def passive_forces(robot: Robot, qpos: Float[Array, " nq"], qvel: Float[Array, " nv"]) -> Float[Array, " nv"]:
    """Joint damping and springs [nv] (MuJoCo's ``qfrc_passive`` without fluid forces):
    ``-dof_damping qvel - jnt_stiffness (qpos - qpos_spring)``, a ball's or a free joint's rotation
    by its rotation vector from the spring's rest.

    Raises:
        JaxanimError: ``qpos`` / ``qvel`` of the wrong shape.
    """
    qpos, qvel, dtype = _prepare(robot, qpos, qvel)
    if robot.nv == 0:
        return jnp.zeros(0, dtype)
    return _dynamics(robot, qpos, qvel, dtype, "passive")


def forward_dynamics(robot: Robot, qpos: Float[Array, " nq"], qvel: Float[Array, " nv"],
                     qfrc_applied: Float[Array, " nv"] | None = None,
                     ctrl: Float[Array, " actuators"] | None = None) -> Float[Array, " nv"]:
    """The joint accelerations ``qacc`` [nv] under gravity, the passive forces, ``qfrc_applied``
    (generalized forces in MuJoCo's dof layout, as its ``qfrc_applied``) and, given ``ctrl``, the
    actuators (:func:`actuator_forces`), without constraints: ``M qacc = qfrc_applied +
    qfrc_actuator + qfrc_passive - qfrc_bias`` (MuJoCo's ``qacc_smooth``; ``mj_forward``'s ``qacc``
    where no contact, joint limit or dry friction is active). Solved by Cholesky.

    Raises:
        JaxanimError: a robot without inertias, an actuator this library does not model, inputs of the
            wrong shape.
    """
    qpos, qvel, dtype = _prepare(robot, qpos, qvel)
    if qfrc_applied is None:
        tau = jnp.zeros(robot.nv, dtype)
    else:
        check_shape("qfrc_applied", qfrc_applied, (robot.nv,), what=f"(nv,) = ({robot.nv},)")
        check_float("qfrc_applied", qfrc_applied)
        tau = jnp.asarray(qfrc_applied).astype(dtype)
    if ctrl is not None:
        tau = tau + actuator_forces(robot, qpos, qvel, ctrl)
    if robot.nv == 0:
        return jnp.zeros(0, dtype)
    return _qacc(robot, qpos, qvel, tau, dtype)


@eqx.filter_jit
def _qacc(robot: Robot, qpos, qvel, tau, dtype):
    M, rhs = _dynamics(robot, qpos, qvel, dtype, "qacc")
    return jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(M, lower=True), tau + rhs)
