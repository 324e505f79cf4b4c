"""End-to-end dataset retargeting (a table of ``python -m benchmarks retarget``; issue 59): what a user pays to
retarget a folder of clips onto the Unitree G1, reading, preparation, calibration, compiling, the solve and writing
included, on the same cores for both.

* jaxanim: the command ``jaxanim retarget FOLDER --robot g1.xml --out OUT`` in a subprocess, once with an empty
  compilation cache (cold) and once more with the cache it left (warm, ``--overwrite``); one clip alike.
* mink: GMR's per-frame loop (:mod:`benchmarks.peers.mink_retarget`) over the clips in as many processes as
  there are cores (``multiprocessing``, spawned), given each clip's targets as jaxanim prepares them
  (:func:`mink_targets`: the same targets as jaxanim's solve), each process starting, loading the robot,
  solving its clips and writing ``qpos`` to an ``.npz``. Reading and preparing the clips is left out of mink's
  time (GMR does both in numpy; here they are jaxanim's, whose JAX compiles would dominate a small dataset),
  and is in jaxanim's: the comparison favours mink.

The dataset (:func:`write_dataset`): variations of the shipped walk and of the shared CMU clip: speed factors,
trims of random start and length, and mirrors, written as BVH files.
"""

from __future__ import annotations

import csv
import dataclasses
import multiprocessing
import os
import pathlib
import re
import subprocess
import sys
import tempfile
import time

import numpy as np
from jaxanim.app._retarget_dataset import _header_frames, bucket_length

from .report import Row, Table, Target, sel
from .timing import Timing

__all__ = ["DatasetSizes", "dataset_table", "mink_targets", "run_mink_dataset", "write_dataset"]

_JAX_COLD = "jaxanim retarget FOLDER (empty compilation cache)"
_JAX_WARM = "jaxanim retarget FOLDER (warm cache, --overwrite)"
_MINK = "mink per frame (GMR's loop), one process per core"
_JAX_ONE = "jaxanim retarget CLIP (warm cache)"
_MINK_ONE = "mink per frame (GMR's loop), one clip"


@dataclasses.dataclass(frozen=True)
class DatasetSizes:
    """The dataset: ``clips`` BVH files of ``min_frames`` to ``max_frames`` frames (``--quick`` shrinks it)."""

    clips: int = 100
    min_frames: int = 40
    max_frames: int = 300


def write_dataset(folder: pathlib.Path, sizes: DatasetSizes, cmu_path: pathlib.Path | None, seed: int = 0) -> int:
    """Write ``sizes.clips`` BVH clips into ``folder``: the shipped walk (and the CMU clip when given), looped,
    resampled at speed factors 0.7-1.3, trimmed to a random start and length, every third walk mirrored. Returns the
    total frame count."""
    import jax.numpy as jnp

    import jaxanim
    from jaxanim.app._simulate import _looped_motion
    from jaxanim.skeleton import Motion, mirror, resample_at

    rng = np.random.default_rng(seed)
    sources = [jaxanim.read_bvh(jaxanim.default_clip_path())[:2]]
    if cmu_path is not None:
        sources.append(jaxanim.read_bvh(cmu_path)[:2])
    folder.mkdir(parents=True, exist_ok=True)
    total = 0
    for i in range(sizes.clips):
        skel, clip = sources[i % len(sources)]
        speed = float(rng.uniform(0.7, 1.3))
        frames = int(rng.integers(sizes.min_frames, sizes.max_frames + 1))
        long = _looped_motion(clip, int(np.ceil((frames + clip.num_frames) * speed)) + 2)
        start = int(rng.integers(0, clip.num_frames))
        m = resample_at(long, jnp.asarray((start + np.arange(frames)) * speed, dtype=long.rotations.dtype))
        m = Motion(m.rotations, m.translations, clip.frame_time)
        if i % 3 == 2 and i % len(sources) == 0:  # the walk's skeleton mirrors; the CMU one is not symmetric
            m = mirror(m, skel)
        jaxanim.write_bvh(folder / f"{'walk' if i % len(sources) == 0 else 'cmu'}_{i:04d}.bvh", skel, m)
        total += frames
    return total


_COMPILED = re.compile(r"Finished (XLA compilation of|jaxpr to MLIR module conversion) (.+) in ([0-9.]+) sec")


def _command(args: list[str], cache: pathlib.Path, compiles: dict | None = None) -> float:
    """Wall seconds of ``python -m jaxanim ARGS`` with its compilation cache in ``cache``; with ``compiles``, JAX
    logs its compilations (``JAX_LOG_COMPILES``) and ``compiles`` gets the seconds of each top-level program's
    lowering (``"MLIR"``) and XLA compilation (``"XLA"``) by program name, as ``(seconds, count)``."""
    env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=str(cache))
    if compiles is not None:
        env["JAX_LOG_COMPILES"] = "1"
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "jaxanim", "--quiet", *args], env=env, capture_output=True,
                          text=True)
    seconds = time.perf_counter() - t0
    if done.returncode not in (0, 1):
        raise RuntimeError(f"jaxanim {' '.join(args)}: exit status {done.returncode}: {done.stderr[-2000:]}")
    if compiles is not None:
        for kind, name, sec in _COMPILED.findall(done.stderr):
            by_name = compiles.setdefault("XLA" if kind.startswith("XLA") else "MLIR", {})
            total, count = by_name.get(name, (0.0, 0))
            by_name[name] = (total + float(sec), count + 1)
    return seconds


def mink_targets(paths: list[pathlib.Path], robot_path: pathlib.Path) -> list[dict]:
    """Each clip's targets for mink, as jaxanim's command prepares them (``auto_map`` per skeleton,
    ``prepare_retarget`` padded to its bucket, cut back): ``names``, ``positions``, ``orientations``, the weights as
    mink's costs and the first frame's ``qpos``; ``None`` for a clip that cannot be prepared."""
    import jax.numpy as jnp

    import jaxanim
    from jaxanim import retargeting, robots
    from jaxanim.app._retarget_dataset import bucket_length
    from jaxanim.retargeting._solve import _initial

    from .retarget import MINK_COST

    robot = robots.load_robot(robot_path)
    maps: dict[tuple, object] = {}  # the auto map of each skeleton, as the command finds it
    out = []
    for path in paths:
        try:
            skel, motion = jaxanim.read_bvh(path)[:2]
            T = motion.num_frames
            key = (skel.names, tuple(np.asarray(skel.offsets).ravel().tolist()))
            if key not in maps:
                maps[key] = retargeting.auto_map(skel, robot)
            p = retargeting.prepare_retarget(skel, motion, robot, maps[key], length=bucket_length(T))
            out.append({"names": p.names, "positions": np.asarray(p.target_positions(), np.float64)[:T],
                        "orientations": np.asarray(p.orientations, np.float64)[:T],
                        "position_cost": MINK_COST * np.sqrt(np.asarray(p.position_weight, np.float64)),
                        "orientation_cost": MINK_COST * np.sqrt(np.asarray(p.orientation_weight, np.float64)),
                        "qpos_init": np.asarray(_initial(robot, p, jnp.float64)[0]),
                        "fps": 1.0 / float(motion.frame_time), "name": pathlib.Path(path).stem})
        except Exception:  # noqa: BLE001 (counted as failed, as the command counts its failed clips)
            out.append(None)
    return out


def _mink_clips(job: tuple) -> tuple[int, int, float]:
    """One process's clips (a spawned worker): load the robot, solve each clip with mink, write its ``qpos``.
    ``(frames, failed, seconds solving)``."""
    targets, robot_path, out = job
    from .peers import mink_retarget as mr

    model = mr.load_model(robot_path)
    frames = failed = 0
    solve_s = 0.0
    for t in targets:
        if t is None:
            failed += 1
            continue
        t0 = time.perf_counter()
        qpos = mr.mink_retarget(model, t["names"], t["positions"], t["orientations"], t["position_cost"],
                                t["orientation_cost"], qpos_init=t["qpos_init"])[0]
        solve_s += time.perf_counter() - t0
        np.savez(pathlib.Path(out) / (t["name"] + ".npz"), qpos=qpos, fps=t["fps"])
        frames += len(qpos)
    return frames, failed, solve_s


def run_mink_dataset(targets: list, robot_path: pathlib.Path, out: pathlib.Path,
                     processes: int) -> tuple[float, int, int, float]:
    """``(wall seconds, frames, failed clips, seconds solving summed over the processes)`` of mink over the
    prepared ``targets`` (:func:`mink_targets`) in ``processes`` spawned processes (clip ``i`` to process
    ``i mod processes``): the processes' start, imports, the model's loading, the solves and the writing."""
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(targets[k::processes], str(robot_path), str(out)) for k in range(processes)]
    t0 = time.perf_counter()
    with multiprocessing.get_context("spawn").Pool(processes) as pool:
        results = pool.map(_mink_clips, jobs)
    return (time.perf_counter() - t0, *(sum(r[k] for r in results) for k in range(3)))


def dataset_table(config, robot_path: pathlib.Path, sizes: DatasetSizes) -> Table:
    """The end-to-end table (see the module docstring)."""
    cores = os.cpu_count() or 1
    table = Table(
        "retarget_dataset", f"Retargeting a dataset end to end: {sizes.clips} clips onto the Unitree G1",
        accuracy_label="clips failed", description=(
            f"The dataset: {sizes.clips} BVH clips of {sizes.min_frames}-{sizes.max_frames} frames, variations of "
            "the shipped walk and the shared CMU clip (speed factors 0.7-1.3, random trims, every third walk mirrored; "
            "`benchmarks/retarget_dataset.py`). Each row is one run, timed on the wall clock from start to end: "
            "reading, preparation, calibration, compiling, the solve and writing. jaxanim: the command "
            "`jaxanim retarget FOLDER --robot g1.xml --map auto --out OUT` (npz) in a subprocess, with an "
            "empty compilation cache, then again with the cache it left (`--overwrite`); its XLA programs use "
            f"every core ({cores} here). mink: GMR's per-frame loop over the same clips in {cores} spawned processes "
            "(one per core), given the targets that jaxanim's `auto_map` and `prepare_retarget` make of each clip "
            "(the same as jaxanim's solve gets), each process starting, loading the robot, solving its clips and "
            "writing their qpos: mink's time leaves out reading and preparing the clips (GMR does both in numpy, "
            "not measured here), where jaxanim's includes them. One clip: the first of the dataset, jaxanim's command run "
            "once untimed (its programs solve one clip padded to its bucket, where the dataset's solve batches) and then timed with "
            "the cache warm, against mink in one process. **µs / char is per frame.**"),
        targets=[Target("dataset end to end, compiling included: ≥ 3× mink's frames per second", sel(_JAX_COLD),
                        3.0, versus=sel(_MINK)),
                 Target("one clip with a warm cache: at most 2× mink's wall time", sel(_JAX_ONE), 0.5,
                        versus=sel(_MINK_ONE))])
    with tempfile.TemporaryDirectory(prefix="jaxanim-bench-dataset-") as tmp:
        tmp = pathlib.Path(tmp)
        cmu = config.data_file("bvh/cmu_01_01_trim300.bvh")
        frames = write_dataset(tmp / "clips", sizes, None if isinstance(cmu, str) else cmu)
        paths = sorted((tmp / "clips").glob("*.bvh"))
        cache = tmp / "cache"
        common = ["retarget", "--robot", str(robot_path), "--map", "auto"]

        def row(impl, seconds, n_frames, failed, batch, note):
            tm = Timing(seconds, seconds, 1)
            return Row(impl, "float64", batch, tm.median, tm.min, n_frames, None, failed, samples=1, note=note)

        def add(impl, make, peer=False):
            if not config.selects(impl):
                return
            try:
                table.rows.append(make())
            except Exception as exc:  # noqa: BLE001 (a failed row, the others go on)
                table.rows.append(Row(impl, "float64", sizes.clips, skipped=f"failed: {type(exc).__name__}: {exc}",
                                      is_peer=peer))
            table.rows[-1].is_peer = peer
            config.log(f"retarget_dataset: {impl}: {table.rows[-1].note or table.rows[-1].skipped}")

        runs: dict[str, tuple[float, float, int]] = {}  # impl: (wall s, the clips' own seconds summed, buckets)

        compiles: dict[str, dict[str, float]] = {}

        def jax_run(impl, extra):
            out = tmp / "jaxanim"
            seconds = _command([*common, str(tmp / "clips"), "--out", str(out), *extra], cache,
                               compiles if impl == _JAX_COLD else None)
            with open(out / "manifest.csv", newline="") as f:
                rows = list(csv.DictReader(f))
            failed = sum(r["status"] != "successful" for r in rows)
            own = sum(float(r["seconds"] or 0.0) for r in rows)
            buckets = len({bucket_length(int(r["frames"])) for r in rows if r["frames"]})
            runs[impl] = (seconds, own, buckets)
            return row(impl, seconds, frames, failed, sizes.clips, f"{seconds:.1f} s for {frames} frames in {buckets} "
                       f"buckets; the clips' own seconds (reading, preparing, their share of their batch's solve, "
                       f"writing) sum to {own:.1f} s")

        add(_JAX_COLD, lambda: jax_run(_JAX_COLD, []))
        add(_JAX_WARM, lambda: jax_run(_JAX_WARM, ["--overwrite"]))

        prepared: list = []

        def mink_run():
            prepared.extend(mink_targets(paths, robot_path))
            seconds, done, failed, solve = run_mink_dataset(prepared, robot_path, tmp / "mink", cores)
            return row(_MINK, seconds, frames, failed, sizes.clips, f"{seconds:.1f} s for {done} frames; its solves "
                       f"{solve:.1f} s summed over the processes")

        add(_MINK, mink_run, peer=True)
        first = paths[0]
        n_first = _header_frames(first)

        def one_jax():  # run once to fill the cache with the one-clip programs (of its bucket), then timed
            _command([*common, str(first), "--out", str(tmp / "one.npz")], cache)
            seconds = _command([*common, str(first), "--out", str(tmp / "one.npz")], cache)
            return row(_JAX_ONE, seconds, n_first, 0, 1, f"{seconds:.2f} s for {n_first} frames")

        def one_mink():
            one = prepared[:1] or mink_targets([first], robot_path)
            seconds, done, failed, solve = run_mink_dataset(one, robot_path, tmp / "mink_one", 1)
            return row(_MINK_ONE, seconds, n_first, failed, 1, f"{seconds:.2f} s for {done} frames; its solve "
                       f"{solve:.2f} s")

        add(_JAX_ONE, one_jax)
        add(_MINK_ONE, one_mink, peer=True)
    table.notes.extend(_compile_notes(runs, compiles))
    return table


def _compile_notes(runs: dict[str, tuple[float, float, int]], compiles: dict[str, dict[str, float]]) -> list[str]:
    """Issue 59's compile target, from the cold and warm runs: what the empty cache added, per bucket, and the
    cold run's compilations by program (JAX's log)."""
    if _JAX_COLD not in runs or _JAX_WARM not in runs:
        return []
    (cold, _, buckets), (warm, own, _) = runs[_JAX_COLD], runs[_JAX_WARM]
    per = (cold - warm) / max(buckets, 1)
    xla, mlir = compiles.get("XLA", {}), compiles.get("MLIR", {})
    top = sorted(xla.items(), key=lambda kv: -kv[1][0])[:5]
    profile = (f" Profile (JAX's compile log of the cold run): XLA compiled {sum(c for _, c in xla.values())} "
               f"programs in {sum(t for t, _ in xla.values()):.1f} s, lowered in "
               f"{sum(t for t, _ in mlir.values()):.1f} s; the most: "
               + ", ".join(f"`{name}` {sec:.1f} s ({n}×)" for name, (sec, n) in top) + ".") if xla else ""
    return [f"Target: cold compiling ≤ 10 s per bucket: the empty cache added {cold - warm:.1f} s over {buckets} "
            f"buckets, {per:.1f} s each: {'met' if per <= 10.0 else 'missed'}.{profile}",
            f"Where the warm run's time goes: {own:.1f} s in the clips' own work (summed per clip in the manifest: "
            "reading, preparing, writing, and each clip's share of its batch's solve, which includes tracing the "
            "bucket's programs and loading them from the cache, paid in every process), the other "
            f"{warm - own:.1f} s in the command's start and end (imports, the robot, the manifest and its picture)."]
