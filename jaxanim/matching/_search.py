"""Exact nearest-neighbour search over a motion-matching database.

The squared distance is expanded, ``|q - x|^2 = |q|^2 - 2 q.x + |x|^2``, so that a batch of queries
(``jax.vmap`` over agents) against the database is one matrix product per chunk of rows (the rows
``[x, |x|^2]`` against ``[-2 q, 1]``). The rows are taken in chunks of 512 (a ``lax.scan``), which
bounds the memory at ``agents x chunk`` distances and keeps them in cache; a running minimum keeps
the lowest index on ties. Rows that are not searchable carry ``|x|^2 = +inf`` and are never
returned.

The expansion loses about ``eps * (|q|^2 + |x|^2)`` of absolute accuracy to cancellation, and a
batched product sums in another order than a single one. So rows within ``8 eps (2 |q|^2 + |d| + 1)``
of the minimum count as tied, and a tie goes to the lowest index: the first such row of a chunk,
and a later chunk only if it is better by more than that. Then a single query and the same query
in a batch return the same row (a database built from a periodic clip has exact duplicates).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .._errors import JaxanimError, check_shape
from .._linalg import HIGHEST, check_precision, dot, matmul
from .._types import Array, Float, Int
from ._database import MatchingDatabase

__all__ = ["SearchResult", "search"]

DEFAULT_CHUNK = 512


class SearchResult(eqx.Module):
    """The nearest searchable row and its squared distance (in the normalised feature space)."""

    index: Int[Array, ""]
    distance: Float[Array, ""]


def _tie(dtype):
    return 8.0 * float(jnp.finfo(dtype).eps)


def _first_near_min(d, tol):
    """``(index, value)``: the first entry within ``tol`` of the minimum of ``d`` (exact ties and
    round-off ties alike go to the lowest index, whatever the summation order)."""
    m = jnp.min(d)
    i = jnp.argmax(d <= m + tol).astype(jnp.int32)
    return i, m


def _search(features, squared_norms, query, chunk: int, precision=HIGHEST):
    N, D = features.shape
    dtype = features.dtype
    q = query.astype(dtype)
    qq = dot(q, q)
    rtol = _tie(dtype)
    # one product gives |x|^2 - 2 q.x: rows [x, |x|^2] against [-2 q, 1] (no pass to add |x|^2)
    Xa = jnp.concatenate([features, squared_norms[:, None]], axis=1)
    qa = jnp.concatenate([-2.0 * q, jnp.ones((1,), dtype)])

    def tol(m):
        return rtol * (2.0 * qq + jnp.abs(m) + 1.0)

    if N <= chunk:
        d = matmul(Xa, qa, precision=precision)
        i, m = _first_near_min(d, tol(jnp.min(d)))
        return i, jnp.maximum(m + qq, 0.0)
    n = -(-N // chunk)
    pad = jnp.zeros((n * chunk - N, D + 1), dtype).at[:, D].set(jnp.inf)  # padding rows: |x|^2 = inf
    X = jnp.concatenate([Xa, pad]).reshape(n, chunk, D + 1)

    def body(carry, xs):
        best_d, best_i = carry
        Xc, k = xs
        d = matmul(Xc, qa, precision=precision)
        i, m = _first_near_min(d, tol(jnp.min(d)))
        # a later chunk must be better beyond round-off (the first finite one always is)
        inf = jnp.isinf(best_d)
        better = jnp.where(inf, m < best_d, m < best_d - tol(jnp.where(inf, 0.0, best_d)))
        return (jnp.where(better, m, best_d), jnp.where(better, k * chunk + i, best_i)), None

    init = (jnp.asarray(jnp.inf, dtype), jnp.asarray(0, jnp.int32))
    (best_d, best_i), _ = lax.scan(body, init, (X, jnp.arange(n, dtype=jnp.int32)))
    return best_i, jnp.maximum(best_d + qq, 0.0)


def _search_flagged(features, squared_norms, query, chunk: int, precision=HIGHEST):
    """:func:`_search`, with ``(-1, nan)`` for a query holding NaN or inf (traced: no error can be
    raised, and a NaN query would otherwise come back as row 0)."""
    i, d = _search(features, squared_norms, query, chunk, precision)
    finite = jnp.all(jnp.isfinite(query))
    return jnp.where(finite, i, -1), jnp.where(finite, d, jnp.nan)


_search_jit = jax.jit(_search_flagged, static_argnums=(3, 4))


def search(db: MatchingDatabase, query: Float[Array, " features"], *, chunk: int = DEFAULT_CHUNK,
           precision: lax.Precision | str = HIGHEST) -> SearchResult:
    """The searchable row nearest to ``query`` (exact; ties go to the lowest index).

    One query; batch over agents with ``jax.vmap(search, in_axes=(None, 0))``: the batched program is
    one ``[agents, chunk] = [agents, features] x [features, chunk]`` product per chunk.

    Args:
        db: the database.
        query: ``[features]`` normalised, weighted features (:func:`normalize_features` of a raw
            vector, or a row of ``db.features``).
        chunk: rows per step of the scan over the database (static); bounds the memory of a
            batched call at ``agents x chunk`` distances.
        precision: of the distance product (static): ``"highest"`` (the default: exact float32 on
            every backend), or ``"default"``, the fast path, which on an NVIDIA GPU runs a float32
            search in TF32 (about 10 bits of mantissa: rows whose distances differ by less than
            that tie and the nearest may be missed). float64 databases are exact either way.

    Returns:
        :class:`SearchResult` ``(index, distance)``: the row and its squared distance. A traced
        ``query`` (under ``jit`` or ``vmap``) holding NaN or inf gives ``index = -1`` and
        ``distance = nan``: no row, rather than a plausible one (check ``index >= 0``).

    Raises:
        JaxanimError: if ``query`` does not have the database's feature count, a concrete ``query``
            holds NaN or inf, or ``precision`` is not a precision.
    """
    check_shape("query", query, (db.num_features,), what=f"(features,) = ({db.num_features},)")
    if not isinstance(query, jax.core.Tracer) and not np.all(np.isfinite(host := np.asarray(query))):
        bad = np.flatnonzero(~np.isfinite(host))
        raise JaxanimError(f"query: expected finite values, got NaN or inf in {len(bad)} feature(s), the first "
                           f"{bad[:5].tolist()}")
    if int(chunk) < 1:
        raise JaxanimError(f"chunk: expected a positive number of rows, got {chunk}")
    precision = check_precision("precision", precision)
    i, d = _search_jit(db.features, db.squared_norms, jnp.asarray(query), int(chunk), precision)
    return SearchResult(i, d)
