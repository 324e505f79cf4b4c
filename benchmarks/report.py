"""Result rows, markdown tables and the BENCHMARKS.md header.

A benchmark returns :class:`Table` objects made of :class:`Row` objects; this module turns them into
markdown. Every row carries its accuracy next to its time (house style §1.8). The "× best peer"
column divides a row's time per character by the fastest *peer* row (``is_peer=True``: anything that
is not jaxanim) at the same batch size, whatever its dtype (Pinocchio only runs in float64); a
table's footnote names that peer for each batch.
"""

from __future__ import annotations

import dataclasses
import datetime
import importlib.metadata
import os
import platform
import traceback
from collections.abc import Callable, Sequence

__all__ = [
    "Row",
    "Table",
    "collect_environment",
    "format_seconds",
    "render_header",
    "render_report",
    "render_table",
]

_DASH = "—"


@dataclasses.dataclass
class Row:
    """One measured (or skipped) implementation at one dtype and batch size.

    Attributes:
        implementation: what ran, e.g. ``"jaxanim jit(vmap(forward_kinematics)), quaternions"``.
        dtype: ``"float32"`` / ``"float64"``; ``None`` for a skipped row.
        batch: characters (problems) in the benchmark's batch; ``None`` for a skipped row.
        time_median_s: median seconds per timed call.
        time_min_s: fastest sample, seconds per timed call.
        chars_per_call: characters one timed call processes. Equal to ``batch`` unless the call was
            capped (a Python-loop peer timed on the first ``chars_per_call`` configurations).
        compile_s: ``lower + compile`` seconds, ``None`` when nothing is compiled.
        accuracy: max abs error against the table's reference, or a string such as ``"n/a (...)"``.
        success: fraction of problems solved, for solvers; ``None`` for closed-form computations.
        is_peer: ``True`` for anything that is not jaxanim (peers and baselines).
        note: free text for the notes column.
        skipped: the reason the implementation could not run; the row is then rendered as
            ``skipped: <reason>``.
    """

    implementation: str
    dtype: str | None = None
    batch: int | None = None
    time_median_s: float | None = None
    time_min_s: float | None = None
    chars_per_call: int | None = None
    compile_s: float | None = None
    accuracy: float | str | None = None
    success: float | None = None
    is_peer: bool = False
    note: str = ""
    skipped: str | None = None

    @property
    def us_per_char(self) -> float | None:
        """Median microseconds per character (per configuration for capped loops)."""
        if self.time_median_s is None:
            return None
        n = self.chars_per_call or self.batch or 1
        return self.time_median_s / n * 1e6


@dataclasses.dataclass
class Table:
    """One benchmark's results.

    Attributes:
        name: the registered benchmark name (``"fk"``), used as the section anchor.
        title: the section heading.
        description: markdown paragraph(s) describing the problem, inputs and reference.
        accuracy_label: header of the accuracy column, e.g. ``"max abs err vs jaxanim f64"``.
        rows: the rows, in the order they are rendered.
        notes: extra bullet points under the table.
        skipped: if set, the whole benchmark was skipped and this is why (no table is drawn).
    """

    name: str
    title: str
    description: str = ""
    accuracy_label: str = "max abs err"
    rows: list[Row] = dataclasses.field(default_factory=list)
    notes: list[str] = dataclasses.field(default_factory=list)
    skipped: str | None = None


# --- formatting -----------------------------------------------------------------------------------
def measure_row(config, table: Table, impl: str, batch: int | None, make_row: Callable[[], Row], is_peer: bool,
                failures: dict, log: Callable[[Row], None]) -> Row | None:
    """Append ``make_row()`` to ``table`` unless ``config`` filters ``impl`` out, and ``log`` it.

    A missing peer (``ImportError`` or ``PeerUnavailable``) becomes one skipped row for the
    implementation (``failures[impl] = None``: later batches add nothing); another exception a
    failed row, and later batches of that implementation a skipped row pointing to it. Returns the
    measured row, or ``None``."""
    from .peers import PeerUnavailable

    if not config.selects(impl):
        return None
    if impl in failures:
        if failures[impl] is None:  # the skipped row is already there
            return None
        row = Row(impl, "float64", batch, skipped=failures[impl], is_peer=is_peer)
    else:
        try:
            row = make_row()
        except (ImportError, PeerUnavailable) as exc:
            row = Row(impl, skipped=_first_line(exc) or type(exc).__name__, is_peer=is_peer)
            failures[impl] = None
        except Exception as exc:  # a failure is reported, not fatal
            traceback.print_exc()
            row = Row(impl, "float64", batch, skipped=f"failed: {type(exc).__name__}: {_first_line(exc)}",
                      is_peer=is_peer)
            failures[impl] = f"failed at batch {batch} (see that row)"
    log(row)
    table.rows.append(row)
    return row if row.skipped is None else None


def _first_line(exc: BaseException) -> str:
    return str(exc).splitlines()[0][:200] if str(exc) else ""


def format_seconds(s: float | None) -> str:
    """``1.23 ms``-style rendering with 3 significant digits; an em dash for ``None``."""
    if s is None:
        return _DASH
    for unit, scale in (("s", 1.0), ("ms", 1e-3), ("µs", 1e-6)):
        if abs(s) >= scale:
            return f"{s / scale:.3g} {unit}"
    return f"{s / 1e-9:.3g} ns"


def _fmt_num(x: float | None, digits: int = 3) -> str:
    if x is None:
        return _DASH
    if x == 0:
        return "0"
    if abs(x) >= 1e4 or abs(x) < 1e-2:
        return f"{x:.{digits - 1}e}"
    return f"{x:.{digits}g}"


def _fmt_accuracy(a: float | str | None) -> str:
    if a is None:
        return _DASH
    if isinstance(a, str):
        return a
    return "0" if a == 0 else f"{a:.2e}"


def _best_peers(rows: Sequence[Row]) -> dict[int, Row]:
    best: dict[int, Row] = {}
    for r in rows:
        if r.skipped is None and r.is_peer and r.batch is not None and r.us_per_char is not None:
            if r.batch not in best or r.us_per_char < best[r.batch].us_per_char:
                best[r.batch] = r
    return best


def render_table(table: Table) -> str:
    """Render one benchmark section (heading, description, table, notes) as markdown."""
    out = [f"## {table.title}", ""]
    if table.description:
        out += [table.description.strip(), ""]
    if table.skipped is not None:
        out += [f"**skipped:** {table.skipped}", ""]
        return "\n".join(out)
    show_success = any(r.success is not None for r in table.rows)
    header = ["implementation", "dtype", "batch", "time / call, median (min)", "µs / char", "compile"]
    header += [table.accuracy_label] + (["success"] if show_success else []) + ["× best peer", "notes"]
    out.append("| " + " | ".join(header) + " |")
    out.append("|" + "|".join(["---"] * 3 + ["---:"] * (len(header) - 4) + ["---"]) + "|")
    best = _best_peers(table.rows)
    for r in table.rows:
        if r.skipped is not None:
            cells = [r.implementation, r.dtype or _DASH, str(r.batch) if r.batch else _DASH]
            cells += [f"skipped: {r.skipped}"] + [_DASH] * (len(header) - 5) + [r.note]
            out.append("| " + " | ".join(cells) + " |")
            continue
        t = f"{format_seconds(r.time_median_s)} ({format_seconds(r.time_min_s)})"
        ratio = _DASH
        if r.batch in best and r.us_per_char is not None:
            ratio = f"{r.us_per_char / best[r.batch].us_per_char:.3g}×"
        cells = [
            r.implementation, r.dtype or _DASH, str(r.batch), t, _fmt_num(r.us_per_char),
            format_seconds(r.compile_s), _fmt_accuracy(r.accuracy),
        ]
        if show_success:
            cells.append(_DASH if r.success is None else f"{100 * r.success:.1f} %")
        cells += [ratio, r.note]
        out.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    out.append("")
    if best:
        peers = ", ".join(
            f"{b}: {r.implementation} {r.dtype} ({_fmt_num(r.us_per_char)} µs)" for b, r in sorted(best.items())
        )
        out += [f"Best peer per batch (µs per character): {peers}.", ""]
    out += [f"- {n}" for n in table.notes]
    if table.notes:
        out.append("")
    return "\n".join(out)


# --- environment ----------------------------------------------------------------------------------
def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def _version(dist: str) -> str:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


def collect_environment() -> dict[str, str]:
    """Machine and library facts for the report header (CPU, cores, devices, versions, x64)."""
    import jax

    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        usable = os.cpu_count() or 0
    devices = ", ".join(f"{d.platform}:{d.id} ({getattr(d, 'device_kind', '?')})" for d in jax.devices())
    env = {
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "CPU": _cpu_model(),
        "cores": f"{os.cpu_count()} logical, {usable} usable by this process",
        "devices": devices,
        "Python": platform.python_version(),
        "jax": _version("jax"),
        "jaxlib": _version("jaxlib"),
        "equinox": _version("equinox"),
        "numpy": _version("numpy"),
        "pin (Pinocchio)": _version("pin"),
        "x64": str(bool(jax.config.jax_enable_x64)),
    }
    if os.environ.get("XLA_FLAGS"):
        env["XLA_FLAGS"] = os.environ["XLA_FLAGS"]
    return env


def render_header(env: dict[str, str], command: str, settings: dict[str, str]) -> str:
    """The top of BENCHMARKS.md: title, command line, machine, versions and run settings."""
    out = [
        "# jaxanim benchmarks",
        "",
        "Generated by `python -m benchmarks`; do not edit by hand. Every implementation runs the same",
        "problem in one process. Run time is the median (min) of N calls after warm-up, each waited for",
        "with `block_until_ready`; compile time is `jax.jit(f).lower(*args).compile()`, timed separately.",
        "Timings on shared machines are noisy (up to ~1.7× between runs): compare rows of one report,",
        "as ratios.",
        "",
        f"- command: `{command}`",
    ]
    out += [f"- {k}: {v}" for k, v in env.items()]
    out += [f"- {k}: {v}" for k, v in settings.items()]
    out.append("")
    return "\n".join(out)


def render_report(env: dict[str, str], command: str, settings: dict[str, str], tables: Sequence[Table]) -> str:
    """The whole BENCHMARKS.md text."""
    parts = [render_header(env, command, settings)] + [render_table(t) for t in tables]
    return "\n".join(parts).rstrip() + "\n"

