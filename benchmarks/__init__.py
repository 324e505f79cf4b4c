"""Benchmarks of jaxanim against its peers: ``python -m benchmarks [NAME ...] [--quick] [--gpu]``. :data:`REGISTRY`
maps the command-line names to ``run(config: BenchConfig) -> list[Table]`` functions, imported lazily so that one
benchmark's missing dependency never stops another; missing peers are ``skipped`` rows. :func:`run_benchmarks` runs
each benchmark as a *section*: within its own time budget (``BenchConfig.deadline``, cooperative: a row that would
end past it is skipped and says so), caught if it raises (a failed table, the rest still runs), and handing the
rows so far to a writer after every row, so that an interrupted run keeps every row it finished."""

from __future__ import annotations

import dataclasses
import fnmatch
import importlib
import os
import pathlib
import sys
import time
import traceback
from collections.abc import Callable, Mapping, Sequence

from .report import Row as Row, Table as Table, utc_now

__all__ = ["ACCELERATOR_BUDGET_S", "ACCELERATOR_SECTIONS", "ACCELERATOR_TOTAL_S", "REGISTRY", "BenchConfig",
           "BenchmarkSpec", "Row", "Table", "default_data_dir", "run_benchmarks"]

REPO = pathlib.Path(__file__).resolve().parents[1]


def default_data_dir() -> pathlib.Path:
    """The shared reference data: ``$JAXANIM_SHARED_DATA`` or ``../shared/data`` beside the clone."""
    env = os.environ.get("JAXANIM_SHARED_DATA")
    return pathlib.Path(env) if env else REPO.parent / "shared" / "data"


@dataclasses.dataclass(frozen=True)
class BenchConfig:
    """Settings shared by every benchmark of one run: ``batches`` (overrides every benchmark's), timed samples
    (``repeats``) after ``warmup`` calls within ``max_row_s`` per row, the most configurations a Python-loop peer
    runs per timed call (``loop_cap``) and ``only`` the implementations matching a case-insensitive shell pattern.
    ``accelerator`` selects each benchmark's accelerator sizes (``--gpu`` on a machine with one; ``quick`` wins).
    :func:`run_benchmarks` sets the running ``section``, its ``section_budget_s`` and ``deadline`` (a
    ``time.monotonic()`` instant; ``None``: no budget) and ``on_row``, called with a table after each of its rows."""

    quick: bool = False
    dtypes: tuple[str, ...] = ("float32", "float64")
    batches: tuple[int, ...] | None = None
    repeats: int = 7
    warmup: int = 2
    max_row_s: float = 20.0
    loop_cap: int = 2048
    data_dir: pathlib.Path = dataclasses.field(default_factory=default_data_dir)
    only: tuple[str, ...] | None = None
    verbose: bool = True
    accelerator: bool = False
    section: str | None = None
    section_budget_s: float | None = None
    deadline: float | None = None
    on_row: Callable[[Table], None] | None = dataclasses.field(default=None, compare=False, repr=False)

    @classmethod
    def make_quick(cls, **kwargs) -> BenchConfig:
        """A configuration for smoke tests: batches (1, 8), 3 repeats, 1 warm-up, loop cap 8."""
        return cls(**dict(quick=True, batches=(1, 8), repeats=3, warmup=1, max_row_s=1.0, loop_cap=8) | kwargs)

    @classmethod
    def make_accelerator(cls, **kwargs) -> BenchConfig:
        """The accelerator sizes (``--gpu``), sampled more briefly so that the ladders fit their section budgets:
        5 repeats, 1 warm-up, 8 s per row, Python loops capped at 512 configurations (their time per configuration
        does not depend on the batch)."""
        return cls(**dict(accelerator=True, repeats=5, warmup=1, max_row_s=8.0, loop_cap=512) | kwargs)

    def batches_for(self, default: Sequence[int], accelerator: Sequence[int] | None = None) -> tuple[int, ...]:
        """``batches`` if set, else the ``accelerator`` ladder under :attr:`accelerator`, else ``default``."""
        if self.batches is not None:
            return tuple(self.batches)
        return tuple(accelerator if self.accelerator and accelerator is not None else default)

    def pick(self, full, quick=None, accelerator=None):
        """A benchmark's sizes for this run: ``quick`` in quick mode, ``accelerator`` under :attr:`accelerator`
        (each when given), else ``full``."""
        if self.quick and quick is not None:
            return quick
        return accelerator if self.accelerator and accelerator is not None else full

    def time_left(self) -> float | None:
        """Seconds left of the running section's budget (negative once spent), or ``None`` without a budget."""
        return None if self.deadline is None else self.deadline - time.monotonic()

    def row_time_s(self) -> float:
        """How long one row may sample: ``max_row_s``, or less where the section has less time left (≥ 0)."""
        left = self.time_left()
        return self.max_row_s if left is None else max(0.0, min(self.max_row_s, left))

    def selects(self, implementation: str) -> bool:
        """Whether ``implementation`` passes the ``only`` filter."""
        return not self.only or any(fnmatch.fnmatchcase(implementation.lower(), p.lower()) for p in self.only)

    def data_file(self, name: str) -> pathlib.Path | str:
        """The shared data file ``name``, or why it is missing."""
        path = pathlib.Path(self.data_dir) / name
        return path if path.is_file() else (f"{path} not found (the shared data sits beside the clone; set "
                                            "JAXANIM_SHARED_DATA or --data-dir)")

    def float64_only(self, name: str, why: str) -> None:
        if "float64" not in self.dtypes:
            self.log(f"{name}: runs in float64 only ({why}); --dtype is ignored")

    def log(self, msg: str) -> None:
        """Print a progress line to stderr (when ``verbose``), after the section's seconds spent / budget."""
        if self.verbose:
            left, budget = self.time_left(), self.section_budget_s
            clock = "" if left is None else f"[{self.section} {budget - left:.0f}/{budget:g} s] "
            print(f"[benchmarks] {clock}{msg}", file=sys.stderr, flush=True)


@dataclasses.dataclass(frozen=True)
class BenchmarkSpec:
    """A registered benchmark: command-line name, ``"module:function"`` of its ``run(config)``, ``--help`` line."""

    name: str
    target: str
    description: str

    def load(self) -> Callable[[BenchConfig], list[Table]]:
        module, _, func = self.target.partition(":")
        return getattr(importlib.import_module(module), func)

REGISTRY: dict[str, BenchmarkSpec] = {s.name: s for s in (
    BenchmarkSpec("fk", "benchmarks.fk:run_fk",
                  "forward kinematics, 31-joint CMU skeleton: jaxanim vs naive JAX, numpy, Pinocchio"),
    BenchmarkSpec("jacobian", "benchmarks.fk:run_jacobian",
                  "6xN geometric Jacobian of 5 end effectors: jaxanim vs jacfwd, jacrev, Pinocchio"),
    BenchmarkSpec("ik", "benchmarks.ik:run_ik",
                  "5-effector IK (position + orientation), CMU skeleton: LM, optimistix, jaxopt, CCD, Pinocchio CLIK"),
    BenchmarkSpec("oc", "benchmarks.oc:run_oc",
                  "optimal control: iLQR/DDP/LQR/DARE vs Crocoddyl and scipy (unicycle, LQ, DARE, swing-ups)"),
    BenchmarkSpec("physics", "benchmarks.physics:run_physics",
                  "~20-body character standing under PD control: jaxanim (penalty, complementarity), MuJoCo C, MJX"),
    BenchmarkSpec("tracking", "benchmarks.tracking:run_tracking",
                  "SAMCON tracking of the shipped walk: samples/s (MuJoCo C rollouts as a reference), time to track 4 s"),
    BenchmarkSpec("matching", "benchmarks.matching:run_matching",
                  "motion matching: search of 1024 agents x 100k frames vs cKDTree and numpy; a 1024-agent crowd"),
    BenchmarkSpec("skinning", "benchmarks.skinning:run_skinning",
                  "LBS and DQS skinning, ~10k vertices x 1k frames of the shipped walk: jaxanim vs vectorised numpy"),
    BenchmarkSpec("retarget", "benchmarks.retarget:run_retarget",
                  "retargeting the walk at 32 speeds onto the Unitree G1: whole-clip solve vs mink per frame (GMR)"),
    BenchmarkSpec("profile", "benchmarks.profile:run_profile",
                  "where the time goes: jax.profiler traces of the kernels behind the speed targets"),
    BenchmarkSpec("scaling", "benchmarks.scaling:run_scaling",
                  "FK of the CMU skeleton sharded over 1 vs 2 devices and 2 processes (jax.distributed, localhost)"),
)}


#: The sections ``--gpu`` runs when no names are given: the accelerator sizes of issue 29 (``jacobian``, ``profile``
#: and ``scaling`` run when named).
ACCELERATOR_SECTIONS = ("fk", "ik", "physics", "tracking", "matching", "skinning", "oc")

#: Seconds per section under ``--gpu``: the sections of :data:`ACCELERATOR_SECTIONS` add up to 475 s, and the run
#: as a whole gets :data:`ACCELERATOR_TOTAL_S` (a row that starts within its budget runs to its end; the total cuts
#: the sections after an overrun short), so that it ends in about 9 minutes.
ACCELERATOR_BUDGET_S: dict[str, float] = {
    "fk": 55.0, "jacobian": 40.0, "ik": 75.0, "physics": 120.0, "tracking": 70.0, "matching": 45.0, "skinning": 35.0,
    "oc": 75.0, "retarget": 90.0, "profile": 60.0, "scaling": 60.0}
ACCELERATOR_TOTAL_S = 540.0


def run_benchmarks(names: Sequence[str], config: BenchConfig, command: str = "python -m benchmarks",
                   budgets: Mapping[str, float] | None = None, write: Callable[[list[Table]], None] | None = None,
                   total_s: float | None = None, rerun_busy: bool = False) -> list[Table]:
    """Run the named benchmarks (all if empty; the command line checks the names) in order, each as a section
    within ``budgets[name]`` seconds (if given) and what is left of ``total_s`` (if given); every table records
    how it was measured, with the cores other processes used meanwhile (:func:`_others`). With ``rerun_busy`` a
    section during which they used more than :data:`OTHERS_MAX` runs once more, where its budget leaves the time
    (at most half of it spent), and the report keeps the second run and says so. ``write`` receives the tables so far after every row (the running section's marked as
    such) and after every section. A section that raises keeps the rows it finished and ends with a failed table;
    the next section runs."""
    names = list(names) or list(REGISTRY)
    tables: list[Table] = []
    end = None if total_s is None else time.monotonic() + total_s
    for n in names:
        live: list[Table] = []  # the running section's tables, as its rows arrive

        def on_row(table: Table, live: list[Table] = live, n: str = n) -> None:
            if not any(t is table for t in live):
                live.append(table)
            if write is not None:
                note = f"*Section `{n}` was still running when this was written: the rows it had finished.*"
                write(tables + [dataclasses.replace(t, run=note) for t in live])

        budget = None if budgets is None else budgets.get(n)
        if end is not None:  # what is left of the run's total
            left = round(max(end - time.monotonic(), 0.0), 1)
            budget = left if budget is None else min(budget, left)
        first_others = None
        for attempt in (1, 2):  # a section that shared the CPU with other processes runs once more
            live.clear()
            cfg = dataclasses.replace(config, section=n, section_budget_s=budget, on_row=on_row,
                                      deadline=None if budget is None else time.monotonic() + budget)
            cfg.log(f"== {n}: {REGISTRY[n].description}" + ("" if budget is None else f" (time budget {budget:g} s)")
                    + (" (rerun: other processes shared the CPU)" if attempt == 2 else ""))
            load0, cpu0, start = _load(), _cpu_seconds(), time.perf_counter()
            try:
                new = REGISTRY[n].load()(cfg)
            except Exception as exc:  # a section that fails loses only itself
                traceback.print_exc()
                why = f"failed: {type(exc).__name__}: {(str(exc).splitlines() or [''])[0][:200]}"
                cfg.log(f"{n}: {why}")
                new = live + [Table(n, f"Benchmark `{n}`: failed", REGISTRY[n].description, skipped=why + (
                    " (the tables above are the rows it finished)" if live else ""))]
            wall = time.perf_counter() - start
            load1, others = _load(), _others(cpu0, _cpu_seconds(), wall)
            busy = others is not None and others > OTHERS_MAX
            rerun = (rerun_busy and attempt == 1 and busy
                     and (budget is None or (wall <= budget / 2 and (end is None or end - time.monotonic() > wall))))
            if not rerun:
                break
            first_others = others
            cfg.log(f"== {n}: other processes used {others:.2f} cores on average; running it again")
        mode = "quick" if config.quick else "accelerator" if config.accelerator else "full"
        shared = "" if others is None else (
            f"; other processes used {others:.2f} cores on average meanwhile"
            + (f" (above {OTHERS_MAX:g}: they inflated every time)" if busy else ""))
        again = "" if first_others is None else (
            f"; this is a second run: during the first, other processes used {first_others:.2f} cores")
        run = (f"*Measured by `{command}` (benchmark `{n}`, {mode} mode), finished {utc_now()}, in {wall:.0f} s"
               + ("" if budget is None else f" (section time budget {budget:g} s)") + f"; 1-minute load average "
               f"{load0} at its start and {load1} at its end on {os.cpu_count()} logical cores (the benchmark's own "
               f"work included){shared}{again}.*")
        for t in new:
            t.run = run
        tables.extend(new)
        cfg.log(f"== {n}: done in {wall:.0f} s")
        if write is not None:
            write(tables)
    return tables


def _load() -> str:
    return f"{os.getloadavg()[0]:.1f}" if hasattr(os, "getloadavg") else "n/a"


#: Cores that other processes may use on average during a section before it counts as measured on a busy machine
#: and runs once more: with a benchmark that keeps one core busy, the machine's load then stays at or below 1.5.
OTHERS_MAX = 0.5


def _cpu_seconds() -> tuple[float, float] | None:
    """``(busy, own)``: CPU seconds the whole machine has spent busy (``/proc/stat``: all but idle and iowait) and
    those of this process and its waited-for children; ``None`` where ``/proc/stat`` cannot be read."""
    try:
        with open("/proc/stat", encoding="ascii") as f:
            ticks = [float(x) for x in f.readline().split()[1:9]]
        hz = float(os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError):
        return None
    import resource

    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    own = me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime
    return (sum(ticks) - ticks[3] - ticks[4]) / hz, own


def _others(before, after, wall: float) -> float | None:
    """Cores that other processes kept busy on average between two :func:`_cpu_seconds` readings ``wall`` s
    apart: the machine's busy time less this process's own."""
    if before is None or after is None or wall <= 0:
        return None
    return max(0.0, ((after[0] - before[0]) - (after[1] - before[1])) / wall)
