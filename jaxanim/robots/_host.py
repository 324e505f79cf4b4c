"""Forward kinematics of many frames on the host, in NumPy: for writing results (a retargeted clip's
body frames, the trainers' formats), where a compiled program per clip length cost seconds of XLA
compiling for work that NumPy does in milliseconds.

The same frames as :func:`jaxanim.robots.forward_kinematics` (MuJoCo's ``mj_kinematics``), in float64,
one loop over the bodies in their order (a parent before its children), each step vectorised over
the frames. No input checks: the callers pass a :class:`~jaxanim.robots.Robot` and a checked ``qpos``.
"""

from __future__ import annotations

import numpy as np

from ..rotations._numpy import quat_exp, quat_to_matrix
from ._robot import Robot


def _unit(q: np.ndarray) -> np.ndarray:
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def body_frames_host(robot: Robot, qpos) -> tuple[np.ndarray, np.ndarray]:
    """World frames of every body at every frame, in NumPy float64.

    Args:
        robot: the robot.
        qpos: ``[T, nq]`` configurations in MuJoCo's layout (as :func:`~jaxanim.robots.forward_kinematics`).

    Returns:
        ``(xpos [T, bodies, 3], xmat [T, bodies, 3, 3])``; body 0 is the world.
    """
    q = np.asarray(qpos, np.float64)
    T, B = q.shape[0], robot.num_bodies
    q0 = np.asarray(robot.qpos0, np.float64)
    body_pos, body_R = np.asarray(robot.body_pos, np.float64), quat_to_matrix(np.asarray(robot.body_quat, np.float64))
    jnt_pos, jnt_axis = np.asarray(robot.jnt_pos, np.float64), np.asarray(robot.jnt_axis, np.float64)
    joints_of: list[list[int]] = [[] for _ in range(B)]
    for j, b in enumerate(robot.jnt_bodies):
        joints_of[b].append(j)
    xpos, xmat = np.zeros((T, B, 3)), np.zeros((T, B, 3, 3))
    xpos[:, 0], xmat[:, 0] = body_pos[0], body_R[0]
    for b in range(1, B):
        kinds = [robot.jnt_types[j] for j in joints_of[b]]
        if "free" in kinds:  # the body's world pose is in qpos
            R, t = np.broadcast_to(np.eye(3), (T, 3, 3)), np.zeros((T, 3))
        else:
            p = robot.body_parents[b]
            R = xmat[:, p] @ body_R[b]
            t = xpos[:, p] + xmat[:, p] @ body_pos[b]
        for j in joints_of[b]:
            a, kind = robot.jnt_qposadr[j], robot.jnt_types[j]
            if kind == "free":
                R_j, t_j = quat_to_matrix(_unit(q[:, a + 3:a + 7])), q[:, a:a + 3]
            elif kind == "slide":
                R_j, t_j = np.broadcast_to(np.eye(3), (T, 3, 3)), (q[:, a] - q0[a])[:, None] * jnt_axis[j]
            else:
                R_j = (quat_to_matrix(_unit(q[:, a:a + 4])) if kind == "ball"
                       else quat_to_matrix(quat_exp((q[:, a] - q0[a])[:, None] * jnt_axis[j])))
                t_j = jnt_pos[j] - R_j @ jnt_pos[j]
            t = t + (R @ t_j[..., None])[..., 0]
            R = R @ R_j
        xpos[:, b], xmat[:, b] = t, R
    return xpos, xmat
