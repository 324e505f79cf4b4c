"""Timing helpers shared by every benchmark.

Two things are measured, and reported apart:

* **compile time**: ``jax.jit(f).lower(*args).compile()``, timed once on a fresh ``jax.jit`` object
  (tracing + lowering + XLA compilation, what a user waits for on the first call);
* **run time**: the median (and min) over ``repeats`` samples, after ``warmup`` untimed calls, of one
  call whose outputs are waited for with :func:`jax.block_until_ready` (a no-op for numpy outputs).

A call that takes less than ``min_sample_s`` is repeated ``number`` times inside each sample (as
:mod:`timeit` does) and the sample is divided by ``number``, so microsecond calls are not dominated
by the timer. Every inner call is waited for, so the figure is the latency of one call, not the
throughput of a pipelined stream of asynchronous dispatches.
"""

from __future__ import annotations

import dataclasses
import math
import os
import statistics
import time
from collections.abc import Callable
from typing import Any

import jax

__all__ = ["CompileStats", "SampledTiming", "TimingStats", "compile_time", "load_note", "sample_call", "time_call"]

_LONG_CALL_S = 1.0


@dataclasses.dataclass(frozen=True)
class TimingStats:
    """Run-time statistics of one callable, in seconds per call.

    Attributes:
        median: median over the samples of the time of one call.
        min: the fastest sample.
        all: every sample (seconds per call), in the order taken.
        number: calls per sample (samples are divided by it).
        warmup: untimed calls made before the first sample.
    """

    median: float
    min: float
    all: tuple[float, ...]
    number: int
    warmup: int

    @property
    def repeats(self) -> int:
        """How many samples were taken."""
        return len(self.all)


@dataclasses.dataclass(frozen=True)
class CompileStats:
    """Ahead-of-time compilation cost of a jitted function, in seconds.

    Attributes:
        lower: ``jitted.lower(*args)`` (tracing and lowering to StableHLO).
        compile: ``lowered.compile()`` (XLA compilation).
        compiled: the compiled executable, callable with the same arguments.
    """

    lower: float
    compile: float
    compiled: Any = dataclasses.field(repr=False, compare=False)

    @property
    def total(self) -> float:
        """``lower + compile``: what the first call of ``jax.jit(f)`` costs on top of running."""
        return self.lower + self.compile


def compile_time(jitted: Callable[..., Any], *args: Any) -> CompileStats:
    """Time ``jitted.lower(*args).compile()``.

    Pass a *fresh* ``jax.jit(f)`` object that has never been called, so that no cache hides work.

    Args:
        jitted: a ``jax.jit``-wrapped function.
        *args: example arguments (arrays or ``jax.ShapeDtypeStruct``).

    Returns:
        The lowering and compilation times and the compiled executable, which the caller can time
        with :func:`time_call` without compiling a second time.
    """
    t0 = time.perf_counter()
    lowered = jitted.lower(*args)
    t1 = time.perf_counter()
    compiled = lowered.compile()
    t2 = time.perf_counter()
    return CompileStats(lower=t1 - t0, compile=t2 - t1, compiled=compiled)


def _call_blocking(fn: Callable[..., Any], args: tuple, number: int) -> float:
    t0 = time.perf_counter()
    for _ in range(number):
        jax.block_until_ready(fn(*args))
    return time.perf_counter() - t0


def time_call(
    fn: Callable[..., Any],
    *args: Any,
    repeats: int = 7,
    warmup: int = 2,
    min_sample_s: float = 2e-3,
    max_total_s: float | None = None,
    number: int | None = None,
) -> TimingStats:
    """Median and min wall-clock time of ``fn(*args)``, waiting for its outputs.

    Args:
        fn: the callable (jitted function, compiled executable, or plain Python).
        *args: its arguments; they are passed unchanged to every call.
        repeats: number of timed samples (at least 1).
        warmup: untimed calls before sampling (compilation, caches, allocator); the warm-up stops
            after the first call if that call took more than a second.
        min_sample_s: calls faster than this are looped ``number`` times per sample, with
            ``number`` chosen from the warm-up so that a sample lasts at least this long.
        max_total_s: optional budget for the samples: sampling stops early, after at least 3
            samples (or ``repeats`` if smaller), once the samples taken add up to more than this.
        number: force the number of calls per sample instead of calibrating it.

    Returns:
        The :class:`TimingStats`, in seconds per call.
    """
    if repeats < 1:
        raise ValueError(f"repeats: expected >= 1, got {repeats}")
    once = math.inf
    for _ in range(max(warmup, 1 if number is None else 0)):
        once = min(once, _call_blocking(fn, args, 1))
        if once > _LONG_CALL_S:  # one warm-up is enough for a call this long
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
    return TimingStats(
        median=statistics.median(samples), min=min(samples), all=tuple(samples), number=number, warmup=warmup
    )


@dataclasses.dataclass(frozen=True)
class SampledTiming:
    """What :func:`sample_call` measured: median and min seconds over ``samples`` calls."""

    median: float
    min: float
    samples: int


def sample_call(config: Any, fn: Callable[..., Any], args: tuple, first_s: float) -> SampledTiming:
    """Time ``fn(*args)`` within a benchmark's budget (``config``: a ``BenchConfig``).

    Short calls go through :func:`time_call` (``config.repeats`` samples, ``config.warmup - 1``
    warm-ups: the caller has made one call already); for a call longer than a second, that first
    call (``first_s`` seconds) is the first sample and more are taken only within
    ``config.max_row_s``."""
    if first_s <= _LONG_CALL_S:
        st = time_call(fn, *args, repeats=config.repeats, warmup=max(config.warmup - 1, 0),
                       max_total_s=config.max_row_s)
        return SampledTiming(st.median, st.min, st.repeats)
    samples = [first_s]
    while len(samples) < config.repeats and sum(samples) + samples[-1] <= config.max_row_s:
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        samples.append(time.perf_counter() - t0)
    return SampledTiming(statistics.median(samples), min(samples), len(samples))


def load_note(name: str, start: float, load0: tuple | None) -> str | None:
    """The closing note of a benchmark's report: its wall time since ``start`` (``perf_counter``)
    and the 1-minute load average at the start (``load0``, from ``os.getloadavg``) and now."""
    if load0 is None:
        return None
    load1 = os.getloadavg()
    return (
        f"The {name} benchmark took {time.perf_counter() - start:.0f} s; 1-minute load average {load0[0]:.1f} at the "
        f"start and {load1[0]:.1f} at the end on {os.cpu_count()} logical cores (a load above the core count "
        "means other processes shared the CPU and inflated every time here)."
    )
