"""Scaling benchmark (``python -m benchmarks scaling``): one batched kernel, FK of the 31-joint CMU skeleton
(``benchmarks.fk``'s problem), on 1 device, on 2 host devices of one process and on 2 processes under
``jax.distributed`` on localhost, each layout in fresh subprocesses pinned to their own cores.

Also the process launcher the distributed test uses: :func:`free_port`, :func:`run_processes` (every process
killed if one fails or the group outlives its timeout) and :func:`check_processes` (an error naming each
process's exit status and stderr tail). ``python -m benchmarks.scaling SPEC_JSON`` is the worker one
subprocess runs.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os
import pathlib
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence

import numpy as np

from .report import Row, Table, Target, sel, usable_cores

__all__ = ["LAYOUTS", "Layout", "ProcessResult", "check_processes", "free_port", "run_processes", "run_scaling",
           "subprocess_env"]

REPO = pathlib.Path(__file__).resolve().parents[1]
SCALING_BATCHES = (4096,)
_STDERR_TAIL = 3000  # characters of each process's stderr in an error message


@dataclasses.dataclass(frozen=True)
class ProcessResult:
    """One subprocess: its exit status (``None``: killed), stdout, stderr, and whether the group timed out."""

    returncode: int | None
    stdout: str
    stderr: str
    timed_out: bool = False


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (bound to port 0, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def subprocess_env(host_devices: int = 1) -> dict[str, str]:
    """This environment for a CPU-only JAX subprocess with ``host_devices`` devices that imports this checkout."""
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    flags = [f for f in env.get("XLA_FLAGS", "").split() if not f.startswith("--xla_force_host_platform_device_count")]
    env["XLA_FLAGS"] = " ".join(flags + ([f"--xla_force_host_platform_device_count={host_devices}"]
                                         if host_devices > 1 else []))
    env["PYTHONPATH"] = os.pathsep.join([str(REPO)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    return env


def run_processes(argvs: Sequence[Sequence[str]], *, env: dict[str, str], timeout_s: float,
                  cwd: pathlib.Path = REPO) -> list[ProcessResult]:
    """Start one process per argv at once and wait for all; kill every one still running when one exits with an
    error (its peers would wait for it in a collective) or when ``timeout_s`` has passed."""
    with tempfile.TemporaryDirectory(prefix="jaxanim-procs-") as tmp:
        outs = [(open(pathlib.Path(tmp) / f"{i}.out", "w+"), open(pathlib.Path(tmp) / f"{i}.err", "w+"))
                for i in range(len(argvs))]
        procs = [subprocess.Popen(list(a), cwd=cwd, env=env, stdout=o, stderr=e, text=True)
                 for a, (o, e) in zip(argvs, outs)]
        deadline, timed_out = time.monotonic() + timeout_s, False
        try:
            while None in (codes := [p.poll() for p in procs]):  # poll every one: each sets its returncode
                if any(c not in (None, 0) for c in codes):
                    break
                if time.monotonic() > deadline:
                    timed_out = True
                    break
                time.sleep(0.05)
        finally:
            for p in procs:
                if p.poll() is None:
                    p.kill()
                p.wait()
        results = []
        for p, (o, e) in zip(procs, outs):
            o.seek(0), e.seek(0)
            results.append(ProcessResult(p.returncode, o.read(), e.read(), timed_out))
            o.close(), e.close()
    return results


def check_processes(results: Sequence[ProcessResult], what: str) -> None:
    """Raise ``RuntimeError`` naming each process's exit status and stderr tail unless all exited with 0."""
    if all(r.returncode == 0 for r in results):
        return
    head = f"{what}: " + ("timed out; " if any(r.timed_out for r in results) else "") + ", ".join(
        f"process {i} exit status {r.returncode}" for i, r in enumerate(results))
    tails = [f"--- process {i} stderr (tail) ---\n{r.stderr[-_STDERR_TAIL:]}" for i, r in enumerate(results)]
    raise RuntimeError("\n".join([head, *tails]))


@dataclasses.dataclass(frozen=True)
class Layout:
    """How a batch is spread: ``processes`` x ``devices`` (CPU devices per process), ``cores`` per process
    (pinned with ``os.sched_setaffinity``; ``None``: all of them, unpinned)."""

    name: str
    processes: int
    devices: int
    cores: int | None

    def core_sets(self, available: Sequence[int]) -> list[list[int] | None]:
        """The cores of each process: consecutive ones, wrapping round when there are too few."""
        if self.cores is None:
            return [None] * self.processes
        return [[available[(i * self.cores + j) % len(available)] for j in range(self.cores)]
                for i in range(self.processes)]


_REF = "1 process × 1 device, 1 core"
LAYOUTS = (
    Layout(_REF, 1, 1, 1),
    Layout("1 process × 1 device, all cores", 1, 1, None),
    Layout("1 process × 2 host devices, 2 cores", 1, 2, 2),
    Layout("2 processes × 1 device (jax.distributed), 1 core each", 2, 1, 1),
)


def _launch(config, layout: Layout, batches: Sequence[int], out: pathlib.Path) -> list[dict]:
    """Run ``layout``'s worker processes over every dtype and batch; their results (one dict per process)."""
    port = free_port() if layout.processes > 1 else None
    specs = [dict(process_id=i, num_processes=layout.processes, port=port, cores=cores, batches=list(batches),
                  dtypes=list(config.dtypes), repeats=config.repeats, warmup=config.warmup,
                  max_row_s=config.max_row_s, data=str(config.data_file(_clip())), out=str(out))
             for i, cores in enumerate(layout.core_sets(sorted(os.sched_getaffinity(0)) if hasattr(
                 os, "sched_getaffinity") else list(range(os.cpu_count() or 1))))]
    timeout = 120.0 if config.quick else 600.0
    results = run_processes([[sys.executable, "-m", "benchmarks.scaling", json.dumps(s)] for s in specs],
                            env=subprocess_env(layout.devices), timeout_s=timeout)
    check_processes(results, f"scaling layout {layout.name!r}")
    return [json.loads((out / f"process{i}.json").read_text()) for i in range(layout.processes)]


def _clip() -> str:
    from .fk import CLIP

    return CLIP


def run_scaling(config, layouts: Sequence[Layout] = LAYOUTS) -> list[Table]:
    """The ``scaling`` benchmark (see the module docstring)."""
    batches = [b for b in config.batches_for(SCALING_BATCHES) if b % 2 == 0]
    cores = usable_cores()
    description = (
        "FK of the `fk` benchmark's poses (31-joint CMU skeleton), `jax.jit(jax.vmap(forward_kinematics))` on a batch "
        "spread over the devices by `jaxanim.shard_batch`, each layout in its own fresh subprocess(es) on the CPU "
        "platform: 1 device on 1 pinned core (the reference), 1 device unpinned (XLA's own threads on every core), "
        "2 forced host devices in one process on 2 pinned cores, and 2 processes under `jax.distributed` "
        "(coordinator 127.0.0.1, one device each, each pinned to its own core; each passes its half of the batch). "
        "Time per call: median (min) of the calls after warm-up; with 2 processes, the slower process's (FK needs no "
        "communication, so each computes its half on its own). Throughput and the speed-up over the reference are in "
        "the notes. Accuracy: max abs difference of the joint + End Site positions, gathered from every device, from "
        "the reference layout's at the same dtype and batch.")
    big = max(batches) if batches else None
    table = Table("scaling", "Scaling out: FK on 1 vs 2 devices and processes (CMU skeleton)", description,
                  "max abs diff vs 1 process", targets=[
                      Target(f"2 processes ≥ 1.6x one process on one core at batch {big} in float64",
                             sel("2 processes", "float64", big), 1.6, versus=sel(_REF, "float64", big, exact=True))])
    path = config.data_file(_clip())
    if isinstance(path, str):
        table.skipped = path
        return [table]
    if not batches:
        table.skipped = f"no batch size divisible by 2 devices in {config.batches_for(SCALING_BATCHES)}"
        return [table]
    from .timing import Runner

    run = Runner(config, table)
    with tempfile.TemporaryDirectory(prefix="jaxanim-scaling-") as tmp:
        measured: dict[str, list[dict] | Exception] = {}
        refs: dict[tuple[str, int], dict[str, np.ndarray]] = {}
        for layout in layouts:
            out = pathlib.Path(tmp) / str(len(measured))
            out.mkdir()
            config.log(f"scaling: {layout.name}")
            try:
                measured[layout.name] = _launch(config, layout, batches, out)
            except Exception as exc:  # one layout's failure is its rows' failure
                measured[layout.name] = exc
            for dtype in config.dtypes:
                for b in batches:
                    run.add(layout.name, dtype, b, functools.partial(
                        _row, run, layout, measured[layout.name], out, refs, dtype, b))
    table.notes.append(
        f"Machine: {cores} usable cores ({os.cpu_count()} logical). The pinned layouts compete with nothing else only "
        "on an idle machine (see the load average below); with fewer than 2 usable cores the 2-core layouts share "
        "one. Speed-up from 2 devices is bounded by 2 on 2 cores, and by memory bandwidth, which both cores share.")
    if len(config.batches_for(SCALING_BATCHES)) != len(batches):
        table.notes.append("Batches not divisible by 2 devices were left out.")
    return [table]


def _row(run, layout: Layout, results: list[dict] | Exception, out: pathlib.Path,
         refs: dict[tuple[str, int], dict[str, np.ndarray]], dtype: str, b: int) -> Row:
    if isinstance(results, Exception):
        raise results
    rows = [next(r for r in res["rows"] if r["dtype"] == dtype and r["batch"] == b) for res in results]
    got = dict(np.load(out / f"{dtype}_{b}.npz"))
    if layout.name == _REF:
        refs[dtype, b] = got
        accuracy = "reference"
    elif (dtype, b) in refs:
        accuracy = max(float(np.max(np.abs(got[k] - refs[dtype, b][k]), initial=0.0)) for k in got)
    else:
        accuracy = None
    median, minimum = max(r["median"] for r in rows), max(r["min"] for r in rows)
    procs, devs = results[0]["process_count"], results[0]["device_count"]
    note = [f"output sharded over {devs} device{'s' * (devs > 1)} of {procs} process{'es' * (procs > 1)}; "
            f"{b / median:.3g} characters/s"]
    ref = next((r for r in run.table.rows if r.implementation == _REF and r.dtype == dtype and r.batch == b
                and r.measured), None)
    if ref is not None and layout.name != _REF:
        note.append(f"{ref.time_median_s / median:.2f}x the 1-core time")
    return Row(layout.name, dtype, b, median, minimum, b, max(r["compile_s"] for r in rows), accuracy,
               samples=min(r["samples"] for r in rows), note="; ".join(note))


def _worker(spec: dict) -> None:
    """One process of a layout: FK on the sharded batch for every dtype and batch, timed; writes
    ``process<i>.json`` (timings) and, from process 0, ``<dtype>_<batch>.npz`` (the gathered outputs)."""
    if spec["cores"] is not None and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, spec["cores"])  # before JAX starts its threads: they inherit it
    import jax

    jax.config.update("jax_enable_x64", True)
    pid, n = spec["process_id"], spec["num_processes"]
    if n > 1:
        # cross-process collectives on the CPU backend (process_allgather below) need an implementation; gloo
        # is jax 0.10's default, named here so an older default ("none") fails loudly instead
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
        jax.distributed.initialize(coordinator_address=f"127.0.0.1:{spec['port']}", num_processes=n,
                                   process_id=pid, initialization_timeout=60)
    from jax.experimental import multihost_utils
    from jaxanim import forward_kinematics, shard_batch

    from . import BenchConfig
    from .fk import Problem, _cast
    from .timing import compile_time, time_call

    cfg = BenchConfig(repeats=spec["repeats"], warmup=spec["warmup"], max_row_s=spec["max_row_s"])
    problem = Problem(pathlib.Path(spec["data"]), max(spec["batches"]))
    out, rows = pathlib.Path(spec["out"]), []
    for dtype in spec["dtypes"]:
        fk = jax.vmap(functools.partial(forward_kinematics, _cast(problem.skeleton, dtype)))
        for b in spec["batches"]:
            lo, hi = pid * b // n, (pid + 1) * b // n  # this process's slice of the batch
            args = shard_batch((problem.quats[lo:hi].astype(dtype), problem.trans[lo:hi].astype(dtype)))
            cs = compile_time(jax.jit(fk), *args)
            res = jax.block_until_ready(cs.compiled(*args))
            if len(res.positions.sharding.device_set) != jax.device_count():
                raise RuntimeError(f"output sharded over {res.positions.sharding.device_set}, not every device")
            if n > 1:
                multihost_utils.sync_global_devices(f"time {dtype} {b}")
            tm = time_call(cs.compiled, *args, repeats=cfg.repeats, warmup=cfg.warmup, max_total_s=cfg.max_row_s)
            rows.append(dict(dtype=dtype, batch=b, median=tm.median, min=tm.min, samples=tm.samples,
                             compile_s=cs.total))
            outputs = (res.positions, res.end_site_positions)
            full = multihost_utils.process_allgather(outputs, tiled=True) if n > 1 else outputs
            if pid == 0:
                np.savez(out / f"{dtype}_{b}.npz", positions=np.asarray(full[0]), end_sites=np.asarray(full[1]))
    (out / f"process{pid}.json").write_text(json.dumps(dict(
        rows=rows, process_count=jax.process_count(), device_count=jax.device_count())))
    if n > 1:
        jax.distributed.shutdown()


if __name__ == "__main__":
    _worker(json.loads(sys.argv[1]))
