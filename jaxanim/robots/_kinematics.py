"""Forward kinematics, geometric Jacobians and the centre of mass of a :class:`Robot`.

All functions take **one** configuration ``qpos [nq]``; batch with ``jax.vmap``. They follow
MuJoCo's ``mj_kinematics``, ``mj_jacBody`` / ``mj_jacSite`` and ``subtree_com`` (``mj_comPos``)
to rounding.

The computation has three vectorised stages and one tree walk:

1. every joint's transform in its body's frame, all joints at once: a hinge is
   ``[R | p - R p]`` with ``R`` the rotation by ``qpos - qpos0`` about ``jnt_axis`` and ``p`` the
   anchor ``jnt_pos``; a ball the same with the qpos quaternion; a slide ``[I | axis (qpos - qpos0)]``;
   a free joint the world pose in qpos;
2. every body's transform in its parent's frame, ``(body_pos, body_quat)`` times its joints' in
   order: one batched product per joint slot (at most the most joints any one body has, 3 on the
   CMU humanoid);
3. the world transforms, walked per depth level of :mod:`jaxanim._tree` (one batched product per
   level). A body with a free joint is walked as a child of the world: its pose is qpos's.

Jacobian columns (MuJoCo's ``cdof``): a hinge's is ``(axis x (point - anchor), axis)`` with the
world axis and anchor; a slide's ``(axis, 0)``; a ball's three are the rotations about the columns of
its body's world rotation ``xmat`` through the anchor; a free joint's are the three world axes
(linear, in world coordinates) and then the columns of its body's ``xmat`` (angular velocity in the
body's local frame) through the body origin. A column is zero unless its joint moves an ancestor of
the target (or the target's own body).
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .. import _tree
from .. import rotations as rot
from .._errors import JaxanimError, check_float, check_shape
from .._linalg import einsum
from .._types import Array, Float
from ._robot import JOINT_NV, Robot


class RobotFK(eqx.Module):
    """World poses of every body, body centre of mass and site of one configuration.

    Attributes:
        xpos: ``[bodies, 3]`` world position of every body frame (m); body 0 is the world.
        xmat: ``[bodies, 3, 3]`` rotation body -> world: ``p_world = xmat @ p_body + xpos``.
        xquat: ``[bodies, 4]`` the same rotations as wxyz unit quaternions, canonical sign
            (``w >= 0``; MuJoCo's ``xquat`` may be the negative, the same rotation).
        xipos: ``[bodies, 3]`` world position of every body's centre of mass.
        site_xpos: ``[sites, 3]`` world position of every site.
        site_xmat: ``[sites, 3, 3]`` rotation site -> world.
    """

    xpos: Float[Array, "bodies 3"]
    xmat: Float[Array, "bodies 3 3"]
    xquat: Float[Array, "bodies 4"]
    xipos: Float[Array, "bodies 3"]
    site_xpos: Float[Array, "sites 3"]
    site_xmat: Float[Array, "sites 3 3"]


# --- static plan -----------------------------------------------------------------------------------


class _Plan:
    """Static index tables for one robot structure (cached)."""

    def __init__(self, parents, types, bodies, qposadr, nq):
        B, J = len(parents), len(types)
        self.J = J
        t = np.array(types, dtype=object).reshape(J)
        self.hinge, self.slide, self.ball, self.free = (t == "hinge"), (t == "slide"), (t == "ball"), (t == "free")
        adr = np.array(qposadr, dtype=np.int64).reshape(J)
        last = max(nq - 1, 0)
        self.q_scalar = adr.tolist()  # hinge / slide value (others: any valid slot, masked)
        self.q_quat = np.minimum(adr[:, None] + np.where(self.free, 3, 0)[:, None] + np.arange(4), last).tolist()
        self.q_pos = np.minimum(adr[:, None] + np.arange(3), last).tolist()
        # bodies: the ones moved by a free joint take their pose from qpos, walked as children of the world
        self.body_free = np.zeros(B, dtype=bool)
        self.body_free[[b for b, f in zip(bodies, self.free) if f]] = True
        self.parents_fk = tuple(0 if self.body_free[b] else int(p) for b, p in enumerate(parents))
        # joint slots: slot s holds the s-th joint of every body (J = the identity, padding)
        slot_of, counts = [], [0] * B
        for b in bodies:
            slot_of.append(counts[b])
            counts[b] += 1
        nslot = max(counts, default=0)
        self.slots = [[J] * B for _ in range(nslot)]
        for j, (b, s) in enumerate(zip(bodies, slot_of)):
            self.slots[s][b] = j
        self.after = [s * B + b for b, s in zip(bodies, slot_of)]  # joint -> row of the stacked slot frames
        self.jnt_parent = [self.parents_fk[b] for b in bodies]
        # dofs: the row of the axis table [joint axes (J); xmat columns (3 B, body-major); world axes (3)]
        src, rotational, dof_joint = [], [], []
        for j, (ty, b) in enumerate(zip(types, bodies)):
            if ty in ("hinge", "slide"):
                src.append(j)
                rotational.append(ty == "hinge")
            elif ty == "ball":
                src += [J + 3 * b + c for c in range(3)]
                rotational += [True] * 3
            else:  # free: linear along the world axes, then angular about the body's axes
                src += [J + 3 * B + c for c in range(3)] + [J + 3 * b + c for c in range(3)]
                rotational += [False] * 3 + [True] * 3
            dof_joint += [j] * JOINT_NV[ty]
        self.dof_src, self.dof_joint = src, dof_joint
        self.dof_rot = np.array(rotational, dtype=bool)
        # ancestors: dof d moves body k when the body of its joint is k or an ancestor of k (MuJoCo's
        # dof_parentid chain, which follows the body tree)
        below = _tree.subtree(tuple(int(p) for p in parents))  # [a, k]: k in the subtree of a
        dof_body = np.array([bodies[j] for j in dof_joint], dtype=np.int64)
        self.moves = below[dof_body].T.copy() if dof_joint else np.zeros((B, 0), dtype=bool)  # [B, nv]


@functools.lru_cache(maxsize=64)
def _plan_cached(parents, types, bodies, qposadr, nq) -> _Plan:
    return _Plan(parents, types, bodies, qposadr, nq)


def kinematic_plan(robot: Robot) -> _Plan:
    return _plan_cached(robot.body_parents, robot.jnt_types, robot.jnt_bodies, robot.jnt_qposadr, robot.nq)


# --- the computation ---------------------------------------------------------------------------------


def _take(x, idx):
    """``x[idx]`` along axis 0 for a static index list: a slice for one run of consecutive indices,
    else one gather (a compiled program of a few ops per level, not one slice per run)."""
    idx = [int(i) for i in idx]
    if not idx:
        return jnp.zeros((0,) + x.shape[1:], x.dtype)
    a = idx[0]
    if idx == list(range(a, a + len(idx))):
        return x if (a, len(idx)) == (0, x.shape[0]) else x[a : a + len(idx)]
    return x.at[np.asarray(idx, dtype=np.int32)].get(mode="promise_in_bounds")


@functools.lru_cache(maxsize=64)
def _walk_plan(parents: tuple[int, ...]):
    levels = _tree.levels(parents)
    where = {b: (lev, k) for lev, row in enumerate(levels) for k, b in enumerate(row)}
    par_local = [[where[parents[b]][1] for b in row] for row in levels[1:]]
    order = [b for row in levels for b in row]
    inverse = np.argsort(np.asarray(order)).tolist()
    return levels, par_local, inverse


def _walk(parents: tuple[int, ...], R_loc, t_loc):
    """World transforms from parent-frame ones, one batched product per depth level (the levels of
    :func:`jaxanim._tree.levels`; body 0, the world, is the only root)."""
    levels, par_local, inverse = _walk_plan(parents)
    R_prev, t_prev = R_loc[0:1], t_loc[0:1]
    Rs, ts = [R_prev], [t_prev]
    for row, par in zip(levels[1:], par_local):
        R_par, t_par = _take(R_prev, par), _take(t_prev, par)
        t_prev = t_par + _mv(R_par, _take(t_loc, row))
        R_prev = mm(R_par, _take(R_loc, row))
        Rs.append(R_prev)
        ts.append(t_prev)
    return _take(jnp.concatenate(Rs, axis=0), inverse), _take(jnp.concatenate(ts, axis=0), inverse)


def check_qpos(robot, qpos):
    if not isinstance(robot, Robot):
        raise JaxanimError(f"robot: expected a jaxanim.robots.Robot, got {type(robot).__name__}")
    check_shape("qpos", qpos, (robot.nq,), what=f"(nq,) = ({robot.nq},)")
    check_float("qpos", qpos)
    qpos = jnp.asarray(qpos)
    dtype = jnp.result_type(robot.body_pos.dtype, qpos.dtype, float)
    return qpos.astype(dtype), dtype


def mm(A, B):
    """``A @ B`` over the last two axes of 3 x 3 blocks, written elementwise: XLA:CPU runs a batch of
    tiny dots slowly, and nested ``vmap`` s of them have met an XLA layout bug (a dot's batch
    dimensions out of order)."""
    return sum(A[..., :, c, None] * B[..., None, c, :] for c in range(3))


def _mv(A, v):
    """``A @ v`` for 3 x 3 blocks and 3-vectors, elementwise (see :func:`mm`)."""
    return sum(A[..., :, c] * v[..., None, c] for c in range(3))


def _eye(n, dtype):
    return jnp.broadcast_to(jnp.eye(3, dtype=dtype), (n, 3, 3))


def _joint_transforms(plan: _Plan, robot: Robot, qpos, dtype):
    """Every joint's transform in its body's frame (stage 1): ``(R [joints, 3, 3], t [joints, 3])``."""
    axis = robot.jnt_axis.astype(dtype)
    value = _take(qpos, plan.q_scalar) - _take(robot.qpos0.astype(dtype), plan.q_scalar)
    angle = jnp.where(plan.hinge, value, 0.0)
    shift = jnp.where(plan.slide, value, 0.0)
    quat_q = qpos[np.asarray(plan.q_quat)]  # ball / free: the qpos quaternion
    quat = jnp.where((plan.ball | plan.free)[:, None], quat_q, rot.axis_angle_to_quat(axis, angle))
    R = rot.quat_to_matrix(quat)  # normalises the qpos quaternions, as MuJoCo does
    anchor = jnp.where(plan.free[:, None], 0.0, robot.jnt_pos.astype(dtype))
    t = anchor - _mv(R, anchor) + shift[:, None] * axis
    t = jnp.where(plan.free[:, None], qpos[np.asarray(plan.q_pos)], t)
    return R, t, anchor


def world_frames(robot: Robot, qpos, dtype):
    """World frames of the bodies and, for each joint, of its body just after the joint."""
    plan = kinematic_plan(robot)
    B, J = robot.num_bodies, plan.J
    R_body = rot.quat_to_matrix(robot.body_quat.astype(dtype))
    t_body = robot.body_pos.astype(dtype)
    R_loc = jnp.where(plan.body_free[:, None, None], _eye(B, dtype), R_body)
    t_loc = jnp.where(plan.body_free[:, None], 0.0, t_body)
    if J:
        R_j, t_j, anchor = _joint_transforms(plan, robot, qpos, dtype)
        R_pad = jnp.concatenate([R_j, _eye(1, dtype)], axis=0)
        t_pad = jnp.concatenate([t_j, jnp.zeros((1, 3), dtype)], axis=0)
        R_after, t_after = [], []
        for slot in plan.slots:
            t_loc = t_loc + _mv(R_loc, _take(t_pad, slot))
            R_loc = mm(R_loc, _take(R_pad, slot))
            R_after.append(R_loc)
            t_after.append(t_loc)
    R_world, p_world = _walk(plan.parents_fk, R_loc, t_loc)
    if not J:
        empty = jnp.zeros((0, 3), dtype)
        return R_world, p_world, empty, empty
    # the world frame of each joint's body just after the joint: its anchor and axis
    R_a = _take(jnp.concatenate(R_after, axis=0), plan.after)
    t_a = _take(jnp.concatenate(t_after, axis=0), plan.after)
    R_par = _take(R_world, plan.jnt_parent)
    p_par = _take(p_world, plan.jnt_parent)
    R_jw = mm(R_par, R_a)
    p_jw = p_par + _mv(R_par, t_a)
    xanchor = p_jw + _mv(R_jw, anchor)
    xaxis = _mv(R_jw, robot.jnt_axis.astype(dtype))
    return R_world, p_world, xanchor, xaxis


def _at_bodies(R_world, p_world, bodies, pos, dtype):
    """World positions of points given in body frames: ``p_b + R_b pos``."""
    if not bodies:
        return jnp.zeros((0, 3), dtype)
    return _take(p_world, bodies) + _mv(_take(R_world, bodies), pos.astype(dtype))


@eqx.filter_jit
def _fk(robot: Robot, qpos, dtype) -> RobotFK:
    R_world, p_world, _, _ = world_frames(robot, qpos, dtype)
    xipos = _at_bodies(R_world, p_world, list(range(robot.num_bodies)), robot.body_ipos, dtype)
    sites = list(robot.site_bodies)
    site_xpos = _at_bodies(R_world, p_world, sites, robot.site_pos, dtype)
    if sites:
        R_site = rot.quat_to_matrix(robot.site_quat.astype(dtype))
        site_xmat = mm(_take(R_world, sites), R_site)
    else:
        site_xmat = jnp.zeros((0, 3, 3), dtype)
    return RobotFK(p_world, R_world, rot.matrix_to_quat(R_world), xipos, site_xpos, site_xmat)


def forward_kinematics(robot: Robot, qpos: Float[Array, " nq"]) -> RobotFK:
    """World poses of every body, body centre of mass and site (MuJoCo's ``mj_kinematics``).

    Args:
        robot: the robot.
        qpos: ``[nq]`` generalised coordinates in MuJoCo's order (``robot.jnt_qposadr``): a free
            joint is ``[x, y, z, qw, qx, qy, qz]`` (the body's world pose; the quaternion need not be
            unit), a ball joint a wxyz quaternion, a hinge an angle (rad) and a slide a length (m),
            both measured from ``robot.qpos0``.

    Returns:
        :class:`RobotFK`: ``xpos [bodies, 3]``, ``xmat [bodies, 3, 3]``, ``xquat [bodies, 4]``,
        ``xipos [bodies, 3]``, ``site_xpos [sites, 3]``, ``site_xmat [sites, 3, 3]``, in the dtype of
        ``qpos`` and the robot's arrays promoted together.

    Raises:
        JaxanimError: if ``qpos`` does not have shape ``(nq,)``.
    """
    qpos, dtype = check_qpos(robot, qpos)
    return _fk(robot, qpos, dtype)


def target_rows(robot: Robot, names) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """``(body of each target, row of each target's point in [xpos (bodies); site_xpos (sites)])``."""
    if isinstance(names, str):
        names = (names,)
    try:
        names = tuple(names)
    except TypeError:
        raise JaxanimError(f"names: expected a sequence of body or site names, got {type(names).__name__}") from None
    bodies, rows = [], []
    for name in names:
        if not isinstance(name, str):
            raise JaxanimError(f"names: expected body or site names (str), got {name!r}")
        kind, _, bare = name.partition(":") if name.startswith(("body:", "site:")) else ("", "", name)
        is_body = kind in ("", "body") and bool(bare) and bare in robot.body_names
        is_site = kind in ("", "site") and bool(bare) and bare in robot.site_names
        if is_body and is_site:
            raise JaxanimError(f"names: {name!r} is both a body and a site; write 'body:{bare}' or 'site:{bare}'")
        if is_body:
            b = robot.body_names.index(bare)
            bodies.append(b)
            rows.append(b)
        elif is_site:
            s = robot.site_names.index(bare)
            bodies.append(robot.site_bodies[s])
            rows.append(robot.num_bodies + s)
        else:
            valid = [n for n in robot.body_names if n] if kind == "body" else [n for n in robot.site_names if n]
            if not kind:
                valid = [n for n in robot.body_names if n] + [n for n in robot.site_names if n]
            raise JaxanimError(f"names: unknown {kind or 'body or site'} {bare!r}; valid names: {valid}")
    return tuple(bodies), tuple(rows)


def _points(robot: Robot, R_world, p_world, rows, dtype):
    """World points ``[K, 3]`` of targets given as rows of ``[xpos (bodies); site_xpos (sites)]``."""
    site_xpos = _at_bodies(R_world, p_world, list(robot.site_bodies), robot.site_pos, dtype)
    return _take(jnp.concatenate([p_world, site_xpos], axis=0), rows)


def target_frames(robot: Robot, R_world, p_world, bodies, rows, dtype):
    """World points ``[K, 3]`` and frames ``[K, 3, 3]`` of targets (a body's ``xmat``, a site's
    ``site_xmat``), ``bodies`` and ``rows`` as :func:`target_rows` gives them."""
    points = _points(robot, R_world, p_world, rows, dtype)
    R = _take(R_world, bodies)
    sites = [r - robot.num_bodies for r in rows]
    if any(s >= 0 for s in sites):
        R_site = rot.quat_to_matrix(_take(robot.site_quat.astype(dtype), [max(s, 0) for s in sites]))
        R = jnp.where(np.asarray([s >= 0 for s in sites])[:, None, None], mm(R, R_site), R)
    return points, R


def surface_points(robot: Robot, R_world, p_world, points, dtype):
    """World positions ``[P, 3]`` of the surface points ``points`` (indices into ``robot.point_pos``)
    and the height above ``z = 0`` of the surface around each (``z - point_radius``)."""
    bodies = [robot.point_bodies[i] for i in points]
    world = _at_bodies(R_world, p_world, bodies, _take(robot.point_pos, points), dtype)
    return world, world[:, 2] - _take(robot.point_radius.astype(dtype), points)


def dof_axes(robot: Robot, kin, dofs, dtype):
    """``(axis, anchor)`` ``[n, 3]``: the world axis of each of the dofs ``dofs`` (a hinge's or slide's, a ball's
    or a free joint's rotation about its body's axes, a free joint's translation along the world's) and the
    anchor it turns about; ``kin`` is :func:`world_frames`'s output."""
    plan = kinematic_plan(robot)
    R_world, _, xanchor, xaxis = kin
    columns = jnp.swapaxes(R_world, 1, 2).reshape(3 * robot.num_bodies, 3)  # row 3 b + c: column c of xmat_b
    table = jnp.concatenate([xaxis, columns, jnp.eye(3, dtype=dtype)], axis=0)
    return _take(table, [plan.dof_src[d] for d in dofs]), _take(xanchor, [plan.dof_joint[d] for d in dofs])


def dof_columns(robot: Robot, kin, points, bodies, dofs, dtype):
    """``(jacp, jacr)`` ``[K, n, 3]``: MuJoCo's Jacobian columns of the dofs ``dofs`` at the target
    ``points`` on ``bodies`` (zero where a dof does not move the target's body); ``kin`` is
    :func:`world_frames`'s output."""
    plan = kinematic_plan(robot)
    dofs = np.asarray(dofs, dtype=np.int64)
    dof_axis, dof_anchor = (x[None] for x in dof_axes(robot, kin, dofs, dtype))  # [1, n, 3]
    moves = plan.moves[np.asarray(bodies)][:, dofs]  # [K, n] static
    is_rot = plan.dof_rot[dofs]
    rot_mask, lin_mask = (moves & is_rot)[:, :, None], (moves & ~is_rot)[:, :, None]
    arm = jnp.cross(dof_axis, points[:, None, :] - dof_anchor)  # [K, n, 3]
    jacp = jnp.where(rot_mask, arm, jnp.where(lin_mask, dof_axis, 0.0))
    jacr = jnp.where(rot_mask, dof_axis, 0.0)
    return jacp, jacr


@eqx.filter_jit
def _jac(robot: Robot, qpos, dtype, bodies: tuple[int, ...], rows: tuple[int, ...]):
    K, nv = len(bodies), robot.nv
    if K == 0 or nv == 0:
        z = jnp.zeros((K, 3, nv), dtype)
        return z, z
    kin = world_frames(robot, qpos, dtype)
    points = _points(robot, kin[0], kin[1], rows, dtype)
    jacp, jacr = dof_columns(robot, kin, points, bodies, range(nv), dtype)
    return jnp.swapaxes(jacp, 1, 2), jnp.swapaxes(jacr, 1, 2)


def jacobian(
    robot: Robot, qpos: Float[Array, " nq"], names
) -> tuple[Float[Array, "targets 3 nv"], Float[Array, "targets 3 nv"]]:
    """Geometric Jacobians of body origins and sites (MuJoCo's ``mj_jacBody`` / ``mj_jacSite``).

    ``jacp[k] @ qvel`` is the world velocity of target ``k``'s point (a body's frame origin, a
    site's position) and ``jacr[k] @ qvel`` the world angular velocity of its body, for the
    velocity ``qvel [nv]`` in MuJoCo's convention: a free joint's six entries are the linear
    velocity of its body's origin **in world coordinates**, then the angular velocity **in the
    body's local frame**; a ball joint's three the angular velocity in its body's frame; a hinge or
    slide one rate each.

    Args:
        robot: the robot.
        qpos: ``[nq]`` configuration (as for :func:`forward_kinematics`).
        names: body and site names (a str for one). A name that is both a body and a site (the CMU
            humanoid's ``"root"``) must be written ``"body:root"`` or ``"site:root"``.

    Returns:
        ``(jacp, jacr)``, each ``[targets, 3, nv]``.

    Raises:
        JaxanimError: a wrong ``qpos`` shape, or an unknown or ambiguous name (listing the valid ones).
    """
    qpos, dtype = check_qpos(robot, qpos)
    bodies, rows = target_rows(robot, names)
    return _jac(robot, qpos, dtype, bodies, rows)


@eqx.filter_jit
def _com(robot: Robot, qpos, dtype, members: tuple[int, ...]):
    R_world, p_world, _, _ = world_frames(robot, qpos, dtype)
    xipos = _at_bodies(R_world, p_world, list(members), _take(robot.body_ipos, members), dtype)
    mass = _take(robot.body_mass.astype(dtype), members)
    total = jnp.sum(mass)
    total = eqx.error_if(total, ~(total > 0), "center_of_mass: the bodies have no mass (a total of 0 kg)")
    return einsum("b,bx->x", mass, xipos) / total


def center_of_mass(robot: Robot, qpos: Float[Array, " nq"], *, body: str | None = None) -> Float[Array, "3"]:
    """Centre of mass of the whole robot, or of one body's subtree (MuJoCo's ``subtree_com``).

    ``c = sum_b m_b xipos_b / sum_b m_b`` over all bodies (``body=None``: MuJoCo's
    ``subtree_com[0]``, equal to ``subtree_com[1]`` when the world has one child tree, as a robot
    does) or over ``body`` and its descendants.

    Args:
        robot: the robot.
        qpos: ``[nq]`` configuration (as for :func:`forward_kinematics`).
        body: a body name, or ``None`` for the whole robot.

    Returns:
        ``[3]`` world position (m).

    Raises:
        JaxanimError: a wrong ``qpos`` shape or an unknown body.
        EquinoxRuntimeError: if the bodies have no mass.
    """
    qpos, dtype = check_qpos(robot, qpos)
    root = 0 if body is None else robot.body_index(body)
    below = _tree.subtree(robot.body_parents)
    members = tuple(int(k) for k in np.flatnonzero(below[root]))
    return _com(robot, qpos, dtype, members)
