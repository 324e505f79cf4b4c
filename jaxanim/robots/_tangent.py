"""The tangent space of a robot's configurations: which coordinates are additive and which are
rotations, ``q ⊕ delta`` and ``q_b ⊖ q_a`` (MuJoCo's velocity coordinates)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .. import rotations as rot
from ._kinematics import mm
from ._robot import Robot


class TangentLayout:
    """Static index sets of a robot's tangent space: MuJoCo's velocity coordinates (dofs), or those of the
    joints that move when some are ``frozen``. Positions are in the tangent vector (``nv`` long; equal to
    the robot's dofs when nothing is frozen), ``var_dofs`` maps them to the robot's dofs.

    * ``scalar_*``: additive coordinates (hinges, slides, a free joint's translation): their positions,
      ``qpos`` slots and joints; ``bounded`` marks the limited ones;
    * ``rot_*``: rotation blocks (balls, a free joint's rotation, a rotation vector in the body's local
      frame): their three positions and the first ``qpos`` slot of their quaternion; ``cone_blocks`` /
      ``cone_joints`` the limited balls (MuJoCo's cone) and their joints;
    * ``joint_*``: the hinges and slides alone (no free translation).

    One layout serves the robot IK (:func:`jaxanim.ik.solve_ik_robot`) and the retargeting solve. It
    compares and hashes by value, so a layout can be a static field of a jitted pytree."""

    def __init__(self, robot: Robot, frozen: tuple[int, ...] = ()):
        frozen = set(frozen)
        var_dofs, scalar_dofs, scalar_q, scalar_j, rot_dofs, rot_q, rot_j = [], [], [], [], [], [], []
        joint_dofs, joint_q = [], []
        for j, ty in enumerate(robot.jnt_types):
            if j in frozen:
                continue
            d, a, k = robot.jnt_dofadr[j], robot.jnt_qposadr[j], len(var_dofs)
            if ty in ("hinge", "slide"):
                scalar_dofs.append(k), scalar_q.append(a), scalar_j.append(j)
                joint_dofs.append(k), joint_q.append(a)
                var_dofs.append(d)
            elif ty == "ball":
                rot_dofs.append((k, k + 1, k + 2)), rot_q.append(a), rot_j.append(j)
                var_dofs += [d, d + 1, d + 2]
            else:  # free: translation (additive, world), then rotation (local)
                scalar_dofs += [k, k + 1, k + 2]
                scalar_q += [a, a + 1, a + 2]
                scalar_j += [j] * 3
                rot_dofs.append((k + 3, k + 4, k + 5)), rot_q.append(a + 3), rot_j.append(j)
                var_dofs += list(range(d, d + 6))
        self.nv = len(var_dofs)
        self.var_dofs = np.asarray(var_dofs, int)
        self.scalar_dofs, self.scalar_q = np.asarray(scalar_dofs, int), np.asarray(scalar_q, int)
        self.scalar_joints = np.asarray(scalar_j, int)
        self.rot_dofs = np.asarray(rot_dofs, int).reshape(-1, 3)
        self.rot_q = np.asarray(rot_q, int)
        self.joint_dofs, self.joint_q = np.asarray(joint_dofs, int), np.asarray(joint_q, int)
        self.bounded = np.asarray([robot.jnt_limited[j] for j in scalar_j], bool)
        # limited balls: their rotation block and joint (MuJoCo's cone, jnt_range[j, 1])
        balls = [(b, j) for b, j in enumerate(rot_j) if robot.jnt_types[j] == "ball" and robot.jnt_limited[j]]
        self.cone_blocks = np.asarray([b for b, _ in balls], int)
        self.cone_joints = np.asarray([j for _, j in balls], int)
        self._key = tuple((k, tuple(np.ravel(v).tolist())) for k, v in sorted(vars(self).items()) if k != "nv")

    def __eq__(self, other) -> bool:
        return isinstance(other, TangentLayout) and self._key == other._key

    def __hash__(self) -> int:
        return hash(self._key)


def retract(lay: TangentLayout, rng, q, delta, cones=None):
    """``q ⊕ delta``, hinges and slides clipped into ``rng`` ``[scalars, 2]`` and limited balls brought
    back onto their cones (``cones``: ``jnt_range[:, 1]`` of ``lay.cone_joints``)."""
    return retract_and_jacobian(lay, rng, q, delta, cones)[0]


def retract_and_jacobian(lay: TangentLayout, rng, q, delta, cones=None):
    """``(q ⊕ delta, J_rot [blocks, 3, 3])`` (:func:`retract`): ``J_rot`` maps ``d delta`` of each rotation
    block to its local angular velocity: ``J_r(delta)`` (``d(quat ⊗ exp(delta))``), times the cone's
    projection (:func:`cone_projection`) where a limited ball was brought back."""
    if lay.scalar_dofs.size:
        q = q.at[lay.scalar_q].set(jnp.clip(q[lay.scalar_q] + delta[lay.scalar_dofs], rng[:, 0], rng[:, 1]))
    d = delta[lay.rot_dofs]
    J_rot = rot.right_jacobian(d)
    if lay.rot_q.size:
        qi = lay.rot_q[:, None] + np.arange(4)
        quat = rot.quat_normalize(rot.quat_multiply(q[qi], rot.rotvec_to_quat(d)))
        if lay.cone_blocks.size and cones is not None:
            clamped, P = cone_projection(quat[lay.cone_blocks], cones)
            quat = quat.at[lay.cone_blocks].set(clamped)
            J_rot = J_rot.at[lay.cone_blocks].set(mm(P, J_rot[lay.cone_blocks]))
        q = q.at[qi].set(quat)
    return q, J_rot


def tangent_difference(lay: TangentLayout, qa, qb):
    """``qb ⊖ qa`` ``[nv]``: additive coordinates' difference, rotations' local rotation vector."""
    v = jnp.zeros(qa.shape[:-1] + (lay.nv,), qa.dtype)
    if lay.scalar_dofs.size:
        v = v.at[..., lay.scalar_dofs].set(qb[..., lay.scalar_q] - qa[..., lay.scalar_q])
    if lay.rot_q.size:
        qi = lay.rot_q[:, None] + np.arange(4)
        v = v.at[..., lay.rot_dofs].set(rot.quat_to_rotvec(rot.quat_multiply(rot.quat_conjugate(qa[..., qi]), qb[..., qi])))
    return v


def free_joint_of(robot: Robot, body: int) -> int | None:
    """The free joint that moves ``body``: on it or on its nearest ancestor that has one (``None``: none)."""
    while body > 0:
        for j, (t, b) in enumerate(zip(robot.jnt_types, robot.jnt_bodies)):
            if t == "free" and b == body:
                return j
        body = robot.body_parents[body]
    return None


def cone_projection(quat, angle):
    """MuJoCo's ball range: a rotation of more than ``angle`` (rad, from the identity) is brought back to
    ``angle`` about the same axis. Returns ``(quat, P)``, ``P [.., 3, 3]`` the map from the local angular
    velocity before to after: ``J_r(v') s (I - u u') J_r(v)^{-1}`` with ``v`` the rotation vector,
    ``v' = s v``, ``s = angle / |v|``, ``u = v / |v|`` (the identity where the rotation is inside)."""
    v = rot.quat_to_rotvec(quat)
    theta = jnp.linalg.norm(v, axis=-1)
    out = theta > angle
    safe = jnp.where(out, theta, 1.0)
    scale = jnp.where(out, angle / safe, 1.0)
    u = v / safe[..., None]
    v2 = v * scale[..., None]
    eye = jnp.broadcast_to(jnp.eye(3, dtype=v.dtype), v.shape[:-1] + (3, 3))
    radial = eye - u[..., :, None] * u[..., None, :]
    Jr_inv = jnp.swapaxes(rot.left_jacobian_inverse(v), -1, -2)  # J_r(v)^{-1} = J_l(v)^{-T}
    P = mm(rot.right_jacobian(v2), mm(scale[..., None, None] * radial, Jr_inv))
    P = jnp.where(out[..., None, None], P, eye)
    return jnp.where(out[..., None], rot.rotvec_to_quat(v2), quat), P
