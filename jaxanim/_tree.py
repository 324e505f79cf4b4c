"""The one tree walk: depths, depth levels, ancestor chains and subtrees of a forest.

A kinematic tree (a skeleton's joints, a character's bodies) is given as ``parents``: a tuple with
one entry per node, the index of its parent or ``-1`` for a root. FK, the Jacobians, CCD and the
physics tree solve all traverse it **per depth level** (as brax ``scan.tree`` and MJX
``scan.body_tree`` do), so that the compiled program has O(depth) operations, not O(nodes). This
module is the one place that plans those traversals. Everything here is static (plain Python and
NumPy on hashable tuples, cached), computed once per structure at trace time.
"""

from __future__ import annotations

import functools

import numpy as np

from ._errors import JaxanimError

__all__ = ["ancestors", "depths", "levels", "padded_levels", "subtree"]


def _as_parents(parents) -> tuple[int, ...]:
    return tuple(int(p) for p in parents)


@functools.lru_cache(maxsize=512)
def _depths(parents: tuple[int, ...]) -> tuple[int, ...]:
    n = len(parents)
    depth = [-1] * n
    for start in range(n):
        chain = []
        node = start
        while node >= 0 and depth[node] < 0:
            if not -1 <= parents[node] < n:
                raise JaxanimError(f"parents[{node}] = {parents[node]}: expected -1 or a node index in [0, {n})")
            if node in chain:
                cycle = chain[chain.index(node):] + [node]
                raise JaxanimError("the tree has a cycle: " + " -> ".join(map(str, cycle)))
            chain.append(node)
            node = parents[node]
        base = -1 if node < 0 else depth[node]
        for k, c in enumerate(reversed(chain)):
            depth[c] = base + 1 + k
    return tuple(depth)


def depths(parents) -> tuple[int, ...]:
    """Depth of every node (a root is 0). ``parents`` need not be in topological order.

    Raises:
        JaxanimError: a parent index out of range, or a cycle.
    """
    return _depths(_as_parents(parents))


@functools.lru_cache(maxsize=512)
def _levels(parents: tuple[int, ...]) -> tuple[tuple[int, ...], ...]:
    d = _depths(parents)
    if not d:
        return ()
    return tuple(tuple(j for j, dj in enumerate(d) if dj == lev) for lev in range(max(d) + 1))


def levels(parents) -> tuple[tuple[int, ...], ...]:
    """Nodes grouped by depth, root level first: ``levels(parents)[d]`` are the nodes at depth ``d``
    in increasing index order."""
    return _levels(_as_parents(parents))


@functools.lru_cache(maxsize=512)
def _ancestors(parents: tuple[int, ...], node: int) -> tuple[int, ...]:
    _depths(parents)  # validates (and rejects cycles)
    chain = []
    while node >= 0:
        chain.append(node)
        node = parents[node]
    return tuple(reversed(chain))


def ancestors(parents, node: int) -> tuple[int, ...]:
    """The chain from the root down to ``node``, both included: ``chain[d]`` is at depth ``d``."""
    return _ancestors(_as_parents(parents), int(node))


@functools.lru_cache(maxsize=512)
def _subtree(parents: tuple[int, ...]) -> np.ndarray:
    n = len(parents)
    below = np.eye(n, dtype=bool)
    for j in range(n):
        for a in _ancestors(parents, j):
            below[a, j] = True
    below.setflags(write=False)
    return below


def subtree(parents) -> np.ndarray:
    """``[N, N]`` boolean (read-only): ``subtree(parents)[a, j]`` is true when ``j`` is ``a`` or
    one of its descendants."""
    return _subtree(_as_parents(parents))


def padded_levels(parents, nodes=None, *, deepest_first: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The depth levels of ``nodes`` (default all), padded to the widest, for a ``lax.scan`` over
    levels whose compiled body does not grow with the depth.

    Levels with no selected node are dropped.

    Returns:
        ``(index [L, W] int, mask [L, W] bool)``: ``index[l, k]`` is the k-th node of level ``l``
        (root level first, or deepest first with ``deepest_first=True``), padded with 0 where
        ``mask`` is false.
    """
    parents = _as_parents(parents)
    keep = None if nodes is None else set(int(j) for j in nodes)
    rows = [tuple(j for j in lev if keep is None or j in keep) for lev in _levels(parents)]
    rows = [r for r in rows if r]
    if deepest_first:
        rows = rows[::-1]
    width = max((len(r) for r in rows), default=0)
    index = np.zeros((len(rows), width), dtype=np.int64)
    mask = np.zeros((len(rows), width), dtype=bool)
    for lev, r in enumerate(rows):
        index[lev, : len(r)] = r
        mask[lev, : len(r)] = True
    return index, mask
