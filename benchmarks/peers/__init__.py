"""Adapters that run the benchmark problems in other libraries (or plain numpy); a missing library raises
:class:`PeerUnavailable` (through :func:`require`), which the benchmark reports as a ``skipped`` row."""

from __future__ import annotations

import importlib
import warnings
from types import ModuleType

__all__ = ["PeerUnavailable", "require"]


class PeerUnavailable(RuntimeError):
    """A peer library cannot be used here; ``str(exc)`` is the reason shown in the report."""


def require(module: str, install_hint: str | None = None, quiet: bool = False) -> ModuleType:
    """Import ``module`` (``quiet``: muting its warnings) or raise :class:`PeerUnavailable`, with ``install_hint``."""
    try:
        with warnings.catch_warnings():
            if quiet:
                warnings.simplefilter("ignore")
            return importlib.import_module(module)
    except ImportError as exc:
        hint = f" ({install_hint})" if install_hint else ""
        raise PeerUnavailable(f"cannot import {module}: {exc}{hint}") from exc
