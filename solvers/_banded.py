r"""Symmetric positive definite block-tridiagonal systems, solved in O(N) by a block Cholesky scan.

The system, ``N`` blocks of size ``m``::

    [ D_0  B_1'                ] [x_0]   [b_0]
    [ B_1  D_1  B_2'           ] [x_1]   [b_1]
    [      B_2  D_2  ...       ] [...] = [...]
    [               B_{N-1} D_{N-1}] [x_{N-1}] [b_{N-1}]

``D_i`` symmetric, ``B_i = H[i, i-1]`` the block below the diagonal. The factor ``H = L L'`` is
block lower bidiagonal: ``L_0 L_0' = D_0`` and, for ``i >= 1``, ``C_i = B_i L_{i-1}^{-T}``,
``L_i L_i' = D_i - C_i C_i'``. A forward scan solves ``L y = b`` (``y_i = L_i^{-1} (b_i - C_i y_{i-1})``)
and a backward one ``L' x = y`` (``x_i = L_i^{-T} (y_i - C_{i+1}' x_{i+1})``): ``O(N m^3)`` work and
``O(N m^2)`` memory, never a dense ``Nm x Nm`` matrix. A trajectory problem whose Hessian couples
each time step with its neighbours (or, grouping ``k`` steps per block, with the ``k`` next) is
one such system.

Differentiable (reverse and forward mode, through the scans) and ``vmap``-able.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
from jaxtyping import Array, Float

from ._linalg import einsum, matmul

__all__ = ["block_pentadiagonal_solve", "block_tridiagonal_solve"]


def _solve_lower(L, B, trans=0):
    return jsl.solve_triangular(L, B, lower=True, trans=trans)


def block_tridiagonal_solve(
    diagonal: Float[Array, "N m m"],
    lower: Float[Array, "N-1 m m"],
    rhs: Float[Array, "N m"],
) -> tuple[Float[Array, "N m"], Array]:
    """Solve the symmetric positive definite block-tridiagonal system ``H x = rhs``.

    Args:
        diagonal: ``[N, m, m]`` the diagonal blocks ``D_i`` (symmetric).
        lower: ``[N-1, m, m]`` the blocks below the diagonal, ``lower[i-1] = H[i, i-1]``.
        rhs: ``[N, m]``.

    Returns:
        ``(x [N, m], ok)``: ``ok`` is a scalar bool, ``False`` when ``H`` is not positive definite (or a
        value is not finite): then ``x`` holds NaN.
    """
    N, m = rhs.shape
    if diagonal.shape != (N, m, m) or lower.shape != (max(N - 1, 0), m, m):
        raise ValueError(f"block_tridiagonal_solve: diagonal {diagonal.shape}, lower {lower.shape} and rhs "
                         f"{rhs.shape} do not describe N = {N} blocks of size m = {m}")
    L0 = jnp.linalg.cholesky(diagonal[0])
    y0 = _solve_lower(L0, rhs[0])

    def forward(carry, inputs):
        L_prev, y_prev = carry
        D, B, b = inputs
        C = _solve_lower(L_prev, B.T).T  # C = B L_prev^{-T}
        L = jnp.linalg.cholesky(D - matmul(C, C.T))
        y = _solve_lower(L, b - matmul(C, y_prev))
        return (L, y), (L, C, y)

    _, (Ls, Cs, ys) = jax.lax.scan(forward, (L0, y0), (diagonal[1:], lower, rhs[1:]))
    Ls = jnp.concatenate([L0[None], Ls])
    ys = jnp.concatenate([y0[None], ys])
    x_last = _solve_lower(Ls[-1], ys[-1], trans=1)

    def backward(x_next, inputs):
        L, C_next, y = inputs
        x = _solve_lower(L, y - matmul(C_next.T, x_next), trans=1)
        return x, x

    _, xs = jax.lax.scan(backward, x_last, (Ls[:-1], Cs, ys[:-1]), reverse=True)
    x = jnp.concatenate([xs, x_last[None]])
    ok = jnp.all(jnp.isfinite(x))
    return x, ok


def _triangular_inverse(L, base: int = 17):
    """``L^{-1}`` of lower-triangular ``[..., m, m]`` by halves: ``[[A, 0], [X, C]]`` with ``A``, ``C`` the
    halves' inverses and ``X = -C L21 A``. Below ``base`` a triangular solve against the identity.
    On XLA:CPU the products run several times faster than one triangular solve of the whole
    (about 2x at ``m = 70``), and the result agrees to rounding."""
    m = L.shape[-1]
    if m <= base:
        eye = jnp.broadcast_to(jnp.eye(m, dtype=L.dtype), L.shape)
        return _solve_lower(L, eye)
    h = m // 2
    A, C = _triangular_inverse(L[..., :h, :h], base), _triangular_inverse(L[..., h:, h:], base)
    X = -matmul(C, matmul(L[..., h:, :h], A))
    top = jnp.concatenate([A, jnp.zeros(A.shape[:-1] + (m - h,), L.dtype)], axis=-1)
    return jnp.concatenate([top, jnp.concatenate([X, C], axis=-1)], axis=-2)


def _spd_inverse(S, base: int = 18):
    """``S^{-1}`` of symmetric positive definite ``S``. Above ``base`` by its halves:
    ``G = S_00^{-1}``, ``M = G S_01``, the Schur complement's inverse ``Q_11 = (S_11 - S_10 M)^{-1}``,
    ``Q_01 = -M Q_11``, ``Q_00 = G - Q_01 M'``; at ``base`` and below ``L^{-T} L^{-1}`` of the Cholesky factor
    ``L``. On XLA:CPU the halves' products run faster than the factorization and triangular inverse of the whole
    (35 x 35, two at a time: 27.5 -> 22.5 us), and the result agrees to rounding."""
    m = S.shape[-1]
    if m <= base:
        Li = _triangular_inverse(jax.lax.linalg.cholesky(S, symmetrize_input=False))
        return einsum("...ki,...kj->...ij", Li, Li)
    h = m // 2
    G = _spd_inverse(S[..., :h, :h], base)
    M = matmul(G, S[..., :h, h:])
    Q11 = _spd_inverse(S[..., h:, h:] - matmul(jnp.swapaxes(S[..., :h, h:], -1, -2), M), base)
    Q01 = -matmul(M, Q11)
    Q00 = G - matmul(Q01, jnp.swapaxes(M, -1, -2))
    return jnp.concatenate([jnp.concatenate([Q00, Q01], axis=-1),
                            jnp.concatenate([jnp.swapaxes(Q01, -1, -2), Q11], axis=-1)], axis=-2)


def block_pentadiagonal_solve(
    diagonal: Float[Array, "T n n"],
    band1: Float[Array, "T-1 n"],
    band2: Float[Array, "T-2 n"],
    rhs: Float[Array, "T n"],
) -> tuple[Float[Array, "T n"], Array]:
    r"""Solve ``H x = rhs``, ``H`` symmetric positive definite, block pentadiagonal with **diagonal**
    off-diagonal blocks: ``H[t, t] = diagonal[t]`` (dense), ``H[t+1, t] = diag(band1[t])``,
    ``H[t+2, t] = diag(band2[t])``. A trajectory cost whose coupling between time steps acts on each
    coordinate alone (velocity and acceleration penalties) has this Hessian.

    The steps are paired into blocks of ``2n``, which makes ``H`` block tridiagonal with sub-diagonal
    blocks ``B_s = [[diag(band2[2s-2]), diag(band1[2s-1])], [0, diag(band2[2s-1])]]``, and the block
    LDL' recursion runs on the Schur complements' inverses ``P_s = S_s^{-1}``::

        S_s = D_s - B_s P_{s-1} B_s',    z_s = rhs_s - B_s P_{s-1} z_{s-1},
        x_s = P_s (z_s - B_{s+1}' x_{s+1})   (backwards)

    ``B_s P B_s'`` is a sum of diagonal scalings of ``P``'s blocks (``O(n^2)``), and ``P_s`` is formed from
    ``S_s``'s ``n x n`` blocks, never as one ``2n`` matrix: ``G = S_00^{-1}``, the Schur complement's inverse
    ``Q_11 = (S_11 - S_10 G S_01)^{-1}``, ``Q_01 = -G S_01 Q_11`` and ``Q_00 = G - Q_01 (G S_01)'``, each
    inverse by a Cholesky factorization of ``n``, a triangular inverse (by halves, mostly matrix products)
    and ``L^{-T} L^{-1}``: ``O(T n^3)`` in all, with no triangular solve against a full matrix. On XLA:CPU
    the blocks save the copies that assembled the ``2n`` matrices and their factors, and most of a ``2n``
    factorization's arithmetic (one 120-step system of 35 on 2 cores: 4.5 -> 3.1 ms). The loop reads each
    pair's diagonal blocks from ``diagonal`` where it needs them: under ``vmap``, assembling the pairs'
    blocks before the loop moved every block through memory twice more (a third of the solve's time at 32
    systems of 120 steps of 35).

    Returns:
        ``(x [T, n], ok)``: ``ok`` False when ``H`` is not positive definite or a value is not finite
        (then ``x`` holds NaN).
    """
    T, n = rhs.shape
    if diagonal.shape != (T, n, n) or band1.shape != (max(T - 1, 0), n) or band2.shape != (max(T - 2, 0), n):
        raise ValueError(f"block_pentadiagonal_solve: diagonal {diagonal.shape}, band1 {band1.shape}, band2 "
                         f"{band2.shape} and rhs {rhs.shape} do not describe T = {T} blocks of size n = {n}")
    dtype = rhs.dtype
    pad = T % 2  # one identity step more
    zero = jnp.zeros((1, n), dtype)
    D = jnp.concatenate([diagonal, jnp.eye(n, dtype=dtype)[None]]) if pad else diagonal
    b = jnp.concatenate([rhs, zero]) if pad else rhs
    N = D.shape[0] // 2
    e1 = jnp.concatenate([zero, band1, jnp.zeros((2, n), dtype)])[: 2 * N + 1]  # e1[t] = H[t, t-1]
    e2 = jnp.concatenate([jnp.zeros((2, n), dtype), band2, jnp.zeros((2, n), dtype)])[: 2 * N]  # H[t, t-2]
    # beta[s] [3, n]: the diagonals of B_s = [[diag(beta0), diag(beta1)], [0, diag(beta2)]] (pair s's rows,
    # pair s-1's columns; zero for s = 0)
    beta = jnp.stack([e2[0::2], e1[0:2 * N:2], e2[1::2]], axis=1)  # [N, 3, n]
    inner = e1[1::2]  # [N, n]: H[2s+1, 2s]

    def forward(carry, inputs):
        (P00, P01, P11), (w0_prev, w1_prev) = carry
        k, (b0, b1, b2), e, (z0, z1) = inputs
        D0 = jax.lax.dynamic_index_in_dim(D, 2 * k, keepdims=False)
        D1 = jax.lax.dynamic_index_in_dim(D, 2 * k + 1, keepdims=False)
        # B P B' by blocks: P's row blocks scaled by B's rows, then its columns by B's columns
        t0, t1 = b0[:, None] * P00 + b1[:, None] * P01.T, b0[:, None] * P01 + b1[:, None] * P11
        u0, u1 = b2[:, None] * P01.T, b2[:, None] * P11
        c0, c1, c2 = b0[None], b1[None], b2[None]
        S00, S11 = D0 - (t0 * c0 + t1 * c1), D1 - u1 * c2
        S01, S10 = jnp.diag(e) - t1 * c2, jnp.diag(e) - (u0 * c0 + u1 * c1)
        # S^{-1} by its blocks: G = S00^{-1}, the Schur complement's inverse Q11, then Q01 and Q00
        G = _spd_inverse(S00)
        M = matmul(G, S01)
        Q11 = _spd_inverse(S11 - matmul(S10, M))
        Q01 = -matmul(M, Q11)
        Q00 = G - matmul(Q01, M.T)
        y0, y1 = z0 - (b0 * w0_prev + b1 * w1_prev), z1 - b2 * w1_prev  # z_s - B_s w_{s-1}
        w = (matmul(Q00, y0) + matmul(Q01, y1), matmul(y0, Q01) + matmul(Q11, y1))
        return ((Q00, Q01, Q11), w), ((Q00, Q01, Q11), w)

    zn, zv = jnp.zeros((n, n), dtype), jnp.zeros(n, dtype)
    pairs = b.reshape(N, 2, n)
    _, (Ps, ws) = jax.lax.scan(forward, ((zn, zn, zn), (zv, zv)), (jnp.arange(N), beta, inner,
                                                                   (pairs[:, 0], pairs[:, 1])))

    def backward(x_next, inputs):
        (P00, P01, P11), (w0, w1), (b0, b1, b2) = inputs
        v0, v1 = b0 * x_next[0], b1 * x_next[0] + b2 * x_next[1]  # B_{s+1}' x_{s+1}
        x = (w0 - (matmul(P00, v0) + matmul(P01, v1)), w1 - (matmul(v0, P01) + matmul(P11, v1)))
        return x, x

    beta_next = jnp.concatenate([beta[1:], jnp.zeros((1, 3, n), dtype)])
    _, (x0, x1) = jax.lax.scan(backward, (zv, zv), (Ps, ws, beta_next), reverse=True)
    x = jnp.stack([x0, x1], axis=1).reshape(2 * N, n)[:T]
    return x, jnp.all(jnp.isfinite(x))
