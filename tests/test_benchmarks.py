"""The benchmark harness: quick-mode reports, skipped peers, and the Pinocchio adapter.

The harness runs here only in its smallest configuration (quick mode, float64, 3 repeats, one batch per
section); the timings are not checked, the report's structure and accuracy columns are.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest

from benchmarks import REGISTRY, BenchConfig
from benchmarks.__main__ import main
from benchmarks.report import Row, Table, format_seconds, render_table
from benchmarks.timing import compile_time, time_call

from .conftest import shared_data_dir

_ATOL_BENCH = 1e-10  # float64 accuracy columns (file units, |p| <= ~30)
_ATOL_PIN_FK = 1e-10  # Pinocchio adapter vs the shared FK reference


def _table_rows(markdown: str, title: str) -> list[list[str]]:
    """Cells of the data rows of the table in the section ``## <title>``."""
    section = markdown.split(f"## {title}", 1)[1].split("\n## ", 1)[0]
    lines = [ln for ln in section.splitlines() if ln.startswith("| ")]
    return [[c.strip() for c in ln.strip("|").split(" | ")] for ln in lines[1:]]  # drop the header


def _row(rows: list[list[str]], impl: str, dtype: str, batch: int) -> list[str]:
    found = [r for r in rows if r[0] == impl and r[1] == dtype and r[2] == str(batch)]
    assert len(found) == 1, f"expected one row {impl!r} {dtype} batch {batch}, got {found}; rows: {rows}"
    return found[0]


def _assert_accurate(row: list[str], accuracy_col: int = 6) -> None:
    acc = row[accuracy_col]
    if acc != "reference":
        assert float(acc) < _ATOL_BENCH, f"accuracy of {row[0]} at batch {row[2]}: {acc}"


def test_registry_lists_fk_and_jacobian():
    assert {"fk", "jacobian"} <= set(REGISTRY)
    assert callable(REGISTRY["fk"].load())


def test_unknown_benchmark_is_a_usage_error(capsys):
    with pytest.raises(SystemExit):
        main(["no_such_benchmark", "--quick"])
    assert "registered" in capsys.readouterr().err


def test_quick_fk_report_with_missing_peer(tmp_path, monkeypatch):
    """``fk`` in quick mode at batch 8: every row present and accurate; Pinocchio reported as skipped. One batch:
    each batch compiles every jitted row again (quick's batch 1 as well cost 4 more programs, 2.7 s of the 8 s this
    test compiled in the suite; the poses of batch 8 are also the profile test's)."""
    data = shared_data_dir()
    monkeypatch.setitem(sys.modules, "pinocchio", None)  # import pinocchio -> ImportError
    out = tmp_path / "BENCHMARKS.md"
    status = main(["fk", "--quick", "--dtype", "float64", "--batches", "8", "--out", str(out), "--data-dir", str(data),
                   "--quiet"])
    assert status == 0
    text = out.read_text(encoding="utf-8")
    for key in ("- command: `python -m benchmarks fk --quick", "- CPU:", "- cores:", "- devices:", "- jax:",
                "- jaxlib:", "- equinox:", "- numpy:", "- pin (Pinocchio):", "- x64: True", "- date:"):
        assert key in text, f"header line {key!r} missing"
    assert "failed:" not in text
    rows = _table_rows(text, "Forward kinematics")
    assert {r[2] for r in rows if not r[3].startswith("skipped")} == {"8"}, rows
    for impl in ("jaxanim (quaternions)", "jaxanim (matrices)", "naive JAX", "numpy"):
        row = _row(rows, impl, "float64", 8)
        _assert_accurate(row)
        assert float(row[4]) > 0, f"µs/char of {impl}"
    assert _row(rows, "jaxanim (quaternions)", "float64", 8)[6] == "reference"
    assert _row(rows, "naive JAX", "float64", 8)[5].endswith("s"), "compile time missing"
    skipped = [r for r in rows if r[0] == "Pinocchio forwardKinematics"]
    assert len(skipped) == 1 and skipped[0][3].startswith("skipped: cannot import pinocchio"), skipped
    assert "vs the shared reference" in text


def test_missing_data_skips_the_benchmark(tmp_path):
    out = tmp_path / "BENCHMARKS.md"
    assert main(["fk", "--quick", "--out", str(out), "--data-dir", str(tmp_path / "nowhere"), "--quiet"]) == 0
    text = out.read_text(encoding="utf-8")
    assert "**skipped:**" in text and "cmu_01_01_trim300.bvh not found" in text


def test_quick_jacobian_report(tmp_path):
    """``jacobian`` at batch 1: jaxanim and (if installed) Pinocchio agree with jacfwd."""
    data = shared_data_dir()
    out = tmp_path / "BENCHMARKS.md"
    status = main([
        "jacobian", "--quick", "--dtype", "float64", "--batches", "1", "--out", str(out), "--data-dir", str(data),
        "--only", "jaxanim,jacfwd of jaxanim*,pinocchio", "--quiet",
    ])
    assert status == 0
    text = out.read_text(encoding="utf-8")
    assert "failed:" not in text
    rows = _table_rows(text, "Jacobian")
    _assert_accurate(_row(rows, "jaxanim", "float64", 1))
    assert _row(rows, "jacfwd of jaxanim FK", "float64", 1)[6] == "reference"
    assert not [r for r in rows if r[0].startswith("jacrev")], "--only should have filtered jacrev out"
    try:
        import pinocchio  # noqa: F401
    except ImportError:
        assert any(r[0] == "Pinocchio" and r[3].startswith("skipped:") for r in rows)
    else:
        _assert_accurate(_row(rows, "Pinocchio", "float64", 1))


def test_pinocchio_model_matches_shared_reference():
    """The Pinocchio adapter (free flyer + spherical joints, xyzw q) reproduces the shared FK reference."""
    pytest.importorskip("pinocchio", reason="Pinocchio (pip install pin==4.0.0) is not installed")
    from benchmarks.peers import pinocchio_peer
    from jaxanim import read_bvh

    data = shared_data_dir()
    bvh = data / "bvh" / "cmu_01_01_trim300.bvh"
    ref_path = data / "fk" / "cmu_01_01_trim300.fk.npz"
    if not (bvh.is_file() and ref_path.is_file()):
        pytest.skip(f"{bvh} or {ref_path} missing")
    skeleton, motion = read_bvh(bvh)
    ref = np.load(ref_path)
    frames = [0, 1, 150, 299]
    model = pinocchio_peer.build_model(skeleton)
    assert (model.model.nq, model.model.nv) == (7 + 4 * 30, 6 + 3 * 30)
    rotations, translations = np.asarray(motion.rotations)[frames], np.asarray(motion.translations)[frames]
    qs = list(pinocchio_peer.configurations(rotations, translations[:, 0]))
    pj, pe = pinocchio_peer.positions(model, qs)
    np.testing.assert_allclose(pj, ref["positions"][frames], rtol=0, atol=_ATOL_PIN_FK, err_msg="positions")
    np.testing.assert_allclose(
        pe, ref["end_site_positions"][frames], rtol=0, atol=_ATOL_PIN_FK, err_msg="end_site_positions"
    )


def test_time_call_and_compile_time():
    import jax
    import jax.numpy as jnp

    x = jnp.arange(4.0)
    cs = compile_time(jax.jit(lambda v: v * 2.0), x)
    assert cs.total > 0 and cs.total == pytest.approx(cs.lower + cs.compile)
    stats = time_call(cs.compiled, x, repeats=3, warmup=1)
    assert stats.samples == 3 and stats.number >= 1
    assert stats.min <= stats.median <= max(stats.all)
    with pytest.raises(ValueError, match="repeats"):
        time_call(cs.compiled, x, repeats=0)


def test_render_table_ratio_and_skipped_row():
    table = Table("t", "Demo", rows=[
        Row("ours", "float64", 10, 1e-3, 9e-4, 10, 0.5, 1e-15),
        Row("peer", "float64", 10, 4e-3, 4e-3, 10, None, "reference", is_peer=True),
        Row("missing", skipped="cannot import x", is_peer=True),
    ])
    md = render_table(table)
    rows = _table_rows(md, "Demo")
    assert rows[0][4] == "100" and rows[0][7] == "0.25×", rows[0]
    assert rows[1][7] == "1×" and rows[1][5] == "—"
    assert rows[2][3] == "skipped: cannot import x"
    assert format_seconds(1.5e-6) == "1.5 µs" and format_seconds(None) == "—"


def test_quick_config_is_small():
    cfg = BenchConfig.make_quick()
    assert cfg.batches == (1, 8) and cfg.repeats <= 3 and cfg.loop_cap <= 8
    assert cfg.selects("anything")
    assert BenchConfig(only=("jaxanim*",)).selects("jaxanim (matrices)")
    assert not BenchConfig(only=("jaxanim",)).selects("jaxanim (matrices)")


def test_ik_problems_are_reachable_and_evaluated_independently():
    """``benchmarks.ik``: the targets are FK of the goal poses, the evaluator sees it, CLIK solves a few."""
    import jax.numpy as jnp

    from benchmarks import ik as bench_ik

    data = shared_data_dir()
    skel = bench_ik.load_skeleton(BenchConfig(data_dir=data))
    ps = bench_ik.draw_problems(skel, 8)
    assert ps.position_tolerance == pytest.approx(1e-3 * bench_ik.skeleton_height(skel))
    goal = bench_ik.evaluate(skel, ps, ps.goal_rotations, ps.goal_translations)
    assert goal.success.all() and goal.position_errors.max() < 1e-12 and goal.orientation_errors.max() < 1e-7
    rest = bench_ik.evaluate(skel, ps, *ps.start(jnp.float64))
    assert not rest.success.any()
    targets, q, t = bench_ik.make_problems(skel, 8, dtype=jnp.float32)
    assert [tg.site for tg in targets] == list(bench_ik.EFFECTORS)
    assert targets[0].position.shape == (8, 3) and targets[0].orientation.dtype == jnp.float32
    assert q.shape == (8, skel.num_joints, 4) and t.dtype == jnp.float32
    # the same seed gives the same problems; Target input to the evaluator agrees with the ProblemSet
    again = bench_ik.evaluate(skel, targets, ps.goal_rotations, ps.goal_translations)
    assert again.success.all() and again.position_errors.max() < 1e-4  # float32 targets
    nan_pose = np.where(np.arange(8)[:, None, None] == 0, np.nan, ps.goal_rotations)
    assert bench_ik.evaluate(skel, ps, nan_pose, ps.goal_translations).success.tolist() == [False] + [True] * 7
    from benchmarks.peers import PeerUnavailable, pinocchio_peer

    try:
        pin = pinocchio_peer.build_model(skel)
    except PeerUnavailable as exc:  # the evaluator checks above ran
        pytest.skip(f"Pinocchio CLIK part: {exc}")
    q0s = list(pinocchio_peer.configurations(np.asarray(q[:3], np.float64), np.asarray(t[:3, 0], np.float64)))
    fids = [pin.frame_ids[s] for s in ps.sites]
    qs, its = pinocchio_peer.clik_loop(
        pin, q0s, fids, ps.positions[:3], ps.rotation_matrices[:3], damping=bench_ik.CLIK_DAMPING,
        max_iterations=bench_ik.CLIK_MAX_ITERATIONS, position_tolerance=ps.position_tolerance,
        orientation_tolerance=bench_ik.ORIENTATION_TOLERANCE,
    )
    rot, tr = pinocchio_peer.to_poses(qs, np.asarray(skel.offsets))
    sub = bench_ik.evaluate(skel, ps.first(3), rot, tr)
    assert sub.success.all() and (its > 0).all() and (its < bench_ik.CLIK_MAX_ITERATIONS).all(), its


def test_quick_ik_report(tmp_path):
    """``ik`` in quick mode (batch 8, float64): the adaptive own LM row solves every problem (one
    compile; the fixed-step row is the same solver); CLIK if installed."""
    from benchmarks import ik as bench_ik

    data = shared_data_dir()
    out = tmp_path / "BENCHMARKS.md"
    status = main([
        "ik", "--quick", "--dtype", "float64", "--batches", "8", "--out", str(out), "--data-dir", str(data),
        "--only", "jaxanim LM (adaptive)*,Pinocchio*", "--quiet",
    ])
    assert status == 0
    text = out.read_text(encoding="utf-8")
    assert "failed:" not in text and "not available" not in text
    rows = _table_rows(text, "Inverse kinematics")
    for impl in (bench_ik._LM_ADAPTIVE,):
        row = _row(rows, impl, "float64", 8)
        assert row[7] == "100.0 %", f"success of {impl}: {row}"
        p98_pos, p98_ori = (float(x) for x in row[6].split(" / "))
        # LM stops once every effector is within STOP_FRACTION of the success thresholds
        # (1e-3 x height = 0.0257 units, 0.01 rad): its errors are inside those stop tolerances
        stop_pos, stop_ori = bench_ik.STOP_FRACTION * 0.0257, bench_ik.STOP_FRACTION * bench_ik.ORIENTATION_TOLERANCE
        assert p98_pos < stop_pos and p98_ori < stop_ori, f"p98 errors of {impl}: {row[6]}"
        assert row[5].endswith("s") and float(row[4]) > 0, row
        assert row[9].startswith("iterations "), row[9]
    assert not [r for r in rows if r[0].startswith(("optimistix", "jaxopt", "jaxanim CCD", bench_ik._LM_FIXED))], (
        "--only ignored"
    )
    try:
        import pinocchio  # noqa: F401
    except ImportError:
        assert any(r[0] == bench_ik._PIN and r[3].startswith("skipped:") for r in rows)
    else:
        assert _row(rows, bench_ik._PIN, "float64", 8)[7] == "100.0 %"
    assert "Target: ≥ 99.5 % success at batch 8 in float32 and float64 (own LM): worst jaxanim LM (adaptive)" in text
    assert "Iterations the adaptive LM took to converge" in text and "*Measured by `python -m benchmarks ik" in text


def test_profile_attributes_time_to_the_compiled_instructions(monkeypatch):
    """``benchmarks.profile``: the trace's events are the compiled program's instructions; a LAPACK solve shows up
    as a library call, and the quick FK profile row reports instructions run and kernels compiled. Inputs are built
    in NumPy (eager jnp compiled a program per op), and the section runs the float64 FK kernel only: ``--only``
    selects by name, which the float32 kernel shares, and its row (another compile and profiler trace) went
    unchecked."""
    import jax
    import jax.numpy as jnp

    from benchmarks import profile

    A = jnp.asarray(np.eye(64) * 3.0 + 0.01)
    compiled = jax.jit(lambda a, b: jnp.linalg.solve(a, jnp.sin(b))).lower(A, A).compile()
    instructions = profile.hlo_instructions(compiled.as_text())
    unfiltered = profile.profile_events(compiled, (A, A), calls=2)
    assert set(unfiltered) & set(instructions), unfiltered  # the trace's events name the program's instructions
    events = profile.profile_events(compiled, (A, A), calls=2, names=instructions)
    assert events and set(events) <= set(instructions), set(events) - set(instructions)
    p = profile.summarize(events, instructions, compiled.as_text())
    kinds = dict(p.by_kind)
    assert any(k.startswith("library calls (dgetrf") for k in kinds), kinds
    assert abs(sum(kinds.values()) - 1.0) < 1e-9 and p.instructions_run >= 2 and p.kernels_compiled >= 2
    # the kernels by the library function they come from (XLA keeps each one's stack): a rotation conversion's
    # kernels are its own, and the product wrappers count at their caller
    from jaxanim.rotations import quat_to_matrix

    q = jnp.asarray(np.tile([0.6, 0.0, 0.8, 0.0], (7, 1)))
    text = jax.jit(lambda q: quat_to_matrix(q) @ jnp.sin(q[:, :3, None])).lower(q).compile().as_text()
    sources = dict(profile.kernel_sources(text))
    assert sum(sources.values()) == len(profile._kernel_lines(text)) >= 2, sources
    assert sources.get("rotations/_matrices.py:_quat_to_matrix", 0) >= 1 and "other" in sources, sources
    assert not any(s.endswith((":matmul", ":einsum", ":dot")) for s in sources), sources
    data = shared_data_dir()
    if data is None:
        pytest.skip("../shared/data is absent: the FK profile row needs the CMU clip")
    fk64 = [k for k in profile.KERNELS if k.name == "FK (quaternions)" and k.dtype == "float64"]
    assert len(fk64) == 1, profile.KERNELS
    monkeypatch.setattr(profile, "KERNELS", tuple(fk64))
    config = BenchConfig.make_quick(dtypes=("float64",), only=("FK (quaternions)",), data_dir=data, verbose=False)
    (table,) = profile.run_profile(config)
    rows = table.rows
    assert len(rows) == 1 and rows[0].dtype == "float64" and rows[0].measured, [r.skipped for r in rows]
    assert int(rows[0].accuracy) > 10 and "kernels compiled (the most from `kinematics/_fk.py:" in rows[0].note
    assert "**Cause**" in rows[0].note


def test_optimistix_lm_solves_the_ik_benchmark_in_float32(tmp_path):
    """The ``ik`` row of ``OptimistixSolver(optx.LevenbergMarquardt)`` in float32 at batch 8 (x64 on, as the
    benchmark runs): it solves every problem by the benchmark's independent evaluator. This failed to trace
    before the adapter cast optimistix's float64 trust-region scalars. (Float64: test_ik's optimistix tests; the
    float64 row here was another 10 s program to compile.)"""
    from benchmarks import ik as bench_ik

    out = tmp_path / "BENCHMARKS.md"
    status = main(["ik", "--quick", "--dtype", "float32", "--batches", "8", "--out", str(out),
                   "--data-dir", str(shared_data_dir()), "--only", "optimistix LM", "--quiet"])
    assert status == 0
    text = out.read_text(encoding="utf-8")
    assert "failed:" not in text, text
    rows = _table_rows(text, "Inverse kinematics")
    row = _row(rows, "optimistix LM", "float32", 8)
    assert row[7] == "100.0 %", f"success of optimistix LM in float32: {row}"
    p98_pos, p98_ori = (float(x) for x in row[6].split(" / "))
    assert p98_pos < bench_ik.STOP_FRACTION * 0.0257, row
    assert p98_ori < bench_ik.STOP_FRACTION * bench_ik.ORIENTATION_TOLERANCE, row
