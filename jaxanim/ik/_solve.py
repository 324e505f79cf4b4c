"""Inverse kinematics on a :class:`~jaxanim.Skeleton` as a nonlinear least-squares problem.

The course notes' objective (``SEEDS.md`` §1.F)::

    F(theta) = 1/2 sum_i w_i |f_i(theta) - x_i|^2 + 1/2 lambda sum_j w_j |delta_j|^2

is solved by :func:`solvers.least_squares` (Gauss-Newton or Levenberg-Marquardt, own or backend
solvers) with the analytic Jacobian of :func:`jaxanim.jacobian`.

Variables. The pose is written in exponential coordinates around a reference pose ``R_ref``
(by default the initial pose): ``R_j = exp(delta_j) R_ref_j`` with ``delta_j`` a rotation vector
in joint ``j``'s parent frame, plus the root translation ``t_0 = t_ref_0 + d``. The regulariser
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
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import solvers

from .. import rotations as rot
from .._errors import JaxanimError, check_shape
from .._types import Array, Float
from ..kinematics._fk import forward_kinematics
from ..kinematics._jacobians import _jacobian_from_fk, _site_indices
from ..kinematics._limits import EulerLimit as EulerLimit, SwingTwistLimit as SwingTwistLimit, _charts, _resolve
from ..kinematics._limits import limit_violation as limit_violation
from ..skeleton._skeleton import Motion, Skeleton


class Target(eqx.Module):
    """One IK target: a position and/or an orientation for a joint or End Site.

    Leading axes on ``position`` / ``orientation`` / ``weight`` are allowed for batches (per frame,
    per character), to be mapped over with ``jax.vmap``; :func:`solve_ik` takes one.

    Attributes:
        site: joint name or End Site name (``<joint>_End``). Static.
        position: ``[3]`` world position (file units), or ``None``.
        orientation: ``[4]`` wxyz world orientation of the site's frame, or ``None``.
        weight: scalar weight ``w`` of this target's squared error (array: sweepable by vmap).
    """

    site: str = eqx.field(static=True)
    position: Float[Array, "3"] | None
    orientation: Float[Array, "4"] | None
    weight: Float[Array, ""]

    def __init__(self, site: str, position=None, orientation=None, weight=1.0):
        if position is None and orientation is None:
            raise JaxanimError(f"targets: the target for {site!r} has neither a position nor an orientation")
        self.site = str(site)
        if position is not None:
            check_shape(f"targets[{site!r}].position", position, (3,), batch=True)
            position = jnp.asarray(position)
        if orientation is not None:
            check_shape(f"targets[{site!r}].orientation", orientation, (4,), batch=True)
            orientation = jnp.asarray(orientation)
        self.position = position
        self.orientation = orientation
        self.weight = jnp.asarray(weight)


class IKSolution(eqx.Module):
    """Result of :func:`solve_ik`.

    Attributes:
        rotations: ``[joints, 4]`` local wxyz quaternions of the solved pose.
        translations: ``[joints, 3]`` local translations (the root's may have moved).
        result: :class:`solvers.RESULTS`, per element under ``vmap``.
        stats: the solver's statistics (``num_steps``, ``cost``, ...).
        position_errors: ``[targets]`` distance to each position target (0 where none).
        orientation_errors: ``[targets]`` angle to each orientation target, radians (0 where none).
        success: scalar bool: the solver converged **and** every target is met within the
            tolerances of :func:`solve_ik`. An unreachable target gives ``False`` with ``result``
            successful: the pose is then the least-squares-closest one the solver found.
    """

    rotations: Float[Array, "joints 4"]
    translations: Float[Array, "joints 3"]
    result: solvers.RESULTS
    stats: dict
    position_errors: Float[Array, " targets"]
    orientation_errors: Float[Array, " targets"]
    success: Array


def _left_jacobian(phi):
    """SO(3) left Jacobian ``J_l(phi)`` ``[..., 3, 3]`` with a Taylor branch at 0."""
    th2 = jnp.sum(phi * phi, axis=-1)
    small = th2 < 1e-8
    th2s = jnp.where(small, 1.0, th2)
    th = jnp.sqrt(th2s)
    a = jnp.where(small, 0.5 - th2 / 24.0, (1.0 - jnp.cos(th)) / th2s)
    b = jnp.where(small, 1.0 / 6.0 - th2 / 120.0, (th - jnp.sin(th)) / (th2s * th))
    K = rot.skew(phi)
    eye = jnp.broadcast_to(jnp.eye(3, dtype=phi.dtype), K.shape)
    return eye + a[..., None, None] * K + b[..., None, None] * (K @ K)


def _left_jacobian_inverse(phi):
    """``J_l(phi)^{-1}`` ``[..., 3, 3]``, with a Taylor branch at 0 (valid for |phi| < 2 pi)."""
    th2 = jnp.sum(phi * phi, axis=-1)
    small = th2 < 1e-8
    th2s = jnp.where(small, 1.0, th2)
    th = jnp.sqrt(th2s)
    c = jnp.where(small, 1.0 / 12.0 + th2 / 720.0, (1.0 / th2s) - (1.0 + jnp.cos(th)) / (2.0 * th * jnp.sin(th)))
    K = rot.skew(phi)
    eye = jnp.broadcast_to(jnp.eye(3, dtype=phi.dtype), K.shape)
    return eye - 0.5 * K + c[..., None, None] * (K @ K)


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


def _check_targets(skeleton: Skeleton, targets, root_translation) -> tuple[tuple[Target, ...], tuple[int, ...]]:
    """Validate one problem's targets and ``root_translation``; the targets and their site indices."""
    if isinstance(targets, Target):
        targets = (targets,)
    if not isinstance(targets, Sequence) or not targets or not all(isinstance(t, Target) for t in targets):
        raise JaxanimError("targets: expected a non-empty sequence of jaxanim.ik.Target")
    if root_translation not in ("free", "fixed"):
        raise JaxanimError(f"root_translation: expected 'free' or 'fixed', got {root_translation!r}")
    site_idx = _site_indices(skeleton, [t.site for t in targets])
    for t in targets:  # one problem: no leading axes (vmap over them instead)
        if t.position is not None:
            check_shape(f"targets[{t.site!r}].position", t.position, (3,))
        if t.orientation is not None:
            check_shape(f"targets[{t.site!r}].orientation", t.orientation, (4,))
        check_shape(f"targets[{t.site!r}].weight", t.weight, ())
    return tuple(targets), site_idx


def _layout(skeleton: Skeleton, targets, pin, frozen, root_translation, limits=(), limit_mode="hard") -> _Layout:
    targets, site_idx = _check_targets(skeleton, targets, root_translation)
    frozen_idx = {skeleton.index(n) for n in frozen}
    pin_idx = None if pin is None else skeleton.site_index(pin)
    free_joints = tuple(j for j in range(skeleton.num_joints) if j not in frozen_idx)
    free_root = root_translation == "free" and pin is None
    if not free_joints and not free_root:
        raise JaxanimError("frozen: every joint is frozen and the root translation is fixed: nothing can move")
    if limit_mode not in ("hard", "soft"):
        raise JaxanimError(f"limit_mode: expected 'hard' or 'soft', got {limit_mode!r}")
    limit_joints = _resolve(skeleton, limits)
    # a frozen joint keeps its reference rotation: its limit does not apply
    pairs = [(free_joints.index(j), i) for i, j in enumerate(limit_joints) if j in free_joints]
    return _Layout(
        site_idx, tuple(t.position is not None for t in targets), tuple(t.orientation is not None for t in targets),
        free_joints, free_root, pin_idx,
        tuple(k for k, _ in pairs), tuple(i for _, i in pairs), limit_mode == "hard",
    )


def _pose(skeleton, layout, q_ref, t_ref, y, charts=()):
    """Pose from the variables ``y``.

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
    E = _left_jacobian(delta[jnp.asarray(layout.free_joints)]) if nfree else jnp.zeros((0, 3, 3), y.dtype)
    for group in charts:
        qk, Ek = group.omega_columns(blocks[jnp.asarray(group.slots)])
        q = q.at[jnp.asarray([layout.free_joints[k] for k in group.slots])].set(qk)
        E = E.at[jnp.asarray(group.slots)].set(Ek)
    t = t_ref
    if layout.free_root:
        t = t.at[0].add(y[:3])
    return q, t, blocks, E


def _site_rotations(skeleton, out, site_idx):
    J = skeleton.num_joints
    owner = [s if s < J else skeleton.end_site_parents[s - J] for s in site_idx]
    return out.rotations[jnp.asarray(owner)]


def _residual_and_jacobian(skeleton, layout, targets, q_ref, t_ref, pin_ref, y, reg_w, charts=(), limit_w=None):
    """Residual vector and its exact Jacobian w.r.t. ``y`` (one FK pass serves both)."""
    q, t, blocks, Jl = _pose(skeleton, layout, q_ref, t_ref, y, charts)
    out = forward_kinematics(skeleton, q, t)
    sites = layout.site_idx + ((layout.pin_idx,) if layout.pin_idx is not None else ())
    G = _jacobian_from_fk(skeleton, out.rotations, out.positions, out.end_site_positions, sites)  # [S(+1), 6, 3+3J]
    # columns w.r.t. the variables: root translation and E_j (J_l(delta_j) or a chart's) per free joint
    cols = np.asarray([3 + 3 * j + k for j in layout.free_joints for k in range(3)], dtype=np.int32)
    Grot = G[..., cols].reshape(G.shape[0], 6, len(layout.free_joints), 3)
    # [s, a, k, c] x [k, c, d] summed over c, written elementwise: as a dot_general it becomes a
    # batch of tiny matrix products under vmap, several times slower on XLA:CPU
    Grot = sum(Grot[..., c, None] * Jl[None, None, :, c, :] for c in range(3))
    Grot = Grot.reshape(G.shape[0], 6, 3 * len(layout.free_joints))
    pos_all = out.site_positions()
    if layout.pin_idx is not None:
        # translate the body so the pinned site stays at pin_ref: every position moves by shift,
        # and every linear Jacobian row loses the pinned site's
        shift = pin_ref - pos_all[layout.pin_idx]
        Grot = Grot.at[:-1, :3].add(-Grot[-1:, :3])
        Grot = Grot[:-1]
        t = t.at[0].add(shift)
    else:
        shift = jnp.zeros(3, y.dtype)
    if layout.free_root:
        Gcols = jnp.concatenate([G[: len(layout.site_idx), :, :3], Grot], axis=2)
    else:
        Gcols = Grot
    R_sites = _site_rotations(skeleton, out, layout.site_idx)
    res, rows = [], []
    for i, tgt in enumerate(targets):
        sw = jnp.sqrt(jnp.asarray(tgt.weight, y.dtype))
        if tgt.position is not None:
            p = pos_all[layout.site_idx[i]] + shift
            res.append(sw * (p - tgt.position.astype(y.dtype)))
            rows.append(sw * Gcols[i, :3])
        if tgt.orientation is not None:
            R_t = rot.quat_to_matrix(tgt.orientation.astype(y.dtype))
            e = rot.matrix_to_rotvec(R_sites[i] @ R_t.T)
            res.append(sw * e)
            Li = _left_jacobian_inverse(e)
            rows.append(sw * sum(Li[:, c, None] * Gcols[i, 3 + c][None, :] for c in range(3)))  # Li @ G_ang
    # regulariser towards the reference pose, per free joint: sqrt(w_j) log(R_j R_ref_j^T), which is
    # the variable block itself for unlimited joints (exponential coordinates around R_ref)
    n = y.shape[0]
    off = 3 if layout.free_root else 0
    nfree = len(layout.free_joints)
    if nfree and reg_w is not None:
        sw = jnp.sqrt(reg_w[jnp.asarray(layout.free_joints)])  # [nfree]
        reg_res = blocks
        reg_jac = jnp.broadcast_to(jnp.eye(3, dtype=y.dtype), (nfree, 3, 3))
        if layout.limit_slots:
            ks = jnp.asarray(layout.limit_slots)
            js = jnp.asarray([layout.free_joints[k] for k in layout.limit_slots])
            e = rot.quat_to_rotvec(rot.quat_multiply(q[js], rot.quat_conjugate(q_ref[js])))
            reg_res = reg_res.at[ks].set(e)
            reg_jac = reg_jac.at[ks].set(_left_jacobian_inverse(e) @ Jl[ks])
        res.append((sw[:, None] * reg_res).reshape(3 * nfree))
        block = jnp.einsum("kl,kab->kalb", jnp.diag(sw), reg_jac).reshape(3 * nfree, 3 * nfree)
        rows.append(jnp.concatenate([jnp.zeros((3 * nfree, off), y.dtype), block], axis=1))
    # soft joint limits: sqrt(limit_w) times the angle outside each limit
    if not layout.hard:
        slw = jnp.sqrt(limit_w)
        for group in charts:
            th = blocks[jnp.asarray(group.slots)]
            res.append(slw * group.excess(th).reshape(-1))
            dk = slw * group.excess_jacobian(th)  # [g, p, 3]
            g, p = dk.shape[:2]
            cols = np.asarray([[off + 3 * k + c for c in range(3)] for k in group.slots])  # [g, 3]
            rows_k = jnp.zeros((g, p, n), y.dtype)
            rows_k = rows_k.at[np.arange(g)[:, None, None], np.arange(p)[None, :, None], cols[:, None, :]].set(dk)
            rows.append(rows_k.reshape(g * p, n))
    return jnp.concatenate(res), jnp.concatenate(rows, axis=0).reshape(-1, n), (q, t)


class _Setup(NamedTuple):
    """One IK problem in the solver's variables (see :func:`_setup`)."""

    fn: Callable  # y, args -> residual [m]
    jac: Callable  # y, args -> Jacobian [m, n]
    y0: Array  # [n] initial variables
    bounds: tuple[Array, Array] | None  # hard limits as a box on y
    pose: Callable  # y -> (rotations [J, 4], translations [J, 3]) with the pin applied
    layout: _Layout
    targets: tuple[Target, ...]
    dtype: Any
    var_weights: Array | None  # [n] joint weights per variable (None: not given)


def _setup(
    skeleton, targets, rotations, translations, *, reference, pin, frozen, root_translation, regularization,
    joint_weights, limits, limit_mode, limit_weight,
) -> _Setup:
    """Validate the input of :func:`solve_ik` and write the problem in the solver's variables."""
    J = skeleton.num_joints
    if isinstance(limits, (EulerLimit, SwingTwistLimit)):
        limits = (limits,)
    limits = tuple(limits)
    layout = _layout(skeleton, targets, pin, frozen, root_translation, limits, limit_mode)
    targets = (targets,) if isinstance(targets, Target) else tuple(targets)
    check_shape("rotations", rotations, (J, 4), what=f"(joints, 4) = ({J}, 4)")
    q0 = jnp.asarray(rotations)
    dtype = q0.dtype
    t0 = skeleton.offsets.astype(dtype) if translations is None else jnp.asarray(translations, dtype)
    check_shape("translations", t0, (J, 3), what=f"(joints, 3) = ({J}, 3)")
    if reference is None:
        q_ref, t_ref = q0, t0
    else:
        q_ref, t_ref = reference
        check_shape("reference[0]", q_ref, (J, 4), what=f"(joints, 4) = ({J}, 4)")
        check_shape("reference[1]", t_ref, (J, 3), what=f"(joints, 3) = ({J}, 3)")
        q_ref, t_ref = jnp.asarray(q_ref, dtype), jnp.asarray(t_ref, dtype)
    w = jnp.ones(J, dtype) if joint_weights is None else jnp.asarray(joint_weights, dtype)
    check_shape("joint_weights", w, (J,), what=f"(joints,) = ({J},)")
    # a literal 0 removes the regulariser's rows: the residual then has only the targets' rows
    # (fewer than the variables), and the solvers take the cheap m x m path
    no_reg = isinstance(regularization, (int, float)) and regularization == 0
    reg_w = None if no_reg else jnp.asarray(regularization, dtype) * w
    pin_ref = None
    if layout.pin_idx is not None:
        pin_ref = forward_kinematics(skeleton, q_ref, t_ref).site_positions()[layout.pin_idx]
    charts = _charts(skeleton, [limits[i] for i in layout.limit_ids],
                     [layout.free_joints[k] for k in layout.limit_slots], layout.limit_slots, layout.hard, dtype)
    limit_w = jnp.asarray(limit_weight, dtype)
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

    def fn(y, args):
        return _residual_and_jacobian(skeleton, layout, targets, q_ref, t_ref, pin_ref, y, reg_w, charts, limit_w)[0]

    def jac(y, args):
        return _residual_and_jacobian(skeleton, layout, targets, q_ref, t_ref, pin_ref, y, reg_w, charts, limit_w)[1]


    def pose(y):
        q, t, _, _ = _pose(skeleton, layout, q_ref, t_ref, y, charts)
        if layout.pin_idx is not None:  # the root translation follows the pin (see _residual_and_jacobian)
            t = t.at[0].add(pin_ref - forward_kinematics(skeleton, q, t).site_positions()[layout.pin_idx])
        return q, t

    # joint weights as the damping metric W of Levenberg-Marquardt (the notes' eq. 4.10)
    var_w = jnp.concatenate(([jnp.ones(3, dtype)] if layout.free_root else []) + [jnp.repeat(w[jnp.asarray(layout.free_joints)], 3)])
    return _Setup(fn, jac, y0, bounds, pose, layout, targets, dtype, None if joint_weights is None else var_w)


def _tolerance_stop(targets, position_tolerance, orientation_tolerance, dtype):
    """``stop(y, r, args)``: every target's residual (``sqrt(w)`` times its error, in the order
    :func:`_residual_and_jacobian` writes them) within ``sqrt(w)`` times its tolerance."""
    blocks, k = [], 0
    for tgt in targets:
        for present, tol in ((tgt.position is not None, position_tolerance), (tgt.orientation is not None, orientation_tolerance)):
            if present:
                blocks.append((k, tgt.weight, tol))
                k += 3

    def stop(y, r, args):
        ok = jnp.array(True)
        for k0, w, tol in blocks:
            sw = jnp.sqrt(jnp.asarray(w, dtype))
            ok = ok & (jnp.sqrt(jnp.sum(r[k0 : k0 + 3] ** 2)) <= sw * jnp.asarray(tol, dtype))
        return ok

    return stop


def solve_ik(
    skeleton: Skeleton,
    targets: Sequence[Target] | Target,
    rotations: Float[Array, "joints 4"],
    translations: Float[Array, "joints 3"] | None = None,
    *,
    reference: tuple[Float[Array, "joints 4"], Float[Array, "joints 3"]] | None = None,
    pin: str | None = None,
    frozen: Sequence[str] = (),
    root_translation: str = "free",
    regularization: float | Float[Array, ""] = 0.0,
    joint_weights: Float[Array, " joints"] | None = None,
    limits: Sequence[EulerLimit | SwingTwistLimit] = (),
    limit_mode: str = "hard",
    limit_weight: float | Float[Array, ""] = 1.0,
    solver=None,
    position_tolerance: float | None = None,
    orientation_tolerance: float = 1e-4,
    stop_at_tolerance: bool = True,
    throw: bool = False,
) -> IKSolution:
    """Solve one IK problem; batch with ``jax.vmap`` over characters or frames.

    Args:
        skeleton: the tree.
        targets: :class:`Target` s (positions and/or orientations of joints / End Sites).
        rotations: ``[joints, 4]`` initial local wxyz quaternions (e.g. a clip frame).
        translations: ``[joints, 3]`` initial local translations (``None``: the offsets).
        reference: ``(rotations, translations)`` of the pose the regulariser pulls towards and the
            pin and frozen joints refer to (default: the initial pose).
        pin: a joint or End Site that stays exactly where the reference pose puts it.
        frozen: joint names that keep their reference rotations.
        root_translation: ``"free"`` or ``"fixed"`` (ignored when ``pin`` is given: it follows).
        regularization: ``lambda`` of the regulariser ``lambda/2 sum_j w_j |delta_j|^2`` towards the
            reference pose. The literal default ``0`` removes it: the solve is then the notes' damped
            least squares from the start pose (each Levenberg-Marquardt step is the smallest in the
            ``W`` metric), and with fewer target rows than variables the solver works with an
            ``m x m`` system (much faster). Any other value, or an array, keeps the term.
        joint_weights: ``[joints]`` per-joint stiffness ``w_j`` against moving (default ones): the
            damping metric ``W`` of ``LevenbergMarquardt`` (``(J^T J + lambda W) p = -J^T r``, the
            notes' eq. 4.10) and the regulariser's weights.
        limits: :class:`~jaxanim.limits.EulerLimit` / :class:`~jaxanim.limits.SwingTwistLimit` s
            on joints' local rotations (frozen joints ignore theirs).
        limit_mode: ``"hard"``: every iterate satisfies the limits exactly (the limited joints
            are written in coordinates where the limit is a box, and the solver is bounded; needs
            an own solver: ``LevenbergMarquardt``, ``GaussNewton`` or ``GradientDescent``); the
            start is projected into the limits. ``"soft"``: a penalty
            ``limit_weight/2 * (angle outside the limit)^2`` per limit, any solver.
        limit_weight: weight of the soft penalty (array: sweepable by vmap).
        solver: a :mod:`solvers` least-squares solver (default ``LevenbergMarquardt()``).
        position_tolerance: distance (file units) within which a position target counts as met
            for ``success``; default ``1e-5`` times the skeleton's size (sum of |offsets|).
        orientation_tolerance: angle (radians) within which an orientation target counts as met.
        stop_at_tolerance: stop as soon as every target is within its tolerance (the usual IK
            criterion, as in closed-loop IK; own solvers only). ``False``: solve the regularised
            least-squares problem to the solver's own tolerances (slow when the regulariser is weak
            and the task leaves many directions free: the minimum is then very flat).
        throw: raise on failure instead of reporting it in ``result`` (use ``False`` under vmap).

    Returns:
        :class:`IKSolution`.
    """
    problem = _setup(
        skeleton, targets, rotations, translations, reference=reference, pin=pin, frozen=frozen,
        root_translation=root_translation, regularization=regularization, joint_weights=joint_weights,
        limits=limits, limit_mode=limit_mode, limit_weight=limit_weight,
    )
    layout, targets, dtype = problem.layout, problem.targets, problem.dtype
    solver = solvers.LevenbergMarquardt() if solver is None else solver
    if problem.var_weights is not None and isinstance(solver, solvers.LevenbergMarquardt):
        if solver.weights is not None:
            raise JaxanimError("joint_weights: the solver already has weights; give one or the other")
        solver = eqx.tree_at(lambda s: s.weights, solver, problem.var_weights, is_leaf=lambda x: x is None)
    if position_tolerance is None:
        position_tolerance = 1e-5 * float(np.abs(np.asarray(skeleton.offsets)).sum())
    stop = None
    if stop_at_tolerance and isinstance(solver, solvers.AbstractLeastSquaresSolver):
        stop = _tolerance_stop(targets, position_tolerance, orientation_tolerance, dtype)
    sol = solvers.least_squares(
        problem.fn, solver, problem.y0, None, jac=problem.jac, bounds=problem.bounds, stop=stop, throw=throw
    )
    q, t = problem.pose(sol.value)
    out = forward_kinematics(skeleton, q, t)
    pos_all = out.site_positions()
    R_sites = _site_rotations(skeleton, out, layout.site_idx)
    pe, oe = [], []
    for i, tgt in enumerate(targets):
        pe.append(jnp.linalg.norm(pos_all[layout.site_idx[i]] - tgt.position) if tgt.position is not None else jnp.zeros((), dtype))
        oe.append(rot.quat_distance(rot.matrix_to_quat(R_sites[i]), tgt.orientation.astype(dtype)) if tgt.orientation is not None else jnp.zeros((), dtype))
    pe, oe = jnp.stack(pe), jnp.stack(oe)
    success = (sol.result == solvers.RESULTS.successful) & jnp.all(pe <= position_tolerance) & jnp.all(oe <= orientation_tolerance)
    return IKSolution(rot.quat_canonical(q), t, sol.result, sol.stats, pe, oe, success)


def solve_ik_clip(
    skeleton: Skeleton,
    motion,
    targets: Sequence[Target] | Target,
    **kwargs,
):
    """Solve IK on every frame of a clip at once (``vmap`` over frames).

    Each frame starts from, and is regularised towards, the clip's own pose of that frame; a
    ``pin`` stays where the clip puts it in every frame.

    Args:
        skeleton: the tree.
        motion: the clip (:class:`~jaxanim.Motion`).
        targets: :class:`Target` s whose ``position`` is ``[3]`` (the same every frame) or
            ``[frames, 3]``, and ``orientation`` ``[4]`` or ``[frames, 4]``.
        **kwargs: as :func:`solve_ik` (``pin``, ``frozen``, ``root_translation``, ``solver``, ...).

    Returns:
        ``(edited Motion, IKSolution)`` where the solution's fields have a leading frames axis.
    """
    motion.check_skeleton(skeleton, "motion")
    F = motion.num_frames
    targets = (targets,) if isinstance(targets, Target) else tuple(targets)

    def per_frame(x, n):
        if x is None:
            return None
        x = jnp.asarray(x)
        if x.ndim == 1:
            return jnp.broadcast_to(x, (F, n))
        check_shape("targets position/orientation", x, (F, n), what=f"({n},) or (frames, {n}) = ({F}, {n})")
        return x

    stacked = tuple(
        Target(tg.site, per_frame(tg.position, 3), per_frame(tg.orientation, 4), jnp.broadcast_to(tg.weight, (F,)))
        for tg in targets
    )

    def one(tg, q, t):
        return solve_ik(skeleton, tg, q, t, **kwargs)

    sol = jax.vmap(one)(stacked, motion.rotations, motion.translations)
    return Motion(sol.rotations, sol.translations, motion.frame_time), sol


def targets_from_json(skeleton: Skeleton, data, num_frames: int):
    """Parse the ``TARGETS.json`` of ``jaxanim ik`` into targets and :func:`solve_ik` options.

    Format::

        {"pin": NAME or null, "root_translation": "free" | "fixed", "frozen": [NAME, ...],
         "targets": [{"joint": NAME, "position": [x, y, z] or one [x, y, z] per frame,
                      "orientation": [w, x, y, z] or one per frame (optional), "weight": number}],
         "regularization": number, "position_tolerance": number, "orientation_tolerance": number,
         "limits": [{"joint": NAME, "lower": [3 degrees], "upper": [3 degrees], "order": "ZXY"}
                    or {"joint": NAME, "swing": degrees or [2 degrees], "twist": [lower, upper] degrees,
                        "axis": [x, y, z]}],
         "limit_mode": "hard" | "soft", "limit_weight": number}

    (every field but ``targets`` optional; an Euler limit's ``order`` defaults to the joint's
    channel order, so its bounds are the angles written in the BVH file; a swing-twist limit's
    ``axis`` defaults to the bone).

    NAME is a joint or an End Site (``<joint>_End``); positions are world coordinates in the file's
    units.

    Returns:
        ``(targets, kwargs)`` for :func:`solve_ik_clip`.

    Raises:
        JaxanimError: naming the offending field.
    """
    if not isinstance(data, dict):
        raise JaxanimError("TARGETS.json: expected a JSON object at the top level")
    unknown = set(data) - {
        "pin", "root_translation", "frozen", "targets", "regularization", "position_tolerance",
        "orientation_tolerance", "limits", "limit_mode", "limit_weight",
    }
    if unknown:
        raise JaxanimError(f"TARGETS.json: unknown fields {sorted(unknown)}")
    items = data.get("targets")
    if not isinstance(items, list) or not items:
        raise JaxanimError("TARGETS.json: 'targets' must be a non-empty list")
    targets = []
    for k, item in enumerate(items):
        where = f"TARGETS.json: targets[{k}]"
        if not isinstance(item, dict) or "joint" not in item:
            raise JaxanimError(f"{where}: expected an object with a 'joint' field")
        name = item["joint"]
        skeleton.site_index(name)  # raises, listing the valid names

        def field(key, n, name=name, where=where, item=item):
            if item.get(key) is None:
                return None
            try:
                x = np.asarray(item[key], dtype=np.float64)
            except (TypeError, ValueError):
                raise JaxanimError(f"{where}.{key}: expected numbers") from None
            if x.shape not in ((n,), (num_frames, n)):
                raise JaxanimError(
                    f"{where}.{key}: expected shape ({n},) or (frames, {n}) = ({num_frames}, {n}), got {x.shape}"
                )
            return x

        weight = item.get("weight", 1.0)
        if not isinstance(weight, (int, float)) or weight < 0:
            raise JaxanimError(f"{where}.weight: expected a non-negative number, got {weight!r}")
        targets.append(Target(name, field("position", 3), field("orientation", 4), float(weight)))
    kwargs = {}
    if data.get("pin") is not None:
        skeleton.site_index(data["pin"])
        kwargs["pin"] = data["pin"]
    if "root_translation" in data:
        kwargs["root_translation"] = data["root_translation"]
    frozen = data.get("frozen", [])
    if not isinstance(frozen, list):
        raise JaxanimError("TARGETS.json: 'frozen' must be a list of joint names")
    kwargs["frozen"] = tuple(frozen)
    for key in ("regularization", "position_tolerance", "orientation_tolerance", "limit_weight"):
        if key in data:
            if not isinstance(data[key], (int, float)) or isinstance(data[key], bool) or data[key] < 0:
                raise JaxanimError(f"TARGETS.json: {key!r} must be a non-negative number, got {data[key]!r}")
            kwargs[key] = float(data[key])
    if "limit_mode" in data:
        kwargs["limit_mode"] = data["limit_mode"]
    if "limits" in data:
        kwargs["limits"] = _limits_from_json(skeleton, data["limits"])
    return tuple(targets), kwargs


def _limits_from_json(skeleton: Skeleton, items) -> tuple:
    if not isinstance(items, list):
        raise JaxanimError("TARGETS.json: 'limits' must be a list of objects")
    out = []
    for k, item in enumerate(items):
        where = f"TARGETS.json: limits[{k}]"
        if not isinstance(item, dict) or "joint" not in item:
            raise JaxanimError(f"{where}: expected an object with a 'joint' field")
        skeleton.index(item["joint"])  # raises, listing the valid names
        euler, swing = "lower" in item or "upper" in item, "swing" in item
        allowed = {"joint", "lower", "upper", "order"} if euler else {"joint", "swing", "twist", "axis"}
        if euler == swing or set(item) - allowed:
            raise JaxanimError(
                f"{where}: expected either 'lower', 'upper' (and 'order') of an Euler box or 'swing' (and "
                f"'twist', 'axis') of a swing-twist limit, got fields {sorted(item)}"
            )
        try:
            if euler:
                out.append(EulerLimit(item["joint"], item.get("lower"), item.get("upper"), item.get("order"), degrees=True))
            else:
                out.append(SwingTwistLimit(item["joint"], item["swing"], item.get("twist", (-180.0, 180.0)),
                                           item.get("axis"), degrees=True))
        except JaxanimError as e:
            raise JaxanimError(f"{where}: {e}") from None
        except (TypeError, ValueError):
            raise JaxanimError(f"{where}: expected numbers") from None
    return tuple(out)

