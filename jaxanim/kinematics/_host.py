"""Forward kinematics of a whole clip on the host, in NumPy: for preparing a retargeting problem and
writing its result, where a compiled program per clip length (or per padded bucket) cost seconds of
XLA compiling for work that NumPy does in milliseconds.

The same frames as :func:`jaxanim.kinematics.forward_kinematics` (``Q_j = Q_parent(j) R_j``,
``p_j = p_parent(j) + Q_parent(j) t_j``), in float64, one step per depth level of the tree, each
vectorised over the frames and the level's joints. No input checks: the callers pass a checked
:class:`~jaxanim.Skeleton` and :class:`~jaxanim.Motion`.
"""

from __future__ import annotations

import numpy as np

from .. import _tree
from ..rotations._numpy import quat_to_matrix
from ..skeleton._skeleton import Skeleton


def clip_frames_host(skeleton: Skeleton, rotations, translations) -> tuple[np.ndarray, np.ndarray]:
    """World rotations and positions of every joint at every frame, in NumPy float64.

    Args:
        skeleton: the tree.
        rotations: ``[T, joints, 4]`` local wxyz quaternions (normalised here, as the JAX kernels do).
        translations: ``[T, joints, 3]`` local translations (``Motion.translations``).

    Returns:
        ``(R [T, joints, 3, 3], p [T, joints, 3])``.
    """
    q = np.asarray(rotations, np.float64)
    t = np.asarray(translations, np.float64)
    R_local = quat_to_matrix(q / np.linalg.norm(q, axis=-1, keepdims=True))
    R, p = np.empty_like(R_local), np.empty_like(t)
    parents = skeleton.parents
    for depth, level in enumerate(_tree.levels(parents)):
        j = np.asarray(level)
        if depth == 0:  # the roots: their local frames are world frames
            R[:, j], p[:, j] = R_local[:, j], t[:, j]
            continue
        par = np.asarray([parents[k] for k in level])
        R[:, j] = R[:, par] @ R_local[:, j]
        p[:, j] = p[:, par] + (R[:, par] @ t[:, j, :, None])[..., 0]
    return R, p
