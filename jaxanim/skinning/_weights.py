"""Skin weights from the distance to the bones (the course notes' heuristic, S3 1185-1191)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._errors import JaxanimError, check_shape
from .._types import Array, Float
from ..skeleton._skeleton import Skeleton
from ._mesh import Mesh, SkinWeights, _is_traced, bone_segments, skeleton_size


def _segment_distances(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``[V, S]`` distances from points ``x [V, 3]`` to segments ``a -> b`` ``[S, 3]``."""
    d = b - a  # [S, 3]
    dd = np.einsum("sc,sc->s", d, d)
    out = np.empty((x.shape[0], a.shape[0]))
    for lo in range(0, x.shape[0], 4096):  # [block, S, 3] at a time
        rel = x[lo:lo + 4096, None, :] - a[None]
        s = np.where(dd > 0, np.einsum("vsc,sc->vs", rel, d) / np.where(dd > 0, dd, 1.0), 0.0)
        s = np.clip(s, 0.0, 1.0)
        out[lo:lo + 4096] = np.linalg.norm(rel - s[:, :, None] * d[None], axis=2)
    return out


def heuristic_weights(
    skeleton: Skeleton,
    vertices: Float[Array, "V 3"] | Mesh,
    k: int = 4,
    bind=None,
    *,
    power: float = 2.0,
) -> SkinWeights:
    """Skin weights by inverse distance to the bones: each vertex's ``k`` nearest joints.

    Every bone of the bind pose is a segment owned by the joint it moves with (the bone from a
    joint to a child joint or an End Site is the joint's; a joint without bones is a point). The
    distance ``d_j`` from a vertex to joint ``j`` is the distance to the nearest of ``j``'s
    segments; the vertex takes the ``k`` joints with the smallest ``d_j`` and weights
    ``w_j ∝ (d_min / d_j)^power`` (so the nearest joint weighs the most; a vertex on a bone takes
    that bone alone, to the distance floor of ``1e-6 x`` the skeleton's size), normalised to sum to
    1. A vertex halfway between two bones takes them 50/50, so the skin blends smoothly across
    a joint.

    Computed on the host (NumPy) from concrete arrays: call it once, outside ``jit``.

    Args:
        skeleton: the tree.
        vertices: ``[V, 3]`` bind-pose vertices (or a :class:`Mesh`).
        k: influences per vertex (with fewer joints than ``k``, the extra slots get weight 0 on
            joint 0).
        bind: the bind pose, as for :func:`~jaxanim.skinning.skin` (default the rest pose).
        power: the exponent of the inverse distance (larger: sharper transitions).

    Returns:
        :class:`SkinWeights` with ``[V, k]`` int32 joints (nearest first) and weights.

    Raises:
        JaxanimError: on a wrong shape, ``k < 1``, a non-positive ``power`` or traced inputs.
    """
    if not isinstance(skeleton, Skeleton):
        raise JaxanimError(f"skeleton: expected a jaxanim.Skeleton, got {type(skeleton).__name__}")
    if isinstance(vertices, Mesh):
        vertices = vertices.vertices
    if _is_traced(vertices):
        raise JaxanimError("vertices: heuristic_weights runs on the host: pass concrete vertices, not a traced array")
    check_shape("vertices", vertices, (None, 3), what="(V, 3)")
    if not isinstance(k, (int, np.integer)) or k < 1:
        raise JaxanimError(f"k: expected an integer >= 1, got {k!r}")
    if not (np.isfinite(power) and power > 0):
        raise JaxanimError(f"power: expected a positive number, got {power!r}")
    dtype = jnp.asarray(vertices).dtype
    dtype = dtype if jnp.issubdtype(dtype, jnp.floating) else jnp.result_type(float)
    x = np.asarray(vertices, np.float64)
    if not np.isfinite(x).all():
        v = int(np.nonzero(~np.isfinite(x).all(axis=1))[0][0])
        raise JaxanimError(f"vertices: vertex {v} is not finite: {x[v].tolist()}")
    a, b, owner = bone_segments(skeleton, bind)
    J = skeleton.num_joints
    dist = _segment_distances(x, a, b)  # [V, S]
    per_joint = np.full((x.shape[0], J), np.inf)
    np.minimum.at(per_joint.T, owner, dist.T)  # the nearest of each joint's segments
    kk = min(int(k), J)
    idx = np.argsort(per_joint, axis=1, kind="stable")[:, :kk]
    d = np.take_along_axis(per_joint, idx, axis=1) + 1e-6 * skeleton_size(skeleton, bind)
    w = (d[:, :1] / d) ** float(power)
    w /= w.sum(axis=1, keepdims=True)
    if kk < k:
        idx = np.concatenate([idx, np.zeros((x.shape[0], k - kk), idx.dtype)], axis=1)
        w = np.concatenate([w, np.zeros((x.shape[0], k - kk))], axis=1)
    return SkinWeights(jnp.asarray(idx, jnp.int32), jnp.asarray(w, dtype))
