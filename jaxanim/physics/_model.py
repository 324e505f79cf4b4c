r"""Articulated rigid-body simulation: the model, one time step, and export to MuJoCo's MJCF.

:class:`PhysicsModel` holds the bodies (:class:`~jaxanim.rigid.RigidBodies`), the joints
(:class:`~jaxanim.joints.Joints`) and the constraint parameters; the state is a
:class:`~jaxanim.rigid.BodyState`. :func:`step` advances it by one step of the course notes'
eq. 6.28 (maximal coordinates, velocity-level constraints):

1. free velocities from the loads, ``v* = v + h (f/m + g)``, ``omega* = omega + h I_n^{-1} tau``
   (joint torques ``tau_j`` act as ``+tau_j`` on the child and ``-tau_j`` on the parent, eq. 7.1);
2. the joint impulses ``lambda`` from ``(J M^{-1} J' + cfm I) lambda = -(erp / h) g - J [v*; omega*]``
   (eq. 6.20 with ERP and CFM), ``[v; omega] = [v*; omega*] + M^{-1} J' lambda``, ``M = diag(m I,
   I_n)``, ``J`` and ``g`` at step ``n`` (:func:`~jaxanim.joints.joint_rows`);
3. ``x_{n+1} = x_n + h v``, ``q_{n+1} = normalise(q_n + (h/2) [0, omega] q_n)``, and the angular
   velocity re-expressed at ``q_{n+1}`` with the angular momentum ``I_n omega`` of each body
   (the gyroscopic term in momentum form, as :func:`~jaxanim.rigid.step_free`).

**Solver for step 2**: exact and ``O(bodies)``. The joints must form a forest (each body the child
of at most one joint, no cycles). Bodies are eliminated from the leaves to the roots: each child's
articulated ``6 x 6`` inertia is folded into its parent through its joint's small system
(``k x k``, ``k`` = the joint's rows), then velocities and impulses are back-substituted from the
roots (:func:`_tree_solve`; the block elimination of the augmented system ``[[M, -J'], [J, cfm]]``
in the order of its tree, Baraff 1996, without fill-in). Bodies at the same depth are processed
together, so a 21-body character takes as many passes as its tree is deep. ``cfm`` keeps each
joint's system positive definite. Stable-PD rows (``spd``) are soft rows of their joint's system;
the root servo's soft rows are folded into its body's inertia.

**One-sided rows** (complementarity contact, :mod:`jaxanim.contact`, and joint limits,
:func:`~jaxanim.joints.limit_rows`): the same solve gives each row's effect ``Y = H^{-1} J_u'`` on
the velocities with the joints held exactly, hence their Delassus matrix ``J_u Y`` (``U x U``), on
which projected Gauss-Seidel runs a fixed number of sweeps (``ground.iterations``). Penalty
contact instead adds forces to the loads of step 1.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .. import rotations as rot
from .._errors import JaxanimError, check_shape
from ._contact import Ground, contact_rows, make_ground, penalty_loads, projected_gauss_seidel
from ._joints import Joints, joint_errors, joint_rows, limit_rows
from ._bodies import BodyState, RigidBodies, _check_loads, _check_model, _free_velocities, _bmm, _integrate, _spd_inverse

__all__ = ["PhysicsModel", "Rollout", "SimResult", "joint_error", "make_model", "rollout", "step", "to_mjcf"]


class PhysicsModel(eqx.Module):
    """Bodies, joints and constraint parameters (the constant part of a simulation).

    Attributes:
        bodies: the rigid bodies.
        joints: the joints (may be empty).
        erp: the error-reduction parameter in ``[0, 1]``: the fraction of each joint's position
            error removed per step (default 0.5: the first-order rotation update leaves an
            ``O(h^2 omega^2 r)`` anchor error per step, and the steady drift is that over ``erp``;
            a double pendulum of 0.5 m capsules drifts < 5e-5 m at 600 Hz).
        cfm: constraint-force mixing, added to the diagonal of ``J M^{-1} J'``.
        ground: the ground plane and contact model (:class:`~jaxanim.contact.Ground`; model
            ``"none"`` for no contact).
        scan_levels: solve the joint tree's depth levels in a ``lax.scan`` (static; see
            :func:`make_model`).
    """

    bodies: RigidBodies
    joints: Joints
    erp: Float[Array, ""]
    cfm: Float[Array, ""]
    ground: Ground
    scan_levels: bool = eqx.field(static=True, default=False)


def make_model(
    bodies: RigidBodies, joints: Joints | None = None, *, ground: Ground | None = None, erp: float = 0.5,
    cfm: float = 1e-10, scan_levels: bool = False,
) -> PhysicsModel:
    """A :class:`PhysicsModel`; ``erp`` in ``[0, 1]``, ``cfm >= 0``; no joints and no ground by
    default (:func:`~jaxanim.contact.make_ground` for one).

    ``scan_levels`` trades run time for compile time: the joint tree's depth levels are solved in
    a ``lax.scan`` instead of being written out one by one. Same results to the bit; on the CMU
    character (7 levels) an unbatched rollout compiles in 2.5 s instead of 4.2 s, and a step at
    batch 1024 takes ~1.4x as long (dynamic gathers and scatters instead of static slices).

    Raises:
        JaxanimError: ``erp`` / ``cfm`` out of range, joints naming bodies out of range, or joints
            forming a cycle (the solver needs a forest).
    """
    _check_model(bodies)
    if not 0 <= erp <= 1:
        raise JaxanimError(f"erp: expected a value in [0, 1], got {erp!r}")
    if not cfm >= 0:
        raise JaxanimError(f"cfm: expected >= 0, got {cfm!r}")
    if joints is None:
        z = np.zeros((0, 3))
        joints = Joints(names=(), types=(), parent=(), child=(), anchor_parent=jnp.asarray(z), anchor_child=jnp.asarray(z),
                        axis_parent=jnp.asarray(z), axis_child=jnp.asarray(z), rest=jnp.zeros((0, 4)), limited=(),
                        lower=jnp.zeros((0,)), upper=jnp.zeros((0,)), swing=jnp.zeros((0,)))
    for name, idx in (("parent", joints.parent), ("child", joints.child)):
        if any(i >= bodies.num_bodies for i in idx):
            raise JaxanimError(f"joints.{name}: a body index is out of range for {bodies.num_bodies} bodies")
    _tree(joints.parent, joints.child, bodies.num_bodies)  # raises for a cycle
    dtype = bodies.mass.dtype
    ground = make_ground("none", dtype=dtype) if ground is None else ground
    return PhysicsModel(bodies=bodies, joints=joints, erp=jnp.asarray(erp, dtype), cfm=jnp.asarray(cfm, dtype),
                        ground=ground, scan_levels=bool(scan_levels))


def joint_error(model: PhysicsModel, state: BodyState) -> Float[Array, " J"]:
    """Per joint, the distance between its two anchors (metres): the constraint drift."""
    _, _, g = joint_rows(model.joints, state)
    return jnp.linalg.norm(g[:, :3], axis=-1)


def _apply_joint_torques(model: PhysicsModel, torque: Array, joint_torque: Array) -> Array:
    par = np.asarray(model.joints.parent)
    chi = np.asarray(model.joints.child)
    torque = torque.at[chi].add(joint_torque)
    has = par >= 0
    if np.any(has):
        torque = torque.at[par[has]].add(-joint_torque[np.nonzero(has)[0]])
    return torque


@functools.lru_cache(maxsize=None)
def _tree(parent: tuple[int, ...], child: tuple[int, ...], num_bodies: int):
    """The static elimination order of a joint forest.

    Returns ``(levels, world, free, parent, child)``: ``levels[d - 1]`` the joints whose child is at
    depth ``d >= 1`` (their parent is a body), ``world`` the joints to the world, ``free`` the bodies
    that are no joint's child, and the joints' parent and child bodies (numpy index arrays).

    Raises:
        JaxanimError: the joints contain a cycle.
    """
    parent_joint = {c: j for j, c in enumerate(child)}
    depth: dict[int, int] = {}
    for b in range(num_bodies):
        chain, a = [], b
        while a not in depth:
            chain.append(a)
            if len(chain) > num_bodies:
                raise JaxanimError("joints: the joints form a cycle; only trees (forests) of joints are supported")
            j = parent_joint.get(a)
            if j is None or parent[j] < 0:
                depth[a] = 0
                chain.pop()
                break
            a = parent[j]
        for c in reversed(chain):
            depth[c] = depth[parent[parent_joint[c]]] + 1
    D = max(depth.values(), default=0)
    levels = tuple(
        np.asarray([j for j, c in enumerate(child) if parent[j] >= 0 and depth[c] == d], int) for d in range(1, D + 1)
    )
    world = np.asarray([j for j, p in enumerate(parent) if p < 0], int)
    free = np.asarray([b for b in range(num_bodies) if b not in parent_joint], int)
    return levels, world, free, np.asarray(parent, int), np.asarray(child, int)


def _tree_solve(tree, M, p, Jp, Jc, b, C, scan_levels: bool = False):
    """Velocities ``V [B, 6, m]`` of the joint-constrained system for ``m`` right-hand sides.

    Solves ``M V = p + sum_j J_j' lambda_j`` with ``J_j V + diag(C_j) lambda_j = b_j`` per joint
    exactly, in ``O(bodies)`` by eliminating bodies from the leaves to the roots (each child's
    articulated ``6 x 6`` inertia ``M^`` and momentum ``p^`` folded into its parent through the
    joint's ``k x k`` system ``S = J_c M^^{-1} J_c' + diag(C)``), then back-substituting from the roots
    (``lambda = S^{-1} (b - J_c M^^{-1} p^ - J_p V_p)``, ``V_c = M^^{-1} (p^ + J_c' lambda)``): the
    block elimination of the augmented matrix ``[[M, -J'], [J, C]]`` whose graph is a tree
    (Baraff 1996), without fill-in.

    Args:
        tree: :func:`_tree`'s levels.
        M: ``[B, 6, 6]`` body inertias (plus any soft world rows folded in).
        p: ``[B, 6, m]`` momenta.
        Jp, Jc: ``[J, k, 6]`` each joint's rows on its parent and child (``[v; omega]``).
        b: ``[J, k, m]`` row targets; C: ``[J, k]`` their compliance (``> 0`` on rows with ``J = 0``).
        scan_levels: run the depth levels as a ``lax.scan`` (one compiled body, levels padded to
            the widest) instead of writing each level out: the same result to the bit, about half
            the compile time, ~1.4x the run time under ``vmap`` (dynamic gathers / scatters).
    """
    if scan_levels:
        return _tree_solve_scan(tree, M, p, Jp, Jc, b, C)
    levels, world, free, parent, child = tree
    Mhat, phat = M, p
    saved = []
    for js in reversed(levels):
        c, pa = child[js], parent[js]
        X, y, Sinv, r = _eliminate(Mhat[c], phat[c], Jc[js], C[js], b[js])
        Mhat, phat = _fold(Mhat, phat, pa, Jp[js], Sinv, r)
        saved.append((js, c, pa, X, y, Sinv, r))
    V = _roots(tree, Mhat, phat, Jc, C, b)
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
    G = _bmm(Sinv, Jp)  # S^{-1} J_p  [n, k, 6]
    return (Mhat.at[pa].add(_bmm(jnp.swapaxes(Jp, -1, -2), G)),
            phat.at[pa].add(_bmm(jnp.swapaxes(G, -1, -2), r)))


def _roots(tree, Mhat, phat, Jc, C, b):
    """Velocities of the free roots (``M^^{-1} p^``) and of the bodies jointed to the world."""
    _, world, free, _, child = tree
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


def _tree_solve_scan(tree, M, p, Jp, Jc, b, C):
    """:func:`_tree_solve` with the depth levels in a ``lax.scan``: levels padded to the widest with
    a dummy joint ``J`` (no rows: ``J = 0``, ``C = 1``) between dummy bodies ``B``."""
    levels, _, _, parent, child = tree
    B, J = M.shape[0], Jp.shape[0]
    Mhat = jnp.concatenate([M, jnp.eye(6, dtype=M.dtype)[None]])
    phat = jnp.concatenate([p, jnp.zeros_like(p[:1])])
    if not levels:
        return _roots(tree, Mhat, phat, Jc, C, b)[:B]
    Jp = jnp.concatenate([Jp, jnp.zeros_like(Jp[:1])])
    Jc = jnp.concatenate([Jc, jnp.zeros_like(Jc[:1])])
    b = jnp.concatenate([b, jnp.zeros_like(b[:1])])
    C = jnp.concatenate([C, jnp.ones_like(C[:1])])
    width = max(js.size for js in levels)
    pad = lambda a, v: np.concatenate([a, np.full(width - a.size, v)])  # noqa: E731
    xs = (np.stack([pad(js, J) for js in levels]), np.stack([pad(child[js], B) for js in levels]),
          np.stack([pad(parent[js], B) for js in levels]))  # [D, width] each, shallowest first

    def up(carry, level):
        Mhat, phat = carry
        js, c, pa = level
        X, y, Sinv, r = _eliminate(Mhat[c], phat[c], Jc[js], C[js], b[js])
        return _fold(Mhat, phat, pa, Jp[js], Sinv, r), (X, y, Sinv, r)

    (Mhat, phat), saved = jax.lax.scan(up, (Mhat, phat), xs, reverse=True)

    def down(V, level):
        (js, c, pa), (X, y, Sinv, r) = level
        return _back_substitute(V, c, pa, Jp[js], X, y, Sinv, r), None

    V, _ = jax.lax.scan(down, _roots(tree, Mhat, phat, Jc, C, b), (xs, saved))
    return V[:B]


def _joint_blocks(model: PhysicsModel, state: BodyState, h, spd):
    """Each joint's rows ``(J_p [J, k, 6], J_c [J, k, 6], b [J, k], C [J, k])``: the 3 anchor rows,
    the type's angular rows (padded to the model's largest count with ``J = 0``, ``C = 1``) with
    targets ``-(erp / h) g``, and with ``spd`` 3 stable-PD rows on the relative angular velocity.

    The stable-PD law ``tau = k_p (e - h w) - k_d w`` (``w`` the new relative angular velocity, ``e``
    the error at step ``n``) is the soft row ``w + C lambda = b`` on the impulse ``lambda = h tau``
    with ``b = k_p e / (h k_p + k_d)`` and ``C = 1 / (h (h k_p + k_d))`` (:func:`_soft_gains`).
    """
    joints = model.joints
    dtype = state.position.dtype
    Jp6, Jc6, g = joint_rows(joints, state)
    mask = joints.row_mask
    nh = int(mask.sum(axis=1).max())
    mask = jnp.asarray(mask[:, :nh])
    Jp, Jc = Jp6[:, :nh], Jc6[:, :nh]
    b = jnp.where(mask, -(model.erp / h) * g[:, :nh], 0.0)
    C = jnp.where(mask, model.cfm, 1.0)
    if spd is not None:
        targets, kp, kd = spd
        e, _ = joint_errors(joints, state, rot.quat_normalize(targets))
        bm, cm, active = _soft_gains(e, kp[:, None], kd[:, None], h)
        eye = jnp.where(active[:, :, None], jnp.eye(3, dtype=dtype)[None], 0.0)  # [J, 3, 3]
        zero = jnp.zeros_like(eye)
        Jc = jnp.concatenate([Jc, jnp.concatenate([zero, eye], axis=-1)], axis=1)
        Jp = jnp.concatenate([Jp, jnp.concatenate([zero, -eye], axis=-1)], axis=1)
        b = jnp.concatenate([b, bm], axis=1)
        C = jnp.concatenate([C, jnp.where(active, cm + model.cfm, 1.0)], axis=1)
    return Jp, Jc, b, C


def _soft_gains(e, kp, kd, h):
    """The soft constraint ``J v + cfm lambda = b`` of the implicit PD law
    ``tau = k_p (e - h J v) - k_d J v`` on the impulse ``lambda = h tau``: ``b = k_p e / (h k_p +
    k_d)``, ``cfm = 1 / (h (h k_p + k_d))``, broadcast to ``e``'s shape, with the mask of driven
    rows (``h k_p + k_d > 0``); rows not driven get ``b = 0``, ``cfm = 1`` and must have ``J = 0``."""
    c = jnp.broadcast_to(h * kp + kd, e.shape)
    active = c > 0
    c_safe = jnp.where(active, c, 1.0)
    b = jnp.where(active, jnp.broadcast_to(kp, e.shape) * e / c_safe, 0.0)
    cfm = jnp.where(active, 1.0 / (h * c_safe), 1.0)
    return b, cfm, active


def _servo_rows(model: PhysicsModel, state: BodyState, servo, h):
    """The stable-PD rows pulling one body to a world pose (the "hand of God") on the body's
    ``[v; omega]``, as the soft rows of :func:`_joint_blocks`: ``(body, b [6], cfm [6], active [6])``."""
    body, x_t, q_t, kp_l, kd_l, kp_a, kd_a = servo
    e_lin = x_t - state.position[body]
    e_ang = rot.quat_to_rotvec(rot.quat_canonical(rot.quat_multiply(q_t, rot.quat_conjugate(state.orientation[body]))))
    e = jnp.stack([e_lin, e_ang])  # [2, 3]
    b, cfm, active = _soft_gains(e, jnp.stack([kp_l, kp_a])[:, None], jnp.stack([kd_l, kd_a])[:, None], h)
    return body, b.reshape(6), cfm.reshape(6), active.reshape(6)


def _solve_constraints(model: PhysicsModel, state: BodyState, v, w, I_n, h, spd=None, servo=None):
    """Velocities after the joint, stable-PD, servo and (complementarity) contact impulses.

    The joints (with their stable-PD rows) are solved exactly by :func:`_tree_solve`; the servo's
    soft rows on one body are folded into that body's inertia; the contacts' effect is found by
    the same solve for each contact row (their Delassus matrix ``A = J_u H^{-1} J_u'`` with the
    joints eliminated exactly) and projected Gauss-Seidel on ``A``.
    """
    dtype = v.dtype
    B = model.bodies.num_bodies
    Jn = model.joints.num_joints
    contact = model.ground.model == "complementarity"
    if Jn == 0 and servo is None and not contact:
        return v, w
    zeros33 = jnp.zeros((B, 3, 3), dtype)
    m_eye = model.bodies.mass[:, None, None] * jnp.eye(3, dtype=dtype)[None]
    M = jnp.concatenate([jnp.concatenate([m_eye, zeros33], -1), jnp.concatenate([zeros33, I_n], -1)], 1)
    V = jnp.concatenate([v, w], axis=-1)
    p = jnp.einsum("bij,bj->bi", M, V)
    if servo is not None:
        body, bs, cs, active = _servo_rows(model, state, servo, h)
        k = jnp.where(active, 1.0 / (cs + model.cfm), 0.0)
        M = M.at[body].add(jnp.diag(k))
        p = p.at[body].add(k * bs)
    if Jn:
        Jp, Jc, b, C = _joint_blocks(model, state, h, spd)
    else:
        Jp = Jc = jnp.zeros((0, 1, 6), dtype)
        b, C = jnp.zeros((0, 1), dtype), jnp.ones((0, 1), dtype)
    tree = _tree(model.joints.parent, model.joints.child, B)
    # One-sided rows: contacts (normal, t1, t2 per point) then joint limits, each on body owner_a
    # (row_a); a limit row also on its parent body owner_b (row_b; zero for a joint to the world).
    owner_a, rows_a, target = [], [], []
    if contact:
        owner, rows, tc = contact_rows(model.ground, model.bodies, state, h)
        owner_a.append(owner)
        rows_a.append(rows)
        target.append(tc)
    lj, axes, phi = limit_rows(model.joints, state)
    L = lj.size
    if L:
        zero3 = jnp.zeros_like(axes)
        par = np.asarray(model.joints.parent)[lj]
        chi = np.asarray(model.joints.child)[lj]
        owner_a.append(jnp.asarray(chi))
        rows_a.append(jnp.concatenate([zero3, axes], -1))
        owner_b = jnp.asarray(np.where(par >= 0, par, chi))
        rows_b = jnp.concatenate([zero3, jnp.where(jnp.asarray(par >= 0)[:, None], -axes, 0.0)], -1)
        target.append(jnp.where(phi > 0, -phi / h, (model.erp / h) * (-phi)))
    if not target:
        return _split(_tree_solve(tree, M, p[..., None], Jp, Jc, b[..., None], C, model.scan_levels)[..., 0])
    owner_a, rows_a, target = jnp.concatenate(owner_a), jnp.concatenate(rows_a), jnp.concatenate(target)
    U = target.shape[0]
    cols = jnp.zeros((B, 6, U), dtype).at[owner_a, :, np.arange(U)].add(rows_a)  # J_u'
    if L:
        cols = cols.at[owner_b, :, np.arange(U - L, U)].add(rows_b)
    P = jnp.concatenate([p[..., None], cols], axis=-1)
    bb = jnp.concatenate([b[..., None], jnp.zeros(b.shape + (U,), dtype)], axis=-1)
    Vall = _tree_solve(tree, M, P, Jp, Jc, bb, C, model.scan_levels)
    V0, Y = Vall[..., 0], Vall[..., 1:]  # Y = H^{-1} J_u'  [B, 6, U]
    A = jnp.einsum("uj,ujv->uv", rows_a, Y[owner_a])
    rhs = target - jnp.einsum("uj,uj->u", rows_a, V0[owner_a])
    if L:
        A = A.at[U - L:].add(jnp.einsum("uj,ujv->uv", rows_b, Y[owner_b]))
        rhs = rhs.at[U - L:].add(-jnp.einsum("uj,uj->u", rows_b, V0[owner_b]))
    A = 0.5 * (A + A.T) + model.cfm * jnp.eye(U, dtype=dtype)
    lam = projected_gauss_seidel(A, rhs, model.ground.friction, model.ground.iterations, num_single=L)
    return _split(V0 + jnp.einsum("bjv,v->bj", Y, lam))


def _split(V):
    return V[:, :3], V[:, 3:]


def _step(model: PhysicsModel, state: BodyState, force, torque, joint_torque, h, spd=None, servo=None) -> BodyState:
    torque = _apply_joint_torques(model, torque, joint_torque) if model.joints.num_joints else torque
    if model.ground.model == "penalty":
        f_c, tau_c = penalty_loads(model.ground, model.bodies, state)
        force, torque = force + f_c, torque + tau_c
    v, w, I_n = _free_velocities(model.bodies, state, force, torque, h)
    v, w = _solve_constraints(model, state, v, w, I_n, h, spd, servo)
    return _integrate(model.bodies, state, v, w, I_n, h)


def _check_inputs(model: PhysicsModel, state: BodyState, force, torque, joint_torque) -> list[Array]:
    B, Jn = model.bodies.num_bodies, model.joints.num_joints
    loads = (("force", force, B, "B"), ("torque", torque, B, "B"), ("joint_torque", joint_torque, Jn, "J"))
    return _check_loads(state, B, model.bodies.mass.dtype, loads)


@eqx.filter_jit
def _step_jit(model, state, force, torque, joint_torque, h, spd, servo):
    return _step(model, state, force, torque, joint_torque, h, spd, servo)


def step(
    model: PhysicsModel,
    state: BodyState,
    dt: Float[ArrayLike, ""],
    *,
    force: Float[ArrayLike, "B 3"] | None = None,
    torque: Float[ArrayLike, "B 3"] | None = None,
    joint_torque: Float[ArrayLike, "J 3"] | None = None,
    spd: tuple[Float[ArrayLike, "J 4"], Float[ArrayLike, " J"], Float[ArrayLike, " J"]] | None = None,
    servo: tuple | None = None,
) -> BodyState:
    """Advance the articulated bodies by one step of ``dt`` seconds (see the module docstring).

    Args:
        model: the :class:`PhysicsModel`.
        state: the bodies' state.
        dt: the step, seconds.
        force: ``[B, 3]`` external forces at the centres of mass (world frame, N).
        torque: ``[B, 3]`` external torques (world frame, N m).
        joint_torque: ``[J, 3]`` joint torques (world frame, N m): ``+tau`` on the child,
            ``-tau`` on the parent.
        spd: optional stable PD on every joint, ``(targets [J, 4], kp [J], kd [J])``: targets
            are the child's orientations relative to the parent (wxyz, ``q_p^{-1} q_c``), gains
            in N m / rad and N m s / rad (0 and 0: that joint is not driven). The law
            ``tau = k_p (e - h w) - k_d w`` is implicit in the new relative angular velocity ``w``
            and solved with the joint constraints (soft rows, the stable PD of Tan et al. 2011 in
            maximal coordinates); see :mod:`jaxanim.control` for ``e``.
        servo: optional stable PD of one body towards a world pose, the root force and torque
            ("hand of God"): ``(body (int), position [3], orientation [4], kp_lin, kd_lin,
            kp_ang, kd_ang)`` (N/m, N s/m, N m/rad, N m s/rad), implicit like ``spd``.

    Returns:
        The new :class:`~jaxanim.rigid.BodyState`.

    Raises:
        JaxanimError: shapes do not match the model.
    """
    loads = _check_inputs(model, state, force, torque, joint_torque)
    dtype = model.bodies.mass.dtype
    if spd is not None:
        Jn = model.joints.num_joints
        if not (isinstance(spd, (tuple, list)) and len(spd) == 3):
            raise JaxanimError("spd: expected (targets [J, 4], kp [J], kd [J])")
        targets, kp, kd = (jnp.asarray(a, dtype) for a in spd)
        check_shape("spd targets", targets, (Jn, 4), what=f"(J, 4) = ({Jn}, 4)")
        kp, kd = jnp.broadcast_to(kp, (Jn,)), jnp.broadcast_to(kd, (Jn,))
        spd = (targets, kp, kd)
    if servo is not None:
        if not (isinstance(servo, (tuple, list)) and len(servo) == 7):
            raise JaxanimError("servo: expected (body, position [3], orientation [4], kp_lin, kd_lin, kp_ang, kd_ang)")
        body = servo[0]
        if not isinstance(body, (int, np.integer)) or not 0 <= body < model.bodies.num_bodies:
            raise JaxanimError(f"servo: body must be an int in [0, {model.bodies.num_bodies}), got {body!r}")
        x_t, q_t = jnp.asarray(servo[1], dtype), rot.quat_normalize(jnp.asarray(servo[2], dtype))
        check_shape("servo position", x_t, (3,))
        check_shape("servo orientation", q_t, (4,))
        servo = (int(body), x_t, q_t, *(jnp.asarray(g, dtype) for g in servo[3:]))
    return _step_jit(model, state, *loads, jnp.asarray(dt, dtype), spd, servo)


class SimResult(eqx.Enumeration):
    """Status of a rollout, per character under ``vmap``."""

    successful = ""
    nonfinite = (
        "The state became non-finite (NaN or inf): the character was stopped at its last finite state. "
        "Reduce the step, the gains, or check the inputs."
    )
    exploded = (
        "A body moved faster than max_speed / max_angular_speed (a blow-up): the character was stopped at "
        "its last state below them. Reduce the step or the gains, or use stable PD."
    )


class Rollout(eqx.Module):
    """The result of :func:`rollout`.

    Attributes:
        final: the last state (the last good one if the character was stopped).
        trajectory: the recorded states, leading axis ``num_steps // record_every`` (a stopped
            character repeats its last good state).
        result: :class:`SimResult` (``successful``, ``nonfinite`` or ``exploded``).
        num_steps: steps completed (``< num_steps`` if stopped).
    """

    final: BodyState
    trajectory: BodyState
    result: SimResult
    num_steps: Int[Array, ""]


def _finite_state(s: BodyState) -> Array:
    return (
        jnp.all(jnp.isfinite(s.position)) & jnp.all(jnp.isfinite(s.orientation))
        & jnp.all(jnp.isfinite(s.linear_velocity)) & jnp.all(jnp.isfinite(s.angular_velocity))
    )


@eqx.filter_jit
def _rollout(model, state, h, num_steps, record_every, controller, controller_args, max_speed, max_angular_speed):
    B = model.bodies.num_bodies
    Jn = model.joints.num_joints
    dtype = h.dtype
    zeros = jnp.zeros((B, 3), dtype)
    jt0 = jnp.zeros((Jn, 3), dtype)

    def inner(carry, _):
        s, code, count = carry
        k = count
        u = {} if controller is None else controller(s, k, controller_args)
        new = _step(model, s, jnp.asarray(u.get("force", zeros), dtype), jnp.asarray(u.get("torque", zeros), dtype),
                    jnp.asarray(u.get("joint_torque", jt0), dtype), h, u.get("spd"), u.get("servo"))
        finite = _finite_state(new)
        fast = (jnp.max(jnp.abs(new.linear_velocity)) > max_speed) | (
            jnp.max(jnp.abs(new.angular_velocity)) > max_angular_speed
        )
        running = code == 0
        new_code = jnp.where(running, jnp.where(~finite, 1, jnp.where(fast, 2, 0)), code)
        ok = running & (new_code == 0)
        s = jax.tree.map(lambda a, b: jnp.where(ok, a, b), new, s)
        return (s, new_code, count + ok.astype(count.dtype)), None

    def outer(carry, _):
        carry, _ = jax.lax.scan(inner, carry, None, length=record_every)
        return carry, carry[0]

    init = (state, jnp.where(_finite_state(state), 0, 1), jnp.zeros((), jnp.int32))
    (final, code, count), traj = jax.lax.scan(outer, init, None, length=num_steps // record_every)
    result = SimResult.where(code == 0, SimResult.successful, SimResult.where(code == 1, SimResult.nonfinite,
                                                                               SimResult.exploded))
    return Rollout(final=final, trajectory=traj, result=result, num_steps=count)


def rollout(
    model: PhysicsModel,
    state: BodyState,
    dt: Float[ArrayLike, ""],
    num_steps: int,
    *,
    record_every: int = 1,
    controller: Callable | None = None,
    controller_args: Any = None,
    max_speed: float = 1e3,
    max_angular_speed: float = 1e4,
) -> Rollout:
    """``num_steps`` steps in a ``lax.scan``, with an optional controller, stopping a character that
    blows up.

    Args:
        model, state, dt: as for :func:`step`.
        num_steps: steps to take (static int, a multiple of ``record_every``).
        record_every: record the state every this many steps (static int >= 1).
        controller: ``controller(state, step, controller_args) -> dict`` with any of the keys
            ``force``, ``torque``, ``joint_torque``, ``spd``, ``servo`` of :func:`step` (default:
            passive; ``servo``'s body index must be a Python int).
            ``step`` is the step index (int array).
        controller_args: a pytree passed to the controller (``vmap`` over it to sweep gains).
        max_speed, max_angular_speed: a body faster than this (m/s, rad/s) counts as a blow-up.

    Returns:
        A :class:`Rollout`: the final state, the recorded trajectory, the :class:`SimResult` and the
        steps completed. A character whose state becomes non-finite or too fast is stopped at its
        last good state with that status; under ``vmap`` the others carry on.
    """
    for name, value in (("num_steps", num_steps), ("record_every", record_every)):
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 1:
            raise JaxanimError(f"{name}: expected an int >= 1, got {value!r}")
    if num_steps % record_every:
        raise JaxanimError(f"num_steps: expected a multiple of record_every = {record_every}, got {num_steps}")
    _check_inputs(model, state, None, None, None)
    dtype = model.bodies.mass.dtype
    return _rollout(model, state, jnp.asarray(dt, dtype), int(num_steps), int(record_every), controller,
                    controller_args, jnp.asarray(max_speed, dtype), jnp.asarray(max_angular_speed, dtype))


# --------------------------------------------------------------------------------------------
# MJCF export.
# --------------------------------------------------------------------------------------------


def _fmt(v) -> str:
    return " ".join(f"{float(x):.17g}" for x in np.ravel(v))


def _quat_between(q_parent: np.ndarray, q_child: np.ndarray) -> np.ndarray:
    return np.asarray(rot.quat_multiply(rot.quat_conjugate(jnp.asarray(q_parent)), jnp.asarray(q_child)))


def to_mjcf(
    model: PhysicsModel, state: BodyState, *, dt: float = 1 / 600, name: str = "jaxanim",
    stiffness: ArrayLike | None = None, damping: ArrayLike | None = None,
) -> str:
    """The model as MuJoCo XML, assembled at ``state``.

    Each body becomes a MuJoCo body whose frame is the body's frame (origin at its centre of
    mass), with an explicit ``inertial`` (mass and full inertia, so MuJoCo does not recompute them
    from the geoms) and its shape as a geom (capsules along body ``z``, as in MuJoCo). Bodies are
    nested along the joints; a ball joint becomes ``type="ball"``, a hinge ``type="hinge"``, a
    universal joint two hinges, a fixed joint no joint (welded), and a body that is no joint's
    child gets a ``freejoint``. A hinge's range becomes MuJoCo's ``range`` (MuJoCo's ball ``range``
    bounds the total rotation angle, not a swing cone and twist, so ball limits are not exported).
    Gravity and the time step are written in ``option``
    (``integrator="Euler"``).

    Contact: with ``model.ground`` of model ``"none"`` no geom collides. Otherwise the ground
    becomes a ``plane`` geom (its normal and offset, the ground's friction) and every body geom
    collides with it but not with other bodies (``contype="1" conaffinity="0"``, the plane
    ``contype="0" conaffinity="1"``), ``condim="3"`` (Coulomb friction), as jaxanim's contact model.

    Args:
        stiffness, damping: optional per-joint (``[J]`` or a scalar) spring stiffness (N m / rad)
            and damping (N m s / rad) pulling each joint to its assembly pose (MuJoCo's joint
            ``stiffness`` / ``damping``, whose spring reference is the assembly configuration
            ``qpos0``): a PD hold of the pose at ``state`` for comparisons with :func:`step`'s
            ``spd``; MuJoCo's Euler integrator treats the damping implicitly.

    Raises:
        JaxanimError: a body has two parent joints (the joints do not form a forest), or
            ``stiffness`` / ``damping`` of the wrong shape.
    """
    bodies, joints = model.bodies, model.joints
    Jn = joints.num_joints
    springs = {}
    for key, value in (("stiffness", stiffness), ("damping", damping)):
        if value is not None:
            arr = np.broadcast_to(np.asarray(value, float), (Jn,)) if np.ndim(value) == 0 else np.asarray(value, float)
            if arr.shape != (Jn,):
                raise JaxanimError(f"{key}: expected a scalar or shape ({Jn},) (one per joint), got {arr.shape}")
            springs[key] = arr
    collide = model.ground.model != "none"
    x = np.asarray(state.position, float)
    q = np.asarray(state.orientation, float)
    Rm = np.asarray(rot.quat_to_matrix(jnp.asarray(q)))
    parent_joint = {}
    for j, c in enumerate(joints.child):
        if c in parent_joint:
            raise JaxanimError(f"to_mjcf: body {bodies.names[c]!r} has two parent joints")
        parent_joint[c] = j
    children: dict[int, list[int]] = {}
    for c, j in parent_joint.items():
        children.setdefault(joints.parent[j], []).append(c)
    I = np.asarray(bodies.inertia, float)
    size = np.asarray(bodies.size, float)
    ap = np.asarray(joints.anchor_parent, float)
    ac = np.asarray(joints.anchor_child, float)
    ep = np.asarray(joints.axis_parent, float)
    ec = np.asarray(joints.axis_child, float)

    def geom(b):
        kind = bodies.shapes[b]
        if kind == "box":
            s = f'type="box" size="{_fmt(size[b] / 2)}"'
        elif kind == "sphere":
            s = f'type="sphere" size="{_fmt(size[b][:1])}"'
        else:
            s = f'type="capsule" size="{_fmt([size[b][0], size[b][1] / 2])}"'
        flags = (f'contype="1" conaffinity="0" condim="3" friction="{float(model.ground.friction):.17g} 0 0"'
                 if collide else 'contype="0" conaffinity="0"')
        return f'<geom name="{bodies.names[b]}_geom" {s} {flags}/>'

    def body_xml(b, parent, indent):
        pad = "  " * indent
        if parent < 0:
            pos, quat = x[b], q[b]
        else:
            pos = Rm[parent].T @ (x[b] - x[parent])
            quat = _quat_between(q[parent], q[b])
        lines = [f'{pad}<body name="{bodies.names[b]}" pos="{_fmt(pos)}" quat="{_fmt(quat)}">']
        Ib = I[b]
        lines.append(
            f'{pad}  <inertial pos="0 0 0" mass="{float(bodies.mass[b]):.17g}" '
            f'fullinertia="{_fmt([Ib[0, 0], Ib[1, 1], Ib[2, 2], Ib[0, 1], Ib[0, 2], Ib[1, 2]])}"/>'
        )
        j = parent_joint.get(b)
        if j is None:
            lines.append(f'{pad}  <freejoint name="{bodies.names[b]}_free"/>')
        else:
            kind = joints.types[j]
            jname = joints.names[j]
            anchor = _fmt(ac[j])
            extra = "".join(f' {k}="{v[j]:.17g}"' for k, v in springs.items())
            if kind == "ball":
                lines.append(f'{pad}  <joint name="{jname}" type="ball" pos="{anchor}"{extra}/>')
            elif kind == "hinge":
                if joints.limited[j]:
                    extra += f' limited="true" range="{_fmt([joints.lower[j], joints.upper[j]])}"'
                lines.append(f'{pad}  <joint name="{jname}" type="hinge" pos="{anchor}" axis="{_fmt(ec[j])}"{extra}/>')
            elif kind == "universal":
                p = joints.parent[j]
                Rp = np.eye(3) if p < 0 else Rm[p]
                first = Rm[b].T @ (Rp @ ep[j])  # the parent-side axis in the child frame at assembly
                lines.append(f'{pad}  <joint name="{jname}_1" type="hinge" pos="{anchor}" axis="{_fmt(first)}"{extra}/>')
                lines.append(f'{pad}  <joint name="{jname}_2" type="hinge" pos="{anchor}" axis="{_fmt(ec[j])}"{extra}/>')
        lines.append(f"{pad}  {geom(b)}")
        for c in children.get(b, []):
            lines.extend(body_xml(c, b, indent + 1))
        lines.append(f"{pad}</body>")
        return lines

    g = np.asarray(bodies.gravity, float)
    out = [
        f'<mujoco model="{name}">',
        '  <compiler angle="radian" inertiafromgeom="false"/>',
        f'  <option timestep="{dt:.17g}" gravity="{_fmt(g)}" integrator="Euler"/>',
        "  <worldbody>",
    ]
    if collide:
        n = np.asarray(model.ground.normal, float)
        qz = np.asarray(rot.rotation_between(jnp.array([0.0, 0.0, 1.0]), jnp.asarray(n)))
        out.append(
            f'    <geom name="ground" type="plane" size="0 0 1" pos="{_fmt(float(model.ground.offset) * n)}" '
            f'quat="{_fmt(qz)}" contype="0" conaffinity="1" condim="3" '
            f'friction="{float(model.ground.friction):.17g} 0 0"/>'
        )
    roots = [b for b in range(bodies.num_bodies) if b not in parent_joint or joints.parent[parent_joint[b]] < 0]
    for b in roots:
        out.extend(body_xml(b, -1, 2))
    out += ["  </worldbody>", "</mujoco>", ""]
    del ap  # the parent anchor is implied by the assembly pose
    return "\n".join(out)
