"""Cyclic coordinate descent (CCD) inverse kinematics: the cheap baseline next to :func:`~jaxanim.ik.solve_ik`.

The course notes (``SEEDS.md`` §1.F) describe CCD as "update one joint at a time to its own
optimum": cheap per step (dot and cross products), but slow and possibly jittery to converge.
:func:`solve_ik_ccd` solves the same problem as :func:`~jaxanim.ik.solve_ik` (same targets, pose,
``frozen`` and ``root_translation`` arguments, same ``success`` test and the same reported cost
``1/2 sum_i w_i (|x_i - x~_i|^2 + theta_i^2)``, without a regularizer), by block-coordinate
descent over the joints.

One sweep:

1. One forward-kinematics pass gives every joint's world pivot ``p_j`` and rotation ``Q_j`` and the
   targets' current site positions ``x_i`` and frame rotations ``R_i``.
2. The free joints are visited from the leaves towards the root, one **depth level** at a time,
   deepest first (a ``lax.scan`` over the levels, padded to the widest, so the compiled program
   does not grow with the depth). For joint ``j`` only the targets whose site lies in ``j``'s subtree count (a
   static mask; joints with no target below them are skipped). The world rotation ``dR`` about
   ``p_j`` that minimizes

   ``sum_i w_i |dR (x_i - p_j) - (x~_i - p_j)|^2 + sum_i w_i s^2 (3 - tr(dR R_i R~_i^T))``

   (positions, then orientations, ``s = orientation_scale``) is a weighted Wahba problem: with the
   cross-covariance ``B = sum_i w_i (x~_i - p_j)(x_i - p_j)^T + sum_i (w_i s^2 / 2) R~_i R_i^T``
   and its SVD ``B = U S V^T``, ``dR = U diag(1, 1, det(U V^T)) V^T``. This generalizes classic
   CCD (rotate the joint-to-effector direction onto the joint-to-target direction) to several
   targets and to orientations. ``B`` gets ``sqrt(eps) |B|_F I`` added so that among equally good
   rotations (one position target: any twist about the aligned direction) the one closest to the
   identity is taken; it damps each step by a relative ``~1e-8`` (float64).
3. The joint's world rotation becomes ``dR Q_j`` (local: ``Q_parent^T dR Q_j``), and the targets
   in its subtree are moved incrementally, ``x_i <- p_j + dR (x_i - p_j)``, ``R_i <- dR R_i``.
   This is exact: joints of one level have disjoint subtrees (so a level is one batched SVD), a
   joint's pivot and rotation depend only on its ancestors, and the ancestors are visited later,
   so the values from step 1 stay valid and one FK per sweep suffices.
4. The root is visited last. With ``root_translation="free"`` its rotation and translation take
   the jointly optimal rigid step: the rotation is the Wahba solution about the weighted centroid
   of the position targets' sites, and the translation then moves that centroid onto the targets'
   (the weighted mean of the position residuals). A frozen root with a free translation takes the
   translation step only.

Each block step is the exact minimizer of the sweep objective ``G`` (the cost with the geodesic
``theta^2`` replaced by the chordal ``s^2 (3 - tr(R R~^T)) = 4 s^2 sin^2(theta / 2)``), so ``G``
never increases (``stats["ccd_cost_history"]``); the reported cost usually decreases too but is
not guaranteed to. The local rotations are carried as matrices between sweeps and kept orthogonal
by one Newton step of the polar decomposition per sweep (without it the rounding error of
``Q_parent^T`` as the inverse of ``Q_parent`` compounds, about x6 per sweep on a 31-joint tree).

Orientation scale: an orientation error ``theta`` weighs like a position error of ``s theta`` (to
second order) in the steps. ``s = 1`` file unit would make ``G`` agree with the reported cost to
second order, but it is not unit-free: on a skeleton measured in centimetres the orientations are
then nearly ignored until the positions are met. The default ``s = 0.05 * sum_j |offsets_j|``
(about a forearm on a human) makes a radian comparable with a limb's lever arm; on random
reachable 5-effector problems on the 31-joint CMU skeleton (hands, toes, head; position and
orientation) it needed a median of ~100 sweeps to meet the default tolerances, against ~170 for
``0.1 *`` and more for ``0.2 *`` the size. For reachable targets every ``s`` has the same
solutions; for conflicting targets CCD's compromise differs from :func:`~jaxanim.ik.solve_ik`'s
(which weighs one radian like one file unit).

Stopping: every iteration evaluates the current pose (one FK), then either stops or sweeps from
that same FK. It stops when every target is within its tolerance, when ``G`` fell by less than
``rtol * G`` over the last sweep (stationary: ``result`` successful, and ``success`` says whether
the targets are met), or after ``max_sweeps`` sweeps (``max_steps_reached``). The loop is a
``lax.while_loop``; ``fixed_sweeps=True`` runs the same iterations in a ``lax.scan`` of length
``max_sweeps + 1`` with finished problems masked, which suits large ``vmap`` batches and gives the
same answer. A non-finite value (NaN targets or weights, an overflow) ends the solve with
``RESULTS.nonfinite`` and returns the last finite pose (the initial one if the problem is
non-finite from the start).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import lax

from solvers import RESULTS
from solvers._iterate import iterate

from .. import _tree
from .. import rotations as rot
from .._errors import JaxanimError, check_shape
from .._linalg import einsum, matmul
from .._types import Array, Bool, Float
from ..kinematics._fk import FKResult, forward_kinematics
from ._solve import IKSolution
from ._targets import Target, _check_targets
from ..skeleton._skeleton import Skeleton

__all__ = ["solve_ik_ccd"]


# --- static structure -----------------------------------------------------------------------------


class _Plan:
    """Static bookkeeping of one CCD problem (hashable inputs, cached).

    The visited levels (deepest first, the root's last) are padded to the same width so that a
    sweep is one ``lax.scan`` over them: the compiled program does not grow with the depth.
    """

    def __init__(self, parents, end_site_parents, site_idx, free, free_root):
        J = len(parents)
        S = len(site_idx)
        depths = _tree.depths(parents)
        self.owner = tuple(s if s < J else end_site_parents[s - J] for s in site_idx)
        # chains[i][d]: the ancestor (or the owner itself) of target i's site at depth d
        chains = [_tree.ancestors(parents, j) for j in self.owner]
        below = _tree.subtree(parents)[:, list(self.owner)]  # joint j has target i's site in its subtree
        self.active = tuple(j for j in range(J) if free[j] and below[j].any())
        self.root_active = 0 in self.active
        self.free_root = free_root
        # the visited levels, deepest first, padded with joint 0
        self.level_joints, level_mask = _tree.padded_levels(parents, self.active, deepest_first=True)
        L, width = self.level_joints.shape
        self.num_levels = L
        self.sel = np.zeros((L, width, S))  # sel[l, k, i] = 1: site i is below slot k of level l
        self.which = np.full((L, S), width, dtype=np.int64)  # slot of site i's ancestor, width: none
        self.root_level = np.zeros(L, dtype=bool)  # the root's level with a free translation
        self.slot = {}  # joint -> (level, slot)
        for lev in range(L):
            joints = tuple(int(j) for j in self.level_joints[lev][level_mask[lev]])
            self.root_level[lev] = free_root and joints == (0,)
            for k, j in enumerate(joints):
                self.slot[j] = (lev, k)
            for i, chain in enumerate(chains):
                d = depths[joints[0]]
                if len(chain) > d and chain[d] in joints:
                    k = joints.index(chain[d])
                    self.sel[lev, k, i] = 1.0
                    self.which[lev, i] = k
        self.width = width
        self.parents_of_active = tuple(parents[j] for j in self.active)


@functools.lru_cache(maxsize=128)
def _plan(parents, end_site_parents, site_idx, free, free_root) -> _Plan:
    return _Plan(parents, end_site_parents, site_idx, free, free_root)


# --- the per-joint Wahba step ---------------------------------------------------------------------


def _wahba(B):
    """Rotations ``[n, 3, 3]`` maximizing ``tr(B^T R)`` (minimizing ``sum w |R a - b|^2`` for
    ``B = sum w b a^T``), nearest the identity when the optimum is not unique."""
    dtype = B.dtype
    eps = float(np.sqrt(np.finfo(dtype).eps))
    tiny = float(np.finfo(dtype).tiny) ** 0.5
    norm = jnp.sqrt(jnp.sum(B * B, axis=(-2, -1)))
    Bp = B + (eps * norm + tiny)[..., None, None] * jnp.eye(3, dtype=dtype)[None]
    U, _, Vt = jnp.linalg.svd(Bp)
    d = _det3(U) * _det3(Vt)
    m = jnp.stack([jnp.ones_like(d), jnp.ones_like(d), jnp.sign(d)], axis=-1)
    return einsum("nab,nb,nbc->nac", U, m, Vt)


def _det3(M):
    return jnp.sum(M[..., 0, :] * jnp.cross(M[..., 1, :], M[..., 2, :]), axis=-1)


def _cross_covariance(x, R_s, x_goal, R_goal, piv, piv_goal, w_pos, w_ori):
    """Per-site terms ``[S, 3, 3]`` of ``B``: ``w (x~ - c~)(x - c)^T + (w s^2 / 2) R~ R^T``."""
    a = x - piv
    b = x_goal - piv_goal
    C = w_pos[:, None, None] * (b[:, :, None] * a[:, None, :])
    return C + w_ori[:, None, None] * einsum("sab,scb->sac", R_goal, R_s)


# --- one sweep and the objective ----------------------------------------------------------------


def _sweep(skeleton, plan, out, R_local, t, x, R_s, x_goal, R_goal, w_pos, w_ori_half):
    """One CCD sweep from the FK ``out`` of the pose ``(R_local, t)`` (local rotation matrices) and
    the targets' sites ``x [S, 3]``, ``R_s [S, 3, 3]`` in it. Returns the new ``(R_local, t)``."""
    dtype = R_local.dtype
    eye = jnp.eye(3, dtype=dtype)
    p0 = out.positions[0]
    # centroids of the position targets, for the root's rigid step (p0 when there are none)
    W = jnp.sum(w_pos)
    has_w = W > 0
    W = jnp.where(has_w, W, 1.0)
    c_goal = jnp.where(has_w, einsum("s,sa->a", w_pos, x_goal) / W, p0)
    S = x.shape[0]

    def level(carry, xs):
        x, R_s = carry
        piv, sel, which, root = xs  # [width, 3], [width, S], [S], scalar bool
        moved = which < plan.width
        p = jnp.concatenate([piv, jnp.zeros((1, 3), dtype)], axis=0)[which]  # [S, 3] pivot per site
        c = jnp.where(has_w, einsum("s,sa->a", w_pos, x) / W, p0)
        p_goal = jnp.where(root, jnp.broadcast_to(c_goal, (S, 3)), p)
        p = jnp.where(root, jnp.broadcast_to(c, (S, 3)), p)
        C = _cross_covariance(x, R_s, x_goal, R_goal, p, p_goal, w_pos, w_ori_half)
        dR = _wahba(einsum("ns,sab->nab", sel, C))
        dR_s = jnp.concatenate([dR, eye[None]], axis=0)[which]
        x = jnp.where(moved[:, None], p_goal + einsum("sab,sb->sa", dR_s, x - p), x)
        R_s = einsum("sab,sbc->sac", dR_s, R_s)
        return (x, R_s), (dR, c)

    if plan.num_levels:
        xs = (
            out.positions[plan.level_joints], jnp.asarray(plan.sel, dtype), jnp.asarray(plan.which),
            jnp.asarray(plan.root_level),
        )
        (x, R_s), (dRs, cs) = lax.scan(level, (x, R_s), xs)
    # the root translation: with the root's rotation about the centroid c, the translation that
    # moves c onto the targets' centroid; a frozen root takes that translation alone
    if plan.free_root:
        if plan.root_active:
            lev, k = plan.slot[0]
            t = t.at[0].set(c_goal + matmul(dRs[lev, k], p0 - cs[lev]))
        else:
            t = t.at[0].add(c_goal - jnp.where(has_w, einsum("s,sa->a", w_pos, x) / W, p0))
    # new local rotations of the visited joints: Q_parent^T dR Q_j (all from the sweep's FK)
    if plan.active:
        act = np.asarray(plan.active, dtype=np.int64)
        Q = out.rotations[act]
        Q_par = jnp.concatenate([eye[None], out.rotations], axis=0)[np.asarray(plan.parents_of_active) + 1]
        lev, k = (np.asarray(v) for v in zip(*(plan.slot[j] for j in plan.active)))
        R_new = einsum("nba,nbc,ncd->nad", Q_par, dRs[lev, k], Q)
        # Q_par^T is the inverse only up to rounding, and the error would compound over sweeps
        # (x6 per sweep on a 31-joint tree): one Newton step of the polar decomposition keeps the
        # local matrices orthogonal to machine precision.
        R_new = 1.5 * R_new - 0.5 * einsum("nab,ncb,ncd->nad", R_new, R_new, R_new)
        R_local = R_local.at[act].set(R_new)
    return R_local, t


def _evaluate(x, R_s, x_goal, R_goal, w, has_pos, has_ori, scale2):
    """Reported cost, sweep objective ``G`` and per-target errors of the sites ``x``, ``R_s``."""
    pe = jnp.where(has_pos, jnp.sqrt(jnp.sum((x - x_goal) ** 2, axis=-1)), 0.0)
    E = einsum("sab,scb->sac", R_s, R_goal)  # R_s R~^T: the world-frame orientation error
    cos = 0.5 * (E[:, 0, 0] + E[:, 1, 1] + E[:, 2, 2] - 1.0)
    sin = 0.5 * jnp.sqrt(
        (E[:, 2, 1] - E[:, 1, 2]) ** 2 + (E[:, 0, 2] - E[:, 2, 0]) ** 2 + (E[:, 1, 0] - E[:, 0, 1]) ** 2
    )
    oe = jnp.where(has_ori, jnp.arctan2(sin, cos), 0.0)
    # chord 3 - tr(E) = 2 (1 - cos) = 2 sin^2 / (1 + cos), each form where it is accurate
    chord = jnp.where(cos > 0, 2.0 * sin**2 / (1.0 + jnp.abs(cos)), 2.0 * (1.0 - cos))
    cost = 0.5 * jnp.sum(w * (pe**2 + oe**2))
    G = 0.5 * jnp.sum(w * (pe**2 + scale2 * jnp.where(has_ori, chord, 0.0)))
    return cost, G, pe, oe


# --- the public function ----------------------------------------------------------------------------


class _State(eqx.Module):
    """One CCD iterate: the pose, its forward kinematics and its evaluation."""

    R_local: Float[Array, "joints 3 3"]
    t: Float[Array, "joints 3"]
    fk: FKResult
    x: Float[Array, "sites 3"]  # site positions
    R_sites: Float[Array, "sites 3 3"]  # orientations of the sites' joints
    cost: Float[Array, ""]
    ccd_cost: Float[Array, ""]
    ccd_cost_prev: Float[Array, ""]  # before the last sweep (equal to ccd_cost before the first)
    pe: Float[Array, " sites"]
    oe: Float[Array, " sites"]
    first: bool | Bool[Array, ""]  # no sweep taken yet


class _Problem(eqx.Module):
    """Everything one solve's sweeps need: the static plan and the targets as arrays."""

    skeleton: Skeleton
    plan: _Plan = eqx.field(static=True)
    site_idx: tuple[int, ...] = eqx.field(static=True)
    owner: tuple[int, ...] = eqx.field(static=True)  # the joint of each site
    x_goal: Array
    R_goal: Array
    w: Array
    has_pos: tuple[bool, ...] = eqx.field(static=True)
    has_ori: tuple[bool, ...] = eqx.field(static=True)
    scale2: Array
    w_pos: Array
    w_ori_half: Array
    ptol: Array
    otol: Array
    rtol: Array

    def state(self, R_local, t, *, first, ccd_cost_prev=None) -> _State:
        """The pose ``(R_local, t)`` with its FK (one pass) and evaluation."""
        out = forward_kinematics(self.skeleton, R_local, t)
        x = out.site_positions()[np.asarray(self.site_idx)]
        R_sites = out.rotations[np.asarray(self.owner)]
        cost, G, pe, oe = _evaluate(x, R_sites, self.x_goal, self.R_goal, self.w, np.asarray(self.has_pos),
                                    np.asarray(self.has_ori), self.scale2)
        return _State(R_local, t, out, x, R_sites, cost, G, G if ccd_cost_prev is None else ccd_cost_prev, pe, oe,
                      jnp.asarray(first))

    def sweep(self, s: _State) -> _State:
        """One sweep from ``s`` (using its FK), then the new pose's FK and evaluation."""
        R_new, t_new = _sweep(self.skeleton, self.plan, s.fk, s.R_local, s.t, s.x, s.R_sites, self.x_goal, self.R_goal,
                              self.w_pos, self.w_ori_half)
        return self.state(R_new, t_new, first=False, ccd_cost_prev=s.ccd_cost)

    def done(self, s: _State):
        """Every target within its tolerance, or the sweep no longer lowers the CCD cost."""
        met = jnp.all(s.pe <= self.ptol) & jnp.all(s.oe <= self.otol)
        stalled = jnp.invert(s.first) & (s.ccd_cost_prev - s.ccd_cost <= self.rtol * s.ccd_cost_prev)
        return met | stalled


def _validate(skeleton, targets, frozen, root_translation, max_sweeps):
    if not isinstance(skeleton, Skeleton):
        raise JaxanimError(f"skeleton: expected a jaxanim.Skeleton, got {type(skeleton).__name__}")
    targets, site_idx = _check_targets(skeleton, targets, root_translation)
    if isinstance(max_sweeps, bool) or not isinstance(max_sweeps, (int, np.integer)) or max_sweeps < 0:
        raise JaxanimError(f"max_sweeps: expected a non-negative int, got {max_sweeps!r}")
    if isinstance(frozen, str):
        frozen = (frozen,)
    frozen_idx = {skeleton.index(n) for n in frozen}
    free = tuple(j not in frozen_idx for j in range(skeleton.num_joints))
    free_root = root_translation == "free"
    if not any(free) and not free_root:
        raise JaxanimError("frozen: every joint is frozen and the root translation is fixed: nothing can move")
    return targets, site_idx, free, free_root


@eqx.filter_jit
def solve_ik_ccd(
    skeleton: Skeleton,
    targets: Sequence[Target] | Target,
    rotations: Float[Array, "joints 4"],
    translations: Float[Array, "joints 3"] | None = None,
    *,
    frozen: Sequence[str] = (),
    root_translation: str = "free",
    max_sweeps: int = 100,
    position_tolerance: float | Float[Array, ""] | None = None,
    orientation_tolerance: float | Float[Array, ""] = 1e-4,
    orientation_scale: float | Float[Array, ""] | None = None,
    rtol: float = 1e-10,
    fixed_sweeps: bool = False,
) -> IKSolution:
    """Solve one IK problem by cyclic coordinate descent (see the module docstring).

    The arguments mean what they mean for :func:`~jaxanim.ik.solve_ik`; the pose starts at
    ``(rotations, translations)`` and there is no regularizer, reference pose or pin. Batch over
    characters or frames with ``jax.vmap`` (use ``fixed_sweeps=True`` for large batches).

    Args:
        skeleton: the tree.
        targets: :class:`~jaxanim.ik.Target` s (positions and/or orientations of joints / End
            Sites ``<joint>_End``), without leading axes.
        rotations: ``[joints, 4]`` initial local wxyz quaternions.
        translations: ``[joints, 3]`` initial local translations (``None``: the offsets).
        frozen: joint names that keep their rotations.
        root_translation: ``"free"`` or ``"fixed"``.
        max_sweeps: the most sweeps (each visits every free joint once). Static.
        position_tolerance: distance (file units) within which a position target is met; default
            ``1e-5`` times the skeleton's size (sum of |offsets|), as :func:`~jaxanim.ik.solve_ik`.
        orientation_tolerance: angle (radians) within which an orientation target is met.
        orientation_scale: length ``s`` (file units) at which an orientation error of ``theta``
            weighs like a position error of ``s theta`` in the per-joint steps; default ``0.05``
            times the skeleton's size (see the module docstring). Does not change the reported
            ``cost``.
        rtol: stop (stationary, ``result`` successful) when a sweep lowers the sweep objective by
            less than ``rtol`` times its value.
        fixed_sweeps: run ``max_sweeps`` sweeps in a ``lax.scan`` (finished problems masked)
            instead of a ``lax.while_loop``; same answer. Static.

    Returns:
        :class:`~jaxanim.ik.IKSolution`: canonical ``rotations``, ``translations``, ``result``
        (``successful`` when the targets are met or the sweeps became stationary,
        ``max_steps_reached`` after ``max_sweeps`` otherwise, ``nonfinite`` when a NaN/inf
        appeared: the pose is then the last finite one, the initial pose if the problem is
        non-finite from the start), ``stats`` (``num_steps``: sweeps done; ``cost``: ``1/2 sum_i
        w_i (|x_i - x~_i|^2 + theta_i^2)`` of the returned pose; ``ccd_cost``: the sweep objective
        ``G``; ``cost_history`` / ``ccd_cost_history``: ``[max_sweeps + 1]`` values after ``k``
        sweeps, padded with the final one), ``position_errors``, ``orientation_errors`` and
        ``success`` (result successful **and** every target within tolerance).

    Raises:
        JaxanimError: on a wrong shape, an unknown joint / End Site name, a bad
            ``root_translation`` or ``max_sweeps``, or when nothing can move.
    """
    J = skeleton.num_joints
    targets, site_idx, free, free_root = _validate(skeleton, targets, frozen, root_translation, max_sweeps)
    check_shape("rotations", rotations, (J, 4), what=f"(joints, 4) = ({J}, 4)")
    q0 = jnp.asarray(rotations)
    if not jnp.issubdtype(q0.dtype, jnp.floating):
        q0 = q0.astype(jnp.result_type(float))
    dtype = q0.dtype
    if translations is None:
        t0 = skeleton.offsets.astype(dtype)
    else:
        check_shape("translations", translations, (J, 3), what=f"(joints, 3) = ({J}, 3)")
        t0 = jnp.asarray(translations, dtype)
    plan = _plan(skeleton.parents, skeleton.end_site_parents, site_idx, free, free_root)

    has_pos = np.asarray([t.position is not None for t in targets])
    has_ori = np.asarray([t.orientation is not None for t in targets])
    w = jnp.stack([jnp.asarray(t.weight, dtype) for t in targets])
    zeros3 = jnp.zeros(3, dtype)
    ident = jnp.asarray([1.0, 0.0, 0.0, 0.0], dtype)
    x_goal = jnp.stack([zeros3 if t.position is None else jnp.asarray(t.position, dtype) for t in targets])
    q_goal = jnp.stack([ident if t.orientation is None else jnp.asarray(t.orientation, dtype) for t in targets])
    R_goal = rot.quat_to_matrix(q_goal)  # normalizes
    size = jnp.sum(jnp.abs(skeleton.offsets.astype(dtype)))
    ptol = 1e-5 * size if position_tolerance is None else jnp.asarray(position_tolerance, dtype)
    otol = jnp.asarray(orientation_tolerance, dtype)
    scale = 0.05 * size if orientation_scale is None else jnp.asarray(orientation_scale, dtype)
    scale2 = scale * scale
    w_pos = jnp.where(has_pos, w, 0.0)
    w_ori_half = jnp.where(has_ori, 0.5 * w * scale2, 0.0)

    problem = _Problem(skeleton, plan, tuple(site_idx), tuple(plan.owner), x_goal, R_goal, w, tuple(has_pos.tolist()),
                       tuple(has_ori.tolist()), scale2,
                       w_pos, w_ori_half, ptol, otol, jnp.asarray(rtol, dtype))
    it = iterate(problem.sweep, problem.state(rot.quat_to_matrix(q0), t0, first=True), done=problem.done,
                 max_steps=max_sweeps, fixed_steps=fixed_sweeps, record=lambda s: (s.cost, s.ccd_cost))
    state = it.state
    R_loc, t, cost, G, pe, oe = state.R_local, state.t, state.cost, state.ccd_cost, state.pe, state.oe
    hist, ghist = it.history
    # a sweep that the non-finite guard rejected is not counted
    k = it.num_steps - (it.nonfinite & (it.num_steps > 0)).astype(it.num_steps.dtype)
    result = RESULTS.where(it.nonfinite, RESULTS.nonfinite,
                           RESULTS.where(it.done, RESULTS.successful, RESULTS.max_steps_reached))
    # frozen joints (and joints with no target below them) keep exactly the rotations given
    moved = np.asarray(plan.active, dtype=np.int64)
    q = q0.at[moved].set(rot.matrix_to_quat(R_loc[moved])) if len(moved) else q0
    success = (result == RESULTS.successful) & jnp.all(pe <= ptol) & jnp.all(oe <= otol)
    stats = {"num_steps": k, "cost": cost, "ccd_cost": G, "cost_history": hist, "ccd_cost_history": ghist}
    return IKSolution(rot.quat_canonical(q), t, result, stats, pe, oe, success)
