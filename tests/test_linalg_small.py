"""Tests of solvers._linalg: the unrolled small Cholesky, solves and products equal numpy's, a matrix that
is not positive definite gives NaN factors (as jnp.linalg.cholesky does), and the pivoted Gauss-Jordan solve
equals numpy's LU solve, also where it must exchange rows, and is non-finite for a singular matrix."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from solvers import _linalg


@pytest.mark.parametrize("m", [1, 2, 4, _linalg.UNROLL_MAX, _linalg.UNROLL_MAX + 2])
def test_cholesky_solve_and_products_equal_numpy(m):
    rng = np.random.default_rng(m)
    G = rng.standard_normal((m, m))
    H = G @ G.T + 0.1 * np.eye(m)
    B = rng.standard_normal((m, 3))
    L = _linalg.cholesky(jnp.asarray(H))
    np.testing.assert_allclose(L, np.linalg.cholesky(H), atol=1e-12, rtol=0)
    np.testing.assert_allclose(_linalg.cho_solve(L, jnp.asarray(B)), np.linalg.solve(H, B), atol=1e-10, rtol=0)
    np.testing.assert_allclose(_linalg.cho_solve(L, jnp.asarray(B[:, 0])), np.linalg.solve(H, B[:, 0]), atol=1e-10)
    np.testing.assert_allclose(_linalg.mm(jnp.asarray(G), jnp.asarray(B)), G @ B, atol=1e-13, rtol=0)
    np.testing.assert_allclose(_linalg.mm(jnp.asarray(G), jnp.asarray(B[:, 1])), G @ B[:, 1], atol=1e-13, rtol=0)


@pytest.mark.parametrize("m", [2, _linalg.UNROLL_MAX + 1])
def test_cholesky_of_indefinite_matrix_is_nan(m):
    H = np.eye(m)
    H[-1, -1] = -1.0
    assert not np.all(np.isfinite(np.asarray(_linalg.cholesky(jnp.asarray(H)))))


def test_large_products_use_dot():
    a = jnp.ones((40, 40))
    np.testing.assert_allclose(_linalg.mm(a, a), np.full((40, 40), 40.0))


def test_gauss_jordan_solve_equals_numpy():
    rng = np.random.default_rng(7)
    for n in (1, 2, 5, 12):
        W = rng.standard_normal((40, n, n))
        Z = rng.standard_normal((40, n, 2 * n))
        X = jax.jit(jax.vmap(_linalg.solve))(jnp.asarray(W), jnp.asarray(Z))
        ref = np.linalg.solve(W, Z)
        err = np.max(np.abs(X - ref), axis=(1, 2)) / np.max(np.abs(ref), axis=(1, 2))
        assert np.max(err) < 1e-11, (n, np.max(err))
    # a zero (and a tiny) leading diagonal: only a row exchange makes the elimination possible (or accurate)
    for corner in (0.0, 1e-14):
        W = np.array([[corner, 2.0, 1.0], [3.0, 1.0, 0.0], [1.0, 1.0, 4.0]])
        Z = np.eye(3)
        np.testing.assert_allclose(_linalg.solve(jnp.asarray(W), jnp.asarray(Z)), np.linalg.inv(W), atol=1e-14)
    singular = np.array([[1.0, 2.0], [2.0, 4.0]])
    assert not np.all(np.isfinite(np.asarray(_linalg.solve(jnp.asarray(singular), jnp.eye(2)))))
