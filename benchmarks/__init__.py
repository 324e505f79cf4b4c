"""Benchmarks of jaxanim against its peers: ``python -m benchmarks [NAME ...] [--quick]``. :data:`REGISTRY` maps
the command-line names to ``run(config: BenchConfig) -> list[Table]`` functions, imported lazily so that one
benchmark's missing dependency never stops another; missing peers are ``skipped`` rows."""

from __future__ import annotations

import dataclasses
import fnmatch
import importlib
import os
import pathlib
import sys
import time
from collections.abc import Callable, Sequence

from .report import Row as Row, Table as Table, utc_now

__all__ = ["REGISTRY", "BenchConfig", "BenchmarkSpec", "Row", "Table", "default_data_dir", "run_benchmarks"]

REPO = pathlib.Path(__file__).resolve().parents[1]


def default_data_dir() -> pathlib.Path:
    """The shared reference data: ``$JAXANIM_SHARED_DATA`` or ``../shared/data`` beside the clone."""
    env = os.environ.get("JAXANIM_SHARED_DATA")
    return pathlib.Path(env) if env else REPO.parent / "shared" / "data"


@dataclasses.dataclass(frozen=True)
class BenchConfig:
    """Settings shared by every benchmark of one run: ``batches`` (overrides every benchmark's), timed samples
    (``repeats``) after ``warmup`` calls within ``max_row_s`` per row, the most configurations a Python-loop peer
    runs per timed call (``loop_cap``) and ``only`` the implementations matching a case-insensitive shell pattern."""

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

    @classmethod
    def make_quick(cls, **kwargs) -> BenchConfig:
        """A configuration for smoke tests: batches (1, 8), 3 repeats, 1 warm-up, loop cap 8."""
        return cls(**dict(quick=True, batches=(1, 8), repeats=3, warmup=1, max_row_s=1.0, loop_cap=8) | kwargs)

    def batches_for(self, default: Sequence[int]) -> tuple[int, ...]:
        return tuple(self.batches) if self.batches is not None else tuple(default)

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
        """Print a progress line to stderr (when ``verbose``)."""
        if self.verbose:
            print(f"[benchmarks] {msg}", file=sys.stderr, flush=True)


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
                  "SAMCON tracking of the shipped walk: samples/s vs MuJoCo C rollouts of the batch, time to track 4 s"),
    BenchmarkSpec("matching", "benchmarks.matching:run_matching",
                  "motion matching: search of 1024 agents x 100k frames vs cKDTree and numpy; a 1024-agent crowd"),
    BenchmarkSpec("skinning", "benchmarks.skinning:run_skinning",
                  "LBS and DQS skinning, ~10k vertices x 1k frames of the shipped walk: jaxanim vs vectorised numpy"),
    BenchmarkSpec("profile", "benchmarks.profile:run_profile",
                  "where the time goes: jax.profiler traces of the kernels behind the speed targets"),
    BenchmarkSpec("scaling", "benchmarks.scaling:run_scaling",
                  "FK of the CMU skeleton sharded over 1 vs 2 devices and 2 processes (jax.distributed, localhost)"),
)}


def run_benchmarks(names: Sequence[str], config: BenchConfig, command: str = "python -m benchmarks") -> list[Table]:
    """Run the named benchmarks (all if empty; the command line checks the names) in order; every table records
    how it was measured."""
    names = list(names) or list(REGISTRY)
    tables: list[Table] = []
    for n in names:
        config.log(f"== {n}: {REGISTRY[n].description}")
        load0, start = _load(), time.perf_counter()
        new = REGISTRY[n].load()(config)
        load1, cores = _load(), os.cpu_count()
        busy = any(x != "n/a" and float(x) > cores for x in (load0, load1))
        run = (f"*Measured by `{command}` (benchmark `{n}`, {'quick' if config.quick else 'full'} mode), finished "
               f"{utc_now()}, in {time.perf_counter() - start:.0f} s; 1-minute load average {load0} at its start and "
               f"{load1} at its end on {cores} logical cores"
               + (" (above the core count: other processes shared the CPU and inflated every time)" if busy else "")
               + ".*")
        for t in new:
            t.run = run
        tables.extend(new)
    return tables


def _load() -> str:
    return f"{os.getloadavg()[0]:.1f}" if hasattr(os, "getloadavg") else "n/a"
