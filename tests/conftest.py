"""Test configuration: float64, strict rank promotion, and access to ../shared/data."""

from __future__ import annotations

import collections
import gc
import os
import pathlib
import shutil
import tempfile

# XLA's CPU fusion emitters (the MLIR-based code generator, on by default in jaxlib 0.10) take two
# to three times longer than the classic emitters to compile the solvers' nested loops (a
# Levenberg-Marquardt solve: 0.27 s against 0.72 s), while the tests' run time stayed the same
# (test_tracking, 4/5 of it running: 209 s against 223 s). Compilation dominates the suite, so the
# suite turns them off. Set before jax starts its CPU backend, which reads XLA_FLAGS once.
if "--xla_cpu_use_fusion_emitters" not in os.environ.get("XLA_FLAGS", ""):  # xdist workers inherit it
    os.environ["XLA_FLAGS"] = " ".join(filter(None, (os.environ.get("XLA_FLAGS"), "--xla_cpu_use_fusion_emitters=false")))

# Each xdist worker runs on a core of its own. XLA:CPU sizes its thread pools (run time and
# parallel LLVM codegen) by the cores a process may use, so two workers on two shared cores ran four
# pools that waited on each other; pinned, each worker's XLA works on one core. Measured on 2 cores,
# test_tracking + test_balance + test_ik + test_least_squares, interleaved: 290 and 300 s shared,
# 234 and 224 s pinned. Skipped where there are fewer cores than workers, or with
# JAXANIM_TEST_NO_PIN=1.
_WORKER = os.environ.get("PYTEST_XDIST_WORKER", "")
if _WORKER.startswith("gw") and not os.environ.get("JAXANIM_TEST_NO_PIN") and hasattr(os, "sched_setaffinity"):
    _cpus = sorted(os.sched_getaffinity(0))
    if len(_cpus) >= int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")):
        os.sched_setaffinity(0, {_cpus[int(_WORKER[2:]) % len(_cpus)]})

# Python's cyclic garbage collector at its default thresholds (700 allocations) ran a collection every few
# hundred of the objects that JAX's tracing creates; at 100,000 the retargeting gradient's program (about 11,000
# equations) traced in 7.8 s instead of 8.8 (two runs each, pinned). Only tracing, lowering and the tests' own
# Python run faster: the programs and their numbers are the same.
gc.set_threshold(100_000, 50, 100)

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

REPO = pathlib.Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
_CACHE_ENV = "JAXANIM_TEST_COMPILE_CACHE"


def pytest_configure(config):
    """One persistent compilation cache per test run, shared by the xdist workers (they inherit the
    controller's environment): a program that several test files compile (the CMU-skeleton IK, the
    character's rollout) is compiled by XLA once per run. Each run starts empty, so times stay those
    of a clean machine. Only programs that take 2 s or more to compile are kept: writing and reading
    every small one cost more than it saved (test_ik + test_least_squares: 143 s with every program
    kept, 126 s without the cache, 129 s with the 2 s floor)."""
    if not hasattr(config, "workerinput"):  # the controller (or a run without xdist) owns the folder
        config._jaxanim_cache = tempfile.mkdtemp(prefix="jaxanim-test-xla-")
        os.environ[_CACHE_ENV] = config._jaxanim_cache
    jax.config.update("jax_compilation_cache_dir", os.environ[_CACHE_ENV])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 2.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


#: The test files that took longest (seconds of test time, both workers' runs of 2026-12-07 summed per file:
#: test_tracking 152, test_robots_retarget 117, test_ik 64, test_balance 55, test_robots_ik 53, test_joint_limits
#: 44, test_precision 44, test_least_squares 40, test_benchmarks 37, test_ik_limits 31, test_torque_limits 27,
#: test_tracking_jump 27; the rest 15 or less each).
_LONGEST = ("test_tracking", "test_robots_retarget", "test_ik", "test_balance", "test_robots_ik", "test_joint_limits",
            "test_precision", "test_least_squares", "test_benchmarks", "test_ik_limits", "test_torque_limits",
            "test_tracking_jump")


def pytest_collection_finish(session):
    """The objects alive after collection (the imported modules: JAX, the library, the peers, the tests) moved
    out of the garbage collector's reach, where its rare full collections no longer walk them: test_precision +
    test_robots_ik took 89-90 s instead of 91-92 (alternating cores, two rounds)."""
    gc.collect()
    gc.freeze()


def pytest_collection_modifyitems(config, items):
    """Files in the order the workers take them (``--dist loadfile --no-loadscope-reorder``): the longest first
    (:data:`_LONGEST`), then the rest by their number of tests, most first (xdist's own order). In xdist's order
    alone, by number of tests, test_tracking_jump.py (27 s in one test) came last and test_tracking.py (2.5 minutes)
    after 300 s: replayed on the per-file times above, one file at a time to the worker that is free first, the two
    workers finished at 607 and 632 s in that order, at 619 and 620 s in this one. Within a file the order is
    unchanged."""
    def file(item):
        return item.nodeid.split("::")[0]

    count = collections.Counter(map(file, items))
    rank = {f"tests/{stem}.py": i for i, stem in enumerate(_LONGEST)}
    items.sort(key=lambda item: (rank.get(file(item), len(rank)), -count[file(item)]))


def pytest_unconfigure(config):
    if getattr(config, "_jaxanim_cache", None):
        shutil.rmtree(config._jaxanim_cache, ignore_errors=True)


def shared_data_dir() -> pathlib.Path:
    """``../shared/data`` beside the clone, or skip the test with the reason."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared reference data not found at {SHARED_DATA} (it sits beside the clone in CI)")
    return SHARED_DATA


def shared_bvh_files() -> list[str]:
    """Names (stems) of the shared BVH clips, or an empty list when the data is absent."""
    if not SHARED_DATA.is_dir():
        return []
    return sorted(p.stem for p in (SHARED_DATA / "bvh").glob("*.bvh"))


@pytest.fixture(scope="session")
def shared_data() -> pathlib.Path:
    return shared_data_dir()
