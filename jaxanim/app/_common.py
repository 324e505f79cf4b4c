"""What the commands share: output (progress to stderr, results to stdout), loading a clip (BVH, or an
AMASS ``.npz`` with ``--body-model``), batched FK and the npz layout, drawing one frame."""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import functools
import os
import pathlib
import statistics
import sys
import time
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import JaxanimError
from ..kinematics._fk import FKResult, forward_kinematics
from ..skeleton._amass import read_clip
from ..skeleton._default_clip import default_clip_path
from ..skeleton._skeleton import Motion, Skeleton

_PROG = "jaxanim"


# ------------------------------------------------------------------------------------------------
# Output
# ------------------------------------------------------------------------------------------------


class _UI:
    """Where messages go: progress to stderr, results to stdout, errors always."""

    def __init__(self, quiet: bool):
        self.quiet = quiet

    def progress(self, message: str) -> None:
        if not self.quiet:
            print(f"{_PROG}: {message}", file=sys.stderr, flush=True)

    def result(self, message: str) -> None:
        if not self.quiet:
            print(message, flush=True)

    def output(self, message: str) -> None:
        print(message, flush=True)

    def warning(self, message: str) -> None:
        print(f"{_PROG}: warning: {message}", file=sys.stderr, flush=True)

    def error(self, message: str) -> None:
        print(f"error: {message}", file=sys.stderr, flush=True)


def _ms(seconds: float) -> str:
    return f"{seconds * 1e3:.1f} ms" if seconds >= 1e-3 else f"{seconds * 1e3:.3f} ms"


def _duration(seconds: float) -> str:
    return f"{seconds:.2f} s" if seconds >= 1.0 else _ms(seconds)


def _num(x: float) -> str:
    return f"{x:.6g}"


# ------------------------------------------------------------------------------------------------
# Loading a clip, batched FK, the npz, one frame's plot
# ------------------------------------------------------------------------------------------------


@dataclasses.dataclass
class _Clip:
    label: str  # what to call it in messages
    path: pathlib.Path
    skeleton: Skeleton
    motion: Motion
    parse_seconds: float

    @property
    def stem(self) -> str:
        return self.path.stem


def _as_dtype(tree, dtype):
    """Cast the floating-point arrays of a Module to ``dtype``."""
    return jax.tree.map(lambda x: x.astype(dtype) if jnp.issubdtype(x.dtype, jnp.floating) else x, tree)


#: ``--body-model``, for the command that :func:`_body_model` wraps: the commands call :func:`_load` without it.
_BODY_MODEL: contextvars.ContextVar[str | None] = contextvars.ContextVar("jaxanim_body_model", default=None)


@contextlib.contextmanager
def _warnings_to(ui: _UI):
    """The Python warnings raised inside (a URDF's missing meshes, a foot's default sole) printed as the
    command's own warnings, one line each, once the block has run."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    for w in caught:
        ui.warning(str(w.message))


@contextlib.contextmanager
def _body_model(path: str | None):
    """Within the block, :func:`_load` reads AMASS ``.npz`` clips with the body model ``path``."""
    token = _BODY_MODEL.set(path)
    try:
        yield
    finally:
        _BODY_MODEL.reset(token)


def _load(file: str | None, ui: _UI, dtype) -> _Clip:
    """Parse ``file`` (or the shipped default clip), with its arrays in ``dtype``: a BVH file, or an AMASS
    ``.npz`` read with the ``--body-model`` of the running command (:func:`_body_model`)."""
    if file is None:
        path = default_clip_path()
        label = f"{path.name} (the shipped default clip)"
    else:
        path = pathlib.Path(file)
        label = str(file)
    ui.progress(f"parsing {label}")
    t0 = time.perf_counter()
    skeleton, motion = read_clip(path, body_model=_BODY_MODEL.get())
    skeleton, motion = _as_dtype(skeleton, dtype), _as_dtype(motion, dtype)
    jax.block_until_ready(motion)
    seconds = time.perf_counter() - t0
    return _Clip(label, path, skeleton, motion, seconds)


@functools.lru_cache(maxsize=None)
def batched_fk():
    """``jax.jit(jax.vmap(forward_kinematics, in_axes=(None, 0, 0)))``: FK of every frame at once."""
    return jax.jit(jax.vmap(forward_kinematics, in_axes=(None, 0, 0)))


@dataclasses.dataclass
class _FKRun:
    result: FKResult  # batched over frames
    compile_seconds: float
    run_seconds: float  # the first call after compilation, or the median of the repeats after it
    repeats: int


def _clip_fk(clip: _Clip, ui: _UI, *, repeats: int = 1) -> _FKRun:
    """FK of all frames in one batched call; compilation timed separately from the run."""
    m = clip.motion
    ui.progress(f"forward kinematics of {m.num_frames} frames x {m.num_joints} joints (one batched call)")
    args = (clip.skeleton, m.rotations, m.translations)
    t0 = time.perf_counter()
    compiled = batched_fk().lower(*args).compile()
    compile_seconds = time.perf_counter() - t0
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        result = jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - t0)
    timed = times[1:] or times  # with repeats, the first call is a warm-up
    return _FKRun(result, compile_seconds, statistics.median(timed), len(timed))


def _fk_arrays(skeleton: Skeleton, motion: Motion, fk: FKResult) -> dict[str, np.ndarray]:
    """The ``fk`` npz content (the layout of ``shared/data/fk/*.fk.npz``)."""
    return {
        "joint_names": np.array(skeleton.names, dtype=str),
        "parents": np.array(skeleton.parents, dtype=np.int64),
        "offsets": np.asarray(skeleton.offsets),
        "channels": np.array([" ".join(ch) for ch in skeleton.channels], dtype=str),
        "end_site_names": np.array(skeleton.end_site_names, dtype=str),
        "end_site_parents": np.array(skeleton.end_site_parents, dtype=np.int64),
        "end_site_offsets": np.asarray(skeleton.end_site_offsets),
        "frame_time": np.asarray(motion.frame_time),
        "positions": np.asarray(fk.positions),
        "rotations": np.asarray(fk.rotations),
        "end_site_positions": np.asarray(fk.end_site_positions),
    }


def _save_npz(path: str | os.PathLike, arrays: dict[str, np.ndarray]) -> None:
    with open(path, "wb") as fh:  # a file object: numpy must not append ".npz" to the name
        np.savez(fh, **arrays)


def _check_frame(clip: _Clip, frame: int) -> None:
    n = clip.motion.num_frames
    if n == 0:
        raise JaxanimError(f"--frame {frame}: {clip.label} has no frames")
    if not 0 <= frame < n:
        raise JaxanimError(f"--frame {frame} is out of range: {clip.label} has {n} frames (valid: 0 to {n - 1})")


def _plot(clip: _Clip, frame: int, out: str | os.PathLike) -> None:
    from ._plot import save_pose_png  # matplotlib is optional: import it only to plot

    m = clip.motion
    fk = forward_kinematics(clip.skeleton, m.rotations[frame], m.translations[frame])
    t = frame * float(m.frame_time)
    title = f"{clip.path.name}: frame {frame} (t = {t:.3f} s)"
    save_pose_png(out, clip.skeleton, fk, title=title)
