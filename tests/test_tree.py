"""The one tree walk (jaxanim._tree) against brute-force definitions."""

from __future__ import annotations

import numpy as np
import pytest

from jaxanim import JaxanimError, _tree


def _brute_depth(parents, j):
    d = 0
    while parents[j] >= 0:
        j = parents[j]
        d += 1
    return d


@pytest.mark.parametrize("seed", range(5))
def test_random_forests_in_any_order(seed):
    rng = np.random.default_rng(seed)
    n = 30
    topo = [-1] + [int(rng.integers(-1 if k % 9 == 0 else 0, k)) for k in range(1, n)]  # a forest
    perm = rng.permutation(n)  # relabel: parents no longer come before children
    inv = np.argsort(perm)
    parents = tuple(-1 if topo[inv[j]] < 0 else int(perm[topo[inv[j]]]) for j in range(n))
    d = _tree.depths(parents)
    assert d == tuple(_brute_depth(parents, j) for j in range(n))
    levels = _tree.levels(parents)
    assert sorted(j for lev in levels for j in lev) == list(range(n))
    assert all(d[j] == k for k, lev in enumerate(levels) for j in lev)
    for j in range(n):
        chain = _tree.ancestors(parents, j)
        assert chain[-1] == j and len(chain) == d[j] + 1 and parents[chain[0]] == -1
        assert all(parents[b] == a for a, b in zip(chain, chain[1:]))
    below = _tree.subtree(parents)
    assert all(below[a, j] == (a in _tree.ancestors(parents, j)) for a in range(n) for j in range(n))


def test_padded_levels():
    parents = (-1, 0, 0, 1, 1, 2, 5)
    index, mask = _tree.padded_levels(parents)
    rows = [tuple(index[l][mask[l]]) for l in range(index.shape[0])]
    assert rows == [(0,), (1, 2), (3, 4, 5), (6,)] and index.shape == (4, 3)
    index, mask = _tree.padded_levels(parents, nodes=(6, 3, 0), deepest_first=True)
    assert [tuple(index[l][mask[l]]) for l in range(index.shape[0])] == [(6,), (3,), (0,)]
    assert not index[~mask].any()


def test_bad_trees():
    with pytest.raises(JaxanimError, match="cycle: 1 -> 2 -> 1"):
        _tree.depths((-1, 2, 1))
    with pytest.raises(JaxanimError, match=r"parents\[1\] = 5"):
        _tree.depths((-1, 5))
