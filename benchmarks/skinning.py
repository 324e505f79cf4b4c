"""Skinning benchmark (``python -m benchmarks skinning``): linear blend (LBS) and dual-quaternion (DQS) skinning
of a ~10k-vertex capsule skin of the shipped walk over ~1k frames, ``jaxanim.skinning`` (one compiled ``vmap``
over the frames, as ``skin_motion`` runs it) against vectorised NumPy implementations in the same run, as
vertices x frames per second."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxanim import default_clip_path, read_bvh, skinning
from jaxanim._linalg import check_precision
from jaxanim.app._simulate import _looped_motion
from jaxanim.rotations._numpy import quat_mul as _qmul
from jaxanim.rotations._numpy import quat_to_matrix as _qmat
from jaxanim.skinning._mesh import bone_segments
from jaxanim.skinning._skin import _frames_kernel, skin_frames_args

from .report import Row, Table, Target, sel
from .timing import Runner

__all__ = ["ACCELERATOR_SIZES", "SkinningSizes", "numpy_dqs", "numpy_lbs", "run_skinning"]

_JAX = {m: f"jaxanim skin_motion ({m.upper()})" for m in ("lbs", "dqs")}
_NUMPY = {m: f"numpy, vectorised ({m.upper()})" for m in ("lbs", "dqs")}
_CHUNK = 32  # frames per NumPy step (bounds its temporaries to ~100 MB at 10k vertices)
_DQS_CHUNK = 8  # frames per NumPy DQS step: its many elementwise passes run faster on temporaries that stay in cache


@dataclasses.dataclass(frozen=True)
class SkinningSizes:
    """Sizes (``--quick`` and tests shrink them): the mesh's target vertex count and the frames; the NumPy peers
    (and the accuracy reference) run on the first ``peer_frames`` frames (``None``: all)."""

    vertices: int = 10_000
    frames: int = 1000
    peer_frames: int | None = None


#: ``--gpu`` on a machine with an accelerator: 10^4 vertices x 10^4 frames; NumPy on the first 1,000 frames (its
#: time per vertex-frame does not depend on the frame count).
ACCELERATOR_SIZES = SkinningSizes(vertices=10_000, frames=10_000, peer_frames=1000)


# ------------------------------------------------------------------------------------------------
# NumPy peers: FK in quaternions, skinning vectorised over vertices and a chunk of frames
# ------------------------------------------------------------------------------------------------


def _numpy_transforms(parents, offsets, rotations, translations):
    """Skinning transforms from the rest bind pose: global quaternions ``[F, J, 4]`` (the rest pose's are the
    identity, so they are the skinning rotations) and translations ``t_j = p_j - R_j p_bind_j`` ``[F, J, 3]``."""
    J = rotations.shape[1]
    q = np.empty_like(rotations)
    p = np.empty_like(translations)
    pb = np.empty((J, 3), offsets.dtype)
    q[:, 0], p[:, 0], pb[0] = rotations[:, 0], translations[:, 0], offsets[0]
    for j in range(1, J):
        a = parents[j]
        q[:, j] = _qmul(q[:, a], rotations[:, j])
        p[:, j] = p[:, a] + np.einsum("fab,fb->fa", _qmat(q[:, a]), translations[:, j])
        pb[j] = pb[a] + offsets[j]
    return q, p - np.einsum("fjab,jb->fja", _qmat(q), pb)


def numpy_lbs(parents, offsets, rotations, translations, vertices, joints, weights) -> np.ndarray:
    """LBS of every frame, ``[F, V, 3]``: the dense ``[V, J]`` weight matrix times the frames' 3x4 transforms
    (one BLAS product per chunk of frames), then each vertex's blended matrix applied."""
    q, t = _numpy_transforms(parents, offsets, rotations, translations)
    F, J = q.shape[:2]
    V = vertices.shape[0]
    W = np.zeros((V, J), vertices.dtype)
    np.add.at(W, (np.arange(V)[:, None], joints), weights)
    M = np.concatenate([_qmat(q), t[..., None]], axis=3)  # [F, J, 3, 4]
    out = np.empty((F, V, 3), vertices.dtype)
    for lo in range(0, F, _CHUNK):
        m = M[lo:lo + _CHUNK]
        A = (W @ m.transpose(1, 0, 2, 3).reshape(J, -1)).reshape(V, m.shape[0], 3, 4)
        out[lo:lo + _CHUNK] = np.einsum("vfab,vb->fva", A[..., :3], vertices) + A[..., 3].transpose(1, 0, 2)
    return out


def _canonical(q: np.ndarray) -> np.ndarray:
    """jaxanim's sign of a rotation quaternion (``rotations.quat_canonical``, which ``matrix_to_quat`` returns):
    ``w >= 0``; when ``w == 0``, the first nonzero of ``x, y, z`` positive."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    key = np.where(w != 0, w, np.where(x != 0, x, np.where(y != 0, y, z)))
    return np.where((key < 0)[..., None], -q, q)


def _cross(a, b):  # component-first 3-vectors (tuples of arrays)
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


def numpy_dqs(parents, offsets, rotations, translations, vertices, joints, weights) -> np.ndarray:
    """DQS of every frame, ``[F, V, 3]``, in jaxanim's formulation (``skinning._skin._dqs`` with the weights'
    pairs, as ``skin_motion`` runs it), step for step:

    * each joint's unit dual quaternion ``q_j = (r_j, d_j)``, ``r_j`` in jaxanim's canonical sign and
      ``d_j = 1/2 (0, t_j) r_j``;
    * a vertex's pivot is the joint of its largest weight (the first of a tie); every (pivot, joint) pair that
      occurs in the weights carries ``s q_joint``, ``s = -1`` where ``r_joint . r_pivot < 0`` (else 1);
    * the blend ``b = X Y``: the pose-independent ``[V, P]`` weights, each in its pair's column, times the
      ``[P, 8]`` signed pairs, one BLAS product per chunk of frames;
    * both parts times ``1 / |b_r|`` (0 where ``|b_r|^2`` is below the square root of the dtype's tiny);
    * ``v' = v + s (w t + u x t)`` with ``t = u x v``, ``s = 2 / |b_r|^2`` (``rotations.quat_apply``), plus
      ``2 vec(b_d b_r*)``."""
    r, t = _numpy_transforms(parents, offsets, rotations, translations)
    r = _canonical(r)
    d = 0.5 * _qmul(np.concatenate([np.zeros_like(t[..., :1]), t], axis=-1), r)
    dtype = vertices.dtype
    F, J = r.shape[:2]
    V = vertices.shape[0]
    pivot = joints[np.arange(V), np.argmax(weights, axis=1)]
    keys, index = np.unique(pivot[:, None].astype(np.int64) * J + joints, return_inverse=True)
    pair_pivot, pair_joint = keys // J, keys % J
    P = keys.size
    Xt = np.zeros((P, V), dtype)  # X transposed: the frames' products come out component-major, [8 c, V]
    np.add.at(Xt, (index.reshape(joints.shape), np.arange(V)[:, None]), weights)
    q = np.concatenate([r, d], axis=-1)  # [F, J, 8]
    tiny = np.sqrt(np.finfo(dtype).tiny)
    v = tuple(vertices.T)  # x, y, z: [V]
    out = np.empty((F, V, 3), dtype)
    for lo in range(0, F, _DQS_CHUNK):
        rk = r[lo:lo + _DQS_CHUNK]
        c = rk.shape[0]
        sign = np.where(np.einsum("cpq,cpq->cp", rk[:, pair_pivot], rk[:, pair_joint]) < 0, -1.0, 1.0)
        Y = sign[..., None] * q[lo:lo + c, pair_joint]  # [c, P, 8]
        b = (Y.transpose(2, 0, 1).reshape(8 * c, P) @ Xt).reshape(8, c, V)
        n2 = b[0] * b[0] + b[1] * b[1] + b[2] * b[2] + b[3] * b[3]
        ok = n2 > tiny
        b = b * np.where(ok, 1.0 / np.sqrt(np.where(ok, n2, 1.0)), 0.0)
        w, u, dw, du = b[0], (b[1], b[2], b[3]), b[4], (b[5], b[6], b[7])
        n2 = w * w + u[0] * u[0] + u[1] * u[1] + u[2] * u[2]
        ok = n2 > tiny
        s = np.where(ok, 2.0 / np.where(ok, n2, 1.0), 0.0)
        tv = _cross(u, v)
        utv = _cross(u, tv)
        dxu = _cross(du, u)  # vec(b_d b_r*) = w du - dw u - du x u
        for a in range(3):
            out[lo:lo + c, :, a] = v[a] + s * (w * tv[a] + utv[a]) + 2.0 * (w * du[a] - dw * u[a] - dxu[a])
    return out


# ------------------------------------------------------------------------------------------------
# The table
# ------------------------------------------------------------------------------------------------


def _mesh_for(skel, target: int) -> skinning.Mesh:
    """A capsule skin with about ``target`` vertices (16 sides and 3 cap rings from 2000, fewer below; rings along the
    bones to fit)."""
    segments = len(bone_segments(skel)[2])
    sides, cap = (16, 3) if target >= 2000 else (8, 2) if target >= 1500 else (4, 1)
    rings = max(1, round((target / segments - 2) / sides - (2 * cap - 1)))
    return skinning.capsule_mesh(skel, sides=sides, rings=rings, cap_rings=cap)


def _description(method: str, V: int, F: int, T: int, K: int, peer_frames: int) -> str:
    common = (f"The shipped walk (21 joints) looped to {F} frames, skinned with a procedural capsule mesh "
              f"(`skinning.capsule_mesh`, {V} vertices, {T} triangles) and the distance-to-bone heuristic weights "
              f"(K = {K}). One timed call skins every frame (the batch column counts the frames); **µs / char is per "
              "vertex-frame** and the note gives "
              "vertices x frames per second. jaxanim: the kernel of `skinning.skin_motion`, one compiled `jax.vmap` "
              "of `skin` over the frames (FK, skinning transforms, blend; compile apart; the weights' Python checks, "
              "done once per call of `skin_motion`, are not timed). NumPy: FK in quaternions vectorised over the "
              "frames, then ")
    if method == "lbs":
        how = ("the dense [V, J] weight matrix times the frames' 3x4 transforms (one BLAS product per "
               f"{_CHUNK} frames) and each vertex's blended matrix applied. jaxanim's LBS is one matrix product "
               "[V, 4J] x [4J, 3] per frame (the weights times the homogeneous vertex, against the transforms), "
               "one GEMM over all frames under `vmap`.")
    else:
        how = ("the same DQS formulation as jaxanim's, step by step: the dual quaternion of each joint (the "
               "rotation's quaternion in jaxanim's canonical sign), each (largest-weight joint, joint) pair that "
               "occurs in the weights flipped onto its largest-weight joint's hemisphere, the blend one matrix "
               f"product [V, P] x [P, 8] over those P pairs (one BLAS product per {_DQS_CHUNK} frames; jaxanim: one "
               "GEMM over all frames under `vmap`), both parts divided by the norm of the blend's real part, and the "
               "position "
               "recovered the same way (the rotation applied as `rotations.quat_apply` does, plus 2 vec(d r*)). The "
               "two differ in the FK (NumPy composes quaternions; jaxanim composes matrices and converts them) and in "
               "how the work is batched, not in the arithmetic of the skinning; NumPy's time includes finding the "
               "pairs, which jaxanim does with the weights' untimed checks.")
    some = f" on the first {peer_frames} frames (NumPy's rows are timed on those)" if peer_frames < F else ""
    return common + how + f" Accuracy: the largest distance from the float64 NumPy result (the reference row){some}."


def run_skinning(config, sizes: SkinningSizes | None = None) -> list[Table]:
    """The ``skinning`` benchmark (see the module docstring): a table for LBS and one for DQS; ``sizes`` shrinks
    it for tests."""
    sz = sizes or config.pick(SkinningSizes(), accelerator=ACCELERATOR_SIZES,
                              quick=SkinningSizes(vertices=500, frames=8))
    skel, walk = read_bvh(default_clip_path())[:2]
    motion = _looped_motion(walk, sz.frames)
    mesh = _mesh_for(skel, sz.vertices)
    w = skinning.heuristic_weights(skel, mesh)
    V, F, K = mesh.num_vertices, motion.num_frames, w.k
    pf = min(F, sz.peer_frames or F)
    np_args = (skel.parents, np.asarray(skel.offsets, np.float64), np.asarray(motion.rotations[:pf], np.float64),
               np.asarray(motion.translations[:pf], np.float64), np.asarray(mesh.vertices, np.float64),
               np.asarray(w.joints), np.asarray(w.weights, np.float64))
    tables = []
    for method in ("lbs", "dqs"):
        table = Table(
            f"skinning-{method}", f"Skinning ({method.upper()}): {V} vertices x {F} frames of the shipped walk",
            accuracy_label="max abs err (m)", description=_description(method, V, F, mesh.num_faces, K, pf),
            targets=[Target(f"jaxanim {method.upper()} at least as fast as NumPy (float64)",
                            sel(_JAX[method], "float64"), 1.0, versus=sel(_NUMPY[method], "float64"))])
        _fill(config, table, method, skel, motion, mesh, w, np_args, pf)
        tables.append(table)
    return tables


def _fill(config, table: Table, method: str, skel, motion, mesh, w, np_args, pf: int) -> None:
    run = Runner(config, table)
    V, F = mesh.num_vertices, motion.num_frames
    numpy_fn = numpy_lbs if method == "lbs" else numpy_dqs
    ref: list[np.ndarray] = []

    def reference() -> np.ndarray:
        if not ref:
            ref.append(numpy_fn(*np_args))
        return ref[0]

    def numpy_row() -> Row:
        out, tm = run.python(numpy_fn, *np_args)
        ref[:] = [out]
        return run.row(_NUMPY[method], "float64", F, tm, V * pf, accuracy="reference",
                       note=f"{V * pf / tm.median / 1e6:.1f} M vertex-frames/s"
                       + (f"; timed on the first {pf} of {F} frames" if pf < F else ""))

    def jax_row(dtype: str, precision: str = "highest") -> Row:
        def cast(tree):
            return jax.tree.map(lambda x: x.astype(dtype) if jnp.issubdtype(x.dtype, jnp.floating) else x, tree)

        prec = check_precision("precision", precision)
        fn = jax.jit(functools.partial(_frames_kernel, method=method, precision=prec))
        args = skin_frames_args(cast(skel), cast(motion), cast(mesh), cast(w), method)
        out, tm, comp = run.jax(fn, *args)
        err = float(np.max(np.linalg.norm(np.asarray(out[:pf], np.float64) - reference(), axis=-1)))
        return run.row(_JAX[method] + ("" if precision == "highest" else f" (precision={precision!r})"), dtype, F, tm,
                       V * F, comp, err, note=f"{V * F / tm.median / 1e6:.1f} M vertex-frames/s")

    run.add(_NUMPY[method], "float64", F, numpy_row, peer=True)
    for dt in config.dtypes:
        run.add(_JAX[method], dt, F, lambda d=dt: jax_row(d))
    if config.accelerator and "float32" in config.dtypes:  # the fast path a user may choose (TF32 on NVIDIA GPUs)
        run.add(_JAX[method] + " (precision='default')", "float32", F, lambda: jax_row("float32", "default"))
