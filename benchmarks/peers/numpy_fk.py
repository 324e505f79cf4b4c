"""Plain-numpy forward kinematics, vectorised over the batch: the "no JAX at all" baseline.

One Python iteration per joint; each iteration does one batched ``[B,3,3] @ [B,3,3]`` product for
the global rotation and one batched matrix-vector product for the position, so the cost is
``joints`` numpy calls on batch-sized arrays. The forms are the fastest numpy offers for these
shapes (numpy 2.4, batch 4096): ``np.matmul`` for the 3x3 products (~5x faster than
``np.einsum("bij,bjk->bik")``) and ``np.einsum("bij,bj->bi")`` for the matrix-vector products
(~4x faster than ``matmul`` on ``[..., None]``). The dtype of the inputs is kept (float32 stays
float32). It is also an independent reference: it shares no code with jaxanim.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

__all__ = ["NumpyFK", "forward_kinematics", "quat_to_matrix"]


class NumpyFK(NamedTuple):
    """Batched FK result.

    Attributes:
        rotations: ``[B, joints, 3, 3]`` global rotations ``R_world_joint``.
        positions: ``[B, joints, 3]`` global joint positions.
        end_site_positions: ``[B, end_sites, 3]`` global End Site positions.
    """

    rotations: np.ndarray
    positions: np.ndarray
    end_site_positions: np.ndarray


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of wxyz quaternions (normalised first).

    Args:
        q: ``[..., 4]`` quaternions, scalar first (w, x, y, z).

    Returns:
        ``[..., 3, 3]`` rotation matrices acting on column vectors, in the dtype of ``q``.
    """
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    m = np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )
    return m.reshape(q.shape[:-1] + (3, 3)).astype(q.dtype, copy=False)


def forward_kinematics(
    parents: Sequence[int],
    end_site_parents: Sequence[int],
    end_site_offsets: np.ndarray,
    rotations: np.ndarray,
    translations: np.ndarray,
) -> NumpyFK:
    """Global joint transforms of a batch of poses, looping over joints.

    ``R_world_j = R_world_parent @ R_parent_j`` and ``p_world_j = p_world_parent + R_world_parent
    @ t_parent_j``; the root's parent is the world. An End Site sits at its joint's transform applied
    to its OFFSET.

    Args:
        parents: parent index per joint, ``-1`` for the root (joint 0), ``parents[j] < j``.
        end_site_parents: the joint each End Site hangs from.
        end_site_offsets: ``[end_sites, 3]`` End Site OFFSETs in their joint's frame.
        rotations: ``[B, joints, 3, 3]`` local rotations ``R_parent_joint``.
        translations: ``[B, joints, 3]`` local translations ``t_parent_joint`` (file units).

    Returns:
        :class:`NumpyFK` with arrays in the dtype of ``rotations``.
    """
    b, nj = rotations.shape[:2]
    dtype = rotations.dtype
    R = np.empty((b, nj, 3, 3), dtype=dtype)
    p = np.empty((b, nj, 3), dtype=dtype)
    R[:, 0] = rotations[:, 0]
    p[:, 0] = translations[:, 0]
    for j in range(1, nj):
        par = parents[j]
        Rp = R[:, par]
        np.matmul(Rp, rotations[:, j], out=R[:, j])
        p[:, j] = p[:, par] + np.einsum("bij,bj->bi", Rp, translations[:, j])
    off = np.asarray(end_site_offsets, dtype=dtype)
    idx = np.asarray(end_site_parents, dtype=np.int64)
    ends = p[:, idx] + np.einsum("beij,ej->bei", R[:, idx], off)
    return NumpyFK(R, p, ends)
