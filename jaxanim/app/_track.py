"""``jaxanim track``: track a clip with the physics character on joint torques only (no root force),
by sampling-based control (:func:`jaxanim.tracking.samcon`), and write the simulated motion as BVH."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import JaxanimError
from ..skeleton._bvh import write_bvh
from ..skeleton._skeleton import Motion
from ._common import _UI, _Clip, _duration, _load, _num
from ._simulate import _check_seconds, _check_writable, _looped_motion

_TRACK_CONTACTS = ("complementarity", "penalty")
_PUSH_SECONDS = 0.2


def _progress(ui: _UI):
    """A ``progress(window, windows)`` callback that redraws one line on stderr."""
    start = time.perf_counter()

    tty = sys.stderr.isatty()

    def show(i: int, n: int) -> None:
        if ui.quiet:
            return
        elapsed = time.perf_counter() - start
        if tty:  # one line, redrawn
            print(f"\rjaxanim: window {i}/{n}, {elapsed:.1f} s", end="\n" if i == n else "", file=sys.stderr, flush=True)
        elif i == n or i % max(1, n // 10) == 0:  # a log: a line every tenth of the run
            print(f"jaxanim: window {i}/{n}, {elapsed:.1f} s", file=sys.stderr, flush=True)

    return show


def _cmd_track(args: argparse.Namespace, ui: _UI) -> int:
    if args.float32:
        raise JaxanimError("track: --float32 is not supported (the physics runs in float64)")
    _check_seconds(args.seconds)
    if args.samples < 2:
        raise JaxanimError(f"--samples: expected at least 2 samples per window, got {args.samples}")
    if args.contact not in _TRACK_CONTACTS:
        raise JaxanimError(f"--contact: expected one of {', '.join(_TRACK_CONTACTS)}, got {args.contact!r}")
    if args.push is not None and not (math.isfinite(args.push) and args.push >= 0):
        raise JaxanimError(f"--push: expected a non-negative force in newtons, got {args.push:g}")
    clip = _load(args.file, ui, args.dtype)
    if not 0 <= args.from_frame < clip.motion.num_frames:
        raise JaxanimError(f"--from-frame: expected a frame of {clip.label} in 0 .. {clip.motion.num_frames - 1}, "
                           f"got {args.from_frame}")
    motion = clip.motion
    if args.from_frame:
        motion = Motion(motion.rotations[args.from_frame:], motion.translations[args.from_frame:], motion.frame_time)
    out = args.out or f"{clip.stem}.track.bvh"
    _check_writable("--out", out)
    if args.plot is not None:
        _check_writable("--plot", args.plot)
        from ._plot import _import_matplotlib

        _import_matplotlib(pyplot=False)
    run = track_clip(clip, motion, args.seconds, args.samples, args.seed, args.contact, ui,
                     label=f"{clip.label} from frame {args.from_frame}")
    char, options, reference, result = run.char, run.options, run.reference, run.result
    frames, windows, seconds, frame_time = run.frames, run.windows, run.seconds, run.frame_time
    status = "fell" if bool(result.fell) else "successful"
    ui.progress(f"writing {out}")
    write_bvh(out, clip.skeleton, run.simulated_motion())
    joint_error = np.asarray(result.joint_error[1:])
    root_error = np.asarray(result.root_error[1:])  # meters
    samples = windows * options.samples
    lines = [
        f"wrote {out}: {frames} frames at {_num(1 / frame_time)} fps, {clip.skeleton.num_joints} joints",
        f"tracking {status}: mean joint error {joint_error.mean():.4f} rad ({np.degrees(joint_error.mean()):.2f}°), "
        f"max {joint_error.max():.4f} rad; mean horizontal root error {root_error.mean():.3f} m "
        f"(max {root_error.max():.3f} m)",
        f"time {_duration(seconds)} (compile included): {samples} samples, {samples / seconds:.0f} samples/s, "
        f"{samples * (options.window + options.lookahead) * options.steps_per_frame / seconds:.0f} character-steps/s "
        f"(each sample: {options.window} frames and {options.lookahead} of look-ahead)",
        _torque_line(char, result.torque, options.torque_limit),
    ]
    if args.push:
        lines += _push_report(args.push, char, reference, result, frames, frame_time, ui)
    if args.plot is not None:
        _plot_tracking(args.plot, result, reference, frame_time, char,
                       f"{clip.path.name}: samcon, {options.samples} samples, no root force")
        lines[0] += f"; plot {args.plot}"
    ui.result("\n".join(lines))
    if status == "fell":
        ui.error("the character fell (its root went below 0.7 x the clip's lowest root height)")
        return 1
    return 0


@dataclasses.dataclass
class TrackRun:
    """One search of :func:`track_clip`: the character, options, reference, result and sizes."""

    char: Any
    options: Any
    reference: Any
    motion: Motion  # the (looped) clip that was tracked
    result: Any
    frames: int
    windows: int
    frame_time: float
    seconds: float  # the search's wall time, compilation included

    def simulated_motion(self) -> Motion:
        """The simulated poses as a clip on the skeleton, in the clip's frame (the reference was lifted
        onto the ground; the lift is taken off again)."""
        from .. import character

        char = self.char
        pose = jax.jit(jax.vmap(lambda s, r: character.character_pose(char, s, reference=r)))
        q, t = pose(self.result.trajectory, self.motion.rotations)
        t = t.at[:, 0, 1].add(-np.asarray(self.reference.lift) / char.unit)
        return Motion(q, t, self.motion.frame_time)


def track_clip(clip: _Clip, motion: Motion, seconds: float, samples: int, seed: int, contact: str, ui: _UI, *,
               label: str | None = None) -> TrackRun:
    """Build the physics character of ``clip`` and run :func:`jaxanim.tracking.samcon` on ``seconds`` of
    ``motion`` (looped when longer), with progress on ``ui``: what ``jaxanim track`` and the demo run."""
    from .. import character, tracking
    from ..physics import make_ground

    ground = make_ground(contact, max_points=8 if contact == "complementarity" else None, iterations=10,
                         dtype=jnp.float64)
    char, _ = character.build_character(clip.skeleton, ground=ground)
    options = tracking.tracking_options(char, float(motion.frame_time), samples)
    if motion.num_frames < options.window + 1:
        raise JaxanimError(f"{label or clip.label} has {motion.num_frames} frames: too short for one control window "
                           f"of {options.window} frames (need at least {options.window + 1})")
    frame_time = float(motion.frame_time)
    frames = int(round(seconds / frame_time)) + 1
    windows = (frames - 1) // options.window
    if windows < 1:
        raise JaxanimError(f"--seconds {seconds:g} is shorter than one control window "
                           f"({options.window} frames = {_num(options.window * frame_time)} s)")
    frames = windows * options.window + 1
    if frames > motion.num_frames:
        ui.progress(f"looping the clip: {frames} frames from {motion.num_frames}")
    reference_motion = _looped_motion(motion, frames)
    t0 = time.perf_counter()
    reference = tracking.tracking_reference(char, reference_motion)
    ui.progress(f"tracking {_num((frames - 1) * frame_time)} s: {windows} windows of {options.window} frames, "
                f"{options.samples} samples each, seed {seed}, {contact} contact, no root force")
    result = tracking.samcon(char, reference, jax.random.PRNGKey(seed), options, progress=_progress(ui))
    jax.block_until_ready(result)
    return TrackRun(char, options, reference, reference_motion, result, frames, windows, frame_time,
                    time.perf_counter() - t0)


def _push_report(newtons: float, char, reference, result, frames: int, frame_time: float, ui: _UI) -> list[str]:
    """Compute the feedback gains, push the torso forward at mid-clip, with and without them: lines."""
    from .. import tracking
    from ..character._build import root_body

    ui.progress("feedback: linearizing the simulation along the tracked motion, time-varying LQR")
    t0 = time.perf_counter()
    result = jax.block_until_ready(tracking.feedback(char, reference, result))
    seconds = time.perf_counter() - t0
    v = np.asarray(reference.states.linear_velocity[:, root_body(char)])
    forward = v.mean(axis=0) * np.array([1.0, 0.0, 1.0])
    forward = forward / np.linalg.norm(forward) if np.linalg.norm(forward) > 1e-6 else np.array([0.0, 0.0, 1.0])
    mid = 0.5 * (frames - 1) * frame_time
    torso = tracking.torso_body(char)
    push = (torso, newtons * forward, mid, _PUSH_SECONDS)
    fell = {fb: bool(tracking.replay(char, reference, result, push=push, feedback=fb).fell) for fb in (False, True)}
    word = {True: "fell", False: "stood"}
    return [f"feedback gains: {frames - 1} frames, {_duration(seconds)} (compile included)",
            f"push {newtons:g} N forward on the torso ({char.model.bodies.names[torso]}) for {_PUSH_SECONDS} s at "
            f"{mid:.2f} s: open-loop controls {word[fell[False]]}, with the feedback gains {word[fell[True]]}"]


def _torque_line(char, torque, limit) -> str:
    """The largest joint torque of the run, against its joint's bound."""
    torque = np.asarray(torque)
    names = char.skeleton.names
    child = np.asarray(char.body_joint)[np.asarray(char.model.joints.child)]
    j = int(np.argmax(torque.max(axis=0) / (1.0 if limit is None else np.asarray(limit))))
    bound = "no torque limit" if limit is None else f"limit {np.broadcast_to(np.asarray(limit), torque.shape[1:])[j]:.0f} N m"
    return f"peak joint torque {torque[:, j].max():.0f} N m at {names[child[j]]} ({bound}; joint_torque_limits)"


def _plot_tracking(path, result, reference, frame_time: float, char, title: str) -> None:
    """Root height against the clip's, the mean joint error and the horizontal root error over time."""
    from ._plot import _import_matplotlib

    _import_matplotlib(pyplot=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..character._build import root_body

    fig = Figure(figsize=(8.0, 6.0), layout="constrained")
    FigureCanvasAgg(fig)
    ax_h, ax_e, ax_r = fig.subplots(3, 1, sharex=True)
    n = result.joint_error.shape[0]
    t = np.arange(n) * frame_time
    root = root_body(char)
    ax_h.plot(t, np.asarray(reference.states.position[:n, root, 1]), color="0.6", label="clip")
    ax_h.plot(t, np.asarray(result.trajectory.position[:, root, 1]), color="tab:blue", label="simulated")
    ax_h.set_ylabel("root height (m)")
    ax_h.legend(loc="lower right")
    ax_h.set_title(title)
    ax_e.plot(t, np.degrees(np.asarray(result.joint_error)), color="tab:red")
    ax_e.set_ylabel("mean joint error (deg)")
    ax_r.plot(t, np.asarray(result.root_error), color="tab:green")
    ax_r.set_ylabel("root error (m)")
    ax_r.set_xlabel("time (s)")
    for ax in (ax_h, ax_e, ax_r):
        ax.grid(True, alpha=0.3)
    fig.savefig(path, dpi=100, format="png")


def add_track_parser(sub, common, file_help: str) -> None:
    p = sub.add_parser("track", parents=[common], help="track a clip on joint torques only (no root force; BVH out)",
                       description="Build the physics character of the clip and search, window by window (0.1 s), "
                                   "for stable-PD target corrections that make it reproduce the clip with joint "
                                   "torques only: no root force or torque at any step (sampling-based control, "
                                   "jaxanim.tracking.samcon). The clip is looped when --seconds is longer. Writes the "
                                   "simulated motion as BVH at the clip's frame rate on the same skeleton, prints the "
                                   "tracking errors, the time and samples/s, and exits with status 1 if the "
                                   "character falls.")
    p.add_argument("file", nargs="?", metavar="FILE.bvh", help=file_help)
    p.add_argument("--seconds", "-s", type=float, required=True, metavar="S", help="duration to track")
    p.add_argument("--out", "-o", metavar="OUT.bvh", help="output file (default: <name>.track.bvh here)")
    p.add_argument("--samples", type=int, default=256, metavar="N", help="samples per window (default 256)")
    p.add_argument("--seed", type=int, default=0, metavar="K", help="random seed (default 0)")
    p.add_argument("--contact", default="complementarity", metavar="MODEL",
                   help="ground contact: complementarity (default) or penalty")
    p.add_argument("--plot", default=None, metavar="P.png",
                   help="draw the root height and the errors over time (needs matplotlib)")
    p.add_argument("--push", type=float, default=None, metavar="NEWTONS",
                   help="then compute the feedback gains (time-varying LQR around the tracked motion) and replay "
                        "with a forward push of this force on the torso for 0.2 s at mid-clip, with and without "
                        "the gains, and report whether the character stands")
    p.add_argument("--from-frame", type=int, default=0, metavar="F",
                   help="track from this frame of the file (default 0; e.g. 1 skips an added T-pose)")
    p.set_defaults(func=_cmd_track)

