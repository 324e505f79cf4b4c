"""The BVH text parser (host side, NumPy): hierarchy, MOTION header and frame lines.

Strict and line oriented, as :mod:`jaxanim.skeleton._bvh` describes. Every problem raises
:class:`_Fail` with the 1-based line number; :func:`jaxanim.skeleton.parse_bvh` turns it into a
:class:`~jaxanim.BVHParseError` carrying the path.
"""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np

from ._skeleton import VALID_CHANNELS

_CHANNEL_BY_LOWER = {c.lower(): c for c in VALID_CHANNELS}
# A finite decimal number as written in BVH files: "-1", "2.5", ".0083333", "1e-05", "5.".
_NUMBER_RE = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
# Characters that may appear in the MOTION block (anything else is certainly not a number).
_NON_NUMERIC_CHAR_RE = re.compile(r"[^0-9eE+\-.\s]")
_FRAMES_RE = re.compile(r"frames\s*:\s*(.*)", re.IGNORECASE)
_FRAME_TIME_RE = re.compile(r"frame\s+time\s*:\s*(.*)", re.IGNORECASE)


# ------------------------------------------------------------------------------------------------
# Tokens and lines
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


def _split_lines(text: str) -> list[str]:
    text = text.replace("\r\n", "\n").replace("\r", "\n")
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    return lines


def _decode(data: bytes, path: str) -> str:
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise _Fail(line, f"not UTF-8 text: byte {data[exc.start]:#04x} at offset {exc.start}") from None


# ------------------------------------------------------------------------------------------------
# HIERARCHY
# ------------------------------------------------------------------------------------------------


def _parse_offset(line: int, toks: list[str], owner: str) -> list[float]:
    """The 3 numbers of an ``OFFSET`` line of ``owner`` (a joint or an End Site)."""
    if len(toks) != 4:
        raise _Fail(line, f"expected 3 numbers after OFFSET in {owner}, got {len(toks) - 1}")
    return [_parse_number(t, line, f"OFFSET of {owner}") for t in toks[1:]]


def _parse_channels(line: int, toks: list[str], owner: str) -> tuple[str, ...]:
    """The channel names of a ``CHANNELS n ...`` line of ``owner`` (spelled as in ``VALID_CHANNELS``)."""
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


@dataclasses.dataclass
class _Hierarchy:
    """What the HIERARCHY block has declared so far, in file order."""

    names: list[str] = dataclasses.field(default_factory=list)
    name_lines: dict[str, int] = dataclasses.field(default_factory=dict)
    parents: list[int] = dataclasses.field(default_factory=list)
    offsets: list[list[float]] = dataclasses.field(default_factory=list)
    channels: list[tuple[str, ...]] = dataclasses.field(default_factory=list)
    end_parents: list[int] = dataclasses.field(default_factory=list)
    end_offsets: list[list[float]] = dataclasses.field(default_factory=list)

    def open_joint(self, reader: _Reader, line: int, text: str, keyword: str, parent: int) -> _Block:
        """A ``ROOT`` / ``JOINT <name>`` line and the ``{`` after it."""
        name = _rest_after_keyword(text)
        if not name:
            raise _Fail(line, f"expected a joint name after {keyword}")
        if name in self.name_lines:
            raise _Fail(line, f"duplicate joint name {name!r} (first on line {self.name_lines[name]})")
        bline, btoks, _ = reader.expect(f"'{{' after {keyword} name")
        if btoks != ["{"]:
            raise _Fail(bline, f"expected '{{' after {keyword} name {name!r}, got {_show(' '.join(btoks))}")
        self.name_lines[name] = line
        self.names.append(name)
        self.parents.append(parent)
        self.offsets.append([0.0, 0.0, 0.0])
        self.channels.append(())
        return _Block("joint", len(self.names) - 1, name, line)

    def open_end_site(self, reader: _Reader, line: int, toks: list[str], joint: _Block) -> _Block:
        """An ``End Site`` line inside ``joint`` and the ``{`` after it."""
        if len(toks) != 2 or toks[1].upper() != "SITE":
            raise _Fail(line, f"expected 'End Site', got {_show(' '.join(toks))}")
        bline, btoks, _ = reader.expect("'{' after End Site")
        if btoks != ["{"]:
            raise _Fail(bline, f"expected '{{' after End Site, got {_show(' '.join(btoks))}")
        self.end_parents.append(joint.index)
        self.end_offsets.append([0.0, 0.0, 0.0])
        return _Block("end", len(self.end_parents) - 1, joint.name, line)

    def result(self):
        """``(names, parents, offsets, channels, end_parents, end_offsets)``; End Sites numbered by
        their joint, then in file order (a stable sort)."""
        order = sorted(range(len(self.end_parents)), key=lambda e: self.end_parents[e])
        return (
            self.names,
            self.parents,
            np.array(self.offsets, dtype=np.float64).reshape(-1, 3),
            self.channels,
            [self.end_parents[e] for e in order],
            np.array([self.end_offsets[e] for e in order], dtype=np.float64).reshape(-1, 3),
        )


def _close_block(line: int, toks: list[str], top: _Block, owner: str) -> None:
    """Check a ``}`` line: alone, and after the block's OFFSET (and a joint's CHANNELS)."""
    if len(toks) != 1:
        raise _Fail(line, f"expected '}}' alone on its line, got {_show(' '.join(toks))}")
    if not top.offset_line:
        raise _Fail(line, f"expected OFFSET in {owner} before '}}'")
    if top.kind == "joint" and not top.channels_line:
        raise _Fail(line, f"expected CHANNELS in {owner} before '}}'")


def _unexpected(line: int, toks: list[str], top: _Block, owner: str) -> _Fail:
    """The error for a line that has no place in the open block."""
    kw = toks[0].upper()
    if kw == "ROOT":
        return _Fail(line, f"unexpected ROOT inside {owner} (expected '}}' first; only one ROOT is supported)")
    if kw == "MOTION":
        return _Fail(line, f"expected '}}' closing {owner} (opened on line {top.line}), got MOTION")
    if toks[0].lower() in _CHANNEL_BY_LOWER:
        return _Fail(line, f"unexpected channel name {_show(toks[0])} in {owner}: channel names belong on the CHANNELS line")
    return _Fail(line, f"expected OFFSET, CHANNELS, JOINT, End Site or '}}' in {owner}, got {_show(toks[0])}")


def _parse_hierarchy(reader: _Reader):
    """The HIERARCHY block: joint names, parents, OFFSETs, channels and the End Sites (by joint)."""
    tree = _Hierarchy()
    line, toks, _ = reader.expect("'HIERARCHY'")
    if toks[0].upper() != "HIERARCHY" or len(toks) != 1:
        raise _Fail(line, f"expected 'HIERARCHY' on the first line, got {_show(' '.join(toks))}")
    line, toks, text = reader.expect("'ROOT <name>'")
    if toks[0].upper() != "ROOT":
        raise _Fail(line, f"expected 'ROOT <name>' after HIERARCHY, got {_show(toks[0])}")
    stack = [tree.open_joint(reader, line, text, "ROOT", -1)]
    while stack:
        top = stack[-1]
        owner = f"joint {top.name!r}" if top.kind == "joint" else f"the End Site of {top.name!r}"
        got = reader.next()
        if got is None:
            raise _Fail(reader.last_line, f"expected '}}' closing {owner} (opened on line {top.line}), got the end of the file")
        line, toks, text = got
        kw = toks[0].upper()
        if kw == "}":
            _close_block(line, toks, top, owner)
            stack.pop()
        elif kw == "OFFSET":
            if top.offset_line:
                raise _Fail(line, f"second OFFSET in {owner} (first on line {top.offset_line})")
            value = _parse_offset(line, toks, owner)
            if top.kind == "joint":
                tree.offsets[top.index] = value
            else:
                tree.end_offsets[top.index] = value
            top.offset_line = line
        elif top.kind == "end":
            raise _Fail(line, f"expected OFFSET or '}}' in {owner}, got {_show(toks[0])}")
        elif kw == "CHANNELS":
            if top.channels_line:
                raise _Fail(line, f"second CHANNELS in {owner} (first on line {top.channels_line})")
            tree.channels[top.index] = _parse_channels(line, toks, owner)
            top.channels_line = line
        elif kw in ("JOINT", "END"):
            child = "JOINT" if kw == "JOINT" else "End Site"
            if not (top.offset_line and top.channels_line):
                raise _Fail(line, f"expected OFFSET and CHANNELS in {owner} before {child}")
            if kw == "JOINT":
                stack.append(tree.open_joint(reader, line, text, "JOINT", top.index))
            else:
                stack.append(tree.open_end_site(reader, line, toks, top))
        else:
            raise _unexpected(line, toks, top, owner)
    return tree.result()


# ------------------------------------------------------------------------------------------------
# MOTION
# ------------------------------------------------------------------------------------------------


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
