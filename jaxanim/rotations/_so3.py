"""SO(3) exponential and logarithm (rotation vectors), axis-angle, interpolation (slerp, nlerp) and
the minimal rotation between two directions, and the SO(3) Jacobians of the exponential
(conventions: :mod:`jaxanim.rotations._base`).
"""

from __future__ import annotations

import jax.numpy as jnp

from .._types import Array, ArrayLike, Float
from ._base import (
    _as_float,
    as_float_any,
    _broadcast,
    _cross,
    _dot,
    _identity_quat_like,
    _perpendicular,
    _safe_normalize,
    _taylor_eps,
)
from ._matrices import _matrix_to_quat, _skew
from ._quaternions import _quat_normalize


# ------------------------------------------------------------------------------------------------
# Kernels (no input checks)
# ------------------------------------------------------------------------------------------------


def _rotvec_trig(v: Array) -> tuple[Array, Array, Array]:
    """``theta^2``, ``cos(theta/2)`` and ``sin(theta/2)/theta`` for ``theta = |v|``, gradient-safe."""
    theta2 = _dot(v, v)
    small = theta2 < _taylor_eps(v.dtype)
    theta = jnp.sqrt(jnp.where(small, jnp.ones_like(theta2), theta2))
    half = 0.5 * theta
    cos_half = jnp.where(small, 1.0 - theta2 / 8.0 + theta2 * theta2 / 384.0, jnp.cos(half))
    sinc_half = jnp.where(small, 0.5 - theta2 / 48.0 + theta2 * theta2 / 3840.0, jnp.sin(half) / theta)
    return theta2, cos_half, sinc_half


def _rotvec_to_quat(v: Array) -> Array:
    _, cos_half, sinc_half = _rotvec_trig(v)
    return jnp.concatenate([cos_half[..., None], sinc_half[..., None] * v], axis=-1)


def _quat_to_rotvec(q: Array) -> Array:
    flip = q[..., 0] < 0
    q = jnp.where(flip[..., None], -q, q)  # w >= 0: the shortest rotation vector
    w, v = q[..., 0], q[..., 1:]
    n2 = _dot(v, v)
    small = n2 <= _taylor_eps(q.dtype) * (w * w)
    # Taylor: 2 atan(n / w) / n = (2 / w) (1 - r / 3 + r^2 / 5), r = n^2 / w^2.
    w_t = jnp.where(small & (w > 0), w, jnp.ones_like(w))
    r = n2 / (w_t * w_t)
    taylor = 2.0 / w_t * (1.0 - r / 3.0 + r * r / 5.0)
    n = jnp.sqrt(jnp.where(small, jnp.ones_like(n2), n2))
    direct = 2.0 * jnp.arctan2(n, w) / n
    factor = jnp.where(small, taylor, direct)
    return factor[..., None] * v


# ------------------------------------------------------------------------------------------------
# Exponential and logarithm
# ------------------------------------------------------------------------------------------------


def rotvec_to_quat(v: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 4"]:
    """Exponential map: rotation vector ``axis * angle`` to unit quaternion
    ``[cos(theta/2), sin(theta/2) / theta * v]``.

    Finite value and gradient at ``v = 0`` (Taylor branch) and at any angle.

    Args:
        v: ``[..., 3]`` rotation vectors, radians.

    Returns:
        ``[..., 4]`` unit quaternions, wxyz (``w < 0`` for angles above pi).

    Raises:
        JaxanimError: if the trailing dimension is not 3.
    """
    return _rotvec_to_quat(_as_float("v", v, (3,)))


def quat_to_rotvec(q: Float[ArrayLike, "*batch 4"]) -> Float[Array, "*batch 3"]:
    """Logarithm: quaternion to the shortest rotation vector (angle in ``[0, pi]``).

    ``q`` and ``-q`` give the same result (except at exactly pi, where both ``+-pi * axis`` are
    shortest). Scale-invariant; finite value and gradient at angle 0 and pi.

    Args:
        q: ``[..., 4]`` quaternions, wxyz.

    Returns:
        ``[..., 3]`` rotation vectors ``axis * angle``, radians.

    Raises:
        JaxanimError: if the trailing dimension is not 4.
    """
    return _quat_to_rotvec(_as_float("q", q, (4,)))


def rotvec_to_matrix(v: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 3 3"]:
    """Exponential map to a matrix (Rodrigues): ``R = I + A [v]x + B [v]x^2`` with
    ``A = sin(theta) / theta`` and ``B = (1 - cos(theta)) / theta^2 = 2 (sin(theta/2) / theta)^2``.

    Finite value and gradient at ``v = 0`` (Taylor branch).

    Args:
        v: ``[..., 3]`` rotation vectors, radians.

    Returns:
        ``[..., 3, 3]`` rotation matrices.

    Raises:
        JaxanimError: if the trailing dimension is not 3.
    """
    v = _as_float("v", v, (3,))
    theta2, cos_half, sinc_half = _rotvec_trig(v)
    A = 2.0 * cos_half * sinc_half  # sin(theta) / theta
    B = 2.0 * sinc_half * sinc_half
    C = 1.0 - B * theta2  # cos(theta), accurate near 0 and pi
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    Bx, By, Bz = B * x, B * y, B * z
    Ax, Ay, Az = A * x, A * y, A * z
    flat = jnp.stack(
        [
            C + Bx * x, Bx * y - Az, Bx * z + Ay,
            Bx * y + Az, C + By * y, By * z - Ax,
            Bx * z - Ay, By * z + Ax, C + Bz * z,
        ],
        axis=-1,
    )  # fmt: skip
    return flat.reshape(v.shape[:-1] + (3, 3))


def matrix_to_rotvec(R: Float[ArrayLike, "*batch 3 3"]) -> Float[Array, "*batch 3"]:
    """Logarithm of a rotation matrix: the shortest rotation vector (angle in ``[0, pi]``).

    Goes through :func:`matrix_to_quat` (robust at pi, where ``R - R^T`` vanishes) and
    :func:`quat_to_rotvec`.

    Args:
        R: ``[..., 3, 3]`` rotation matrices.

    Returns:
        ``[..., 3]`` rotation vectors, radians.

    Raises:
        JaxanimError: if the trailing dimensions are not ``(3, 3)``.
    """
    R = _as_float("R", R, (3, 3))
    return _quat_to_rotvec(_matrix_to_quat(R))


def axis_angle_to_quat(
    axis: Float[ArrayLike, "*batch 3"], angle: Float[ArrayLike, "*batch"]
) -> Float[Array, "*batch 4"]:
    """Quaternion ``[cos(angle/2), sin(angle/2) * axis / |axis|]``.

    Args:
        axis: ``[..., 3]`` rotation axes, need not be unit; a zero axis gives the identity.
        angle: ``[...]`` angles in radians; batch axes broadcast against ``axis``.

    Returns:
        ``[..., 4]`` unit quaternions, wxyz.

    Raises:
        JaxanimError: on a wrong trailing dimension or batch shapes that do not broadcast.
    """
    axis = _as_float("axis", axis, (3,))
    angle = as_float_any("angle", angle)
    axis, angle = _broadcast(("axis", "angle"), (axis, 1), (angle, 0))
    u, ok = _safe_normalize(axis, jnp.zeros_like(axis))
    half = 0.5 * angle
    w = jnp.where(ok, jnp.cos(half), jnp.ones_like(half))
    return jnp.concatenate([w[..., None], jnp.sin(half)[..., None] * u], axis=-1)


def quat_to_axis_angle(q: Float[ArrayLike, "*batch 4"]) -> tuple[Float[Array, "*batch 3"], Float[Array, "*batch"]]:
    """Unit axis and angle in ``[0, pi]`` (the sign of ``q`` is chosen with ``w >= 0``).

    At the identity the axis is undefined and ``[1, 0, 0]`` is returned with angle 0.

    Args:
        q: ``[..., 4]`` quaternions, wxyz.

    Returns:
        ``(axis, angle)``: ``[..., 3]`` unit axes and ``[...]`` angles in radians.

    Raises:
        JaxanimError: if the trailing dimension is not 4.
    """
    q = _as_float("q", q, (4,))
    q = jnp.where((q[..., 0] < 0)[..., None], -q, q)
    v = q[..., 1:]
    e_x = jnp.zeros_like(v).at[..., 0].set(1)
    axis, ok = _safe_normalize(v, e_x)
    n2 = _dot(v, v)
    n = jnp.sqrt(jnp.where(ok, n2, jnp.ones_like(n2)))
    angle = jnp.where(ok, 2.0 * jnp.arctan2(n, q[..., 0]), jnp.zeros_like(n2))
    return axis, angle


# ------------------------------------------------------------------------------------------------
# Interpolation and construction
# ------------------------------------------------------------------------------------------------


def _interp_inputs(q0, q1, t) -> tuple[Array, Array, Array]:
    q0, q1, t = _as_float("q0", q0, (4,)), _as_float("q1", q1, (4,)), as_float_any("t", t)
    q0, q1, t = _broadcast(("q0", "q1", "t"), (q0, 1), (q1, 1), (t, 0))
    # Shortest path: q1 and -q1 are the same rotation; take the one in q0's hemisphere. Rotations
    # 180 degrees apart (q0 . q1 = 0) have two shortest paths; a margin above round-off keeps q1 as
    # given there, so the choice does not depend on how the dot product was rounded (jit, FMA).
    flip = _dot(q0, q1) < -16.0 * jnp.finfo(q0.dtype).eps
    q1 = jnp.where(flip[..., None], -q1, q1)
    return q0, q1, t


def _nlerp(q0: Array, q1: Array, t: Array) -> Array:
    return _quat_normalize((1.0 - t)[..., None] * q0 + t[..., None] * q1)


def slerp(
    q0: Float[ArrayLike, "*batch 4"], q1: Float[ArrayLike, "*batch 4"], t: Float[ArrayLike, "*batch"]
) -> Float[Array, "*batch 4"]:
    """Spherical linear interpolation along the shortest arc (constant angular speed).

    ``q(t) = sin((1 - t) W) / sin(W) q0 + sin(t W) / sin(W) q1`` with ``W`` the angle between
    ``q0`` and ``q1`` in R^4, computed as ``2 atan2(|q1 - q0|, |q1 + q0|)``; ``q1`` is negated first
    when ``q0 . q1 < 0``. Rotations 180 degrees apart (``q0 . q1 == 0`` up to round-off) have two
    shortest paths: ``q1`` is then used as given. For nearly equal quaternions it falls back to
    normalized lerp, so value and gradient are finite for ``q0 == q1`` and any ``t``.

    Args:
        q0: ``[..., 4]`` unit quaternions at ``t = 0``, wxyz.
        q1: ``[..., 4]`` unit quaternions at ``t = 1``.
        t: ``[...]`` interpolation parameters (usually in [0, 1]); all batch axes broadcast.

    Returns:
        ``[..., 4]`` unit quaternions (``q0`` at ``t = 0``, ``+-q1`` at ``t = 1``).

    Raises:
        JaxanimError: on wrong trailing dimensions or batch shapes that do not broadcast.
    """
    q0, q1, t = _interp_inputs(q0, q1, t)
    d, s = q1 - q0, q1 + q0
    a2, b2 = _dot(d, d), _dot(s, s)
    small = a2 < _taylor_eps(q0.dtype)
    ones = jnp.ones_like(a2)
    omega = 2.0 * jnp.arctan2(jnp.sqrt(jnp.where(small, ones, a2)), jnp.sqrt(jnp.where(small, ones, b2)))
    inv_sin = 1.0 / jnp.sin(omega)
    c0 = jnp.sin((1.0 - t) * omega) * inv_sin
    c1 = jnp.sin(t * omega) * inv_sin
    spherical = c0[..., None] * q0 + c1[..., None] * q1
    return jnp.where(small[..., None], _nlerp(q0, q1, t), spherical)


def nlerp(
    q0: Float[ArrayLike, "*batch 4"], q1: Float[ArrayLike, "*batch 4"], t: Float[ArrayLike, "*batch"]
) -> Float[Array, "*batch 4"]:
    """Normalized linear interpolation along the shortest arc (cheap; not constant speed).

    Args:
        q0: ``[..., 4]`` unit quaternions at ``t = 0``, wxyz.
        q1: ``[..., 4]`` unit quaternions at ``t = 1`` (negated when ``q0 . q1 < 0``).
        t: ``[...]`` interpolation parameters; all batch axes broadcast.

    Returns:
        ``[..., 4]`` unit quaternions.

    Raises:
        JaxanimError: on wrong trailing dimensions or batch shapes that do not broadcast.
    """
    return _nlerp(*_interp_inputs(q0, q1, t))


def rotation_between(a: Float[ArrayLike, "*batch 3"], b: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 4"]:
    """Quaternion of the minimal rotation taking the direction of ``a`` to the direction of ``b``.

    With unit ``a_hat, b_hat`` and ``h = a_hat + b_hat`` the result is the normalization of
    ``[|h|^2 / 2, a_hat x h]`` (= ``[1 + cos, sin * axis]``, accurate near both 0 and pi). For
    antiparallel vectors (within ``sqrt(eps)``) it is the rotation by pi about an axis
    perpendicular to ``a``. A zero ``a`` or ``b`` gives the identity. Gradients are finite away
    from the antiparallel case.

    Args:
        a: ``[..., 3]`` vectors, need not be unit.
        b: ``[..., 3]`` vectors; batch axes broadcast against ``a``.

    Returns:
        ``[..., 4]`` unit quaternions, wxyz, with ``w >= 0``.

    Raises:
        JaxanimError: on wrong trailing dimensions or batch shapes that do not broadcast.
    """
    a = _as_float("a", a, (3,))
    b = _as_float("b", b, (3,))
    a, b = _broadcast(("a", "b"), (a, 1), (b, 1))
    zeros = jnp.zeros_like(a)
    ua, ok_a = _safe_normalize(a, zeros)
    ub, ok_b = _safe_normalize(b, zeros)
    h = ua + ub
    w = 0.5 * _dot(h, h)
    v = _cross(ua, h)
    n2 = w * w + _dot(v, v)
    anti = n2 < jnp.finfo(a.dtype).eps
    n = jnp.sqrt(jnp.where(anti, jnp.ones_like(n2), n2))
    q = jnp.concatenate([w[..., None], v], axis=-1) / n[..., None]
    q_anti = jnp.concatenate([jnp.zeros_like(w)[..., None], _perpendicular(ua)], axis=-1)
    q = jnp.where(anti[..., None], q_anti, q)
    return jnp.where((ok_a & ok_b)[..., None], q, _identity_quat_like(q))


# ------------------------------------------------------------------------------------------------
# SO(3) Jacobians of the exponential (IK's exact Jacobians in exponential coordinates)
# ------------------------------------------------------------------------------------------------


def _skew_square(v: Array) -> Array:
    """``skew(v) @ skew(v) = v v^T - |v|^2 I``, elementwise (no batch of tiny dots under vmap)."""
    eye = jnp.broadcast_to(jnp.eye(3, dtype=v.dtype), v.shape + (3,))
    return v[..., :, None] * v[..., None, :] - jnp.sum(v * v, axis=-1)[..., None, None] * eye


def _left_jacobian(phi: Array) -> Array:
    th2 = jnp.sum(phi * phi, axis=-1)
    small = th2 < 1e-8
    th2s = jnp.where(small, 1.0, th2)
    th = jnp.sqrt(th2s)
    a = jnp.where(small, 0.5 - th2 / 24.0, (1.0 - jnp.cos(th)) / th2s)
    b = jnp.where(small, 1.0 / 6.0 - th2 / 120.0, (th - jnp.sin(th)) / (th2s * th))
    eye = jnp.broadcast_to(jnp.eye(3, dtype=phi.dtype), phi.shape + (3,))
    return eye + a[..., None, None] * _skew(phi) + b[..., None, None] * _skew_square(phi)


def _left_jacobian_inverse(phi: Array) -> Array:
    th2 = jnp.sum(phi * phi, axis=-1)
    small = th2 < 1e-8
    th2s = jnp.where(small, 1.0, th2)
    th = jnp.sqrt(th2s)
    c = jnp.where(small, 1.0 / 12.0 + th2 / 720.0, (1.0 / th2s) - (1.0 + jnp.cos(th)) / (2.0 * th * jnp.sin(th)))
    eye = jnp.broadcast_to(jnp.eye(3, dtype=phi.dtype), phi.shape + (3,))
    return eye - 0.5 * _skew(phi) + c[..., None, None] * _skew_square(phi)


def left_jacobian(phi: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 3 3"]:
    """SO(3) left Jacobian ``J_l(phi) = I + a K + b K^2`` (``K = skew(phi)``, a Taylor branch at 0):
    ``exp(phi + d) = exp(J_l(phi) d) exp(phi)`` to first order.

    Args:
        phi: ``[..., 3]`` rotation vectors.

    Returns:
        ``[..., 3, 3]``.
    """
    return _left_jacobian(_as_float("phi", phi, (3,)))


def right_jacobian(phi: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 3 3"]:
    """SO(3) right Jacobian ``J_r(phi) = J_l(-phi)``: ``exp(phi + d) = exp(phi) exp(J_r(phi) d)`` to
    first order (``[..., 3]`` -> ``[..., 3, 3]``)."""
    return _left_jacobian(-_as_float("phi", phi, (3,)))


def left_jacobian_inverse(phi: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 3 3"]:
    """``J_l(phi)^{-1} = I - K/2 + c K^2`` (a Taylor branch at 0; valid for ``|phi| < 2 pi``):
    ``log(exp(d) exp(phi)) = phi + J_l(phi)^{-1} d`` to first order (``[..., 3]`` -> ``[..., 3, 3]``)."""
    return _left_jacobian_inverse(_as_float("phi", phi, (3,)))
