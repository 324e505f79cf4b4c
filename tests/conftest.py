"""Test configuration: float64, strict rank promotion, and access to ../shared/data."""

from __future__ import annotations

import pathlib

import jax
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

REPO = pathlib.Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


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
