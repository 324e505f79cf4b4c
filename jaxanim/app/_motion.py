"""``jaxanim blend`` and ``jaxanim loop``: motion processing on BVH files
(:mod:`jaxanim.skeleton._processing`), written back as BVH on the same skeleton."""

from __future__ import annotations

import argparse

import jax
import numpy as np

from .. import rotations as rot
from .._errors import JaxanimError
from ..skeleton._bvh import write_bvh
from ..skeleton._processing import make_loop, transition
from ..skeleton._skeleton import Skeleton
from ._common import _UI, _Clip, _load, _num
from ._simulate import _check_writable

_UP = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
_OFFSET_RTOL = 1e-6  # offsets of the two files' skeletons that count as equal (relative to the largest)
_FRAME_TIME_RTOL = 1e-6


def _check_same_skeleton(a: _Clip, b: _Clip) -> None:
    """The two files must hold the same skeleton: names, parents, channels, End Sites, offsets."""
    sa, sb = a.skeleton, b.skeleton
    where = f"{a.label} and {b.label} have different skeletons"
    if sa.names != sb.names:
        diff = next((i for i, (x, y) in enumerate(zip(sa.names, sb.names)) if x != y), min(len(sa.names), len(sb.names)))
        raise JaxanimError(f"{where}: {sa.num_joints} vs {sb.num_joints} joints, names differ from joint {diff} "
                           f"({_name(sa, diff)!r} vs {_name(sb, diff)!r})")
    for field in ("parents", "channels", "end_site_parents"):
        if getattr(sa, field) != getattr(sb, field):
            j = next(i for i, (x, y) in enumerate(zip(getattr(sa, field), getattr(sb, field))) if x != y)
            raise JaxanimError(f"{where}: the {field.replace('_', ' ')} differ (first at index {j})")
    oa, ob = np.asarray(sa.offsets, np.float64), np.asarray(sb.offsets, np.float64)
    ea, eb = np.asarray(sa.end_site_offsets, np.float64), np.asarray(sb.end_site_offsets, np.float64)
    scale = max(np.abs(oa).max(initial=0.0), np.abs(ea).max(initial=0.0), 1e-300)
    tol = _OFFSET_RTOL * scale + 1e-12
    bad = np.flatnonzero(np.abs(oa[1:] - ob[1:]).max(axis=-1, initial=0.0) > tol) + 1  # the root's OFFSET is free
    if bad.size:
        j = int(bad[0])
        raise JaxanimError(f"{where}: OFFSET of joint {sa.names[j]!r} is {oa[j].tolist()} vs {ob[j].tolist()}")
    if ea.shape == eb.shape and ea.size and np.abs(ea - eb).max() > tol:
        e = int(np.argmax(np.abs(ea - eb).max(axis=-1)))
        raise JaxanimError(f"{where}: OFFSET of End Site {sa.end_site_names[e]!r} is {ea[e].tolist()} vs {eb[e].tolist()}")


def _name(sk: Skeleton, j: int) -> str:
    return sk.names[j] if j < sk.num_joints else "(none)"


def _root_steps(motion) -> np.ndarray:
    p = np.asarray(motion.translations[:, 0], np.float64)
    return np.linalg.norm(np.diff(p, axis=0), axis=-1)


def _cmd_blend(args: argparse.Namespace, ui: _UI) -> int:
    frame_a, frame_b = args.at
    if args.window < 0:
        raise JaxanimError(f"--window: expected a number of frames >= 0, got {args.window}")
    out = args.out or "blend.bvh"
    _check_writable("--out", out)
    a = _load(args.a, ui, args.dtype)
    b = _load(args.b, ui, args.dtype)
    _check_same_skeleton(a, b)
    fa, fb = float(a.motion.frame_time), float(b.motion.frame_time)
    if abs(fa - fb) > _FRAME_TIME_RTOL * max(fa, fb):
        raise JaxanimError(f"{a.label} and {b.label} have different frame times ({_num(fa)} s vs {_num(fb)} s); "
                           "blend does not resample: resample one first (jaxanim.skeleton.resample)")
    na, nb = a.motion.num_frames, b.motion.num_frames
    if not 0 <= frame_a <= na:
        raise JaxanimError(f"--at: frame {frame_a} of {a.label} is out of range (it has {na} frames: 0 to {na})")
    if not 0 <= frame_b < nb:
        raise JaxanimError(f"--at: frame {frame_b} of {b.label} is out of range (it has {nb} frames: 0 to {nb - 1})")
    if args.window > na - frame_a:
        raise JaxanimError(f"--window {args.window} is longer than what remains of {a.label} from frame {frame_a} "
                           f"({na - frame_a} frames)")
    if args.window > nb - frame_b:
        raise JaxanimError(f"--window {args.window} is longer than what remains of {b.label} from frame {frame_b} "
                           f"({nb - frame_b} frames)")
    ui.progress(f"blending {a.label} at frame {frame_a} into {b.label} from frame {frame_b} over {args.window} frames")
    result = jax.block_until_ready(transition(a.motion, b.motion, frame_a, frame_b, args.window, up=_UP[args.up]))
    ui.progress(f"writing {out}")
    write_bvh(out, a.skeleton, result)
    steps = _root_steps(result)
    k = frame_a - 1 if frame_a > 0 else None
    own = max(_root_steps(a.motion).max(initial=0.0), _root_steps(b.motion).max(initial=0.0))
    jump = f"; root step at the switch {steps[k]:.4g}" if k is not None and k < steps.size else ""
    ui.result(f"wrote {out}: {result.num_frames} frames ({frame_a} of {a.label}, then {nb - frame_b} of {b.label}, "
              f"the first {args.window} blended) at {_num(1.0 / fa)} fps{jump} (largest in the inputs {own:.4g})")
    return 0


def _cmd_loop(args: argparse.Namespace, ui: _UI) -> int:
    clip = _load(args.file, ui, args.dtype)
    out = args.out or f"{clip.stem}.loop.bvh"
    _check_writable("--out", out)
    if clip.motion.num_frames < 2:
        raise JaxanimError(f"{clip.label}: a loop needs at least 2 frames, it has {clip.motion.num_frames}")
    ui.progress(f"making {clip.label} loop ({clip.motion.num_frames} frames)")
    result = jax.block_until_ready(make_loop(clip.motion, up=_UP[args.up]))
    ui.progress(f"writing {out}")
    write_bvh(out, clip.skeleton, result)
    delta = rot.quat_multiply(result.rotations, rot.quat_conjugate(clip.motion.rotations))
    change = float(np.degrees(np.asarray(rot.rotation_angle(delta)).max()))
    ui.result(f"wrote {out}: {result.num_frames} frames at {_num(clip.motion.fps)} fps "
              f"(joint rotations changed by up to {change:.3g} degrees)")
    return 0


def add_motion_parsers(sub, common: argparse.ArgumentParser, file_help: str) -> None:
    """Register ``blend`` and ``loop`` on the subcommand parser ``sub``."""
    p = sub.add_parser("blend", parents=[common], help="transition from one clip to another (BVH out)",
                       description="Switch from A to B: A's frames before --at A, then B's from --at B on, B moved on "
                                   "the ground so that its facing frame there is A's at the switch (course notes eq. "
                                   "5.5). The first --window frames after the switch blend A's continuation into B "
                                   "(smoothstep weight; slerp per joint, lerp for the root), so the root does not jump; "
                                   "from frame a + W on the output is B (aligned) with B's own joint rotations. OUT has "
                                   "a + len(B) - b frames. Both files must hold the same skeleton (names, parents, "
                                   "channels, offsets) and the same frame time: blend does not resample (use "
                                   "jaxanim.skeleton.resample first).")
    p.add_argument("a", metavar="A.bvh", help="the clip to leave")
    p.add_argument("b", metavar="B.bvh", help="the clip to enter")
    p.add_argument("--at", nargs=2, type=int, required=True, metavar=("A", "B"),
                   help="the switch: frame of A (0 to len(A)) where B's frame B (0 to len(B)-1) starts")
    p.add_argument("--window", "-w", type=int, default=0, metavar="W",
                   help="blend length in frames (default 0: a cut, B aligned)")
    p.add_argument("--up", choices=tuple(_UP), default="y", help="the up axis (default y, BVH's)")
    p.add_argument("--out", "-o", metavar="OUT.bvh", help="output file (default: blend.bvh here)")
    p.set_defaults(func=_cmd_blend)

    p = sub.add_parser("loop", parents=[common], help="make a clip loop seamlessly (BVH out)",
                       description="Spread the mismatch between the last frame and the first (root height and tilt "
                                   "relative to its facing frame, every joint's rotation) linearly over the clip, so "
                                   "that playing it again, aligned to where it ended, does not jump. Root headings "
                                   "and ground positions are kept; frame 0 is unchanged.")
    p.add_argument("file", nargs="?", metavar="FILE.bvh", help=file_help)
    p.add_argument("--up", choices=tuple(_UP), default="y", help="the up axis (default y, BVH's)")
    p.add_argument("--out", "-o", metavar="OUT.bvh", help="output file (default: <name>.loop.bvh here)")
    p.set_defaults(func=_cmd_loop)
