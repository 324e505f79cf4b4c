"""Rotations in 3-D: unit quaternions, rotation matrices, rotation vectors, Euler angles, 6-D.

Conventions (used by every function here and by the rest of jaxanim):

* **Quaternions are wxyz** (scalar first), ``q = [cos(theta/2), sin(theta/2) * axis]``. ``q`` and
  ``-q`` are the same rotation. scipy (and Pinocchio) store xyzw: convert explicitly at the boundary.
* **Matrices act on column vectors**: ``v_a = R_a_b @ v_b``; composition ``R = R2 @ R1`` applies
  ``R1`` first, and ``quat_multiply(q2, q1)`` is the same composition (Hamilton product).
* **Rotation vectors** (axis-angle, the tangent space of SO(3)) are ``axis * angle`` in radians;
  :func:`rotvec_to_quat` / :func:`rotvec_to_matrix` are the exponential map, :func:`quat_to_rotvec`
  / :func:`matrix_to_rotvec` the logarithm, which returns the shortest vector (angle in [0, pi]).
* **Euler orders** follow scipy: upper case is intrinsic (rotating axes), ``"ZXY"`` with angles
  ``(a, b, c)`` is ``Rz(a) @ Rx(b) @ Ry(c)`` (the BVH channel convention); lower case is extrinsic
  (fixed axes), ``"xyz"`` is ``Rz(c) @ Ry(b) @ Rx(a)``.
* Every function broadcasts over leading ``...`` axes (arguments with different batch shapes are
  broadcast explicitly, numpy style), keeps the floating dtype it is given (integers become the
  default float) and never modifies its inputs. Trailing dimensions are checked in Python and a
  wrong shape raises :class:`~jaxanim.JaxanimError` naming the argument.
* Values **and gradients** are finite at the singular points of the maps (angle 0 and pi for
  exp/log, equal endpoints for slerp, zero-length quaternions): the code uses Taylor branches
  selected with the double-``where`` trick and dtype-dependent thresholds.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from .._errors import JaxanimError, check_float, check_shape
from .._types import Array, ArrayLike, Float

__all__ = [
    "axis_angle_to_quat",
    "perpendicular_basis",
    "euler_to_matrix",
    "euler_to_quat",
    "matrix_to_euler",
    "matrix_to_quat",
    "matrix_to_rotvec",
    "matrix_to_sixd",
    "nlerp",
    "quat_apply",
    "quat_canonical",
    "quat_conjugate",
    "quat_distance",
    "quat_identity",
    "quat_inverse",
    "quat_multiply",
    "quat_normalize",
    "quat_to_axis_angle",
    "quat_to_euler",
    "quat_to_matrix",
    "quat_to_rotvec",
    "rotation_angle",
    "rotation_between",
    "rotvec_to_matrix",
    "rotvec_to_quat",
    "sixd_to_matrix",
    "skew",
    "slerp",
]

# ------------------------------------------------------------------------------------------------
# Private helpers
# ------------------------------------------------------------------------------------------------


def _as_float(name: str, x, trailing: tuple[int, ...]) -> Array:
    """Check the trailing shape and dtype of ``x`` and return it as a floating jax array."""
    check_shape(name, x, trailing, batch=True)
    x = jnp.asarray(x)
    check_float(name, x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


def _as_float_any(name: str, x) -> Array:
    """Like :func:`_as_float` for an argument with no core dimensions (a scalar per batch item)."""
    try:
        x = jnp.asarray(x)
    except (TypeError, ValueError) as exc:
        raise JaxanimError(f"{name}: expected a real floating-point array, got {type(x).__name__}") from exc
    check_float(name, x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


def _broadcast(names: tuple[str, ...], *pairs: tuple[Array, int]) -> list[Array]:
    """Broadcast the batch (leading) axes of several arrays; each pair is ``(array, n_core_dims)``."""
    batches = [x.shape[: x.ndim - k] for x, k in pairs]
    try:
        batch = tuple(np.broadcast_shapes(*batches))
    except ValueError:
        desc = ", ".join(f"{n} {b}" for n, b in zip(names, batches, strict=True))
        raise JaxanimError(f"{', '.join(names)}: batch shapes do not broadcast: {desc}") from None
    out = []
    for (x, k), b in zip(pairs, batches, strict=True):
        out.append(x if b == batch else jnp.broadcast_to(x, batch + x.shape[x.ndim - k :]))
    return out


def _taylor_eps(dtype) -> float:
    """Threshold on a squared angle below which the Taylor branches are used (as jaxlie)."""
    return 1e-10 if jnp.finfo(dtype).bits >= 64 else 1e-5


def _tiny(dtype) -> float:
    """Smallest squared norm that is safe to divide by, gradients included (sqrt of the tiny)."""
    return float(np.sqrt(np.float64(jnp.finfo(dtype).tiny)))


def _cross(a: Array, b: Array) -> Array:
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return jnp.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], axis=-1)


def _dot(a: Array, b: Array) -> Array:
    return jnp.sum(a * b, axis=-1)


def _safe_normalize(x: Array, default: Array) -> tuple[Array, Array]:
    """``x / |x|`` along the last axis, ``default`` where ``|x|`` is (nearly) zero; also the mask."""
    n2 = _dot(x, x)
    ok = n2 > _tiny(x.dtype)
    n = jnp.sqrt(jnp.where(ok, n2, jnp.ones_like(n2)))
    return jnp.where(ok[..., None], x / n[..., None], default), ok


def _perpendicular(u: Array) -> Array:
    """A unit vector perpendicular to the unit (or zero) vector ``u``; ``e_z`` when ``u == 0``."""
    x, y, z = u[..., 0], u[..., 1], u[..., 2]
    zero = jnp.zeros_like(x)
    use_xy = jnp.abs(x) > jnp.abs(z)
    p = jnp.stack([jnp.where(use_xy, -y, zero), jnp.where(use_xy, x, -z), jnp.where(use_xy, zero, y)], axis=-1)
    e_z = jnp.zeros_like(u).at[..., 2].set(1)
    return _safe_normalize(p, e_z)[0]


def _identity_quat_like(x: Array) -> Array:
    return jnp.zeros(x.shape[:-1] + (4,), x.dtype).at[..., 0].set(1)


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


def _skew(v: Array) -> Array:
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    zero = jnp.zeros_like(x)
    flat = jnp.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1)
    return flat.reshape(v.shape[:-1] + (3, 3))


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

    For a slightly non-orthogonal input the result is normalised (like scipy's ``from_matrix``).

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

    ``b1 = a1 / |a1|``, ``b2 = normalise(a2 - (b1 . a2) b1)``, ``b3 = b1 x b2``, ``R = [b1 b2 b3]``.
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
    angle = _as_float_any("angle", angle)
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
# Euler angles
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
    canonicalised (use :func:`quat_canonical` for ``w >= 0``).

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


# ------------------------------------------------------------------------------------------------
# Interpolation and construction
# ------------------------------------------------------------------------------------------------


def _interp_inputs(q0, q1, t) -> tuple[Array, Array, Array]:
    q0, q1, t = _as_float("q0", q0, (4,)), _as_float("q1", q1, (4,)), _as_float_any("t", t)
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
    normalised lerp, so value and gradient are finite for ``q0 == q1`` and any ``t``.

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
    """Normalised linear interpolation along the shortest arc (cheap; not constant speed).

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

    With unit ``a_hat, b_hat`` and ``h = a_hat + b_hat`` the result is the normalisation of
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


def perpendicular_basis(n: Float[Array, "*batch 3"]) -> tuple[Array, Array]:
    """Two unit vectors ``(t1, t2)`` completing the unit vector ``n`` to a right-handed orthonormal
    basis ``(t1, t2, n)``, over leading axes (``t2 = n x t1``)."""
    zero = jnp.zeros_like(n)
    helper = jnp.where(jnp.abs(n[..., :1]) < 0.9, zero.at[..., 0].set(1.0), zero.at[..., 1].set(1.0))
    t1 = jnp.cross(n, helper)
    t1 = t1 / jnp.linalg.norm(t1, axis=-1, keepdims=True)
    return t1, jnp.cross(n, t1)
