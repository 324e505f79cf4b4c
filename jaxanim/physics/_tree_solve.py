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
        chains: ``[bodies + 1, D + 1]``: ``chains[b, d]`` the ancestor of body ``b`` at depth ``d`` (``b`` itself
            at its own depth; :func:`jaxanim._tree.ancestors`), the dummy body ``bodies`` past that depth and on
            the dummy's own row.
        depth: ``[bodies + 1]`` each body's depth (-2 for the dummy: no depth matches it).
    """

    levels: tuple[np.ndarray, ...]
    world: np.ndarray
    free: np.ndarray
    parent: np.ndarray
    child: np.ndarray
    padded: tuple[np.ndarray, np.ndarray, np.ndarray]
    chains: np.ndarray
    depth: np.ndarray


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
    depth = np.append(np.asarray(_tree.depths(body_parent), int), -2)
    chains = np.full((B + 1, max(depth.max(), 0) + 1), B)
    for b in range(B):
        chain = _tree.ancestors(body_parent, b)
        chains[b, :len(chain)] = chain
    return _TreePlan(levels, world, free, parent_arr, child_arr, (js, child_pad[js], parent_pad[js]), chains, depth)


def _tree_solve(plan: _TreePlan, M, p, Jp, Jc, b, C, scan_levels: bool = False):
    """Velocities ``V [bodies, 6, m]`` of the joint-constrained system for ``m`` right-hand sides.

    Solves ``M V = p + sum_j J_j' lambda_j`` with ``J_j V + diag(C_j) lambda_j = b_j`` per joint
    exactly, in ``O(bodies)`` by eliminating bodies from the leaves to the roots (each child's
    articulated ``6 x 6`` inertia ``M^`` and momentum ``p^`` folded into its parent through the
    joint's ``k x k`` system ``S = J_c M^^{-1} J_c' + diag(C)``), then back-substituting from the roots
    (``lambda = S^{-1} (b - J_c M^^{-1} p^ - J_p V_p)``, ``V_c = M^^{-1} (p^ + J_c' lambda)``): the
    block elimination of the augmented matrix ``[[M, -J'], [J, C]]`` whose graph is a tree
    (Baraff 1996), without fill-in. It is split into :func:`_factor` (what depends on ``M, J, C``
    only) and :func:`_substitute` (the right-hand sides).

    Differentiated implicitly (:func:`_implicit_jvp`): the tangent ``dV`` is one more substitution
    through the same factors, with the right-hand sides ``dp - dM V + dJ' lambda`` and
    ``db - dJ V - dC lambda`` of the linearized system, instead of the derivative of every
    elimination step: the JVP of a physics step compiles faster and runs faster, which is most of
    ``tracking.linearize``. (``M`` is taken as symmetric, as the bodies' inertias are: it is the
    derivative of the symmetric system.)

    Args:
        plan: the joints' :func:`_plan`.
        M: ``[bodies, 6, 6]`` body inertias (plus any soft world rows folded in).
        p: ``[bodies, 6, m]`` momenta.
        Jp, Jc: ``[joints, k, 6]`` each joint's rows on its parent and child (``[v; omega]``).
        b: ``[joints, k, m]`` row targets; C: ``[joints, k]`` their compliance (``> 0`` on rows
            with ``J = 0``).
        scan_levels: run the depth levels as a ``lax.scan`` (one compiled body, levels padded to
            the widest) instead of writing each level out: the same result to round-off, about half
            the compile time, ~1.4x the run time under ``vmap`` (dynamic gathers / scatters).
    """
    return _implicit(plan, scan_levels, M, p, Jp, Jc, b, C)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def _implicit(plan, scan_levels, M, p, Jp, Jc, b, C):
    return _tree_solve_multipliers(plan, M, p, Jp, Jc, b, C, scan_levels)[0]


@_implicit.defjvp
def _implicit_jvp(plan, scan_levels, primals, tangents):
    M, p, Jp, Jc, b, C = primals
    dM, dp, dJp, dJc, db, dC = tangents
    factors = _factor(plan, M, Jp, Jc, C, scan_levels)
    V, lam = _substitute(plan, factors, p, Jp, Jc, b, scan_levels)
    rhs_p = _joints_from(plan, dJp, dJc, lam, dp - _bmm(dM, V))
    rhs_b = db - _joints_on(plan, dJp, dJc, V) - dC[..., None] * lam
    dV, _ = _substitute(plan, factors, rhs_p, Jp, Jc, rhs_b, scan_levels)
    return V, dV


def _joints_on(plan: _TreePlan, Jp, Jc, X):
    """``J X [joints, k, m]``: every joint's rows on its child's and parent's ``X [bodies, 6, m]``."""
    out = _bmm(Jc, X[plan.child])
    jointed = np.flatnonzero(plan.parent >= 0)
    if jointed.size:
        out = _add_rows(out, jointed, _bmm(Jp[jointed], X[plan.parent[jointed]]))
    return out


def _joints_from(plan: _TreePlan, Jp, Jc, lam, base):
    """``base + J' lam [bodies, 6, m]`` for the joints' multipliers ``lam [joints, k, m]``."""
    out = _add_rows(base, plan.child, _bmm(jnp.swapaxes(Jc, -1, -2), lam))
    jointed = np.flatnonzero(plan.parent >= 0)
    if jointed.size:
        out = _add_rows(out, plan.parent[jointed], _bmm(jnp.swapaxes(Jp[jointed], -1, -2), lam[jointed]))
    return out


def _add_rows(a, idx, x):
    """``a.at[idx].add(x)`` for a static ``idx``, as gathers of ``x``'s rows (a zero row where a row of ``a``
    gets nothing; one gather per repeat of an index): elementwise, so XLA:CPU fuses it with the arithmetic
    around it, where a scatter is a pass of its own over the whole of ``a`` (under ``jacfwd``, ``a`` is every
    tangent's right-hand sides)."""
    idx = np.asarray(idx)
    xz = jnp.concatenate([x, jnp.zeros((1,) + x.shape[1:], x.dtype)])
    left = np.arange(idx.size)
    while left.size:
        first = np.unique(idx[left], return_index=True)[1]
        pos = np.full(a.shape[0], idx.size)
        pos[idx[left[first]]] = left[first]
        a = a + xz[pos]
        left = np.delete(left, first)
    return a


def _tree_solve_multipliers(plan: _TreePlan, M, p, Jp, Jc, b, C, scan_levels: bool = False):
    """``(V [bodies, 6, m], lambda [joints, k, m])`` of :func:`_tree_solve`, without its implicit
    derivative (differentiating this differentiates every elimination step)."""
    return _substitute(plan, _factor(plan, M, Jp, Jc, C, scan_levels), p, Jp, Jc, b, scan_levels)


def _pad(a, value):
    """``a`` with one more leading entry ``value``: the dummy body or joint of the scanned solve."""
    return jnp.concatenate([a, jnp.broadcast_to(value, a.shape[1:])[None].astype(a.dtype)])


def _joint_factor(Mhat_c, Jc, C):
    """Joints given their children's articulated inertias ``Mhat_c``: ``(M^^{-1} [n, 6, 6],
    X = M^^{-1} J_c' [n, 6, k], S^{-1} [n, k, k])``."""
    Minv = _spd_inverse(Mhat_c)
    X = _bmm(Minv, jnp.swapaxes(Jc, -1, -2))
    return Minv, X, _spd_inverse(_bmm(Jc, X) + jax.vmap(jnp.diag)(C))


def _level_factor(Mhat, pa, Mhat_c, Jp, Jc, C):
    """A level's joints: the parents' inertias with ``J_p' S^{-1} J_p`` added, and the level's
    factors ``(M^^{-1}, X, S^{-1}, S^{-1} J_p [n, k, 6])`` (:func:`_joint_factor`)."""
    Minv, X, Sinv = _joint_factor(Mhat_c, Jc, C)
    SinvJp = _bmm(Sinv, Jp)
    return Mhat.at[pa].add(_bmm(jnp.swapaxes(Jp, -1, -2), SinvJp)), (Minv, X, Sinv, SinvJp)


def _joint_up(phat_c, Jc, b, Minv):
    """``(y = M^^{-1} p^_c, r = b - J_c y)``."""
    y = _bmm(Minv, phat_c)
    return y, b - _bmm(Jc, y)


def _level_up(phat, c, pa, Jc, b, factors):
    """A level's right-hand sides: the parents' momenta with ``(S^{-1} J_p)' r`` added, and
    ``(y, r)`` (:func:`_joint_up`)."""
    Minv, _, _, SinvJp = factors
    y, r = _joint_up(phat[c], Jc, b, Minv)
    return phat.at[pa].add(_bmm(jnp.swapaxes(SinvJp, -1, -2), r)), (y, r)


def _joint_down(V, lam, js, c, X, Sinv, y, r):
    """Joints' multipliers ``lambda = S^{-1} r`` and child velocities ``y + X lambda`` (``V`` and
    ``lam`` start at zero and each entry is written once: added, which transposes)."""
    lam_js = _bmm(Sinv, r)
    return V.at[c].add(y + _bmm(X, lam_js)), lam.at[js].add(lam_js)


def _level_down(V, lam, js, c, pa, Jp, factors, yr):
    """A level's multipliers and child velocities (:func:`_joint_down` with ``r - J_p V_p``)."""
    _, X, Sinv, _ = factors
    y, r = yr
    return _joint_down(V, lam, js, c, X, Sinv, y, r - _bmm(Jp, V[pa]))


def _root_factors(plan: _TreePlan, Mhat, Jc, C):
    """The factors of the free roots (``M^^{-1}``) and of the joints to the world
    (:func:`_joint_factor`)."""
    world, free, child = plan.world, plan.free, plan.child
    free_inv = _spd_inverse(Mhat[free]) if free.size else None
    world_f = _joint_factor(Mhat[child[world]], Jc[world], C[world]) if world.size else None
    return free_inv, world_f


def _roots(plan: _TreePlan, roots, phat, Jc, b, lam):
    """Velocities of the free roots (``M^^{-1} p^``) and of the bodies jointed to the world, and
    ``lam`` with the world joints' multipliers added."""
    world, free, child = plan.world, plan.free, plan.child
    free_inv, world_f = roots
    V = jnp.zeros_like(phat)
    if free.size:
        V = V.at[free].add(_bmm(free_inv, phat[free]))
    if world.size:
        c = child[world]
        Minv, X, Sinv = world_f
        y, r = _joint_up(phat[c], Jc[world], b[world], Minv)
        V, lam = _joint_down(V, lam, world, c, X, Sinv, y, r)
    return V, lam


def _factor(plan: _TreePlan, M, Jp, Jc, C, scan_levels: bool):
    """Everything of the elimination that depends on ``M, J, C`` only: ``(level factors, root
    factors)``; with ``scan_levels``, the levels' factors stacked ``[D, width, ...]`` over the padded
    levels (a dummy body ``M = I`` and a dummy joint ``J = 0``, ``C = 1`` appended)."""
    if scan_levels:
        M, Jp, Jc, C = _pad(M, jnp.eye(6)), _pad(Jp, 0.0), _pad(Jc, 0.0), _pad(C, 1.0)
        if not plan.levels:
            return None, _root_factors(plan, M, Jc, C)

        def up(Mhat, level):
            js, c, pa = level
            return _level_factor(Mhat, pa, Mhat[c], Jp[js], Jc[js], C[js])

        Mhat, levels = jax.lax.scan(up, M, plan.padded, reverse=True)
        return levels, _root_factors(plan, Mhat, Jc, C)
    Mhat, levels = M, []
    for js in reversed(plan.levels):
        Mhat, f = _level_factor(Mhat, plan.parent[js], Mhat[plan.child[js]], Jp[js], Jc[js], C[js])
        levels.append(f)
    return levels, _root_factors(plan, Mhat, Jc, C)


def _substitute(plan: _TreePlan, factors, p, Jp, Jc, b, scan_levels: bool):
    """``(V [bodies, 6, m], lambda [joints, k, m])`` for the right-hand sides ``p, b`` through the
    factors of :func:`_factor`: the leaves-to-roots pass (:func:`_up`), then the roots-to-leaves pass
    (:func:`_down`)."""
    B, J = p.shape[0], b.shape[0]
    if scan_levels:
        p, Jp, Jc, b = _pad(p, 0.0), _pad(Jp, 0.0), _pad(Jc, 0.0), _pad(b, 0.0)
    phat, saved = _up(plan, factors, p, Jc, b, scan_levels)
    V, lam = _down(plan, factors, phat, Jp, Jc, b, saved, scan_levels)
    return V[:B], lam[:J]


def _up(plan: _TreePlan, factors, p, Jc, b, scan_levels: bool):
    """The leaves-to-roots pass of :func:`_substitute` (with ``scan_levels``, ``p``, ``Jc``, ``b`` padded by
    :func:`_pad`): ``(phat, saved)``, each body's momentum with its descendants' folded in, and each level's ``(y, r)``
    (:func:`_joint_up`), stacked over the padded levels with ``scan_levels``."""
    levels, _ = factors
    if scan_levels:
        if levels is None:
            return p, None

        def up(phat, x):
            (js, c, pa), f = x
            return _level_up(phat, c, pa, Jc[js], b[js], f)

        return jax.lax.scan(up, p, (plan.padded, levels), reverse=True)
    phat, saved = p, []
    for js, f in zip(reversed(plan.levels), levels):
        phat, yr = _level_up(phat, plan.child[js], plan.parent[js], Jc[js], b[js], f)
        saved.append(yr)
    return phat, saved


def _down(plan: _TreePlan, factors, phat, Jp, Jc, b, saved, scan_levels: bool):
    """The roots-to-leaves pass of :func:`_substitute`: ``(V, lambda)`` from the momenta ``phat`` of :func:`_up`
    (padded with ``scan_levels``), with each level's ``(y, r)`` from ``saved``, or computed from ``phat`` where
    ``saved`` is ``None``."""
    levels, roots = factors

    def yr_of(c, js, f):
        return _joint_up(phat[c], Jc[js], b[js], f[0])

    V, lam = _roots(plan, roots, phat, Jc, b, jnp.zeros_like(b))
    if scan_levels:
        if levels is None:
            return V, lam

        def down(carry, x):
            (js, c, pa), f, *yr = x
            return _level_down(*carry, js, c, pa, Jp[js], f, yr[0] if yr else yr_of(c, js, f)), None

        xs = (plan.padded, levels) if saved is None else (plan.padded, levels, saved)
        return jax.lax.scan(down, (V, lam), xs)[0]
    saved = [None] * len(levels) if saved is None else saved
    for js, f, yr in zip(plan.levels, reversed(levels), reversed(saved)):
        c = plan.child[js]
        V, lam = _level_down(V, lam, js, c, plan.parent[js], Jp[js], f, yr_of(c, js, f) if yr is None else yr)
    return V, lam


def _body_blocks(plan: _TreePlan, factors, num_bodies: int, scan_levels: bool, up=None):
    """Per body, from :func:`_factor`: ``(D, T, w, slot)``, ``D`` and ``T`` ``[n + 1, 6, 6]`` stacked in the
    factors' order (a zero block last) and ``slot [bodies + 1]`` (numpy) the row of each body's blocks (the dummy
    body ``bodies``: the zero block): the level factors' blocks side by side, without writing each level into
    arrays in body order.

    For right-hand sides ``(z, 0)`` the leaves-to-roots pass of :func:`_substitute` carries the momentum that
    reaches a body's parent from the body as ``T z`` (``T = -(X S^{-1} J_p)'`` of the body's joint, 0 at a root),
    and ``z_1' H^{-1} z_2`` (``H^{-1}`` the velocities' block of the joint system's inverse) is the sum over the
    bodies of ``p^_1' D p^_2`` for the momenta ``p^`` that reach them: ``D = M^^{-1} - X S^{-1} X'`` for a joint's
    child (its block ``[[M^, J_c'], [J_c, -C]]`` of the symmetric system in ``mu = -lambda``) and ``M^^{-1}`` for a
    free root.

    With ``up = (phat, saved, Jc, b)`` of :func:`_up` (padded with ``scan_levels``), ``w [n + 1, 6, m]`` in the
    same rows: each body's velocity were its parent at rest, ``y + X S^{-1} r`` of its joint (:func:`_joint_up`;
    ``M^^{-1} p^`` for a free root), so that the roots-to-leaves pass gives ``V = w + T' V_parent`` and
    ``z' V = sum_d phi[d]' w`` over the body's chain for ``phi`` its momentum ``z`` carried up by the ``T`` blocks;
    ``None`` without ``up``."""
    levels, (free_inv, world_f) = factors
    phat, saved, Jc, b = up if up is not None else (None,) * 4
    Ds, Ts, Ws, owners = [], [], [], []

    def put(c, f, yr=None):
        Minv, X, Sinv, *rest = f
        XS = _bmm(X, Sinv)
        Ds.append(Minv - _bmm(XS, jnp.swapaxes(X, -1, -2)))
        Ts.append(-jnp.swapaxes(_bmm(X, rest[0]), -1, -2) if rest else jnp.zeros_like(Minv))
        if yr is not None:
            y, r = yr
            Ws.append(y + _bmm(XS, r))
        owners.append(np.asarray(c).reshape(-1))

    flat = lambda x: jax.tree.map(lambda a: a.reshape((-1,) + a.shape[2:]), x)  # noqa: E731
    if scan_levels and levels is not None:
        put(plan.padded[1], flat(levels), None if up is None else flat(saved))  # the padding's rows: no body's slot
    elif not scan_levels:
        for i, (js, f) in enumerate(zip(reversed(plan.levels), levels)):
            put(plan.child[js], f, None if up is None else saved[i])
    if plan.free.size:
        Ds.append(free_inv)
        Ts.append(jnp.zeros_like(free_inv))
        if up is not None:
            Ws.append(_bmm(free_inv, phat[plan.free]))
        owners.append(plan.free)
    if plan.world.size:
        c = plan.child[plan.world]
        put(c, world_f, None if up is None else _joint_up(phat[c], Jc[plan.world], b[plan.world], world_f[0]))
    owner = np.concatenate(owners)
    slot = np.full(num_bodies + 1, owner.size)
    real = owner < num_bodies
    slot[owner[real]] = np.flatnonzero(real)
    zero = jnp.zeros((1, 6, 6), Ds[0].dtype)
    w = None if up is None else jnp.concatenate(Ws + [jnp.zeros((1,) + Ws[0].shape[1:], Ws[0].dtype)])
    return jnp.concatenate(Ds + [zero]), jnp.concatenate(Ts + [zero]), w, slot
