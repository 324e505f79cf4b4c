"""The library's stated numerics on every backend: matrix products at a stated precision (the library's default:
``lax.Precision.HIGHEST``), and the XLA:CPU options of the simulator's, the tracker's and the retargeting's
programs.

Without a stated precision an NVIDIA GPU runs a float32 ``dot`` in TF32 (about 10 bits of mantissa); every
product in jaxanim goes through these, or states ``precision=`` itself. They are the solvers package's
(``solvers._linalg``), so the two packages share one default. The kernels where a user may want the fast path
(skinning, the motion-matching search) take a ``precision`` option, checked by :func:`check_precision`.

**Compiler options** (:func:`jit`: the physics step and rollout, the tracking search, replay, linearization
and gains, the robots' retargeting solve). jaxlib 0.10's XLA:CPU generates its fused loops with the MLIR
"fusion emitters" by default. For these programs, hundreds of small fusions of ``[batch, 6, 6]`` blocks, the
classic emitters (``xla_cpu_use_fusion_emitters=False``) build them in about two thirds of the time, and the
programs run as fast or faster. Measured on the 2-core CPU, alternating processes, emitters on / off: the
tracking search of the shipped walk (64 samples, 20 windows) compiles in 14.3-14.4 / 10.5-10.8 s and runs in
the same time; its linearization (``tracking.linearize``) compiles in 6.8-7.2 / 3.7-4.0 s (the same Jacobians
to the bit) and the LQR gains on it in 0.9-1.0 / 0.6 s; a batched rollout of 1,024 characters, complementarity
on 8 points, in 6.6 / 5.2 s, running 46-47 / 44-45 us per character-step (penalty contact: 5.5 / 3.8 s, 22 /
18-20 us); the whole-clip retargeting solve of four 120-frame clips onto the G1 in 9.6-10.7 / 7.5-7.6 s,
running 179-300 / 162-271 ms, the same joint angles to the bit. Not every program gains: the batched doubling
of ``solvers.dare`` ran 18 % slower, and a batch of 1,024 IK solves (Levenberg-Marquardt on the CMU skeleton)
compiled in 3.2-3.4 s instead of 4.7-4.9 but ran 5 % slower, so the option is these programs', not the
process's: ``solvers`` and the IK keep XLA's defaults.

The option reaches only programs whose top level is one of these entry points, called directly or under an
eager ``jax.vmap`` or ``jax.jvp`` (so a batch and a loop of calls compile alike). Called under a caller's own
``jax.jit`` or ``grad``, they take the plain jit, whose program compiles with the caller's options
(``XLA_FLAGS`` sets them for a whole process, ``jax.jit(..., compiler_options=COMPILER_OPTIONS)`` for one
program). It is passed only on the jaxlib versions it was measured on, and not where ``XLA_FLAGS`` already
names it, so a user's own setting wins.
"""

import functools
import os

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import lax
from jax._src import core as jax_core

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


def own_kernel(x):
    """``x`` itself, as the output of an XLA kernel of its own: a product with the identity over its last axis
    (exact for finite values). XLA:CPU otherwise fuses the whole computation of a value into every output of its
    consumers: in the IK residuals, the rotation vector's conversion (Shepperd's cases, the arctangent) was
    rebuilt in each of the nine entries of its left Jacobian, one kernel that LLVM took 0.19 / 0.38 s to build in
    float64 / float32. ``jax.lax.optimization_barrier`` does not do this: XLA:CPU removes it before fusion."""
    return einsum("...a,ab->...b", x, jnp.eye(x.shape[-1], dtype=x.dtype))


_FLAG = "xla_cpu_use_fusion_emitters"


def _options() -> dict:
    if tuple(jax.__version_info__[:2]) != (0, 10) or _FLAG in os.environ.get("XLA_FLAGS", ""):
        return {}
    return {_FLAG: False}


#: The compiler options of :func:`jit` (empty where they do not apply).
COMPILER_OPTIONS = _options()


#: The traces under which a jit's call still compiles as a top-level program (eager evaluation, and ``jax.vmap`` or
#: ``jax.jvp`` applied eagerly, which batch or differentiate the jit's own program); under any other (a caller's
#: ``jax.jit``, ``grad``, ``eval_shape``) its program is part of the caller's, where compiler options are an error.
_EAGER_TRACES = ("EvalTrace", "BatchTrace", "JVPTrace")


def _top_level() -> bool:
    """A jit called now compiles a program of its own, with its own compiler options (jax internals: where they
    are not as expected, the answer is no, and the plain jit runs)."""
    trace = getattr(getattr(jax_core, "trace_ctx", None), "trace", None)
    if trace is None:
        return False
    while trace is not None:
        if type(trace).__name__ not in _EAGER_TRACES:
            return False
        trace = getattr(trace, "parent_trace", None)
    return True


def _jit_with(options: dict, fun, **kwargs):
    """``eqx.filter_jit(fun)`` whose top-level calls (:func:`_top_level`) compile with ``options``; calls under a
    caller's ``jax.jit`` or ``grad`` take the plain one, whose program becomes part of the caller's."""
    plain = eqx.filter_jit(fun, **kwargs)
    if not options:
        return plain
    top = eqx.filter_jit(fun, compiler_options=options, **kwargs)

    def pick():
        return top if _top_level() else plain

    @functools.wraps(fun)
    def call(*args, **kw):
        return pick()(*args, **kw)

    call.lower = lambda *args, **kw: pick().lower(*args, **kw)
    return call


def jit(fun=None, **kwargs):
    """``eqx.filter_jit`` with :data:`COMPILER_OPTIONS` for its top-level calls (usable as a decorator)."""
    if fun is None:
        return lambda f: jit(f, **kwargs)
    return _jit_with(COMPILER_OPTIONS, fun, **kwargs)
