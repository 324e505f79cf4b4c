"""The ``jaxanim`` command line: ``info``, ``fk``, ``plot``, ``ik``, ``simulate`` and ``demo`` on BVH files.

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

``simulate`` builds the physics character of the clip (:func:`jaxanim.character.build_character`)
and tracks the clip with stable PD plus the root servo (:func:`jaxanim.character.tracking_controller`)
in one compiled :func:`jaxanim.physics.rollout`. The step is ``frame_time / k`` with ``k =
max(1, round(frame_time / dt))``, so that every ``k``-th state falls exactly on a frame of the clip
(``--dt`` is adjusted to that when it does not divide the frame period, and a progress line says
so); those states are written, as BVH on the same skeleton at the clip's frame time, with the
start pose as frame 0. A rollout that ends ``nonfinite`` or ``exploded`` still writes its frames
(held at the last good state) and exits with status 1.

``demo`` runs a list of steps (:data:`DEMO_STEPS`); later features append theirs to it.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import os
import pathlib
import statistics
import sys
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import BVHParseError, JaxanimError
from ..skeleton._bvh import read_bvh, write_bvh
from ..skeleton._default_clip import default_clip_path
from ..kinematics._fk import FKResult, forward_kinematics
from ..skeleton._skeleton import POSITION_CHANNELS, Motion, Skeleton

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


def _duration(seconds: float) -> str:
    return f"{seconds:.2f} s" if seconds >= 1.0 else _ms(seconds)


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
    from ._plot import save_pose_png  # matplotlib is optional: import it only to plot

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

    from ..skeleton._bvh import write_bvh
    from ..ik._solve import solve_ik_clip, targets_from_json

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


# --- simulate: track the clip with the physics character ----------------------------------------------
_SIM_CONTROLLERS = ("spd",)
_SIM_CONTACTS = ("complementarity", "penalty", "none")


@dataclasses.dataclass
class _SimPlan:
    """How the rollout maps onto the clip's frames."""

    frames: int  # frames written; frame 0 is the start pose, frame i is at i * frame_time
    k: int  # physics steps per frame
    dt: float  # the step used: frame_time / k
    steps: int  # (frames - 1) * k


def _sim_plan(seconds: float, dt: float, frame_time: float) -> _SimPlan:
    """Frames ``round(seconds * fps)`` and the step ``frame_time / k``, ``k = max(1, round(frame_time / dt))``."""
    fps = 1.0 / frame_time
    frames = int(round(seconds * fps))
    if frames < 2:
        raise JaxanimError(f"--seconds {seconds:g} is shorter than two frames of the clip at {_num(fps)} fps "
                           f"(use at least {_num(1.5 * frame_time)} s)")
    k = max(1, int(round(frame_time / dt)))
    return _SimPlan(frames=frames, k=k, dt=frame_time / k, steps=(frames - 1) * k)


def _looped_motion(motion: Motion, frames: int) -> Motion:
    """``frames`` frames of the clip, looped: loop ``n`` repeats the clip with the root moved on
    horizontally (X and Z, BVH's Y is up) by ``n`` times the clip's displacement, last frame minus first
    plus one more frame's step, so a walk carries on instead of jumping back to its start."""
    F = motion.num_frames
    idx = np.arange(frames)
    loop = (idx // F).astype(np.float64)
    rotations = motion.rotations[idx % F]
    translations = motion.translations[idx % F]
    if frames > F and F >= 2:
        root = np.asarray(motion.translations[:, 0], np.float64)
        step = (root[-1] - root[0]) + (root[-1] - root[-2])
        step[1] = 0.0
        shift = np.zeros((frames, motion.num_joints, 3))
        shift[:, 0] = loop[:, None] * step[None, :]
        translations = translations + jnp.asarray(shift, translations.dtype)
    return Motion(rotations, translations, motion.frame_time)


@dataclasses.dataclass
class _SimRun:
    """What :func:`_simulate` returns: the written frames, their diagnostics, the status and timings."""

    motion: Motion  # the simulated clip (file units, the clip's frame time)
    com_height: np.ndarray  # [frames] meters
    error: np.ndarray  # [frames] mean joint rotation error, radians
    ok: bool
    status: str  # "successful", "nonfinite" or "exploded"
    message: str
    steps_done: int
    setup_seconds: float  # build_character + tracking_controller (op by op: the first call compiles each op)
    compile_seconds: float
    run_seconds: float


def _sim_status(result) -> tuple[str, str]:
    from ..physics._model import SimResult

    for name in ("successful", "nonfinite", "exploded"):
        if bool(result == getattr(SimResult, name)):
            return name, SimResult[result]
    return "unknown", ""


def _simulate(clip: _Clip, args: argparse.Namespace, plan: _SimPlan, ui: _UI) -> _SimRun:
    """Build the character, compile the rollout and the pose / CoM / error maps, run them."""
    from .. import character
    from ..physics._contact import make_ground
    from ..character._balance import center_of_mass
    from ..character._pd import joint_errors
    from ..physics._model import rollout

    reference = _looped_motion(clip.motion, plan.frames)
    ui.progress(f"building the character ({args.contact} contact) and the controller")
    t0 = time.perf_counter()
    char, state0 = character.build_character(clip.skeleton, reference.rotations[0], reference.translations[0],
                                             ground=make_ground(args.contact, dtype=jnp.float64))
    ctrl, gains = character.tracking_controller(char, reference, plan.dt, kp=args.kp, kd=args.kd,
                                                root_force=not args.no_root_force)
    jax.block_until_ready(gains)
    setup_seconds = time.perf_counter() - t0

    def simulate(state0, gains, reference):
        run = rollout(char.model, state0, plan.dt, plan.steps, record_every=plan.k, controller=ctrl,
                      controller_args=gains)
        traj = jax.tree.map(lambda a0, a: jnp.concatenate([a0[None], a]), state0, run.trajectory)
        q, t = jax.vmap(lambda s, r: character.character_pose(char, s, reference=r))(traj, reference.rotations)
        targets = jax.vmap(lambda r, tr: character.spd_targets(char, r, tr))(
            reference.rotations, reference.translations)
        err = jax.vmap(lambda s, tg: jnp.mean(jnp.linalg.norm(joint_errors(char.model.joints, s, tg)[0], axis=-1)))(
            traj, targets)
        com_y = jax.vmap(lambda s: center_of_mass(char.model.bodies, s)[0][1])(traj)
        return q, t, com_y, err, run.result, run.num_steps

    call_args = (state0, gains, reference)
    ui.progress(f"compiling the rollout: {plan.steps} steps of {_ms(plan.dt)}, recording every {plan.k}")
    t0 = time.perf_counter()
    compiled = jax.jit(simulate).lower(*call_args).compile()
    compile_seconds = time.perf_counter() - t0
    ui.progress(f"simulating {_num(plan.steps * plan.dt)} s")
    t0 = time.perf_counter()
    q, t, com_y, err, result, steps_done = jax.block_until_ready(compiled(*call_args))
    run_seconds = time.perf_counter() - t0
    status, message = _sim_status(result)
    return _SimRun(
        motion=Motion(q, t, clip.motion.frame_time), com_height=np.asarray(com_y), error=np.asarray(err),
        ok=status == "successful", status=status, message=message, steps_done=int(steps_done),
        setup_seconds=setup_seconds, compile_seconds=compile_seconds, run_seconds=run_seconds,
    )


def _plot_simulation(path, run: _SimRun, frame_time: float, title: str) -> None:
    """Two panels over time: the center of mass height (m) and the mean joint error (degrees)."""
    from ._plot import _import_matplotlib

    _import_matplotlib(pyplot=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.0, 5.0), layout="constrained")
    FigureCanvasAgg(fig)
    ax_com, ax_err = fig.subplots(2, 1, sharex=True)
    t = np.arange(run.com_height.shape[0]) * frame_time
    ax_com.plot(t, run.com_height, color="tab:blue")
    ax_com.set_ylabel("CoM height (m)")
    ax_com.set_title(title)
    ax_com.grid(True, alpha=0.3)
    ax_err.plot(t, np.degrees(run.error), color="tab:red")
    ax_err.set_ylabel("mean joint error (deg)")
    ax_err.set_xlabel("time (s)")
    ax_err.grid(True, alpha=0.3)
    fig.savefig(path, dpi=100, format="png")


def _check_number(flag: str, value: float, *, zero_ok: bool = False) -> None:
    """A finite number, positive (or non-negative with ``zero_ok``)."""
    if not (math.isfinite(value) and (value >= 0 if zero_ok else value > 0)):
        raise JaxanimError(f"{flag}: expected a {'non-negative' if zero_ok else 'positive'} finite number, "
                           f"got {value:g}")


def _check_writable(flag: str, path: str) -> None:
    parent = pathlib.Path(path).resolve().parent
    if not parent.is_dir():
        raise JaxanimError(f"{flag} {path}: cannot write it: the directory {parent} does not exist")


def _cmd_simulate(args: argparse.Namespace, ui: _UI) -> int:
    if args.float32:
        raise JaxanimError("simulate: --float32 is not supported (the physics runs in float64)")
    if args.seconds is not None:
        _check_number("--seconds", args.seconds)
    _check_number("--dt", args.dt)
    _check_number("--kp", args.kp, zero_ok=True)
    _check_number("--kd", args.kd, zero_ok=True)
    clip = _load(args.file, ui, args.dtype)
    if clip.motion.num_frames == 0:
        raise JaxanimError(f"{clip.label} has no frames: nothing to track")
    out = args.out or f"{clip.stem}.sim.bvh"
    plot = None if args.plot is None else (args.plot or str(pathlib.Path(out).with_suffix(".png")))
    _check_writable("--out", out)
    if plot is not None:
        _check_writable("--plot", plot)
        from ._plot import _import_matplotlib

        _import_matplotlib(pyplot=False)  # fail before simulating when matplotlib is missing
    frame_time = float(clip.motion.frame_time)
    seconds = clip.motion.num_frames * frame_time if args.seconds is None else args.seconds
    plan = _sim_plan(seconds, args.dt, frame_time)
    if abs(plan.dt - args.dt) > 1e-3 * args.dt:  # not for the rounding of the file's frame time
        ui.progress(f"--dt {args.dt:g} does not divide the frame time {_num(frame_time)} s: using "
                    f"dt = frame time / {plan.k} = {_num(plan.dt)} s")
    if plan.frames > clip.motion.num_frames:
        ui.progress(f"looping the clip: {plan.frames} frames from {clip.motion.num_frames}")
    run = _simulate(clip, args, plan, ui)
    ui.progress(f"writing {out}")
    write_bvh(out, clip.skeleton, run.motion)
    setup = (f"{args.controller} kp {args.kp:g} kd {args.kd:g}, {'no ' if args.no_root_force else ''}root force, "
             f"{args.contact} contact")
    if plot is not None:
        ui.progress(f"drawing {plot}")
        _plot_simulation(plot, run, frame_time, f"{clip.path.name}: {setup}")
    err = run.error[1:]  # frame 0 is the start pose, the clip's first frame
    com = run.com_height
    ui.result("\n".join([
        f"wrote {out}: {plan.frames} frames at {_num(1.0 / frame_time)} fps "
        f"({_num(plan.frames * frame_time)} s, frames x frame time), {clip.skeleton.num_joints} joints"
        + (f"; plot {plot}" if plot is not None else ""),
        f"rollout {run.status}: {run.steps_done}/{plan.steps} steps of {_ms(plan.dt)} ({plan.k} per frame), {setup}",
        f"tracking error (joint rotation vs the clip) mean {float(err.mean()):.4f} rad "
        f"({np.degrees(float(err.mean())):.2f}°), max {float(err.max()):.4f} rad; CoM height {com[0]:.3f} m at the "
        f"start, {com[-1]:.3f} m at the end, min {com.min():.3f} m",
        f"parse {_ms(clip.parse_seconds)}, character and controller {_duration(run.setup_seconds)}, "
        f"rollout compile {_duration(run.compile_seconds)}, run {_duration(run.run_seconds)} "
        f"({run.run_seconds / plan.steps * 1e3:.2f} ms per step)",
    ]))
    if not run.ok:
        ui.error(f"the rollout stopped after {run.steps_done} of {plan.steps} steps ({run.status}): {run.message} "
                 f"The frames after that hold the last good state.")
        return 1
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

    p = sub.add_parser("demo", parents=[common], help="run the pipeline on the shipped clip, with timings",
                       description="Load the shipped walk clip, run forward kinematics of all frames in one batched "
                                   "call, write demo_fk.npz and demo_pose.png, and print a summary with timings "
                                   "(parse, compile separate from run, µs per frame).")
    p.add_argument("--out-dir", "-d", default="jaxanim_demo", metavar="DIR",
                   help="where to write demo_fk.npz and demo_pose.png (created; default: ./jaxanim_demo)")
    p.set_defaults(func=_cmd_demo)
    return parser


def _version() -> str:
    from .._version import __version__

    return __version__


def main(argv: list[str] | None = None) -> int:
    """Run the ``jaxanim`` command line; returns the exit status (0 ok, 2 bad input, 1 a simulation that
    did not finish: ``simulate``'s rollout ended ``nonfinite`` or ``exploded``).

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
