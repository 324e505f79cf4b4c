"""Test configuration: float64, strict rank promotion, and access to ../shared/data."""

from __future__ import annotations

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
