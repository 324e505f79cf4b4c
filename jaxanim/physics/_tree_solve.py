r"""The exact ``O(bodies)`` solve of the joint-constrained velocities (step 2 of
:func:`jaxanim.physics.step`).

The joints must form a forest (each body the child of at most one joint, no cycles). Bodies are
eliminated from the leaves to the roots: each child's articulated ``6 x 6`` inertia is folded into
its parent through its joint's small system (``k x k``, ``k`` = the joint's rows), then velocities
and impulses are back-substituted from the roots (the block elimination of the augmented system
``[[M, -J'], [J, cfm]]`` in the order of its tree, Baraff 1996, without fill-in). Bodies at the
same depth are processed together, so a 21-body character takes as many passes as its tree is
deep. The depth levels come from :mod:`jaxanim._tree`, the one tree walk.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import _tree
from .._errors import JaxanimError
from ._bodies import _bmm, _spd_inverse


class _TreePlan(NamedTuple):
    """The static elimination order of a joint forest (numpy index arrays).

    Attributes:
        levels: ``levels[d - 1]`` the joints whose child is at depth ``d >= 1`` (their parent is
            a body), in increasing joint order.
        world: the joints to the world.
        free: the bodies that are no joint's child.
        parent, child: the joints' parent and child bodies.
        padded: ``(joints, children, parents)`` each ``[D, width]``: ``levels`` padded to the
            widest with a dummy joint (index ``joints``) between dummy bodies (index ``bodies``),
            shallowest first, for :func:`_tree_solve_scan`.
    """

    levels: tuple[np.ndarray, ...]
    world: np.ndarray
    free: np.ndarray
    parent: np.ndarray
    child: np.ndarray
    padded: tuple[np.ndarray, np.ndarray, np.ndarray]


@functools.lru_cache(maxsize=None)
def _plan(parent: tuple[int, ...], child: tuple[int, ...], num_bodies: int) -> _TreePlan:
    """The :class:`_TreePlan` of the joints ``(parent[j], child[j])`` over ``num_bodies`` bodies.

    Raises:
        JaxanimError: the joints contain a cycle.
    """
    joint_of = {c: j for j, c in enumerate(child)}  # body -> the joint whose child it is
    body_parent = tuple(parent[joint_of[b]] if b in joint_of else -1 for b in range(num_bodies))
    jointed = [c for j, c in enumerate(child) if parent[j] >= 0]  # bodies below a body
    try:
        index, mask = _tree.padded_levels(body_parent, jointed)
    except JaxanimError as err:
        raise JaxanimError(f"joints: the joints form a cycle ({err}); only trees (forests) of joints are "
                           "supported") from None
    Jn, B = len(parent), num_bodies
    body_joint = np.asarray([joint_of.get(b, Jn) for b in range(num_bodies)] + [Jn], int)
    js = np.sort(np.where(mask, body_joint[index], Jn), axis=1)  # joint order; the dummy joint last
    parent_arr, child_arr = np.asarray(parent, int), np.asarray(child, int)
    parent_pad, child_pad = np.append(parent_arr, B), np.append(child_arr, B)
    levels = tuple(row[row < Jn] for row in js)
    world = np.asarray([j for j, p in enumerate(parent) if p < 0], int)
    free = np.asarray([b for b in range(num_bodies) if b not in joint_of], int)
    return _TreePlan(levels, world, free, parent_arr, child_arr, (js, child_pad[js], parent_pad[js]))


def _tree_solve(plan: _TreePlan, M, p, Jp, Jc, b, C, scan_levels: bool = False):
    """Velocities ``V [bodies, 6, m]`` of the joint-constrained system for ``m`` right-hand sides.

    Solves ``M V = p + sum_j J_j' lambda_j`` with ``J_j V + diag(C_j) lambda_j = b_j`` per joint
    exactly, in ``O(bodies)`` by eliminating bodies from the leaves to the roots (each child's
    articulated ``6 x 6`` inertia ``M^`` and momentum ``p^`` folded into its parent through the
    joint's ``k x k`` system ``S = J_c M^^{-1} J_c' + diag(C)``), then back-substituting from the roots
    (``lambda = S^{-1} (b - J_c M^^{-1} p^ - J_p V_p)``, ``V_c = M^^{-1} (p^ + J_c' lambda)``): the
    block elimination of the augmented matrix ``[[M, -J'], [J, C]]`` whose graph is a tree
    (Baraff 1996), without fill-in.

    Args:
        plan: the joints' :func:`_plan`.
        M: ``[bodies, 6, 6]`` body inertias (plus any soft world rows folded in).
        p: ``[bodies, 6, m]`` momenta.
        Jp, Jc: ``[joints, k, 6]`` each joint's rows on its parent and child (``[v; omega]``).
        b: ``[joints, k, m]`` row targets; C: ``[joints, k]`` their compliance (``> 0`` on rows
            with ``J = 0``).
        scan_levels: run the depth levels as a ``lax.scan`` (one compiled body, levels padded to
            the widest) instead of writing each level out: the same result to the bit, about half
            the compile time, ~1.4x the run time under ``vmap`` (dynamic gathers / scatters).
    """
    if scan_levels:
        return _tree_solve_scan(plan, M, p, Jp, Jc, b, C)
    parent, child = plan.parent, plan.child
    Mhat, phat = M, p
    saved = []
    for js in reversed(plan.levels):
        c, pa = child[js], parent[js]
        X, y, Sinv, r = _eliminate(Mhat[c], phat[c], Jc[js], C[js], b[js])
        Mhat, phat = _fold(Mhat, phat, pa, Jp[js], Sinv, r)
        saved.append((js, c, pa, X, y, Sinv, r))
    V = _roots(plan, Mhat, phat, Jc, C, b)
    for js, c, pa, X, y, Sinv, r in reversed(saved):
        V = _back_substitute(V, c, pa, Jp[js], X, y, Sinv, r)
    return V


def _eliminate(Mhat_c, phat_c, Jc, C, b):
    """A level's joints given their children's articulated inertias and momenta: ``(X = M^^{-1}
    J_c' [n, 6, k], y = M^^{-1} p^ [n, 6, m], S^{-1} [n, k, k], r = b - J_c y [n, k, m])``."""
    Minv = _spd_inverse(Mhat_c)
    X = _bmm(Minv, jnp.swapaxes(Jc, -1, -2))
    y = _bmm(Minv, phat_c)
    S = _bmm(Jc, X) + jax.vmap(jnp.diag)(C)
    return X, y, _spd_inverse(S), b - _bmm(Jc, y)


def _fold(Mhat, phat, pa, Jp, Sinv, r):
    """Add a level's joints to their parents: ``M^_p += J_p' S^{-1} J_p``, ``p^_p += J_p' S^{-1} r``."""
    SinvJp = _bmm(Sinv, Jp)  # [n, k, 6]
    return (Mhat.at[pa].add(_bmm(jnp.swapaxes(Jp, -1, -2), SinvJp)),
            phat.at[pa].add(_bmm(jnp.swapaxes(SinvJp, -1, -2), r)))


def _roots(plan: _TreePlan, Mhat, phat, Jc, C, b):
    """Velocities of the free roots (``M^^{-1} p^``) and of the bodies jointed to the world."""
    world, free, child = plan.world, plan.free, plan.child
    V = jnp.zeros_like(phat)
    if free.size:
        V = V.at[free].set(_bmm(_spd_inverse(Mhat[free]), phat[free]))
    if world.size:
        c = child[world]
        X, y, Sinv, r = _eliminate(Mhat[c], phat[c], Jc[world], C[world], b[world])
        V = V.at[c].set(y + _bmm(X, _bmm(Sinv, r)))
    return V


def _back_substitute(V, c, pa, Jp, X, y, Sinv, r):
    """A level's impulses ``lambda = S^{-1} (r - J_p V_p)`` and child velocities ``y + X lambda``."""
    lam = _bmm(Sinv, r - _bmm(Jp, V[pa]))
    return V.at[c].set(y + _bmm(X, lam))


def _tree_solve_scan(plan: _TreePlan, M, p, Jp, Jc, b, C):
    """:func:`_tree_solve` with the depth levels in a ``lax.scan``: levels padded to the widest with
    a dummy joint (no rows: ``J = 0``, ``C = 1``) between dummy bodies (``M = I``, ``p = 0``)."""
    B = M.shape[0]
    Mhat = jnp.concatenate([M, jnp.eye(6, dtype=M.dtype)[None]])
    phat = jnp.concatenate([p, jnp.zeros_like(p[:1])])
    if not plan.levels:
        return _roots(plan, Mhat, phat, Jc, C, b)[:B]
    Jp = jnp.concatenate([Jp, jnp.zeros_like(Jp[:1])])
    Jc = jnp.concatenate([Jc, jnp.zeros_like(Jc[:1])])
    b = jnp.concatenate([b, jnp.zeros_like(b[:1])])
    C = jnp.concatenate([C, jnp.ones_like(C[:1])])
    xs = plan.padded  # [D, width] each, shallowest first

    def up(carry, level):
        Mhat, phat = carry
        js, c, pa = level
        X, y, Sinv, r = _eliminate(Mhat[c], phat[c], Jc[js], C[js], b[js])
        return _fold(Mhat, phat, pa, Jp[js], Sinv, r), (X, y, Sinv, r)

    (Mhat, phat), saved = jax.lax.scan(up, (Mhat, phat), xs, reverse=True)

    def down(V, level):
        (js, c, pa), (X, y, Sinv, r) = level
        return _back_substitute(V, c, pa, Jp[js], X, y, Sinv, r), None

    V, _ = jax.lax.scan(down, _roots(plan, Mhat, phat, Jc, C, b), (xs, saved))
    return V[:B]
