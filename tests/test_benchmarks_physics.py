"""The ``physics`` benchmark: a reduced in-process run (tiny batch, few steps).

Only one jaxanim contact model and a two-step call run here (each jaxanim row costs a compilation
of several seconds); timings are not checked, the rows, accuracy columns and skipped peers are.
MJX is reported as skipped (its compilation takes about a minute on CPU).
"""

from __future__ import annotations

import pathlib

import numpy as np
import pytest

from benchmarks import REGISTRY, default_data_dir
from benchmarks.peers import PeerUnavailable
from benchmarks.physics import CLIP, PhysicsSizes, run_physics
from benchmarks.report import render_table

from .helpers import bench_rows, quick_bench_config

_TINY = PhysicsSizes(batches=(2,), steps_per_call=2, mjx_steps=1, contact_models=("complementarity",),
                     stand_seconds=0.0, pendulum_seconds=0.05, pendulum_dts=(1 / 600,))


def test_registered():
    assert REGISTRY["physics"].target == "benchmarks.physics:run_physics"
    assert REGISTRY["physics"].load() is run_physics


def test_reduced_run(monkeypatch):
    """MuJoCo C and jaxanim rows run and agree roughly; a missing MJX becomes a skipped row."""
    pytest.importorskip("mujoco")
    if not (default_data_dir() / CLIP).is_file():
        pytest.skip(f"shared data {default_data_dir() / CLIP} not found")
    from benchmarks.peers import mujoco_physics

    def no_mjx():
        raise PeerUnavailable("cannot import mujoco.mjx: blocked by the test")

    monkeypatch.setattr(mujoco_physics, "load_mjx", no_mjx)
    tables = run_physics(quick_bench_config(), _TINY, tables=("throughput", "pendulum"))
    assert [t.name for t in tables] == ["physics", "physics-pendulum"]
    text = "\n".join(render_table(t) for t in tables)
    assert "failed:" not in text, text

    table, rows = bench_rows(tables, "physics")
    assert rows[("MuJoCo C mj_step (Python loop)", 2)].accuracy == "reference"
    assert rows[("MuJoCo C mj_step (Python loop)", 2)].chars_per_call == 2 * 2  # characters x steps
    assert rows[("MuJoCo C rollout.rollout", 2)].accuracy < 1e-12  # the same C code
    own = rows[("jaxanim rollout (complementarity)", 2)]
    assert own.success == 1.0 and own.compile_s > 0 and own.time_median_s > 0
    # two steps of 1/600 s move a body by at most |v| 2 dt + g (2 dt)^2 / 2 = 0.07 * 3.3e-3 + 5.4e-5 ~ 2.9e-4 m
    # (root speed <= 0.07 m/s); the two contact and PD models may differ by about that, not more (measured 1.5e-4)
    assert own.accuracy < 3e-4, own.accuracy
    assert rows[("MJX jit(vmap(scan(mjx.step)))", None)].skipped.startswith("cannot import mujoco.mjx")
    text = render_table(table)
    assert "- Target: rollout compile ≤ 5 s (jaxanim rows): worst jaxanim rollout (complementarity)" in text
    assert "- Target: penalty contact at batch 1024 at most 0.5x MuJoCo C's time per character-step (rollout on all threads; speedup ≥ 2x): not measured in this run." in text

    _, pend = bench_rows(tables, "physics-pendulum")
    mj, ja = pend[("MuJoCo C mj_step (dt 1/600)", 1)], pend[("jaxanim rollout (dt 1/600)", 1)]
    # both are first order: ~2.6e-4 m from the dt 1/19200 reference after 0.05 s, and 5e-6 m apart
    assert mj.accuracy < 5e-4 and ja.accuracy < 5e-4 and ja.success == 1.0
    assert "joint separation" in ja.note


def test_missing_data_is_skipped(tmp_path: pathlib.Path):
    tables = run_physics(quick_bench_config(data_dir=tmp_path), _TINY, tables=("throughput", "standing"))
    assert [t.name for t in tables] == ["physics", "physics-standing"]
    assert all(t.skipped and "not found" in t.skipped for t in tables)
    assert "**skipped:**" in render_table(tables[0])


def test_root_velocities_are_prefixes():
    from benchmarks.physics import root_velocities

    v = root_velocities(64)
    np.testing.assert_array_equal(root_velocities(2), v[:2])
    assert np.all(v[:, 1] == 0) and np.all(np.abs(v) <= 0.05)
