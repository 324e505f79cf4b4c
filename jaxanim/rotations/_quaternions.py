"""Quaternion algebra on wxyz quaternions: identity, product, conjugate, inverse, normalization,
canonical sign, rotating vectors, angles and distances (conventions: :mod:`jaxanim.rotations._base`).
"""

from __future__ import annotations

import jax.numpy as jnp

from .._types import Array, ArrayLike, Float
from ._base import _as_float, _broadcast, _cross, _dot, _identity_quat_like, _safe_normalize, _tiny


# ------------------------------------------------------------------------------------------------
# Kernels (no input checks)
# ------------------------------------------------------------------------------------------------


def _quat_multiply(q1: Array, q2: Array) -> Array:
    w1, x1, y1, z1 = q1[..., 0], q1[..., 1], q1[..., 2], q1[..., 3]
    w2, x2, y2, z2 = q2[..., 0], q2[..., 1], q2[..., 2], q2[..., 3]
    return jnp.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=-1,
    )


def _quat_conjugate(q: Array) -> Array:
    return jnp.concatenate([q[..., :1], -q[..., 1:]], axis=-1)


def _quat_canonical(q: Array) -> Array:
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    key = jnp.where(w != 0, w, jnp.where(x != 0, x, jnp.where(y != 0, y, z)))
    return jnp.where((key < 0)[..., None], -q, q)


def _quat_normalize(q: Array) -> Array:
    return _safe_normalize(q, _identity_quat_like(q))[0]


def _rotation_angle(q: Array) -> Array:
    v = q[..., 1:]
    n2 = _dot(v, v)
    ok = n2 > _tiny(q.dtype)
    n = jnp.sqrt(jnp.where(ok, n2, jnp.ones_like(n2)))
    return jnp.where(ok, 2.0 * jnp.arctan2(n, jnp.abs(q[..., 0])), jnp.zeros_like(n2))


# ------------------------------------------------------------------------------------------------
# Quaternion algebra
# ------------------------------------------------------------------------------------------------


def quat_identity(shape: int | tuple[int, ...] = (), dtype=None) -> Float[Array, "*shape 4"]:
    """Identity quaternions ``[1, 0, 0, 0]``.

    Args:
        shape: the batch shape; the result has shape ``(*shape, 4)``.
        dtype: a floating dtype; the default float (float64 with x64 enabled) when ``None``.

    Returns:
        ``[*shape, 4]`` identity quaternions, wxyz.
    """
    shape = (shape,) if isinstance(shape, int) else tuple(shape)
    dtype = jnp.result_type(float) if dtype is None else dtype
    return jnp.zeros(shape + (4,), dtype).at[..., 0].set(1)


def quat_multiply(q1: Float[ArrayLike, "*batch 4"], q2: Float[ArrayLike, "*batch 4"]) -> Float[Array, "*batch 4"]:
    """Hamilton product ``q1 q2``: the rotation ``q2`` followed by ``q1``.

    ``quat_to_matrix(quat_multiply(q1, q2)) == quat_to_matrix(q1) @ quat_to_matrix(q2)``.

    Args:
        q1: ``[..., 4]`` quaternions, wxyz (applied second).
        q2: ``[..., 4]`` quaternions, wxyz (applied first); batch axes broadcast against ``q1``.

    Returns:
        ``[..., 4]`` product, wxyz.

    Raises:
        JaxanimError: if a trailing dimension is not 4 or the batch shapes do not broadcast.
    """
    q1 = _as_float("q1", q1, (4,))
    q2 = _as_float("q2", q2, (4,))
    return _quat_multiply(*_broadcast(("q1", "q2"), (q1, 1), (q2, 1)))


def quat_conjugate(q: Float[ArrayLike, "*batch 4"]) -> Float[Array, "*batch 4"]:
    """Conjugate ``[w, -x, -y, -z]``; the inverse rotation for a unit quaternion.

    Args:
        q: ``[..., 4]`` quaternions, wxyz.

    Returns:
        ``[..., 4]`` conjugates.

    Raises:
        JaxanimError: if the trailing dimension is not 4.
    """
    return _quat_conjugate(_as_float("q", q, (4,)))


def quat_inverse(q: Float[ArrayLike, "*batch 4"]) -> Float[Array, "*batch 4"]:
    """Multiplicative inverse ``conj(q) / |q|^2`` (zero for a zero quaternion, never NaN).

    Args:
        q: ``[..., 4]`` quaternions, wxyz, not necessarily unit.

    Returns:
        ``[..., 4]`` inverses, so that ``quat_multiply(q, quat_inverse(q))`` is the identity.

    Raises:
        JaxanimError: if the trailing dimension is not 4.
    """
    q = _as_float("q", q, (4,))
    n2 = _dot(q, q)
    ok = n2 > _tiny(q.dtype)
    inv_n2 = jnp.where(ok, 1.0 / jnp.where(ok, n2, jnp.ones_like(n2)), jnp.zeros_like(n2))
    return _quat_conjugate(q) * inv_n2[..., None]


def quat_normalize(q: Float[ArrayLike, "*batch 4"]) -> Float[Array, "*batch 4"]:
    """Scale to unit norm; a zero (or underflowing) quaternion becomes the identity, not NaN.

    Args:
        q: ``[..., 4]`` quaternions, wxyz.

    Returns:
        ``[..., 4]`` unit quaternions.

    Raises:
        JaxanimError: if the trailing dimension is not 4.
    """
    return _quat_normalize(_as_float("q", q, (4,)))


def quat_canonical(q: Float[ArrayLike, "*batch 4"]) -> Float[Array, "*batch 4"]:
    """Pick the sign of ``q`` (same rotation) with ``w >= 0``; when ``w == 0``, the first nonzero of
    ``x, y, z`` is made positive (scipy's ``as_quat(canonical=True)``).

    Args:
        q: ``[..., 4]`` quaternions, wxyz.

    Returns:
        ``[..., 4]`` ``q`` or ``-q``.

    Raises:
        JaxanimError: if the trailing dimension is not 4.
    """
    return _quat_canonical(_as_float("q", q, (4,)))


def quat_apply(q: Float[ArrayLike, "*batch 4"], v: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 3"]:
    """Rotate vectors: ``R(q) @ v``, i.e. the vector part of ``q [0, v] q*``.

    Uses ``v' = v + s (w t + u x t)`` with ``t = u x v`` and ``s = 2 / |q|^2``, which is exact for
    non-unit quaternions too (it rotates by ``q / |q|``).

    Args:
        q: ``[..., 4]`` quaternions, wxyz.
        v: ``[..., 3]`` vectors; batch axes broadcast against ``q``.

    Returns:
        ``[..., 3]`` rotated vectors.

    Raises:
        JaxanimError: on wrong trailing dimensions or batch shapes that do not broadcast.
    """
    q = _as_float("q", q, (4,))
    v = _as_float("v", v, (3,))
    q, v = _broadcast(("q", "v"), (q, 1), (v, 1))
    w, u = q[..., 0], q[..., 1:]
    n2 = _dot(q, q)
    ok = n2 > _tiny(q.dtype)
    s = jnp.where(ok, 2.0 / jnp.where(ok, n2, jnp.ones_like(n2)), jnp.zeros_like(n2))
    t = _cross(u, v)
    return v + s[..., None] * (w[..., None] * t + _cross(u, t))


def rotation_angle(q: Float[ArrayLike, "*batch 4"]) -> Float[Array, "*batch"]:
    """Rotation angle in ``[0, pi]``: ``2 atan2(|v|, |w|)`` (sign- and scale-invariant).

    Args:
        q: ``[..., 4]`` quaternions, wxyz.

    Returns:
        ``[...]`` angles in radians; gradient finite (zero) at the identity.

    Raises:
        JaxanimError: if the trailing dimension is not 4.
    """
    return _rotation_angle(_as_float("q", q, (4,)))


def quat_distance(q0: Float[ArrayLike, "*batch 4"], q1: Float[ArrayLike, "*batch 4"]) -> Float[Array, "*batch"]:
    """Geodesic distance on SO(3): the angle in ``[0, pi]`` of ``q0^-1 q1`` (sign-invariant).

    Args:
        q0: ``[..., 4]`` quaternions, wxyz.
        q1: ``[..., 4]`` quaternions, wxyz; batch axes broadcast against ``q0``.

    Returns:
        ``[...]`` angles in radians.

    Raises:
        JaxanimError: on wrong trailing dimensions or batch shapes that do not broadcast.
    """
    q0 = _as_float("q0", q0, (4,))
    q1 = _as_float("q1", q1, (4,))
    q0, q1 = _broadcast(("q0", "q1"), (q0, 1), (q1, 1))
    return _rotation_angle(_quat_multiply(_quat_conjugate(q0), q1))
