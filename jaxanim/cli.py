"""The ``jaxanim`` command line: ``info``, ``fk``, ``plot`` and ``demo`` on BVH files.

Every command takes an optional BVH file and uses the shipped default clip (a walk, see
:mod:`jaxanim.default_clip`) without one. Computation is float64 unless ``--float32`` is given:
:func:`main` switches ``jax_enable_x64`` on before computing and leaves it on (toggling it back and
forth inside one process is not safe with jax 0.10), while ``--float32`` leaves the setting alone
and casts the parsed clip to float32. Forward kinematics of a whole clip is one batched call,
``jax.jit(jax.vmap(forward_kinematics, in_axes=(None, 0, 0)))`` (:func:`batched_fk`).

Bad input (an unreadable or malformed BVH file, a frame out of range, an output that cannot be
written) prints ``error: <path>:<line>: <message>`` (or ``error: <message>``) on stderr and exits
with status 2, never with a traceback. Progress lines go to stderr, results to stdout; ``--quiet``
keeps only the errors and the output a command exists for (the ``info`` report).

``demo`` runs a list of steps (:data:`DEMO_STEPS`); later features append theirs to it.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import os
import pathlib
import statistics
import sys
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ._errors import BVHParseError, JaxanimError
from .bvh import read_bvh
from .default_clip import default_clip_path
from .fk import FKResult, forward_kinematics
from .skeleton import POSITION_CHANNELS, Motion, Skeleton

__all__ = ["DEMO_STEPS", "main"]

_PROG = "jaxanim"
_DEMO_TIMING_REPEATS = 20


# ------------------------------------------------------------------------------------------------
# Output
# ------------------------------------------------------------------------------------------------
class _UI:
    """Where messages go: progress to stderr, results to stdout, errors always."""

    def __init__(self, quiet: bool):
        self.quiet = quiet

    def progress(self, message: str) -> None:
        if not self.quiet:
            print(f"{_PROG}: {message}", file=sys.stderr, flush=True)

    def result(self, message: str) -> None:
        if not self.quiet:
            print(message, flush=True)

    def output(self, message: str) -> None:
        print(message, flush=True)

    def error(self, message: str) -> None:
        print(f"error: {message}", file=sys.stderr, flush=True)


def _ms(seconds: float) -> str:
    return f"{seconds * 1e3:.1f} ms" if seconds >= 1e-3 else f"{seconds * 1e3:.3f} ms"


def _num(x: float) -> str:
    return f"{x:.6g}"


# ------------------------------------------------------------------------------------------------
# Shared work: load a clip, batched FK
# ------------------------------------------------------------------------------------------------
@dataclasses.dataclass
class _Clip:
    label: str  # what to call it in messages
    path: pathlib.Path
    skeleton: Skeleton
    motion: Motion
    parse_seconds: float

    @property
    def stem(self) -> str:
        return self.path.stem


def _as_dtype(tree, dtype):
    """Cast the floating-point arrays of a Module to ``dtype``."""
    return jax.tree.map(lambda x: x.astype(dtype) if jnp.issubdtype(x.dtype, jnp.floating) else x, tree)


def _load(file: str | None, ui: _UI, dtype) -> _Clip:
    """Parse ``file`` (or the shipped default clip), with its arrays in ``dtype``."""
    if file is None:
        path = default_clip_path()
        label = f"{path.name} (the shipped default clip)"
    else:
        path = pathlib.Path(file)
        label = str(file)
    ui.progress(f"parsing {label}")
    t0 = time.perf_counter()
    skeleton, motion = read_bvh(path)
    skeleton, motion = _as_dtype(skeleton, dtype), _as_dtype(motion, dtype)
    jax.block_until_ready(motion)
    seconds = time.perf_counter() - t0
    return _Clip(label, path, skeleton, motion, seconds)


@functools.lru_cache(maxsize=None)
def batched_fk():
    """``jax.jit(jax.vmap(forward_kinematics, in_axes=(None, 0, 0)))``: FK of every frame at once."""
    return jax.jit(jax.vmap(forward_kinematics, in_axes=(None, 0, 0)))


@dataclasses.dataclass
class _FKRun:
    result: FKResult  # batched over frames
    compile_seconds: float
    run_seconds: float  # the first call after compilation, or the median of the repeats after it
    repeats: int


def _clip_fk(clip: _Clip, ui: _UI, *, repeats: int = 1) -> _FKRun:
    """FK of all frames in one batched call; compilation timed separately from the run."""
    m = clip.motion
    ui.progress(f"forward kinematics of {m.num_frames} frames x {m.num_joints} joints (one batched call)")
    args = (clip.skeleton, m.rotations, m.translations)
    t0 = time.perf_counter()
    compiled = batched_fk().lower(*args).compile()
    compile_seconds = time.perf_counter() - t0
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        result = jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - t0)
    timed = times[1:] or times  # with repeats, the first call is a warm-up
    return _FKRun(result, compile_seconds, statistics.median(timed), len(timed))


def _fk_arrays(skeleton: Skeleton, motion: Motion, fk: FKResult) -> dict[str, np.ndarray]:
    """The ``fk`` npz content (the layout of ``shared/data/fk/*.fk.npz``)."""
    return {
        "joint_names": np.array(skeleton.names, dtype=str),
        "parents": np.array(skeleton.parents, dtype=np.int64),
        "offsets": np.asarray(skeleton.offsets),
        "channels": np.array([" ".join(ch) for ch in skeleton.channels], dtype=str),
        "end_site_names": np.array(skeleton.end_site_names, dtype=str),
        "end_site_parents": np.array(skeleton.end_site_parents, dtype=np.int64),
        "end_site_offsets": np.asarray(skeleton.end_site_offsets),
        "frame_time": np.asarray(motion.frame_time),
        "positions": np.asarray(fk.positions),
        "rotations": np.asarray(fk.rotations),
        "end_site_positions": np.asarray(fk.end_site_positions),
    }


def _save_npz(path: str | os.PathLike, arrays: dict[str, np.ndarray]) -> None:
    with open(path, "wb") as fh:  # a file object: numpy must not append ".npz" to the name
        np.savez(fh, **arrays)


def _check_frame(clip: _Clip, frame: int) -> None:
    n = clip.motion.num_frames
    if n == 0:
        raise JaxanimError(f"--frame {frame}: {clip.label} has no frames")
    if not 0 <= frame < n:
        raise JaxanimError(f"--frame {frame} is out of range: {clip.label} has {n} frames (valid: 0 to {n - 1})")


def _plot(clip: _Clip, frame: int, out: str | os.PathLike) -> None:
    from .plot import save_pose_png  # matplotlib is optional: import it only to plot

    m = clip.motion
    fk = forward_kinematics(clip.skeleton, m.rotations[frame], m.translations[frame])
    t = frame * float(m.frame_time)
    title = f"{clip.path.name}: frame {frame} (t = {t:.3f} s)"
    save_pose_png(out, clip.skeleton, fk, title=title)


def _describe_channels(ch: tuple[str, ...]) -> str:
    pos = "".join(c[0] for c in ch if c in POSITION_CHANNELS)
    rot = "".join(c[0] for c in ch if c not in POSITION_CHANNELS)
    parts = ([f"pos {pos}"] if pos else []) + ([f"rot {rot}"] if rot else [])
    return ", ".join(parts) if parts else "none"


def _vec(v) -> str:
    return " ".join(f"{x:9.4f}" for x in np.asarray(v).tolist())


# ------------------------------------------------------------------------------------------------
# Commands
# ------------------------------------------------------------------------------------------------
def _cmd_info(args: argparse.Namespace, ui: _UI) -> int:
    clip = _load(args.file, ui, args.dtype)
    sk, m = clip.skeleton, clip.motion
    fk = _clip_fk(clip, ui).result
    ft = float(m.frame_time)
    w = max(4, *(len(n) for n in sk.names + sk.end_site_names))
    lines = [
        f"file        {clip.label}" + (f"\npath        {clip.path}" if args.file is None else ""),
        f"joints      {sk.num_joints} (+ {sk.num_end_sites} End Sites), {sk.num_channels} channels, "
        f"{max(sk.depths) + 1} depth levels",
        f"frames      {m.num_frames} at {_num(1.0 / ft)} fps",
        f"frame time  {_num(ft)} s",
        f"duration    {_num(m.num_frames * ft)} s (frames x frame time)",
        f"dtype       {np.asarray(m.rotations).dtype}",
        "",
        f"joints:\n  {'#':>3}  {'name':<{w}}  {'parent':<{w}}  {'channels':<18}  {'offset (x y z)':>29}",
    ]
    for j, name in enumerate(sk.names):
        parent = sk.names[sk.parents[j]] if sk.parents[j] >= 0 else "-"
        lines.append(
            f"  {j:>3}  {name:<{w}}  {parent:<{w}}  {_describe_channels(sk.channels[j]):<18}  {_vec(sk.offsets[j])}"
        )
    lines.append("")
    if sk.num_end_sites:
        lines.append(f"End Sites:\n  {'#':>3}  {'name':<{w}}  {'joint':<{w}}  {'offset (x y z)':>29}")
        for e, name in enumerate(sk.end_site_names):
            lines.append(f"  {e:>3}  {name:<{w}}  {sk.names[sk.end_site_parents[e]]:<{w}}  {_vec(sk.end_site_offsets[e])}")
    else:
        lines.append("End Sites:  none")
    pts = np.concatenate([np.asarray(fk.positions), np.asarray(fk.end_site_positions)], axis=1).reshape(-1, 3)
    lines += ["", "bounding box of all joint and End Site positions over all frames (FK, file units):"]
    if pts.size:
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        lines += [
            f"  {'':<4}  {'x':>9} {'y':>9} {'z':>9}",
            f"  {'min':<4}  {_vec(lo)}",
            f"  {'max':<4}  {_vec(hi)}",
            f"  {'size':<4}  {_vec(hi - lo)}",
        ]
    else:
        lines.append("  (no frames)")
    ui.output("\n".join(lines))
    return 0


def _cmd_fk(args: argparse.Namespace, ui: _UI) -> int:
    clip = _load(args.file, ui, args.dtype)
    run = _clip_fk(clip, ui)
    out = args.out or f"{clip.stem}.fk.npz"
    ui.progress(f"writing {out}")
    arrays = _fk_arrays(clip.skeleton, clip.motion, run.result)
    _save_npz(out, arrays)
    f, j = clip.motion.num_frames, clip.motion.num_joints
    ui.result(
        f"wrote {out}: positions [{f}, {j}, 3], rotations [{f}, {j}, 3, 3], "
        f"end_site_positions [{f}, {clip.skeleton.num_end_sites}, 3] ({arrays['positions'].dtype})\n"
        f"parse {_ms(clip.parse_seconds)}, FK compile {_ms(run.compile_seconds)}, "
        f"FK run {_ms(run.run_seconds)} ({run.run_seconds / max(f, 1) * 1e6:.2f} µs per frame)"
    )
    return 0


def _cmd_ik(args: argparse.Namespace, ui: _UI) -> int:
    import json

    from .bvh import write_bvh
    from .ik import solve_ik_clip, targets_from_json

    clip = _load(args.file, ui, args.dtype)
    try:
        with open(args.targets, encoding="utf-8") as fh:
            data = json.load(fh)
    except json.JSONDecodeError as exc:
        raise JaxanimError(f"{args.targets}:{exc.lineno}: not valid JSON: {exc.msg}") from None
    targets, kwargs = targets_from_json(clip.skeleton, data, clip.motion.num_frames)
    ui.progress(f"IK on {clip.motion.num_frames} frames (one batched call)")
    t0 = time.perf_counter()
    edited, sol = solve_ik_clip(clip.skeleton, clip.motion, targets, **kwargs)
    jax.block_until_ready(edited)
    seconds = time.perf_counter() - t0
    out = args.out or f"{clip.stem}.ik.bvh"
    write_bvh(out, clip.skeleton, edited)
    ok = int(np.asarray(sol.success).sum())
    ui.result(
        f"wrote {out}: {ok}/{clip.motion.num_frames} frames meet every target; max position error "
        f"{float(np.asarray(sol.position_errors).max()):.3g} (file units), "
        f"{_ms(seconds)} including compilation"
    )
    return 0


def _cmd_plot(args: argparse.Namespace, ui: _UI) -> int:
    clip = _load(args.file, ui, args.dtype)
    _check_frame(clip, args.frame)
    out = args.out or f"{clip.stem}_frame{args.frame}.png"
    ui.progress(f"drawing frame {args.frame} to {out}")
    _plot(clip, args.frame, out)
    ui.result(f"wrote {out} (frame {args.frame} of {clip.motion.num_frames})")
    return 0


# --- demo: a list of steps ----------------------------------------------------------------------------
@dataclasses.dataclass
class DemoState:
    """What the demo steps share: the options, the clip and what earlier steps computed."""

    out_dir: pathlib.Path
    ui: _UI
    dtype: type  # np.float64, or np.float32 with --float32
    clip: _Clip | None = None
    fk: _FKRun | None = None
    rows: list[tuple[str, str]] = dataclasses.field(default_factory=list)  # (step, summary) lines


def _demo_load(s: DemoState) -> None:
    cold = _load(None, s.ui, s.dtype)  # the first parse also compiles the jitted channel conversion
    s.clip = _load(None, _UI(quiet=True), s.dtype)
    m = s.clip.motion
    s.rows.append(("load", f"parse {s.clip.path.name}: {s.clip.skeleton.num_joints} joints, {m.num_frames} frames "
                           f"at {_num(m.fps)} fps"))
    s.rows.append(("", f"{_ms(cold.parse_seconds)} cold (compiles the channel conversion), "
                       f"{_ms(s.clip.parse_seconds)} warm"))


def _demo_fk(s: DemoState) -> None:
    s.fk = _clip_fk(s.clip, s.ui, repeats=_DEMO_TIMING_REPEATS + 1)
    f = s.clip.motion.num_frames
    s.rows.append(("fk", f"compile jit(vmap(forward_kinematics)) in {_ms(s.fk.compile_seconds)}"))
    s.rows.append(("", f"run {f} frames in one call: {_ms(s.fk.run_seconds)} = "
                       f"{s.fk.run_seconds / f * 1e6:.2f} µs per frame (median of {s.fk.repeats})"))


def _demo_save_fk(s: DemoState) -> None:
    out = s.out_dir / "demo_fk.npz"
    _save_npz(out, _fk_arrays(s.clip.skeleton, s.clip.motion, s.fk.result))
    s.rows.append(("save", f"wrote {out}"))


def _demo_plot(s: DemoState) -> None:
    frame = s.clip.motion.num_frames // 2
    out = s.out_dir / "demo_pose.png"
    try:
        import matplotlib  # noqa: F401  (optional: the plot extra)
    except ImportError:
        s.rows.append(("plot", "skipped: matplotlib is not installed (pip install 'jaxanim[plot]')"))
        return
    _plot(s.clip, frame, out)
    s.rows.append(("plot", f"wrote {out} (frame {frame})"))


#: The demo, in order: ``(name, step)``; a step reads and extends the :class:`DemoState`.
DEMO_STEPS: list[tuple[str, Callable[[DemoState], None]]] = [
    ("load the shipped clip", _demo_load),
    ("forward kinematics of every frame", _demo_fk),
    ("save the FK arrays", _demo_save_fk),
    ("plot a stick figure", _demo_plot),
]


def _cmd_demo(args: argparse.Namespace, ui: _UI) -> int:
    out_dir = pathlib.Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    state = DemoState(out_dir=out_dir, ui=ui, dtype=args.dtype)
    t_start = time.perf_counter()
    for i, (name, step) in enumerate(DEMO_STEPS, start=1):
        ui.progress(f"[{i}/{len(DEMO_STEPS)}] {name}")
        step(state)
    total = time.perf_counter() - t_start
    dev = jax.devices()[0]
    dtype = np.asarray(state.clip.motion.rotations).dtype
    lines = [f"jaxanim demo ({dtype}, {dev.platform}: {dev.device_kind})"]
    lines += [f"  {name:<5} {text}" for name, text in state.rows]
    lines.append(f"  total {_ms(total)}")
    ui.result("\n".join(lines))
    return 0


# ------------------------------------------------------------------------------------------------
# Parser and entry point
# ------------------------------------------------------------------------------------------------
_DESCRIPTION = """\
jaxanim: physics-based character animation numerics in JAX.

Commands read a BVH file; without FILE they use the shipped default clip (a
procedural walk, 21 joints, metres, Y up, 120 frames at 30 fps). Computation is
float64 unless --float32. Bad input exits with status 2 and an
'error: <path>:<line>: <message>' line on stderr."""

_EPILOG = """\
examples:
  jaxanim info                         describe the shipped clip
  jaxanim info walk.bvh                joints, End Sites, frames, bounding box
  jaxanim fk walk.bvh --out walk.npz   global transforms of every frame
  jaxanim plot walk.bvh --frame 10 --out pose.png
  jaxanim demo --out-dir results       run the whole pipeline with timings"""


def _add_global_flags(p: argparse.ArgumentParser, default) -> None:
    p.add_argument("--float32", action="store_true", default=default,
                   help="compute in float32 (default: float64, with jax_enable_x64 switched on)")
    p.add_argument("--quiet", "-q", action="store_true", default=default,
                   help="no progress or result lines, only errors and the info report")


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=_PROG, description=_DESCRIPTION, epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    _add_global_flags(parser, False)
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    # the global flags are also accepted after the command; SUPPRESS keeps the parser's value then
    common = argparse.ArgumentParser(add_help=False)
    _add_global_flags(common, argparse.SUPPRESS)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    file_help = "a BVH file (default: the shipped walk clip)"

    p = sub.add_parser("info", parents=[common], help="describe a BVH file",
                       description="Print the skeleton (joint table: index, name, parent, channels, offset; End Sites), "
                                   "the frames, fps, frame time and duration, and the bounding box of all joint and "
                                   "End Site positions over all frames (forward kinematics).")
    p.add_argument("file", nargs="?", metavar="FILE.bvh", help=file_help)
    p.set_defaults(func=_cmd_info)

    p = sub.add_parser("fk", parents=[common], help="forward kinematics of every frame to an .npz",
                       description="Forward kinematics of every frame in one batched call "
                                   "(jax.jit(jax.vmap(forward_kinematics))), written as an .npz with joint_names [J], "
                                   "parents [J], positions [F,J,3], rotations [F,J,3,3] (global, file joint order, "
                                   "file units), end_site_names [E], end_site_positions [F,E,3], frame_time, and "
                                   "offsets, channels, end_site_parents, end_site_offsets.")
    p.add_argument("file", nargs="?", metavar="FILE.bvh", help=file_help)
    p.add_argument("--out", "-o", metavar="OUT.npz", help="output file (default: <name>.fk.npz here)")
    p.set_defaults(func=_cmd_fk)

    p = sub.add_parser("plot", parents=[common], help="draw one frame as a stick figure (PNG)",
                       description="Draw the stick figure of one frame (needs matplotlib: jaxanim[plot]).")
    p.add_argument("file", nargs="?", metavar="FILE.bvh", help=file_help)
    p.add_argument("--frame", "-f", type=int, default=0, metavar="K", help="frame index, 0-based (default: 0)")
    p.add_argument("--out", "-o", metavar="OUT.png", help="output file (default: <name>_frame<K>.png here)")
    p.set_defaults(func=_cmd_plot)

    p = sub.add_parser("ik", parents=[common], help="edit a clip by inverse kinematics on every frame (BVH out)",
                       description="Solve IK on every frame at once (vmap over frames, warm-started from the clip) "
                                   "and write the edited clip as BVH on the same skeleton and channels. TARGETS.json: "
                                   '{"pin": NAME or null, "root_translation": "free" | "fixed", "frozen": [NAME, ...], '
                                   '"targets": [{"joint": NAME, "position": [x,y,z] or one per frame, '
                                   '"orientation": [w,x,y,z] or one per frame (optional), "weight": number}]}.')
    p.add_argument("file", nargs="?", metavar="FILE.bvh", help=file_help)
    p.add_argument("--targets", "-t", required=True, metavar="TARGETS.json", help="the IK targets (see above)")
    p.add_argument("--out", "-o", metavar="OUT.bvh", help="output file (default: <name>.ik.bvh here)")
    p.set_defaults(func=_cmd_ik)

    p = sub.add_parser("demo", parents=[common], help="run the pipeline on the shipped clip, with timings",
                       description="Load the shipped walk clip, run forward kinematics of all frames in one batched "
                                   "call, write demo_fk.npz and demo_pose.png, and print a summary with timings "
                                   "(parse, compile separate from run, µs per frame).")
    p.add_argument("--out-dir", "-d", default="jaxanim_demo", metavar="DIR",
                   help="where to write demo_fk.npz and demo_pose.png (created; default: ./jaxanim_demo)")
    p.set_defaults(func=_cmd_demo)
    return parser


def _version() -> str:
    from . import __version__

    return __version__


def main(argv: list[str] | None = None) -> int:
    """Run the ``jaxanim`` command line; returns the exit status (0 ok, 2 bad input).

    Args:
        argv: the arguments after the program name (default ``sys.argv[1:]``).
    """
    parser = _build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, usage errors (argparse printed the message)
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    ui = _UI(quiet=args.quiet)
    # float64 needs x64. Switching it on and off inside one process is not safe in jax 0.10 (a NumPy
    # index array used in both modes then fails with an int32/int64 mismatch), so it is switched
    # on and left on, and --float32 casts the parsed arrays instead of switching it off.
    if not args.float32 and not jax.config.jax_enable_x64:
        jax.config.update("jax_enable_x64", True)
    args.dtype = np.float32 if args.float32 else np.float64
    try:
        return args.func(args, ui)
    except BVHParseError as exc:
        ui.error(f"{exc.path}:{exc.line}: {exc.message}" if exc.line > 0 else f"{exc.path}: {exc.message}")
    except JaxanimError as exc:
        ui.error(str(exc))
    except OSError as exc:  # an output that cannot be written
        name = exc.filename if exc.filename is not None else ""
        ui.error(f"{name}: {exc.strerror or exc}" if name else str(exc))
    except KeyboardInterrupt:
        ui.error("interrupted")
        return 130
    return 2


if __name__ == "__main__":
    sys.exit(main())
