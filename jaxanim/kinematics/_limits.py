"""Joint limits: boxes on Euler angles, or a swing cone plus a twist range.

A limit constrains the **local** rotation ``R_j`` of one joint (the rotation FK applies in the
parent's frame; the identity is the skeleton's rest pose), so for a BVH clip an :class:`EulerLimit`
in the joint's own channel order bounds exactly the angles written in the file.

* :class:`EulerLimit` ``(joint, lower, upper, order)``: ``R_j = Euler(theta, order)`` for some
  ``theta`` with ``lower <= theta <= upper`` (radians, or degrees with ``degrees=True``). A rotation
  has two Euler triples (and ``2 pi`` wraps); it satisfies the box if any of them lies in it.
* :class:`SwingTwistLimit` ``(joint, swing, twist, axis)``: ``R_j = R_swing R_twist`` where
  ``R_twist`` turns by ``tau`` about the twist ``axis`` (default: the bone, i.e. the direction of the
  joint's first child or End Site) and ``R_swing`` turns by the rotation vector
  ``s1 b1 + s2 b2`` perpendicular to it; the limit is the elliptical cone
  ``(s1 / swing[0])^2 + (s2 / swing[1])^2 <= 1`` and ``twist[0] <= tau <= twist[1]``.
  ``b1 = normalize(e x axis)`` with ``e`` the coordinate axis least aligned with ``axis`` and
  ``b2 = axis x b1``.

How :func:`jaxanim.ik.solve_ik` uses them. A limited joint is written in coordinates in which its
limit is a box, so the bounded solver enforces it **exactly** at every iterate (hard limits):
Euler angles for an Euler limit; for a swing-twist limit ``(u, v, tau)`` in
``[-1, 1]^2 x [twist]``, mapped onto the elliptical cone by the elliptical grid map
``(x, y) = (u sqrt(1 - v^2/2), v sqrt(1 - u^2/2))``, ``s = (swing[0] x, swing[1] y)`` (smooth and
one-to-one from the square onto the disc; singular only at the square's four corners). As soft
penalties the same joints use Euler angles / ``(s1, s2, tau)`` without bounds and add the residual
``sqrt(weight)`` times the distance outside the limit (radians). :func:`limit_violation` measures
how far a pose is outside each limit, independently of those coordinates.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import rotations as rot
from .._errors import JaxanimError, check_shape
from .._linalg import dot
from .._types import Array, Float
from ..skeleton._skeleton import Skeleton

__all__ = ["EulerLimit", "SwingTwistLimit", "limit_violation"]

_TAIT_BRYAN = {"XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"}
_PROPER = {"XYX", "XZX", "YXY", "YZY", "ZXZ", "ZYZ"}


def _traced(*xs) -> bool:
    return any(isinstance(x, jax.core.Tracer) for x in xs)


class EulerLimit(eqx.Module):
    """A box on the Euler angles of one joint's local rotation.

    Attributes:
        joint: the joint's name. Static.
        lower: ``[3]`` lower bounds, radians, in the order of ``order``.
        upper: ``[3]`` upper bounds, radians (``upper - lower <= 2 pi``).
        order: static Euler order (upper case intrinsic, lower case extrinsic, see
            :func:`jaxanim.rotations.euler_to_matrix`); ``None``: the joint's BVH rotation channel
            order, so the bounds apply to the angles written in the file.
    """

    joint: str = eqx.field(static=True)
    lower: Float[Array, "3"]
    upper: Float[Array, "3"]
    order: str | None = eqx.field(static=True)

    def __init__(self, joint: str, lower, upper, order: str | None = None, *, degrees: bool = False):
        check_shape(f"limits[{joint!r}].lower", lower, (3,))
        check_shape(f"limits[{joint!r}].upper", upper, (3,))
        scale = math.pi / 180.0 if degrees else 1.0
        self.joint = str(joint)
        self.lower = jnp.asarray(lower, dtype=float) * scale
        self.upper = jnp.asarray(upper, dtype=float) * scale
        self.order = order
        if order is not None and order.upper() not in _TAIT_BRYAN | _PROPER:
            raise JaxanimError(f"limits[{joint!r}].order: expected one of the 12 Euler orders, got {order!r}")
        if _traced(self.lower, self.upper):  # built inside jit / vmap: values checked by the caller
            return
        lo, hi = np.asarray(self.lower), np.asarray(self.upper)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise JaxanimError(f"limits[{joint!r}]: bounds must be finite")
        if np.any(lo > hi) or np.any(hi - lo > 2 * math.pi + 1e-12):
            raise JaxanimError(f"limits[{joint!r}]: expected lower <= upper <= lower + 2 pi, got {lo} and {hi}")


class SwingTwistLimit(eqx.Module):
    """A swing cone and a twist range for one joint's local rotation (``R = R_swing R_twist``).

    Attributes:
        joint: the joint's name. Static.
        swing: ``[2]`` half-angles of the elliptical cone about ``b1`` and ``b2`` (radians, in
            ``(0, pi)``); a scalar gives a circular cone.
        twist: ``[2]`` ``(lower, upper)`` twist range about ``axis`` (radians, within ``[-pi, pi]``).
        axis: ``[3]`` unit twist axis in the joint's frame, or ``None`` for the bone direction.
    """

    joint: str = eqx.field(static=True)
    swing: Float[Array, "2"]
    twist: Float[Array, "2"]
    axis: Float[Array, "3"] | None

    def __init__(self, joint: str, swing, twist=(-math.pi, math.pi), axis=None, *, degrees: bool = False):
        scale = math.pi / 180.0 if degrees else 1.0
        swing = jnp.broadcast_to(jnp.asarray(swing, dtype=float), (2,)) if np.ndim(swing) == 0 else swing
        check_shape(f"limits[{joint!r}].swing", swing, (2,))
        check_shape(f"limits[{joint!r}].twist", twist, (2,))
        self.joint = str(joint)
        self.swing = jnp.asarray(swing, dtype=float) * scale
        self.twist = jnp.asarray(twist, dtype=float) * scale
        if _traced(self.swing, self.twist, axis):
            self.axis = None if axis is None else jnp.asarray(axis) / jnp.linalg.norm(jnp.asarray(axis))
            return
        sw, tw = np.asarray(self.swing), np.asarray(self.twist)
        if not (np.all(sw > 0) and np.all(sw < math.pi)):
            raise JaxanimError(f"limits[{joint!r}].swing: expected angles in (0, pi), got {sw}")
        if not (-math.pi - 1e-12 <= tw[0] <= tw[1] <= math.pi + 1e-12):
            raise JaxanimError(f"limits[{joint!r}].twist: expected -pi <= lower <= upper <= pi, got {tw}")
        if axis is not None:
            check_shape(f"limits[{joint!r}].axis", axis, (3,))
            a = np.asarray(axis, dtype=float)
            if not np.linalg.norm(a) > 0:
                raise JaxanimError(f"limits[{joint!r}].axis: expected a non-zero vector")
            axis = jnp.asarray(a / np.linalg.norm(a))
        self.axis = axis


Limit = EulerLimit | SwingTwistLimit


# --------------------------------------------------------------------------------------------
# Resolution against a skeleton (static data: joint index, order, twist axis).
# --------------------------------------------------------------------------------------------


def bone_axis(skeleton: Skeleton, j: int) -> np.ndarray:
    """The unit direction of joint ``j``'s bone in its own frame: its first child's (or End Site's)
    non-zero offset (internal interface: also used by :mod:`jaxanim.ik`)."""
    offsets = np.asarray(skeleton.offsets)
    cands = [offsets[c] for c in range(skeleton.num_joints) if skeleton.parents[c] == j]
    cands += [np.asarray(skeleton.end_site_offsets)[e] for e, p in enumerate(skeleton.end_site_parents) if p == j]
    for c in cands:
        n = np.linalg.norm(c)
        if n > 0:
            return c / n
    raise JaxanimError(
        f"limits[{skeleton.names[j]!r}]: the joint has no child bone to take the twist axis from; pass axis="
    )


def _basis(axis: Array) -> tuple[Array, Array]:
    """``b1, b2`` completing the twist axis to a right-handed frame (see the module docstring)."""
    k = jnp.argmin(jnp.abs(axis))
    e = jnp.zeros(3, axis.dtype).at[k].set(1)
    b1 = jnp.cross(e, axis)
    b1 = b1 / jnp.linalg.norm(b1)
    return b1, jnp.cross(axis, b1)


def resolve_limits(skeleton: Skeleton, limits: Sequence[Limit]) -> tuple[int, ...]:
    """Joint index of each limit; checks names, orders and duplicates (static, before tracing)."""
    if isinstance(limits, (EulerLimit, SwingTwistLimit)):
        limits = (limits,)
    idx = []
    for lim in limits:
        if not isinstance(lim, (EulerLimit, SwingTwistLimit)):
            raise JaxanimError(f"limits: expected EulerLimit or SwingTwistLimit, got {type(lim).__name__}")
        j = skeleton.index(lim.joint)
        if j in idx:
            raise JaxanimError(f"limits: joint {lim.joint!r} has more than one limit")
        if isinstance(lim, EulerLimit):
            _order(skeleton, lim, j)
        elif lim.axis is None:
            bone_axis(skeleton, j)
        idx.append(j)
    return tuple(idx)


def _order(skeleton: Skeleton, lim: EulerLimit, j: int) -> str:
    order = lim.order if lim.order is not None else skeleton.rotation_orders[j]
    if order.upper() not in _TAIT_BRYAN | _PROPER:
        raise JaxanimError(
            f"limits[{lim.joint!r}]: the joint's rotation channels {order!r} are not a 3-axis Euler order; pass order="
        )
    return order


def _axis(skeleton: Skeleton, lim: SwingTwistLimit, j: int, dtype) -> Array:
    return (lim.axis if lim.axis is not None else jnp.asarray(bone_axis(skeleton, j))).astype(dtype)


# --------------------------------------------------------------------------------------------
# Coordinates in which a limit is a box ("charts"), their inverses and soft residuals.
# --------------------------------------------------------------------------------------------


def _wrap(x: Array) -> Array:
    return x - 2 * jnp.pi * jnp.round(x / (2 * jnp.pi))


def _box_excess(theta: Array, lower: Array, upper: Array) -> Array:
    """Signed distance of each component outside ``[lower, upper]`` (0 inside)."""
    return jnp.maximum(theta - upper, 0) + jnp.minimum(theta - lower, 0)


def _euler_candidates(q: Array, order: str, lower: Array, upper: Array) -> Array:
    """The Euler triples of ``q`` (both branches), each wrapped next to the box center: ``[2, 3]``."""
    a = rot.quat_to_euler(q, order)
    if order.upper() in _TAIT_BRYAN:
        b = a + jnp.asarray([jnp.pi, 0.0, jnp.pi], a.dtype)
        b = b.at[1].set(jnp.pi - a[1])
    else:
        b = a + jnp.asarray([jnp.pi, 0.0, jnp.pi], a.dtype)
        b = b.at[1].set(-a[1])
    center = 0.5 * (lower + upper)
    cands = jnp.stack([a, b])
    return center[None] + _wrap(cands - center[None])


def _euler_from_quat(q: Array, order: str, lower: Array, upper: Array) -> Array:
    """The Euler triple of ``q`` closest to the box (least total excess)."""
    cands = _euler_candidates(q, order, lower, upper)
    excess = jnp.sum(jnp.abs(_box_excess(cands, lower[None], upper[None])), axis=-1)
    return jnp.where(excess[0] <= excess[1], cands[0], cands[1])


def _square_to_disc(uv: Array) -> Array:
    u, v = uv[..., 0], uv[..., 1]
    return jnp.stack([u * jnp.sqrt(1 - 0.5 * v * v), v * jnp.sqrt(1 - 0.5 * u * u)], axis=-1)


def _disc_to_square(xy: Array) -> Array:
    x, y = xy[..., 0], xy[..., 1]
    r8 = 2 * math.sqrt(2.0)
    d = x * x - y * y

    def half(p, c):
        return 0.5 * jnp.sqrt(jnp.maximum(2 + p + r8 * c, 0)) - 0.5 * jnp.sqrt(jnp.maximum(2 + p - r8 * c, 0))

    return jnp.clip(jnp.stack([half(d, x), half(-d, y)], axis=-1), -1, 1)


def _swing_twist(q: Array, axis: Array, b1: Array, b2: Array) -> tuple[Array, Array]:
    """``(s [2], tau)`` with ``q = exp(s1 b1 + s2 b2) exp(tau axis)`` (tau in ``[-pi, pi]``)."""
    q = rot.quat_canonical(q)
    w, v = q[0], q[1:]
    c = dot(v, axis)
    n = jnp.sqrt(w * w + c * c)
    ok = n > 1e-12
    n = jnp.where(ok, n, 1)
    qt = jnp.where(ok, jnp.concatenate([w[None], c * axis]) / n, jnp.asarray([1.0, 0, 0, 0], q.dtype))
    tau = jnp.where(ok, 2 * jnp.arctan2(c, jnp.where(ok, w, 1)), 0)
    tau = _wrap(tau)
    sigma = rot.quat_to_rotvec(rot.quat_multiply(q, rot.quat_conjugate(qt)))
    return jnp.stack([dot(sigma, b1), dot(sigma, b2)]), tau


class _Chart(eqx.Module):
    """One limited joint's coordinates ``theta [3]``: map to a quaternion, inverse, box, penalty."""

    kind: str = eqx.field(static=True)  # "euler" | "cone" (hard swing-twist) | "swing" (soft)
    order: str | None = eqx.field(static=True)
    hard: bool = eqx.field(static=True)
    lower: Array  # euler: angles; cone/swing: (swing1, swing2, twist_lower)
    upper: Array  # euler: angles; cone/swing: (swing1, swing2, twist_upper)
    axis: Array | None
    b1: Array | None
    b2: Array | None

    def quat(self, theta: Array) -> Array:
        if self.kind == "euler":
            return rot.euler_to_quat(theta, self.order)
        s = theta[:2]
        if self.kind == "cone":
            s = _square_to_disc(theta[:2]) * self.lower[:2]
        tau = theta[2]
        qt = jnp.concatenate([jnp.cos(0.5 * tau)[None], jnp.sin(0.5 * tau) * self.axis])
        return rot.quat_multiply(rot.rotvec_to_quat(s[0] * self.b1 + s[1] * self.b2), qt)

    def from_quat(self, q: Array) -> Array:
        """Coordinates of ``q``; for a hard chart, projected into the box (nearest allowed pose)."""
        if self.kind == "euler":
            theta = _euler_from_quat(q, self.order, self.lower, self.upper)
            return jnp.clip(theta, self.lower, self.upper) if self.hard else theta
        s, tau = _swing_twist(q, self.axis, self.b1, self.b2)
        if self.kind == "swing":
            return jnp.concatenate([s, tau[None]])
        xy = s / self.lower[:2]
        r = jnp.sqrt(dot(xy, xy))
        xy = jnp.where(r > 1, xy / jnp.where(r > 1, r, 1), xy)
        return jnp.concatenate([_disc_to_square(xy), jnp.clip(tau, self.lower[2], self.upper[2])[None]])

    def bounds(self) -> tuple[Array, Array]:
        if self.kind == "euler":
            return self.lower, self.upper
        one = jnp.ones(2, self.lower.dtype)
        return jnp.concatenate([-one, self.lower[2:]]), jnp.concatenate([one, self.upper[2:]])

    def excess(self, theta: Array) -> Array:
        """Soft-penalty residual: radians outside the limit (``[3]`` Euler, ``[2]`` swing + twist)."""
        if self.kind == "euler":
            return _box_excess(theta, self.lower, self.upper)
        c = self.lower[:2]
        xy = theta[:2] / c
        r2 = dot(xy, xy)
        r = jnp.sqrt(jnp.where(r2 > 1, r2, 1))  # safe: only r > 1 matters
        swing = jnp.where(r2 > 1, (r - 1) * jnp.sqrt(c[0] * c[1]), 0)
        return jnp.stack([swing, _box_excess(theta[2], self.lower[2], self.upper[2])])


class _ChartGroup(eqx.Module):
    """Limited joints that share a chart kind and order, vectorized: ``slots`` index the free
    joints' variable blocks; ``chart`` holds the stacked numbers (leading axis: the group)."""

    slots: tuple[int, ...] = eqx.field(static=True)
    chart: _Chart

    def quat(self, theta: Array) -> Array:
        return jax.vmap(_Chart.quat)(self.chart, theta)

    def from_quat(self, q: Array) -> Array:
        return jax.vmap(_Chart.from_quat)(self.chart, q)

    def bounds(self) -> tuple[Array, Array]:
        return jax.vmap(_Chart.bounds)(self.chart)

    def excess(self, theta: Array) -> Array:
        return jax.vmap(_Chart.excess)(self.chart, theta)

    def omega_columns(self, theta: Array) -> tuple[Array, Array]:
        return jax.vmap(_omega_columns)(self.chart, theta)

    def excess_jacobian(self, theta: Array) -> Array:
        return jax.vmap(jax.jacfwd(_Chart.excess, argnums=1))(self.chart, theta)


def limit_charts(
    skeleton: Skeleton, limits: Sequence[Limit], joint_idx: Sequence[int], slots: Sequence[int], hard: bool, dtype
) -> list[_ChartGroup]:
    """The limited joints' charts, grouped by kind and Euler order (one vectorized call each)."""
    groups: dict[tuple, list] = {}
    for lim, j, k in zip(limits, joint_idx, slots):
        if isinstance(lim, EulerLimit):
            order = _order(skeleton, lim, j)
            chart = _Chart("euler", order, hard, lim.lower.astype(dtype), lim.upper.astype(dtype), None, None, None)
        else:
            a = _axis(skeleton, lim, j, dtype)
            b1, b2 = _basis(a)
            sw, tw = lim.swing.astype(dtype), lim.twist.astype(dtype)
            chart = _Chart(
                "cone" if hard else "swing", None, hard,
                jnp.concatenate([sw, tw[:1]]), jnp.concatenate([sw, tw[1:]]), a, b1, b2,
            )
        groups.setdefault((chart.kind, chart.order), []).append((k, chart))
    return [
        _ChartGroup(tuple(k for k, _ in items), jax.tree.map(lambda *x: jnp.stack(x), *[c for _, c in items]))
        for items in groups.values()
    ]


def _omega_columns(chart: _Chart, theta: Array) -> tuple[Array, Array]:
    """``(q, E)``: the chart's quaternion and ``E [3, 3]`` with ``dR R^T = [E dtheta]_x``."""
    q = chart.quat(theta)
    dq = jax.jacfwd(chart.quat)(theta)  # [4, 3]
    qc = rot.quat_conjugate(q)
    E = 2 * jax.vmap(lambda d: rot.quat_multiply(d, qc)[1:], in_axes=1, out_axes=1)(dq)
    return q, E


# --------------------------------------------------------------------------------------------
# Public check.
# --------------------------------------------------------------------------------------------


def limit_violation(
    skeleton: Skeleton, limits: Sequence[Limit] | Limit, rotations: Float[Array, "joints 4"]
) -> Float[Array, " limits"]:
    """How far a pose is outside each limit, in radians (0 when the limit holds).

    Euler limits: the largest per-angle distance outside the box, for the Euler triple of the
    rotation (of both branches and their ``2 pi`` wraps) that comes closest. Swing-twist limits:
    the larger of the swing angle beyond the cone (``(r - 1) sqrt(swing1 swing2)`` with ``r`` the
    elliptical radius, exactly the excess angle for a circular cone) and the twist outside its range.

    Args:
        skeleton: the tree.
        limits: :class:`EulerLimit` / :class:`SwingTwistLimit` s.
        rotations: ``[joints, 4]`` local wxyz quaternions.

    Returns:
        ``[limits]`` non-negative violations.
    """
    if isinstance(limits, (EulerLimit, SwingTwistLimit)):
        limits = (limits,)
    idx = resolve_limits(skeleton, limits)
    check_shape("rotations", rotations, (skeleton.num_joints, 4), what=f"(joints, 4) = ({skeleton.num_joints}, 4)")
    q = jnp.asarray(rotations)
    out = jnp.zeros((len(limits),), q.dtype)
    for group in limit_charts(skeleton, limits, idx, range(len(limits)), False, q.dtype):
        qj = q[jnp.asarray([idx[i] for i in group.slots])]
        c = group.chart
        if c.kind == "euler":
            cands = jax.vmap(lambda qq, lo, hi: _euler_candidates(qq, c.order, lo, hi))(qj, c.lower, c.upper)
            v = jnp.min(jnp.max(jnp.abs(_box_excess(cands, c.lower[:, None], c.upper[:, None])), axis=-1), axis=-1)
        else:
            v = jnp.max(jnp.abs(group.excess(group.from_quat(qj))), axis=-1)
        out = out.at[jnp.asarray(group.slots)].set(v)
    return out
