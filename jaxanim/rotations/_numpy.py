"""Host-side NumPy kernels on wxyz quaternions, for preprocessing that runs once outside JAX (the
matching database's features, the robots' frames of a written result) and for the benchmarks' NumPy
peers. Same conventions as the JAX kernels (:mod:`jaxanim.rotations._base`); no input checks."""

from __future__ import annotations

import numpy as np


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The Hamilton product ``a b`` of ``[..., 4]`` quaternions."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def quat_conj(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_exp(v: np.ndarray) -> np.ndarray:
    """``[..., 4]`` wxyz unit quaternions of ``[..., 3]`` rotation vectors, exact at and near zero:
    ``w = cos(a/2)``, ``xyz = v sin(a/2)/a`` with ``sin(a/2)/a = sinc(a/2pi)/2`` (NumPy's sinc)."""
    angle = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.concatenate([np.cos(0.5 * angle), v * (0.5 * np.sinc(angle / (2.0 * np.pi)))], axis=-1)


def quat_log(q: np.ndarray) -> np.ndarray:
    """Rotation vector of unit quaternions (shortest arc)."""
    q = np.where(q[..., :1] < 0, -q, q)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    scale = np.where(s > 1e-12, angle / np.where(s > 1e-12, s, 1.0), 2.0)
    return v * scale


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """``[..., 3, 3]`` rotation matrices of unit quaternions."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1
                    ).reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """``[..., 4]`` wxyz unit quaternions of ``[..., 3, 3]`` rotation matrices, ``w >= 0`` (Shepperd's
    method: the largest of the four squared components first)."""
    m = np.asarray(R, np.float64)
    tr = np.trace(m, axis1=-2, axis2=-1)
    w = np.stack([1.0 + tr, 1.0 + 2.0 * m[..., 0, 0] - tr, 1.0 + 2.0 * m[..., 1, 1] - tr,
                  1.0 + 2.0 * m[..., 2, 2] - tr], axis=-1)  # 4 x each squared component
    k = np.argmax(w, axis=-1)
    s = np.sqrt(np.maximum(np.take_along_axis(w, k[..., None], axis=-1)[..., 0], 1e-300))
    a, b, c = m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]
    e, f, g = m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 2] + m[..., 2, 1]
    cases = np.stack([np.stack([s * s, a, b, c], -1), np.stack([a, s * s, e, f], -1),
                      np.stack([b, e, s * s, g], -1), np.stack([c, f, g, s * s], -1)], axis=-2)
    q = np.take_along_axis(cases, k[..., None, None], axis=-2)[..., 0, :] / (2.0 * s[..., None])
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)
