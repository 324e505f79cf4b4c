"""Tests of solvers._linalg: the unrolled small Cholesky, solves and products equal numpy's, and a
matrix that is not positive definite gives NaN factors (as jnp.linalg.cholesky does)."""

from __future__ import annotations

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
