"""Rows as data (:class:`Row`, :class:`Table`, :class:`Target`) and the one template that writes them,
:func:`render_table`: the table, the best peers, each target met / missed with its rows, the notes, the run."""

from __future__ import annotations

import dataclasses
import datetime
import importlib.metadata
import os
import platform
from collections.abc import Callable, Sequence
from typing import Any

__all__ = ["Row", "Table", "Target", "collect_environment", "describe_device", "format_seconds", "render_report",
           "render_table", "sel"]

_DASH = "—"


@dataclasses.dataclass
class Row:
    """What one implementation measured at one dtype and batch: seconds per timed call of ``chars_per_call``
    problems or character-steps (``batch`` unless a Python loop was capped), ``compile_s`` (lower + compile),
    ``accuracy`` (number or text), ``success`` (fraction solved), ``status`` (counts of the other statuses),
    ``samples`` (timed calls), why it was ``skipped`` and ``extra`` values later rows need (not rendered)."""

    implementation: str
    dtype: str | None = None
    batch: int | None = None
    time_median_s: float | None = None
    time_min_s: float | None = None
    chars_per_call: int | None = None
    compile_s: float | None = None
    accuracy: float | str | None = None
    success: float | None = None
    status: dict[str, int] = dataclasses.field(default_factory=dict)
    samples: int | None = None
    is_peer: bool = False
    note: str = ""
    skipped: str | None = None
    extra: dict[str, Any] = dataclasses.field(default_factory=dict, repr=False)

    def _per_char(self, t: float | None) -> float | None:  # µs per problem (character-step, capped configuration)
        return None if t is None else t / (self.chars_per_call or self.batch or 1) * 1e6

    us_per_char = property(lambda self: self._per_char(self.time_median_s))
    min_us_per_char = property(lambda self: self._per_char(self.time_min_s))
    measured = property(lambda self: self.skipped is None)


def sel(prefix: str | tuple[str, ...] = "", dtype: str | None = None, batch: int | None = None,
        exact: bool = False) -> Callable[[Row], bool]:
    """A row predicate: implementation starting with (or, ``exact``, equal to) ``prefix``, dtype, batch."""
    names = (prefix,) if isinstance(prefix, str) else prefix
    return lambda r: (any(r.implementation == p if exact else r.implementation.startswith(p) for p in names)
                      and dtype in (None, r.dtype) and batch in (None, r.batch))


@dataclasses.dataclass(frozen=True)
class Target:
    """A goal judged on the rows: the best (or ``worst``) selected row's ``metric`` (``"us"``: median µs per
    problem, ``"min_us"``, ``"compile"`` s, or ``"success"``, higher is better) against ``limit``; with
    ``versus``, the speedup of the selected row over the fastest ``versus`` row must be at least ``limit``."""

    text: str
    select: Callable[[Row], bool]
    limit: float
    metric: str = "us"
    worst: bool = False
    versus: Callable[[Row], bool] | None = None


@dataclasses.dataclass
class Table:
    """One section: a problem (``title``, ``description``), its rows, its targets, measured facts
    (``notes``), why it was ``skipped`` if it was, and how it was measured (``run``)."""

    name: str
    title: str
    description: str = ""
    accuracy_label: str = "max abs err"
    rows: list[Row] = dataclasses.field(default_factory=list)
    targets: list[Target] = dataclasses.field(default_factory=list)
    notes: list[str] = dataclasses.field(default_factory=list)
    skipped: str | None = None
    run: str = ""


def utc_now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def format_seconds(s: float | None) -> str:
    """``1.23 ms``-style rendering with 3 significant digits; an em dash for ``None``."""
    if s is None:
        return _DASH
    for unit, scale in (("s", 1.0), ("ms", 1e-3), ("µs", 1e-6)):
        if abs(s) >= scale:
            return f"{s / scale:.3g} {unit}"
    return f"{s / 1e-9:.3g} ns"


def _num(x: float | None) -> str:
    return _DASH if x is None else "0" if x == 0 else f"{x:.2e}" if abs(x) >= 1e4 or abs(x) < 1e-2 else f"{x:.3g}"


def _acc(a: float | str | None) -> str:
    return _DASH if a is None else a if isinstance(a, str) else "0" if a == 0 else f"{a:.2e}"


def _best_peers(rows: Sequence[Row]) -> dict[int, Row]:  # the fastest peer per batch (the first of a tie)
    peers = sorted([r for r in rows if r.measured and r.is_peer and r.us_per_char is not None],
                   key=lambda r: r.us_per_char)
    return {r.batch: r for r in reversed(peers)}


def _notes_cell(r: Row) -> str:
    parts = [r.note] if r.note else []
    if r.status:
        parts.append(f"status (of {r.batch}): " + ", ".join(f"{k} {v}" for k, v in r.status.items()))
    if r.samples is not None and r.samples < 3:
        parts.append(f"{r.samples} timed call{'s' if r.samples != 1 else ''}")
    return "; ".join(parts)


def _metric(r: Row, metric: str) -> float | None:
    return {"us": r.us_per_char, "min_us": r.min_us_per_char, "compile": r.compile_s, "success": r.success}[metric]


def _fmt_metric(x: float, metric: str) -> str:
    return f"{100 * x:.1f} %" if metric == "success" else format_seconds(x) if metric == "compile" else f"{x:.3g} µs"


def _who(r: Row) -> str:
    capped = r.chars_per_call and r.batch and r.chars_per_call < r.batch
    n = f", {r.chars_per_call} of {r.batch} timed" if capped else ""
    return f"{r.implementation} ({r.dtype}, batch {r.batch}{n})"


def judge(target: Target, rows: Sequence[Row]) -> str:
    """The target's line: the value, the row(s) it comes from, met or missed."""
    key = lambda r: _metric(r, target.metric)  # noqa: E731
    higher = target.metric == "success"
    cands = [r for r in rows if r.measured and target.select(r) and key(r) is not None]
    if not cands:
        return f"Target: {target.text}: not measured in this run."
    cands.sort(key=key, reverse=higher != target.worst)  # the judged row first
    r = cands[0]
    if target.versus is not None:
        peers = [p for p in rows if p.measured and target.versus(p) and key(p) is not None]
        if not peers:
            return f"Target: {target.text}: not measured in this run (no row to compare with)."
        p = min(peers, key=key)
        x = key(p) / key(r)
        return (f"Target: {target.text}: {_who(r)} {_fmt_metric(key(r), target.metric)} vs {_who(p)} "
                f"{_fmt_metric(key(p), target.metric)} = {x:.3g}x: {'met' if x >= target.limit else 'missed'}.")
    ok = key(r) >= target.limit if higher else key(r) <= target.limit
    ranged = target.worst and len(cands) > 1
    span = f" (range {_fmt_metric(key(cands[-1]), target.metric)} to it over {len(cands)} rows)" if ranged else ""
    return f"Target: {target.text}: {'worst' if target.worst else 'best'} {_who(r)} " \
           f"{_fmt_metric(key(r), target.metric)}{span}: {'met' if ok else 'missed'}."


def render_table(table: Table) -> str:
    """The one template: heading, description, table, best peers, targets, facts, run line."""
    out = [f"## {table.title}", ""]
    if table.description:
        out += [table.description.strip(), ""]
    if table.skipped is not None:
        return "\n".join(out + [f"**skipped:** {table.skipped}", ""] + ([table.run, ""] if table.run else []))
    show_success = any(r.success is not None for r in table.rows)
    header = ["implementation", "dtype", "batch", "time / call, median (min)", "µs / char", "compile",
              table.accuracy_label] + (["success"] if show_success else []) + ["× best peer", "notes"]
    out.append("| " + " | ".join(header) + " |")
    out.append("|" + "|".join(["---"] * 3 + ["---:"] * (len(header) - 4) + ["---"]) + "|")
    best = _best_peers(table.rows)
    for r in table.rows:
        if not r.measured:
            cells = [r.implementation, r.dtype or _DASH, str(r.batch) if r.batch else _DASH, f"skipped: {r.skipped}"]
            cells += [_DASH] * (len(header) - 5) + [r.note]
        else:
            ok = r.batch in best and r.us_per_char is not None
            ratio = f"{r.us_per_char / best[r.batch].us_per_char:.3g}×" if ok else _DASH
            cells = [r.implementation, r.dtype or _DASH, str(r.batch),
                     f"{format_seconds(r.time_median_s)} ({format_seconds(r.time_min_s)})", _num(r.us_per_char),
                     format_seconds(r.compile_s), _acc(r.accuracy)]
            if show_success:
                cells.append(_DASH if r.success is None else f"{100 * r.success:.1f} %")
            cells += [ratio, _notes_cell(r)]
        out.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    out.append("")
    if best:
        out += ["Best peer per batch (µs per character): " + ", ".join(
            f"{b}: {r.implementation} {r.dtype} ({_num(r.us_per_char)} µs"
            + (f", {100 * r.success:.1f} % success" if r.success is not None and r.success < 0.995 else "") + ")"
            for b, r in sorted(best.items())) + ". The × best peer column compares time only.", ""]
    lines = [judge(t, table.rows) for t in table.targets] + list(table.notes)
    out += [f"- {n}" for n in lines] + ([""] if lines else [])
    if table.run:
        out += [table.run, ""]
    return "\n".join(out)


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            return next(ln.split(":", 1)[1].strip() for ln in f if ln.lower().startswith("model name"))
    except (OSError, StopIteration):
        return platform.processor() or platform.machine() or "unknown"


def _version(dist: str) -> str:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


def usable_cores() -> int:
    """Cores this process may use."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def describe_device() -> str:
    """What JAX runs on: its backend, the devices' count and kind, and an accelerator's memory, e.g. ``gpu: 1 ×
    NVIDIA H200, 139.8 GiB`` or ``cpu: 1 × cpu (no accelerator)``."""
    import jax

    devices = jax.devices()
    kinds = ", ".join(sorted({getattr(d, "device_kind", "?") for d in devices}))
    text = f"{jax.default_backend()}: {len(devices)} × {kinds}"
    if jax.default_backend() == "cpu":
        return text + " (no accelerator)"
    try:
        limit = (devices[0].memory_stats() or {}).get("bytes_limit")
    except Exception:  # noqa: BLE001 -- memory_stats is optional per backend
        limit = None
    return text + (f", {limit / 2**30:.1f} GiB" if limit else "")


def _jax_plugins() -> dict[str, str]:
    """Versions of the installed JAX backend plugins (``jax-cuda12-plugin``, ``jax-cuda12-pjrt``, ``libtpu``...)."""
    names = {d.metadata["Name"].lower().replace("_", "-") for d in importlib.metadata.distributions()
             if d.metadata["Name"]}
    plugins = sorted(n for n in names if n.startswith(("jax-cuda", "jax-rocm", "libtpu")))
    return {n: _version(n) for n in plugins}


def collect_environment() -> dict[str, str]:
    """Machine and library facts for the report header (device, CPU, cores, devices, versions, x64)."""
    import jax

    env = {"date": utc_now(), "device": describe_device(), "CPU": _cpu_model(),
           "cores": f"{os.cpu_count()} logical, {usable_cores()} usable by this process",
           "devices": ", ".join(f"{d.platform}:{d.id} ({getattr(d, 'device_kind', '?')})" for d in jax.devices()),
           "Python": platform.python_version()}
    env.update({d: _version(d) for d in ("jax", "jaxlib")})
    env.update(_jax_plugins())
    env.update({d: _version(d) for d in ("equinox", "optimistix", "numpy", "scipy", "jaxopt", "crocoddyl", "mujoco",
                                         "mujoco-mjx", "mink", "daqp", "faiss-cpu")})
    env.update({"pin (Pinocchio)": _version("pin"), "x64": str(bool(jax.config.jax_enable_x64))})
    return env | ({"XLA_FLAGS": os.environ["XLA_FLAGS"]} if os.environ.get("XLA_FLAGS") else {})


def render_report(env: dict[str, str], command: str, settings: dict[str, str], tables: Sequence[Table]) -> str:
    """The whole BENCHMARKS.md text: a header written by this run, then every section."""
    out = [
        f"# jaxanim benchmarks: `{command}`",
        "",
        f"Written by one invocation of `{command}` (every section below ran in its process; each",
        "section ends with its own wall time and load). Run time is the median (min) of N calls after",
        "warm-up, each waited for with `block_until_ready`; compile time is",
        "`jax.jit(f).lower(*args).compile()`, timed apart and never included in run time. Compare rows of",
        "one report, as ratios: timings on a shared machine move between runs.",
        "",
        f"- command: `{command}`",
    ]
    out += [f"- {k}: {v}" for k, v in {**env, **settings}.items()] + [""]
    return "\n".join(out + [render_table(t) for t in tables]).rstrip() + "\n"
