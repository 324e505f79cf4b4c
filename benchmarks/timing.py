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

__all__ = ["CompileStats", "Runner", "Timing", "budget_spent", "compile_time", "row_limits", "sample_call",
           "status_counts", "time_call"]

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
              max_total_s: float | None = None, number: int | None = None, min_samples: int = 3) -> Timing:
    """Median and min seconds of ``fn(*args)`` after ``warmup`` calls (one if it takes over a second); calls faster
    than ``min_sample_s`` run ``number`` times per sample (calibrated unless given); sampling stops past
    ``max_total_s`` once ``min_samples`` (or ``repeats``) were taken."""
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
        if max_total_s is not None and spent > max_total_s and i + 1 >= min(min_samples, repeats):
            break
    return Timing(statistics.median(samples), min(samples), len(samples), number, tuple(samples))


def row_limits(config: Any) -> tuple[float, int]:
    """``(seconds, samples)``: how long a row may sample and the fewest samples it takes: ``max_row_s`` and 3, or
    what is left of the section's time budget and 1 once that is shorter."""
    limit = config.row_time_s()
    return limit, 3 if limit >= config.max_row_s else 1


def sample_call(config: Any, fn: Callable[..., Any], args: tuple, first_s: float) -> Timing:
    """Time ``fn(*args)`` within ``config``'s budget after the caller's first call (``first_s``), which
    is the first sample of a call over a second (more are taken while they fit in ``max_row_s`` and the section's
    time left: :func:`row_limits`)."""
    limit, fewest = row_limits(config)
    if first_s <= _LONG_CALL_S:
        return time_call(fn, *args, repeats=config.repeats, warmup=max(config.warmup - 1, 0), max_total_s=limit,
                         min_samples=fewest)
    samples = [first_s]
    while len(samples) < config.repeats and sum(samples) + samples[-1] <= limit:
        samples.append(_call_blocking(fn, args, 1))
    return Timing(statistics.median(samples), min(samples), len(samples))


def budget_spent(config: Any) -> str | None:
    """The skipped reason of a row once the running section's time budget is spent, else ``None``."""
    left = config.time_left()
    return None if left is None or left > 0 else f"not run (section time budget of {config.section_budget_s:g} s spent)"


def _row_seconds(compile_s: float | None, call_s: float) -> float:
    """What a row takes: its compile, a first call and the fewest samples (1 after a call over a second, else 3:
    the first call, the calibrating call, one sample)."""
    return (compile_s or 0.0) + call_s * (1 if call_s > _LONG_CALL_S else 3)


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
        """Why the row should not run (time budget), or ``None``: the section's time is spent, or the previous
        batch's row predicts a call over ``4 x max_row_s``, or the row is expected to end past the section's
        deadline (from the previous batch's row, else the same batch's in another dtype, else the table's median
        row: compile, first call and the fewest samples)."""
        if spent := budget_spent(self.config):
            return spent
        left = self.config.time_left()
        budget_s = self.config.section_budget_s
        timed = [r for r in self.table.rows if r.implementation == impl and r.measured and r.batch is not None
                 and batch is not None and r.time_median_s is not None]
        prev = [r for r in timed if r.dtype == dtype and r.batch < batch]
        if prev:
            last = max(prev, key=lambda r: r.batch)
            if len(prev) >= 2 and all(r.success == 0 for r in prev):
                return f"not run (time budget): 0 % success at batches {', '.join(str(r.batch) for r in prev)}"
            est = last.time_median_s * batch / last.batch
            if max_batch is not None and not self.config.quick and batch > max_batch:
                return (f"not run above batch {max_batch} (time budget): ~{est:.0f} s per call expected from batch "
                        f"{last.batch}")
            budget = _CALL_BUDGET_FACTOR * self.config.max_row_s
            if est > budget:
                return (f"not run (time budget): ~{est:.0f} s per call expected from batch {last.batch}, over "
                        f"{budget:.0f} s")
            source = f"batch {last.batch}"
            row_s = _row_seconds(last.compile_s, est)
        elif left is None:
            return None
        elif twins := [r for r in timed if r.batch == batch and r.dtype != dtype]:  # the same batch, another dtype
            last = max(twins, key=lambda r: _row_seconds(r.compile_s, r.time_median_s))
            row_s, source = _row_seconds(last.compile_s, last.time_median_s), f"the {last.dtype} row"
        else:  # no history: the table's median row so far
            seen = sorted(_row_seconds(r.compile_s, r.time_median_s) for r in self.table.rows
                          if r.measured and r.time_median_s is not None)
            if not seen:
                return None
            row_s, source = seen[len(seen) // 2], "the median row of this table so far"
        if left is not None and row_s > left:
            return (f"not run (section time budget of {budget_s:g} s): ~{row_s:.0f} s expected from {source}, "
                    f"{left:.0f} s left")
        return None

    def add(self, impl: str, dtype: str | None, batch: int | None, make: Callable[[], Row], *, peer: bool = False,
            max_batch: int | None = None) -> Row | None:
        """Append the row ``make()`` measures, or the reason it did not run; return it if measured. A missing
        peer (``ImportError``, :class:`~benchmarks.peers.PeerUnavailable`) is one skipped row for the
        implementation; a failure is a ``failed:`` row, and later batches point to it. Each row is logged as it
        starts and ends, and handed to ``config.on_row`` (the run's writer) once added."""
        if not self.config.selects(impl):
            return None
        key = (impl, dtype)
        why = self._failed.get(key, self._failed.get((impl, None), ""))
        if why is None:  # the skipped row is already there
            return None
        if why := why or self._budget(impl, dtype, batch, max_batch):
            row = Row(impl, dtype, batch, skipped=why, is_peer=peer)
        else:
            self.config.log(f"{self.table.name} {dtype} B={batch}: {impl}: running")
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
        if (on_row := self.config.on_row) is not None:
            on_row(self.table)
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
