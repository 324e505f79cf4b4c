"""The ``jaxanim`` command line on BVH files: ``info``, ``fk``, ``plot``, ``ik``, ``simulate``, ``track``, ``blend``,
``loop``, ``match``, ``skin``, ``render``, ``view`` and ``demo``.

Every command takes an optional BVH file and uses the shipped default clip (a walk, see
:mod:`jaxanim.default_clip`) without one. An ``.npz`` in place of the BVH file is read as an AMASS clip
(:func:`jaxanim.skeleton.read_amass`, Y up) with the body model given by ``--body-model MODEL``; without
it the command exits 2 saying where to get one. Computation is float64 unless ``--float32`` is given:
:func:`main` switches ``jax_enable_x64`` on before computing and leaves it on (toggling it back and
forth inside one process is not safe with jax 0.10), while ``--float32`` leaves the setting alone
and casts the parsed clip to float32. Forward kinematics of a whole clip is one batched call,
``jax.jit(jax.vmap(forward_kinematics, in_axes=(None, 0, 0)))`` (:func:`batched_fk`).

Bad input (an unreadable or malformed BVH file, a frame out of range, an output that cannot be
written) prints ``error: <path>:<line>: <message>`` (or ``error: <message>``) on stderr and exits
with status 2, never with a traceback. Progress lines go to stderr, results to stdout; ``--quiet``
keeps only the errors and the output a command exists for (the ``info`` report).

``simulate`` builds the physics character of the clip (:func:`jaxanim.character.build_character`)
and tracks the clip with stable PD plus the root servo (:func:`jaxanim.character.tracking_controller`)
in one compiled :func:`jaxanim.physics.rollout`. The step is ``frame_time / k`` with ``k =
max(1, round(frame_time / dt))``, so that every ``k``-th state falls exactly on a frame of the clip
(``--dt`` is adjusted to that when it does not divide the frame period, and a progress line says
so); those states are written, as BVH on the same skeleton at the clip's frame time, with the
start pose as frame 0. A rollout that ends ``nonfinite`` or ``exploded`` still writes its frames
(held at the last good state) and exits with status 1.

``demo`` runs a list of steps (:data:`DEMO_STEPS`), a tour of the suite; later features append theirs to it.

The commands live beside this module: :mod:`._simulate` (``simulate``), :mod:`._track` (``track``),
:mod:`._motion` (``blend``, ``loop``), :mod:`._match` (``match``), :mod:`._skin` (``skin``),
:mod:`._render` (``render``), :mod:`._view` (``view``), :mod:`._demo` (``demo``),
:mod:`._common` (output, loading, batched FK); this module holds ``info``, ``fk``, ``ik``, ``plot``,
the parser and :func:`main`, and re-exports the others' names, so ``jaxanim.cli`` (the 0.1 path)
still offers them.

Every command keeps JAX's compiled programs in a persistent cache (:mod:`._cache`): at
``$XDG_CACHE_HOME/jaxanim`` or ``~/.cache/jaxanim``, or ``$JAX_COMPILATION_CACHE_DIR``; the global
flag ``--no-compile-cache`` turns it off. :func:`main` sets the cache up for the command and puts
JAX's settings back when it returns; importing jaxanim leaves them alone.
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import numpy as np

from .._errors import BVHParseError, JaxanimError
from ..kinematics._fk import forward_kinematics  # noqa: F401  (the 0.1 ``jaxanim.cli`` offered it)
from ..skeleton._bvh import write_bvh
from ..skeleton._skeleton import POSITION_CHANNELS
from . import _cache
from ._track import add_track_parser
from ._motion import add_motion_parsers
from ._match import add_match_parser
from ._render import add_render_parser
from ._retarget import add_retarget_parser
from ._retarget_map import add_retarget_map_parser
from ._view import add_view_parser
from ._skin import add_skin_parser
from ._common import _body_model
from ._common import (  # the 0.1 module held these: ``jaxanim.cli`` still offers them
    _PROG as _PROG,
    _UI as _UI,
    _as_dtype as _as_dtype,
    _check_frame as _check_frame,
    _Clip as _Clip,
    _clip_fk as _clip_fk,
    _duration as _duration,
    _fk_arrays as _fk_arrays,
    _FKRun as _FKRun,
    _load as _load,
    _ms as _ms,
    _num as _num,
    _plot as _plot,
    _save_npz as _save_npz,
    batched_fk as batched_fk,
)
from ._demo import (
    _DEMO_TIMING_REPEATS as _DEMO_TIMING_REPEATS,
    DEMO_STEPS as DEMO_STEPS,
    DemoState as DemoState,
    _cmd_demo as _cmd_demo,
    _demo_fk as _demo_fk,
    _demo_load as _demo_load,
    _demo_plot as _demo_plot,
    _demo_save_fk as _demo_save_fk,
)
from ._simulate import (
    _SIM_CONTACTS as _SIM_CONTACTS,
    _SIM_CONTROLLERS as _SIM_CONTROLLERS,
    _check_number as _check_number,
    _check_writable as _check_writable,
    _cmd_simulate as _cmd_simulate,
    _looped_motion as _looped_motion,
    _plot_simulation as _plot_simulation,
    _sim_plan as _sim_plan,
    _sim_status as _sim_status,
    _SimPlan as _SimPlan,
    _SimRun as _SimRun,
    _simulate as _simulate,
)

__all__ = ["DEMO_STEPS", "main"]


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
    out = args.out or f"{clip.stem}.fk.npz"
    _check_writable("--out", out)
    run = _clip_fk(clip, ui)
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

    from ..ik import solve_ik_clip, targets_from_json

    clip = _load(args.file, ui, args.dtype)
    out = args.out or f"{clip.stem}.ik.bvh"
    _check_writable("--out", out)
    try:
        with open(args.targets, encoding="utf-8") as fh:
            data = json.load(fh)
    except json.JSONDecodeError as exc:
        raise JaxanimError(f"{args.targets}:{exc.lineno}: not valid JSON: {exc.msg}") from None
    except UnicodeDecodeError as exc:
        raise JaxanimError(f"{args.targets}: not UTF-8 text (byte {exc.start}): save the targets as UTF-8 "
                           "JSON") from None
    except OSError as exc:
        raise JaxanimError(f"{args.targets}: cannot read the file: {exc.strerror or exc}") from None
    targets, kwargs = targets_from_json(clip.skeleton, data, clip.motion.num_frames)
    ui.progress(f"IK on {clip.motion.num_frames} frames (one batched call)")
    t0 = time.perf_counter()
    edited, sol = solve_ik_clip(clip.skeleton, clip.motion, targets, **kwargs)
    jax.block_until_ready(edited)
    seconds = time.perf_counter() - t0
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
    _check_writable("--out", out)
    ui.progress(f"drawing frame {args.frame} to {out}")
    _plot(clip, args.frame, out)
    ui.result(f"wrote {out} (frame {args.frame} of {clip.motion.num_frames})")
    return 0


# ------------------------------------------------------------------------------------------------
# Parser and entry point
# ------------------------------------------------------------------------------------------------
_DESCRIPTION = """\
jaxanim: physics-based character animation numerics in JAX.

Commands read a BVH file; without FILE they use the shipped default clip (a
procedural walk, 21 joints, meters, Y up, 120 frames at 30 fps). Computation is
float64 unless --float32. Bad input exits with status 2 and an
'error: <path>:<line>: <message>' line on stderr."""

_EPILOG = """\
examples:
  jaxanim info                         describe the shipped clip
  jaxanim info walk.bvh                joints, End Sites, frames, bounding box
  jaxanim fk walk.bvh --out walk.npz   global transforms of every frame
  jaxanim plot walk.bvh --frame 10 --out pose.png
  jaxanim simulate walk.bvh --seconds 5 --out sim.bvh --plot
                                       track the clip with stable PD (physics)
  jaxanim track walk.bvh --seconds 4 --out trk.bvh
                                       track the clip on joint torques only
  jaxanim render walk.bvh --compare trk.bvh --out cmp.gif
                                       the clip beside its simulation
  jaxanim demo --out-dir results       a tour of the suite with timings"""


def _add_global_flags(p: argparse.ArgumentParser, default) -> None:
    p.add_argument("--float32", action="store_true", default=default,
                   help="compute in float32 (default: float64, with jax_enable_x64 switched on)")
    p.add_argument("--quiet", "-q", action="store_true", default=default,
                   help="no progress or result lines, only errors and the info report")
    p.add_argument("--no-compile-cache", action="store_true", default=default,
                   help="do not keep compiled programs on disk (default: kept in $XDG_CACHE_HOME/jaxanim or "
                        "~/.cache/jaxanim, or $JAX_COMPILATION_CACHE_DIR; clear it with rm -rf ~/.cache/jaxanim)")
    p.add_argument("--body-model", metavar="MODEL", default=None if default is False else default,
                   help="the SMPL / SMPL+H / SMPL-X body model (.npz or .pkl, as distributed by its project website "
                        "after registering) that an AMASS .npz clip was fitted with: a FILE.npz is read as an AMASS "
                        "clip with it")


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

    p = sub.add_parser("simulate", parents=[common], help="track a clip with a simulated character (BVH out)",
                       description="Build the physics character of the clip (one rigid body per bone group, ball "
                                   "joints, 70 kg, ground contact) and track the clip (looping it, with the root moved "
                                   "on, if it is shorter than --seconds) with stable PD on every joint plus a root "
                                   "force and torque servo unless --no-root-force. The step is the frame time / k, "
                                   "k = round(frame time / --dt), so every k-th state is a frame of the clip (--dt is "
                                   "adjusted to that); the simulated motion is written as BVH on the same skeleton at "
                                   "the clip's frame rate, round(seconds x fps) frames starting at the clip's first "
                                   "pose. Prints the rollout status (successful, nonfinite or exploded: exit status "
                                   "1), the mean joint error against the clip and the compile and run times.")
    p.add_argument("file", nargs="?", metavar="FILE.bvh", help=file_help)
    p.add_argument("--controller", choices=_SIM_CONTROLLERS, default="spd",
                   help="the tracking controller: spd (stable PD, the default)")
    p.add_argument("--seconds", "-s", type=float, default=None, metavar="S",
                   help="simulated duration (default: the clip's duration)")
    p.add_argument("--dt", type=float, default=1 / 120, metavar="H",
                   help="physics step in seconds (default 1/120; made to divide the frame time)")
    p.add_argument("--kp", type=float, default=500.0, help="joint stiffness, N m / rad (default 500)")
    p.add_argument("--kd", type=float, default=50.0, help="joint damping, N m s / rad (default 50)")
    p.add_argument("--no-root-force", action="store_true",
                   help="no root servo (no \"hand of God\"): the character must balance on the joint torques alone")
    p.add_argument("--contact", choices=_SIM_CONTACTS, default="complementarity",
                   help="ground contact model (default: complementarity; penalty needs a small --dt)")
    p.add_argument("--out", "-o", metavar="OUT.bvh", help="output file (default: <name>.sim.bvh here)")
    p.add_argument("--plot", nargs="?", const="", default=None, metavar="OUT.png",
                   help="also draw the CoM height and the mean joint error over time "
                        "(default file: OUT with .png; needs matplotlib)")
    p.set_defaults(func=_cmd_simulate)

    add_track_parser(sub, common, file_help)
    add_motion_parsers(sub, common, file_help)
    add_match_parser(sub, common)
    add_render_parser(sub, common)
    add_retarget_parser(sub, common)
    add_retarget_map_parser(sub, common)
    add_view_parser(sub, common)
    add_skin_parser(sub, common)

    p = sub.add_parser("demo", parents=[common], help="a tour of the suite on the shipped clip, with timings",
                       description="A tour on the shipped walk clip, each step with its timings and a picture: "
                                   "load; forward kinematics of all frames in one batched call (demo_fk.npz, "
                                   "demo_pose.png); an IK edit of every frame (demo_ik.png); 2 s tracked without "
                                   "root force (demo_track.bvh, demo_track.png); LBS and DQS skinning "
                                   "(demo_skin.gif); the clip beside its simulation (demo_compare.gif). About a "
                                   "minute on two cores, most of it compiling the tracking search.")
    p.add_argument("--out-dir", "-d", default="jaxanim_demo", metavar="DIR",
                   help="where to write the demo's files (created; default: ./jaxanim_demo)")
    p.set_defaults(func=_cmd_demo)
    return parser


def _version() -> str:
    from .._version import __version__

    return __version__


def main(argv: list[str] | None = None) -> int:
    """Run the ``jaxanim`` command line; returns the exit status (0 ok, 2 bad input, 1 a simulation that
    did not finish: ``simulate``'s rollout ended ``nonfinite`` or ``exploded``, or ``track``'s character fell).

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
        with _cache.compile_cache(None if args.no_compile_cache else _cache.compile_cache_dir()), \
                _body_model(args.body_model):
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
