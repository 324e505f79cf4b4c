"""The IK problem in the solver's variables: layout, pose map, residual and its exact Jacobian.

The course notes' objective (``SEEDS.md`` §1.F)::

    F(theta) = 1/2 sum_i w_i |f_i(theta) - x_i|^2 + 1/2 lambda sum_j w_j |delta_j|^2

Variables. The pose is written in exponential coordinates around a reference pose ``R_ref``
(by default the initial pose): ``R_j = exp(delta_j) R_ref_j`` with ``delta_j`` a rotation vector
in joint ``j``'s parent frame, plus the root translation ``t_0 = t_ref_0 + d``. The regularizer
``sqrt(lambda w_j) delta_j`` pulls towards the reference. The Jacobian of these coordinates is the
geometric Jacobian times the left Jacobian of SO(3), ``J_l(delta_j)``, so it is exact and
Gauss-Newton converges quadratically.

What moves:
    * ``root_translation="fixed"`` removes ``d``;
    * ``frozen`` joints keep their reference rotations (their columns are removed);
    * ``pin`` names a joint or End Site that stays where the reference pose puts it: the root
      translation is then not a variable but follows from the rotations so that the pinned site
      does not move (exactly, not by a penalty), which makes the pinned site the root of the
      IK chain (the notes' "put the root at the foot").

Orientation targets use the residual ``log(R_site R_target^T)`` (world frame rotation vector) with
its exact Jacobian ``J_l^{-1}(e)``.

Compiling once. The residual :func:`_residual` and the stop test :func:`_stop` are module-level
functions of ``(y, data)``: everything that describes one problem is in :class:`_IKData` (its
structure static and hashable, its numbers arrays), so a jitted solve is keyed on the structure
alone and new targets or start poses reuse it. :func:`_residual` returns the residual and its
Jacobian together (one FK pass, one call per linearization: ``least_squares(..., jac=True)``).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .. import rotations as rot
from .._errors import JaxanimError
from .._linalg import einsum, matmul, own_kernel
from .._types import Array
from ..kinematics._fk import forward_kinematics
from ..kinematics._jacobians import jacobian_from_fk
from ..kinematics._limits import limit_charts, resolve_limits
from ..skeleton._skeleton import Skeleton
from ._targets import Target, _check_targets


# --- static layout --------------------------------------------------------------------------------


class _Layout(eqx.Module):
    """Static bookkeeping of one IK problem: which columns are variables, which sites are targets."""

    site_idx: tuple[int, ...] = eqx.field(static=True)
    has_pos: tuple[bool, ...] = eqx.field(static=True)
    has_ori: tuple[bool, ...] = eqx.field(static=True)
    free_joints: tuple[int, ...] = eqx.field(static=True)
    free_root: bool = eqx.field(static=True)
    pin_idx: int | None = eqx.field(static=True)
    limit_slots: tuple[int, ...] = eqx.field(static=True, default=())  # positions in free_joints
    limit_ids: tuple[int, ...] = eqx.field(static=True, default=())  # the matching entries of limits
    hard: bool = eqx.field(static=True, default=True)

    @property
    def num_variables(self) -> int:
        return (3 if self.free_root else 0) + 3 * len(self.free_joints)


def _layout(skeleton: Skeleton, targets, pin, frozen, root_translation, limits=(), limit_mode="hard") -> _Layout:
    """Validate one problem's structure (raises :class:`JaxanimError` before tracing) and lay it out."""
    targets, site_idx = _check_targets(skeleton, targets, root_translation)
    frozen_idx = {skeleton.index(n) for n in frozen}
    pin_idx = None if pin is None else skeleton.site_index(pin)
    free_joints = tuple(j for j in range(skeleton.num_joints) if j not in frozen_idx)
    free_root = root_translation == "free" and pin is None
    if not free_joints and not free_root:
        raise JaxanimError("frozen: every joint is frozen and the root translation is fixed: nothing can move")
    if limit_mode not in ("hard", "soft"):
        raise JaxanimError(f"limit_mode: expected 'hard' or 'soft', got {limit_mode!r}")
    limit_joints = resolve_limits(skeleton, limits)
    # a frozen joint keeps its reference rotation: its limit does not apply
    pairs = [(free_joints.index(j), i) for i, j in enumerate(limit_joints) if j in free_joints]
    return _Layout(
        site_idx, tuple(t.position is not None for t in targets), tuple(t.orientation is not None for t in targets),
        free_joints, free_root, pin_idx,
        tuple(k for k, _ in pairs), tuple(i for _, i in pairs), limit_mode == "hard",
    )


# --- one problem's data: the args of the residual -------------------------------------------------


class _IKData(eqx.Module):
    """Everything :func:`_residual` and :func:`_stop` need besides ``y``: static structure (the
    skeleton's tree, the layout, the targets' sites) and arrays (targets, reference pose, weights)."""

    skeleton: Skeleton
    layout: _Layout
    targets: tuple[Target, ...]
    q_ref: Array  # [joints, 4] reference rotations
    t_ref: Array  # [joints, 3] reference translations
    p_world_pin: Array | None  # [3] where the reference pose puts the pinned site
    reg_w: Array | None  # [joints] lambda w_j, None: no regularizer rows
    charts: tuple  # the limited joints' chart groups
    limit_w: Array  # soft-limit weight
    position_tolerance: Array
    orientation_tolerance: Array


def _setup(
    skeleton, layout, targets, q0, t0, q_ref, t_ref, reg_w, limits, limit_weight,
    position_tolerance=1e-5, orientation_tolerance=1e-4,
) -> tuple[_IKData, Array, tuple[Array, Array] | None]:
    """``(data, y0, bounds)``: one problem in the solver's variables. Arrays in ``q0``'s dtype."""
    dtype = q0.dtype
    p_world_pin = None
    if layout.pin_idx is not None:
        p_world_pin = forward_kinematics(skeleton, q_ref, t_ref).site_positions()[layout.pin_idx]
    charts = limit_charts(skeleton, [limits[i] for i in layout.limit_ids],
                     [layout.free_joints[k] for k in layout.limit_slots], layout.limit_slots, layout.hard, dtype)
    data = _IKData(
        skeleton, layout, tuple(targets), q_ref, t_ref, p_world_pin, reg_w, tuple(charts),
        jnp.asarray(limit_weight, dtype), jnp.asarray(position_tolerance, dtype),
        jnp.asarray(orientation_tolerance, dtype),
    )
    # initial variables: the initial pose in coordinates around the reference (limited joints: in
    # their chart, projected into the limit when hard)
    nfree = len(layout.free_joints)
    d0 = rot.quat_to_rotvec(rot.quat_multiply(q0, rot.quat_conjugate(q_ref)))[jnp.asarray(layout.free_joints)]
    for group in charts:
        js = jnp.asarray([layout.free_joints[k] for k in group.slots])
        d0 = d0.at[jnp.asarray(group.slots)].set(group.from_quat(q0[js]))
    off = 3 if layout.free_root else 0
    parts = ([t0[0] - t_ref[0]] if layout.free_root else []) + [d0.reshape(3 * nfree)]
    y0 = jnp.concatenate(parts)
    bounds = None
    if layout.hard and charts:
        lower = jnp.full(y0.shape, -jnp.inf, dtype)
        upper = jnp.full(y0.shape, jnp.inf, dtype)
        for group in charts:
            lo, hi = group.bounds()  # [g, 3]
            cols = jnp.asarray([[off + 3 * k + c for c in range(3)] for k in group.slots])
            lower = lower.at[cols].set(lo)
            upper = upper.at[cols].set(hi)
        bounds = (lower, upper)
    return data, y0, bounds


# --- pose, residual, Jacobian ---------------------------------------------------------------------


def _variables_to_pose(skeleton, layout, q_ref, t_ref, y, charts=()):
    """Pose from the variables ``y`` (before the pin moves the root).

    Returns ``(q, t, blocks, E)``: rotations (``exp(delta) R_ref`` for the unlimited free joints,
    the chart's rotation for limited ones), translations, the per-free-joint variable blocks
    ``[nfree, 3]`` and ``E [nfree, 3, 3]``, the map from a block's increment to the joint's
    parent-frame rotation-vector increment (``J_l(delta)`` or the chart's).
    """
    J = skeleton.num_joints
    nfree = len(layout.free_joints)
    off = 3 if layout.free_root else 0
    blocks = y[off : off + 3 * nfree].reshape(nfree, 3)
    limited = set(layout.limit_slots)
    exp_slots = np.asarray([k for k in range(nfree) if k not in limited], dtype=np.int32)
    exp_joints = np.asarray(layout.free_joints, dtype=np.int32)[exp_slots]
    delta = jnp.zeros((J, 3), y.dtype).at[exp_joints].set(blocks[exp_slots])
    q = rot.quat_multiply(rot.rotvec_to_quat(delta), q_ref)
    E = rot.left_jacobian(delta[jnp.asarray(layout.free_joints)]) if nfree else jnp.zeros((0, 3, 3), y.dtype)
    for group in charts:
        qk, Ek = group.omega_columns(blocks[jnp.asarray(group.slots)])
        q = q.at[jnp.asarray([layout.free_joints[k] for k in group.slots])].set(qk)
        E = E.at[jnp.asarray(group.slots)].set(Ek)
    t = t_ref
    if layout.free_root:
        t = t.at[0].add(y[:3])
    return q, t, blocks, E


def _pose(y, data: _IKData):
    """The solved pose ``(rotations [joints, 4], translations [joints, 3])`` of the variables ``y``,
    with the root translation that keeps the pinned site in place."""
    skeleton, layout = data.skeleton, data.layout
    q, t, _, _ = _variables_to_pose(skeleton, layout, data.q_ref, data.t_ref, y, data.charts)
    if layout.pin_idx is not None:  # the root translation follows the pin (see _residual_and_jacobian)
        t = t.at[0].add(data.p_world_pin - forward_kinematics(skeleton, q, t).site_positions()[layout.pin_idx])
    return q, t


def _site_rotations(skeleton, out, site_idx):
    J = skeleton.num_joints
    owner = [s if s < J else skeleton.end_site_parents[s - J] for s in site_idx]
    return out.rotations[jnp.asarray(owner)]


def _variable_jacobian(skeleton, layout, out, E, p_world_pin, dtype):
    """``(J_vars [targets, 6, n], shift [3])``: the geometric Jacobian of the target sites w.r.t.
    the variables (root translation, then ``E_j`` per free joint), and the translation of the whole
    body that keeps the pinned site at ``p_world_pin`` (zero without a pin)."""
    sites = layout.site_idx + ((layout.pin_idx,) if layout.pin_idx is not None else ())
    J_sites = jacobian_from_fk(skeleton, out.rotations, out.positions, out.end_site_positions, sites)  # [S(+1), 6, 3+3J]
    nfree = len(layout.free_joints)
    cols = np.asarray([3 + 3 * j + k for j in layout.free_joints for k in range(3)], dtype=np.int32)
    J_rot = J_sites[..., cols].reshape(J_sites.shape[0], 6, nfree, 3)
    # [s, a, k, c] x [k, c, d] summed over c, written elementwise: as a dot_general it becomes a
    # batch of tiny matrix products under vmap, several times slower on XLA:CPU
    J_rot = sum(J_rot[..., c, None] * E[None, None, :, c, :] for c in range(3))
    J_rot = J_rot.reshape(J_sites.shape[0], 6, 3 * nfree)
    if layout.pin_idx is not None:
        # translate the body so the pinned site stays at p_world_pin: every position moves by
        # shift, and every linear Jacobian row loses the pinned site's
        shift = p_world_pin - out.site_positions()[layout.pin_idx]
        J_rot = J_rot.at[:-1, :3].add(-J_rot[-1:, :3])
        J_rot = J_rot[:-1]
    else:
        shift = jnp.zeros(3, dtype)
    if layout.free_root:
        return jnp.concatenate([J_sites[: len(layout.site_idx), :, :3], J_rot], axis=2), shift
    return J_rot, shift


def _target_rows(layout, targets, p_world_sites, R_world_sites, J_vars, shift, dtype):
    """Residual blocks ``sqrt(w) (p - p_target)`` and ``sqrt(w) log(R R_target^T)`` with their rows,
    in target order (each target's position block, then its orientation block).

    The blocks of all position targets, and of all orientation targets, are computed as one
    stacked array each (one traced rotation log for every target, not one per target: the
    compiled program stays small), then put in target order by a static gather.
    """
    n = J_vars.shape[-1]
    pos = [i for i, t in enumerate(targets) if t.position is not None]
    ori = [i for i, t in enumerate(targets) if t.orientation is not None]
    sqrt_w = jnp.sqrt(jnp.stack([jnp.asarray(t.weight, dtype) for t in targets]))  # [targets]
    res, rows = [], []
    if pos:
        ip = np.asarray(pos)
        goal = jnp.stack([targets[i].position.astype(dtype) for i in pos])  # [kp, 3]
        p_world = p_world_sites[np.asarray([layout.site_idx[i] for i in pos])] + shift[None]
        res.append(sqrt_w[ip, None] * (p_world - goal))
        rows.append(sqrt_w[ip, None, None] * J_vars[ip, :3])
    if ori:
        io = np.asarray(ori)
        R_goal = rot.quat_to_matrix(jnp.stack([targets[i].orientation.astype(dtype) for i in ori]))  # [ko, 3, 3]
        R_site = R_world_sites[io]
        # R_site @ R_goal^T, written elementwise (a batch of 3x3 dots is slow under vmap on XLA:CPU)
        e = rot.matrix_to_rotvec(sum(R_site[..., :, c, None] * R_goal[..., None, :, c] for c in range(3)))
        e = own_kernel(e)  # computed once, not inside each entry of its left Jacobian below
        Li = rot.left_jacobian_inverse(e)  # [ko, 3, 3]
        J_ang = J_vars[io, 3:]  # [ko, 3, n]
        res.append(sqrt_w[io, None] * e)
        rows.append(sqrt_w[io, None, None] * sum(Li[:, :, c, None] * J_ang[:, c, None, :] for c in range(3)))
    order, kp = [], len(pos)
    for i in range(len(targets)):
        order += ([pos.index(i)] if i in pos else []) + ([kp + ori.index(i)] if i in ori else [])
    order = np.asarray(order)
    return [jnp.concatenate(res)[order].reshape(-1)], [jnp.concatenate(rows)[order].reshape(-1, n)]


def _regularization_rows(layout, blocks, q, q_ref, E, reg_w, n, dtype):
    """The regularizer towards the reference pose, per free joint: ``sqrt(w_j) log(R_j R_ref_j^T)``,
    which is the variable block itself for unlimited joints (exponential coordinates around R_ref)."""
    off = 3 if layout.free_root else 0
    nfree = len(layout.free_joints)
    sqrt_w = jnp.sqrt(reg_w[jnp.asarray(layout.free_joints)])  # [nfree]
    reg_res = blocks
    reg_jac = jnp.broadcast_to(jnp.eye(3, dtype=dtype), (nfree, 3, 3))
    if layout.limit_slots:
        ks = jnp.asarray(layout.limit_slots)
        js = jnp.asarray([layout.free_joints[k] for k in layout.limit_slots])
        e = rot.quat_to_rotvec(rot.quat_multiply(q[js], rot.quat_conjugate(q_ref[js])))
        reg_res = reg_res.at[ks].set(e)
        reg_jac = reg_jac.at[ks].set(matmul(rot.left_jacobian_inverse(e), E[ks]))
    block = einsum("kl,kab->kalb", jnp.diag(sqrt_w), reg_jac).reshape(3 * nfree, 3 * nfree)
    return (sqrt_w[:, None] * reg_res).reshape(3 * nfree), jnp.concatenate([jnp.zeros((3 * nfree, off), dtype), block], axis=1)


def _soft_limit_rows(layout, charts, blocks, limit_w, n, dtype):
    """Soft joint limits: ``sqrt(limit_w)`` times the angle outside each limit, with their rows."""
    off = 3 if layout.free_root else 0
    sqrt_w = jnp.sqrt(limit_w)
    res, rows = [], []
    for group in charts:
        th = blocks[jnp.asarray(group.slots)]
        res.append(sqrt_w * group.excess(th).reshape(-1))
        dk = sqrt_w * group.excess_jacobian(th)  # [g, p, 3]
        g, p = dk.shape[:2]
        cols = np.asarray([[off + 3 * k + c for c in range(3)] for k in group.slots])  # [g, 3]
        rows_k = jnp.zeros((g, p, n), dtype)
        rows_k = rows_k.at[np.arange(g)[:, None, None], np.arange(p)[None, :, None], cols[:, None, :]].set(dk)
        rows.append(rows_k.reshape(g * p, n))
    return res, rows


def _residual_and_jacobian(skeleton, layout, targets, q_ref, t_ref, p_world_pin, y, reg_w, charts=(), limit_w=None):
    """Residual vector, its exact Jacobian w.r.t. ``y`` and the pose (one FK pass serves all)."""
    dtype = y.dtype
    n = y.shape[0]
    q, t, blocks, E = _variables_to_pose(skeleton, layout, q_ref, t_ref, y, charts)
    out = forward_kinematics(skeleton, q, t)
    J_vars, shift = _variable_jacobian(skeleton, layout, out, E, p_world_pin, dtype)
    if layout.pin_idx is not None:
        t = t.at[0].add(shift)
    res, rows = _target_rows(layout, targets, out.site_positions(), _site_rotations(skeleton, out, layout.site_idx),
                             J_vars, shift, dtype)
    if layout.free_joints and reg_w is not None:
        r_reg, J_reg = _regularization_rows(layout, blocks, q, q_ref, E, reg_w, n, dtype)
        res.append(r_reg)
        rows.append(J_reg)
    if not layout.hard:
        r_lim, J_lim = _soft_limit_rows(layout, charts, blocks, limit_w, n, dtype)
        res += r_lim
        rows += J_lim
    return jnp.concatenate(res), jnp.concatenate(rows, axis=0).reshape(-1, n), (q, t)


def _residual(y, data: _IKData):
    """``(r [m], J [m, n])`` of one problem: the residual function of ``least_squares(jac=True)``."""
    r, J, _ = _residual_and_jacobian(
        data.skeleton, data.layout, data.targets, data.q_ref, data.t_ref, data.p_world_pin, y, data.reg_w,
        data.charts, data.limit_w,
    )
    return r, J


def _stop(y, r, data: _IKData):
    """Every target's residual (``sqrt(w)`` times its error, in the order :func:`_target_rows`
    writes them) within ``sqrt(w)`` times its tolerance: the early stop of ``stop_at_tolerance``."""
    dtype = r.dtype
    ok, k = jnp.array(True), 0
    for tgt in data.targets:
        for present, tol in ((tgt.position is not None, data.position_tolerance),
                             (tgt.orientation is not None, data.orientation_tolerance)):
            if present:
                sqrt_w = jnp.sqrt(jnp.asarray(tgt.weight, dtype))
                ok = ok & (jnp.sqrt(jnp.sum(r[k : k + 3] ** 2)) <= sqrt_w * jnp.asarray(tol, dtype))
                k += 3
    return ok
