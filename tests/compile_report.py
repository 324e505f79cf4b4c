"""Where the suite's time goes: ``python -m pytest -p tests.compile_report`` (opt-in, a pytest plugin).

Compiling dominates the suite, so this counts, per test, the XLA programs compiled and the seconds spent
tracing, lowering and compiling them (JAX's own ``jax.monitoring`` duration events), beside the test's wall
time, and prints the tests that compiled longest at the end. Under pytest-xdist each worker counts its own
tests and sends them to the controller. ``JAXANIM_COMPILE_REPORT=path.json`` also writes every test's row,
with the name and compile seconds of each program it compiled. A program read from the persistent compilation
cache is not a compile: it counts apart, as a cache hit, and its seconds (the read) are left out.
"""

from __future__ import annotations

import json
import os
import time

import pytest

#: jax.monitoring's duration events, by the column they add to.
_EVENTS = {"/jax/core/compile/backend_compile_duration": "compile",
           "/jax/core/compile/jaxpr_trace_duration": "trace",
           "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower"}
_TOP = 25

_CACHE_HIT = "/jax/compilation_cache/cache_hits"

_rows: dict[str, dict] = {}
_current: list[str] = []
_hit = [False]  # jax records a persistent-cache hit inside the backend-compile event that it then closes


def _hit_listener(event: str, **_) -> None:
    if event == _CACHE_HIT:
        _hit[0] = True


def _listener(event: str, duration: float, fun_name: str = "?", **_) -> None:
    column = _EVENTS.get(event)
    hit = column == "compile" and _hit[0]
    if column == "compile":
        _hit[0] = False
    if column is None or not _current:
        return
    row = _rows.setdefault(_current[-1], {})
    if hit:
        row["cache_hits"] = row.get("cache_hits", 0) + 1
        return
    row[column] = row.get(column, 0.0) + duration
    if column == "compile":
        row["programs"] = row.get("programs", 0) + 1
        row.setdefault("compiled", []).append([fun_name, round(duration, 3)])


def pytest_configure(config):
    import jax.monitoring

    jax.monitoring.register_event_duration_secs_listener(_listener)
    jax.monitoring.register_event_listener(_hit_listener)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    _current.append(item.nodeid)
    start = time.perf_counter()
    try:
        yield
    finally:
        _rows.setdefault(item.nodeid, {})["wall"] = time.perf_counter() - start
        _current.pop()


def pytest_sessionfinish(session):
    workeroutput = getattr(session.config, "workeroutput", None)
    if workeroutput is not None:  # an xdist worker: the controller merges the rows
        workeroutput["jaxanim_compile_report"] = json.dumps(_rows)


@pytest.hookimpl(optionalhook=True)  # an xdist hook: without xdist, pytest would refuse the plugin
def pytest_testnodedown(node, error):
    rows = getattr(node, "workeroutput", {}).get("jaxanim_compile_report")
    if rows:
        _rows.update(json.loads(rows))


def pytest_terminal_summary(terminalreporter, config):
    if hasattr(config, "workerinput") or not _rows:
        return
    path = os.environ.get("JAXANIM_COMPILE_REPORT")
    if path:
        with open(path, "w", encoding="utf-8") as f:
            json.dump(_rows, f, indent=1, sort_keys=True)
    total = {k: sum(r.get(k, 0) for r in _rows.values())
             for k in ("wall", "compile", "trace", "lower", "programs", "cache_hits")}
    tr = terminalreporter
    tr.section("compile report (tests.compile_report)")
    tr.write_line(f"{len(_rows)} tests: {total['wall']:.0f} s of test time, of which XLA compiled "
                  f"{int(total['programs'])} programs in {total['compile']:.0f} s, tracing {total['trace']:.0f} s, "
                  f"lowering {total['lower']:.0f} s; {int(total['cache_hits'])} programs read from the persistent "
                  "cache")
    tr.write_line(f"{'wall s':>7} {'compile s':>9} {'programs':>8} {'trace s':>7}  test (the {_TOP} longest compiles)")
    for nodeid, r in sorted(_rows.items(), key=lambda kv: -kv[1].get("compile", 0.0))[:_TOP]:
        tr.write_line(f"{r.get('wall', 0.0):7.1f} {r.get('compile', 0.0):9.1f} {int(r.get('programs', 0)):8d} "
                      f"{r.get('trace', 0.0):7.1f}  {nodeid}")
    if path:
        tr.write_line(f"every test's row: {path}")
