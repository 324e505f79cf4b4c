"""Forward kinematics, its inverse (global -> local) and the center of mass.

All functions take **one** pose; batch over characters and frames with ``jax.vmap``.

The tree is traversed per depth level: joints are regrouped (statically) so that every depth
level is a contiguous block, and each level is one batched 3x3 product with its parents, which
are taken from the previous level with static slices rather than a gather. A 31-joint BVH tree
has about 10 levels, so the compiled program has O(depth) ops, not O(joints).
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import lax

from .. import _tree
from .. import rotations as rot
from .._errors import JaxanimError, check_shape
from .._linalg import einsum
from .._types import Array, Float
from ..skeleton._skeleton import Skeleton


class FKResult(eqx.Module):
    """Global transforms of every joint and End Site of one pose.

    Attributes:
        rotations: ``[joints, 3, 3]`` global rotations ``R_world_joint``.
        positions: ``[joints, 3]`` global joint positions (file units).
        end_site_positions: ``[end_sites, 3]`` global End Site positions; an End Site's rotation
            is its joint's.
    """

    rotations: Float[Array, "joints 3 3"]
    positions: Float[Array, "joints 3"]
    end_site_positions: Float[Array, "end_sites 3"]

    def site_positions(self) -> Float[Array, "joints+end_sites 3"]:
        """Joints then End Sites, the indexing of :meth:`Skeleton.site_index`."""
        return jnp.concatenate([self.positions, self.end_site_positions], axis=0)


# --- static traversal plan ------------------------------------------------------------------------


class _Plan:
    """Static index bookkeeping for the per-level traversal of one tree (cached per structure)."""

    def __init__(self, parents: tuple[int, ...]):
        self.levels = [list(lev) for lev in _tree.levels(parents)]
        nlev = len(self.levels)
        self.order = [j for lev in self.levels for j in lev]  # level-major position -> joint
        self.pos = {j: i for i, j in enumerate(self.order)}  # joint -> level-major position
        self.inverse = [self.pos[j] for j in range(len(parents))]
        self.starts = np.cumsum([0] + [len(lev) for lev in self.levels]).tolist()
        # for every level > 0: indices of the parents within the previous level's block
        self.parent_local = [
            [self.pos[parents[j]] - self.starts[lev - 1] for j in self.levels[lev]] for lev in range(1, nlev)
        ]


@functools.lru_cache(maxsize=128)
def _plan(parents: tuple[int, ...]) -> _Plan:
    return _Plan(parents)


def _take(x, idx):
    """``x[idx]`` along axis 0 for a static index list, without a gather.

    ``x`` is cut once with ``lax.split`` at every boundary of the runs of consecutive indices, and
    the pieces are concatenated in the order asked for. Both ops transpose to each other, so the
    reverse-mode derivative is one concatenate and one split too (plain slices would transpose to
    one full-size pad per run).
    """
    idx = [int(i) for i in idx]
    n = x.shape[0]
    runs, i = [], 0
    while i < len(idx):
        k = i
        while k + 1 < len(idx) and idx[k + 1] == idx[k] + 1:
            k += 1
        runs.append((idx[i], idx[k] + 1))
        i = k + 1
    if len(runs) == 1:
        a, b = runs[0]
        return x if (a, b) == (0, n) else lax.slice_in_dim(x, a, b, axis=0)
    cuts = sorted({0, n} | {a for a, _ in runs} | {b for _, b in runs})
    pieces = lax.split(x, [b - a for a, b in zip(cuts[:-1], cuts[1:])], axis=0)
    start_of = {a: k for k, a in enumerate(cuts[:-1])}
    parts = []
    for a, b in runs:
        k = start_of[a]
        while cuts[k] < b:
            parts.append(pieces[k])
            k += 1
    return jnp.concatenate(parts, axis=0)


def _local_matrices(name: str, rotations, num_joints: int):
    """Accept ``[joints, 4]`` wxyz quaternions or ``[joints, 3, 3]`` matrices; return matrices."""
    rotations = jnp.asarray(rotations)
    if rotations.ndim == 2 and rotations.shape == (num_joints, 4):
        return rot.quat_to_matrix(rotations)
    if rotations.ndim == 3 and rotations.shape == (num_joints, 3, 3):
        return rotations
    raise JaxanimError(
        f"{name}: expected shape (joints, 4) = ({num_joints}, 4) wxyz quaternions or "
        f"(joints, 3, 3) = ({num_joints}, 3, 3) matrices, got {tuple(rotations.shape)}"
    )


def _prepare(skeleton: Skeleton, rotations, translations):
    if not isinstance(skeleton, Skeleton):
        raise JaxanimError(f"skeleton: expected a jaxanim.Skeleton, got {type(skeleton).__name__}")
    J = skeleton.num_joints
    R_local = _local_matrices("rotations", rotations, J)
    if translations is None:
        t_local = skeleton.offsets.astype(R_local.dtype)
    else:
        check_shape("translations", translations, (J, 3), what=f"(joints, 3) = ({J}, 3)")
        t_local = jnp.asarray(translations, dtype=R_local.dtype)
    return R_local, t_local


def _fk_levels(parents: tuple[int, ...], R_local, t_local):
    """Global rotations and positions, traversed per depth level. Returns joint-order arrays."""
    plan = _plan(parents)
    R = _take(R_local, plan.order)
    t = _take(t_local, plan.order)
    R_prev, p_prev = R[0:1], t[0:1]
    Rs, ps = [R_prev], [p_prev]
    for lev in range(1, len(plan.levels)):
        s, e = plan.starts[lev], plan.starts[lev + 1]
        idx = plan.parent_local[lev - 1]
        R_par = _take(R_prev, idx)
        p_par = _take(p_prev, idx)
        R_prev = einsum("jab,jbc->jac", R_par, R[s:e])
        p_prev = p_par + einsum("jab,jb->ja", R_par, t[s:e])
        Rs.append(R_prev)
        ps.append(p_prev)
    R_world = _take(jnp.concatenate(Rs, axis=0), plan.inverse)
    p_world = _take(jnp.concatenate(ps, axis=0), plan.inverse)
    return R_world, p_world


def site_transforms_sequential(skeleton: Skeleton, rotations, translations, sites):
    """``(positions [S, 3], rotations [S, 3, 3])`` of the sites ``sites`` (joint or End Site indices,
    :meth:`Skeleton.site_index`; an End Site's rotation is its joint's): the products of
    :func:`forward_kinematics`, one joint after another in a ``lax.scan`` (in its level order).

    For a one-off evaluation beside a large program (a solve's final check): it compiles to one small
    loop body instead of the per-level kernels, and runs ``joints - 1`` short sequential steps.
    """
    R_local, t_local = _prepare(skeleton, rotations, translations)
    parents = skeleton.parents
    plan = _plan(parents)
    order = np.asarray(plan.order[1:], dtype=np.int32)
    par = np.asarray([parents[j] for j in plan.order[1:]], dtype=np.int32)

    def body(carry, x):
        R_all, p_all = carry
        j, pj = x
        R_par = R_all[pj]
        R_j = einsum("ab,bc->ac", R_par, R_local[j])
        p_j = p_all[pj] + einsum("ab,b->a", R_par, t_local[j])
        return (R_all.at[j].set(R_j), p_all.at[j].set(p_j)), None

    (R_world, p_world), _ = lax.scan(body, (R_local, t_local), (order, par))
    J = skeleton.num_joints
    owner = np.asarray([s if s < J else skeleton.end_site_parents[s - J] for s in sites], dtype=np.int32)
    R_sites = R_world[owner]
    p_sites = p_world[owner]
    es = [k for k, s in enumerate(sites) if s >= J]
    if es:
        off = skeleton.end_site_offsets.astype(p_world.dtype)[np.asarray([sites[k] - J for k in es])]
        p_sites = p_sites.at[np.asarray(es)].add(einsum("eab,eb->ea", R_sites[np.asarray(es)], off))
    return p_sites, R_sites


def _end_sites(skeleton: Skeleton, R_world, p_world):
    if skeleton.num_end_sites == 0:
        return jnp.zeros((0, 3), dtype=p_world.dtype)
    par = list(skeleton.end_site_parents)
    off = skeleton.end_site_offsets.astype(p_world.dtype)
    return _take(p_world, par) + einsum("eab,eb->ea", _take(R_world, par), off)


def forward_kinematics(
    skeleton: Skeleton,
    rotations: Float[Array, "joints 4"] | Float[Array, "joints 3 3"],
    translations: Float[Array, "joints 3"] | None = None,
) -> FKResult:
    """Global joint and End Site transforms of one pose.

    ``Q_j = Q_parent(j) R_j`` and ``p_j = p_parent(j) + Q_parent(j) t_j`` (the root's parent is the
    world); End Site ``e`` of joint ``j`` is at ``p_j + Q_j offset_e``.

    Args:
        skeleton: the tree.
        rotations: local rotations ``R_parent_joint``, either ``[joints, 4]`` wxyz unit quaternions
            or ``[joints, 3, 3]`` rotation matrices.
        translations: ``[joints, 3]`` local translations in the parent frame (file units): the
            root translation in row 0, position-channel values or OFFSETs elsewhere, e.g. a row of
            ``Motion.translations``. ``None`` uses ``skeleton.offsets`` (root at its OFFSET).

    Returns:
        :class:`FKResult` with ``rotations [joints, 3, 3]``, ``positions [joints, 3]`` and
        ``end_site_positions [end_sites, 3]``.

    Raises:
        JaxanimError: if a shape does not match the skeleton.
    """
    R_local, t_local = _prepare(skeleton, rotations, translations)
    R_world, p_world = _fk_levels(skeleton.parents, R_local, t_local)
    return FKResult(R_world, p_world, _end_sites(skeleton, R_world, p_world))


def global_to_local(
    skeleton: Skeleton,
    global_rotations: Float[Array, "joints 3 3"] | Float[Array, "joints 4"],
    global_positions: Float[Array, "joints 3"],
) -> tuple[Float[Array, "joints 4"], Float[Array, "joints 3"]]:
    """Invert forward kinematics: local rotations and translations from global transforms.

    ``R_j = Q_parent(j)^T Q_j`` and ``t_j = Q_parent(j)^T (p_j - p_parent(j))``; the root's local
    values are its global ones.

    Args:
        skeleton: the tree.
        global_rotations: ``[joints, 3, 3]`` matrices or ``[joints, 4]`` wxyz quaternions
            ``R_world_joint``.
        global_positions: ``[joints, 3]`` world positions of the joints.

    Returns:
        ``(rotations [joints, 4], translations [joints, 3])``: local wxyz quaternions (canonical
        sign, w >= 0) and local translations, as :func:`forward_kinematics` takes them.
    """
    if not isinstance(skeleton, Skeleton):
        raise JaxanimError(f"skeleton: expected a jaxanim.Skeleton, got {type(skeleton).__name__}")
    J = skeleton.num_joints
    Q = _local_matrices("global_rotations", global_rotations, J)
    check_shape("global_positions", global_positions, (J, 3), what=f"(joints, 3) = ({J}, 3)")
    p = jnp.asarray(global_positions, dtype=Q.dtype)
    parents = list(skeleton.parents)
    if J == 1:
        return rot.matrix_to_quat(Q), p
    child = list(range(1, J))
    Q_par = _take(Q, [parents[j] for j in child])
    p_par = _take(p, [parents[j] for j in child])
    R_loc = jnp.concatenate([Q[0:1], einsum("jba,jbc->jac", Q_par, Q[1:])], axis=0)
    t_loc = jnp.concatenate([p[0:1], einsum("jba,jb->ja", Q_par, p[1:] - p_par)], axis=0)
    return rot.matrix_to_quat(R_loc), t_loc


def segment_com_offsets(skeleton: Skeleton) -> Float[Array, "joints 3"]:
    """Default center of each joint's segment, in the joint's frame.

    The segment of joint ``j`` runs from ``j`` to its children (and End Sites); its center is half
    the mean of their offsets. A joint with neither has its center at the joint.
    """
    J = skeleton.num_joints
    off = np.asarray(skeleton.offsets, dtype=np.float64)
    es_off = np.asarray(skeleton.end_site_offsets, dtype=np.float64)
    acc = np.zeros((J, 3))
    cnt = np.zeros(J)
    for j, p in enumerate(skeleton.parents):
        if p >= 0:
            acc[p] += off[j]
            cnt[p] += 1
    for e, p in enumerate(skeleton.end_site_parents):
        acc[p] += es_off[e]
        cnt[p] += 1
    center = 0.5 * acc / np.maximum(cnt, 1)[:, None]
    return jnp.asarray(center, dtype=skeleton.offsets.dtype)


def center_of_mass(
    skeleton: Skeleton,
    rotations: Float[Array, "joints 4"] | Float[Array, "joints 3 3"],
    translations: Float[Array, "joints 3"] | None,
    masses: Float[Array, " joints"],
    com_offsets: Float[Array, "joints 3"] | None = None,
) -> Float[Array, "3"]:
    """Whole-body center of mass of one pose.

    ``c = sum_j m_j (p_j + Q_j c_j) / sum_j m_j`` with segment masses ``m_j`` and segment centers
    ``c_j`` in the joint frames.

    Args:
        skeleton: the tree.
        rotations, translations: the pose, as for :func:`forward_kinematics`.
        masses: ``[joints]`` mass of each joint's segment (any unit; only ratios matter). The total
            must be positive.
        com_offsets: ``[joints, 3]`` segment centers in the joint frames; default
            :func:`segment_com_offsets`.

    Returns:
        ``[3]`` world position of the center of mass (file units).
    """
    J = skeleton.num_joints
    check_shape("masses", masses, (J,), what=f"(joints,) = ({J},)")
    res = forward_kinematics(skeleton, rotations, translations)
    if com_offsets is None:
        com_offsets = segment_com_offsets(skeleton)
    check_shape("com_offsets", com_offsets, (J, 3), what=f"(joints, 3) = ({J}, 3)")
    dtype = res.positions.dtype
    m = jnp.asarray(masses, dtype=dtype)
    c = res.positions + einsum("jab,jb->ja", res.rotations, jnp.asarray(com_offsets, dtype=dtype))
    return einsum("j,ja->a", m, c) / jnp.sum(m)
