"""``jaxanim match``: animate a character by motion matching on a database of BVH clips, driven by a
velocity (and facing) input over time, and write the result as BVH."""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import time

import jax
import numpy as np

from .._errors import JaxanimError
from ..ik import clean_foot_contacts
from ..kinematics._contacts import clip_positions
from ..skeleton._bvh import write_bvh
from ..skeleton._clips import resample
from ._common import _UI, _duration, _load, _num
from ._simulate import _check_seconds, _check_writable

_INPUT_FIELDS = ("velocity", "facing")


def _read_keys(path: str, data: dict, field: str, what: str) -> np.ndarray:
    """``data[field]`` as an ``[keys, 3]`` array of ``[t, a, b]`` entries with increasing ``t``."""
    entries = data[field]
    if not isinstance(entries, list) or not entries:
        raise JaxanimError(f"{path}: {field}: expected a non-empty list of [t, {what}] entries, got {entries!r}")
    rows = []
    for i, e in enumerate(entries):
        ok = (isinstance(e, list) and len(e) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                           for x in e))
        if not ok or not all(math.isfinite(float(x)) for x in e):
            raise JaxanimError(f"{path}: {field}[{i}]: expected [t, {what}] (3 finite numbers), got {json.dumps(e)}")
        rows.append([float(x) for x in e])
    keys = np.asarray(rows)
    for i in range(1, len(keys)):
        if keys[i, 0] <= keys[i - 1, 0]:
            raise JaxanimError(f"{path}: {field}[{i}]: times must increase, but t = {keys[i, 0]:g} follows "
                               f"t = {keys[i - 1, 0]:g} ({field}[{i - 1}])")
    return keys


def read_input(path: str, dtype=None):
    """Parse a ``jaxanim match`` input file into a :class:`jaxanim.matching.ControlInput`.

    The file is ``{"velocity": [[t, vx, vz], ...], "facing": [[t, fx, fz], ...]}`` (``facing``
    optional: the velocity's direction); each list piecewise linear in time with increasing ``t``.
    When the two lists have different times, both are sampled at the union of their times (the
    facing as an angle, so it turns the short way between keys).

    Raises:
        JaxanimError: naming the file and the field or entry at fault.
    """
    from ..matching import control_input

    try:
        text = pathlib.Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise JaxanimError(f"{path}: cannot read it: {exc.strerror or exc}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise JaxanimError(f"{path}:{exc.lineno}: not valid JSON: {exc.msg}") from None
    if not isinstance(data, dict):
        raise JaxanimError(f"{path}: expected a JSON object with \"velocity\" (and optionally \"facing\"), "
                           f"got {type(data).__name__}")
    unknown = sorted(set(data) - set(_INPUT_FIELDS))
    if unknown:
        raise JaxanimError(f"{path}: unknown field(s) {unknown}; valid fields: {list(_INPUT_FIELDS)}")
    if "velocity" not in data:
        raise JaxanimError(f"{path}: missing field \"velocity\": [[t, vx, vz], ...]")
    vel = _read_keys(path, data, "velocity", "vx, vz")
    if "facing" not in data:
        return control_input(vel[:, 0], vel[:, 1:], dtype=dtype)
    face = _read_keys(path, data, "facing", "fx, fz")
    zero = np.nonzero(np.linalg.norm(face[:, 1:], axis=1) <= 1e-12)[0]
    if zero.size:
        raise JaxanimError(f"{path}: facing[{int(zero[0])}]: a zero vector has no direction")
    times = np.union1d(vel[:, 0], face[:, 0])
    v = np.stack([np.interp(times, vel[:, 0], vel[:, k]) for k in (1, 2)], axis=1)
    yaw = np.interp(times, face[:, 0], np.unwrap(np.arctan2(face[:, 1], face[:, 2])))
    return control_input(times, v, np.stack([np.sin(yaw), np.cos(yaw)], axis=1), dtype=dtype)


def _stance_speed(skeleton, motion, cleaned) -> float:
    """Median ground speed (file units per s) of the feet of ``cleaned`` over the frame steps where
    the foot is on the ground at both ends (0 without any)."""
    idx = [skeleton.index(f) for f in cleaned.feet]
    P = np.asarray(clip_positions(skeleton, motion))[:, idx][..., [0, 2]]
    v = np.linalg.norm(np.diff(P, axis=0), axis=-1) / float(motion.frame_time)
    c = np.asarray(cleaned.contacts)
    both = c[1:] & c[:-1]
    return float(np.median(v[both])) if both.any() else 0.0


def _cmd_match(args: argparse.Namespace, ui: _UI) -> int:
    from .. import matching

    _check_seconds(args.seconds)
    _check_writable("--out", args.out)
    inputs = read_input(args.input, dtype=args.dtype)
    clips = [_load(f, ui, args.dtype) for f in (args.files or [None])]
    first = clips[0]
    dt = float(first.motion.frame_time)
    motions = []
    for c in clips:
        m = c.motion
        if abs(float(m.frame_time) - dt) > 1e-6 * dt:
            ui.progress(f"resampling {c.label} from {_num(1 / float(m.frame_time))} to {_num(1 / dt)} fps")
            m = resample(m, dt)
        motions.append(m)
    ui.progress(f"building the database: {len(clips)} clip(s){' and their mirror images' if args.mirror else ''}")
    t0 = time.perf_counter()
    db = matching.build_database(motions, first.skeleton, mirror=args.mirror, mirror_check=False,
                                 skeletons=[c.skeleton for c in clips], sources=[c.label for c in clips])
    build_seconds = time.perf_counter() - t0
    too_fast = matching.check_input_speed(db, inputs)
    if too_fast:
        ui.warning(f"{args.input}: {too_fast}")
    frames = int(round(args.seconds / dt)) + 1
    ui.progress(f"matching {_num((frames - 1) * dt)} s: {frames} frames, database of {db.num_rows} frames "
                f"({int(np.sum(np.asarray(db.searchable)))} searchable), {db.num_features} features")
    t0 = time.perf_counter()
    result = jax.block_until_ready(matching.motion_matching(db, inputs, frames))
    seconds = time.perf_counter() - t0
    cleaned = None
    if args.clean_feet:
        ui.progress("planting the feet: IK foot-contact cleanup (ik.clean_foot_contacts)")
        t1 = time.perf_counter()
        cleaned = jax.block_until_ready(clean_foot_contacts(first.skeleton, result.motion))
        clean_seconds = time.perf_counter() - t1
    write_bvh(args.out, first.skeleton, result.motion if cleaned is None else cleaned.motion)
    root = np.asarray(result.motion.translations[:, 0])
    span = (frames - 1) * dt
    moved = root[-1, [0, 2]] - root[0, [0, 2]]
    want = np.asarray(inputs.velocity).mean(axis=0) if len(np.asarray(inputs.times)) == 1 else None
    lines = [
        f"wrote {args.out}: {frames} frames at {_num(1 / dt)} fps, {first.skeleton.num_joints} joints",
        f"{int(np.sum(np.asarray(result.searched)))} searches, {int(np.sum(np.asarray(result.switched)))} "
        f"transitions; the root moved ({moved[0]:.3f}, {moved[1]:.3f}) in {_num(span)} s "
        f"(mean ground speed {np.linalg.norm(moved) / span:.3f} per s"
        + (f", asked {np.linalg.norm(want):.3f})" if want is not None else ")"),
        f"time: database {_duration(build_seconds)}, matching {_duration(seconds)} (compile included)",
    ]
    if cleaned is not None:
        before = _stance_speed(first.skeleton, result.motion, cleaned)
        after = _stance_speed(first.skeleton, cleaned.motion, cleaned)
        contacts = np.asarray(cleaned.contacts)
        lines.append(f"feet planted ({', '.join(cleaned.feet)}): on the ground in {100 * contacts.mean():.0f} % of "
                     f"foot-frames, where their median speed went from {before:.3g} to {after:.3g} per s; the IK met "
                     f"its targets in {int(np.sum(np.asarray(cleaned.success)))}/{frames} frames "
                     f"({_duration(clean_seconds)}, compile included)")
    ui.result("\n".join(lines))
    return 0


def add_match_parser(sub, common) -> None:
    p = sub.add_parser("match", parents=[common], help="animate by motion matching on BVH clips (BVH out)",
                       description="Build a motion-matching database from the clips (all on one skeleton; the "
                                   "shipped walk without any; --mirror adds their mirror images), drive a character "
                                   "with the velocity (and facing) input of IN.json and write the animation as BVH at "
                                   "the database's frame rate. IN.json: {\"velocity\": [[t, vx, vz], ...], "
                                   "\"facing\": [[t, fx, fz], ...]} in the clips' units per second on the ground "
                                   "plane, piecewise linear in time; \"facing\" is optional (default: the velocity's "
                                   "direction).")
    p.add_argument("files", nargs="*", metavar="DB.bvh", help="database clips (default: the shipped walk clip)")
    p.add_argument("--input", "-i", required=True, metavar="IN.json", help="the velocity / facing input (see above)")
    p.add_argument("--seconds", "-s", type=float, required=True, metavar="S", help="duration to animate")
    p.add_argument("--out", "-o", required=True, metavar="OUT.bvh", help="output file")
    p.add_argument("--mirror", action="store_true",
                   help="add the clips' mirror images (left and right swapped by joint name; a skeleton whose two "
                        "sides differ a little, as CMU's, is mirrored anyway)")
    p.add_argument("--clean-feet", action="store_true",
                   help="plant the feet afterwards with the IK foot-contact cleanup (ik.clean_foot_contacts): a foot "
                        "on the ground stays where it landed, so the trajectory adjustment no longer slides it; "
                        "prints the stance feet's median speed before and after")
    p.set_defaults(func=_cmd_match)
