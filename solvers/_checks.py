"""Small helpers shared by the solvers: input checks (Python, before tracing) and tree / array
utilities used inside the traced code."""

from __future__ import annotations

import jax
import jax.numpy as jnp
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


def _tree_where(pred: Bool[Array, ""], a, b):
    return jax.tree.map(lambda x, y: jnp.where(pred, x, y), a, b)
