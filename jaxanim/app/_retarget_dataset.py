"""``jaxanim retarget SOURCES... --robot R --out FOLDER``: a whole dataset in one command (issue 59).

Sources are files and folders; a folder is read recursively for ``.bvh`` and AMASS ``.npz`` clips (an
``.npz`` that is not an AMASS clip is a failed row, like any unreadable file). Each clip writes to
``OUT/<its path relative to its source folder>`` with the format's suffix; a file given by itself is
relative to its own folder.

The run:

* **buckets**: each clip is padded to the first of a few lengths (:func:`bucket_length`: 32, 48, 64,
  96, ... frames, at most half again the clip), and clips of one bucket are solved ``--batch`` at a
  time in one ``vmap`` (the last batch of a bucket repeats its last clip), so that one compiled
  program serves a bucket; the command's persistent compilation cache keeps it for the next run. The
  buckets are done in turn, shortest first (the frame counts read from the files' headers);
* **the manifest** ``OUT/manifest.csv`` has a row per clip, failed ones included with their error
  (:data:`MANIFEST_COLUMNS`); it is rewritten after every batch, so an interrupted run keeps what it
  finished;
* **resuming**: a clip is skipped when its output exists and its row records the same ``sha256`` of
  the source, ``robot``, ``map`` and ``options`` (which hold the robot and map files' hashes too, so an
  edited file redoes its clips); ``--overwrite`` redoes it;
* **failures** (an unreadable file, NaN, a solve that did not converge) are rows with ``status`` and
  ``error``; the others go on, and the exit status is 1 if any clip failed;
* **processes**: under ``jax.distributed`` (``--distributed``, or ``--coordinator``,
  ``--num-processes`` and ``--process-id``) process ``k`` of ``n`` takes clips ``k, k + n, ...`` of the
  sorted list and writes ``OUT/manifest.part-k-of-n.csv``; once every process has finished, process 0
  merges the parts into ``manifest.csv`` and draws the picture (a part left by an interrupted run is
  read as rows of the previous run);
* **the picture** ``OUT/manifest.png``: the per-clip distributions of foot slide, penetration,
  jitter and matching error, the outliers named (needs ``jaxanim[plot]``).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import hashlib
import json
import os
import pathlib
import time

import jax
import numpy as np

from .._errors import JaxanimError
from ._common import _UI, _as_dtype, _warnings_to

#: The manifest's columns, in order: the clip, its status and time, its diagnostics
#: (``retargeting.summary``: m/s, m, rad, rad/s^2), then what the resume test compares and the error.
MANIFEST_COLUMNS = ("source", "sha256", "frames", "fps", "status", "seconds", "foot_slide", "penetration",
                    "range_violation", "matching_error", "orientation_error", "jitter", "output", "robot", "map",
                    "options", "error")
#: The diagnostics columns, from ``retargeting.summary``.
_MEASURES = ("foot_slide", "penetration", "range_violation", "matching_error", "orientation_error", "jitter")
#: The files a folder is searched for.
CLIP_SUFFIXES = (".bvh", ".npz")
#: A process's part of the manifest under ``jax.distributed`` (merged into ``manifest.csv`` by process 0).
_PART = "manifest.part-{index:04d}-of-{count:04d}.csv"
_PART_GLOB = "manifest.part-*-of-*.csv"
#: The smallest bucket; the others grow by 3/2 and 4/3 in turn (32, 48, 64, 96, 128, ...).
_SMALLEST_BUCKET = 32


def bucket_length(frames: int) -> int:
    """The padded length of a clip of ``frames`` frames: the first of 32, 48, 64, 96, 128, 192, ... (each
    power of two and its half again) that holds it."""
    length = _SMALLEST_BUCKET
    while length < frames:
        length = length * 3 // 2 if (length & (length - 1)) == 0 else length * 4 // 3
    return length


@dataclasses.dataclass(frozen=True)
class ClipFile:
    """One clip of the dataset: its file, its name in the manifest (the path relative to its source folder)
    and its output file."""

    path: pathlib.Path
    name: str
    output: pathlib.Path


def find_clips(sources, out: pathlib.Path, suffix: str) -> list[ClipFile]:
    """The clips of ``sources`` (files, and folders searched recursively for :data:`CLIP_SUFFIXES`), sorted by
    name, each with its output under ``out`` (files under ``out`` itself are left out).

    Raises:
        JaxanimError: a source that does not exist, or two clips that would write the same output.
    """
    out = out.resolve()
    clips: dict[pathlib.Path, ClipFile] = {}
    for s in sources:
        p = pathlib.Path(s)
        if not p.exists():
            raise JaxanimError(f"source {s}: no such file or folder")
        if p.is_dir():
            found = sorted(f for f in p.rglob("*") if f.suffix.lower() in CLIP_SUFFIXES and f.is_file()
                           and out not in f.resolve().parents)
            pairs = [(f, f.relative_to(p)) for f in found]
        else:
            pairs = [(p, pathlib.Path(p.name))]
        for f, rel in pairs:
            clip = ClipFile(f, rel.as_posix(), out / rel.with_suffix(suffix))
            other = clips.get(clip.output)
            if other is not None and other.path.resolve() != f.resolve():
                raise JaxanimError(f"sources: {other.path} and {f} would both write {clip.output}; give them "
                                   "separate folders")
            clips[clip.output] = clip
    return sorted(clips.values(), key=lambda c: (c.name, str(c.path)))


def sha256(path: pathlib.Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def read_manifest(path: pathlib.Path) -> dict[str, dict[str, str]]:
    """The rows of a manifest by ``source`` (empty when there is none)."""
    if not path.exists():
        return {}
    with open(path, newline="") as f:
        return {row["source"]: row for row in csv.DictReader(f)}


def write_manifest(path: pathlib.Path, rows: dict[str, dict]) -> None:
    """Write the rows (sorted by ``source``) through a temporary file, so a reader never sees half of one."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=MANIFEST_COLUMNS, extrasaction="ignore")
        w.writeheader()
        for key in sorted(rows):
            w.writerow({k: _cell(rows[key].get(k, "")) for k in MANIFEST_COLUMNS})
    os.replace(tmp, path)


def _cell(v) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    return " ".join(str(v).split())  # one line per row


class _Batcher:
    """The prepared clips waiting for a solve, by bucket; solves a batch once it is full."""

    def __init__(self, batch: int, solve):
        self.batch, self.solve = batch, solve
        self.waiting: dict[tuple, list] = {}

    def add(self, key, item):
        group = self.waiting.setdefault(key, [])
        group.append(item)
        if len(group) == self.batch:
            self.solve(self.waiting.pop(key))

    def flush(self):
        for key in sorted(self.waiting, key=str):
            self.solve(self.waiting.pop(key))


def run_dataset(args: argparse.Namespace, ui: _UI, sources: list[str]) -> int:
    """The dataset form of ``jaxanim retarget`` (see the module docstring); returns the exit status."""
    from .. import retargeting, robots  # noqa: PLC0415 (mujoco is an optional extra)
    from ..skeleton import read_clip  # noqa: PLC0415

    fmt = args.format
    suffix = retargeting.format_suffix(fmt)
    out = pathlib.Path(args.out)
    if out.suffix.lower() in (".npz", ".csv", ".pkl") or (out.exists() and not out.is_dir()):
        raise JaxanimError(f"--out {args.out}: with several sources or a folder, --out is a folder")
    if args.render is not None:
        raise JaxanimError("--render: draws one clip; render a dataset's outputs one by one with `jaxanim render`")
    if args.batch < 1:
        raise JaxanimError(f"--batch {args.batch}: expected at least 1")
    out = out.resolve()  # the outputs' paths in the manifest are relative to it
    clips = find_clips(sources, out, suffix)
    if not clips:
        raise JaxanimError(f"sources {' '.join(sources)}: no {' or '.join(CLIP_SUFFIXES)} clips found")
    out.mkdir(parents=True, exist_ok=True)
    dtype = "float32" if args.float32 else "float64"
    robot_path = str(args.robot or robots.default_robot_path())
    map_arg = args.map or str(retargeting.default_mapping_path())
    with _warnings_to(ui):  # a URDF's missing meshes
        robot = robots.load_robot(robot_path, dtype=dtype)
    mapping = None if map_arg == "auto" else retargeting.load_mapping(map_arg)
    options = retargeting.RetargetOptions(iterations=args.iterations)
    # what else decides an output: the options, and the robot and map files' contents (edited in place, they redo)
    option_key = json.dumps({"format": fmt, "fps": args.fps, "csv_header": bool(args.csv_header), "dtype": dtype,
                             "iterations": args.iterations, "fixed_base": bool(args.fixed_base),
                             "body_model": args.body_model, "robot_sha256": sha256(pathlib.Path(robot_path)),
                             "map_sha256": None if map_arg == "auto" else sha256(pathlib.Path(map_arg))},
                            sort_keys=True)
    manifest = out / "manifest.csv"
    previous = read_manifest(manifest)
    for part in sorted(out.glob(_PART_GLOB)):  # an interrupted distributed run's rows
        previous.update(read_manifest(part))
    processes, index = jax.process_count(), jax.process_index()
    everything = clips
    clips = clips[index::processes]  # this process's share of the sorted list
    own = out / _PART.format(index=index, count=processes) if processes > 1 else manifest
    rows: dict[str, dict] = {}
    failed: list[str] = []
    maps: dict[str, object] = {}
    bar = _progress_bar(len(clips), ui)
    frames_done = [0]
    started = time.perf_counter()

    def record(clip: ClipFile, row: dict, solved: bool = True) -> None:
        rows[clip.name] = row
        if row["status"] != "successful":
            failed.append(clip.name)
        frames_done[0] += int(row.get("frames") or 0) if solved else 0
        bar.update(1)
        bar.set_postfix_str(f"{frames_done[0] / max(time.perf_counter() - started, 1e-9):.0f} frames/s, "
                            f"{len(failed)} failed")

    def base_row(clip: ClipFile, digest: str) -> dict:
        return {"source": clip.name, "sha256": digest, "output": str(clip.output.relative_to(out)),
                "robot": robot_path, "map": map_arg, "options": option_key}

    def solve(group: list) -> None:
        t0 = time.perf_counter()
        problems = [g["problem"] for g in group]
        padded = problems + [problems[-1]] * (args.batch - len(problems))
        prepared = group[0]["robot"]
        try:
            batch = jax.block_until_ready(jax.vmap(retargeting.solve_retarget, in_axes=(None, 0, None))(
                prepared, retargeting.stack_problems(padded), options))
        except Exception as exc:  # noqa: BLE001 (one failed batch does not stop the run)
            for g in group:
                record(g["clip"], {**g["row"], "status": "failed", "error": f"solve: {exc}"})
            return
        share = (time.perf_counter() - t0) / len(group)
        for i, g in enumerate(group):
            t1 = time.perf_counter()
            res = jax.tree.map(lambda x, i=i: x[i], batch)
            row = dict(g["row"])
            try:
                s = _write_clip(g, res, prepared, args, fmt, robot_path, map_arg)
                row.update(s)
                row["status"] = _status(res)
                if row["status"] != "successful":
                    row["error"] = f"the solve ended with {row['status']}; its output is written"
            except Exception as exc:  # noqa: BLE001
                row.update(status="failed", error=str(exc))
            row["seconds"] = g["seconds"] + share + time.perf_counter() - t1
            record(g["clip"], row)
        write_manifest(own, {**previous, **rows} if own == manifest else rows)

    batcher = _Batcher(args.batch, solve)
    quiet, skipped = _Collect(), 0
    # bucket by bucket (the frame counts from the files' headers, read once), so that batches fill in turn
    buckets = {c.name: bucket_length(_header_frames(c.path)) for c in clips}
    bucket = None
    with bar:
        for clip in sorted(clips, key=lambda c: (buckets[c.name], c.name)):
            if buckets[clip.name] != bucket:
                batcher.flush()
                bucket = buckets[clip.name]
            t0 = time.perf_counter()
            try:
                digest = sha256(clip.path)
            except OSError as exc:
                record(clip, {"source": clip.name, "status": "failed", "error": f"{clip.path}: {exc}"})
                continue
            row = base_row(clip, digest)
            old = previous.get(clip.name)
            if (not args.overwrite and old is not None and clip.output.exists() and old.get("status") == "successful"
                    and all(old.get(k) == str(row[k]) for k in ("sha256", "robot", "map", "options"))):
                skipped += 1
                record(clip, old, solved=False)  # the manifest keeps the row of the run that wrote it
                continue
            try:
                with _warnings_to(quiet):
                    skeleton, motion = _as_dtype(read_clip(clip.path, body_model=args.body_model), dtype)
                    row.update(frames=motion.num_frames, fps=1.0 / float(motion.frame_time))
                    mp = mapping if mapping is not None else _auto_map(maps, skeleton, robot)
                    L = bucket_length(motion.num_frames)
                    problem = retargeting.prepare_retarget(skeleton, motion, robot, mp, length=L,
                                                           fixed_base=args.fixed_base)
                    prepared = retargeting.prepared_robot(robot, problem)
            except Exception as exc:  # noqa: BLE001 (an unreadable clip is a row, the others go on)
                message = str(exc) if str(clip.path) in str(exc) else f"{clip.path}: {exc}"
                record(clip, {**row, "status": "failed", "error": message})
                continue
            key = (L, id(mp), jax.tree_util.tree_structure(problem))
            batcher.add(key, {"clip": clip, "row": row, "problem": problem, "robot": prepared, "skeleton": skeleton,
                              "motion": motion, "seconds": time.perf_counter() - t0})
        batcher.flush()
    for message in sorted(quiet.messages):
        ui.warning(message)
    if processes > 1:  # every process's part, merged by process 0 once all have finished
        write_manifest(own, rows)
        from jax.experimental import multihost_utils  # noqa: PLC0415

        multihost_utils.sync_global_devices("jaxanim retarget: manifest parts written")
        if index:
            ui.result(f"process {index} of {processes}: {len(clips)} clips, {len(failed)} failed; process 0 "
                      f"writes {manifest}")
            return 1 if failed else 0
        parts = [out / _PART.format(index=i, count=processes) for i in range(processes)]
        for part in parts:
            rows.update(read_manifest(part))
        write_manifest(manifest, {**previous, **rows})
        for part in out.glob(_PART_GLOB):
            part.unlink()
        failed = [c.name for c in everything if rows.get(c.name, {}).get("status") != "successful"]
        skipped = sum(1 for c in everything if c.name in previous and rows.get(c.name) == previous[c.name]
                      and previous[c.name].get("status") == "successful")  # rows read back: strings alike
    else:
        write_manifest(manifest, {**previous, **rows})
    done = len(everything) - len(failed)
    ui.result(f"wrote {manifest}: {len(everything)} clips, {done} retargeted or up to date ({skipped} skipped), "
              f"{len(failed)} failed, in {time.perf_counter() - started:.1f} s"
              + (f" ({processes} processes)" if processes > 1 else ""))
    for name in failed:
        ui.error(f"{name}: {rows.get(name, {}).get('error', rows.get(name, {}).get('status'))}")
    picture = out / "manifest.png"
    try:
        manifest_picture({**previous, **rows}, picture)
        ui.result(f"wrote {picture}")
    except ImportError:
        ui.warning("manifest.png needs matplotlib: pip install 'jaxanim[plot]'")
    return 1 if failed else 0


def _header_frames(path: pathlib.Path) -> int:
    """A clip's frame count from its header (a BVH's ``Frames:`` line, an AMASS file's ``trans``), read without
    the clip; 1 where it cannot be read (the clip's own reading then reports why)."""
    try:
        if path.suffix.lower() == ".bvh":
            with open(path, errors="replace") as f:
                for line in f:
                    if line.strip().lower().startswith("frames:"):
                        return max(int(line.split(":", 1)[1]), 1)
            return 1
        with np.load(path, allow_pickle=False) as data:
            return max(int(data["trans"].shape[0]), 1)
    except (OSError, ValueError, KeyError, IndexError):
        return 1


def _status(res) -> str:
    """``successful``, or the name of the solver's status (``max_steps_reached``, ``nonfinite``, ...)."""
    import solvers  # noqa: PLC0415

    if bool(res.success):
        return "successful"
    names = [n for n, item in solvers.RESULTS._name_to_item.items() if bool(res.result == item)]
    return names[0] if names and names[0] != "successful" else "failed"


class _Collect(_UI):
    """The clips' warnings (a foot's default sole, the same for every clip), printed once at the end."""

    def __init__(self):
        super().__init__(quiet=True)
        self.messages: set[str] = set()

    def warning(self, message: str) -> None:
        self.messages.add(message)


def _auto_map(cache: dict, skeleton, robot):
    from .. import retargeting  # noqa: PLC0415

    key = json.dumps([skeleton.names, np.asarray(skeleton.parents).tolist(),
                      np.round(np.asarray(skeleton.offsets, np.float64), 9).tolist()])
    if key not in cache:
        cache[key] = retargeting.auto_map(skeleton, robot)
    return cache[key]


def _write_clip(g: dict, res, robot, args, fmt: str, robot_path: str, map_arg: str) -> dict:
    """Write one solved clip in ``fmt``; returns its manifest measures. Raises on a non-finite result."""
    from .. import retargeting  # noqa: PLC0415
    from ._retarget_clip import retarget_arrays  # noqa: PLC0415

    clip, problem, motion = g["clip"], g["problem"], g["motion"]
    T = motion.num_frames
    qpos_all = np.asarray(res.qpos)
    if not np.all(np.isfinite(qpos_all[:T])):
        raise JaxanimError(f"the solve gave non-finite values ({res.result}); nothing written")
    s = retargeting.summary(res.diagnostics, position_weight=problem.position_weight)
    clip.output.parent.mkdir(parents=True, exist_ok=True)
    fps = float(res.fps)
    if fmt == "npz":
        arrays = retarget_arrays(g["skeleton"], motion, robot, problem, res, robot_path=robot_path,
                                 source=str(clip.path), map_path=map_arg)  # the clip's frames, without padding
        arrays["qvel"] = retargeting.qvel_from_qpos(robot, arrays["qpos"], fps)
        bad = [k for k, v in arrays.items() if v.dtype.kind == "f" and not np.all(np.isfinite(v))]
        if bad:
            raise JaxanimError(f"non-finite values in {bad}; nothing written")
        np.savez(clip.output, **arrays)
    else:
        qpos = qpos_all[:T]
        if args.fps is not None:
            qpos, fps = retargeting.resample_qpos(robot, qpos, fps, args.fps), float(args.fps)
        retargeting.write_motion(clip.output, robot, qpos, fps, fmt, csv_header=bool(args.csv_header))
    return {k: s[k] for k in _MEASURES}


def _progress_bar(total: int, ui: _UI):
    """tqdm's bar on stderr (clips per second, the remaining time; frames per second in its postfix), or a
    silent stand-in with ``--quiet``."""
    if ui.quiet:
        return _NoBar()
    from tqdm import tqdm  # noqa: PLC0415

    return tqdm(total=total, unit="clip", dynamic_ncols=True, desc="retarget")


class _NoBar(contextlib.AbstractContextManager):
    def __exit__(self, *exc):
        return None

    def update(self, n=1):
        pass

    def set_postfix_str(self, s):
        pass


def manifest_picture(rows: dict[str, dict], path: pathlib.Path) -> None:
    """``manifest.png``: per-clip foot slide, penetration, jitter and matching error (the successful
    rows), one strip each, the box of the middle half drawn, and the clips beyond the whiskers
    (1.5 box lengths) named, the worst three at most per panel (the worst one where none is beyond)."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    panels = (("foot_slide", "stance foot slide (mm/s)", 1e3), ("penetration", "penetration (mm)", 1e3),
              ("jitter", "jitter (rad/s²)", 1.0), ("matching_error", "matching error (mm)", 1e3))
    good = {k: r for k, r in rows.items() if r.get("status") == "successful" and r.get("foot_slide") not in (None, "")}
    names = sorted(good)
    fig, axes = plt.subplots(1, len(panels), figsize=(4 * len(panels), 4.2))
    failed = len(rows) - len(good)
    fig.suptitle(f"{len(good)} clips retargeted" + (f", {failed} failed or not converged" if failed else ""))
    rng = np.random.default_rng(0)
    for ax, (key, label, unit) in zip(axes, panels):
        v = np.asarray([float(good[n][key]) * unit for n in names])
        ax.set_title(label, fontsize=10)
        if v.size:
            ax.boxplot(v, positions=[0], widths=0.5, showfliers=False)
            ax.scatter(rng.uniform(-0.15, 0.15, v.size), v, s=8, alpha=0.6, color="tab:blue")
        ax.set_xticks([])
        if not v.size:
            continue
        q1, q3 = np.percentile(v, [25, 75])
        out = [i for i in np.argsort(-v) if v[i] > q3 + 1.5 * (q3 - q1) and v[i] > 0][:3] or [int(np.argmax(v))]
        for i in out:
            ax.annotate(pathlib.Path(names[i]).stem, (0.3, v[i]), fontsize=7, xytext=(8, 0),
                        textcoords="offset points", va="center")
        ax.set_xlim(-0.6, 1.2)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
