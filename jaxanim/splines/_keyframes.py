"""Keyframe interpolation of a clip at new times: translations by a positional curve, joint
rotations by a slerp chain or squad.

Frame ``k`` of a :class:`~jaxanim.Motion` is the key at time ``k * frame_time`` (or at
``key_times[k]`` for a clip of sparse keys). Every translation column (the root translation, and
the OFFSETs of joints without position channels, which every curve here reproduces) is
interpolated with the chosen curve of :mod:`jaxanim.splines._curves`; every joint's rotation with
:func:`~jaxanim.splines.slerp_spline` or :func:`~jaxanim.splines.squad_spline`. ``"linear"`` with
``"slerp"`` is what :func:`jaxanim.resample_at` does.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from .._errors import JaxanimError, check_shape
from .._types import Array, ArrayLike, Float
from ..skeleton import Motion
from ._curves import _as_float_array, _check_knots, _evaluate, _make_curve
from ._rotation_curves import _rotation_curve

POSITION_METHODS = ("linear", "catmull_rom", "natural")
ROTATION_METHODS = ("slerp", "squad")


@eqx.filter_jit
def _interpolate(motion: Motion, knots: Array, times: Array, position: str, rotation: str) -> Motion:
    curve = _make_curve(position, knots, motion.translations)
    translations = _evaluate(curve, times, 0)
    per_joint = jax.vmap(_rotation_curve, in_axes=(None, None, 1, None), out_axes=1)
    rotations = per_joint(rotation, knots, motion.rotations, times)
    return Motion(rotations, translations, motion.frame_time)


def _method(name: str, value, valid: tuple[str, ...]) -> str:
    if value not in valid:
        raise JaxanimError(f"{name}: expected one of {', '.join(repr(v) for v in valid)}, got {value!r}")
    return value


def interpolate_motion(
    motion: Motion,
    times: Float[ArrayLike, " m"],
    *,
    key_times: Float[ArrayLike, " frames"] | None = None,
    position: str = "catmull_rom",
    rotation: str = "squad",
) -> Motion:
    """Sample a clip at new times by keyframe interpolation (jittable, vmappable).

    Translations follow the positional curve through the frames (``"linear"``, ``"catmull_rom"``
    with tangents ``(p_{k+1} - p_{k-1}) / (t_{k+1} - t_{k-1})``, or the ``"natural"`` cubic spline,
    C2), joint rotations the rotation curve (``"slerp"`` chain or ``"squad"``, C1), each joint
    separately. ``position="linear", rotation="slerp"`` matches :func:`jaxanim.resample_at` at
    ``frames = times / frame_time`` (rotations up to sign). Times outside the keys hold the first or
    last frame.

    Args:
        motion: the clip, at least 2 frames.
        times: ``[m]`` query times in seconds, frame 0 at time 0.
        key_times: ``[frames]`` strictly increasing times of the frames (default
            ``k * motion.frame_time``): for a clip whose frames are sparse keys.
        position: ``"linear"``, ``"catmull_rom"`` (default) or ``"natural"``.
        rotation: ``"slerp"`` or ``"squad"`` (default).

    Returns:
        A :class:`~jaxanim.Motion` with ``m`` frames and the same ``frame_time`` (set it as you
        need). Quaternions are continuous along the clip's keys (sign-aligned per joint), so a
        frame may come back as ``-q``.

    Raises:
        JaxanimError: if ``motion`` is not a ``Motion`` or has fewer than 2 frames, ``times`` is not
            ``(m,)``, ``key_times`` is not ``(frames,)`` or not strictly increasing (without
            ``key_times``: ``frame_time`` not a positive number), or a method is unknown.
    """
    if not isinstance(motion, Motion):
        raise JaxanimError(f"motion: expected a jaxanim Motion, got {type(motion).__name__}")
    position = _method("position", position, POSITION_METHODS)
    rotation = _method("rotation", rotation, ROTATION_METHODS)
    frames = motion.num_frames
    if frames < 2:
        raise JaxanimError(f"motion: expected at least 2 frames to interpolate, got {frames}")
    check_shape("times", times, (None,), what="(m,)")
    dtype = motion.rotations.dtype
    times = _as_float_array("times", times).astype(dtype)
    if key_times is None:
        motion.check_frame_time("motion")  # the knots k * frame_time must increase
        knots = jnp.arange(frames, dtype=dtype) * motion.frame_time.astype(dtype)
    else:
        check_shape("key_times", key_times, (frames,), what=f"(frames,) = ({frames},)")
        knots = _check_knots("key_times", key_times).astype(dtype)
    return _interpolate(motion, knots, times, position, rotation)
