"""The tangent space of a robot's configurations: which coordinates are additive and which are
rotations, ``q ⊕ delta`` and ``q_b ⊖ q_a`` (MuJoCo's velocity coordinates)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .. import rotations as rot
from ._robot import Robot


class _Layout:
    """Static index sets of a robot (dofs of hinges/slides, of free translations, rotation blocks)."""

    def __init__(self, robot: Robot):
        self.nv = robot.nv
        scalar_dofs, scalar_q, scalar_j, rot_dofs, rot_q, joint_dofs, joint_q = [], [], [], [], [], [], []
        for j, ty in enumerate(robot.jnt_types):
            d, a = robot.jnt_dofadr[j], robot.jnt_qposadr[j]
            if ty in ("hinge", "slide"):
                scalar_dofs.append(d), scalar_q.append(a), scalar_j.append(j)
                joint_dofs.append(d), joint_q.append(a)
            elif ty == "ball":
                rot_dofs.append((d, d + 1, d + 2)), rot_q.append(a)
            else:
                scalar_dofs += [d, d + 1, d + 2]
                scalar_q += [a, a + 1, a + 2]
                scalar_j += [j] * 3
                rot_dofs.append((d + 3, d + 4, d + 5)), rot_q.append(a + 3)
        self.scalar_dofs, self.scalar_q = np.asarray(scalar_dofs, int), np.asarray(scalar_q, int)
        self.scalar_joints = np.asarray(scalar_j, int)
        self.rot_dofs = np.asarray(rot_dofs, int).reshape(-1, 3)
        self.rot_q = np.asarray(rot_q, int)
        self.joint_dofs, self.joint_q = np.asarray(joint_dofs, int), np.asarray(joint_q, int)
        self.bounded = np.asarray([robot.jnt_limited[j] for j in scalar_j], bool)


def _retract(lay: _Layout, rng, q, delta):
    """``q ⊕ delta``, hinges and slides clipped into ``rng`` ``[scalars, 2]``."""
    if lay.scalar_dofs.size:
        q = q.at[lay.scalar_q].set(jnp.clip(q[lay.scalar_q] + delta[lay.scalar_dofs], rng[:, 0], rng[:, 1]))
    if lay.rot_q.size:
        qi = lay.rot_q[:, None] + np.arange(4)
        q = q.at[qi].set(rot.quat_normalize(rot.quat_multiply(q[qi], rot.rotvec_to_quat(delta[lay.rot_dofs]))))
    return q


def _difference(lay: _Layout, qa, qb):
    """``qb ⊖ qa`` ``[nv]``: additive coordinates' difference, rotations' local rotation vector."""
    v = jnp.zeros(qa.shape[:-1] + (lay.nv,), qa.dtype)
    if lay.scalar_dofs.size:
        v = v.at[..., lay.scalar_dofs].set(qb[..., lay.scalar_q] - qa[..., lay.scalar_q])
    if lay.rot_q.size:
        qi = lay.rot_q[:, None] + np.arange(4)
        v = v.at[..., lay.rot_dofs].set(rot.quat_to_rotvec(rot.quat_multiply(rot.quat_conjugate(qa[..., qi]), qb[..., qi])))
    return v


def _free_joint(robot: Robot, body: int) -> int | None:
    """The free joint that moves ``body``: on it or on its nearest ancestor that has one (``None``: none)."""
    while body > 0:
        for j, (t, b) in enumerate(zip(robot.jnt_types, robot.jnt_bodies)):
            if t == "free" and b == body:
                return j
        body = robot.body_parents[body]
    return None
