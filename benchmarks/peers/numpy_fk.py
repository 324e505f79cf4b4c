"""Plain-numpy forward kinematics, vectorized over the batch: the "no JAX at all" baseline and an
independent reference (one Python iteration per joint, batched ``np.matmul`` and ``einsum``; dtype kept)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

__all__ = ["FKArrays", "forward_kinematics"]


class FKArrays(NamedTuple):
    """World ``rotations [B, joints, 3, 3]``, ``positions [B, joints, 3]``, ``end_site_positions`` (naive_fk: no B)."""

    rotations: np.ndarray
    positions: np.ndarray
    end_site_positions: np.ndarray


def forward_kinematics(parents: Sequence[int], end_site_parents: Sequence[int], end_site_offsets: np.ndarray,
                       rotations: np.ndarray, translations: np.ndarray) -> FKArrays:
    """``R_world_j = R_world_parent @ R_parent_j``, ``p_world_j = p_world_parent + R_world_parent @ t_parent_j``
    and End Sites at their joint's transform of their OFFSET (``rotations [B, joints, 3, 3]``, root first)."""
    b, nj = rotations.shape[:2]
    R = np.empty((b, nj, 3, 3), dtype=rotations.dtype)
    p = np.empty((b, nj, 3), dtype=rotations.dtype)
    R[:, 0], p[:, 0] = rotations[:, 0], translations[:, 0]
    for j in range(1, nj):
        Rp = R[:, parents[j]]
        np.matmul(Rp, rotations[:, j], out=R[:, j])
        p[:, j] = p[:, parents[j]] + np.einsum("bij,bj->bi", Rp, translations[:, j])
    idx = np.asarray(end_site_parents, dtype=np.int64)
    ends = p[:, idx] + np.einsum("beij,ej->bei", R[:, idx], np.asarray(end_site_offsets, dtype=rotations.dtype))
    return FKArrays(R, p, ends)
