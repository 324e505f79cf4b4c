"""``python -m benchmarks --gpu``: the accelerator sizes, section time budgets, a report written as rows finish.

Here (no accelerator) ``--gpu`` must say so and run the small sizes end to end within the budgets; a section that
runs out of time or raises loses only its own rows. The vectorised problem generators are checked against the
per-item constructions they replaced (same seeds, same draws).
"""

from __future__ import annotations

import re
import time
import types

import jax
import numpy as np
import pytest

from benchmarks import (ACCELERATOR_BUDGET_S, ACCELERATOR_SECTIONS, ACCELERATOR_TOTAL_S, REGISTRY, BenchConfig,
                        run_benchmarks)
from benchmarks.__main__ import ACCELERATOR_SIZES_TEXT, main, parse_budgets
from benchmarks.report import Row, Table
from benchmarks.timing import Runner, sample_call, time_call

from .conftest import shared_data_dir

_ATOL_QUAT = 1e-15  # vectorised quaternion products vs scipy's Rotation (float64 round-off)


def _rows(markdown: str, title: str) -> list[list[str]]:
    """Cells of the data rows of the table in the section ``## <title>``."""
    section = markdown.split(f"## {title}", 1)[1].split("\n## ", 1)[0]
    return [[c.strip() for c in ln.strip("|").split(" | ")] for ln in section.splitlines() if ln.startswith("| ")][1:]


@pytest.mark.skipif(jax.default_backend() != "cpu", reason="checks the fallback of a machine without an accelerator")
def test_gpu_without_accelerator_runs_the_small_sizes_within_budgets(tmp_path, capsys):
    """``--gpu`` on the CPU: says so on stderr, runs the quick sizes; the report names the device and the jax
    version; ``fk``, given a budget it has spent before its first row, reports every row as skipped for it, and
    ``skinning`` after it still runs and is written."""
    out = tmp_path / "BENCHMARKS.md"
    status = main(["--gpu", "fk", "skinning", "--quick", "--dtype", "float64", "--only", "numpy*",
                   "--section-budget", "fk=0.001", "--out", str(out), "--data-dir", str(shared_data_dir()), "--quiet"])
    assert status == 0
    err = capsys.readouterr().err
    assert "no accelerator found (jax backend: cpu): running the small sizes" in err, err
    text = out.read_text(encoding="utf-8")
    for line in ("- device: cpu: ", "(no accelerator)", f"- jax: {jax.__version__}", "- jaxlib: ",
                 "- mode: --gpu without an accelerator (jax backend cpu): the small sizes of a quick",
                 f"- time budgets: fk 0.001 s, skinning {ACCELERATOR_BUDGET_S['skinning']:g} s; "
                 f"{ACCELERATOR_TOTAL_S:g} s for the whole run"):
        assert line in text, f"header line {line!r} missing"
    fk = _rows(text, "Forward kinematics")
    assert [(r[0], r[2]) for r in fk] == [("numpy", "1"), ("numpy", "8")], fk
    assert all(r[3] == "skipped: not run (section time budget of 0.001 s spent)" for r in fk), fk
    for method in ("LBS", "DQS"):
        (row,) = _rows(text, f"Skinning ({method})")
        assert row[0] == f"numpy, vectorised ({method})" and row[2] == "8" and float(row[4]) > 0, row
    assert "(benchmark `skinning`, quick mode)" in text
    assert f"(section time budget {ACCELERATOR_BUDGET_S['skinning']:g} s)" in text


def test_gpu_with_an_accelerator_selects_the_accelerator_profile(tmp_path, monkeypatch, capsys):
    """With an accelerator (JAX's backend faked here; ``--batches`` keeps the run small) ``--gpu`` takes the
    accelerator settings and says so in the report. Other processes' CPU share reads as 0 here: a full run (no
    ``--quick``) runs a section again when they kept the cores busy, as the suite's other worker does, which
    compiled its FK twice more (2.3 s); that rerun has its own test below."""
    import benchmarks

    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    monkeypatch.setattr(benchmarks, "_others", lambda *a: 0.0)
    out = tmp_path / "BENCHMARKS.md"
    assert main(["--gpu", "fk", "--batches", "2", "--dtype", "float64", "--only", "numpy", "--out", str(out),
                 "--data-dir", str(shared_data_dir()), "--quiet"]) == 0
    assert "no accelerator" not in capsys.readouterr().err
    text = out.read_text(encoding="utf-8")
    for line in (f"- mode: accelerator sizes (--gpu): {ACCELERATOR_SIZES_TEXT}", "- repeats / warm-up: 5 / 1",
                 "- Python-loop cap: 512 configurations", "- device: gpu: ", "(benchmark `fk`, accelerator mode)"):
        assert line in text, f"{line!r} missing"
    assert [(r[0], r[2]) for r in _rows(text, "Forward kinematics")] == [("numpy", "2")]


def test_a_failing_section_loses_only_itself(tmp_path, monkeypatch):
    """The report is on disk after the first section and after each row of the next; a section that raises
    keeps the rows it finished, ends with a failed table, and the section after it still runs. The first section,
    ``fk``, finds no data (a skipped table, written like any other): with the data it compiled two FK programs
    (2 s) that nothing here checks."""
    out = tmp_path / "BENCHMARKS.md"
    seen = {}

    def boom(config):
        seen["after fk"] = out.read_text(encoding="utf-8")
        run = Runner(config, Table("boom", "Boom table"))
        run.add("numpy (fake)", "float64", 1, lambda: Row("numpy (fake)", "float64", 1, 1e-3, 1e-3, 1, accuracy=0.0))
        seen["after a row"] = out.read_text(encoding="utf-8")
        raise RuntimeError("the section broke")

    monkeypatch.setitem(REGISTRY, "boom", types.SimpleNamespace(name="boom", description="raises", load=lambda: boom))
    status = main(["fk", "boom", "skinning", "--quick", "--dtype", "float64", "--batches", "1", "--only", "numpy*",
                   "--out", str(out), "--data-dir", str(tmp_path / "nowhere"), "--quiet"])
    assert status == 0
    assert "## Forward kinematics" in seen["after fk"] and "Boom" not in seen["after fk"]
    assert "cmu_01_01_trim300.bvh not found" in seen["after fk"]
    assert "## Boom table" in seen["after a row"] and "Section `boom` was still running" in seen["after a row"]
    text = out.read_text(encoding="utf-8")
    assert [r[0] for r in _rows(text, "Boom table")] == ["numpy (fake)"]
    assert "## Benchmark `boom`: failed" in text
    assert "**skipped:** failed: RuntimeError: the section broke (the tables above are the rows it finished)" in text
    assert _rows(text, "Skinning (LBS)")[0][0] == "numpy, vectorised (LBS)"
    assert "still running" not in text
    assert not list(tmp_path.glob("*.part"))


def test_the_total_budget_caps_the_sections(monkeypatch):
    """``total_s``: a section gets at most what is left of the run's total; past it, the next one's rows skip."""
    seen = {}

    def slow(config):
        seen["slow"] = config.section_budget_s
        time.sleep(0.3)
        return []

    def late(config):
        seen["late"] = config.section_budget_s
        run = Runner(config, Table("late", "Late"))
        run.add("x", "float64", 1, lambda: pytest.fail("ran past the total budget"))
        return [run.table]

    for name, fn in (("slow", slow), ("late", late)):
        monkeypatch.setitem(REGISTRY, name, types.SimpleNamespace(name=name, description=name, load=lambda fn=fn: fn))
    (table,) = run_benchmarks(["slow", "late"], BenchConfig(verbose=False), budgets={"slow": 10.0}, total_s=0.2)
    assert seen == {"slow": 0.2, "late": 0.0}
    assert table.rows[0].skipped == "not run (section time budget of 0 s spent)"
    assert "(section time budget 0 s)" in table.run


def _config(left: float | None, **kw) -> BenchConfig:
    deadline = None if left is None else time.monotonic() + left
    return BenchConfig(verbose=False, section="t", section_budget_s=5.0, deadline=deadline, **kw)


def test_runner_skips_rows_past_the_section_budget():
    """A spent budget skips every row; a row the previous batch predicts to end past the deadline is skipped with
    the estimate; one that fits runs."""
    spent = Runner(_config(-1.0), Table("t", "T"))
    assert spent.add("a", "float64", 1, lambda: pytest.fail("ran past the budget")) is None
    assert spent.table.rows[0].skipped == "not run (section time budget of 5 s spent)"

    def runner(left: float) -> Runner:  # batch 1 measured: 0.5 s per call, compiled in 2 s
        run = Runner(_config(left), Table("t", "T"))
        run.table.rows.append(Row("a", "float64", 1, 0.5, 0.5, 1, compile_s=2.0))
        return run

    tight = runner(3.0)  # batch 4: ~2 s per call, one call after a 2 s compile: ~4 s > 3 s left
    assert tight.add("a", "float64", 4, lambda: pytest.fail("should not run")) is None
    assert re.fullmatch(r"not run \(section time budget of 5 s\): ~4 s expected from batch 1, [23] s left",
                        tight.table.rows[-1].skipped), tight.table.rows[-1].skipped
    roomy = runner(60.0)
    assert roomy.add("a", "float64", 4, lambda: Row("a", "float64", 4, 2.0, 2.0, 4)) is not None
    twin = runner(10.0)  # no float32 row yet: the float64 row of the same batch predicts 2 + 3 x 0.5 s
    assert twin.add("a", "float32", 1, lambda: Row("a", "float32", 1, 0.5, 0.5, 1)) is not None
    twin.table.rows[0].compile_s = 9.0  # now 10.5 s: past the deadline
    assert twin.add("a", "float16", 1, lambda: pytest.fail("should not run")) is None
    assert "expected from the float64 row" in twin.table.rows[-1].skipped, twin.table.rows[-1].skipped
    # a new implementation has no history: the table's median row (2 + 3 x 0.5 s) stands in for it
    assert runner(3.0).add("b", "float64", 1, lambda: pytest.fail("should not run")) is None
    assert runner(5.0).add("b", "float64", 1, lambda: Row("b", "float64", 1, 0.1, 0.1, 1)) is not None
    no_budget = Runner(_config(None), Table("t", "T", rows=[Row("a", "float64", 1, 99.0, 99.0, 1, compile_s=99.0)]))
    assert no_budget.add("b", "float64", 1, lambda: Row("b", "float64", 1, 0.1, 0.1, 1)) is not None


def test_sampling_stops_at_the_deadline():
    """Past the deadline a row takes one sample; ``time_call`` honours ``min_samples``."""
    calls = []
    fn = lambda: calls.append(1)  # noqa: E731
    tm = sample_call(_config(-1.0, repeats=7, warmup=1), fn, (), 0.0)
    assert tm.samples == 1
    assert time_call(fn, repeats=5, warmup=0, number=1, max_total_s=0.0, min_samples=1).samples == 1
    assert time_call(fn, repeats=5, warmup=0, number=1, max_total_s=0.0).samples == 3
    assert sample_call(_config(None, repeats=4, warmup=1), fn, (), 0.0).samples == 4


def test_section_budgets_parse():
    assert parse_budgets(None, False, ["fk"]) is None
    assert parse_budgets(None, True, ["fk", "ik"]) == {n: ACCELERATOR_BUDGET_S[n] for n in ("fk", "ik")}
    assert parse_budgets("60,fk=30", False, ["fk", "ik", "oc"]) == {"fk": 30.0, "ik": 60.0, "oc": 60.0}
    assert parse_budgets("ik=10", True, ["fk", "ik"]) == {"fk": ACCELERATOR_BUDGET_S["fk"], "ik": 10.0}
    for bad, match in (("nope=3", "unknown benchmark 'nope'"), ("fk=x", "expected SECONDS"), ("0", "positive")):
        with pytest.raises(ValueError, match=match):
            parse_budgets(bad, False, ["fk"])
    assert sum(ACCELERATOR_BUDGET_S[n] for n in ACCELERATOR_SECTIONS) <= ACCELERATOR_TOTAL_S <= 9 * 60


def test_accelerator_sizes_are_those_the_help_states():
    """Each module's accelerator sizes (issue 29's) are those ``--help`` and the report's mode line state, and a
    config picks them only under ``accelerator`` (quick wins)."""
    from benchmarks import fk, ik, matching, oc, physics, skinning, tracking

    assert fk.FK_ACCELERATOR_BATCHES[-1] == 2**20 and ik.IK_ACCELERATOR_BATCHES[-1] == 131072
    assert physics.ACCELERATOR_SIZES.batches == (1024, 65536) and physics.ACCELERATOR_SIZES.mjx_batches == (65536,)
    assert tracking.ACCELERATOR_SIZES.batches == (4096,) and tracking.ACCELERATOR_SIZES.walk_samples == 1024
    assert matching.ACCELERATOR_SIZES.batches == (1024, 16384) and matching.ACCELERATOR_SIZES.crowd == 16384
    assert (skinning.ACCELERATOR_SIZES.vertices, skinning.ACCELERATOR_SIZES.frames) == (10_000, 10_000)
    assert oc.ACCELERATOR_SIZES.dare_batches[-1] == 10**5 and oc.ACCELERATOR_SIZES.swing_batches == (16384,)
    for phrase in ("FK of 1,024, 131,072 and 1,048,576 poses", "IK of 1,024, 16,384 and 131,072 problems",
                   "physics of 1,024 and 65,536 characters, MJX beside it at 65,536", "SAMCON at 4,096 samples",
                   "the 4 s walk at 1,024", "1,024 and 16,384 agents and a crowd of 16,384",
                   "10^4 vertices x 10^4 frames", "DARE of 1,024 to 10^5", "swing-ups of 16,384"):
        assert phrase in ACCELERATOR_SIZES_TEXT, phrase
    gpu, cpu = BenchConfig(accelerator=True), BenchConfig()
    assert gpu.batches_for(fk.FK_BATCHES, fk.FK_ACCELERATOR_BATCHES) == fk.FK_ACCELERATOR_BATCHES
    assert cpu.batches_for(fk.FK_BATCHES, fk.FK_ACCELERATOR_BATCHES) == fk.FK_BATCHES
    assert gpu.pick("full", quick="quick", accelerator="gpu") == "gpu" and cpu.pick("full", accelerator="gpu") == "full"
    assert BenchConfig.make_quick(accelerator=True).pick("full", quick="quick", accelerator="gpu") == "quick"


def test_euler_quats_match_scipy_and_poses_are_prefixes():
    """The vectorised Euler products (NumPy and jitted JAX) equal scipy's ``from_euler``; the FK poses of a batch
    are the first poses of any larger one."""
    from scipy.spatial.transform import Rotation

    from benchmarks import fk

    ang = np.random.default_rng(1).uniform(-np.pi, np.pi, size=(5, 7, 3))
    for axes in ("XYZ", "ZYX"):
        want = Rotation.from_euler(axes, ang.reshape(-1, 3)).as_quat()[:, [3, 0, 1, 2]].reshape(5, 7, 4)
        np.testing.assert_allclose(fk.euler_quats(ang, axes), want, rtol=0, atol=_ATOL_QUAT, err_msg=f"numpy {axes}")
        got = jax.jit(lambda a, axes=axes: fk.euler_quats(a, axes))(jax.numpy.asarray(ang))
        np.testing.assert_allclose(np.asarray(got), want, rtol=0, atol=_ATOL_QUAT, err_msg=f"jax {axes}")
    path = BenchConfig(data_dir=shared_data_dir()).data_file(fk.CLIP)
    small, large = fk.Problem(path, 4), fk.Problem(path, 9)
    for name in ("quats", "mats", "trans"):
        np.testing.assert_array_equal(getattr(small, name), getattr(large, name)[:4], err_msg=name)
    want = (Rotation.from_quat(np.asarray(large.motion.rotations)[np.arange(9) % 300].reshape(-1, 4)[:, [1, 2, 3, 0]])
            * Rotation.from_euler("XYZ", np.deg2rad(np.random.default_rng(fk.SEED).uniform(
                -fk.MAX_ANGLE_DEG, fk.MAX_ANGLE_DEG, size=(9, 31, 3))).reshape(-1, 3))).as_matrix()
    np.testing.assert_allclose(large.mats.reshape(-1, 3, 3), want, rtol=0, atol=1e-14, err_msg="poses vs scipy")


def test_crowd_inputs_equal_one_control_input_per_agent():
    """The vectorised crowd equals ``matching.control_input`` of each agent's keys from the same draws in order."""
    from jaxanim import matching

    from benchmarks.matching import crowd_inputs

    n, seconds, speed = 6, 10.0, 1.3
    got = crowd_inputs(n, seconds, speed)
    rng = np.random.default_rng(0)
    for i in range(n):
        yaw0 = rng.uniform(-np.pi, np.pi)
        yaw1 = yaw0 + rng.uniform(-2.1, 2.1)
        s0, s1 = speed * rng.uniform(0.7, 1.3, 2)
        t1 = rng.uniform(0.3, 0.7) * seconds
        d0, d1 = np.array([np.sin(yaw0), np.cos(yaw0)]), np.array([np.sin(yaw1), np.cos(yaw1)])
        want = matching.control_input([0.0, t1, t1 + 1.0], [s0 * d0, s0 * d0, s1 * d1])
        for field in ("times", "velocity", "yaw"):
            np.testing.assert_array_equal(np.asarray(getattr(got, field))[i], np.asarray(getattr(want, field)),
                                          err_msg=f"agent {i} {field}")


def test_mujoco_initial_states_equal_one_state_per_character():
    """``MujocoSim``'s initial states (one state with each root velocity written in) equal ``mj_getState`` of each
    character's own reset ``MjData``."""
    pytest.importorskip("mujoco")
    from benchmarks import physics
    from benchmarks.peers import mujoco_physics as mp

    ch = physics.standing_character(shared_data_dir(), "complementarity")
    sim = mp.MujocoSim(ch.mjcf(physics.DT), ch.char.model.bodies.names, ch.root, physics.root_velocities(4))
    mujoco = sim.mujoco
    for i in range(4):
        state = np.empty(mujoco.mj_stateSize(sim.model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
        mujoco.mj_getState(sim.model, sim.reset(i, mujoco.MjData(sim.model)), state,
                           mujoco.mjtState.mjSTATE_FULLPHYSICS)
        np.testing.assert_array_equal(sim.initial_states[i], state, err_msg=f"character {i}")


def test_the_issues_accelerator_targets_judge_their_rows():
    """Issue 29's H200 targets, which ``--gpu`` adds to the physics, IK and tracking tables on an accelerator,
    judge the rows they name: met just inside each limit, missed just outside."""
    from benchmarks import ik, physics, tracking
    from benchmarks.report import Row, judge

    def row(impl, us, dtype="float64", batch=65536, success=1.0):
        return Row(impl, dtype, batch, us * 1e-6, us * 1e-6, 1, 1.0, 0.0, success)

    pen, comp, mjx = "jaxanim rollout (penalty)", "jaxanim rollout (complementarity:8)", physics._MJX
    fast, slow = [row(pen, 0.3), row(comp, 0.9), row(mjx, 0.31)], [row(pen, 0.34), row(comp, 1.1), row(mjx, 0.29)]
    assert [judge(t, fast).endswith("met.") for t in physics.ACCELERATOR_TARGETS] == [True, True, True]
    assert [judge(t, slow).endswith("missed.") for t in physics.ACCELERATOR_TARGETS] == [True, True, True]
    lm, b = ik._LM_ADAPTIVE, 131072
    ok = [row(lm, 9.9, "float32", b), row(lm, 16.6, "float64", b, success=0.996)]
    bad = [row(lm, 10.1, "float32", b), row(lm, 16.8, "float64", b, success=0.994)]
    assert [judge(t, ok).endswith("met.") for t in ik._accelerator_targets(b)] == [True, True, True]
    assert [judge(t, bad).endswith("missed.") for t in ik._accelerator_targets(b)] == [True, True, True]
    (walk,) = tracking._accelerator_walk_targets(4.0, 1024)
    assert judge(walk, [row(tracking._TOTAL, 3.9e6, batch=1)]).endswith("met.")
    assert judge(walk, [row(tracking._TOTAL, 4.1e6, batch=1)]).endswith("missed.")


def test_a_section_shared_with_other_processes_runs_again(monkeypatch):
    """Issue 31, item 2: a section during which other processes kept more than ``OTHERS_MAX`` cores busy runs once
    more (with ``rerun_busy``, as the command line's full runs do), and the report says what both runs shared."""
    import benchmarks

    assert benchmarks._others((10.0, 1.0), (14.0, 2.0), 2.0) == 1.5  # 4 s busy, 1 s of them this process's, in 2 s
    assert benchmarks._others(None, (1.0, 1.0), 1.0) is None
    busy, own = benchmarks._cpu_seconds()
    assert busy > 0 and own > 0
    calls, shares = [], iter([1.2, 0.1])
    monkeypatch.setattr(benchmarks, "_others", lambda *a: next(shares))
    monkeypatch.setitem(REGISTRY, "twice", types.SimpleNamespace(
        name="twice", description="twice", load=lambda: lambda config: calls.append(1) or [Table("twice", "Twice")]))
    (table,) = run_benchmarks(["twice"], BenchConfig(verbose=False), rerun_busy=True)
    assert len(calls) == 2
    assert "other processes used 0.10 cores on average meanwhile" in table.run
    assert "this is a second run: during the first, other processes used 1.20 cores" in table.run
    shares = iter([1.2])
    (table,) = run_benchmarks(["twice"], BenchConfig(verbose=False))  # the default: measured once, and said
    assert len(calls) == 3 and "1.20 cores on average meanwhile (above 0.5: they inflated every time)" in table.run
