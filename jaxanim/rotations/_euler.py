"""Euler angles of all 12 orders, intrinsic (upper case) and extrinsic (lower case), to and from
quaternions and matrices; BVH joints may have 0 to 3 rotation channels (conventions:
:mod:`jaxanim.rotations._base`).
"""

from __future__ import annotations

import math

import jax.numpy as jnp

from .._errors import JaxanimError
from .._types import Array, ArrayLike, Float
from ._base import _as_float
from ._matrices import _matrix_to_quat


# ------------------------------------------------------------------------------------------------
# Orders
# ------------------------------------------------------------------------------------------------


_EVEN_PERMUTATIONS = ((0, 1, 2), (1, 2, 0), (2, 0, 1))


def _parse_order(order, *, forward: bool) -> tuple[list[int], bool]:
    """Validate an Euler order string; return its axis indices (x=0) and whether it is extrinsic."""
    if not isinstance(order, str):
        raise JaxanimError(
            f"order: expected a string of axes such as 'ZXY' or 'xyz', got {type(order).__name__} {order!r}"
        )
    if forward:
        ok_len = len(order) <= 3
        need = "0 to 3 axes"
    else:
        ok_len = len(order) == 3
        need = "exactly 3 axes"
    if not ok_len:
        raise JaxanimError(f"order: expected {need}, got {order!r} ({len(order)} axes)")
    if order and not (set(order) <= set("XYZ") or set(order) <= set("xyz")):
        raise JaxanimError(
            f"order: expected axes all from 'XYZ' (intrinsic) or all from 'xyz' (extrinsic), got {order!r}"
        )
    if not forward and (order[0] == order[1] or order[1] == order[2]):
        raise JaxanimError(f"order: consecutive axes must differ (one of the 12 Euler orders), got {order!r}")
    return ["xyz".index(c) for c in order.lower()], order.islower()


def _intrinsic_three(axes: list[int], angles: list[Array], extrinsic: bool):
    """Reduce any sequence of up to 3 elementary rotations to an intrinsic Tait-Bryan or proper
    Euler triple ``(i, j, k)`` with angles, or ``None`` for the empty sequence."""
    if extrinsic:
        axes, angles = axes[::-1], angles[::-1]
    m_axes: list[int] = []
    m_angles: list[Array] = []
    for ax, an in zip(axes, angles, strict=True):
        if m_axes and m_axes[-1] == ax:  # Rx(a) Rx(b) = Rx(a + b)
            m_angles[-1] = m_angles[-1] + an
        else:
            m_axes.append(ax)
            m_angles.append(an)
    if not m_axes:
        return None
    zero = jnp.zeros_like(m_angles[0])
    if len(m_axes) == 1:
        i = m_axes[0]
        m_axes = [i, (i + 1) % 3, (i + 2) % 3]
        m_angles = m_angles + [zero, zero]
    elif len(m_axes) == 2:
        i, j = m_axes
        m_axes = [i, j, 3 - i - j]
        m_angles = m_angles + [zero]
    i, j, k = m_axes
    proper = i == k
    perm = (i, j, 3 - i - j) if proper else (i, j, k)
    odd = perm not in _EVEN_PERMUTATIONS
    # With P e_x = e_i, P e_y = e_j, P e_z = e_k: R_i(a) = P R_x(+-a) P^T, with - when det P = -1.
    if odd:
        m_angles = [-a for a in m_angles]
    return perm, proper, odd, m_angles


def _euler_check(angles, order: str) -> Array:
    _parse_order(order, forward=True)
    return _as_float("angles", angles, (len(order),))


def _euler_reduced(angles: Array, order: str, degrees: bool):
    axes, extrinsic = _parse_order(order, forward=True)
    if degrees:
        angles = angles * (math.pi / 180.0)
    return _intrinsic_three(axes, [angles[..., n] for n in range(len(axes))], extrinsic)


# ------------------------------------------------------------------------------------------------
# Euler angles
# ------------------------------------------------------------------------------------------------


def euler_to_matrix(
    angles: Float[ArrayLike, "*batch n"], order: str, *, degrees: bool = False
) -> Float[Array, "*batch 3 3"]:
    """Rotation matrix from Euler angles.

    Upper-case ``order`` is intrinsic: ``"ZXY"`` gives ``Rz(a) @ Rx(b) @ Ry(c)`` (the product of
    the elementary rotations left to right, the BVH channel convention). Lower case is extrinsic:
    ``"xyz"`` gives ``Rz(c) @ Ry(b) @ Rx(a)``. Any 0 to 3 axes are accepted here (BVH joints may
    have 1 or 2 rotation channels; ``""`` gives the identity); the result is computed in closed form
    (one stack of 9 entries).

    Args:
        angles: ``[..., len(order)]`` angles, radians (degrees if ``degrees``).
        order: static string of axes from ``XYZ`` (intrinsic) or ``xyz`` (extrinsic).
        degrees: whether ``angles`` are in degrees.

    Returns:
        ``[..., 3, 3]`` rotation matrices.

    Raises:
        JaxanimError: on an invalid ``order`` or if the trailing dimension of ``angles`` is not
            ``len(order)``.
    """
    angles = _euler_check(angles, order)
    red = _euler_reduced(angles, order, degrees)
    if red is None:
        return jnp.broadcast_to(jnp.eye(3, dtype=angles.dtype), angles.shape[:-1] + (3, 3))
    perm, proper, _, (a, b, c) = red
    ca, sa, cb, sb, cc, sc = jnp.cos(a), jnp.sin(a), jnp.cos(b), jnp.sin(b), jnp.cos(c), jnp.sin(c)
    if proper:  # Rx(a) Ry(b) Rx(c)
        M = [
            [cb, sb * sc, sb * cc],
            [sa * sb, ca * cc - sa * cb * sc, -ca * sc - sa * cb * cc],
            [-ca * sb, sa * cc + ca * cb * sc, ca * cb * cc - sa * sc],
        ]
    else:  # Rx(a) Ry(b) Rz(c)
        sasb, casb = sa * sb, ca * sb
        M = [
            [cb * cc, -cb * sc, sb],
            [sasb * cc + ca * sc, ca * cc - sasb * sc, -sa * cb],
            [sa * sc - casb * cc, casb * sc + sa * cc, ca * cb],
        ]
    R = [[None] * 3 for _ in range(3)]
    for m in range(3):
        for n in range(3):
            R[perm[m]][perm[n]] = M[m][n]
    flat = jnp.stack([R[r][s] for r in range(3) for s in range(3)], axis=-1)
    return flat.reshape(angles.shape[:-1] + (3, 3))


def euler_to_quat(
    angles: Float[ArrayLike, "*batch n"], order: str, *, degrees: bool = False
) -> Float[Array, "*batch 4"]:
    """Unit quaternion from Euler angles (same conventions as :func:`euler_to_matrix`).

    The result is the product of the elementary quaternions in closed form; its sign is not
    canonicalized (use :func:`quat_canonical` for ``w >= 0``).

    Args:
        angles: ``[..., len(order)]`` angles, radians (degrees if ``degrees``).
        order: static string of 0 to 3 axes from ``XYZ`` (intrinsic) or ``xyz`` (extrinsic).
        degrees: whether ``angles`` are in degrees.

    Returns:
        ``[..., 4]`` unit quaternions, wxyz.

    Raises:
        JaxanimError: on an invalid ``order`` or if the trailing dimension of ``angles`` is not
            ``len(order)``.
    """
    angles = _euler_check(angles, order)
    red = _euler_reduced(angles, order, degrees)
    if red is None:
        return jnp.zeros(angles.shape[:-1] + (4,), angles.dtype).at[..., 0].set(1)
    perm, proper, odd, (a, b, c) = red
    a, b, c = 0.5 * a, 0.5 * b, 0.5 * c
    if proper:  # q_x(a) q_y(b) q_x(c)
        cb, sb = jnp.cos(b), jnp.sin(b)
        p, m = a + c, a - c
        w, v = cb * jnp.cos(p), [cb * jnp.sin(p), sb * jnp.cos(m), sb * jnp.sin(m)]
    else:  # q_x(a) q_y(b) q_z(c)
        ca, sa, cb, sb, cc, sc = jnp.cos(a), jnp.sin(a), jnp.cos(b), jnp.sin(b), jnp.cos(c), jnp.sin(c)
        cacb, sasb, sacb, casb = ca * cb, sa * sb, sa * cb, ca * sb
        w = cacb * cc - sasb * sc
        v = [sacb * cc + casb * sc, casb * cc - sacb * sc, cacb * sc + sasb * cc]
    out = [None] * 3
    for n in range(3):
        out[perm[n]] = -v[n] if odd else v[n]  # P R P^T has quaternion (w, det(P) P v)
    return jnp.stack([w] + out, axis=-1)


def _quat_to_euler(q: Array, order: str) -> Array:
    """Bernardes & Viollet (2022), as scipy's ``as_euler``: radians, wrapped to ``[-pi, pi)``."""
    axes, extrinsic = _parse_order(order, forward=False)
    if not extrinsic:
        axes = axes[::-1]
    i, j, k = axes
    symmetric = i == k
    if symmetric:
        k = 3 - i - j
    sign = float((i - j) * (j - k) * (k - i) // 2)
    qw, qi, qj, qk = q[..., 0], q[..., i + 1], q[..., j + 1], q[..., k + 1]
    if symmetric:
        a, b, c, d = qw, qi, qj, qk * sign
    else:
        a, b, c, d = qw - qj, qi + qk * sign, qj + qw, qk * sign - qi
    half_sum = jnp.arctan2(b, a)
    half_diff = jnp.arctan2(d, c)
    middle = 2.0 * jnp.arctan2(jnp.hypot(c, d), jnp.hypot(a, b))
    # Gimbal lock (middle angle 0 or pi): set the third angle to 0, as scipy (without the warning).
    # scipy flags |middle| <= 1e-7, which costs up to ~1e-7 in the reproduced matrix; a threshold
    # just above round-off still catches exact gimbal lock, and unflagged near-lock angles
    # reproduce the rotation to round-off anyway.
    eps = 16.0 * float(jnp.finfo(q.dtype).eps)
    case1 = jnp.abs(middle) <= eps
    case2 = jnp.abs(middle - math.pi) <= eps
    case0 = ~(case1 | case2)
    zero = jnp.zeros_like(middle)
    a0 = jnp.where(case1, 2.0 * half_sum, 2.0 * half_diff * (-1.0 if extrinsic else 1.0))
    t_sign = 1.0 if symmetric else sign
    if extrinsic:
        first = jnp.where(case0, half_sum - half_diff, a0)
        last = t_sign * jnp.where(case0, half_sum + half_diff, zero)
    else:
        last = jnp.where(case0, half_sum - half_diff, zero)
        first = t_sign * jnp.where(case0, half_sum + half_diff, a0)
    if not symmetric:
        middle = middle - 0.5 * math.pi
    angles = jnp.stack([first, middle, last], axis=-1)
    return jnp.mod(angles + math.pi, 2.0 * math.pi) - math.pi


def quat_to_euler(q: Float[ArrayLike, "*batch 4"], order: str, *, degrees: bool = False) -> Float[Array, "*batch 3"]:
    """Euler angles of a quaternion, inverse of :func:`euler_to_quat` for the 12 Euler orders.

    Follows scipy's ``as_euler`` (Bernardes & Viollet 2022): angles wrapped to ``[-pi, pi)``, the
    middle angle in ``[-pi/2, pi/2]`` (Tait-Bryan) or ``[0, pi]`` (proper Euler; pi wraps to
    -pi). At gimbal lock (middle angle within ``16 eps`` of its singular value; scipy uses 1e-7) the
    third angle is set to 0 and the first absorbs the rotation. The angles reproduce the rotation to
    round-off everywhere, near gimbal lock included, and are never NaN. Scale-invariant in ``q``.

    Args:
        q: ``[..., 4]`` quaternions, wxyz.
        order: one of the 12 orders (``XYZ XZY YXZ YZX ZXY ZYX XYX XZX YXY YZY ZXZ ZYZ``) in upper
            case (intrinsic) or lower case (extrinsic).
        degrees: return degrees instead of radians.

    Returns:
        ``[..., 3]`` angles in the order of ``order``.

    Raises:
        JaxanimError: on an invalid ``order`` or if the trailing dimension of ``q`` is not 4.
    """
    _parse_order(order, forward=False)
    q = _as_float("q", q, (4,))
    out = _quat_to_euler(q, order)
    return out * (180.0 / math.pi) if degrees else out


def matrix_to_euler(
    R: Float[ArrayLike, "*batch 3 3"], order: str, *, degrees: bool = False
) -> Float[Array, "*batch 3"]:
    """Euler angles of a rotation matrix (through :func:`matrix_to_quat`; see :func:`quat_to_euler`).

    Args:
        R: ``[..., 3, 3]`` rotation matrices.
        order: one of the 12 Euler orders, upper case intrinsic or lower case extrinsic.
        degrees: return degrees instead of radians.

    Returns:
        ``[..., 3]`` angles such that ``euler_to_matrix(angles, order)`` reproduces ``R``.

    Raises:
        JaxanimError: on an invalid ``order`` or if the trailing dimensions are not ``(3, 3)``.
    """
    _parse_order(order, forward=False)
    R = _as_float("R", R, (3, 3))
    out = _quat_to_euler(_matrix_to_quat(R), order)
    return out * (180.0 / math.pi) if degrees else out
