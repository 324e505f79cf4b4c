"""Benchmarks of jaxanim against its peers: ``python -m benchmarks [NAME ...] [--quick]``.

Each benchmark is a function ``run(config: BenchConfig) -> list[Table]`` in a module of this package;
:data:`REGISTRY` maps the names accepted on the command line to those functions (imported lazily, so
one benchmark's missing dependency never stops another): ``fk``, ``jacobian`` (:mod:`benchmarks.fk`),
``ik`` (:mod:`benchmarks.ik`), ``oc`` (:mod:`benchmarks.oc`) and ``physics`` (:mod:`benchmarks.physics`). To add a
benchmark, write ``benchmarks/<name>.py`` with such a function and add one :class:`BenchmarkSpec` line to
:data:`REGISTRY`. Peers live in ``benchmarks/peers/`` and raise
:class:`benchmarks.peers.PeerUnavailable` when they cannot be imported; the benchmark then reports
them as ``skipped: <reason>`` rows.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import importlib
import os
import pathlib
import sys
from collections.abc import Callable, Sequence

from .report import Row as Row, Table as Table

__all__ = ["REGISTRY", "BenchConfig", "BenchmarkSpec", "Row", "Table", "default_data_dir", "run_benchmarks"]

REPO = pathlib.Path(__file__).resolve().parents[1]


def default_data_dir() -> pathlib.Path:
    """The shared reference data: ``$JAXANIM_SHARED_DATA`` or ``../shared/data`` beside the clone."""
    env = os.environ.get("JAXANIM_SHARED_DATA")
    return pathlib.Path(env) if env else REPO.parent / "shared" / "data"


@dataclasses.dataclass(frozen=True)
class BenchConfig:
    """Settings shared by every benchmark of one run.

    Attributes:
        quick: small batches and few repeats (for tests and smoke runs).
        dtypes: the dtypes to run, ``"float32"`` and/or ``"float64"``.
        batches: if set, overrides every benchmark's batch sizes.
        repeats: timed samples per row (the median and min are reported).
        warmup: untimed calls per row before sampling.
        max_row_s: sampling budget per row; sampling stops early (after 3 samples) past it.
        loop_cap: Python-loop peers (Pinocchio) run at most this many configurations per timed
            call and report time per configuration.
        data_dir: the shared data folder (``bvh/``, ``fk/``).
        only: if set, run only the implementations whose name matches one of these shell-style
            patterns (case-insensitive :func:`fnmatch.fnmatch`), e.g. ``("jaxanim*", "pinocchio*")``.
        verbose: print progress to stderr.
    """

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
        kw = dict(quick=True, batches=(1, 8), repeats=3, warmup=1, max_row_s=1.0, loop_cap=8)
        kw.update(kwargs)
        return cls(**kw)

    def batches_for(self, default: Sequence[int]) -> tuple[int, ...]:
        """The batch sizes to run: the override if given, else ``default``."""
        return tuple(self.batches) if self.batches is not None else tuple(default)

    def selects(self, implementation: str) -> bool:
        """Whether ``implementation`` passes the ``only`` filter."""
        if not self.only:
            return True
        name = implementation.lower()
        return any(fnmatch.fnmatchcase(name, pattern.lower()) for pattern in self.only)

    def log(self, msg: str) -> None:
        """Print a progress line to stderr (when ``verbose``)."""
        if self.verbose:
            print(f"[benchmarks] {msg}", file=sys.stderr, flush=True)


@dataclasses.dataclass(frozen=True)
class BenchmarkSpec:
    """A registered benchmark.

    Attributes:
        name: the name used on the command line.
        target: ``"module:function"`` of the ``run(config) -> list[Table]`` function.
        description: one line for ``--help``.
    """

    name: str
    target: str
    description: str

    def load(self) -> Callable[[BenchConfig], list[Table]]:
        """Import and return the benchmark's run function."""
        module, _, func = self.target.partition(":")
        return getattr(importlib.import_module(module), func)


REGISTRY: dict[str, BenchmarkSpec] = {
    s.name: s
    for s in (
        BenchmarkSpec(
            "fk", "benchmarks.fk:run_fk",
            "forward kinematics, 31-joint CMU skeleton: jaxanim vs naive JAX, numpy, Pinocchio",
        ),
        BenchmarkSpec(
            "jacobian", "benchmarks.fk:run_jacobian",
            "6xN geometric Jacobian of 5 end effectors: jaxanim vs jacfwd, jacrev, Pinocchio",
        ),
        BenchmarkSpec(
            "ik", "benchmarks.ik:run_ik",
            "IK, 5 effectors (position + orientation), CMU skeleton: LM, optimistix, jaxopt, CCD, Pinocchio CLIK",
        ),
        BenchmarkSpec(
            "oc", "benchmarks.oc:run_oc",
            "optimal control: iLQR/DDP/LQR/DARE vs Crocoddyl and scipy (unicycle, LQ, DARE, swing-ups)",
        ),
        BenchmarkSpec(
            "physics", "benchmarks.physics:run_physics",
            "~20-body character standing under PD control: jaxanim (penalty, complementarity) vs MuJoCo C and MJX",
        ),
    )
}


def run_benchmarks(names: Sequence[str], config: BenchConfig) -> list[Table]:
    """Run the named benchmarks in order and collect their tables.

    Args:
        names: registered names (see :data:`REGISTRY`); an empty sequence runs all of them.
        config: the shared settings.

    Returns:
        Every benchmark's tables, in order.

    Raises:
        KeyError: an unknown name (the message lists the valid ones).
    """
    names = list(names) or list(REGISTRY)
    unknown = [n for n in names if n not in REGISTRY]
    if unknown:
        raise KeyError(f"unknown benchmark(s) {unknown}; registered: {sorted(REGISTRY)}")
    tables: list[Table] = []
    for n in names:
        config.log(f"== {n}: {REGISTRY[n].description}")
        tables.extend(REGISTRY[n].load()(config))
    return tables
