r"""The joint rows and the one-sided rows (contacts, joint limits) of one step, solved together, and their
derivative.

:func:`solve_rows` eliminates the joints exactly (:func:`~jaxanim.physics._tree_solve._tree_solve`, with the
one-sided rows' columns ``Y = H^{-1} J_u'`` as extra right-hand sides), forms their Delassus matrix
``A = J_u Y`` and solves the contact problem on it by projected Gauss-Seidel. For a few rows (at most
:data:`_CHAIN_ROWS`: a contact step's 8 points) it forms ``A`` without the columns: each row's momentum is carried
from its body up its chain of ancestors by the elimination's per-body blocks, and ``A`` is the sum of their products
at the bodies that two chains share (:func:`_delassus`; the same matrix to round-off). The contact right-hand side
``J_u V_0`` comes from the same chains and the leaves-to-roots pass of ``(p, b)`` (each body's velocity were its parent
at rest, summed along the chain), and the velocities from one roots-to-leaves pass after the impulses' momenta are
carried up the chains: one pass each way where a solve before and one after the impulses took two each.

Its derivative (:func:`_solve_rows_jvp`) needs no derivative of the ``U`` columns ``Y``. With ``S`` the joint
system's solve (``K = [[M, -J_j'], [J_j, C]]``, so that ``K' = D K D`` with ``D = diag(I, -I)``), ``J_u S(z) =
Y' z_p - Lambda_Y' z_b`` for any right-hand side ``z`` (``Lambda_Y`` the joints' multipliers of the columns),
so the tangents of ``A`` and of the contact right-hand side are products of ``Y`` and ``Lambda_Y`` with the
tangents of the rows and inertias (the adjoint form of ``d(J H^{-1} J') = dJ H^{-1} J' + J H^{-1} dJ' - J H^{-1}
dH H^{-1} J'``); the impulses' tangent is the forward derivative of the Gauss-Seidel sweeps, and the velocities'
is one substitution through the joint factors with one column, ``dV = S(dp - dM V + dJ_j' lambda_j + dJ_u'
lambda_u, db - dJ_j V - dC lambda_j) + Y d lambda_u``. Under ``jacfwd`` (``tracking.linearize``: hundreds of
tangents) the substitutions then carry one column per tangent instead of ``1 + U``. As in the tree solve's own
JVP, the inertias' tangent is taken as symmetric (the derivative of the bodies' symmetric inertias).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jax.custom_derivatives import SymbolicZero

from .._linalg import einsum
from ._bodies import _bmm
from ._contact import projected_gauss_seidel
from ._tree_solve import (_body_blocks, _down, _factor, _joints_from, _joints_on, _pad, _substitute, _tree_solve,
                          _up)

__all__ = ["solve_rows"]


def _rows_on(owner_a, rows_a, owner_b, rows_b, L, X):
    """``J_u X [U, m]`` of ``X [bodies, 6, m]``: row ``u`` on body ``owner_a[u]`` (the last ``L`` also on
    ``owner_b``)."""
    out = einsum("uj,ujm->um", rows_a, X[owner_a])
    if L:
        U = out.shape[0]
        out = out.at[U - L:].add(einsum("uj,ujm->um", rows_b, X[owner_b]))
    return out


def _rows_from(B, owner_a, rows_a, owner_b, rows_b, L, lam):
    """``J_u' lam [bodies, 6, m]`` of ``lam [U, m]``."""
    U, m = lam.shape
    out = jnp.zeros((B, 6, m), lam.dtype).at[owner_a].add(rows_a[:, :, None] * lam[:, None, :])
    if L:
        out = out.at[owner_b].add(rows_b[:, :, None] * lam[U - L:, None, :])
    return out


def _assembled(M, Jp, Jc):
    """The inertias ``M = (M_lin, M_ang)`` (``[bodies, 3, 3]`` each) as ``[bodies, 6, 6]`` blocks and the joint
    rows ``J = (geometric, drive)`` (``[joints, k_g, 6]``, ``[joints, k_d, 6]``) stacked ``[joints, k, 6]``."""
    Mt, Mr = M
    z = jnp.zeros_like(Mt)
    M6 = jnp.concatenate([jnp.concatenate([Mt, z], -1), jnp.concatenate([z, Mr], -1)], 1)
    return M6, jnp.concatenate(Jp, axis=1), jnp.concatenate(Jc, axis=1)


def _columns(plan, scan_levels, L, M, p, Jp, Jc, b, C, owner_a, rows_a, target, owner_b, rows_b, cfm):
    """The joint factors, ``(V0, lam0)`` of ``(p, b)``, ``(Y, Lambda_Y)`` of the columns ``J_u'``, and the
    contact problem ``(A, rhs)`` (``M``, ``Jp``, ``Jc`` in parts: :func:`_assembled`)."""
    M, Jp, Jc = _assembled(M, Jp, Jc)
    B, U = M.shape[0], target.shape[0]
    cols = jnp.zeros((B, 6, U), M.dtype).at[owner_a, :, np.arange(U)].add(rows_a)  # J_u'
    if L:
        cols = cols.at[owner_b, :, np.arange(U - L, U)].add(rows_b)
    P = jnp.concatenate([p[..., None], cols], axis=-1)
    bb = jnp.concatenate([b[..., None], jnp.zeros(b.shape + (U,), b.dtype)], axis=-1)
    factors = _factor(plan, M, Jp, Jc, C, scan_levels)
    Vall, lam_all = _substitute(plan, factors, P, Jp, Jc, bb, scan_levels)
    V0, Y, lam0, LY = Vall[..., 0], Vall[..., 1:], lam_all[..., 0], lam_all[..., 1:]
    A = _rows_on(owner_a, rows_a, owner_b, rows_b, L, Y)
    rhs = target - _rows_on(owner_a, rows_a, owner_b, rows_b, L, V0[..., None])[:, 0]
    return (factors, Jp, Jc), V0, lam0, Y, LY, *_contact_problem(A, rhs, cfm)


def _contact_problem(A, rhs, cfm):
    """The Delassus matrix made exactly symmetric, with ``cfm`` on its diagonal, and ``rhs``."""
    return 0.5 * (A + A.T) + cfm * jnp.eye(A.shape[0], dtype=A.dtype), rhs


def _delassus(plan, blocks, B, L, owner_a, rows_a, owner_b, rows_b):
    """``(A, Phi, slots, bodies)``: ``A = J_u H^{-1} J_u' [U, U]`` along the rows' bodies' ancestor chains
    (``blocks``: ``(D, T, slot)`` of :func:`_body_blocks`), without a right-hand side per row through the tree solve:
    row ``u``'s momentum ``z_u`` (``rows_a`` on ``owner_a``, and for the last ``L`` rows ``rows_b`` on its parent
    ``owner_b``) carried from its body to the root by the ``T`` blocks, ``Phi [U, depths, 6]`` (zero past the row's
    depth), then ``A_uv = sum_d Phi_u[d]' D Phi_v[d]`` over the depths ``d`` where the two chains share their body
    (their common ancestors); ``slots`` and ``bodies`` ``[U, depths]`` the chains' rows of the blocks and their
    bodies (``B`` past the row's depth). The first ``U - L`` rows are the contact points' triples (one body each):
    they are carried together, three columns on one chain."""
    D, T, slot = blocks
    chain, depth = plan.chains, plan.depth
    U = rows_a.shape[0]
    K = (U - L) // 3
    groups = []  # (owner [n], z_a [n, 6, c], z_b [n, 6, c]): the points' triples, then the single rows
    if K:
        za = jnp.swapaxes(rows_a[:3 * K].reshape(K, 3, 6), -1, -2)
        groups.append((owner_a[:3 * K:3], za, None))
    if L:
        groups.append((owner_a[3 * K:], rows_a[3 * K:, :, None], rows_b[:, :, None]))
    Phis, Psis, row_slots, row_bodies = [], [], [], []
    for owner, za, zb in groups:
        bodies = jnp.asarray(chain)[owner]  # [n, depths]
        slots = jnp.asarray(slot[chain])[owner]  # their rows of D and T
        du = jnp.asarray(depth)[owner][:, None, None]
        Tg, phi, Phi = T[slots], jnp.zeros_like(za), []
        for d in range(chain.shape[1] - 1, -1, -1):
            if Phi:  # from the body at depth d + 1 to its parent
                phi = _bmm(Tg[:, d + 1], phi)
            phi = phi + jnp.where(du == d, za, 0.0)
            if zb is not None:
                phi = phi + jnp.where(du == d + 1, zb, 0.0)
            Phi.append(phi)
        Phi = jnp.stack(Phi[::-1], axis=1)  # [n, depths, 6, c]
        Psi = _bmm(D[slots], Phi)
        c = za.shape[-1]
        Phis.append(jnp.moveaxis(Phi, -1, 1).reshape(-1, *Phi.shape[1:3]))  # [n c, depths, 6]
        Psis.append(jnp.moveaxis(Psi, -1, 1).reshape(-1, *Psi.shape[1:3]))
        row_slots.append(jnp.repeat(slots, c, axis=0))
        row_bodies.append(jnp.repeat(bodies, c, axis=0))
    cat = lambda xs: xs[0] if len(xs) == 1 else jnp.concatenate(xs)  # noqa: E731
    Phi, Psi, slots, bodies = cat(Phis), cat(Psis), cat(row_slots), cat(row_bodies)
    shared = (bodies[:, None, :] == bodies[None, :, :]) & (bodies != B)[:, None, :]
    return einsum("udi,vdi,uvd->uv", Phi, Psi, shared.astype(Phi.dtype)), Phi, slots, bodies


#: The most one-sided rows whose Delassus matrix :func:`_solve` forms along their chains (:func:`_delassus`); more
#: go through the tree solve as columns. Measured on the 2-core CPU, the standing character's rollout in chunks of
#: 64, us per character-step, chains / columns: 8 contact points (24 rows) 49-53 / 56-58 at a batch of 1,024,
#: 16 points (48 rows) 111 / 102 at 64 (the chains' product grows with the rows squared times the tree's depth).
_CHAIN_ROWS = 32


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1, 2, 3))
def _solve(plan, scan_levels, iterations, L, M, p, Jp, Jc, b, C, owner_a, rows_a, target, owner_b, rows_b,
           friction, cfm):
    if target.shape[0] > _CHAIN_ROWS:
        _, V0, _, Y, _, A, rhs = _columns(plan, scan_levels, L, M, p, Jp, Jc, b, C, owner_a, rows_a, target,
                                          owner_b, rows_b, cfm)
        lam = projected_gauss_seidel(A, rhs, friction, iterations, num_single=L)
        return V0 + einsum("bjv,v->bj", Y, lam)
    # few rows: their Delassus matrix and right-hand side along their chains, then one roots-to-leaves pass with
    # the impulses' momenta carried up the same chains, instead of a column per row (the derivative,
    # _solve_rows_jvp, has the columns)
    M, Jp, Jc = _assembled(M, Jp, Jc)
    B = M.shape[0]
    factors = _factor(plan, M, Jp, Jc, C, scan_levels)
    p, b = p[..., None], b[..., None]
    if scan_levels:
        p, Jp, Jc, b = _pad(p, 0.0), _pad(Jp, 0.0), _pad(Jc, 0.0), _pad(b, 0.0)
    phat, saved = _up(plan, factors, p, Jc, b, scan_levels)
    D, T, w, slot = _body_blocks(plan, factors, B, scan_levels, (phat, saved, Jc, b))
    A, Phi, slots, bodies = _delassus(plan, (D, T, slot), B, L, owner_a, rows_a, owner_b, rows_b)
    rhs = target - einsum("udi,udi->u", Phi, w[slots][..., 0])  # J_u V0 = sum_d Phi[d]' w along the chain
    lam = projected_gauss_seidel(*_contact_problem(A, rhs, cfm), friction, iterations, num_single=L)
    # the leaves-to-roots pass of (p + J_u' lam, b): phat plus each row's momentum where its chain carries it (Phi
    # is zero past a row's depth, where its chain names the dummy body B: an extra row here, the padding's with
    # scan_levels)
    n = phat.shape[0]
    ext = phat if scan_levels else jnp.concatenate([phat, jnp.zeros_like(phat[:1])])
    phat = ext.at[bodies].add((lam[:, None, None] * Phi)[..., None])[:n]
    return _down(plan, factors, phat, Jp, Jc, b, None, scan_levels)[0][:B, :, 0]


def _zero(t) -> bool:
    return isinstance(t, SymbolicZero)


def _dense(t, like):
    return jnp.zeros(like.shape, like.dtype) if _zero(t) else t


def _inertia_on(dM, X):
    """``dM X [bodies, 6, m]`` for the inertias' tangent in parts (a part that is a symbolic zero costs nothing)."""
    parts = [jnp.zeros(X[:, :3].shape, X.dtype) if _zero(d) else _bmm(d, X[:, 3 * i:3 * i + 3])
             for i, d in enumerate(dM)]
    return jnp.concatenate(parts, axis=1)


def _parts(Jp, Jc, dJp, dJc):
    """The row slices of the joint rows' parts, with their tangents (``None`` for a part whose tangents are both
    symbolic zeros)."""
    out, start = [], 0
    for jp, jc, dp_, dc_ in zip(Jp, Jc, dJp, dJc):
        k = jp.shape[1]
        tangent = None if _zero(dp_) and _zero(dc_) else (_dense(dp_, jp), _dense(dc_, jc))
        out.append((slice(start, start + k), tangent))
        start += k
    return out


def _joint_rows_on(plan, parts, X):
    """``dJ_j X [joints, k, m]``."""
    rows = [jnp.zeros((len(plan.child), sl.stop - sl.start) + X.shape[2:], X.dtype) if t is None
            else _joints_on(plan, *t, X) for sl, t in parts]
    return jnp.concatenate(rows, axis=1)


def _joint_rows_from(plan, parts, lam, base):
    """``base + dJ_j' lam [bodies, 6, m]``."""
    out = base
    for sl, t in parts:
        if t is not None:
            out = _joints_from(plan, *t, lam[:, sl], out)
    return out


@functools.partial(_solve.defjvp, symbolic_zeros=True)
def _solve_rows_jvp(plan, scan_levels, iterations, L, primals, tangents):
    M, p, Jp, Jc, b, C, owner_a, rows_a, target, owner_b, rows_b, friction, cfm = primals
    dM, dp, dJp, dJc, db, dC, _, drows_a, dtarget, _, drows_b, dfriction, dcfm = tangents
    dp, db, dC, drows_a, dtarget, dfriction, dcfm = (_dense(t, x) for t, x in zip(
        (dp, db, dC, drows_a, dtarget, dfriction, dcfm), (p, b, C, rows_a, target, friction, cfm)))
    drows_b = None if rows_b is None else _dense(drows_b, rows_b)
    B, U = p.shape[0], target.shape[0]
    (factors, Jp6, Jc6), V0, lam0, Y, LY, A, rhs = _columns(plan, scan_levels, L, M, p, Jp, Jc, b, C, owner_a,
                                                           rows_a, target, owner_b, rows_b, cfm)
    parts = _parts(Jp, Jc, dJp, dJc)

    def through(zp, zb):  # J_u S(z) = Y' z_p - Lambda_Y' z_b
        return einsum("biu,bim->um", Y, zp) - einsum("jku,jkm->um", LY, zb)

    # the Delassus matrix's tangent: dJ_u Y + Y' dJ_u' + J_u dS J_u', dS x = S(-dK S x); the parts of the
    # inertias and joint rows whose tangents are symbolic zeros (the bodies' masses, the stable-PD rows) skipped
    G = _rows_on(owner_a, drows_a, owner_b, drows_b, L, Y)
    dA = G + G.T + einsum("jku,jk,jkv->uv", LY, dC, LY) + dcfm * jnp.eye(U, dtype=A.dtype)
    for sl, t in parts:
        if t is not None:
            X = einsum("jku,jkv->uv", LY[:, sl], _joints_on(plan, *t, Y))
            dA = dA + X + X.T
    for i, d in enumerate(dM):
        if not _zero(d):
            Yi = Y[:, 3 * i:3 * i + 3]
            dA = dA - einsum("biu,bij,bjv->uv", Yi, d, Yi)
    # the right-hand side's: -dJ_u V0 - J_u S(dp - dM V0 + dJ_j' lam0, db - dJ_j V0 - dC lam0)
    z0p = _joint_rows_from(plan, parts, lam0[..., None], dp[..., None] - _inertia_on(dM, V0[..., None]))
    z0b = db[..., None] - _joint_rows_on(plan, parts, V0[..., None]) - (dC * lam0)[..., None]
    drhs = (dtarget - _rows_on(owner_a, drows_a, owner_b, drows_b, L, V0[..., None])[:, 0]
            - through(z0p, z0b)[:, 0])
    lam, dlam = jax.jvp(lambda A, r, mu: projected_gauss_seidel(A, r, mu, iterations, num_single=L),
                        (A, rhs, friction), (dA, drhs, dfriction))
    V = V0 + einsum("bjv,v->bj", Y, lam)
    lam_j = lam0 + einsum("jkv,v->jk", LY, lam)
    zp = (_joint_rows_from(plan, parts, lam_j[..., None], dp[..., None] - _inertia_on(dM, V[..., None]))
          + _rows_from(B, owner_a, drows_a, owner_b, drows_b, L, lam[:, None]))
    zb = db[..., None] - _joint_rows_on(plan, parts, V[..., None]) - (dC * lam_j)[..., None]
    dV = _substitute(plan, factors, zp, Jp6, Jc6, zb, scan_levels)[0][..., 0]
    return V, dV + einsum("bjv,v->bj", Y, dlam)


def solve_rows(model, plan, one_sided, M, p, Jp, Jc, b, C):
    """``V [bodies, 6]``: the tree solve of the joint rows, then the one-sided rows by projected
    Gauss-Seidel on their Delassus matrix (module docstring; :func:`~jaxanim.physics._step._solve_constraints`).
    ``M = (M_lin, M_ang)`` ``[bodies, 3, 3]`` each; ``Jp``, ``Jc``: ``(geometric, drive)`` rows, ``[joints, k_g, 6]``
    and ``[joints, k_d, 6]`` (``b``, ``C`` ``[joints, k_g + k_d]``): parts apart, so that a part that nothing
    differentiates (the masses, the stable-PD rows) costs its tangent's products nothing."""
    if one_sided is None:
        M6, Jp6, Jc6 = _assembled(M, Jp, Jc)
        return _tree_solve(plan, M6, p[..., None], Jp6, Jc6, b[..., None], C, model.scan_levels)[..., 0]
    owner_a, rows_a, target, L, owner_b, rows_b = one_sided
    dtype = p.dtype
    cfm = jnp.asarray(model.cfm, dtype)
    friction = jnp.asarray(model.ground.friction, dtype)
    return _solve(plan, model.scan_levels, model.ground.iterations, L, M, p, Jp, Jc, b, C, owner_a, rows_a, target,
                  owner_b, rows_b, friction, cfm)
