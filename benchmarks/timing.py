"""Timing (compile time, and apart from it the median / min run time of calls waited for with ``block_until_ready``)
and the one harness, :class:`Runner`, that turns a measurement into a :class:`~benchmarks.report.Row`."""

from __future__ import annotations

import dataclasses
import math
import statistics
import time
import traceback
from collections.abc import Callable
from typing import Any

import jax
import numpy as np

import solvers

from .peers import PeerUnavailable
from .report import Row, Table

__all__ = ["CompileStats", "Runner", "Timing", "compile_time", "sample_call", "status_counts", "time_call"]

_LONG_CALL_S = 1.0
_CALL_BUDGET_FACTOR = 4.0  # a row is skipped when one call is expected to take > this x max_row_s


@dataclasses.dataclass(frozen=True)
class Timing:
    """Seconds per call, median and min over the samples (``all``, or their count ``samples``), calls per sample."""

    median: float
    min: float | None
    samples: int
    number: int = 1
    all: tuple[float, ...] = ()


@dataclasses.dataclass(frozen=True)
class CompileStats:
    """``lower`` and ``compile`` seconds of a jitted function, and the compiled executable."""

    lower: float
    compile: float
    compiled: Any = dataclasses.field(repr=False, compare=False)
    total = property(lambda self: self.lower + self.compile)


def compile_time(jitted: Callable[..., Any], *args: Any) -> CompileStats:
    """Time ``jitted.lower(*args).compile()`` (on a fresh ``jax.jit`` object, so no cache hides work)."""
    t0 = time.perf_counter()
    lowered = jitted.lower(*args)
    t1 = time.perf_counter()
    compiled = lowered.compile()
    return CompileStats(lower=t1 - t0, compile=time.perf_counter() - t1, compiled=compiled)


def _call_blocking(fn: Callable[..., Any], args: tuple, number: int) -> float:
    t0 = time.perf_counter()
    for _ in range(number):
        jax.block_until_ready(fn(*args))
    return time.perf_counter() - t0


def time_call(fn: Callable[..., Any], *args: Any, repeats: int = 7, warmup: int = 2, min_sample_s: float = 2e-3,
              max_total_s: float | None = None, number: int | None = None) -> Timing:
    """Median and min seconds of ``fn(*args)`` after ``warmup`` calls (one if it takes over a second); calls faster
    than ``min_sample_s`` run ``number`` times per sample (calibrated unless given); sampling stops past
    ``max_total_s`` once 3 samples (or ``repeats``) were taken."""
    if repeats < 1:
        raise ValueError(f"repeats: expected >= 1, got {repeats}")
    once = math.inf
    for _ in range(max(warmup, 1 if number is None else 0)):
        once = min(once, _call_blocking(fn, args, 1))
        if once > _LONG_CALL_S:
            break
    if number is None:
        number = 1 if once >= min_sample_s else max(1, min(10_000, math.ceil(min_sample_s / max(once, 1e-7))))
    samples: list[float] = []
    spent = 0.0
    for i in range(repeats):
        s = _call_blocking(fn, args, number)
        spent += s
        samples.append(s / number)
        if max_total_s is not None and spent > max_total_s and i + 1 >= min(3, repeats):
            break
    return Timing(statistics.median(samples), min(samples), len(samples), number, tuple(samples))


def sample_call(config: Any, fn: Callable[..., Any], args: tuple, first_s: float) -> Timing:
    """Time ``fn(*args)`` within ``config``'s budget after the caller's first call (``first_s``), which
    is the first sample of a call over a second (more are taken while they fit in ``max_row_s``)."""
    if first_s <= _LONG_CALL_S:
        return time_call(fn, *args, repeats=config.repeats, warmup=max(config.warmup - 1, 0),
                         max_total_s=config.max_row_s)
    samples = [first_s]
    while len(samples) < config.repeats and sum(samples) + samples[-1] <= config.max_row_s:
        samples.append(_call_blocking(fn, args, 1))
    return Timing(statistics.median(samples), min(samples), len(samples))


def _first_line(exc: BaseException) -> str:
    return (str(exc).splitlines() or [""])[0][:200]


class Runner:
    """Adds the rows of one table: filters, budget, missing peers and failures handled in one place."""

    def __init__(self, config: Any, table: Table):
        self.config, self.table = config, table
        self._failed: dict[tuple[str, str | None], str | None] = {}

    def jax(self, fn: Callable[..., Any], *args: Any) -> tuple[Any, Timing, float]:
        """``(output, timing, compile seconds)`` of ``jax.jit(fn)``, compiled ahead of time, called once and timed."""
        cs = compile_time(fn if hasattr(fn, "lower") else jax.jit(fn), *args)
        t0 = time.perf_counter()
        out = jax.block_until_ready(cs.compiled(*args))
        return out, sample_call(self.config, cs.compiled, args, time.perf_counter() - t0), cs.total

    def python(self, fn: Callable[..., Any], *args: Any) -> tuple[Any, Timing]:
        """Call ``fn(*args)`` once (its value is returned) and time it like a jitted call."""
        t0 = time.perf_counter()
        out = fn(*args)
        return out, sample_call(self.config, fn, args, time.perf_counter() - t0)

    def _budget(self, impl: str, dtype: str | None, batch: int | None, max_batch: int | None) -> str | None:
        prev = [r for r in self.table.rows if r.implementation == impl and r.dtype == dtype and r.measured
                and r.batch is not None and batch is not None and r.batch < batch]
        if not prev:
            return None
        last = max(prev, key=lambda r: r.batch)
        if len(prev) >= 2 and all(r.success == 0 for r in prev):
            return f"not run (time budget): 0 % success at batches {', '.join(str(r.batch) for r in prev)}"
        est = last.time_median_s * batch / last.batch
        if max_batch is not None and not self.config.quick and batch > max_batch:
            return (f"not run above batch {max_batch} (time budget): ~{est:.0f} s per call expected from batch "
                    f"{last.batch}")
        budget = _CALL_BUDGET_FACTOR * self.config.max_row_s
        if est > budget:
            return f"not run (time budget): ~{est:.0f} s per call expected from batch {last.batch}, over {budget:.0f} s"
        return None

    def add(self, impl: str, dtype: str | None, batch: int | None, make: Callable[[], Row], *, peer: bool = False,
            max_batch: int | None = None) -> Row | None:
        """Append the row ``make()`` measures, or the reason it did not run; return it if measured. A missing
        peer (``ImportError``, :class:`~benchmarks.peers.PeerUnavailable`) is one skipped row for the
        implementation; a failure is a ``failed:`` row, and later batches point to it."""
        if not self.config.selects(impl):
            return None
        key = (impl, dtype)
        why = self._failed.get(key, self._failed.get((impl, None), ""))
        if why is None:  # the skipped row is already there
            return None
        if why := why or self._budget(impl, dtype, batch, max_batch):
            row = Row(impl, dtype, batch, skipped=why, is_peer=peer)
        else:
            try:
                row = make()
                row.is_peer = peer
            except (ImportError, PeerUnavailable) as exc:
                row = Row(impl, skipped=_first_line(exc) or type(exc).__name__, is_peer=peer)
                self._failed[(impl, None)] = None
            except Exception as exc:  # a failure is reported, not fatal
                traceback.print_exc()
                row = Row(impl, dtype, batch, skipped=f"failed: {type(exc).__name__}: {_first_line(exc)}",
                          is_peer=peer)
                self._failed[key] = f"failed at batch {batch} (see that row)"
        self._log(row)
        self.table.rows.append(row)
        return row if row.measured else None

    def _log(self, r: Row) -> None:
        head = f"{self.table.name} {r.dtype} B={r.batch}: {r.implementation}:"
        if not r.measured:
            return self.config.log(f"{head} {r.skipped}")
        comp = "" if r.compile_s is None else f", compile {r.compile_s:.2f} s"
        succ = "" if r.success is None else f", success {100 * r.success:.1f} %"
        us = "" if r.us_per_char is None else f" {r.us_per_char:.4g} µs/char"
        self.config.log(f"{head}{us}{comp}{succ}, accuracy {r.accuracy}")

    def row(self, impl: str, dtype: str, batch: int, tm: Timing | None, per_call: int | None = None,
            compile_s: float | None = None, accuracy: Any = None, **kw: Any) -> Row:
        """A measured :class:`Row` from a :class:`Timing` (``per_call``: problems per timed call)."""
        return Row(impl, dtype, batch, tm.median if tm else None, tm.min if tm else None, per_call or batch,
                   compile_s, accuracy, samples=tm.samples if tm else None, **kw)


def status_counts(result: Any, enumeration: Any = solvers.RESULTS) -> dict[str, int]:
    """Counts of each status but success in a (batched) solver ``result``."""
    counts = ((name, int(np.sum(np.asarray(result == item)))) for name, item in enumeration._name_to_item.items())
    return {name: n for name, n in counts if n and name != "successful"}
