"""``jaxanim skin``: skin every frame of a clip (LBS or DQS) and write the vertices as an .npz or an
OBJ sequence. Without ``--mesh`` the mesh is the procedural capsule skin of the clip's skeleton;
without ``--weights`` the weights are the distance-to-bone heuristic."""

from __future__ import annotations

import argparse
import pathlib
import textwrap
import time
import zipfile

import jax
import numpy as np

from .._errors import JaxanimError
from ..skinning import METHODS, Mesh, SkinWeights, capsule_mesh, check_weights, heuristic_weights, read_obj, write_obj
from ..skinning._skin import skin_frames_args, skin_frames
from ._common import _UI, _duration, _load, _ms, _save_npz
from ._simulate import _check_writable

_OUT_KINDS = {".npz": "npz", ".obj": "obj"}


def _out_kind(out: str) -> str:
    ext = pathlib.Path(out).suffix.lower()
    if ext not in _OUT_KINDS:
        raise JaxanimError(f"--out {out}: unknown output extension {ext or '(none)'!r}; expected .npz (vertices "
                           "[F, V, 3] and faces [T, 3]) or .obj (an OBJ sequence, one file per frame)")
    return _OUT_KINDS[ext]


def _sequence_paths(out: str, frames: int) -> list[pathlib.Path]:
    """``DIR/name.obj`` -> ``DIR/name_0000.obj``, ``DIR/name_0001.obj``, ... (at least 4 digits)."""
    p = pathlib.Path(out)
    width = max(4, len(str(max(frames - 1, 0))))
    return [p.with_name(f"{p.stem}_{f:0{width}d}{p.suffix}") for f in range(frames)]


def read_weights(path: str, dtype=None) -> SkinWeights:
    """Read a weights file: an .npz with ``joints`` ``[V, K]`` (integers, the skeleton's joint order) and
    ``weights`` ``[V, K]``.

    Raises:
        JaxanimError: naming the file: unreadable, a missing array (listing those present), a wrong
            dtype or shape.
    """
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except FileNotFoundError:
        raise JaxanimError(f"{path}: no such file") from None
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise JaxanimError(f"{path}: cannot read it as an .npz file: {exc}") from None
    missing = [k for k in ("joints", "weights") if k not in arrays]
    if missing:
        raise JaxanimError(f"{path}: missing array(s) {missing}; expected 'joints' [V, K] (integer joint indices) and "
                           f"'weights' [V, K]; the file holds {sorted(arrays)}")
    j, w = arrays["joints"], arrays["weights"]
    if not np.issubdtype(j.dtype, np.integer):
        raise JaxanimError(f"{path}: 'joints' must hold integer joint indices, got dtype {j.dtype}")
    if not (np.issubdtype(w.dtype, np.floating) or np.issubdtype(w.dtype, np.integer)):
        raise JaxanimError(f"{path}: 'weights' must be real numbers, got dtype {w.dtype}")
    try:
        return SkinWeights(j, w if dtype is None else w.astype(dtype))
    except JaxanimError as exc:
        raise JaxanimError(f"{path}: {exc}") from None


def _cmd_skin(args: argparse.Namespace, ui: _UI) -> int:
    if args.method not in METHODS:
        raise JaxanimError(f"--method: expected one of {', '.join(METHODS)}, got {args.method!r}")
    if args.k < 1:
        raise JaxanimError(f"--k: expected at least 1 influence per vertex, got {args.k}")
    if args.radius is not None:
        if args.mesh is not None:
            raise JaxanimError("--radius sizes the procedural capsule mesh: it cannot be used with --mesh")
        if not (np.isfinite(args.radius) and args.radius > 0):
            raise JaxanimError(f"--radius: expected a positive number (file units), got {args.radius:g}")
    if args.out is not None:
        _out_kind(args.out)
    clip = _load(args.file, ui, args.dtype)
    sk, motion = clip.skeleton, clip.motion
    out = args.out or f"{clip.stem}.skin.npz"
    kind = _out_kind(out)
    if kind == "npz":
        _check_writable("--out", out)
    t0 = time.perf_counter()
    if args.mesh is not None:
        ui.progress(f"reading {args.mesh}")
        mesh = read_obj(args.mesh, dtype=args.dtype)
        mesh_label = f"{args.mesh}: {mesh.num_vertices} vertices, {mesh.num_faces} triangles"
    else:
        mesh = capsule_mesh(sk, args.radius, dtype=args.dtype)
        mesh_label = f"the procedural capsule mesh: {mesh.num_vertices} vertices, {mesh.num_faces} triangles"
    if args.weights is not None:
        weights = read_weights(args.weights, args.dtype)
        weights_label = f"{args.weights} (K = {weights.k})"
        try:
            weights = check_weights(sk, weights, mesh.num_vertices, normalize=args.normalize)
        except JaxanimError as exc:
            raise JaxanimError(f"{args.weights}: {exc} (mesh: {mesh_label})") from None
    else:
        ui.progress(f"{mesh_label}; distance-to-bone weights, K = {args.k}")
        weights = heuristic_weights(sk, mesh, k=args.k)
        weights_label = f"distance-to-bone heuristic (K = {weights.k})"
    prep_seconds = time.perf_counter() - t0
    F, V = motion.num_frames, mesh.num_vertices
    ui.progress(f"skinning {F} frames x {V} vertices ({args.method.upper()}, one batched call)")
    dyn = skin_frames_args(sk, motion, mesh, weights, args.method)
    t0 = time.perf_counter()
    compiled = skin_frames.lower(*dyn, method=args.method).compile()
    compile_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    verts = np.asarray(jax.block_until_ready(compiled(*dyn)))
    run_seconds = time.perf_counter() - t0
    faces = np.asarray(mesh.faces)
    if kind == "npz":
        ui.progress(f"writing {out}")
        _save_npz(out, {"vertices": verts, "faces": faces})
        what = f"wrote {out}: vertices [{F}, {V}, 3] ({verts.dtype}), faces [{faces.shape[0]}, 3]"
    else:
        paths = _sequence_paths(out, F)
        parent = pathlib.Path(out).parent
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise JaxanimError(f"--out {out}: cannot create the directory {parent}: {exc.strerror or exc}") from None
        ui.progress(f"writing {F} OBJ files {paths[0]} ... {paths[-1].name}" if F else "no frames to write")
        for f, path in enumerate(paths):
            write_obj(path, Mesh(verts[f], faces), comment=f"jaxanim skin {clip.path.name} frame {f} "
                                                             f"({args.method.upper()})")
        what = (f"wrote {F} OBJ files {paths[0]} ... {paths[-1].name}: {V} vertices and {faces.shape[0]} triangles "
                f"each ({verts.dtype})" if F else f"{clip.label} has no frames: nothing written")
    rate = V * F / run_seconds / 1e6 if run_seconds > 0 else float("inf")
    ui.result(
        f"{what}\n"
        f"{args.method.upper()} skinning of {mesh_label}; weights: {weights_label}\n"
        f"parse {_ms(clip.parse_seconds)}, mesh and weights {_duration(prep_seconds)}, skin compile "
        f"{_duration(compile_seconds)}, skin run {_ms(run_seconds)} ({rate:.1f} M vertex-frames/s)"
    )
    return 0


def add_skin_parser(sub, common) -> None:
    description = "\n\n".join(textwrap.fill(par, 79) for par in (
        ("Deform a mesh by the clip's poses, every frame in one batched call, by linear blend (lbs) or "
         "dual-quaternion (dqs) skinning from the rest pose (every rotation zero, every joint at its OFFSET). "
         "Without --mesh: a procedural capsule around every bone; without --weights: distance-to-bone weights, "
         "the --k nearest joints per vertex."),
        ("OUT.npz holds vertices [F, V, 3] and faces [T, 3] (0-based). With --out DIR/name.obj it writes an OBJ "
         "sequence instead, one file per frame: DIR/name_0000.obj, DIR/name_0001.obj, ... (DIR is created)."),
    ))
    p = sub.add_parser("skin", parents=[common], help="skin every frame with a mesh (LBS or DQS; .npz or OBJ out)",
                       formatter_class=argparse.RawDescriptionHelpFormatter, description=description)
    p.add_argument("file", nargs="?", metavar="FILE.bvh", help="a BVH file (default: the shipped walk clip)")
    p.add_argument("--mesh", "-m", metavar="M.obj",
                   help="the mesh in the rest pose, as OBJ (default: the procedural capsule mesh)")
    p.add_argument("--weights", "-w", metavar="W.npz",
                   help="skin weights: an .npz with 'joints' [V, K] (integer indices in the file's joint order) and "
                        "'weights' [V, K], each row summing to 1 (default: distance-to-bone weights)")
    p.add_argument("--method", default="lbs", metavar="lbs|dqs",
                   help="lbs (linear blend, the default) or dqs (dual quaternions)")
    p.add_argument("--out", "-o", metavar="OUT.npz|DIR/name.obj",
                   help="OUT.npz, or DIR/name.obj for an OBJ sequence, one file per frame named "
                        "DIR/name_<frame>.obj (default: <name>.skin.npz here)")
    p.add_argument("--k", type=int, default=4, metavar="K",
                   help="influences per vertex of the distance-to-bone weights (default 4)")
    p.add_argument("--radius", type=float, default=None, metavar="R",
                   help="radius of the procedural capsules, file units (default 0.035 x the skeleton's size)")
    p.add_argument("--normalize", action="store_true",
                   help="divide each vertex's weights by their sum (default: a row not summing to 1 is an error)")
    p.set_defaults(func=_cmd_skin)
