"""Input-check helpers shared by the solvers (Python, before tracing)."""

from __future__ import annotations


def _fmt(shape) -> str:
    """A shape as Python prints a tuple: ``(3,)``, ``(2, 3)``."""
    shape = tuple(shape)
    return "(" + ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
