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
vmappable; joints are grouped by rotation order so it costs a few vectorised calls, not one per
joint. The text parsing itself runs on the host with NumPy.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import re

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .. import rotations as _rotations
from .._errors import BVHParseError, JaxanimError, check_float, check_shape
from .._types import Array, ArrayLike, Float
from ._skeleton import ROTATION_CHANNELS, VALID_CHANNELS, Motion, Skeleton

__all__ = [
    "channels_to_motion",
    "format_bvh",
    "motion_to_channels",
    "parse_bvh",
    "read_bvh",
    "write_bvh",
]

_AXES = "XYZ"
_CHANNEL_BY_LOWER = {c.lower(): c for c in VALID_CHANNELS}
# A finite decimal number as written in BVH files: "-1", "2.5", ".0083333", "1e-05", "5.".
_NUMBER_RE = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
# Characters that may appear in the MOTION block (anything else is certainly not a number).
_NON_NUMERIC_CHAR_RE = re.compile(r"[^0-9eE+\-.\s]")
_FRAMES_RE = re.compile(r"frames\s*:\s*(.*)", re.IGNORECASE)
_FRAME_TIME_RE = re.compile(r"frame\s+time\s*:\s*(.*)", re.IGNORECASE)


# ------------------------------------------------------------------------------------------------
# Channel layout: index arrays shared by channels_to_motion and motion_to_channels
# ------------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class _RotationGroup:
    order: str  # the joints' rotation axes in channel order, e.g. "ZXY", "Z" or "XY"
    joints: np.ndarray  # [n] joint indices
    cols: np.ndarray  # [n, len(order)] channel columns of those angles
    full_order: str  # a valid 3-axis order containing `order` (the inverse needs one)
    keep: np.ndarray  # [len(order)] which of the 3 angles of `full_order` are the listed ones


@dataclasses.dataclass(frozen=True)
class _Layout:
    num_channels: int
    num_joints: int
    groups: tuple[_RotationGroup, ...]
    identity_joints: np.ndarray  # [m] joints without rotation channels
    joint_inv_perm: np.ndarray  # [joints] position of each joint in the group concatenation
    trans_src: np.ndarray  # [3 * joints] index into concat([values, offsets.ravel()]) per component
    pos_src: np.ndarray  # [P] index into translations.reshape(3 * joints) per position column
    col_inv_perm: np.ndarray  # [channels] position of each file column in concat([pos, groups...])


def _complete_order(order: str) -> tuple[str, np.ndarray]:
    """A valid 3-axis order containing ``order`` and where its angles sit in it.

    One listed axis goes first, two listed axes go first and last, so the missing (zero) angle is
    in the middle, far from the gimbal singularity at a middle angle of +-90 degrees.
    """
    missing = "".join(a for a in _AXES if a not in order)
    if len(order) == 3:
        return order, np.arange(3)
    if len(order) == 2:
        return order[0] + missing + order[1], np.array([0, 2])
    return order + missing, np.array([0])


@functools.lru_cache(maxsize=256)
def _layout(channels: tuple[tuple[str, ...], ...]) -> _Layout:
    num_joints = len(channels)
    starts = np.cumsum([0] + [len(ch) for ch in channels])
    num_channels = int(starts[-1])
    by_order: dict[str, tuple[list[int], list[list[int]]]] = {}
    identity = []
    trans_src = num_channels + np.arange(3 * num_joints)
    pos_cols, pos_src = [], []
    for j, ch in enumerate(channels):
        order, cols = "", []
        for k, c in enumerate(ch):
            col = int(starts[j]) + k
            if c in ROTATION_CHANNELS:
                order += c[0]
                cols.append(col)
            else:
                a = _AXES.index(c[0])
                trans_src[3 * j + a] = col
                pos_cols.append(col)
                pos_src.append(3 * j + a)
        if order:
            js, cs = by_order.setdefault(order, ([], []))
            js.append(j)
            cs.append(cols)
        else:
            identity.append(j)
    groups = []
    concat_joints = []
    concat_cols = list(pos_cols)
    for order, (js, cs) in by_order.items():
        full_order, keep = _complete_order(order)
        groups.append(_RotationGroup(order, np.array(js), np.array(cs, dtype=np.int64), full_order, keep))
        concat_joints.extend(js)
        concat_cols.extend(np.array(cs).reshape(-1).tolist())
    concat_joints.extend(identity)
    joint_inv_perm = np.empty(num_joints, dtype=np.int64)
    joint_inv_perm[np.array(concat_joints, dtype=np.int64)] = np.arange(num_joints)
    col_inv_perm = np.empty(num_channels, dtype=np.int64)
    col_inv_perm[np.array(concat_cols, dtype=np.int64)] = np.arange(num_channels)
    return _Layout(
        num_channels=num_channels,
        num_joints=num_joints,
        groups=tuple(groups),
        identity_joints=np.array(identity, dtype=np.int64),
        joint_inv_perm=joint_inv_perm,
        trans_src=trans_src,
        pos_src=np.array(pos_src, dtype=np.int64),
        col_inv_perm=col_inv_perm,
    )


# ------------------------------------------------------------------------------------------------
# Channel values <-> Motion (pure jnp)
# ------------------------------------------------------------------------------------------------
def channels_to_motion(
    skeleton: Skeleton,
    values: Float[ArrayLike, "frames channels"],
    frame_time: Float[ArrayLike, ""],
    *,
    degrees: bool = True,
) -> Motion:
    """Convert raw BVH channel values (file order) to a :class:`Motion`.

    For joint ``j`` with rotation channels ``(A, B, C)`` (any 0 to 3 distinct axes, in file order)
    and values ``(a, b, c)``: ``R_parent_joint = R_A(a) @ R_B(b) @ R_C(c)`` as a wxyz quaternion
    (identity without rotation channels). Its translation is its OFFSET with each position channel
    replacing the matching component (so ``Xposition Yposition Zposition`` replace it entirely).

    Pure ``jax.numpy`` and jitted; batch over clips with ``jax.vmap``.

    Args:
        skeleton: gives the channel layout and the OFFSETs.
        values: ``[frames, channels]`` channel values, joint by joint in file order
            (``channels = skeleton.num_channels``); positions in file units, angles in degrees (or
            radians if ``degrees=False``). Integers are promoted to floats.
        frame_time: scalar seconds per frame.
        degrees: whether the rotation channels are in degrees (BVH files are).

    Returns:
        A :class:`Motion` with ``rotations [frames, joints, 4]`` (wxyz),
        ``translations [frames, joints, 3]`` and ``frame_time``, in the promoted dtype of
        ``values`` and ``skeleton.offsets``.

    Raises:
        JaxanimError: ``values`` is not ``[frames, channels]`` or ``frame_time`` is not a scalar.
    """
    if not isinstance(skeleton, Skeleton):
        raise JaxanimError(f"skeleton: expected a Skeleton, got {type(skeleton).__name__}")
    values = jnp.asarray(values)
    check_float("values", values)
    check_shape("values", values, (None, skeleton.num_channels), what=f"(frames, channels) = (*, {skeleton.num_channels})")
    frame_time = jnp.asarray(frame_time)
    check_float("frame_time", frame_time)
    check_shape("frame_time", frame_time, (), what="() (a scalar)")
    dtype = jnp.result_type(values.dtype, skeleton.offsets.dtype, jnp.float32)
    return _channels_to_motion(
        skeleton.channels, skeleton.offsets, values.astype(dtype), frame_time.astype(dtype), bool(degrees)
    )


# The jitted kernels take the channel layout (static), not the Skeleton, so that skeletons that
# differ only in names or End Sites share one compilation.
@eqx.filter_jit
def _channels_to_motion(
    channels: tuple[tuple[str, ...], ...], offsets: Array, values: Array, frame_time: Array, degrees: bool
) -> Motion:
    lay = _layout(channels)
    f, nj = values.shape[0], lay.num_joints
    quats = []
    for g in lay.groups:
        angles = values[:, g.cols]  # [F, n, k]
        quats.append(_rotations.euler_to_quat(angles, g.order, degrees=degrees))
    if lay.identity_joints.size:
        ident = jnp.array([1.0, 0.0, 0.0, 0.0], dtype=values.dtype)
        quats.append(jnp.broadcast_to(ident, (f, lay.identity_joints.size, 4)))
    rotations = jnp.concatenate(quats, axis=1)[:, lay.joint_inv_perm]
    offsets = jnp.broadcast_to(offsets.astype(values.dtype).reshape(1, 3 * nj), (f, 3 * nj))
    translations = jnp.concatenate([values, offsets], axis=1)[:, lay.trans_src].reshape(f, nj, 3)
    return Motion(rotations, translations, frame_time)


def motion_to_channels(
    skeleton: Skeleton,
    motion: Motion,
    *,
    degrees: bool = True,
) -> Float[Array, "frames channels"]:
    """Convert a :class:`Motion` to raw BVH channel values in file order (the inverse of
    :func:`channels_to_motion`).

    Position channels take the matching component of ``motion.translations``; translation
    components without a position channel (e.g. the OFFSET of an ordinary joint) are not stored.
    Rotation channels are the Euler angles of ``motion.rotations`` in the joint's channel order,
    in the canonical range of :func:`jaxanim.rotations.quat_to_euler` (middle angle in
    ``[-90, 90]``, outer ones in ``[-180, 180)``), so they may differ from the angles a clip was
    read from while describing the same rotation. A joint with one or two rotation channels gets
    the listed angles of a decomposition in a completed 3-axis order (listed axes first and last,
    missing axis in the middle): exact when the rotation is a product of the listed axes, a
    projection otherwise.

    Pure ``jax.numpy`` and jitted; batch over clips with ``jax.vmap``.

    Args:
        skeleton: gives the channel layout.
        motion: ``rotations [frames, joints, 4]`` (wxyz, normalised here) and
            ``translations [frames, joints, 3]``.
        degrees: return angles in degrees (as BVH files store them) rather than radians.

    Returns:
        ``[frames, channels]`` channel values (``channels = skeleton.num_channels``).

    Raises:
        JaxanimError: ``motion`` does not have one column per joint of ``skeleton``.
    """
    if not isinstance(skeleton, Skeleton):
        raise JaxanimError(f"skeleton: expected a Skeleton, got {type(skeleton).__name__}")
    if not isinstance(motion, Motion):
        raise JaxanimError(f"motion: expected a Motion, got {type(motion).__name__}")
    motion.check_skeleton(skeleton, "motion")
    check_float("motion.rotations", motion.rotations)
    check_float("motion.translations", motion.translations)
    return _motion_to_channels(skeleton.channels, motion.rotations, motion.translations, bool(degrees))


@eqx.filter_jit
def _motion_to_channels(
    channels: tuple[tuple[str, ...], ...], rotations: Array, translations: Array, degrees: bool
) -> Array:
    lay = _layout(channels)
    dtype = jnp.result_type(rotations.dtype, translations.dtype, jnp.float32)
    f, nj = rotations.shape[0], lay.num_joints
    pieces = [translations.astype(dtype).reshape(f, 3 * nj)[:, lay.pos_src]]
    for g in lay.groups:
        q = _rotations.quat_normalize(rotations[:, g.joints].astype(dtype))  # [F, n, 4]
        angles = _rotations.quat_to_euler(q, g.full_order, degrees=degrees)[..., g.keep]  # [F, n, k]
        pieces.append(angles.reshape(f, g.cols.size))
    return jnp.concatenate(pieces, axis=1)[:, lay.col_inv_perm]


# ------------------------------------------------------------------------------------------------
# Parsing (host side)
# ------------------------------------------------------------------------------------------------
class _Fail(Exception):
    """Internal: a parse error at a line; turned into BVHParseError with the path."""

    def __init__(self, line: int, message: str):
        super().__init__(message)
        self.line = line
        self.message = message


def _parse_number(tok: str, line: int, what: str) -> float:
    if _NUMBER_RE.fullmatch(tok):
        x = float(tok)
        if math.isfinite(x):
            return x
        raise _Fail(line, f"{what}: not a finite number: {tok!r}")
    raise _Fail(line, f"{what}: not a number: {tok!r}")


def _show(tok: str) -> str:
    return repr(tok if len(tok) <= 40 else tok[:37] + "...")


@dataclasses.dataclass
class _Block:
    kind: str  # "joint" or "end"
    index: int  # joint index, or End Site index
    name: str  # the joint's name (the owner's for an End Site)
    line: int
    offset_line: int = 0
    channels_line: int = 0


class _Reader:
    """Non-blank lines of the text with their 1-based numbers."""

    def __init__(self, lines: list[str]):
        self.lines = lines
        self.i = 0

    @property
    def last_line(self) -> int:
        return max(len(self.lines), 1)

    def next(self) -> tuple[int, list[str], str] | None:
        while self.i < len(self.lines):
            text = self.lines[self.i]
            self.i += 1
            toks = text.split()
            if toks:
                return self.i, toks, text
        return None

    def expect(self, what: str) -> tuple[int, list[str], str]:
        got = self.next()
        if got is None:
            raise _Fail(self.last_line, f"expected {what}, got the end of the file")
        return got


def _rest_after_keyword(text: str) -> str:
    """The line after its first token, stripped."""
    s = text.strip()
    parts = s.split(None, 1)
    return parts[1].strip() if len(parts) > 1 else ""


def _parse_hierarchy(reader: _Reader):
    names: list[str] = []
    name_lines: dict[str, int] = {}
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    end_parents: list[int] = []
    end_offsets: list[list[float]] = []

    line, toks, _ = reader.expect("'HIERARCHY'")
    if toks[0].upper() != "HIERARCHY" or len(toks) != 1:
        raise _Fail(line, f"expected 'HIERARCHY' on the first line, got {_show(' '.join(toks))}")
    line, toks, text = reader.expect("'ROOT <name>'")
    if toks[0].upper() != "ROOT":
        raise _Fail(line, f"expected 'ROOT <name>' after HIERARCHY, got {_show(toks[0])}")

    def open_joint(line: int, text: str, keyword: str, parent: int) -> _Block:
        name = _rest_after_keyword(text)
        if not name:
            raise _Fail(line, f"expected a joint name after {keyword}")
        if name in name_lines:
            raise _Fail(line, f"duplicate joint name {name!r} (first on line {name_lines[name]})")
        bline, btoks, _ = reader.expect(f"'{{' after {keyword} name")
        if btoks != ["{"]:
            raise _Fail(bline, f"expected '{{' after {keyword} name {name!r}, got {_show(' '.join(btoks))}")
        name_lines[name] = line
        names.append(name)
        parents.append(parent)
        offsets.append([0.0, 0.0, 0.0])
        channels.append(())
        return _Block("joint", len(names) - 1, name, line)

    def parse_offset(line: int, toks: list[str], owner: str) -> list[float]:
        if len(toks) != 4:
            raise _Fail(line, f"expected 3 numbers after OFFSET in {owner}, got {len(toks) - 1}")
        return [_parse_number(t, line, f"OFFSET of {owner}") for t in toks[1:]]

    def parse_channels(line: int, toks: list[str], owner: str) -> tuple[str, ...]:
        if len(toks) < 2 or not toks[1].isdigit() or not toks[1].isascii():
            got = _show(toks[1]) if len(toks) > 1 else "nothing"
            raise _Fail(line, f"expected a channel count after CHANNELS in {owner}, got {got}")
        n = int(toks[1])
        found = toks[2:]
        if len(found) != n:
            raise _Fail(line, f"expected {n} channel names after 'CHANNELS {n}' in {owner}, got {len(found)}")
        out = []
        for t in found:
            c = _CHANNEL_BY_LOWER.get(t.lower())
            if c is None:
                raise _Fail(line, f"bad channel name {_show(t)} in {owner}; valid: {', '.join(VALID_CHANNELS)}")
            if c in out:
                raise _Fail(line, f"channel {c} listed twice in {owner}")
            out.append(c)
        return tuple(out)

    stack = [open_joint(line, text, "ROOT", -1)]
    while stack:
        top = stack[-1]
        owner = f"joint {top.name!r}" if top.kind == "joint" else f"the End Site of {top.name!r}"
        got = reader.next()
        if got is None:
            raise _Fail(reader.last_line, f"expected '}}' closing {owner} (opened on line {top.line}), got the end of the file")
        line, toks, text = got
        kw = toks[0].upper()
        if kw == "}":
            if len(toks) != 1:
                raise _Fail(line, f"expected '}}' alone on its line, got {_show(' '.join(toks))}")
            if not top.offset_line:
                raise _Fail(line, f"expected OFFSET in {owner} before '}}'")
            if top.kind == "joint" and not top.channels_line:
                raise _Fail(line, f"expected CHANNELS in {owner} before '}}'")
            stack.pop()
        elif kw == "OFFSET":
            if top.offset_line:
                raise _Fail(line, f"second OFFSET in {owner} (first on line {top.offset_line})")
            value = parse_offset(line, toks, owner)
            if top.kind == "joint":
                offsets[top.index] = value
            else:
                end_offsets[top.index] = value
            top.offset_line = line
        elif top.kind == "end":
            raise _Fail(line, f"expected OFFSET or '}}' in {owner}, got {_show(toks[0])}")
        elif kw == "CHANNELS":
            if top.channels_line:
                raise _Fail(line, f"second CHANNELS in {owner} (first on line {top.channels_line})")
            channels[top.index] = parse_channels(line, toks, owner)
            top.channels_line = line
        elif kw in ("JOINT", "END"):
            child = "JOINT" if kw == "JOINT" else "End Site"
            if not (top.offset_line and top.channels_line):
                raise _Fail(line, f"expected OFFSET and CHANNELS in {owner} before {child}")
            if kw == "JOINT":
                stack.append(open_joint(line, text, "JOINT", top.index))
            else:
                if len(toks) != 2 or toks[1].upper() != "SITE":
                    raise _Fail(line, f"expected 'End Site', got {_show(' '.join(toks))}")
                bline, btoks, _ = reader.expect("'{' after End Site")
                if btoks != ["{"]:
                    raise _Fail(bline, f"expected '{{' after End Site, got {_show(' '.join(btoks))}")
                end_parents.append(top.index)
                end_offsets.append([0.0, 0.0, 0.0])
                stack.append(_Block("end", len(end_parents) - 1, top.name, line))
        elif kw == "ROOT":
            raise _Fail(line, f"unexpected ROOT inside {owner} (expected '}}' first; only one ROOT is supported)")
        elif kw == "MOTION":
            raise _Fail(line, f"expected '}}' closing {owner} (opened on line {top.line}), got MOTION")
        elif toks[0].lower() in _CHANNEL_BY_LOWER:
            raise _Fail(line, f"unexpected channel name {_show(toks[0])} in {owner}: channel names belong on the CHANNELS line")
        else:
            raise _Fail(line, f"expected OFFSET, CHANNELS, JOINT, End Site or '}}' in {owner}, got {_show(toks[0])}")

    # End Sites numbered by their joint, then in file order (a stable sort).
    order = sorted(range(len(end_parents)), key=lambda e: end_parents[e])
    return (
        names,
        parents,
        np.array(offsets, dtype=np.float64).reshape(-1, 3),
        channels,
        [end_parents[e] for e in order],
        np.array([end_offsets[e] for e in order], dtype=np.float64).reshape(-1, 3),
    )


def _parse_motion_header(reader: _Reader) -> tuple[int, float]:
    got = reader.next()
    if got is None:
        raise _Fail(reader.last_line, "expected MOTION after the hierarchy, got the end of the file")
    line, toks, _ = got
    if toks[0].upper() == "ROOT":
        raise _Fail(line, "a second ROOT: files with several ROOTs are not supported")
    if toks[0].upper() != "MOTION" or len(toks) != 1:
        raise _Fail(line, f"expected MOTION after the hierarchy, got {_show(' '.join(toks))}")

    line, toks, text = reader.expect("'Frames: <count>'")
    m = _FRAMES_RE.fullmatch(text.strip())
    if m is None:
        raise _Fail(line, f"expected 'Frames: <count>' after MOTION, got {_show(text.strip())}")
    count = m.group(1).strip()
    if not (count.isascii() and count.isdigit()):
        raise _Fail(line, f"expected a frame count (a non-negative integer) after 'Frames:', got {_show(count)}")
    num_frames = int(count)

    line, toks, text = reader.expect("'Frame Time: <seconds>'")
    m = _FRAME_TIME_RE.fullmatch(text.strip())
    if m is None:
        raise _Fail(line, f"expected 'Frame Time: <seconds>' after 'Frames:', got {_show(text.strip())}")
    frame_time = _parse_number(m.group(1).strip(), line, "Frame Time")
    if not frame_time > 0:
        raise _Fail(line, f"expected a positive Frame Time, got {m.group(1).strip()!r}")
    return num_frames, frame_time


def _parse_frames(reader: _Reader, num_frames: int, num_channels: int) -> np.ndarray:
    lines = reader.lines[reader.i:]
    first = reader.i + 1  # 1-based number of lines[0]
    if num_channels == 0:  # every frame line is empty: nothing to count or parse
        for k, text in enumerate(lines):
            if text.split():
                raise _Fail(first + k, f"expected empty frame lines (the skeleton has no channels), got {_show(text.split()[0])}")
        return np.zeros((num_frames, 0), dtype=np.float64)
    rows, row_lines = [], []
    for k, text in enumerate(lines):
        toks = text.split()
        if not toks:
            continue
        if len(rows) == num_frames:
            raise _Fail(first + k, f"expected {num_frames} frames, got more (extra line)")
        if len(toks) != num_channels:
            raise _Fail(first + k, f"expected {num_channels} values on frame {len(rows)}, got {len(toks)}")
        rows.append(toks)
        row_lines.append(first + k)
    if len(rows) < num_frames:
        raise _Fail(reader.last_line, f"expected {num_frames} frames, got {len(rows)} (file ends)")
    if not rows:
        return np.zeros((0, num_channels), dtype=np.float64)
    # Fast path: one character scan and one NumPy conversion for the whole block.
    values = None
    if _NON_NUMERIC_CHAR_RE.search("\n".join(lines)) is None:
        try:
            values = np.array(rows, dtype=np.float64)
        except ValueError:
            values = None
        if values is not None and not np.isfinite(values).all():
            values = None
    if values is None:  # slow path: find the first offending token
        for f, (toks, line) in enumerate(zip(rows, row_lines)):
            for t in toks:
                _parse_number(t, line, f"frame {f}")
        raise _Fail(row_lines[0], "could not read the frame values")  # pragma: no cover (unreachable)
    return values


def _split_lines(text: str) -> list[str]:
    text = text.replace("\r\n", "\n").replace("\r", "\n")
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    return lines


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


def _decode(data: bytes, path: str) -> str:
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise _Fail(line, f"not UTF-8 text: byte {data[exc.start]:#04x} at offset {exc.start}") from None


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
    values = np.array(motion_to_channels(skeleton, motion, degrees=True), dtype=np.float64)
    offsets = np.asarray(skeleton.offsets)
    end_offsets = np.asarray(skeleton.end_site_offsets)
    frame_time = np.asarray(motion.frame_time)
    if not np.isfinite(values).all():
        f = int(np.argwhere(~np.isfinite(values))[0, 0])
        raise JaxanimError(f"motion: non-finite rotation or translation on frame {f}; cannot write it")
    if not (np.isfinite(offsets).all() and np.isfinite(end_offsets).all()):
        raise JaxanimError("skeleton: non-finite offsets or end_site_offsets; cannot write them")
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise JaxanimError(f"motion.frame_time: expected a positive finite number, got {frame_time}")

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
