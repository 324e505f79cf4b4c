"""Arc length of a :class:`~jaxanim.splines.PiecewiseCubic` and reparameterisation by arc length.

The curve parameter is not arc length (course notes S3:482-490): equal steps in ``t`` give unequal
steps along the curve. The arc length from the first knot is

    s(t) = integral_{t_0}^{t} |S'(tau)| d tau.

**Table.** Each segment is split into ``subdivisions`` equal pieces in ``t`` and ``|S'|`` is
integrated over each piece with 5-point Gauss-Legendre quadrature; the cumulative sums are the
table ``(t_k, s_k)``. The speed is a smooth function inside a segment (it is the norm of a
quadratic), so the error falls like ``(h / subdivisions)^10`` away from points where the speed
vanishes. (The notes build the table by forward differencing, summing chords
``|P(u + du) - P(u)|``; a chord sum underestimates the length by ``O(du^2)``.)

**Inverse.** ``t(s)`` is found in the table's piece with ``s_k <= s < s_{k+1}``: a linear guess
between the table entries, then Newton steps ``t <- t - (s(t) - s) / |S'(t)|`` with ``s(t)`` again
by 5-point Gauss-Legendre from ``t_k``, each step kept inside ``[t_k, t_{k+1}]``. Pieces where the
curve does not move (zero speed) are skipped.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import JaxanimError
from .._types import Array, ArrayLike, Float
from ._curves import PiecewiseCubic, _as_float_array, _check_curve, _evaluate_segment

_GL_X, _GL_W = np.polynomial.legendre.leggauss(5)  # nodes and weights on [-1, 1]


class ArcLengthTable(eqx.Module):
    """Cumulative arc length of a curve at increasing parameters.

    Attributes:
        curve: the :class:`~jaxanim.splines.PiecewiseCubic` the table measures.
        params: ``[K]`` increasing curve parameters ``t_k``, from ``knots[0]`` to ``knots[-1]``
            (``K = subdivisions * (n - 1) + 1``).
        lengths: ``[K]`` arc lengths ``s_k = s(t_k)``, ``s_0 = 0``, non-decreasing.
    """

    curve: PiecewiseCubic
    params: Float[Array, " K"] = eqx.field(converter=jnp.asarray)
    lengths: Float[Array, " K"] = eqx.field(converter=jnp.asarray)

    @property
    def total(self) -> Float[Array, ""]:
        """The length of the whole curve, ``s(t_{n-1})``."""
        return self.lengths[-1]


def _speed(curve: PiecewiseCubic, seg: Array, t: Array) -> Array:
    """``|S'(t)|`` on segments ``seg`` over the flattened value dimensions (gradient-safe at zero speed)."""
    v = _evaluate_segment(curve, seg, t, 1).reshape(t.shape + (-1,))
    n2 = jnp.sum(v * v, axis=-1)
    ok = n2 > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, n2, jnp.ones_like(n2))), jnp.zeros_like(n2))


def _gauss_legendre(curve: PiecewiseCubic, seg: Array, a: Array, b: Array) -> Array:
    """``integral_a^b |S'|`` by 5-point Gauss-Legendre, ``[a, b]`` inside segment ``seg`` (one shape)."""
    lead = (1,) * a.ndim
    x = jnp.asarray(_GL_X, a.dtype).reshape(lead + (-1,))
    w = jnp.asarray(_GL_W, a.dtype).reshape(lead + (-1,))
    mid, half = 0.5 * (a + b), 0.5 * (b - a)
    nodes = mid[..., None] + half[..., None] * x
    seg = jnp.broadcast_to(seg[..., None], nodes.shape)
    return half * jnp.sum(w * _speed(curve, seg, nodes), axis=-1)


@eqx.filter_jit
def _table(curve: PiecewiseCubic, subdivisions: int) -> ArcLengthTable:
    knots = curve.knots
    frac = jnp.arange(subdivisions, dtype=knots.dtype) / subdivisions
    inner = knots[:-1, None] + jnp.diff(knots)[:, None] * frac[None, :]
    params = jnp.concatenate([inner.reshape(-1), knots[-1:]])
    seg = jnp.repeat(jnp.arange(curve.num_segments), subdivisions)
    pieces = _gauss_legendre(curve, seg, params[:-1], params[1:])
    lengths = jnp.concatenate([jnp.zeros((1,), knots.dtype), jnp.cumsum(pieces)])
    return ArcLengthTable(curve, params, lengths)


def _piece(x: Array, table_x: Array) -> Array:
    k = table_x.shape[0]
    return jnp.clip(jnp.searchsorted(table_x, x, side="right", method="scan_unrolled") - 1, 0, k - 2)


def _segment_of_piece(table: ArcLengthTable, k: Array) -> Array:
    per_segment = (table.params.shape[0] - 1) // table.curve.num_segments  # the table's subdivisions
    return k // per_segment


@eqx.filter_jit
def _arc_length(table: ArcLengthTable, t: Array) -> Array:
    p = table.params
    tc = jnp.clip(t, p[0], p[-1])
    k = _piece(tc, p)
    return table.lengths[k] + _gauss_legendre(table.curve, _segment_of_piece(table, k), p[k], tc)


@eqx.filter_jit
def _param_at(table: ArcLengthTable, s: Array, newton_steps: int) -> Array:
    p, L = table.params, table.lengths
    sc = jnp.clip(s, 0.0, L[-1])
    k = _piece(sc, L)
    seg = _segment_of_piece(table, k)
    a, b, la, lb = p[k], p[k + 1], L[k], L[k + 1]
    dl = lb - la
    ok = dl > 0
    frac = jnp.where(ok, (sc - la) / jnp.where(ok, dl, jnp.ones_like(dl)), jnp.zeros_like(dl))
    t = a + jnp.clip(frac, 0.0, 1.0) * (b - a)
    tiny = jnp.finfo(t.dtype).tiny

    def newton(_, t):
        g = la + _gauss_legendre(table.curve, seg, a, t) - sc
        v = _speed(table.curve, seg, t)
        moving = v > tiny
        step = jnp.where(moving, g / jnp.where(moving, v, jnp.ones_like(v)), jnp.zeros_like(v))
        return jnp.clip(t - step, a, b)

    return jax.lax.fori_loop(0, newton_steps, newton, t)


def _check_table(table) -> None:
    if not isinstance(table, ArcLengthTable):
        raise JaxanimError(f"table: expected a jaxanim.splines.ArcLengthTable, got {type(table).__name__}")


def _check_count(name: str, x, lo: int) -> int:
    if isinstance(x, bool) or not isinstance(x, (int, np.integer)) or x < lo:
        raise JaxanimError(f"{name}: expected a Python int >= {lo} (it fixes an output shape), got {x!r}")
    return int(x)


def arc_length_table(curve: PiecewiseCubic, *, subdivisions: int = 16) -> ArcLengthTable:
    """Tabulate the arc length ``s(t) = integral_{t_0}^t |S'|`` of a curve.

    Each segment is cut into ``subdivisions`` equal pieces in ``t``; each piece is integrated with
    5-point Gauss-Legendre quadrature of the speed ``|S'|`` (the norm over all value dimensions).

    Args:
        curve: the :class:`~jaxanim.splines.PiecewiseCubic`.
        subdivisions: pieces per segment (a Python int >= 1; it fixes the table's length).

    Returns:
        The :class:`ArcLengthTable` with ``K = subdivisions * (n - 1) + 1`` entries.

    Raises:
        JaxanimError: if ``curve`` is not a ``PiecewiseCubic`` or ``subdivisions`` is not an int >= 1.
    """
    _check_curve("curve", curve)
    subdivisions = _check_count("subdivisions", subdivisions, 1)
    return _table(curve, subdivisions)


def arc_length(table: ArcLengthTable, t: Float[ArrayLike, "*q"]) -> Float[Array, "*q"]:
    """Arc length ``s(t)`` from the first knot to parameters ``t`` (clamped to the knots).

    ``s(t) = s_k + integral_{t_k}^t |S'|`` with ``t_k <= t`` the table entry below ``t`` and the
    integral by 5-point Gauss-Legendre.

    Args:
        table: the curve's :class:`ArcLengthTable`.
        t: ``[*q]`` curve parameters.

    Returns:
        ``[*q]`` arc lengths, in the units of the curve's points.

    Raises:
        JaxanimError: if ``table`` is not an ``ArcLengthTable`` or ``t`` is not real.
    """
    _check_table(table)
    t = _as_float_array("t", t).astype(table.params.dtype)
    return _arc_length(table, t)


def param_at_arc_length(
    table: ArcLengthTable, s: Float[ArrayLike, "*q"], *, newton_steps: int = 4
) -> Float[Array, "*q"]:
    """The curve parameter ``t`` at which the arc length is ``s`` (the inverse of :func:`arc_length`).

    ``s`` is clamped to ``[0, table.total]``. The table piece holding ``s`` gives a linear guess,
    refined by ``newton_steps`` Newton steps on ``s(t) - s`` (derivative ``|S'(t)|``), kept inside
    the piece. Where the curve stands still (zero speed) any ``t`` of that stretch is an answer;
    the first is returned.

    Args:
        table: the curve's :class:`ArcLengthTable`.
        s: ``[*q]`` arc lengths from the curve's start.
        newton_steps: Newton refinements (a Python int >= 0); 4 reach round-off for smooth curves.

    Returns:
        ``[*q]`` curve parameters, in ``[knots[0], knots[-1]]``.

    Raises:
        JaxanimError: if ``table`` is not an ``ArcLengthTable``, ``s`` is not real or
            ``newton_steps`` is not an int >= 0.
    """
    _check_table(table)
    newton_steps = _check_count("newton_steps", newton_steps, 0)
    s = _as_float_array("s", s).astype(table.params.dtype)
    return _param_at(table, s, newton_steps)


def reparameterize_by_arc_length(table: ArcLengthTable, num: int, *, newton_steps: int = 4) -> Float[Array, " num"]:
    """Parameters of ``num`` points equally spaced in arc length, from the curve's start to its end.

    ``t_j = t(s_j)`` with ``s_j = j L / (num - 1)`` and ``L = table.total``; evaluating the curve at
    them (:func:`~jaxanim.splines.evaluate`) walks it at constant speed, the usual fix for a path
    animation whose speed follows the key spacing. Put an ease-in / ease-out on ``s_j`` instead of
    the uniform spacing with :func:`param_at_arc_length`.

    Args:
        table: the curve's :class:`ArcLengthTable`.
        num: number of samples (a Python int >= 2).
        newton_steps: as in :func:`param_at_arc_length`.

    Returns:
        ``[num]`` increasing curve parameters, the first ``knots[0]`` and the last ``knots[-1]``.

    Raises:
        JaxanimError: if ``table`` is not an ``ArcLengthTable`` or ``num`` is not an int >= 2.
    """
    _check_table(table)
    num = _check_count("num", num, 2)
    newton_steps = _check_count("newton_steps", newton_steps, 0)
    return _uniform_params(table, num, newton_steps)


@eqx.filter_jit
def _uniform_params(table: ArcLengthTable, num: int, newton_steps: int) -> Array:
    s = jnp.linspace(0.0, 1.0, num, dtype=table.params.dtype) * table.total
    return _param_at(table, s, newton_steps)
