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

__all__ = ["block_tridiagonal_solve"]


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
