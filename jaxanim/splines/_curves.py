"""Piecewise cubic curves through keys: linear, cubic Hermite, Catmull-Rom, natural cubic spline and
piecewise cubic Bezier, all held as one :class:`PiecewiseCubic` (Bezier form per segment), plus a
single Bezier curve of any degree (De Casteljau).

**One representation.** Every curve here is cubic on each interval ``[t_i, t_{i+1}]`` of its knots.
With ``h_i = t_{i+1} - t_i`` and the local parameter ``u = (t - t_i) / h_i`` in ``[0, 1]``, segment
``i`` is stored by its four Bezier control points ``P_i0 .. P_i3`` and evaluated in the Bernstein
basis

    S_i(u) = sum_k P_ik B_k(u),   B_k(u) = C(3, k) u^k (1 - u)^(3 - k),

so ``S_i(0) = P_i0`` and ``S_i(1) = P_i3`` exactly (keys are hit to the last bit). A cubic Hermite
segment with end values ``y_i, y_{i+1}`` and end derivatives (in ``t``) ``m_i, m_{i+1}`` is the
same cubic as

    P_i0 = y_i,  P_i1 = y_i + h_i m_i / 3,  P_i2 = y_{i+1} - h_i m_{i+1} / 3,  P_i3 = y_{i+1},

which is the matrix form of the course notes, ``S(u) = [u^3 u^2 u 1] M [y_i, y_{i+1}, h m_i, h m_{i+1}]``
with ``M = [[2,-2,1,1],[-3,3,-2,-1],[0,0,1,0],[1,0,0,0]]`` (basis ``H_0 = 2u^3 - 3u^2 + 1``,
``H_1 = -2u^3 + 3u^2``, ``H_2 = u^3 - 2u^2 + u``, ``H_3 = u^3 - u^2``). Note the factor ``h_i``: the
tangents are derivatives in ``t`` and must be scaled when the segment is mapped to ``u``.

**Derivatives.** ``d^k S / dt^k = 3! / (3 - k)! / h_i^k sum_j (Delta^k P_i)_j B^(3-k)_j(u)``, the
Bernstein form of the forward differences of the control points.

**Evaluation and extrapolation.** The segment of a query ``t`` comes from ``jnp.searchsorted`` on
the knots (``t_i <= t < t_{i+1}``; the last segment also owns its right end). Queries outside
``[t_0, t_{n-1}]`` are **clamped**: the curve holds its end values there, and its derivatives are
zero (the derivatives of the held constant), so value and derivative agree outside the range.

**Knots** are a strictly increasing ``[n]`` vector with ``n >= 2``. Concrete knots are checked in
Python (a :class:`~jaxanim.JaxanimError` names the first offending pair); traced knots (under
``jit`` / ``vmap``) are checked with ``eqx.error_if`` at run time.

Points have shape ``[n, *shape]``: a key may be a scalar, a 3-vector or any array (a clip's
``[joints, 3]`` translations); values come back as ``[*q, *shape]`` for queries ``t`` of shape ``*q``.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.lax.linalg import tridiagonal_solve

from .._errors import JaxanimError, check_shape
from .._linalg import einsum
from .._types import Array, ArrayLike, Float
from ..rotations._base import as_float_any

_MAX_DERIVATIVE = 3


# ------------------------------------------------------------------------------------------------
# Input checks
# ------------------------------------------------------------------------------------------------


def _as_float_array(name: str, x) -> Array:
    """``x`` as a floating jax array (integers become the default float); the rotations' own check."""
    return as_float_any(name, x)


def _check_knots(name: str, knots) -> Array:
    """A ``[n]`` float vector of strictly increasing knots, ``n >= 2`` (see the module docstring)."""
    check_shape(name, knots, (None,), what="(n,) with n >= 2")
    knots = _as_float_array(name, knots)
    n = knots.shape[0]
    if n < 2:
        raise JaxanimError(f"{name}: expected shape (n,) with n >= 2 (at least 2 points), got ({n},)")
    if isinstance(knots, jax.core.Tracer):
        bad = jnp.any(jnp.diff(knots) <= 0) | ~jnp.all(jnp.isfinite(knots))
        return eqx.error_if(knots, bad, f"{name}: expected strictly increasing finite knots")
    k = np.asarray(knots)
    if not np.all(np.isfinite(k)):
        raise JaxanimError(f"{name}: expected finite knots, got {k.tolist()}")
    step = np.diff(k)
    if np.any(step <= 0):
        i = int(np.argmax(step <= 0))
        raise JaxanimError(
            f"{name}: expected strictly increasing knots, got {name}[{i}] = {k[i]:.9g} >= "
            f"{name}[{i + 1}] = {k[i + 1]:.9g}"
        )
    return knots


def _check_points(name: str, points, n: int, what: str = "n") -> Array:
    """``[n, *shape]`` float keys: the leading dimension must be ``n`` (written ``what``)."""
    points = _as_float_array(name, points)
    if points.ndim < 1 or points.shape[0] != n:
        raise JaxanimError(f"{name}: expected shape ({what}, ...) = ({n}, ...), got {tuple(points.shape)}")
    return points


def _common_dtype(*xs: Array):
    return jnp.result_type(*(x.dtype for x in xs))


def _keys(knots, points) -> tuple[Array, Array]:
    """Checked ``knots [n]`` and ``points [n, *shape]``, cast to their common float dtype."""
    knots = _check_knots("knots", knots)
    points = _check_points("points", points, knots.shape[0])
    dtype = _common_dtype(knots, points)
    return knots.astype(dtype), points.astype(dtype)


def _check_derivative(derivative, highest: int) -> int:
    if isinstance(derivative, bool) or not isinstance(derivative, (int, np.integer)) or not 0 <= derivative <= highest:
        raise JaxanimError(f"derivative: expected an int from 0 to {highest}, got {derivative!r}")
    return int(derivative)


def _check_curve(name: str, curve) -> None:
    if not isinstance(curve, PiecewiseCubic):
        raise JaxanimError(f"{name}: expected a jaxanim.splines.PiecewiseCubic, got {type(curve).__name__}")


# ------------------------------------------------------------------------------------------------
# The curve Module
# ------------------------------------------------------------------------------------------------


class PiecewiseCubic(eqx.Module):
    """A curve that is cubic between consecutive knots, stored in Bezier form per segment.

    Build it with :func:`linear_spline`, :func:`hermite_spline`, :func:`catmull_rom_spline`,
    :func:`natural_cubic_spline` or :func:`bezier_spline`; evaluate it (and its derivatives) with
    :func:`evaluate`. All fields are arrays, so curves batch with ``jax.vmap``.

    Attributes:
        knots: ``[n]`` strictly increasing parameters (times) of the keys, ``n >= 2``.
        control_points: ``[n - 1, 4, *shape]`` Bezier control points ``P_i0 .. P_i3`` of each
            segment (``P_i0`` is the key at ``knots[i]``, ``P_i3`` the key at ``knots[i + 1]``).
    """

    knots: Float[Array, " n"] = eqx.field(converter=jnp.asarray)
    control_points: Float[Array, " segments 4 *shape"] = eqx.field(converter=jnp.asarray)

    def __check_init__(self):
        check_shape("knots", self.knots, (None,), what="(n,) with n >= 2")
        n = self.knots.shape[0]
        if n < 2:
            raise JaxanimError(f"knots: expected shape (n,) with n >= 2 (at least 2 points), got ({n},)")
        cp = self.control_points
        if cp.ndim < 2 or cp.shape[:2] != (n - 1, 4):
            raise JaxanimError(
                f"control_points: expected shape (n - 1, 4, ...) = ({n - 1}, 4, ...), got {tuple(cp.shape)}"
            )

    @property
    def num_segments(self) -> int:
        return self.control_points.shape[0]

    @property
    def value_shape(self) -> tuple[int, ...]:
        """The shape of one point of the curve (``()`` for a scalar curve, ``(3,)`` in 3-D)."""
        return tuple(self.control_points.shape[2:])


# ------------------------------------------------------------------------------------------------
# Kernels (no input checks; points flattened to [n, D])
# ------------------------------------------------------------------------------------------------


def _locate(knots: Array, t: Array) -> tuple[Array, Array, Array, Array]:
    """Segment index ``i``, local parameter ``u`` in [0, 1], width ``h_i`` and the in-range mask."""
    n = knots.shape[0]
    tc = jnp.clip(t, knots[0], knots[-1])
    i = jnp.clip(jnp.searchsorted(knots, tc, side="right", method="scan_unrolled") - 1, 0, n - 2)
    h = knots[i + 1] - knots[i]
    u = (tc - knots[i]) / h
    inside = (t >= knots[0]) & (t <= knots[-1])
    return i, u, h, inside


def _bernstein(degree: int, u: Array) -> Array:
    """``[*q, degree + 1]`` Bernstein basis ``C(p, k) u^k (1 - u)^(p - k)``."""
    v = 1.0 - u
    return jnp.stack([math.comb(degree, k) * u**k * v ** (degree - k) for k in range(degree + 1)], axis=-1)


def _difference(cp: Array, derivative: int, axis: int) -> Array:
    """``p! / (p - k)! Delta^k cp`` along ``axis`` (the control points of the k-th derivative in u)."""
    p = cp.shape[axis] - 1
    return math.perm(p, derivative) * jnp.diff(cp, n=derivative, axis=axis) if derivative else cp


def _hermite_to_bezier(knots: Array, y: Array, m: Array) -> Array:
    """``[n - 1, 4, D]`` control points of the Hermite segments with values ``y`` and tangents ``m``."""
    h = jnp.diff(knots)[:, None]
    return jnp.stack([y[:-1], y[:-1] + h * m[:-1] / 3.0, y[1:] - h * m[1:] / 3.0, y[1:]], axis=1)


def _linear_cp(knots: Array, y: Array) -> Array:
    d = jnp.diff(y, axis=0)
    return jnp.stack([y[:-1], y[:-1] + d / 3.0, y[1:] - d / 3.0, y[1:]], axis=1)


def _catmull_rom_tangents(knots: Array, y: Array) -> Array:
    h = jnp.diff(knots)
    first = (y[1:2] - y[:1]) / h[:1, None]
    last = (y[-1:] - y[-2:-1]) / h[-1:, None]
    interior = (y[2:] - y[:-2]) / (knots[2:] - knots[:-2])[:, None]
    return jnp.concatenate([first, interior, last], axis=0)


def _natural_second_derivatives(knots: Array, y: Array) -> Array:
    """``[n, D]`` second derivatives ``M`` of the natural spline (``M_0 = M_{n-1} = 0``)."""
    n = knots.shape[0]
    if n == 2:
        return jnp.zeros_like(y)
    h = jnp.diff(knots)
    slope = jnp.diff(y, axis=0) / h[:, None]
    rhs = 6.0 * (slope[1:] - slope[:-1])
    zero = jnp.zeros((1,), knots.dtype)
    diag = 2.0 * (h[:-1] + h[1:])
    lower = jnp.concatenate([zero, h[1:-1]])
    upper = jnp.concatenate([h[1:-1], zero])
    inner = tridiagonal_solve(lower, diag, upper, rhs)
    pad = jnp.zeros((1, y.shape[1]), y.dtype)
    return jnp.concatenate([pad, inner, pad], axis=0)


def _natural_tangents(knots: Array, y: Array) -> Array:
    M = _natural_second_derivatives(knots, y)
    h = jnp.diff(knots)[:, None]
    slope = jnp.diff(y, axis=0) / h
    left = slope - h * (2.0 * M[:-1] + M[1:]) / 6.0  # S'(t_i) from segment i
    end = slope[-1:] + h[-1:] * (M[-2:-1] + 2.0 * M[-1:]) / 6.0  # S'(t_{n-1}) from the last segment
    return jnp.concatenate([left, end], axis=0)


def _flat(points: Array) -> tuple[Array, tuple[int, ...]]:
    return points.reshape(points.shape[0], -1), tuple(points.shape[1:])


def _curve(knots: Array, cp_flat: Array, shape: tuple[int, ...]) -> PiecewiseCubic:
    return PiecewiseCubic(knots, cp_flat.reshape(cp_flat.shape[:2] + shape))


def _make_curve(kind: str, knots: Array, points: Array, tangents: Array | None = None) -> PiecewiseCubic:
    """The ``kind`` curve (``"linear"``, ``"hermite"``, ``"catmull_rom"``, ``"natural"``) through the keys."""
    y, shape = _flat(points)
    if kind == "linear":
        return _curve(knots, _linear_cp(knots, y), shape)
    if kind == "hermite":
        m = tangents.reshape(y.shape)
    elif kind == "catmull_rom":
        m = _catmull_rom_tangents(knots, y)
    elif kind == "natural":
        m = _natural_tangents(knots, y)
    else:  # pragma: no cover - the public functions pass known kinds
        raise AssertionError(kind)
    return _curve(knots, _hermite_to_bezier(knots, y, m), shape)


_build = eqx.filter_jit(_make_curve)


def _evaluate_segment(curve: PiecewiseCubic, i: Array, t: Array, derivative: int) -> Array:
    """Segment ``i`` (an index per query, ``t`` inside it) evaluated at ``t``: no search, no clamping."""
    h = curve.knots[i + 1] - curve.knots[i]
    return _bezier_segments(curve, i, (t - curve.knots[i]) / h, h, derivative)


def _bezier_segments(curve: PiecewiseCubic, i: Array, u: Array, h: Array, derivative: int) -> Array:
    """``[*q, *shape]``: the ``derivative`` of segments ``i`` at local parameters ``u`` (widths ``h``)."""
    shape, q = curve.value_shape, u.shape
    cp = curve.control_points.reshape(curve.num_segments, 4, -1)[i.reshape(-1)]  # [Q, 4, D]
    cp = _difference(cp, derivative, axis=1)
    w = _bernstein(3 - derivative, u.reshape(-1))  # [Q, 4 - k]
    val = einsum("qk,qkd->qd", w, cp)
    if derivative:
        val = val * (h ** (-derivative)).reshape(-1, 1)
    return val.reshape(q + shape)


def _evaluate(curve: PiecewiseCubic, t: Array, derivative: int) -> Array:
    i, u, h, inside = _locate(curve.knots, t)
    val = _bezier_segments(curve, i, u, h, derivative)
    if derivative:
        mask = inside.reshape(inside.shape + (1,) * len(curve.value_shape))
        val = jnp.where(mask, val, jnp.zeros_like(val))
    return val


_evaluate_jit = eqx.filter_jit(_evaluate)


# ------------------------------------------------------------------------------------------------
# Public API
# ------------------------------------------------------------------------------------------------


def evaluate(curve: PiecewiseCubic, t: Float[ArrayLike, "*q"], *, derivative: int = 0) -> Array:
    """Value (or a derivative in ``t``) of a piecewise cubic curve at query times.

    On segment ``i`` (``t_i <= t < t_{i+1}``, found with ``jnp.searchsorted``), with
    ``u = (t - t_i) / h_i``, ``S(t) = sum_k P_ik B_k(u)`` in the cubic Bernstein basis, and
    ``d^k S / dt^k = 3! / (3 - k)! h_i^-k sum_j (Delta^k P_i)_j B^(3-k)_j(u)``.

    **Extrapolation:** ``t`` outside ``[knots[0], knots[-1]]`` is clamped, so the curve holds its
    end values there and every derivative is zero.

    Args:
        curve: the curve (:class:`PiecewiseCubic`).
        t: ``[*q]`` query times, any shape, in the units of ``curve.knots``.
        derivative: 0 for values, 1, 2 or 3 for that derivative with respect to ``t`` (a Python int).

    Returns:
        ``[*q, *shape]`` values (or derivatives, in units per unit of ``t`` to the ``derivative``).

    Raises:
        JaxanimError: if ``curve`` is not a :class:`PiecewiseCubic`, ``t`` is not real, or
            ``derivative`` is not 0 to 3.
    """
    _check_curve("curve", curve)
    derivative = _check_derivative(derivative, _MAX_DERIVATIVE)
    t = _as_float_array("t", t).astype(curve.knots.dtype)
    return _evaluate_jit(curve, t, derivative)


def linear_spline(knots: Float[ArrayLike, " n"], points: Float[ArrayLike, " n *shape"]) -> PiecewiseCubic:
    """The piecewise linear curve through the keys, ``S(t) = y_i + (t - t_i) / h_i (y_{i+1} - y_i)``.

    Stored as cubics (control points at thirds of each chord), so it evaluates like every other
    curve here; it is C0, with a jump in the first derivative at each interior key.

    Args:
        knots: ``[n]`` strictly increasing times, ``n >= 2``.
        points: ``[n, *shape]`` keys, one per knot.

    Returns:
        The :class:`PiecewiseCubic`.

    Raises:
        JaxanimError: on fewer than 2 knots, knots not strictly increasing, or points whose leading
            dimension is not ``n``.
    """
    return _build("linear", *_keys(knots, points), None)


def hermite_spline(
    knots: Float[ArrayLike, " n"], points: Float[ArrayLike, " n *shape"], tangents: Float[ArrayLike, " n *shape"]
) -> PiecewiseCubic:
    """The cubic Hermite spline through the keys with the given tangents (C1).

    On ``[t_i, t_{i+1}]``, with ``u = (t - t_i) / h_i``,
    ``S = H_0(u) y_i + H_1(u) y_{i+1} + h_i (H_2(u) m_i + H_3(u) m_{i+1})`` where
    ``H_0 = 2u^3 - 3u^2 + 1``, ``H_1 = -2u^3 + 3u^2``, ``H_2 = u^3 - 2u^2 + u``, ``H_3 = u^3 - u^2``;
    ``S(t_i) = y_i`` and ``S'(t_i) = m_i``. The tangents are derivatives with respect to ``t``
    (the ``h_i`` factor maps them to the local parameter), as in ``scipy.interpolate.CubicHermiteSpline``.

    Args:
        knots: ``[n]`` strictly increasing times, ``n >= 2``.
        points: ``[n, *shape]`` keys ``y_i``.
        tangents: ``[n, *shape]`` derivatives ``m_i = dS/dt`` at the keys.

    Returns:
        The :class:`PiecewiseCubic`.

    Raises:
        JaxanimError: on fewer than 2 knots, knots not strictly increasing, or points / tangents of
            another shape.
    """
    knots = _check_knots("knots", knots)
    points = _check_points("points", points, knots.shape[0])
    tangents = _as_float_array("tangents", tangents)
    check_shape("tangents", tangents, points.shape, what=f"{tuple(points.shape)} (the shape of points)")
    dtype = _common_dtype(knots, points, tangents)
    return _build("hermite", knots.astype(dtype), points.astype(dtype), tangents.astype(dtype))


def catmull_rom_tangents(knots: Float[ArrayLike, " n"], points: Float[ArrayLike, " n *shape"]) -> Array:
    """Catmull-Rom tangents: central finite differences on the knots, one-sided at the ends.

    ``m_i = (y_{i+1} - y_{i-1}) / (t_{i+1} - t_{i-1})`` inside (``(y_{i+1} - y_{i-1}) / 2`` for unit
    spacing), ``m_0 = (y_1 - y_0) / h_0`` and ``m_{n-1} = (y_{n-1} - y_{n-2}) / h_{n-2}`` at the ends
    (the same as a phantom key reflected through the end key). The course notes' (S4:706)
    ``m_1 = (p_2 - p_0) / (2 (x_2 - x_0))`` has an extra factor 2: it halves the tangent, and a
    straight line sampled at uniform knots would then not be reproduced.

    Args:
        knots: ``[n]`` strictly increasing times, ``n >= 2``.
        points: ``[n, *shape]`` keys.

    Returns:
        ``[n, *shape]`` tangents ``dS/dt`` at the keys.

    Raises:
        JaxanimError: as :func:`catmull_rom_spline`.
    """
    return _catmull_rom_tangents_jit(*_keys(knots, points))


@eqx.filter_jit
def _catmull_rom_tangents_jit(knots: Array, points: Array) -> Array:
    return _catmull_rom_tangents(knots, _flat(points)[0]).reshape(points.shape)


def catmull_rom_spline(knots: Float[ArrayLike, " n"], points: Float[ArrayLike, " n *shape"]) -> PiecewiseCubic:
    """The Catmull-Rom spline: the cubic Hermite spline with :func:`catmull_rom_tangents` (C1, local).

    ``m_i = (y_{i+1} - y_{i-1}) / (t_{i+1} - t_{i-1})``: the correct tangent for non-uniform knots,
    ``(y_{i+1} - y_{i-1}) / 2`` for unit spacing. The notes' ``(p_2 - p_0) / (2 (x_2 - x_0))`` has an
    extra factor 2 and is an error. This is the finite-difference (cardinal, tension 0)
    Catmull-Rom on the given knots; moving one key changes only the four segments around it.

    Args:
        knots: ``[n]`` strictly increasing times, ``n >= 2``.
        points: ``[n, *shape]`` keys.

    Returns:
        The :class:`PiecewiseCubic`.

    Raises:
        JaxanimError: on fewer than 2 knots, knots not strictly increasing, or points whose leading
            dimension is not ``n``.
    """
    return _build("catmull_rom", *_keys(knots, points), None)


def natural_cubic_spline(knots: Float[ArrayLike, " n"], points: Float[ArrayLike, " n *shape"]) -> PiecewiseCubic:
    """The natural cubic spline through the keys (C2, global), from one tridiagonal solve.

    With ``M_i = S''(t_i)`` and ``M_0 = M_{n-1} = 0`` (natural ends), continuity of ``S'`` at the
    interior keys gives, for ``i = 1 .. n - 2``,

        h_{i-1} M_{i-1} + 2 (h_{i-1} + h_i) M_i + h_i M_{i+1}
            = 6 ((y_{i+1} - y_i) / h_i - (y_i - y_{i-1}) / h_{i-1}),

    a symmetric, strictly diagonally dominant tridiagonal system (``jax.lax.linalg.tridiagonal_solve``,
    every component of the keys as one right-hand side). This is the notes' 4N x 4N global system
    reduced to its N - 1 unknowns: every key moves every segment. The slopes at the keys are
    ``S'(t_i) = (y_{i+1} - y_i) / h_i - h_i (2 M_i + M_{i+1}) / 6`` and the segments are stored as
    cubic Hermite pieces. Two keys give the straight line.

    Args:
        knots: ``[n]`` strictly increasing times, ``n >= 2``.
        points: ``[n, *shape]`` keys.

    Returns:
        The :class:`PiecewiseCubic` (the same curve as
        ``scipy.interpolate.CubicSpline(knots, points, bc_type="natural")`` inside the knots).

    Raises:
        JaxanimError: on fewer than 2 knots, knots not strictly increasing, or points whose leading
            dimension is not ``n``.
    """
    return _build("natural", *_keys(knots, points), None)


def bezier_spline(
    knots: Float[ArrayLike, " n"], control_points: Float[ArrayLike, " 3*n-2 *shape"]
) -> PiecewiseCubic:
    """A piecewise cubic Bezier curve: segment ``i`` on ``[t_i, t_{i+1}]`` has control points
    ``control_points[3 i : 3 i + 4]``.

    Consecutive segments share their end control point, so the curve is C0 and passes through
    ``control_points[0], [3], [6], ...``; it is C1 where ``P_{3i+1} - P_{3i}`` and
    ``P_{3i} - P_{3i-1}`` are in the ratio ``h_i / h_{i-1}``. With ``u = (t - t_i) / h_i``,
    ``S(t) = sum_k P_{3i+k} C(3, k) u^k (1 - u)^(3 - k)``. For a single Bezier curve of any degree on
    ``[0, 1]`` use :func:`bezier_curve`.

    Args:
        knots: ``[n]`` strictly increasing times, ``n >= 2``.
        control_points: ``[3 (n - 1) + 1, *shape]`` control points.

    Returns:
        The :class:`PiecewiseCubic`.

    Raises:
        JaxanimError: on fewer than 2 knots, knots not strictly increasing, or a control-point count
            other than ``3 (n - 1) + 1``.
    """
    knots = _check_knots("knots", knots)
    n = knots.shape[0]
    cp = _check_points("control_points", control_points, 3 * (n - 1) + 1, what="3 (n - 1) + 1")
    dtype = _common_dtype(knots, cp)
    idx = 3 * np.arange(n - 1)[:, None] + np.arange(4)[None, :]
    return PiecewiseCubic(knots.astype(dtype), cp.astype(dtype)[idx])


def bezier_curve(
    control_points: Float[ArrayLike, " p+1 *shape"], s: Float[ArrayLike, "*q"], *, derivative: int = 0
) -> Array:
    """One Bezier curve of degree ``p`` on ``s`` in ``[0, 1]``, by De Casteljau's algorithm.

    ``B(s) = sum_k P_k C(p, k) s^k (1 - s)^(p - k)``, computed by ``p`` rounds of
    ``P_k <- (1 - s) P_k + s P_{k+1}`` (numerically stable; every intermediate is a convex
    combination). The ``k``-th derivative is ``p! / (p - k)!`` times the degree ``p - k`` curve of
    the ``k``-th forward differences of the control points. ``s`` outside ``[0, 1]`` is clamped
    (end values held, derivatives zero). ``B(0) = P_0``, ``B(1) = P_p``, ``B'(0) = p (P_1 - P_0)``.

    Args:
        control_points: ``[p + 1, *shape]`` control points, ``p >= 1``.
        s: ``[*q]`` curve parameters.
        derivative: 0 for values, up to ``p`` for that derivative with respect to ``s``.

    Returns:
        ``[*q, *shape]`` points (or derivatives).

    Raises:
        JaxanimError: on fewer than 2 control points, a non-real ``s`` or a bad ``derivative``.
    """
    cp = _as_float_array("control_points", control_points)
    if cp.ndim < 1 or cp.shape[0] < 2:
        raise JaxanimError(
            f"control_points: expected shape (p + 1, ...) with p + 1 >= 2 (at least 2 points), got {tuple(cp.shape)}"
        )
    derivative = _check_derivative(derivative, cp.shape[0] - 1)
    s = _as_float_array("s", s)
    dtype = _common_dtype(cp, s)
    return _bezier_curve_jit(cp.astype(dtype), s.astype(dtype), derivative)


@eqx.filter_jit
def _bezier_curve_jit(cp: Array, s: Array, derivative: int) -> Array:
    q, shape = s.shape, tuple(cp.shape[1:])
    c = _difference(cp.reshape(cp.shape[0], -1), derivative, axis=0)  # [p - k + 1, D]
    sc = jnp.clip(s, 0.0, 1.0).reshape(-1, 1, 1)
    pts = jnp.broadcast_to(c[None], (sc.shape[0],) + c.shape)
    for _ in range(c.shape[0] - 1):
        pts = (1.0 - sc) * pts[:, :-1] + sc * pts[:, 1:]
    val = pts[:, 0]
    if derivative:
        inside = ((s >= 0) & (s <= 1)).reshape(-1, 1)
        val = jnp.where(inside, val, jnp.zeros_like(val))
    return val.reshape(q + shape)
