"""``jaxanim demo``: the pipeline on the shipped clip, a list of steps (:data:`DEMO_STEPS`) with timings;
later features append theirs to it."""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ..skeleton._bvh import write_bvh
from ._common import _UI, _Clip, _clip_fk, _duration, _FKRun, _fk_arrays, _load, _ms, _num, _plot, _save_npz

_DEMO_TIMING_REPEATS = 20


@dataclasses.dataclass
class DemoState:
    """What the demo steps share: the options, the clip and what earlier steps computed."""

    out_dir: pathlib.Path
    ui: _UI
    dtype: type  # np.float64, or np.float32 with --float32
    clip: _Clip | None = None
    fk: _FKRun | None = None
    ik_motion: object | None = None  # the IK-edited Motion
    track: object | None = None  # the TrackRun of the tracking step
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


def _has_matplotlib(s: DemoState, step: str) -> bool:
    try:
        import matplotlib  # noqa: F401  (optional: the plot extra)
    except ImportError:
        s.rows.append((step, "picture skipped: matplotlib is not installed (pip install 'jaxanim[plot]')"))
        return False
    return True


def _side_by_side(path: pathlib.Path, skeleton, poses: list[tuple[str, object]], title: str) -> None:
    """One stick figure per ``(caption, FKResult)``, side by side on shared limits, as a PNG."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ._plot import plot_pose

    fig = Figure(figsize=(4.5 * len(poses), 5.0), layout="constrained")
    FigureCanvasAgg(fig)
    for i, (caption, fk) in enumerate(poses, start=1):
        plot_pose(skeleton, fk, ax=fig.add_subplot(1, len(poses), i, projection="3d"), title=caption)
    fig.suptitle(title)
    fig.savefig(path, dpi=90, format="png")


#: The IK edit of the demo: the right hand raised this far (metres) above where the clip puts it, on every frame.
_DEMO_IK_RAISE = 0.3


def _demo_ik(s: DemoState) -> None:
    """An IK edit of the whole clip in one batched call: the right hand raised, the only its arm moving."""
    from ..ik import Target, solve_ik_clip
    from ..kinematics._fk import forward_kinematics

    skel, motion = s.clip.skeleton, s.clip.motion
    hand = "RightHand_End" if "RightHand_End" in skel.end_site_names else skel.end_site_names[0]
    # only the arm that carries the hand moves (from the shoulder down); the rest stays as in the clip
    arm, j = set(), skel.end_site_parents[skel.end_site_names.index(hand)]
    for _ in range(4):
        arm.add(skel.names[j])
        j = skel.parents[j]
    frozen = tuple(n for n in skel.names if n not in arm)
    sites = s.fk.result.end_site_positions  # the FK step's, of every frame
    # the shipped clip is in metres, with y up
    goal = sites[:, skel.end_site_names.index(hand)] + jnp.asarray([[0.0, _DEMO_IK_RAISE, 0.0]], sites.dtype)
    target = Target(hand, position=goal)
    t0 = time.perf_counter()
    edited, sol = jax.block_until_ready(solve_ik_clip(skel, motion, target, frozen=frozen, root_translation="fixed"))
    cold = time.perf_counter() - t0
    t0 = time.perf_counter()
    jax.block_until_ready(solve_ik_clip(skel, motion, target, frozen=frozen, root_translation="fixed"))
    warm = time.perf_counter() - t0
    f = motion.num_frames
    ok = int(np.asarray(sol.success).sum())
    s.rows.append(("ik", f"raise {hand} by {_DEMO_IK_RAISE:g} m on all {f} frames, only its arm moving "
                         f"(solve_ik_clip, Levenberg-Marquardt): {ok}/{f} frames meet the target, max error "
                         f"{float(np.asarray(sol.position_errors).max()):.2g} (file units)"))
    s.rows.append(("", f"{_duration(cold)} with compilation, {_ms(warm)} warm = {warm / f * 1e3:.2f} ms per frame"))
    s.ik_motion = edited
    if _has_matplotlib(s, "ik"):
        out = s.out_dir / "demo_ik.png"
        k = f // 2
        poses = [(caption, forward_kinematics(skel, m.rotations[k], m.translations[k]))
                 for caption, m in (("the clip", motion), (f"{hand} raised {_DEMO_IK_RAISE:g} m", edited))]
        _side_by_side(out, skel, poses, f"IK edit, frame {k}")
        s.rows.append(("", f"wrote {out}"))


#: The tracking run of the demo: the shape that ``jaxanim track --seconds 2 --samples 64`` compiles (at 32 the
#: tracked trajectory was too loose for the default feedback gains to hold a push).
_DEMO_TRACK_SECONDS, _DEMO_TRACK_SAMPLES = 2.0, 64


#: What the demo calls standing: the character did not fall, its root ends within this height (m) of the clip's
#: root at the last frame, and its mean joint error is at most this (rad).
STOOD_ROOT_HEIGHT, STOOD_JOINT_ERROR = 0.05, 0.15


def _final_root_drop(run) -> float:
    """How far (m) the simulated root ends from the clip's root height at the last frame (along the ground's normal)."""
    from ..character import root_body

    root, normal = root_body(run.char), np.asarray(run.char.model.ground.normal, np.float64)
    sim = np.asarray(run.result.trajectory.position[-1, root], np.float64)
    ref = np.asarray(run.reference.states.position[-1, root], np.float64)
    return abs(float((sim - ref) @ normal))


def _demo_track(s: DemoState) -> None:
    """Tracking without root force: the sampling-based search on joint torques only."""
    from ._track import _plot_tracking, track_clip

    if s.dtype != np.float64:
        s.rows.append(("track", "skipped: the physics runs in float64 (drop --float32)"))
        return
    run = track_clip(s.clip, s.clip.motion, _DEMO_TRACK_SECONDS, _DEMO_TRACK_SAMPLES, 0, "complementarity", s.ui)
    r = run.result
    samples = run.windows * run.options.samples
    joint = float(np.asarray(r.joint_error[1:]).mean())
    drop = _final_root_drop(run)
    if bool(r.fell):
        status = "fell"
    elif drop <= STOOD_ROOT_HEIGHT and joint <= STOOD_JOINT_ERROR:
        status = "stood"
    else:
        status = "did not fall, but did not stand"
    s.rows.append(("track", f"{_DEMO_TRACK_SECONDS:g} s of the clip on joint torques only (tracking.samcon, "
                            f"{run.options.samples} samples per window, no root force): {status} (final root height "
                            f"{100 * drop:.1f} cm from the clip's, stood at most {100 * STOOD_ROOT_HEIGHT:g}; mean "
                            f"joint error {joint:.3f} rad, stood at most {STOOD_JOINT_ERROR:g}), root "
                            f"{float(np.asarray(r.root_error[1:]).mean()):.3f} m"))
    s.rows.append(("", f"{samples} samples simulated in {_duration(run.seconds)}, compilation included (more "
                       "samples track closer: jaxanim track --samples 256, as in the README)"))
    s.track = run
    bvh = s.out_dir / "demo_track.bvh"
    write_bvh(bvh, s.clip.skeleton, run.simulated_motion())
    s.rows.append(("", f"wrote {bvh}"))
    if _has_matplotlib(s, "track"):
        out = s.out_dir / "demo_track.png"
        _plot_tracking(out, r, run.reference, run.frame_time, run.char,
                       f"{s.clip.path.name}: samcon, {run.options.samples} samples, no root force")
        s.rows.append(("", f"wrote {out}"))


def _demo_skin(s: DemoState) -> None:
    """Skinning of every frame: the procedural capsule mesh, distance-to-bone weights, LBS and DQS."""
    from ..skinning import capsule_mesh, heuristic_weights, skin_motion

    skel, motion = s.clip.skeleton, s.clip.motion
    t0 = time.perf_counter()
    mesh = capsule_mesh(skel)
    weights = heuristic_weights(skel, mesh)
    setup = time.perf_counter() - t0
    v, f = mesh.vertices.shape[0], motion.num_frames
    s.rows.append(("skin", f"capsule mesh of {v} vertices, {mesh.faces.shape[0]} triangles, "
                           f"{weights.joints.shape[1]} bones per vertex (distance-to-bone weights): {_duration(setup)}"))
    for method in ("lbs", "dqs"):
        t0 = time.perf_counter()
        jax.block_until_ready(skin_motion(skel, motion, mesh, weights, method))
        cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        jax.block_until_ready(skin_motion(skel, motion, mesh, weights, method))
        warm = time.perf_counter() - t0
        s.rows.append(("", f"{method.upper()} of all {f} frames: {_duration(cold)} with compilation, {_ms(warm)} warm "
                           f"= {v * f / warm / 1e6:.1f} M vertex-frames/s"))
    if _has_matplotlib(s, "skin"):
        from ._render import render_clips

        out = s.out_dir / "demo_skin.gif"
        info = render_clips([s.clip], out, frames=(0, min(f, 30)), mesh=True)
        s.rows.append(("", f"wrote {out} ({info.frames} frames, the skinned mesh over the skeleton)"))


def _demo_render(s: DemoState) -> None:
    """The clip beside its simulation (the tracking step's), as an animated GIF."""
    if not _has_matplotlib(s, "render"):
        return
    from ._render import render_clips

    clips = [s.clip]
    if s.track is not None:
        simulated = s.track.simulated_motion()
        clips.append(_Clip(label="the simulation", path=s.out_dir / "demo_track.bvh", skeleton=s.clip.skeleton,
                           motion=simulated, parse_seconds=0.0))
    out = s.out_dir / "demo_compare.gif"
    t0 = time.perf_counter()
    info = render_clips(clips, out, frames=(0, clips[-1].motion.num_frames))
    what = "the clip beside its simulation without root force" if len(clips) == 2 else "the clip"
    s.rows.append(("render", f"wrote {out}: {what}, {info.frames} frames in {_duration(time.perf_counter() - t0)}"))


#: The frames of the clip the retarget step's picture shows.
_DEMO_RETARGET_FRAMES = 4


def _retarget_picture(path: pathlib.Path, npz: pathlib.Path, frames: list[int]) -> None:
    """A PNG of a retarget result at ``frames``, side by side: the robot from its collision geometry beside its
    source, drawn as ``jaxanim render RESULT.npz`` draws each frame."""
    from ._render import _DPI, _figure, _RetargetArtist
    from ._retarget_clip import load_retarget, retarget_scene

    clip = load_retarget(npz)
    scene = retarget_scene(clip)
    size = 320
    fig = _figure(size * len(frames), size)
    for i, f in enumerate(frames):
        artist = _RetargetArtist(fig.add_subplot(1, len(frames), i + 1, projection="3d"), f"frame {f}", scene,
                                 np.array([f]), "follow", size)
        artist.update(f, f * clip.frame_time)
        if i:
            artist.ax.get_legend().remove()  # one legend, in the first panel
    fig.savefig(path, dpi=_DPI, format="png")


def _demo_retarget(s: DemoState) -> None:
    """The shipped walk retargeted onto the shipped humanoid with the shipped map: ``jaxanim retarget``'s solve
    and .npz (prepare_retarget, solve_retarget, retarget_arrays), and a picture of a few frames."""
    try:
        import mujoco  # noqa: F401  (optional: the robots extra reads the robot)
    except ImportError:
        s.rows.append(("retarget", "skipped: mujoco is not installed (pip install 'jaxanim[robots]')"))
        return
    from .. import retargeting, robots
    from ._retarget_clip import retarget_arrays

    skel, motion = s.clip.skeleton, s.clip.motion
    robot_path, map_path = robots.default_robot_path(), retargeting.default_mapping_path()
    robot = robots.load_robot(robot_path, dtype=s.dtype)
    t0 = time.perf_counter()
    problem = retargeting.prepare_retarget(skel, motion, robot, map_path)
    options = retargeting.RetargetOptions()
    res = jax.block_until_ready(retargeting.solve_retarget(robot, problem, options))
    cold = time.perf_counter() - t0
    t0 = time.perf_counter()
    jax.block_until_ready(retargeting.solve_retarget(robot, problem, options).qpos)
    warm = time.perf_counter() - t0
    robot = retargeting.prepared_robot(robot, problem)  # the free joint and soles the problem was prepared with
    out = s.out_dir / "demo_retarget.npz"
    _save_npz(out, retarget_arrays(skel, motion, robot, problem, res, robot_path=robot_path,
                                   source=s.clip.path, map_path=map_path))
    d = retargeting.summary(res.diagnostics, position_weight=problem.position_weight)
    f = motion.num_frames
    status = "successful" if bool(res.success) else str(res.result)
    s.rows.append(("retarget", f"the clip onto {robot.name} ({robot.nq} qpos) with the shipped map, one least-squares "
                               f"problem over all {f} frames (retargeting.prepare_retarget, solve_retarget): {status} "
                               f"in {int(res.num_steps)} iterations"))
    s.rows.append(("", f"stance foot slide (median) {1e3 * d['foot_slide']:.2f} mm/s, penetration "
                       f"{1e3 * d['penetration']:.2f} mm, joint-range violation {d['range_violation']:.2g}, "
                       f"matching error {1e3 * d['matching_error']:.1f} mm"))
    s.rows.append(("", f"{_duration(cold)} with compilation (and the preparation), {_ms(warm)} warm = "
                       f"{warm / f * 1e3:.2f} ms per frame; wrote {out}"))
    if _has_matplotlib(s, "retarget"):
        png = s.out_dir / "demo_retarget.png"
        frames = np.linspace(0, f - 1, _DEMO_RETARGET_FRAMES).round().astype(int).tolist()
        _retarget_picture(png, out, frames)
        s.rows.append(("", f"wrote {png} (frames {', '.join(map(str, frames))}: the robot from its collision "
                           "geometry beside its source)"))


#: The demo, in order: ``(name, step)``; a step reads and extends the :class:`DemoState`.
DEMO_STEPS: list[tuple[str, Callable[[DemoState], None]]] = [
    ("load the shipped clip", _demo_load),
    ("forward kinematics of every frame", _demo_fk),
    ("save the FK arrays", _demo_save_fk),
    ("plot a stick figure", _demo_plot),
    ("edit the clip by inverse kinematics", _demo_ik),
    ("track the clip without root force", _demo_track),
    ("skin the clip (LBS and DQS)", _demo_skin),
    ("render the clip beside its simulation", _demo_render),
    ("retarget the clip onto the shipped humanoid", _demo_retarget),
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
    lines.append(f"  total {_duration(total)}")
    ui.result("\n".join(lines))
    return 0
