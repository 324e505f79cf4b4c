"""Reading and writing Biovision Hierarchy (BVH) motion files.

A BVH file has two parts. ``HIERARCHY`` describes the skeleton as nested blocks::

    HIERARCHY
    ROOT Hips
    {
        OFFSET 0.0 0.0 0.0
        CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
        JOINT Chest
        {
            OFFSET 0.0 5.21 0.0
            CHANNELS 3 Zrotation Xrotation Yrotation
            End Site
            {
                OFFSET 0.0 3.87 0.0
            }
        }
    }
    MOTION
    Frames: 2
    Frame Time: 0.033333
    8.03 35.01 88.36 -3.41 14.78 -164.35 13.09 40.30 -24.60
    7.81 35.10 86.47 -3.78 12.94 -166.97 12.64 42.57 -22.34

``MOTION`` then gives the frame count, the frame time in seconds, and one line per frame holding
every joint's channel values, joint by joint in file order and, within a joint, in the order of its
``CHANNELS`` line.

Conventions (those of :mod:`jaxanim.skeleton`):
    * joints are numbered in file order (depth first); ``parents[j] < j``; the root is joint 0;
    * a joint's rotation channels, listed left to right, compose left-most outermost:
      ``CHANNELS 3 Zrotation Xrotation Yrotation`` with values ``(a, b, c)`` gives
      ``R_parent_joint = Rz(a) @ Rx(b) @ Ry(c)`` (angles in degrees in the file). Any subset of the
      three axes in any order is allowed, and orders may differ between joints of one file;
    * a joint's local translation is its OFFSET, except that each position channel it has replaces
      the matching OFFSET component. For the usual ``Xposition Yposition Zposition`` the position
      channels replace the OFFSET entirely; a partial set (say only ``Yposition``) replaces only
      that component and the others keep the OFFSET's values;
    * an End Site is named ``<joint>_End`` (``_End1``, ... if a joint has several) and End Sites are
      numbered by their joint, then in file order.

Parsing is strict and line oriented: each keyword (``HIERARCHY``, ``ROOT``, ``JOINT``, ``End Site``,
``{``, ``}``, ``OFFSET``, ``CHANNELS``, ``MOTION``, ``Frames:``, ``Frame Time:``) starts its own
line, ``OFFSET`` and ``CHANNELS`` keep their values on their line, and each frame is exactly one
line. Keywords and channel names are matched case-insensitively; joint names are the rest of the
line after ``ROOT``/``JOINT`` with the surrounding whitespace removed (so they may contain colons or
inner spaces). Any whitespace separates tokens; LF, CRLF or CR line ends, blank lines and a missing
final newline are accepted. Only one ``ROOT`` is supported. Numbers must be finite decimals.

Every problem is reported as a :class:`~jaxanim.BVHParseError` carrying the path, the 1-based line
number and what was expected versus found; frame numbers in messages are 0-based, like
``Motion.rotations[f]``. Files are decoded as UTF-8 (a byte-order mark is skipped).

Writing uses ``"%.{precision}f"`` for the frame values, so reading the written file reproduces every
channel value to ``0.5 * 10**-precision`` (angles written in ``(-180, 180]``); OFFSETs and the frame
time are written with the shortest decimal that reads back to the same float, so the skeleton and
the frame time round-trip exactly.

The conversion between raw channel values and :class:`~jaxanim.Motion`
(:func:`channels_to_motion`, :func:`motion_to_channels`) is pure ``jax.numpy``, jittable and
vmappable; joints are grouped by rotation order so it costs a few vectorized calls, not one per
joint. The text parsing itself runs on the host with NumPy.

The parser lives in :mod:`jaxanim.skeleton._bvh_parse` and the channel conversion in
:mod:`jaxanim.skeleton._bvh_channels`; this module is the home of the public functions.
"""

from __future__ import annotations

import os

import jax.numpy as jnp
import numpy as np

from .._errors import BVHParseError, JaxanimError
from ._bvh_channels import channels_to_motion as channels_to_motion
from ._bvh_channels import _layout, motion_to_channels as motion_to_channels
from ._bvh_parse import _decode, _Fail, _parse_frames, _parse_hierarchy, _parse_motion_header, _Reader, _split_lines
from ._skeleton import Motion, Skeleton

__all__ = [
    "channels_to_motion",
    "format_bvh",
    "motion_to_channels",
    "parse_bvh",
    "read_bvh",
    "write_bvh",
]


# ------------------------------------------------------------------------------------------------
# Reading
# ------------------------------------------------------------------------------------------------


def parse_bvh(text: str, path: str = "<string>") -> tuple[Skeleton, Motion]:
    """Parse the text of a BVH file.

    See the module docstring for the accepted format and conventions.

    Args:
        text: the whole file (``str``; ``bytes`` are decoded as UTF-8).
        path: the name used in error messages.

    Returns:
        ``(skeleton, motion)``: the :class:`Skeleton` (names, parents, channels, OFFSETs and End
        Sites in file order) and the :class:`Motion` (``[frames, joints, 4]`` wxyz local rotations,
        ``[frames, joints, 3]`` local translations, frame time), as
        :func:`channels_to_motion` builds it from the frame values. Arrays are float64 when
        ``jax_enable_x64`` is on, float32 otherwise.

    Raises:
        BVHParseError: for any malformed input, with the 1-based line number (0 when the input is
            not text at all) and what was expected versus found. No other exception escapes and
            no partial result is returned.
    """
    path = str(path)
    line = 0
    try:
        if isinstance(text, (bytes, bytearray)):
            text = _decode(bytes(text), path)
        if not isinstance(text, str):
            raise _Fail(0, f"expected the BVH text as str or bytes, got {type(text).__name__}")
        reader = _Reader(_split_lines(text.removeprefix("\ufeff")))
        line = 1
        names, parents, offsets, channels, end_parents, end_offsets = _parse_hierarchy(reader)
        line = reader.i
        try:
            skeleton = Skeleton(names, parents, offsets, channels, end_parents, end_offsets)
        except JaxanimError as exc:
            raise _Fail(1, f"invalid skeleton: {exc}") from exc
        num_frames, frame_time = _parse_motion_header(reader)
        line = reader.i
        values = _parse_frames(reader, num_frames, skeleton.num_channels)
        line = reader.last_line
        motion = channels_to_motion(skeleton, jnp.asarray(values), jnp.asarray(frame_time))
    except BVHParseError:
        raise
    except _Fail as exc:
        raise BVHParseError(path, exc.line, exc.message) from None
    except Exception as exc:  # anything unforeseen still surfaces as a parse error
        raise BVHParseError(path, max(line, 1), f"could not parse: {type(exc).__name__}: {exc}") from exc
    return skeleton, motion


def read_bvh(path: str | os.PathLike) -> tuple[Skeleton, Motion]:
    """Read a BVH file.

    Args:
        path: the file to read (decoded as UTF-8; a byte-order mark is skipped).

    Returns:
        ``(skeleton, motion)`` as :func:`parse_bvh` returns them.

    Raises:
        BVHParseError: for malformed content (1-based line number), and also, with line 0, when
            the file cannot be opened or read (missing, a directory, no permission); the
            ``OSError`` is chained as ``__cause__``.
    """
    name = os.fspath(path) if isinstance(path, (str, os.PathLike)) else str(path)
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except (OSError, TypeError, ValueError) as exc:
        raise BVHParseError(str(name), 0, f"cannot read the file: {exc}") from exc
    return parse_bvh(data, path=str(name))


# ------------------------------------------------------------------------------------------------
# Writing
# ------------------------------------------------------------------------------------------------


def _shortest(x: float) -> str:
    """The shortest decimal that reads back to the same float (of the array's own precision)."""
    return np.format_float_positional(x, unique=True, trim="0")


def _check_name(name: str) -> None:
    if not name or name != name.strip() or "\n" in name or "\r" in name:
        raise JaxanimError(
            f"skeleton.names: joint name {name!r} cannot be written to BVH (it must be non-empty, "
            "on one line, without leading or trailing whitespace)"
        )


def _check_finite_motion(skeleton: Skeleton, motion: Motion) -> None:
    """A non-finite or zero quaternion, or a non-finite translation, names its first frame and joint (the
    conversion to Euler angles would otherwise write some angle for it)."""
    for what, arr in (("rotation", motion.rotations), ("translation", motion.translations)):
        a = np.asarray(arr, dtype=np.float64)
        bad = ~np.isfinite(a).all(axis=-1)
        if what == "rotation":
            bad |= ~(np.linalg.norm(np.where(np.isfinite(a), a, 0.0), axis=-1) > 0)
        if bad.any():
            f, j = (int(i) for i in np.argwhere(bad)[0])
            name = skeleton.names[j] if j < len(skeleton.names) else str(j)
            kind = "a zero quaternion" if what == "rotation" and np.isfinite(a[f, j]).all() else f"a non-finite {what}"
            raise JaxanimError(f"motion: {kind} on frame {f}, joint {name!r} ({int(bad.sum())} such values in all); "
                               "cannot write it")


def format_bvh(skeleton: Skeleton, motion: Motion, *, precision: int = 6) -> str:
    """Format a skeleton and clip as BVH text (the inverse of :func:`parse_bvh`).

    Frame values come from :func:`motion_to_channels` (degrees) and are written as
    ``"%.{precision}f"``; rotation angles are written in ``(-180, 180]``. OFFSETs and the frame
    time are written with the shortest decimal that reads back to the same float. Lines end with
    LF, indentation is one tab per level, and the text ends with a newline. The guarantees above
    assume float64 (``jax_enable_x64``); with float32 arrays the values carry float32 round-off
    (about 1e-7 relative, 1e-5 degrees), so decimals past that are noise and writing a clip read
    from such a file need not reproduce the text exactly. Translation components
    of joints without the matching position channel are not stored (the file keeps only the
    OFFSET), and End Sites are written inside their joint after its child joints.

    Args:
        skeleton: the skeleton to write.
        motion: ``[frames, joints, ...]`` clip on ``skeleton``.
        precision: decimals after the point for the frame values (0 to 17).

    Returns:
        The BVH text.

    Raises:
        JaxanimError: the motion does not match the skeleton, holds non-finite values, a joint
            name cannot be written, or ``precision`` is out of range.
    """
    if not isinstance(precision, (int, np.integer)) or isinstance(precision, bool) or not 0 <= precision <= 17:
        raise JaxanimError(f"precision: expected an integer in [0, 17], got {precision!r}")
    for name in skeleton.names:
        _check_name(name)
    values = np.array(motion_to_channels(skeleton, motion, degrees=True), dtype=np.float64)  # checks the shapes
    _check_finite_motion(skeleton, motion)
    offsets = np.asarray(skeleton.offsets)
    end_offsets = np.asarray(skeleton.end_site_offsets)
    frame_time = np.asarray(motion.frame_time)
    if not np.isfinite(values).all():
        f = int(np.argwhere(~np.isfinite(values))[0, 0])
        raise JaxanimError(f"motion: non-finite rotation or translation on frame {f}; cannot write it")
    if not (np.isfinite(offsets).all() and np.isfinite(end_offsets).all()):
        raise JaxanimError("skeleton: non-finite offsets or end_site_offsets; cannot write them")
    motion.check_frame_time("motion")

    # Angles in (-180, 180]: a value that would print as -180.000... prints as 180.000... instead.
    lay = _layout(skeleton.channels)
    rot_cols = np.concatenate([g.cols.reshape(-1) for g in lay.groups] + [np.zeros(0, dtype=np.int64)])
    half = 0.5 * 10.0 ** (-precision)
    rot = values[:, rot_cols]
    values[:, rot_cols] = np.where(rot <= -180.0 + half, rot + 360.0, rot)

    children: list[list[int]] = [[] for _ in skeleton.names]
    for j, p in enumerate(skeleton.parents):
        if p >= 0:
            children[p].append(j)
    ends: list[list[int]] = [[] for _ in skeleton.names]
    for e, p in enumerate(skeleton.end_site_parents):
        ends[p].append(e)

    def vec(v) -> str:
        return " ".join(_shortest(x) for x in v)

    out = ["HIERARCHY"]
    # Iterative depth-first walk (no recursion limit on deep chains).
    stack: list[tuple[str, int, int]] = [("joint", 0, 0)]
    while stack:
        kind, i, depth = stack.pop()
        pad = "\t" * depth
        if kind == "close":
            out.append(f"{pad}}}")
            continue
        if kind == "end":
            out += [f"{pad}End Site", f"{pad}{{", f"{pad}\tOFFSET {vec(end_offsets[i])}", f"{pad}}}"]
            continue
        keyword = "ROOT" if skeleton.parents[i] < 0 else "JOINT"
        ch = skeleton.channels[i]
        out += [f"{pad}{keyword} {skeleton.names[i]}", f"{pad}{{", f"{pad}\tOFFSET {vec(offsets[i])}",
                f"{pad}\tCHANNELS {len(ch)}" + "".join(" " + c for c in ch)]
        stack.append(("close", i, depth))
        for e in reversed(ends[i]):
            stack.append(("end", e, depth + 1))
        for c in reversed(children[i]):
            stack.append(("joint", c, depth + 1))
    out += ["MOTION", f"Frames: {values.shape[0]}", f"Frame Time: {_shortest(frame_time[()])}"]
    row = " ".join([f"%.{precision}f"] * values.shape[1])
    out += [row % tuple(r) for r in values.tolist()]
    return "\n".join(out) + "\n"


def write_bvh(path: str | os.PathLike, skeleton: Skeleton, motion: Motion, *, precision: int = 6) -> None:
    """Write a skeleton and clip to a BVH file (UTF-8, LF line ends); see :func:`format_bvh`.

    Args:
        path: the file to write (overwritten).
        skeleton: the skeleton to write.
        motion: ``[frames, joints, ...]`` clip on ``skeleton``.
        precision: decimals after the point for the frame values.

    Raises:
        JaxanimError: as :func:`format_bvh`.
        OSError: the file cannot be written.
    """
    text = format_bvh(skeleton, motion, precision=precision)
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(text)
