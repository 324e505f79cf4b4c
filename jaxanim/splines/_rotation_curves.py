"""Rotation curves through unit-quaternion keys: slerp chains and squad (Shoemake), wxyz.

**Hemispheres.** ``q`` and ``-q`` are the same rotation. Before interpolating, the keys are put on
one hemisphere chain by :func:`align_hemispheres` (key ``i`` is negated when its dot product with
the already aligned key ``i - 1`` is negative), so every segment takes the shortest arc and the
output quaternion is continuous in time, not only the rotation. The output may therefore be
``-q_i`` at a key given as ``q_i``: compare rotations up to sign.

**Slerp chain.** On ``[t_i, t_{i+1}]`` with ``u = (t - t_i) / h_i``,
``q(t) = slerp(q_i, q_{i+1}, u) = q_i exp(u d_i)`` with ``d_i = log(q_i^-1 q_{i+1})`` (a rotation
vector; :func:`jaxanim.rotations.slerp`). Constant angular speed per segment, C0 at the keys.

**Squad** (Shoemake 1987). ``q(t) = slerp(slerp(q_i, q_{i+1}, u), slerp(a_i, b_{i+1}, u), 2u(1 - u))``
with inner control quaternions ``a_i = q_i exp(e_i^out)`` and ``b_{i+1} = q_{i+1} exp(e_{i+1}^in)``.
At ``u = 0`` the body angular velocity (rotation vector per unit ``u``) is ``d_i + 2 e_i^out``; at
``u = 1`` it is ``d_i - 2 e_{i+1}^in``. Choosing the key's angular velocity (per unit time, the
rotation analogue of the Catmull-Rom tangent)

    w_i = (d_{i-1} + d_i) / (h_{i-1} + h_i)      (one-sided at the ends: w_0 = d_0 / h_0,
                                                   w_{n-1} = d_{n-2} / h_{n-2})

and solving for it, ``e_i^out = (h_i w_i - d_i) / 2`` and ``e_{i+1}^in = (d_i - h_i w_{i+1}) / 2``,
makes the curve C1 **in time** at every key, also for non-uniform knots. For uniform knots
``e^out = e^in = (d_{i-1} - d_i) / 4``, which is Shoemake's
``a_i = q_i exp(-(log(q_i^-1 q_{i+1}) + log(q_i^-1 q_{i-1})) / 4)`` (there in half-angle
quaternion logs). At the ends ``e = 0``, i.e. ``a_0 = q_0`` and ``b_{n-1} = q_{n-1}``, so two keys
give exactly the slerp, and keys turning at a constant rate about one axis (uniform knots) are
interpolated at that constant rate. (``log(q_i^-1 q_{i-1}) = -d_{i-1}``: the axis of a rotation
is fixed by it, so the vector is the same in the frames of both keys.)

Queries outside ``[t_0, t_{n-1}]`` are clamped (the end keys are held). Every function takes one
curve, ``[n, 4]`` keys; batch joints or curves with ``jax.vmap``.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from .. import rotations as rot
from .._errors import check_shape
from .._types import Array, ArrayLike, Float
from ._curves import _as_float_array, _check_knots, _common_dtype, _locate


def _align(q: Array) -> Array:
    d = jnp.sum(q[1:] * q[:-1], axis=-1)
    flips = jnp.where(d < 0, -jnp.ones_like(d), jnp.ones_like(d))
    sign = jnp.cumprod(jnp.concatenate([jnp.ones((1,), q.dtype), flips]))
    return q * sign[:, None]


_align_jit = eqx.filter_jit(_align)


def _squad_controls(knots: Array, q: Array) -> tuple[Array, Array]:
    """``[n - 1, 4]`` outgoing controls ``a_i`` and ``[n - 1, 4]`` incoming controls ``b_{i+1}``."""
    d = rot.quat_to_rotvec(rot.quat_multiply(rot.quat_conjugate(q[:-1]), q[1:]))  # [n - 1, 3]
    h = jnp.diff(knots)[:, None]
    interior = (d[:-1] + d[1:]) / (h[:-1] + h[1:])
    w = jnp.concatenate([d[:1] / h[:1], interior, d[-1:] / h[-1:]], axis=0)  # [n, 3]
    e_out = 0.5 * (h * w[:-1] - d)
    e_in = 0.5 * (d - h * w[1:])
    a = rot.quat_multiply(q[:-1], rot.rotvec_to_quat(e_out))
    b = rot.quat_multiply(q[1:], rot.rotvec_to_quat(e_in))
    return a, b


@eqx.filter_jit
def _rotation_curve(kind: str, knots: Array, quats: Array, t: Array) -> Array:
    q = _align(rot.quat_normalize(quats))
    i, u, _, _ = _locate(knots, t)
    outer = rot.slerp(q[i], q[i + 1], u)
    if kind == "slerp":
        return outer
    a, b = _squad_controls(knots, q)
    inner = rot.slerp(a[i], b[i], u)
    return rot.slerp(outer, inner, 2.0 * u * (1.0 - u))


def _inputs(knots, quats, t) -> tuple[Array, Array, Array]:
    knots = _check_knots("knots", knots)
    n = knots.shape[0]
    check_shape("quats", quats, (n, 4), what=f"(n, 4) = ({n}, 4) (one wxyz key per knot)")
    quats = _as_float_array("quats", quats)
    t = _as_float_array("t", t)
    dtype = _common_dtype(knots, quats)
    return knots.astype(dtype), quats.astype(dtype), t.astype(dtype)


def align_hemispheres(quats: Float[ArrayLike, "n 4"]) -> Float[Array, "n 4"]:
    """Negate keys so that consecutive keys have a non-negative dot product (same rotations).

    ``q'_0 = q_0`` and ``q'_i = sign(q'_{i-1} . q_i) q_i``: each key moves to the hemisphere of the
    previous aligned key, so the chain is continuous as quaternions and every slerp takes the
    shortest arc.

    Args:
        quats: ``[n, 4]`` unit quaternions, wxyz.

    Returns:
        ``[n, 4]`` the same rotations, sign-aligned along the chain.

    Raises:
        JaxanimError: if ``quats`` is not ``(n, 4)`` or not real.
    """
    check_shape("quats", quats, (None, 4), what="(n, 4)")
    return _align_jit(_as_float_array("quats", quats))


def slerp_spline(
    knots: Float[ArrayLike, " n"], quats: Float[ArrayLike, "n 4"], t: Float[ArrayLike, "*q"]
) -> Float[Array, "*q 4"]:
    """Slerp chain through rotation keys: ``q(t) = slerp(q_i, q_{i+1}, (t - t_i) / h_i)`` on segment ``i``.

    Keys are normalized and sign-aligned first (:func:`align_hemispheres`); queries outside the
    knots hold the end keys.

    Args:
        knots: ``[n]`` strictly increasing key times, ``n >= 2``.
        quats: ``[n, 4]`` unit quaternion keys, wxyz.
        t: ``[*q]`` query times.

    Returns:
        ``[*q, 4]`` unit quaternions, continuous in ``t`` (a key may come back as ``-q_i``).

    Raises:
        JaxanimError: on fewer than 2 knots, knots not strictly increasing, or ``quats`` not ``(n, 4)``.
    """
    return _rotation_curve("slerp", *_inputs(knots, quats, t))


def squad_spline(
    knots: Float[ArrayLike, " n"], quats: Float[ArrayLike, "n 4"], t: Float[ArrayLike, "*q"]
) -> Float[Array, "*q 4"]:
    """Squad through rotation keys (Shoemake's spherical quadrangle, C1 in time at the keys).

    ``q(t) = slerp(slerp(q_i, q_{i+1}, u), slerp(a_i, b_{i+1}, u), 2u(1 - u))`` on segment ``i`` with
    ``u = (t - t_i) / h_i`` and inner controls chosen so that the angular velocity at key ``i`` is
    ``(d_{i-1} + d_i) / (h_{i-1} + h_i)`` from both sides, ``d_i = log(q_i^-1 q_{i+1})`` (see the
    module docstring; for uniform knots these are Shoemake's controls). Keys are hit; two keys give
    the slerp.

    Args:
        knots: ``[n]`` strictly increasing key times, ``n >= 2``.
        quats: ``[n, 4]`` unit quaternion keys, wxyz.
        t: ``[*q]`` query times.

    Returns:
        ``[*q, 4]`` unit quaternions, continuous in ``t`` (a key may come back as ``-q_i``).

    Raises:
        JaxanimError: on fewer than 2 knots, knots not strictly increasing, or ``quats`` not ``(n, 4)``.
    """
    return _rotation_curve("squad", *_inputs(knots, quats, t))
