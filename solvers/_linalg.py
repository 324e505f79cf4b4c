"""Small dense Cholesky factorization, solves and products for the sequential passes of LQR / iLQR / DDP.

Inside a ``lax.scan`` over time steps each LAPACK custom call (``potrf``, ``trsm``) costs about a
microsecond of dispatch on XLA:CPU, more than the arithmetic of a 2x2 or 4x4 system. For
``m <= UNROLL_MAX`` these functions write the factorization and the triangular solves out as scalar
and row-vector arithmetic (static Python loops), which XLA fuses; larger systems use
``jnp.linalg.cholesky`` / ``jax.scipy.linalg.cho_solve``. Both paths return NaN factors for a matrix
that is not positive definite, like ``jnp.linalg.cholesky``.

:func:`solve` is a small general solve (Gauss-Jordan with partial pivoting) for batched doubling steps,
where LAPACK's per-system LU dominated the time.

Every matrix product of the library states its precision: :data:`HIGHEST` unless a kernel takes a
documented ``precision`` option. Without it an NVIDIA GPU runs a float32 ``dot`` in TF32 (about 10
bits of mantissa), so float32 results would not be float32-accurate there. :func:`matmul`,
:func:`einsum` and :func:`dot` are ``jnp``'s with that default.
"""

from __future__ import annotations

import jax.numpy as jnp
import jax.scipy.linalg as jsl
from jax import lax
from jaxtyping import Array, Float

HIGHEST = lax.Precision.HIGHEST  # full float32 (or float64) accuracy on every backend: no TF32


def matmul(a: Array, b: Array, *, precision=HIGHEST) -> Array:
    """``jnp.matmul(a, b)`` (``a @ b``) at ``precision`` (default :data:`HIGHEST`)."""
    return jnp.matmul(a, b, precision=precision)


def dot(a: Array, b: Array, *, precision=HIGHEST) -> Array:
    """``jnp.dot(a, b)`` at ``precision`` (default :data:`HIGHEST`)."""
    return jnp.dot(a, b, precision=precision)


def einsum(subscripts: str, *operands: Array, precision=HIGHEST) -> Array:
    """``jnp.einsum(subscripts, *operands)`` at ``precision`` (default :data:`HIGHEST`)."""
    return jnp.einsum(subscripts, *operands, precision=precision)


UNROLL_MAX = 6


def cholesky(H: Float[Array, "m m"]) -> Float[Array, "m m"]:
    """The lower Cholesky factor of the symmetric ``H`` (NaN where ``H`` is not positive definite)."""
    m = H.shape[0]
    if m > UNROLL_MAX:
        return jnp.linalg.cholesky(H)
    L: list[list] = [[None] * m for _ in range(m)]
    zero = jnp.zeros((), H.dtype)
    for j in range(m):
        s = H[j, j] - sum((L[j][k] ** 2 for k in range(j)), zero)
        d = jnp.where(s > 0, jnp.sqrt(jnp.where(s > 0, s, 1)), jnp.nan)
        L[j][j] = d
        for i in range(j + 1, m):
            L[i][j] = (H[i, j] - sum((L[i][k] * L[j][k] for k in range(j)), zero)) / d
    rows = [jnp.stack([L[i][j] if j <= i else zero for j in range(m)]) for i in range(m)]
    return jnp.stack(rows)


def cho_solve(L: Float[Array, "m m"], B: Float[Array, "m ..."]) -> Float[Array, "m ..."]:
    """``X`` with ``L L' X = B`` for the lower factor ``L`` of :func:`cholesky`."""
    m = L.shape[0]
    if m > UNROLL_MAX:
        return jsl.cho_solve((L, True), B)
    y: list = [None] * m
    for i in range(m):
        acc = B[i]
        for k in range(i):
            acc = acc - L[i, k] * y[k]
        y[i] = acc / L[i, i]
    x: list = [None] * m
    for i in reversed(range(m)):
        acc = y[i]
        for k in range(i + 1, m):
            acc = acc - L[k, i] * x[k]
        x[i] = acc / L[i, i]
    return jnp.stack(x)


EW_MAX = 4096  # largest a.shape[0] * a.shape[1] * b.shape[-1] multiplied elementwise


def mm(a: Float[Array, "p q"], b: Float[Array, "q ..."]) -> Float[Array, "p ..."]:
    """``a @ b`` for a matrix ``a`` and a matrix or vector ``b``.

    Small products are written as a broadcast multiply and a sum, which XLA:CPU fuses with their
    neighbours instead of dispatching a ``dot`` per product (inside the per-time-step body of a
    ``lax.scan`` this is 1.5-5x faster for the state sizes of the problem library); larger ones are
    plain ``dot``s.
    """
    cols = 1 if b.ndim == 1 else b.shape[-1]
    if a.shape[0] * a.shape[1] * cols > EW_MAX:
        return matmul(a, b)
    if b.ndim == 1:
        return jnp.sum(a * b[None, :], axis=1)
    return jnp.sum(a[:, :, None] * b[None, :, :], axis=1)


def solve(W: Float[Array, "n n"], Z: Float[Array, "n k"]) -> Float[Array, "n k"]:
    """``W^{-1} Z`` for a small square ``W``: Gauss-Jordan inversion in place with partial pivoting, then one
    product.

    Under ``vmap`` on XLA:CPU, ``jnp.linalg.solve`` calls LAPACK's ``getrf`` and ``trsm`` once per system, about
    three microseconds for a 12 x 12 system with 24 right-hand sides; here each of the ``n`` pivot steps is a
    row exchange (a gather) and one fused elimination over the whole batch, and the right-hand sides take one
    batched ``dot``: a third of the time. Each step picks the largest remaining entry of its column as the pivot
    (``jnp.linalg.solve``'s choice), and the result agrees with it to round-off. A singular ``W`` gives
    non-finite values, as LU does. The pivot steps run in a ``fori_loop`` unrolled by two: fully unrolled
    they were 5 % faster in the batched DARE at 1,024 and took 70 % longer to compile. Tried and slower on
    the 2-core CPU (1,024 systems of 12 x 12, 24 right-hand sides; this form 1.0 ms, LAPACK 3.1 ms): the row
    exchange as selects fused into the elimination (5.5 ms), pivot rows picked in place by a mask instead of
    exchanged (2.2-3.9 ms), and the same steps element by element with the batch last, ``[n, n, batch]``
    (12.5 ms: XLA:CPU's fused selects over broadcast rows run at several ns an entry).
    """
    n = W.shape[0]
    rows = jnp.arange(n)

    def pivot(k, carry):
        M, order = carry
        p = jnp.argmax(jnp.where(rows >= k, jnp.abs(M[:, k]), -1))
        at_k, at_p = rows == k, rows == p
        swap = jnp.where(at_k, p, jnp.where(at_p, k, rows))
        M, order = M[swap], order[swap]
        # the exchanged rows in memory before the elimination reads them: fused into it, the exchange is
        # recomputed per entry (measured 5x slower)
        M = lax.optimization_barrier(M)
        inv = 1 / M[k, k]
        pivot_row = jnp.where(at_k, inv, M[k] * inv)
        column = jnp.where(at_k, 0, M[:, k])
        M = jnp.where(at_k[None, :], 0, M) - column[:, None] * pivot_row[None, :]
        return jnp.where(at_k[:, None], pivot_row[None, :], M), order

    M, order = lax.fori_loop(0, n, pivot, (W, rows), unroll=2)
    return matmul(M, Z[order])
