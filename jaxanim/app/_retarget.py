"""``jaxanim retarget SOURCE.bvh --robot ROBOT.xml|ROBOT.urdf --map MAP.json --out OUT.npz`` (issue 30)."""

from __future__ import annotations

import argparse
import pathlib
import time

import jax
import numpy as np

from .._errors import JaxanimError
from ._common import _UI, _as_dtype, _duration, _warnings_to

#: The clip length above which the command reports the solve's stages as it goes.
_LONG = 300


def _cmd_retarget(args: argparse.Namespace, ui: _UI) -> int:
    from .. import retargeting, robots  # noqa: PLC0415 (mujoco is an optional extra)
    from ..skeleton import read_clip  # noqa: PLC0415
    from ._retarget_clip import retarget_arrays  # noqa: PLC0415

    out = pathlib.Path(args.out)
    if out.suffix != ".npz":
        raise JaxanimError(f"--out {args.out}: expected a .npz file")
    if args.render is not None and pathlib.Path(args.render).suffix not in (".gif", ".mp4"):
        raise JaxanimError(f"--render {args.render}: expected a .gif or .mp4 file")
    dtype = "float32" if args.float32 else "float64"
    robot_path = args.robot or robots.default_robot_path()
    map_path = args.map or retargeting.default_mapping_path()
    source = args.source
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
    with _warnings_to(ui):  # a foot's default sole
        problem = retargeting.prepare_retarget(skeleton, motion, robot, retargeting.auto_map(skeleton, robot)
                                               if map_path == "auto" else map_path, fixed_base=args.fixed_base)
    if problem.floating:
        ui.progress(f"{robot.name}: its root body has no free joint; retargeting adds one, 'root_joint', first in "
                    "qpos (--fixed-base refuses this)")
    robot = retargeting.prepared_robot(robot, problem)  # the free joint and soles the problem was prepared with
    T = motion.num_frames
    if T >= _LONG:
        ui.progress(f"{source}: {T} frames prepared (contacts, anchors) in {_duration(time.perf_counter() - start)}; "
                    f"solving the whole clip (compiling first)")
    options = retargeting.RetargetOptions(iterations=args.iterations)
    res = retargeting.solve_retarget(robot, problem, options)
    qpos = np.asarray(jax.block_until_ready(res.qpos))
    seconds = time.perf_counter() - start
    if not np.all(np.isfinite(qpos)):
        raise JaxanimError(f"the solve gave non-finite values ({res.result}); nothing written")
    s = retargeting.summary(res.diagnostics, position_weight=problem.position_weight)
    # FK of every frame (positions, rotations), the source in the robot's frame, the geometry, the diagnostics
    arrays = retarget_arrays(skeleton, motion, robot, problem, res, robot_path=robot_path, source=source,
                             map_path=map_path)
    bad = [k for k, v in arrays.items() if v.dtype.kind == "f" and not np.all(np.isfinite(v))]
    if bad:
        raise JaxanimError(f"non-finite values in {bad}; nothing written")
    np.savez(out, **arrays)
    ui.result(f"wrote {out}: {T} frames of {robot.name} ({robot.nq} qpos) at {float(res.fps):g} fps in "
              f"{_duration(seconds)} (compile included); status: "
              f"{'successful' if bool(res.success) else res.result}")
    ui.result(f"  stance foot slide (median) {1e3 * s['foot_slide']:.2f} mm/s, penetration {1e3 * s['penetration']:.2f} mm, "
              f"lowest foot point {1e3 * s['lowest_foot']:.2f} mm")
    ui.result(f"  joint-range violation {s['range_violation']:.2g}, limit hits {s['limit_hits']} (frames x joints), "
              f"matching error {1e3 * s['matching_error']:.1f} mm, jitter {s['jitter']:.2f} rad/s^2")
    if args.render is not None:
        from ._render import render_retarget  # noqa: PLC0415 (matplotlib is an optional extra)
        render_retarget(out, args.render, ui=ui)
        ui.result(f"wrote {args.render}")
    return 0 if bool(res.success) else 1


def add_retarget_parser(sub, common) -> None:
    p = sub.add_parser("retarget", parents=[common], help="retarget a BVH clip onto a robot (MJCF or URDF), feet planted",
                       description="Retarget a BVH clip onto a robot (jaxanim.retargeting.retarget, needs jaxanim[robots]): "
                                   "one least-squares problem over the whole clip, joint ranges as hard bounds, the "
                                   "feet planted in the source's stance phases. Writes qpos [T, nq], fps, joint and "
                                   "body names and the per-frame diagnostics to OUT.npz, and prints the foot slide, "
                                   "penetration, limit hits and matching error. Defaults: the shipped walk, humanoid "
                                   "and map.")
    p.add_argument("source", nargs="?", metavar="SOURCE.bvh", help="the clip (default: the shipped walk)")
    p.add_argument("--robot", metavar="ROBOT.xml|ROBOT.urdf", help="the robot (default: the shipped humanoid)")
    p.add_argument("--map", metavar="MAP.json|auto", help="the retargeting map (default: the shipped walk's), or "
                   "'auto' to find it from the clip's and the robot's shapes (retargeting.auto_map, the map "
                   "that `jaxanim retarget-map` writes)")
    p.add_argument("--out", "-o", default="retarget.npz", metavar="OUT.npz", help="output (default retarget.npz)")
    p.add_argument("--render", metavar="OUT.gif", help="also draw the robot beside its source (GIF or MP4)")
    p.add_argument("--iterations", type=int, default=200, help="the most Levenberg-Marquardt iterations; the solve "
                   "stops once converged (default 200)")
    p.add_argument("--fixed-base", action="store_true", help="the robot really is fixed: refuse it when its root "
                   "has no free joint, instead of adding one named root_joint (a URDF has none)")
    p.set_defaults(func=_cmd_retarget)
