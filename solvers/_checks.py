"""Small helpers shared by the solvers: input checks (Python, before tracing) and tree / array
utilities used inside the traced code."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool


def _fmt(shape) -> str:
    """A shape as Python prints a tuple: ``(3,)``, ``(2, 3)``."""
    shape = tuple(shape)
    return "(" + ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


def _as_float(name: str, x) -> Array:
    """``x`` as a real floating array (integers promoted); ``None`` and complex input raise."""
    if x is None:
        raise ValueError(f"{name}: expected an array, got None")
    x = jnp.asarray(x)
    if jnp.issubdtype(x.dtype, jnp.complexfloating):
        raise ValueError(f"{name}: expected a real array, got dtype {x.dtype}")
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


def _sym(M: Array) -> Array:
    """The symmetric part of (a stack of) square matrices."""
    return 0.5 * (M + jnp.swapaxes(M, -1, -2))


def _all_finite(*xs: Array) -> Bool[Array, ""]:
    out = jnp.array(True)
    for x in xs:
        out = out & jnp.all(jnp.isfinite(x))
    return out


def _amax(x: Array) -> Array:
    """``max |x|`` over all entries."""
    return jnp.max(jnp.abs(x))


def _check_shape(name: str, x: Array, dims: tuple[str, ...], sizes: dict[str, int]) -> None:
    """Raise unless ``x.shape`` is ``dims`` with the ``sizes``: ``B: expected shape (n, m) = (4, 2), got (4, 3)``."""
    expected = tuple(sizes[d] for d in dims)
    if x.shape != expected:
        names = "(" + ", ".join(dims) + ("," if len(dims) == 1 else "") + ")"
        raise ValueError(f"{name}: expected shape {names} = {_fmt(expected)}, got {_fmt(x.shape)}")


def _check_int(name: str, value, minimum: int) -> None:
    """Raise unless ``value`` is an int (not a bool) ``>= minimum``."""
    if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < minimum:
        raise ValueError(f"{name}: expected an int >= {minimum}, got {value!r}")


def _common_dtype(*xs: Array):
    """The promoted dtype of the arrays that are not ``None``."""
    return jnp.result_type(*[x.dtype for x in xs if x is not None])
