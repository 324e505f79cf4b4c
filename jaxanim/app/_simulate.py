"""``jaxanim simulate``: track a clip with the physics character and write the simulated motion as BVH."""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import pathlib
import time

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import JaxanimError
from .._linalg import COMPILER_OPTIONS
from ..skeleton._bvh import write_bvh
from ..skeleton._skeleton import Motion
from ._common import _UI, _Clip, _duration, _load, _ms, _num

_SIM_CONTROLLERS = ("spd",)
_SIM_CONTACTS = ("complementarity", "penalty", "none")


# ------------------------------------------------------------------------------------------------
# The frame / step plan and the looped clip
# ------------------------------------------------------------------------------------------------


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
    if (frames - 1) * k > MAX_STEPS:
        raise JaxanimError(f"--dt {dt:g}: {seconds:g} s at that step is {(frames - 1) * k:,} physics steps, more "
                           f"than {MAX_STEPS:,}: use a larger --dt (the frame time is {_num(frame_time)} s) or fewer "
                           "--seconds")
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


# ------------------------------------------------------------------------------------------------
# The rollout
# ------------------------------------------------------------------------------------------------


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
    from ..physics import SimResult

    for name in ("successful", "nonfinite", "exploded"):
        if bool(result == getattr(SimResult, name)):
            return name, SimResult[result]
    return "unknown", ""


def _simulate(clip: _Clip, args: argparse.Namespace, plan: _SimPlan, ui: _UI) -> _SimRun:
    """Build the character, compile the rollout and the pose / CoM / error maps, run them."""
    from .. import character
    from ..physics import bodies_center_of_mass, joint_errors, make_ground, rollout

    reference = _looped_motion(clip.motion, plan.frames)
    ui.progress(f"building the character ({args.contact} contact) and the controller")
    t0 = time.perf_counter()
    char, state0 = character.build_character(clip.skeleton, reference.rotations[0], reference.translations[0],
                                             ground=make_ground(args.contact, dtype=jnp.float64))
    ctrl, gains = character.tracking_controller(char, reference, plan.dt, kp=args.kp, kd=args.kd,
                                                root_force=not args.no_root_force)
    # Strongly typed gains: 0.0 (no root force) and a computed gain then make the same program, so
    # the persistent cache serves both (a weakly typed scalar would change the cache key).
    gains = jax.tree.map(lambda x: jnp.asarray(x, x.dtype), gains)
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
        com_y = jax.vmap(lambda s: bodies_center_of_mass(char.model.bodies, s)[0][1])(traj)
        return q, t, com_y, err, run.result, run.num_steps

    call_args = (state0, gains, reference)
    ui.progress(f"compiling the rollout: {plan.steps} steps of {_ms(plan.dt)}, recording every {plan.k}")
    t0 = time.perf_counter()
    compiled = jax.jit(simulate, compiler_options=COMPILER_OPTIONS or None).lower(*call_args).compile()
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


# ------------------------------------------------------------------------------------------------
# The command
# ------------------------------------------------------------------------------------------------


def _check_number(flag: str, value: float, *, zero_ok: bool = False) -> None:
    """A finite number, positive (or non-negative with ``zero_ok``)."""
    if not (math.isfinite(value) and (value >= 0 if zero_ok else value > 0)):
        raise JaxanimError(f"{flag}: expected a {'non-negative' if zero_ok else 'positive'} finite number, "
                           f"got {value:g}")


#: The longest ``--seconds`` of the commands that simulate or match (an hour): ``--seconds 1e9`` asked for
#: hundreds of GiB, and the CLI writes every frame it computes.
MAX_SECONDS = 3600.0
#: The most physics steps of one ``simulate`` (``--dt 1e-9`` planned 166 million and hung).
MAX_STEPS = 10_000_000


def _check_seconds(value: float) -> None:
    """``--seconds``: a positive finite number, at most :data:`MAX_SECONDS`."""
    if not (math.isfinite(value) and 0 < value <= MAX_SECONDS):
        raise JaxanimError(f"--seconds: expected a positive finite number, got {value:g} (at most "
                           f"{MAX_SECONDS:g}: an hour)")


def _check_writable(flag: str, path: str) -> None:
    """Refuse an output path before any work: a folder, a missing or unwritable folder, an unwritable file."""
    target = pathlib.Path(path)
    parent = target.resolve().parent
    if target.is_dir():
        raise JaxanimError(f"{flag} {path}: cannot write it: it is a directory (give a file name)")
    if not parent.is_dir():
        raise JaxanimError(f"{flag} {path}: cannot write it: the directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK) or (target.exists() and not os.access(target, os.W_OK)):
        raise JaxanimError(f"{flag} {path}: cannot write it: permission denied")


def _cmd_simulate(args: argparse.Namespace, ui: _UI) -> int:
    if args.float32:
        raise JaxanimError("simulate: --float32 is not supported (the physics runs in float64)")
    if args.seconds is not None:
        _check_seconds(args.seconds)
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
