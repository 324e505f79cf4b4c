"""The ``tracking`` benchmark: a reduced in-process run (batch 2, one window per call).

Timings are not checked; the rows, their units and the MuJoCo peer rows are. The walk table (4 s
at 256 samples, then the feedback gains: minutes) is left to ``python -m benchmarks tracking``.
"""

from __future__ import annotations

import pytest

from benchmarks import REGISTRY
from benchmarks.report import render_table
from benchmarks.tracking import TrackingSizes, run_tracking

from .helpers import bench_rows, quick_bench_config


def test_registered():
    assert REGISTRY["tracking"].load() is run_tracking


def test_reduced_run():
    pytest.importorskip("mujoco")
    tables = run_tracking(quick_bench_config(), TrackingSizes(batches=(2,), windows_per_call=1, walk_seconds=0.0))
    assert [t.name for t in tables] == ["tracking"]
    table, rows = bench_rows(tables, "tracking")
    text = render_table(table)
    assert "failed:" not in text, text
    steps = (3 + 6) * 4  # (window + look-ahead frames) x steps per frame, per sample
    own = rows[("jaxanim tracking.samcon", 2)]
    assert own.chars_per_call == 1 * 2 * steps and own.compile_s > 0 and own.success == 1.0
    assert 0.0 < own.accuracy < 0.5  # mean joint error (rad) of one tracked window
    assert rows[("MuJoCo C rollout.rollout", 2)].chars_per_call == 2 * steps
    assert rows[("MuJoCo C mj_step (Python loop)", 2)].chars_per_call == 2 * steps
    assert "samples/s" in own.note and "- Target: search compile ≤ 30 s: worst jaxanim tracking.samcon" in text
