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

from ._linalg import matmul

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

    ``B_s P B_s'`` is a sum of diagonal scalings of ``P``'s blocks (``O(n^2)``), so each step costs one
    Cholesky factorization of ``2n``, a triangular inverse (by halves, mostly matrix products) and
    one product: ``O(T n^3)`` in all, with no triangular solve against a full matrix.

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
    e1 = jnp.concatenate([band1, zero]) if pad else band1
    e2 = jnp.concatenate([band2, zero]) if pad and T > 1 else band2
    b = jnp.concatenate([rhs, zero]) if pad else rhs
    N = D.shape[0] // 2
    e1 = jnp.concatenate([e1, zero])  # [2N, n]: the last entry unused
    e2 = jnp.concatenate([e2, jnp.zeros((2, n), dtype)])[: 2 * N]  # [2N, n]
    diag = jax.vmap(jnp.diag)
    inner = diag(e1[0::2])  # H[2s+1, 2s]
    Ds = jnp.concatenate([jnp.concatenate([D[0::2], inner], axis=2), jnp.concatenate([inner, D[1::2]], axis=2)], axis=1)
    bs = b.reshape(N, 2 * n)
    # beta[s] [2, 2, n]: the diagonals of B_s's blocks (pair s's rows, pair s-1's columns), s = 1..N-1
    s = jnp.arange(1, N)
    beta = jnp.stack([jnp.stack([e2[2 * s - 2], e1[2 * s - 1]], axis=1),
                      jnp.stack([jnp.zeros_like(e2[2 * s - 1]), e2[2 * s - 1]], axis=1)], axis=1)

    def BPBt(beta, P):  # B P B' by row and column scalings (B's blocks are diagonal): O(n^2)
        top, bottom = P[:n], P[n:]
        Q = jnp.concatenate([beta[0, 0][:, None] * top + beta[0, 1][:, None] * bottom,
                             beta[1, 0][:, None] * top + beta[1, 1][:, None] * bottom])
        left, right = Q[:, :n], Q[:, n:]
        return jnp.concatenate([left * beta[0, 0][None] + right * beta[0, 1][None],
                                left * beta[1, 0][None] + right * beta[1, 1][None]], axis=1)

    def B_times(beta, v):  # B_s v, v [2n]
        return jnp.sum(beta * v.reshape(1, 2, n), axis=1).reshape(2 * n)

    def Bt_times(beta, v):  # B_s' v
        return jnp.sum(beta * v.reshape(2, 1, n), axis=0).reshape(2 * n)

    def inverse(S):
        Li = _triangular_inverse(jnp.linalg.cholesky(S))
        return matmul(jnp.swapaxes(Li, -1, -2), Li)

    P0 = inverse(Ds[0])
    w0 = matmul(P0, bs[0])

    def forward(carry, inputs):
        P_prev, w_prev = carry
        D, beta, b = inputs
        P = inverse(D - BPBt(beta, P_prev))
        w = matmul(P, b - B_times(beta, w_prev))  # P_s z_s
        return (P, w), (P, w)

    _, (Ps, ws) = jax.lax.scan(forward, (P0, w0), (Ds[1:], beta, bs[1:]))
    Ps = jnp.concatenate([P0[None], Ps])
    ws = jnp.concatenate([w0[None], ws])

    def backward(x_next, inputs):
        P, w, beta_next = inputs
        x = w - matmul(P, Bt_times(beta_next, x_next))
        return x, x

    _, xs = jax.lax.scan(backward, ws[-1], (Ps[:-1], ws[:-1], beta), reverse=True)
    x = jnp.concatenate([xs, ws[-1][None]]).reshape(2 * N, n)[:T]
    return x, jnp.all(jnp.isfinite(x))
