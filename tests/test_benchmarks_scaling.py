"""The ``scaling`` benchmark: a reduced run (batch 2, float64, the reference and the 2-process
layouts only; each layout is a fresh subprocess, a few seconds each); timings are not checked, the
rows, the layouts they ran in and the accuracy column are."""

from __future__ import annotations

import dataclasses

from benchmarks import REGISTRY
from benchmarks.report import render_table
from benchmarks.scaling import LAYOUTS, run_scaling

from .conftest import shared_data_dir
from .helpers import bench_rows, quick_bench_config


def test_registered():
    assert REGISTRY["scaling"].load() is run_scaling


def test_reduced_run():
    """One process and two under ``jax.distributed``: the same FK, each row says where it ran."""
    ref, two = LAYOUTS[0], LAYOUTS[-1]
    assert two.processes == 2 and ref.processes == 1 and ref.cores == 1
    tables = run_scaling(quick_bench_config(dtypes=("float64",), data_dir=shared_data_dir()), (ref, two))
    table, rows = bench_rows(tables, "scaling")
    assert table.skipped is None and all(r.measured for r in table.rows), [r.skipped for r in table.rows]
    assert rows[ref.name, 2].accuracy == "reference" and rows[two.name, 2].accuracy == 0.0
    assert rows[two.name, 2].note.startswith("output sharded over 2 devices of 2 processes"), rows[two.name, 2].note
    assert "x the 1-core time" in rows[two.name, 2].note and rows[two.name, 2].time_median_s > 0
    text = render_table(table)
    assert "Target: 2 processes ≥ 1.6x one process on one core at batch 2" in text and "usable cores" in text


def test_missing_data_and_odd_batches_skip(tmp_path):
    (table,) = run_scaling(quick_bench_config(data_dir=tmp_path))
    assert "not found" in table.skipped
    (table,) = run_scaling(dataclasses.replace(quick_bench_config(data_dir=shared_data_dir()), batches=(1, 3)))
    assert table.skipped.startswith("no batch size divisible by 2 devices")
