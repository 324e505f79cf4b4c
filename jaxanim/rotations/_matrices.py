"""Rotation matrices: to and from quaternions, the 6-D representation, the cross-product (skew)
matrix and a perpendicular basis (conventions: :mod:`jaxanim.rotations._base`).
"""

from __future__ import annotations

import jax.numpy as jnp

from .._types import Array, ArrayLike, Float
from ._base import _as_float, _cross, _dot, _perpendicular, _safe_normalize, _tiny
from ._quaternions import _quat_canonical


# ------------------------------------------------------------------------------------------------
# Kernels (no input checks)
# ------------------------------------------------------------------------------------------------


def _quat_to_matrix(q: Array) -> Array:
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    n2 = w * w + x * x + y * y + z * z
    ok = n2 > _tiny(q.dtype)
    # s = 2/|q|^2 makes this the matrix of q/|q|; a zero quaternion gives the identity.
    s = jnp.where(ok, 2.0 / jnp.where(ok, n2, jnp.ones_like(n2)), jnp.zeros_like(n2))
    sx, sy, sz = s * x, s * y, s * z
    xx, xy, xz = x * sx, x * sy, x * sz
    yy, yz, zz = y * sy, y * sz, z * sz
    wx, wy, wz = w * sx, w * sy, w * sz
    flat = jnp.stack(
        [
            1.0 - (yy + zz), xy - wz, xz + wy,
            xy + wz, 1.0 - (xx + zz), yz - wx,
            xz - wy, yz + wx, 1.0 - (xx + yy),
        ],
        axis=-1,
    )  # fmt: skip
    return flat.reshape(q.shape[:-1] + (3, 3))


def _matrix_to_quat(R: Array) -> Array:
    r00, r01, r02 = R[..., 0, 0], R[..., 0, 1], R[..., 0, 2]
    r10, r11, r12 = R[..., 1, 0], R[..., 1, 1], R[..., 1, 2]
    r20, r21, r22 = R[..., 2, 0], R[..., 2, 1], R[..., 2, 2]
    # 4 * (w^2, x^2, y^2, z^2) for a rotation matrix; they sum to 4, so the largest is >= 1.
    t0 = 1.0 + r00 + r11 + r22
    t1 = 1.0 + r00 - r11 - r22
    t2 = 1.0 - r00 + r11 - r22
    t3 = 1.0 - r00 - r11 + r22
    d_wx, d_wy, d_wz = r21 - r12, r02 - r20, r10 - r01  # 4 w x, 4 w y, 4 w z
    s_xy, s_xz, s_yz = r10 + r01, r02 + r20, r21 + r12  # 4 x y, 4 x z, 4 y z
    # Shepperd: use the row of the 4x4 outer product q q^T with the largest diagonal entry.
    use_w = (t0 >= t1) & (t0 >= t2) & (t0 >= t3)
    use_x = ~use_w & (t1 >= t2) & (t1 >= t3)
    use_y = ~use_w & ~use_x & (t2 >= t3)

    def pick(cw, cx, cy, cz):
        return jnp.where(use_w, cw, jnp.where(use_x, cx, jnp.where(use_y, cy, cz)))

    c = jnp.stack(
        [
            pick(t0, d_wx, d_wy, d_wz),
            pick(d_wx, t1, s_xy, s_xz),
            pick(d_wy, s_xy, t2, s_yz),
            pick(d_wz, s_xz, s_yz, t3),
        ],
        axis=-1,
    )
    # |c| >= 1 always (even for a non-orthogonal input), so the division is safe.
    q = c / jnp.sqrt(_dot(c, c))[..., None]
    return _quat_canonical(q)


def angle_between_matrices(R: Array, G: Array) -> Array:
    """The angle in ``[0, pi]`` of ``R G^T`` (``[..., 3, 3]`` rotations): ``atan2`` of its skew part's norm
    and its trace, accurate to round-off at every angle (the library's solvers' final checks; a conversion to
    quaternions first, Shepperd's four cases, compiles to kernels that LLVM builds several times longer)."""
    M = sum(R[..., :, c, None] * G[..., None, :, c] for c in range(3))
    sin = 0.5 * jnp.sqrt((M[..., 2, 1] - M[..., 1, 2]) ** 2 + (M[..., 0, 2] - M[..., 2, 0]) ** 2
                         + (M[..., 1, 0] - M[..., 0, 1]) ** 2)
    cos = 0.5 * (M[..., 0, 0] + M[..., 1, 1] + M[..., 2, 2] - 1)
    return jnp.arctan2(sin, cos)


def _skew(v: Array) -> Array:
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    zero = jnp.zeros_like(x)
    flat = jnp.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1)
    return flat.reshape(v.shape[:-1] + (3, 3))


# ------------------------------------------------------------------------------------------------
# Matrices
# ------------------------------------------------------------------------------------------------


def quat_to_matrix(q: Float[ArrayLike, "*batch 4"]) -> Float[Array, "*batch 3 3"]:
    """Rotation matrix of a quaternion (of ``q / |q|``; the identity for a zero quaternion).

    Args:
        q: ``[..., 4]`` quaternions, wxyz, not necessarily unit.

    Returns:
        ``[..., 3, 3]`` rotation matrices acting on column vectors.

    Raises:
        JaxanimError: if the trailing dimension is not 4.
    """
    return _quat_to_matrix(_as_float("q", q, (4,)))


def matrix_to_quat(R: Float[ArrayLike, "*batch 3 3"]) -> Float[Array, "*batch 4"]:
    """Unit quaternion of a rotation matrix (Shepperd's method, branch on the largest of
    ``w^2, x^2, y^2, z^2``, selected with ``jnp.where`` so it is jittable and differentiable).

    For a slightly non-orthogonal input the result is normalized (like scipy's ``from_matrix``).

    Args:
        R: ``[..., 3, 3]`` rotation matrices acting on column vectors.

    Returns:
        ``[..., 4]`` unit quaternions, wxyz, canonical sign (see :func:`quat_canonical`).

    Raises:
        JaxanimError: if the trailing dimensions are not ``(3, 3)``.
    """
    return _matrix_to_quat(_as_float("R", R, (3, 3)))


def matrix_to_sixd(R: Float[ArrayLike, "*batch 3 3"]) -> Float[Array, "*batch 6"]:
    """6-D rotation representation (Zhou et al. 2019): the first two columns of ``R``.

    Args:
        R: ``[..., 3, 3]`` rotation matrices.

    Returns:
        ``[..., 6]`` ``(R[:, 0], R[:, 1])`` concatenated.

    Raises:
        JaxanimError: if the trailing dimensions are not ``(3, 3)``.
    """
    R = _as_float("R", R, (3, 3))
    return jnp.concatenate([R[..., :, 0], R[..., :, 1]], axis=-1)


def sixd_to_matrix(x: Float[ArrayLike, "*batch 6"]) -> Float[Array, "*batch 3 3"]:
    """Rotation matrix from the 6-D representation by Gram-Schmidt (Zhou et al. 2019).

    ``b1 = a1 / |a1|``, ``b2 = normalize(a2 - (b1 . a2) b1)``, ``b3 = b1 x b2``, ``R = [b1 b2 b3]``.
    Degenerate inputs (``a1 = 0``, or ``a2`` parallel to ``a1``) fall back to some valid rotation
    instead of NaN.

    Args:
        x: ``[..., 6]`` two 3-vectors ``(a1, a2)``, not necessarily orthonormal.

    Returns:
        ``[..., 3, 3]`` rotation matrices with columns ``b1, b2, b3``.

    Raises:
        JaxanimError: if the trailing dimension is not 6.
    """
    x = _as_float("x", x, (6,))
    a1, a2 = x[..., :3], x[..., 3:]
    e_x = jnp.zeros_like(a1).at[..., 0].set(1)
    b1, _ = _safe_normalize(a1, e_x)
    u2 = a2 - _dot(b1, a2)[..., None] * b1
    # Relative test so that a2 (numerically) parallel to a1 picks a true perpendicular.
    ok = _dot(u2, u2) > jnp.finfo(x.dtype).eps * _dot(a2, a2)
    b2, _ = _safe_normalize(jnp.where(ok[..., None], u2, jnp.zeros_like(u2)), _perpendicular(b1))
    b3 = _cross(b1, b2)
    return jnp.stack([b1, b2, b3], axis=-1)


def skew(v: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 3 3"]:
    """Cross-product matrix ``[v]x`` with ``[v]x @ u == cross(v, u)``.

    Args:
        v: ``[..., 3]`` vectors.

    Returns:
        ``[..., 3, 3]`` skew-symmetric matrices ``[[0, -z, y], [z, 0, -x], [-y, x, 0]]``.

    Raises:
        JaxanimError: if the trailing dimension is not 3.
    """
    return _skew(_as_float("v", v, (3,)))


def perpendicular_basis(n: Float[Array, "*batch 3"]) -> tuple[Array, Array]:
    """Two unit vectors ``(t1, t2)`` completing the unit vector ``n`` to a right-handed orthonormal
    basis ``(t1, t2, n)``, over leading axes (``t2 = n x t1``)."""
    zero = jnp.zeros_like(n)
    helper = jnp.where(jnp.abs(n[..., :1]) < 0.9, zero.at[..., 0].set(1.0), zero.at[..., 1].set(1.0))
    t1 = jnp.cross(n, helper)
    t1 = t1 / jnp.linalg.norm(t1, axis=-1, keepdims=True)
    return t1, jnp.cross(n, t1)
