"""Rotations in 3-D: the conventions of :mod:`jaxanim.rotations` and the helpers its modules share.

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

import jax.numpy as jnp
import numpy as np

from .._errors import JaxanimError, check_float, check_shape
from .._types import Array


# ------------------------------------------------------------------------------------------------
# Input checks and safe primitives shared by the rotation modules
# ------------------------------------------------------------------------------------------------


def _as_float(name: str, x, trailing: tuple[int, ...]) -> Array:
    """Check the trailing shape and dtype of ``x`` and return it as a floating jax array."""
    check_shape(name, x, trailing, batch=True)
    x = jnp.asarray(x)
    check_float(name, x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


def as_float_any(name: str, x) -> Array:
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
