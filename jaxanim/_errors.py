"""Exceptions and input checks shared by the whole package.

Shape, dtype and structure problems are found in Python, before tracing, and raise
:class:`JaxanimError` (a ``ValueError``) whose message names the argument, the expected shape and
the shape it got. File parsing raises :class:`BVHParseError` with the path and line number.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import numpy as np


class JaxanimError(ValueError):
    """Bad input to a jaxanim function: wrong shape, dtype, name or structure."""


class BVHParseError(JaxanimError):
    """A BVH file could not be parsed.

    Attributes:
        path: the file (or ``"<string>"`` when parsing text).
        line: 1-based line number where the problem was found (the last line for a truncated file).
        message: what was expected and what was found.
    """

    def __init__(self, path: str, line: int, message: str):
        self.path = str(path)
        self.line = int(line)
        self.message = message
        super().__init__(f"{self.path}:{self.line}: {message}")


def _fmt_shape(shape: Sequence[int | None | str]) -> str:
    parts = ["*" if s is None else str(s) for s in shape]
    return "(" + ", ".join(parts) + ("," if len(parts) == 1 else "") + ")"


def check_shape(
    name: str,
    x,
    expected: Sequence[int | None],
    *,
    batch: bool = False,
    what: str | None = None,
) -> None:
    """Raise :class:`JaxanimError` unless ``x`` has the ``expected`` shape.

    Args:
        name: the argument's name, as the user wrote it.
        x: anything with a ``.shape`` (arrays, tracers, ``ShapeDtypeStruct``) or a nested sequence.
        expected: the expected shape; ``None`` matches any size along that axis.
        batch: if true, any number of leading axes may precede ``expected``.
        what: an optional description of the dimensions, e.g. ``"(joints, 3) = (31, 3)"``.
    """
    shape = getattr(x, "shape", None)
    if shape is None:
        try:
            shape = np.shape(x)
        except Exception as exc:  # ragged lists and the like
            raise JaxanimError(f"{name}: expected an array of shape {_fmt_shape(expected)}, got {type(x).__name__}") from exc
    shape = tuple(shape)
    exp = tuple(expected)
    tail = shape[len(shape) - len(exp):] if batch and len(shape) >= len(exp) else shape
    ok = len(tail) == len(exp) and all(e is None or e == s for e, s in zip(exp, tail))
    if batch and len(shape) < len(exp):
        ok = False
    if not ok:
        if what is not None:
            desc = what
        elif batch:
            desc = "(..., " + ", ".join("*" if s is None else str(s) for s in exp) + ")"
        else:
            desc = _fmt_shape(exp)
        raise JaxanimError(f"{name}: expected shape {desc}, got {_fmt_shape(shape)}")


def check_float(name: str, x) -> None:
    """Raise :class:`JaxanimError` unless ``x`` has a floating dtype (ints are promoted by callers)."""
    dtype = getattr(x, "dtype", None)
    if dtype is not None and not (np.issubdtype(dtype, np.floating) or np.issubdtype(dtype, np.integer)):
        raise JaxanimError(f"{name}: expected a real floating-point array, got dtype {dtype}")


def check_positive(name: str, x, *, zero: bool = False, units: str | None = None) -> None:
    """Raise :class:`JaxanimError` unless every value of ``x`` is a finite number ``> 0`` (``>= 0`` with
    ``zero=True``), when ``x`` is concrete: a traced ``x`` (under ``jit`` or ``vmap``) is the caller's
    to check, so functions that call this still trace. ``None`` passes (an optional argument).

    Args:
        name: the argument's name, as the user wrote it.
        x: a number or an array of them.
        zero: accept 0 (gains, where 0 means off); otherwise 0 is refused (halflives, times).
        units: shown in the message, e.g. ``"seconds"``.
    """
    if x is None or isinstance(x, jax.core.Tracer):
        return
    v = np.asarray(x)
    if not (np.issubdtype(v.dtype, np.floating) or np.issubdtype(v.dtype, np.integer)):
        return  # not a number: a dtype problem, for check_float
    bad = ~np.isfinite(v) | ((v < 0) if zero else ~(v > 0))
    if bad.any():
        sign = "non-negative" if zero else "positive"
        unit = f" ({units})" if units else ""
        if v.ndim == 0:
            raise JaxanimError(f"{name}: expected a {sign} finite number{unit}, got {v.item()!r}")
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        raise JaxanimError(f"{name}: expected {sign} finite values{unit}, got {v[first].item()!r} at index "
                           f"{first[0] if len(first) == 1 else first}")
