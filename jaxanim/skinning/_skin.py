"""Linear blend skinning (LBS) and dual-quaternion skinning (DQS) of one pose, and of a clip.

Both deform bind-pose vertices by the joints' skinning transforms ``M_j = G_j(pose) G_j(bind)^-1``
(``G_j`` the joint's global transform, from :func:`~jaxanim.forward_kinematics`), so a pose equal
to the bind pose leaves the mesh where it is (eqs. 5.17-5.18 of the course notes:
``x' = sum_j w_j (R_j x + t_j)`` with ``R_j = Q'_j Q_j^T`` and ``t_j = o'_j - R_j o_j``).

* **LBS** blends the 3x4 matrices: ``v' = (sum_k w_k M_{j_k}) v``. Blending rotation matrices
  linearly shrinks a twisted joint towards its axis (the candy-wrapper artefact).
* **DQS** (Kavan et al. 2007) turns every ``M_j`` into a unit dual quaternion
  ``q = r + eps d`` with ``r`` the rotation's quaternion and ``d = 1/2 (0, t) r``, flips each of a
  vertex's ``K`` onto the hemisphere of its largest-weight joint's (``q`` and ``-q`` are the same
  transform), blends them linearly, divides by the norm of the real part and applies the result:
  ``v' = R(r) v + 2 vec(d r*)``. The dual-quaternion product is
  ``(r1 + eps d1)(r2 + eps d2) = r1 r2 + eps (r1 d2 + d1 r2)`` (the notes swap the last term).

Everything here takes one pose; batch over frames and characters with ``jax.vmap``
(:func:`skin_motion` is the jitted vmap over a clip's frames).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .. import rotations as rot
from .._errors import JaxanimError, check_shape
from .._linalg import HIGHEST, check_precision, einsum, matmul
from .._types import Array, Float
from ..kinematics._fk import forward_kinematics
from ..skeleton._skeleton import Motion, Skeleton
from ._bind import _bind_rt, _rest_fk
from ._mesh import Mesh, SkinWeights, _as_float_array, _is_traced, check_weights

METHODS = ("lbs", "dqs")


# ------------------------------------------------------------------------------------------------
# Kernels (no input checks)
# ------------------------------------------------------------------------------------------------


def _skinning_transforms(skeleton, rotations, translations, R_bind, p_bind):
    """``M_j = G_j(pose) G_j(bind)^-1`` as ``(R [J, 3, 3], t [J, 3])``."""
    fk = forward_kinematics(skeleton, rotations, translations)
    R = einsum("jab,jcb->jac", fk.rotations, R_bind)
    t = fk.positions - einsum("jab,jb->ja", R, p_bind)
    return R, t


_DENSE_MAX = 1 << 24  # entries of a dense per-vertex matrix of the one-product forms (128 MB in float64)


def _lbs(R, t, vertices, joints, w, precision=HIGHEST):
    """``v' = (sum_k w_k M_{j_k}) [v; 1]``, regrouped as one matrix product when it fits in
    :data:`_DENSE_MAX`: ``v'_a = sum_{j,b} (W_vj [v; 1]_b) M_jab``, i.e. ``X [V, 4J] @ M' [4J, 3]``
    with ``W`` the ``[V, J]`` weights scattered into their joints' columns. ``X`` does not depend on
    the pose, so under ``vmap`` over frames it is built once and the frames are one GEMM that writes
    the result directly (on two CPU cores ~3x faster than blending gathered ``[V, K, 3, 4]``
    matrices, which stays as the fallback for very large meshes)."""
    J, V = R.shape[0], vertices.shape[0]
    M = jnp.concatenate([R, t[:, :, None]], axis=2)  # [J, 3, 4]
    if 4 * V * J > _DENSE_MAX:
        A = einsum("vk,vkab->vab", w, M[joints], precision=precision)  # blended 3x4 per vertex
        return einsum("vab,vb->va", A[:, :, :3], vertices, precision=precision) + A[:, :, 3]
    W = jnp.zeros((V, J), w.dtype).at[jnp.arange(V)[:, None], joints].add(w)
    vh = jnp.concatenate([vertices, jnp.ones_like(vertices[:, :1])], axis=1)  # [V, 4]
    X = (W[:, :, None] * vh[:, None, :]).reshape(V, 4 * J)
    return matmul(X, jnp.transpose(M, (0, 2, 1)).reshape(4 * J, 3), precision=precision)


def _dual_quaternions(R, t):
    """Unit dual quaternions ``(r, d)`` of rigid transforms: ``r = quat(R)``, ``d = 1/2 (0, t) r``."""
    r = rot.matrix_to_quat(R)
    t_quat = jnp.concatenate([jnp.zeros_like(t[:, :1]), t], axis=1)
    return r, 0.5 * rot.quat_multiply(t_quat, r)


class _Pairs(NamedTuple):
    """The (pivot joint, joint) pairs that occur in a mesh's weights, for the one-product DQS blend:
    ``index [V, K]`` the pair of each influence, ``pivot [P]`` and ``joint [P]`` the pairs' joints."""

    index: Array
    pivot: Array
    joint: Array


def _dqs_pairs(joints: np.ndarray, w: np.ndarray, num_joints: int) -> _Pairs | None:
    """The pairs of concrete weights (the pivot is each vertex's largest weight, the first of a tie, as
    ``jnp.argmax``), or ``None`` when the dense ``[V, P]`` matrix would not fit in :data:`_DENSE_MAX`."""
    V = joints.shape[0]
    pivot = joints[np.arange(V), np.argmax(w, axis=1)]
    keys, index = np.unique(pivot[:, None].astype(np.int64) * num_joints + joints, return_inverse=True)
    if V * keys.size > _DENSE_MAX:
        return None
    return _Pairs(jnp.asarray(index.reshape(joints.shape), jnp.int32), jnp.asarray(keys // num_joints, jnp.int32),
                  jnp.asarray(keys % num_joints, jnp.int32))


def _dqs(R, t, vertices, joints, w, pairs: _Pairs | None = None, precision=HIGHEST):
    """Dual-quaternion skinning. The blend ``b_v = sum_k w_k s_k q_{j_k}``, with the sign ``s_k`` of
    ``r_{j_k} . r_pivot(v)``, is either gathered per vertex (``[V, K, 8]``), or, given the ``pairs``
    of the weights (:func:`_dqs_pairs`), one matrix product ``X [V, P] @ Y [P, 8]``: ``X`` holds the
    weights in the columns of their (pivot, joint) pairs, ``Y`` the signed dual quaternion of each
    pair. ``X`` does not depend on the pose, so under ``vmap`` over frames the blend is one GEMM over
    all frames (2.6x faster on two CPU cores for the benchmark's 10k-vertex mesh and 118 pairs)."""
    qr, qd = _dual_quaternions(R, t)
    if pairs is None:
        r, d = qr[joints], qd[joints]  # [V, K, 4]
        pivot = jnp.argmax(w, axis=1)
        r_pivot = jnp.take_along_axis(r, pivot[:, None, None], axis=1)  # [V, 1, 4]
        ws = w * jnp.where(jnp.sum(r * r_pivot, axis=2) < 0, -1.0, 1.0).astype(w.dtype)
        b_r = einsum("vk,vkc->vc", ws, r, precision=precision)
        b_d = einsum("vk,vkc->vc", ws, d, precision=precision)
    else:
        V, P = vertices.shape[0], pairs.pivot.shape[0]
        sign = jnp.where(jnp.sum(qr[pairs.pivot] * qr[pairs.joint], axis=1) < 0, -1.0, 1.0).astype(w.dtype)
        Y = sign[:, None] * jnp.concatenate([qr, qd], axis=1)[pairs.joint]  # [P, 8]
        X = jnp.zeros((V, P), w.dtype).at[jnp.arange(V)[:, None], pairs.index].add(w)
        b = matmul(X, Y, precision=precision)
        b_r, b_d = b[:, :4], b[:, 4:]
    n2 = jnp.sum(b_r * b_r, axis=1, keepdims=True)
    tiny = jnp.finfo(w.dtype).tiny ** 0.5
    ok = n2 > tiny
    inv = jnp.where(ok, lax.rsqrt(jnp.where(ok, n2, 1.0)), 0.0)
    b_r, b_d = b_r * inv, b_d * inv
    # translation 2 vec(d r*): for a non-unit blend this is the sandwich (r + eps d) v (r* - eps d*)
    trans = 2.0 * rot.quat_multiply(b_d, rot.quat_conjugate(b_r))[:, 1:]
    return rot.quat_apply(b_r, vertices) + trans


def _skin_kernel(skeleton, rotations, translations, vertices, joints, w, bind, pairs, method: str,
                 precision=HIGHEST):
    dtype = vertices.dtype
    if bind is None:
        R_bind, p_bind = _rest_fk(skeleton)
    else:
        R_bind, p_bind = bind
    R, t = _skinning_transforms(skeleton, rotations, translations, R_bind.astype(dtype), p_bind.astype(dtype))
    if method == "lbs":
        return _lbs(R, t, vertices, joints, w, precision)
    return _dqs(R, t, vertices, joints, w, pairs, precision)


_skin_one = jax.jit(_skin_kernel, static_argnames=("method", "precision"))


def _frames_kernel(skeleton, rotations, translations, vertices, joints, w, bind, pairs, method: str,
                   precision=HIGHEST):
    """``vmap(skin)`` over the frames of ``rotations [F, J, 4]`` and ``translations [F, J, 3]``."""
    fn = functools.partial(_skin_kernel, method=method, precision=precision)
    return jax.vmap(fn, in_axes=(None, 0, 0, None, None, None, None, None))(
        skeleton, rotations, translations, vertices, joints, w, bind, pairs)


skin_frames = jax.jit(_frames_kernel, static_argnames=("method", "precision"))


# ------------------------------------------------------------------------------------------------
# Public entry points
# ------------------------------------------------------------------------------------------------


def _check_method(method) -> str:
    if method not in METHODS:
        raise JaxanimError(f"method: expected one of {', '.join(repr(m) for m in METHODS)}, got {method!r}")
    return method


def _prepare(skeleton, vertices, weights, method, bind, normalize, rotations=None, translations=None):
    if not isinstance(skeleton, Skeleton):
        raise JaxanimError(f"skeleton: expected a jaxanim.Skeleton, got {type(skeleton).__name__}")
    _check_method(method)
    if isinstance(vertices, Mesh):
        vertices = vertices.vertices
    vertices = _as_float_array("vertices", vertices)
    check_shape("vertices", vertices, (None, 3), what="(V, 3)")
    weights = check_weights(skeleton, weights, vertices.shape[0], normalize=normalize)
    dtype = jnp.result_type(vertices.dtype, weights.weights.dtype,
                            *(x.dtype for x in (rotations, translations) if hasattr(x, "dtype")))
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    bind = None if bind is None else _bind_rt(skeleton, bind, dtype)
    joints, w = weights.joints, weights.weights.astype(dtype)
    pairs = None
    if method == "dqs" and not _is_traced(joints, w):
        pairs = _dqs_pairs(np.asarray(joints), np.asarray(w), skeleton.num_joints)
    return vertices.astype(dtype), joints, w, bind, pairs, dtype


def skin(
    skeleton: Skeleton,
    rotations: Float[Array, "joints 4"] | Float[Array, "joints 3 3"],
    translations: Float[Array, "joints 3"] | None,
    vertices: Float[Array, "V 3"] | Mesh,
    weights: SkinWeights,
    method: str = "lbs",
    bind=None,
    *,
    normalize: bool = False,
    precision: lax.Precision | str = HIGHEST,
) -> Float[Array, "V 3"]:
    """Deform bind-pose vertices to one pose by linear blend or dual-quaternion skinning.

    With ``M_j = G_j(pose) G_j(bind)^-1``:

    * ``"lbs"``: ``v' = sum_k w_k M_{j_k} v``;
    * ``"dqs"``: the ``K`` unit dual quaternions of ``M_{j_k}``, each flipped onto the hemisphere of
      the vertex's largest-weight joint, blended with the weights, normalised, applied.

    Differentiable with respect to the pose, the vertices and the weights; batch over frames and
    characters with ``jax.vmap``. The weights are checked (:func:`check_weights`) when they are
    concrete.

    Args:
        skeleton: the tree.
        rotations: local rotations ``[joints, 4]`` wxyz (or ``[joints, 3, 3]``), as for
            :func:`~jaxanim.forward_kinematics`.
        translations: ``[joints, 3]`` local translations (the root translation in row 0), or
            ``None`` for the OFFSETs.
        vertices: ``[V, 3]`` bind-pose vertex positions (file units), or a :class:`Mesh`.
        weights: :class:`SkinWeights` with ``[V, K]`` joints and weights.
        method: ``"lbs"`` or ``"dqs"``.
        bind: the bind pose: ``None`` (the rest pose), ``[joints, 4, 4]`` from
            :func:`bind_transforms`, or a tuple ``(R [joints, 3, 3], p [joints, 3])``.
        normalize: divide each vertex's weights by their sum instead of requiring a sum of 1.
        precision: of the blend's matrix products over the vertices: ``"highest"`` (the default:
            float32 at float32 accuracy on every backend) or the fast ``"default"``, which on an
            NVIDIA GPU runs float32 products in TF32 (about 10 bits of mantissa, so an error of
            about 1e-3 of the coordinates' size). The joints' transforms are always ``"highest"``.

    Returns:
        ``[V, 3]`` deformed vertex positions, world frame (file units).

    Raises:
        JaxanimError: an unknown method or precision, a shape that does not match, or bad weights
            (see :func:`check_weights`).
    """
    vertices, joints, w, bind, pairs, dtype = _prepare(skeleton, vertices, weights, method, bind, normalize,
                                                       rotations, translations)
    rotations = jnp.asarray(rotations).astype(dtype)
    if translations is not None:
        translations = jnp.asarray(translations).astype(dtype)
    return _skin_one(skeleton, rotations, translations, vertices, joints, w, bind, pairs, method=method,
                     precision=check_precision("precision", precision))


def skin_motion(
    skeleton: Skeleton,
    motion: Motion,
    mesh: Mesh | Float[Array, "V 3"],
    weights: SkinWeights,
    method: str = "lbs",
    bind=None,
    *,
    normalize: bool = False,
    precision: lax.Precision | str = HIGHEST,
) -> Float[Array, "frames V 3"]:
    """Skin every frame of a clip: one compiled ``jax.vmap`` of :func:`skin` over the frames.

    Args:
        skeleton: the clip's skeleton.
        motion: the clip (``[frames, joints, 4]`` rotations, ``[frames, joints, 3]`` translations).
        mesh: the bind-pose :class:`Mesh` (or its ``[V, 3]`` vertices).
        weights: :class:`SkinWeights` for the mesh's vertices.
        method: ``"lbs"`` or ``"dqs"``.
        bind: the bind pose, as for :func:`skin`.
        normalize: as for :func:`skin`.
        precision: as for :func:`skin`.

    Returns:
        ``[frames, V, 3]`` deformed vertices.

    Raises:
        JaxanimError: as :func:`skin`, or a clip that does not fit the skeleton.
    """
    return skin_frames(*skin_frames_args(skeleton, motion, mesh, weights, method, bind, normalize), method=method,
                        precision=check_precision("precision", precision))


def skin_frames_args(skeleton, motion, mesh, weights, method="lbs", bind=None, normalize=False) -> tuple:
    """The checked arguments of :data:`skin_frames` (the command line and the benchmark compile it apart)."""
    if not isinstance(motion, Motion):
        raise JaxanimError(f"motion: expected a jaxanim.Motion, got {type(motion).__name__}")
    vertices, joints, w, bind, pairs, dtype = _prepare(skeleton, mesh, weights, method, bind, normalize,
                                                       motion.rotations, motion.translations)
    motion.check_skeleton(skeleton)
    return (skeleton, motion.rotations.astype(dtype), motion.translations.astype(dtype), vertices, joints, w, bind,
            pairs)
