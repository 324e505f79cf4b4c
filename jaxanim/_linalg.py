"""Matrix products at a stated precision (the library's default: ``lax.Precision.HIGHEST``).

Without a stated precision an NVIDIA GPU runs a float32 ``dot`` in TF32 (about 10 bits of
mantissa); every product in jaxanim goes through these, or states ``precision=`` itself. They are
the solvers package's (``solvers._linalg``), so the two packages share one default. The kernels
where a user may want the fast path (skinning, the motion-matching search) take a ``precision``
option, checked by :func:`check_precision`.
"""

from jax import lax

from solvers._linalg import HIGHEST as HIGHEST, dot as dot, einsum as einsum, matmul as matmul

from ._errors import JaxanimError

_NAMES = {"highest": lax.Precision.HIGHEST, "high": lax.Precision.HIGH, "default": lax.Precision.DEFAULT}


def check_precision(name: str, precision) -> lax.Precision:
    """``precision`` as a ``lax.Precision``: one, or ``"highest"`` / ``"high"`` / ``"default"``.

    ``"default"`` is the backend's fastest (TF32 for float32 on NVIDIA GPUs, about 10 bits of
    mantissa; the same as ``"highest"`` on a CPU), ``"high"`` is bf16_3x on GPUs (about float32
    accuracy in three bf16 passes) and ``"highest"`` is full float32 / float64.

    Raises:
        JaxanimError: naming ``name`` if ``precision`` is none of these.
    """
    if isinstance(precision, lax.Precision):
        return precision
    if isinstance(precision, str) and precision.lower() in _NAMES:
        return _NAMES[precision.lower()]
    raise JaxanimError(
        f"{name}: expected a jax.lax.Precision or one of {sorted(_NAMES)}, got {precision!r}"
    )
