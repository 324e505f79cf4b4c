"""Analytic geometric Jacobians of joints and End Sites with respect to the pose.

Pose parameters (the columns, ``cols = 3 + 3 * joints``):
    * columns ``0:3`` -- the root translation, in the world frame;
    * columns ``3 + 3 j : 6 + 3 j`` -- a rotation-vector increment ``delta`` of joint ``j``'s local
      rotation, expressed in the joint's parent frame: ``R_j <- exp(delta) R_j`` (for the root the
      parent frame is the world).

Rows of one site are the spatial vector ``[linear (3); angular (3)]`` in the world frame (the
Pinocchio ``LOCAL_WORLD_ALIGNED`` convention): the velocity of the site's position and the
angular velocity of its frame.

Built from the course notes' formula ``dx/dtheta = a x r`` (axis times lever arm): the world axis of
component ``k`` of joint ``j``'s increment is ``a = Q_parent(j) e_k``, the lever arm is
``r = x_site - p_j``, so the linear block is ``-[r]_x Q_parent(j)`` and the angular block is
``Q_parent(j)``, for every joint on the path from the root to the site (zero elsewhere).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import jax.numpy as jnp
import numpy as np

from .. import _tree
from .. import rotations as rot
from .._errors import JaxanimError, check_shape
from .._types import Array, Float
from ._fk import _end_sites, _fk_levels, _prepare, _take
from ..skeleton._skeleton import Skeleton


def site_indices(skeleton: Skeleton, sites) -> tuple[int, ...]:
    """The site index of each joint or End Site name (or index), checked (internal interface: also
    used by :mod:`jaxanim.ik`)."""
    if isinstance(sites, (str, int, np.integer)):
        sites = (sites,)
    if not isinstance(sites, Sequence) or len(sites) == 0:
        raise JaxanimError(f"sites: expected a non-empty sequence of joint / End Site names or indices, got {sites!r}")
    n = skeleton.num_joints + skeleton.num_end_sites
    out = []
    for s in sites:
        if isinstance(s, str):
            out.append(skeleton.site_index(s))
        elif isinstance(s, (int, np.integer)) and 0 <= int(s) < n:
            out.append(int(s))
        else:
            raise JaxanimError(f"sites: {s!r} is neither a joint / End Site name nor an index in [0, {n})")
    return tuple(out)


@functools.lru_cache(maxsize=256)
def _site_structure(parents, end_site_parents, site_idx):
    """Static: the joint each site hangs from, and the ancestor mask ``[sites, joints]``."""
    J = len(parents)
    owner = tuple(s if s < J else end_site_parents[s - J] for s in site_idx)
    mask = np.ascontiguousarray(_tree.subtree(parents)[:, list(owner)].T)  # joint j is on site i's chain
    return owner, mask


def jacobian(
    skeleton: Skeleton,
    rotations: Float[Array, "joints 4"] | Float[Array, "joints 3 3"],
    translations: Float[Array, "joints 3"] | None,
    sites: Sequence[str | int],
) -> Float[Array, "sites 6 cols"]:
    """Geometric Jacobian of the given joints' / End Sites' positions and orientations.

    Args:
        skeleton: the tree.
        rotations: local rotations, ``[joints, 4]`` wxyz quaternions or ``[joints, 3, 3]`` matrices.
        translations: ``[joints, 3]`` local translations (``None``: the skeleton's offsets).
        sites: joint names, End Site names (``<joint>_End``) or indices into joints followed by
            End Sites (:meth:`Skeleton.site_index`). Static.

    Returns:
        ``[sites, 6, 3 + 3 * joints]``: for each site the rows ``[linear; angular]`` (world frame)
        against the columns described in the module docstring.

    Raises:
        JaxanimError: on a wrong shape or an unknown site.
    """
    site_idx = site_indices(skeleton, sites)
    R_local, t_local = _prepare(skeleton, rotations, translations)
    R_world, p_world = _fk_levels(skeleton.parents, R_local, t_local)
    return jacobian_from_fk(skeleton, R_world, p_world, None, site_idx)


def jacobian_from_fk(skeleton: Skeleton, R_world, p_world, end_site_positions, site_idx: tuple[int, ...]):
    """:func:`jacobian` from global transforms already computed (``end_site_positions`` may be
    ``None``: computed here if a site needs it). For callers that also need FK (IK)."""
    J = skeleton.num_joints
    S = len(site_idx)
    dtype = R_world.dtype
    owner, mask = _site_structure(skeleton.parents, skeleton.end_site_parents, site_idx)

    # site positions: joints directly, End Sites through their joint
    if any(s >= J for s in site_idx):
        if end_site_positions is None:
            end_site_positions = _end_sites(skeleton, R_world, p_world)
        p_sites_all = jnp.concatenate([p_world, end_site_positions], axis=0)
    else:
        p_sites_all = p_world
    x = _take(p_sites_all, site_idx)  # [S, 3]

    # the parent frames' rotations, identity for the root
    eye = jnp.eye(3, dtype=dtype)[None]
    Q_par = jnp.concatenate([eye, _take(R_world, [p for p in skeleton.parents[1:]])], axis=0) if J > 1 else eye

    # Everything below is elementwise, so XLA writes the output in one fused pass.
    m = jnp.asarray(mask, dtype=dtype)  # [S, J]
    r = x[:, None, :] - p_world[None, :, :]  # [S, J, 3] lever arms
    rx, ry, rz = (r[..., i, None] * m[..., None] for i in range(3))  # [S, J, 1]
    # column c of the linear block is a_c x r with a_c = Q_par[:, :, c]
    Qx, Qy, Qz = (Q_par[None, :, i, :] for i in range(3))  # [1, J, 3] over c
    rows = [Qy * rz - Qz * ry, Qz * rx - Qx * rz, Qx * ry - Qy * rx]  # linear x, y, z
    rows += [Q * m[..., None] for Q in (Qx, Qy, Qz)]  # angular x, y, z
    rot_cols = jnp.stack(rows, axis=1)  # [S, 6, J, 3]
    trans = jnp.concatenate([eye[0], jnp.zeros((3, 3), dtype)], axis=0)  # [6, 3]
    trans_cols = jnp.broadcast_to(trans[None, :, None, :], (S, 6, 1, 3))
    return jnp.concatenate([trans_cols, rot_cols], axis=2).reshape(S, 6, 3 + 3 * J)


def apply_increment(
    skeleton: Skeleton,
    rotations: Float[Array, "joints 4"],
    translations: Float[Array, "joints 3"] | None,
    delta: Float[Array, " cols"],
) -> tuple[Float[Array, "joints 4"], Float[Array, "joints 3"]]:
    """Move a pose along the Jacobian's parameters: the retraction matching :func:`jacobian`.

    Args:
        skeleton: the tree.
        rotations: ``[joints, 4]`` local wxyz quaternions.
        translations: ``[joints, 3]`` local translations (``None``: the offsets).
        delta: ``[3 + 3 * joints]`` root translation increment then per-joint rotation vectors in
            the parent frames.

    Returns:
        ``(rotations, translations)`` with ``R_j <- exp(delta_j) R_j`` and ``t_root += delta[:3]``.
    """
    J = skeleton.num_joints
    check_shape("rotations", rotations, (J, 4), what=f"(joints, 4) = ({J}, 4)")
    check_shape("delta", delta, (3 + 3 * J,), what=f"(3 + 3 * joints,) = ({3 + 3 * J},)")
    q = jnp.asarray(rotations)
    t = skeleton.offsets.astype(q.dtype) if translations is None else jnp.asarray(translations, dtype=q.dtype)
    check_shape("translations", t, (J, 3), what=f"(joints, 3) = ({J}, 3)")
    delta = jnp.asarray(delta, dtype=q.dtype)
    dq = rot.rotvec_to_quat(delta[3:].reshape(J, 3))
    q_new = rot.quat_multiply(dq, q)
    t_new = t.at[0].add(delta[:3])
    return q_new, t_new
