"""Pinocchio damped least-squares IK (CLIK) in a Python loop: per iteration the world-axes errors
``[p_k - p(q); log3(R_k R(q)^T)]`` of every frame, stacked ``LOCAL_WORLD_ALIGNED`` Jacobians ``J`` and
``q = integrate(q, J^T (J J^T + lambda I)^{-1} e)``; it stops when every error is under its tolerance."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .pinocchio_peer import PinocchioSkeleton, configurations

__all__ = ["clik_loop", "clik_solve", "configurations", "to_poses"]


def clik_solve(ps: PinocchioSkeleton, q0: np.ndarray, frame_ids: Sequence[int], positions: np.ndarray,
               rotations: np.ndarray, *, damping: float, max_iterations: int, position_tolerance: float,
               orientation_tolerance: float) -> tuple[np.ndarray, int, bool]:
    """One problem: ``q0 [nq]``, targets ``positions [frames, 3]`` / ``rotations [frames, 3, 3]`` (world);
    returns ``(q, iterations, converged)``."""
    pin, model, data = ps.pin, ps.model, ps.data
    lwa = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    n = len(frame_ids)
    e, jac, damp = np.empty(6 * n), np.empty((6 * n, model.nv)), damping * np.eye(6 * n)
    q = np.array(q0, dtype=np.float64)
    for it in range(max_iterations + 1):
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        done = True
        for k, fid in enumerate(frame_ids):
            oMf = data.oMf[fid]
            dp, w = positions[k] - oMf.translation, pin.log3(rotations[k] @ oMf.rotation.T)
            e[6 * k:6 * k + 3], e[6 * k + 3:6 * k + 6] = dp, w
            done = done and dp @ dp < position_tolerance**2 and w @ w < orientation_tolerance**2
        if done:
            return q, it, True
        if it == max_iterations:
            break
        for k, fid in enumerate(frame_ids):
            jac[6 * k:6 * k + 6] = pin.getFrameJacobian(model, data, fid, lwa)
        q = pin.integrate(model, q, jac.T @ np.linalg.solve(jac @ jac.T + damp, e))
    return q, max_iterations, False


def clik_loop(ps: PinocchioSkeleton, q0s: Sequence[np.ndarray], frame_ids: Sequence[int], positions: np.ndarray,
              rotations: np.ndarray, **kwargs: Any) -> tuple[list[np.ndarray], np.ndarray]:
    """:func:`clik_solve` for each problem (the timed call): ``(final configurations, iterations [B])``."""
    out = [clik_solve(ps, q0, frame_ids, positions[b], rotations[b], **kwargs) for b, q0 in enumerate(q0s)]
    return [q for q, _, _ in out], np.array([it for _, it, _ in out], dtype=np.int64)


def to_poses(qs: Sequence[np.ndarray], offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(rotations [B, J, 4] wxyz, translations [B, J, 3])`` of configurations (non-root translations = OFFSETs)."""
    q = np.stack([np.asarray(x, dtype=np.float64) for x in qs])
    b, J = q.shape[0], offsets.shape[0]
    t = np.broadcast_to(np.asarray(offsets, dtype=np.float64), (b, J, 3)).copy()
    t[:, 0] = q[:, :3]
    return q[:, 3:].reshape(b, J, 4)[..., [3, 0, 1, 2]], t
