"""``jaxanim retarget SOURCE.bvh --robot ROBOT.xml|ROBOT.urdf --map MAP.json --out OUT.npz`` (issue 30)."""

from __future__ import annotations

import argparse
import pathlib
import time

import jax
import numpy as np

from .._errors import JaxanimError
from ._common import _UI, _as_dtype, _duration, _warnings_to
from ._retarget_dataset import bucket_length

#: The clip length above which the command reports the solve's stages as it goes.
_LONG = 300


def _cmd_retarget(args: argparse.Namespace, ui: _UI) -> int:
    from .. import retargeting, robots  # noqa: PLC0415 (mujoco is an optional extra)
    from ..skeleton import read_clip  # noqa: PLC0415
    from ._retarget_clip import retarget_arrays  # noqa: PLC0415

    if args.fps is not None and not (np.isfinite(args.fps) and args.fps > 0):
        raise JaxanimError(f"--fps {args.fps}: expected a positive frame rate")
    if args.fps is not None and args.format == "npz":
        raise JaxanimError("--fps: the npz format keeps the source's frame rate (its diagnostics are per source "
                           "frame); resample with --format csv, beyondmimic or gmr")
    if args.csv_header and args.format != "csv":
        raise JaxanimError(f"--csv-header: only with --format csv (not {args.format})")
    sources = list(args.source)
    distributed = args.distributed or any(a is not None for a in (args.coordinator, args.num_processes,
                                                                  args.process_id))
    if len(sources) > 1 or (sources and pathlib.Path(sources[0]).is_dir()):
        from ._retarget_dataset import run_dataset  # noqa: PLC0415

        if args.out is None:
            raise JaxanimError("--out: with several sources or a folder, give the output folder")
        if distributed:
            _initialize_distributed(args)
        return run_dataset(args, ui, sources)
    if distributed:
        raise JaxanimError("--distributed: shares the clips of a dataset (several sources or a folder) among "
                           "processes; give one of those")
    suffix = retargeting.format_suffix(args.format)
    out = pathlib.Path(args.out or "retarget" + suffix)
    if out.suffix != suffix:
        raise JaxanimError(f"--out {out}: expected a {suffix} file for --format {args.format}")
    if args.render is not None and pathlib.Path(args.render).suffix not in (".gif", ".mp4"):
        raise JaxanimError(f"--render {args.render}: expected a .gif or .mp4 file")
    dtype = "float32" if args.float32 else "float64"
    robot_path = args.robot or robots.default_robot_path()
    map_path = args.map or retargeting.default_mapping_path()
    source = sources[0] if sources else None
    if source is None:
        from ..skeleton import default_clip_path  # noqa: PLC0415
        source = default_clip_path()
    skeleton, motion = _as_dtype(read_clip(source, body_model=args.body_model), dtype)
    with _warnings_to(ui):  # a URDF's missing meshes
        robot = robots.load_robot(robot_path, dtype=dtype)
    unbounded = [n for n, t, lim in zip(robot.jnt_names, robot.jnt_types, robot.jnt_limited)
                 if t in ("hinge", "slide") and not lim]
    if unbounded:
        ui.warning(f"{len(unbounded)} joint(s) without a range, treated as unbounded: {unbounded}")
    start = time.perf_counter()
    T = motion.num_frames
    with _warnings_to(ui):  # a foot's default sole
        # padded to the dataset's bucket: one compiled program (kept in the compile cache) serves clips of
        # nearby lengths, here and in a dataset run
        problem = retargeting.prepare_retarget(skeleton, motion, robot, retargeting.auto_map(skeleton, robot)
                                               if map_path == "auto" else map_path, fixed_base=args.fixed_base,
                                               length=bucket_length(T))
    if problem.floating:
        ui.progress(f"{robot.name}: its root body has no free joint; retargeting adds one, 'root_joint', first in "
                    "qpos (--fixed-base refuses this)")
    robot = retargeting.prepared_robot(robot, problem)  # the free joint and soles the problem was prepared with
    if T >= _LONG:
        ui.progress(f"{source}: {T} frames prepared (contacts, anchors) in {_duration(time.perf_counter() - start)}; "
                    f"solving the whole clip (compiling first)")
    options = retargeting.RetargetOptions(iterations=args.iterations)
    res = retargeting.solve_retarget(robot, problem, options)
    qpos = np.asarray(jax.block_until_ready(res.qpos))[:T]  # the clip's frames, without the padding
    seconds = time.perf_counter() - start
    if not np.all(np.isfinite(qpos)):
        raise JaxanimError(f"the solve gave non-finite values ({res.result}); nothing written")
    s = retargeting.summary(res.diagnostics, position_weight=problem.position_weight)
    # FK of every frame (positions, rotations), the source in the robot's frame, the geometry, the diagnostics
    arrays = retarget_arrays(skeleton, motion, robot, problem, res, robot_path=robot_path, source=source,
                             map_path=map_path)
    arrays["qvel"] = retargeting.qvel_from_qpos(robot, arrays["qpos"], float(res.fps))
    bad = [k for k, v in arrays.items() if v.dtype.kind == "f" and not np.all(np.isfinite(v))]
    if bad:
        raise JaxanimError(f"non-finite values in {bad}; nothing written")
    if args.format == "npz":
        np.savez(out, **arrays)
    else:
        fps = float(res.fps)
        qpos = qpos if args.fps is None else retargeting.resample_qpos(robot, qpos, fps, args.fps)
        retargeting.write_motion(out, robot, qpos, fps if args.fps is None else float(args.fps), args.format,
                                 csv_header=bool(args.csv_header))
    ui.result(f"wrote {out}: {T} frames of {robot.name} ({robot.nq} qpos) at {float(res.fps):g} fps in "
              f"{_duration(seconds)} (compile included); status: "
              f"{'successful' if bool(res.success) else res.result}")
    ui.result(f"  stance foot slide (median) {1e3 * s['foot_slide']:.2f} mm/s, penetration {1e3 * s['penetration']:.2f} mm, "
              f"lowest foot point {1e3 * s['lowest_foot']:.2f} mm")
    ui.result(f"  joint-range violation {s['range_violation']:.2g}, limit hits {s['limit_hits']} (frames x joints), "
              f"matching error {1e3 * s['matching_error']:.1f} mm, jitter {s['jitter']:.2f} rad/s^2")
    if args.render is not None:
        from ._render import render_retarget  # noqa: PLC0415 (matplotlib is an optional extra)
        render_retarget(arrays, args.render, ui=ui)
        ui.result(f"wrote {args.render}")
    return 0 if bool(res.success) else 1


def _initialize_distributed(args: argparse.Namespace) -> None:
    """``jax.distributed.initialize``: from ``--coordinator``, ``--num-processes`` and ``--process-id`` (all three),
    or with none of them from JAX's own cluster detection (SLURM, Open MPI, Kubernetes, ...)."""
    given = (args.coordinator, args.num_processes, args.process_id)
    if any(a is not None for a in given) and not all(a is not None for a in given):
        raise JaxanimError("--coordinator, --num-processes, --process-id: give all three, or none with "
                           "--distributed on a cluster that JAX detects")
    if all(a is not None for a in given):
        if not 0 <= args.process_id < args.num_processes:
            raise JaxanimError(f"--process-id {args.process_id}: expected 0 to {args.num_processes - 1}")
        jax.distributed.initialize(coordinator_address=args.coordinator, num_processes=args.num_processes,
                                   process_id=args.process_id)
    else:
        jax.distributed.initialize()


def add_retarget_parser(sub, common) -> None:
    p = sub.add_parser("retarget", parents=[common], help="retarget clips or whole datasets onto a robot (MJCF or "
                       "URDF), feet planted",
                       description="Retarget BVH or AMASS clips onto a robot (jaxanim.retargeting.retarget, needs "
                                   "jaxanim[robots]): one least-squares problem over each whole clip, joint ranges as "
                                   "hard bounds, the feet planted in the source's stance phases. One clip writes "
                                   "OUT (qpos [T, nq], qvel [T, nv], fps, joint and body names and the per-frame "
                                   "diagnostics in the npz format) and prints the foot slide, penetration, limit hits "
                                   "and matching error. Several sources or a folder (searched recursively for .bvh "
                                   "and .npz) write into the folder OUT, one file per clip at its path relative to "
                                   "its source folder, with OUT/manifest.csv (a row per clip, failed ones included) "
                                   "and OUT/manifest.png; clips already done with the same source, robot, map and "
                                   "options are skipped, and the exit status is 1 if any clip failed. Defaults: the "
                                   "shipped walk, humanoid and map.")
    p.add_argument("source", nargs="*", metavar="SOURCE", help="clips (.bvh, AMASS .npz) or folders of them "
                   "(default: the shipped walk)")
    p.add_argument("--robot", metavar="ROBOT.xml|ROBOT.urdf", help="the robot (default: the shipped humanoid)")
    p.add_argument("--map", metavar="MAP.json|auto", help="the retargeting map (default: the shipped walk's), or "
                   "'auto' to find it from the clip's and the robot's shapes (retargeting.auto_map, the map "
                   "that `jaxanim retarget-map` writes)")
    p.add_argument("--out", "-o", metavar="OUT", help="the output file (default retarget.npz, or the format's "
                   "suffix), or with several sources or a folder the output folder")
    p.add_argument("--format", default="npz", choices=("npz", "csv", "beyondmimic", "gmr"),
                   help="npz: jaxanim's (qpos, qvel, FK, diagnostics); csv: a row per frame, root position, root "
                   "quaternion x y z w, joint angles (the LAFAN1 retargeting CSVs of mjlab and BeyondMimic); "
                   "beyondmimic: the motion .npz of mjlab and whole_body_tracking; gmr: GMR's pickle")
    p.add_argument("--fps", type=float, metavar="F", help="resample the output to F frames per second, rotations "
                   "slerped (csv, beyondmimic, gmr)")
    p.add_argument("--csv-header", action="store_true", help="a header row of column names in the csv")
    p.add_argument("--overwrite", action="store_true", help="redo the clips whose output is up to date")
    p.add_argument("--batch", type=int, default=8, help="clips solved together in one vmap, per bucket of "
                   "lengths (default 8)")
    p.add_argument("--distributed", action="store_true", help="a dataset over several processes under "
                   "jax.distributed, each taking its share of the clips (the cluster found by JAX: SLURM, Open MPI, "
                   "...; or --coordinator, --num-processes, --process-id); process 0 merges the manifest")
    p.add_argument("--coordinator", metavar="HOST:PORT", help="jax.distributed's coordinator (process 0's address)")
    p.add_argument("--num-processes", type=int, metavar="N", help="the number of processes")
    p.add_argument("--process-id", type=int, metavar="K", help="this process's index, 0 to N-1")
    p.add_argument("--render", metavar="OUT.gif", help="also draw the robot beside its source (GIF or MP4; one clip)")
    p.add_argument("--iterations", type=int, default=200, help="the most Levenberg-Marquardt iterations; the solve "
                   "stops once converged (default 200)")
    p.add_argument("--fixed-base", action="store_true", help="the robot really is fixed: refuse it when its root "
                   "has no free joint, instead of adding one named root_joint (a URDF has none)")
    p.set_defaults(func=_cmd_retarget)
