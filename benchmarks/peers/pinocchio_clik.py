"""Pinocchio damped least-squares IK (closed-loop inverse kinematics, CLIK) in a Python loop.

The peer of the ``ik`` benchmark: the textbook CLIK loop of Pinocchio's examples, on the model of
:func:`benchmarks.peers.pinocchio_peer.build_model` (free flyer + spherical joints; frames named as
jaxanim's sites). For one problem with target placements ``(p_k, R_k)`` of frames ``k``:

1. ``computeJointJacobians(model, data, q)`` (forward kinematics and every joint's Jacobian), then
   ``updateFramePlacements``;
2. the 6D error of each frame in world axes (``LOCAL_WORLD_ALIGNED``): ``e_k = [p_k - p(q);
   log3(R_k R(q)^T)]``, stacked into ``e`` (``6 x frames``); stop when every position error is below
   ``position_tolerance`` and every angle below ``orientation_tolerance``;
3. the stacked frame Jacobians ``J`` (``getFrameJacobian(..., LOCAL_WORLD_ALIGNED)``, ``6 x frames``
   by ``nv``) and the damped least-squares step ``dq = J^T (J J^T + lambda I)^{-1} e``;
4. ``q = integrate(model, q, dq)``; repeat up to ``max_iterations`` times.

The angular rows of a ``LOCAL_WORLD_ALIGNED`` frame Jacobian give the world angular velocity
``omega`` (``dR = [omega]x R``), so ``log3(R_k R^T)`` is the world rotation vector that takes the
frame onto its target, and the linear rows give the frame origin's velocity in world axes: both
parts of ``e`` are in the frame the Jacobian uses. The loop reads positions and rotations out of
Pinocchio every iteration: that copying is part of any Python CLIK loop and is timed.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .pinocchio_peer import PinocchioSkeleton, build_model, configurations, load_pinocchio

__all__ = ["PinocchioSkeleton", "build_model", "clik_loop", "clik_solve", "load_pinocchio", "to_poses"]


def clik_solve(
    ps: PinocchioSkeleton,
    q0: np.ndarray,
    frame_ids: Sequence[int],
    positions: np.ndarray,
    rotations: np.ndarray,
    *,
    damping: float,
    max_iterations: int,
    position_tolerance: float,
    orientation_tolerance: float,
) -> tuple[np.ndarray, int, bool]:
    """Solve one problem by damped least squares (see the module docstring).

    Args:
        ps: the model.
        q0: ``[nq]`` start configuration (Pinocchio's layout, xyzw quaternions).
        frame_ids: Pinocchio frame ids of the targets.
        positions: ``[frames, 3]`` target positions, world.
        rotations: ``[frames, 3, 3]`` target rotations, world.
        damping: ``lambda``.
        max_iterations: the most steps.
        position_tolerance: stop when every position error is below this (file units)...
        orientation_tolerance: ... and every angle below this (rad).

    Returns:
        ``(q [nq], iterations taken, converged)``.
    """
    pin, model, data = ps.pin, ps.model, ps.data
    cjj, ufp, gfj, log3, integrate = (
        pin.computeJointJacobians, pin.updateFramePlacements, pin.getFrameJacobian, pin.log3, pin.integrate
    )
    lwa = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    n = len(frame_ids)
    e = np.empty(6 * n)
    jac = np.empty((6 * n, model.nv))
    damp = damping * np.eye(6 * n)
    q = np.array(q0, dtype=np.float64)
    for it in range(max_iterations + 1):
        cjj(model, data, q)
        ufp(model, data)
        done = True
        for k, fid in enumerate(frame_ids):
            oMf = data.oMf[fid]
            dp = positions[k] - oMf.translation
            w = log3(rotations[k] @ oMf.rotation.T)
            e[6 * k : 6 * k + 3] = dp
            e[6 * k + 3 : 6 * k + 6] = w
            if done and (dp @ dp >= position_tolerance**2 or w @ w >= orientation_tolerance**2):
                done = False
        if done:
            return q, it, True
        if it == max_iterations:
            break
        for k, fid in enumerate(frame_ids):
            jac[6 * k : 6 * k + 6] = gfj(model, data, fid, lwa)
        dq = jac.T @ np.linalg.solve(jac @ jac.T + damp, e)
        q = integrate(model, q, dq)
    return q, max_iterations, False


def clik_loop(
    ps: PinocchioSkeleton,
    q0s: Sequence[np.ndarray],
    frame_ids: Sequence[int],
    positions: np.ndarray,
    rotations: np.ndarray,
    **kwargs: Any,
) -> tuple[list[np.ndarray], np.ndarray]:
    """:func:`clik_solve` for each problem (the timed call).

    Args:
        ps, frame_ids: as for :func:`clik_solve`.
        q0s: start configurations, one per problem.
        positions: ``[B, frames, 3]``.
        rotations: ``[B, frames, 3, 3]``.
        **kwargs: :func:`clik_solve`'s keyword arguments.

    Returns:
        ``(final configurations, iterations [B])``.
    """
    qs, its = [], np.empty(len(q0s), dtype=np.int64)
    for b, q0 in enumerate(q0s):
        q, it, _ = clik_solve(ps, q0, frame_ids, positions[b], rotations[b], **kwargs)
        qs.append(q)
        its[b] = it
    return qs, its


def start_configurations(rotations: np.ndarray, root_translations: np.ndarray) -> list[np.ndarray]:
    """Pinocchio ``q`` of jaxanim poses ``[B, J, 4]`` (wxyz) / ``[B, 3]`` (see :func:`configurations`)."""
    return list(configurations(rotations, root_translations))


def to_poses(qs: Sequence[np.ndarray], offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """jaxanim poses of Pinocchio configurations (xyzw -> wxyz; non-root translations = OFFSETs).

    Args:
        qs: ``B`` configurations ``[nq]``.
        offsets: ``[J, 3]`` the skeleton's OFFSETs.

    Returns:
        ``(rotations [B, J, 4] wxyz, translations [B, J, 3])``, float64.
    """
    q = np.stack([np.asarray(x, dtype=np.float64) for x in qs])
    b, J = q.shape[0], offsets.shape[0]
    xyzw = q[:, 3:].reshape(b, J, 4)
    rot = xyzw[..., [3, 0, 1, 2]]
    t = np.broadcast_to(np.asarray(offsets, dtype=np.float64), (b, J, 3)).copy()
    t[:, 0] = q[:, :3]
    return rot, t
