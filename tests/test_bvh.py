"""Tests for jaxanim.bvh: parsing, writing and the channel <-> Motion conversion.

References are independent of the parser under test: the skeleton layout and frame time stored
in ``shared/data/fk/*.fk.npz`` (bvh-python), scipy's ``Rotation.from_euler`` on the channel values
(scipy quaternions are **xyzw**; converted to wxyz here), and the local keyframes quoted from
bvhio's own unit test.
"""

from __future__ import annotations

import functools
import json
import re
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st
from scipy.spatial.transform import Rotation

from jaxanim import BVHParseError, JaxanimError, Motion, Skeleton
from jaxanim.bvh import channels_to_motion, format_bvh, motion_to_channels, parse_bvh, read_bvh, write_bvh
from tests.conftest import shared_bvh_files, shared_data_dir

_ATOL_QUAT = 1e-12  # float64 quaternion vs scipy from_euler
_ATOL_BVHIO = 1e-6  # bvhio keyframes are float32, quoted with 6 significant digits
_ATOL_MATRIX_ROUNDTRIP = 1e-7  # angles written with 6 decimals: 5e-7 deg per angle
_WRITTEN = 0.5e-6 + 1e-9  # half a unit in the 6th decimal, plus float64 slack


# ------------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------------
def _wxyz(q_xyzw: np.ndarray) -> np.ndarray:
    """scipy quaternions are xyzw; jaxanim's are wxyz."""
    return np.concatenate([q_xyzw[..., 3:], q_xyzw[..., :3]], axis=-1)


def _assert_same_rotation(q, q_ref, atol, what):
    """Quaternions equal up to sign (q and -q are the same rotation)."""
    q, q_ref = np.asarray(q), np.asarray(q_ref)
    sign = np.where(np.sum(q * q_ref, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    err = np.max(np.abs(q * sign - q_ref), initial=0.0)
    assert err <= atol, f"{what}: max quaternion difference {err:.3g} > {atol:.3g}"


def _matrices(q) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    return Rotation.from_quat(np.concatenate([q[:, 1:], q[:, :1]], axis=1)).as_matrix()


def _raw_frame_values(text: str) -> np.ndarray:
    """The MOTION values by plain splitting (independent of the parser under test)."""
    lines = text.replace("\r\n", "\n").split("\n")
    k = next(i for i, ln in enumerate(lines) if ln.strip().lower().startswith("frame time"))
    return np.array([[float(t) for t in ln.split()] for ln in lines[k + 1:] if ln.strip()])


def _rotation_columns(skeleton: Skeleton) -> np.ndarray:
    cols, c = [], 0
    for ch in skeleton.channels:
        cols += [c + k for k, name in enumerate(ch) if name.endswith("rotation")]
        c += len(ch)
    return np.array(cols, dtype=np.int64)


def _wrapped(d: np.ndarray) -> np.ndarray:
    """Angle differences (degrees) wrapped to [-180, 180)."""
    return (d + 180.0) % 360.0 - 180.0


@functools.lru_cache(maxsize=None)
def _shared(stem: str):
    data = shared_data_dir()
    path = data / "bvh" / f"{stem}.bvh"
    skeleton, motion = read_bvh(path)
    with open(path, encoding="utf-8", newline="") as fh:
        text = fh.read()
    return skeleton, motion, text, dict(np.load(data / "fk" / f"{stem}.fk.npz"))


# A small file exercising what the shared ones do not: mixed orders, position channels on
# non-root joints (a partial set on Spine), 1- and 2-channel rotations, CHANNELS 0, a joint without
# End Site, a name with a space and a colon. Line numbers matter to the error tests below.
_SMALL_HEADER = [
    "HIERARCHY",  # 1
    "ROOT Hips",  # 2
    "{",  # 3
    "\tOFFSET 1.0 2.0 3.0",  # 4
    "\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation",  # 5
    "\tJOINT Spine",  # 6
    "\t{",  # 7
    "\t\tOFFSET 0.5 5.0 -0.25",  # 8
    "\t\tCHANNELS 4 Yposition Xrotation Yrotation Zrotation",  # 9
    "\t\tJOINT Head",  # 10
    "\t\t{",  # 11
    "\t\t\tOFFSET 0.0 4.0 0.5",  # 12
    "\t\t\tCHANNELS 1 Yrotation",  # 13
    "\t\t\tEnd Site",  # 14
    "\t\t\t{",  # 15
    "\t\t\t\tOFFSET 0.0 2.0 0.0",  # 16
    "\t\t\t}",  # 17
    "\t\t}",  # 18
    "\t}",  # 19
    "\tJOINT Left Arm:1",  # 20
    "\t{",  # 21
    "\t\tOFFSET 3.0 0.0 0.0",  # 22
    "\t\tCHANNELS 5 Xposition Yposition Zposition Zrotation Yrotation",  # 23
    "\t\tJOINT LeftHand",  # 24
    "\t\t{",  # 25
    "\t\t\tOFFSET 2.0 0.0 0.0",  # 26
    "\t\t\tCHANNELS 3 Yrotation Zrotation Xrotation",  # 27
    "\t\t}",  # 28
    "\t}",  # 29
    "\tJOINT Tail",  # 30
    "\t{",  # 31
    "\t\tOFFSET 0.0 -1.0 -2.0",  # 32
    "\t\tCHANNELS 0",  # 33
    "\t\tEnd Site",  # 34
    "\t\t{",  # 35
    "\t\t\tOFFSET 0.0 0.0 -1.0",  # 36
    "\t\t}",  # 37
    "\t}",  # 38
    "}",  # 39
    "MOTION",  # 40
    "Frames: 3",  # 41
    "Frame Time: .04",  # 42
]  # frames on lines 43, 44, 45
_SMALL_ORDERS = ("ZXY", "XYZ", "Y", "ZY", "YZX", "")
_SMALL_NUM_CHANNELS = 19


def _small_values() -> np.ndarray:
    """[3, 19] frame values, angles inside the canonical Euler ranges (middle in (-80, 80))."""
    rng = np.random.default_rng(0)
    v = np.round(rng.uniform(-170.0, 170.0, size=(3, _SMALL_NUM_CHANNELS)), 2)
    v[:, [4, 8, 17]] = np.round(rng.uniform(-80.0, 80.0, size=(3, 3)), 2)  # middle angles
    v[:, [0, 1, 2, 6, 11, 12, 13]] = np.round(rng.uniform(-10.0, 10.0, size=(3, 7)), 3)  # positions
    return np.array([[float(f"{x:.3f}") for x in row] for row in v])  # exactly what the file holds


def _small_lines() -> list[str]:
    return _SMALL_HEADER + [" ".join(f"{x:.3f}" for x in row) for row in _small_values()]


def _small_text(eol: str = "\n", final_newline: bool = True) -> str:
    return eol.join(_small_lines()) + (eol if final_newline else "")


@functools.lru_cache(maxsize=None)
def _small():
    return parse_bvh(_small_text())


# ------------------------------------------------------------------------------------------------
# shared files vs references
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("stem", shared_bvh_files())
def test_shared_file_layout_matches_reference(stem):
    skeleton, motion, _, ref = _shared(stem)
    assert list(skeleton.names) == [str(x) for x in ref["joint_names"]], "joint_names"
    assert list(skeleton.parents) == ref["parents"].tolist(), "parents"
    np.testing.assert_array_equal(np.asarray(skeleton.offsets), ref["offsets"], err_msg="offsets")
    assert [" ".join(ch) for ch in skeleton.channels] == [str(x) for x in ref["channels"]], "channels"
    assert list(skeleton.end_site_names) == [str(x) for x in ref["end_site_names"]], "end_site_names"
    assert list(skeleton.end_site_parents) == ref["end_site_parents"].tolist(), "end_site_parents"
    np.testing.assert_array_equal(
        np.asarray(skeleton.end_site_offsets), ref["end_site_offsets"].reshape(-1, 3), err_msg="end_site_offsets"
    )
    assert float(motion.frame_time) == float(ref["frame_time"]), "frame_time"
    assert motion.num_frames == ref["positions"].shape[0], "frames"
    assert motion.rotations.shape == (motion.num_frames, skeleton.num_joints, 4)
    assert motion.rotations.dtype == jnp.float64 and motion.translations.dtype == jnp.float64


@pytest.mark.parametrize("stem", shared_bvh_files())
def test_shared_file_local_transforms_match_scipy(stem):
    skeleton, motion, text, _ = _shared(stem)
    raw = _raw_frame_values(text)
    assert raw.shape == (motion.num_frames, skeleton.num_channels)
    frames = sorted({0, motion.num_frames // 2, motion.num_frames - 1})
    rot = np.asarray(motion.rotations)[frames]
    trans = np.asarray(motion.translations)[frames]
    c = 0
    for j, ch in enumerate(skeleton.channels):
        vals = raw[frames, c:c + len(ch)]
        c += len(ch)
        axes = "".join(name[0] for name in ch if name.endswith("rotation"))
        angles = vals[:, [k for k, name in enumerate(ch) if name.endswith("rotation")]]
        q_ref = _wxyz(Rotation.from_euler(axes, angles, degrees=True).as_quat()) if axes else [1.0, 0.0, 0.0, 0.0]
        _assert_same_rotation(rot[:, j], q_ref, _ATOL_QUAT, f"{stem} joint {skeleton.names[j]!r} rotation")
        t_ref = np.tile(np.asarray(skeleton.offsets)[j], (len(frames), 1))
        for k, name in enumerate(ch):
            if name.endswith("position"):
                t_ref[:, "XYZ".index(name[0])] = vals[:, k]
        np.testing.assert_array_equal(trans[:, j], t_ref, err_msg=f"{stem} joint {skeleton.names[j]!r} translation")


def test_bvhio_local_keyframes():
    data = shared_data_dir()
    with open(data / "fk" / "bvhio_example.bvhio_unit_test_local_keyframes.json") as fh:
        ref = json.load(fh)["joints"]
    skeleton, motion, _, _ = _shared("bvhio_example")
    assert sorted(ref) == sorted(skeleton.names)
    for name, keys in ref.items():
        j = skeleton.index(name)
        for f, key in enumerate(keys):
            np.testing.assert_allclose(
                np.asarray(motion.translations[f, j]), key["position"], atol=_ATOL_BVHIO, err_msg=f"{name} frame {f} position"
            )
            _assert_same_rotation(motion.rotations[f, j], key["quat_wxyz"], _ATOL_BVHIO, f"{name} frame {f} rotation")


@pytest.mark.parametrize("stem", shared_bvh_files())
def test_shared_file_round_trip(stem):
    skeleton, motion, _, _ = _shared(stem)
    text = format_bvh(skeleton, motion)
    skeleton2, motion2 = parse_bvh(text)
    assert skeleton2.names == skeleton.names and skeleton2.parents == skeleton.parents
    assert skeleton2.channels == skeleton.channels and skeleton2.end_site_parents == skeleton.end_site_parents
    np.testing.assert_array_equal(np.asarray(skeleton2.offsets), np.asarray(skeleton.offsets), err_msg="offsets")
    np.testing.assert_array_equal(
        np.asarray(skeleton2.end_site_offsets), np.asarray(skeleton.end_site_offsets), err_msg="end_site_offsets"
    )
    assert float(motion2.frame_time) == float(motion.frame_time), "frame_time"

    c1 = np.asarray(motion_to_channels(skeleton, motion))
    c2 = np.asarray(motion_to_channels(skeleton2, motion2))
    rc = _rotation_columns(skeleton)
    pc = np.setdiff1d(np.arange(skeleton.num_channels), rc)
    assert np.max(np.abs(c2[:, pc] - c1[:, pc]), initial=0.0) <= _WRITTEN, "position channels"
    assert np.max(np.abs(_wrapped(c2[:, rc] - c1[:, rc])), initial=0.0) <= _WRITTEN, "rotation channels"
    np.testing.assert_allclose(
        np.asarray(motion2.translations), np.asarray(motion.translations), rtol=0, atol=_WRITTEN, err_msg="translations"
    )
    np.testing.assert_allclose(
        _matrices(motion2.rotations), _matrices(motion.rotations), rtol=0, atol=_ATOL_MATRIX_ROUNDTRIP, err_msg="rotations"
    )
    # write -> read -> write is the identity on the text.
    assert format_bvh(skeleton2, motion2) == text


# ------------------------------------------------------------------------------------------------
# handcrafted files
# ------------------------------------------------------------------------------------------------
def test_small_file_structure_and_values():
    skeleton, motion = _small()
    assert skeleton.names == ("Hips", "Spine", "Head", "Left Arm:1", "LeftHand", "Tail")
    assert skeleton.parents == (-1, 0, 1, 0, 3, 0)
    assert skeleton.rotation_orders == _SMALL_ORDERS
    assert skeleton.position_axes == ("XYZ", "Y", "", "XYZ", "", "")
    assert skeleton.end_site_names == ("Head_End", "Tail_End")
    assert skeleton.end_site_parents == (2, 5)
    np.testing.assert_array_equal(np.asarray(skeleton.end_site_offsets), [[0.0, 2.0, 0.0], [0.0, 0.0, -1.0]])
    assert float(motion.frame_time) == 0.04
    values = _small_values()
    starts = np.cumsum([0] + [len(ch) for ch in skeleton.channels])
    offsets = np.asarray(skeleton.offsets)
    for j, (ch, order) in enumerate(zip(skeleton.channels, _SMALL_ORDERS)):
        v = values[:, starts[j]:starts[j + 1]]
        angles = v[:, [k for k, c in enumerate(ch) if c.endswith("rotation")]]
        q_ref = _wxyz(Rotation.from_euler(order, angles, degrees=True).as_quat()) if order else np.tile([1.0, 0, 0, 0], (3, 1))
        _assert_same_rotation(motion.rotations[:, j], q_ref, _ATOL_QUAT, f"joint {skeleton.names[j]!r}")
    trans = np.asarray(motion.translations)
    np.testing.assert_array_equal(trans[:, 0], values[:, 0:3], err_msg="root positions replace the OFFSET")
    # Spine has only Yposition: X and Z come from its OFFSET (0.5, _, -0.25).
    np.testing.assert_array_equal(trans[:, 1], np.stack([np.full(3, 0.5), values[:, 6], np.full(3, -0.25)], 1))
    np.testing.assert_array_equal(trans[:, 3], values[:, 11:14], err_msg="non-root full position channels")
    for j in (2, 4, 5):
        np.testing.assert_array_equal(trans[:, j], np.tile(offsets[j], (3, 1)), err_msg=f"joint {j} OFFSET")


def test_small_file_channels_inverse():
    """motion_to_channels recovers the file's values (angles in canonical ranges), including the
    1- and 2-channel joints, in degrees and in radians."""
    skeleton, motion = _small()
    values = _small_values()
    np.testing.assert_allclose(np.asarray(motion_to_channels(skeleton, motion)), values, rtol=0, atol=1e-9)
    rad = np.asarray(motion_to_channels(skeleton, motion, degrees=False))
    rc = _rotation_columns(skeleton)
    expected = values.copy()
    expected[:, rc] = np.deg2rad(values[:, rc])
    np.testing.assert_allclose(rad, expected, rtol=0, atol=1e-11)
    motion_rad = channels_to_motion(skeleton, expected, 0.04, degrees=False)
    _assert_same_rotation(motion_rad.rotations, motion.rotations, 1e-12, "radians input")


@pytest.mark.parametrize(
    "variant",
    ["crlf", "cr", "no_final_newline", "crlf_no_final_newline", "spaces", "tabs_and_blank_lines", "bom", "bytes"],
)
def test_small_file_text_variants(variant):
    lines = _small_lines()
    if variant == "crlf":
        text = _small_text("\r\n")
    elif variant == "cr":
        text = _small_text("\r")
    elif variant == "no_final_newline":
        text = _small_text(final_newline=False)
    elif variant == "crlf_no_final_newline":
        text = _small_text("\r\n", final_newline=False)
    elif variant == "spaces":  # indentation and separators made of spaces, trailing spaces
        text = "\n".join(
            "  " * (len(ln) - len(ln.lstrip("\t")))
            + (ln.lstrip("\t") if "JOINT" in ln else ln.lstrip("\t").replace(" ", "   ")) + "  "
            for ln in lines
        )
    elif variant == "tabs_and_blank_lines":  # tab separators, blank lines everywhere, keywords' case
        out = []
        for ln in lines:
            ln = ln if ln.strip().startswith(("JOINT", "ROOT")) else ln.replace(" ", "\t")
            out += [ln, "", "\t"]
        text = "\n".join(out).replace("MOTION", "motion").replace("Frames:", "FRAMES :") + "\n\n\n"
    elif variant == "bom":
        text = "\ufeff" + _small_text()
    else:
        text = _small_text().encode("utf-8")
    skeleton, motion = parse_bvh(text)
    ref_skeleton, ref_motion = _small()
    assert skeleton.names == ref_skeleton.names and skeleton.channels == ref_skeleton.channels
    np.testing.assert_array_equal(np.asarray(skeleton.offsets), np.asarray(ref_skeleton.offsets))
    np.testing.assert_array_equal(np.asarray(motion.rotations), np.asarray(ref_motion.rotations))
    np.testing.assert_array_equal(np.asarray(motion.translations), np.asarray(ref_motion.translations))


def test_small_file_write_read(tmp_path):
    skeleton, motion = _small()
    path = tmp_path / "small.bvh"
    write_bvh(path, skeleton, motion)
    text = format_bvh(skeleton, motion)
    with open(path, encoding="utf-8", newline="") as fh:
        assert fh.read() == text
    assert "\r" not in text and text.endswith("\n")
    skeleton2, motion2 = read_bvh(path)
    assert skeleton2.names == skeleton.names and skeleton2.channels == skeleton.channels
    assert skeleton2.end_site_parents == skeleton.end_site_parents
    np.testing.assert_allclose(
        np.asarray(motion_to_channels(skeleton2, motion2)), _small_values(), rtol=0, atol=_WRITTEN, err_msg="values"
    )
    # Lower precision: values to half a unit of the last decimal; the skeleton stays exact.
    skeleton3, motion3 = parse_bvh(format_bvh(skeleton, motion, precision=1))
    np.testing.assert_array_equal(np.asarray(skeleton3.offsets), np.asarray(skeleton.offsets))
    np.testing.assert_allclose(
        np.asarray(motion_to_channels(skeleton3, motion3)), _small_values(), rtol=0, atol=0.05 + 1e-9, err_msg="precision=1"
    )


def test_writer_prints_angles_in_half_open_range():
    """An angle of -180 degrees is written as 180 so that write -> read -> write is stable."""
    skeleton, _ = _small()
    values = _small_values()
    values[:, 3] = [-180.0, 180.0, -179.9999999]
    text = format_bvh(skeleton, channels_to_motion(skeleton, values, 0.04))
    frames = [ln.split() for ln in text.splitlines()[-3:]]
    assert [row[3] for row in frames] == ["180.000000"] * 3
    assert format_bvh(*parse_bvh(text)) == text


def test_writer_rejects_bad_input(tmp_path):
    skeleton, motion = _small()
    with pytest.raises(JaxanimError, match="precision"):
        format_bvh(skeleton, motion, precision=-1)
    bad = Motion(motion.rotations, motion.translations.at[1, 0, 0].set(jnp.nan), motion.frame_time)
    with pytest.raises(JaxanimError, match="non-finite .* on frame 1"):
        format_bvh(skeleton, bad)
    # a NaN or zero quaternion is named by frame and joint (it would have been written as some angle)
    nan = Motion(motion.rotations.at[2, 3, 1].set(jnp.nan), motion.translations, motion.frame_time)
    with pytest.raises(JaxanimError, match=f"non-finite rotation on frame 2, joint '{skeleton.names[3]}'"):
        write_bvh(tmp_path / "nan.bvh", skeleton, nan)
    assert not (tmp_path / "nan.bvh").exists()
    zero = Motion(motion.rotations.at[0, 1].set(0.0), motion.translations, motion.frame_time)
    with pytest.raises(JaxanimError, match=f"zero quaternion on frame 0, joint '{skeleton.names[1]}'"):
        format_bvh(skeleton, zero)
    named = Skeleton(("Hips ",), (-1,), np.zeros((1, 3)))
    with pytest.raises(JaxanimError, match="cannot be written"):
        format_bvh(named, Motion(np.tile([1.0, 0, 0, 0], (1, 1, 1)), np.zeros((1, 1, 3)), 0.1))


def test_zero_frames_and_zero_channels():
    skeleton, motion = parse_bvh("\n".join(_SMALL_HEADER).replace("Frames: 3", "Frames: 0"))
    assert motion.rotations.shape == (0, 6, 4) and motion.translations.shape == (0, 6, 3)
    assert parse_bvh(format_bvh(skeleton, motion))[1].num_frames == 0
    text = "HIERARCHY\nROOT a\n{\n\tOFFSET 1 2 3\n\tCHANNELS 0\n}\nMOTION\nFrames: 2\nFrame Time: 0.1\n\n\n"
    skeleton, motion = parse_bvh(text)  # a frame of no channels is an empty line
    np.testing.assert_array_equal(np.asarray(motion.translations), np.tile([1.0, 2.0, 3.0], (2, 1, 1)))
    assert format_bvh(skeleton, motion).endswith("Frame Time: 0.1\n\n\n")
    with pytest.raises(BVHParseError, match="expected empty frame lines") as info:
        parse_bvh(text + "1\n")
    assert info.value.line == 12


def test_read_speed():
    """Host-side parsing of the 300-frame CMU clip is fast once the conversion is compiled (the
    target is well under 100 ms; the bound here is loose for loaded machines)."""
    path = shared_data_dir() / "bvh" / "cmu_01_01_trim300.bvh"
    _shared("cmu_01_01_trim300")  # compiled
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        jax.block_until_ready(read_bvh(path))
        times.append(time.perf_counter() - t0)
    assert min(times) < 0.5, f"reading took {min(times):.3f} s"


# ------------------------------------------------------------------------------------------------
# errors
# ------------------------------------------------------------------------------------------------
def _edit(edits):
    """The small file's lines with ``{line_number: new_text or None (delete)}`` applied."""
    lines = _small_lines()
    for n in sorted(edits, reverse=True):
        if edits[n] is None:
            del lines[n - 1]
        else:
            lines[n - 1] = edits[n]
    return "\n".join(lines) + "\n"


_FRAME1 = _small_lines()[43]
_FRAME2 = _small_lines()[44]

_ERROR_CASES = {
    "empty file": ("", 1, r"expected 'HIERARCHY', got the end of the file"),
    "blank file": ("\n  \n\t\n", 3, r"expected 'HIERARCHY'"),
    "not hierarchy": (_edit({1: "HIERARCHIES"}), 1, r"expected 'HIERARCHY' on the first line, got 'HIERARCHIES'"),
    "missing brace after JOINT": (_edit({7: None}), 7, r"expected '\{' after JOINT name 'Spine', got 'OFFSET"),
    "missing brace after ROOT": (_edit({3: None}), 3, r"expected '\{' after ROOT name 'Hips'"),
    "missing joint name": (_edit({6: "\tJOINT  "}), 6, r"expected a joint name after JOINT"),
    "bad channel name": (_edit({13: "\t\t\tCHANNELS 1 Yrot"}), 13, r"bad channel name 'Yrot' in joint 'Head'; valid: Xposition"),
    "channel count too high": (
        _edit({5: "\tCHANNELS 7 Xposition Yposition Zposition Zrotation Xrotation Yrotation"}),
        5, r"expected 7 channel names after 'CHANNELS 7' in joint 'Hips', got 6",
    ),
    "channel count too low": (_edit({27: "\t\t\tCHANNELS 2 Yrotation Zrotation Xrotation"}), 27, r"expected 2 channel names"),
    "channel count not a number": (_edit({13: "\t\t\tCHANNELS one Yrotation"}), 13, r"expected a channel count after CHANNELS"),
    "repeated channel": (_edit({27: "\t\t\tCHANNELS 3 Yrotation Zrotation Yrotation"}), 27, r"channel Yrotation listed twice"),
    "channel names on the next line": (
        _edit({13: "\t\t\tCHANNELS 1\n\t\t\tYrotation"}), 13, r"expected 1 channel names after 'CHANNELS 1' in joint 'Head', got 0",
    ),
    "offset not a number": (_edit({12: "\t\t\tOFFSET 0.0 abc 0.5"}), 12, r"OFFSET of joint 'Head': not a number: 'abc'"),
    "offset too short": (_edit({12: "\t\t\tOFFSET 0.0 4.0"}), 12, r"expected 3 numbers after OFFSET in joint 'Head', got 2"),
    "offset nan": (_edit({16: "\t\t\t\tOFFSET 0.0 nan 0.0"}), 16, r"End Site of 'Head'.*not a number: 'nan'"),
    "offset overflow": (_edit({16: "\t\t\t\tOFFSET 0.0 1e999 0.0"}), 16, r"not a finite number: '1e999'"),
    "missing offset": (_edit({26: None}), 27, r"expected OFFSET in joint 'LeftHand' before '\}'"),
    "missing channels": (_edit({33: None}), 33, r"expected OFFSET and CHANNELS in joint 'Tail' before End Site"),
    "second offset": (_edit({9: "\t\tOFFSET 0 0 0"}), 9, r"second OFFSET in joint 'Spine' \(first on line 8\)"),
    "junk in joint": (_edit({9: "\t\tROTATION 0 0 0"}), 9, r"expected OFFSET, CHANNELS, JOINT, End Site or '\}' in joint 'Spine'"),
    "channels in End Site": (_edit({16: "\t\t\t\tCHANNELS 0"}), 16, r"expected OFFSET or '\}' in the End Site of 'Head', got 'CHANNELS'"),
    "End without Site": (_edit({14: "\t\t\tEnd"}), 14, r"expected 'End Site', got 'End'"),
    "duplicate name": (_edit({24: "\t\tJOINT Spine"}), 24, r"duplicate joint name 'Spine' \(first on line 6\)"),
    "unclosed root": (_edit({39: None}), 39, r"expected '\}' closing joint 'Hips' \(opened on line 2\), got MOTION"),
    "second ROOT": (
        "\n".join(_SMALL_HEADER[:39] + ["ROOT Other", "{", "OFFSET 0 0 0", "CHANNELS 0", "}"] + _SMALL_HEADER[39:]) + "\n",
        40, r"second ROOT",
    ),
    "missing MOTION": (_edit({40: None}), 40, r"expected MOTION after the hierarchy, got 'Frames: 3'"),
    "truncated after hierarchy": ("\n".join(_SMALL_HEADER[:39]) + "\n", 39, r"expected MOTION after the hierarchy, got the end"),
    "bad frame count": (_edit({41: "Frames: three"}), 41, r"expected a frame count .* got 'three'"),
    "missing frame time": (_edit({42: None}), 42, r"expected 'Frame Time: <seconds>' after 'Frames:', got"),
    "bad frame time": (_edit({42: "Frame Time: 0"}), 42, r"expected a positive Frame Time, got '0'"),
    "frame non-number": (_edit({44: "abc " + _FRAME1.split(" ", 1)[1]}), 44, r"frame 1: not a number: 'abc'"),
    "frame malformed number": (_edit({45: "1.0.0 " + _FRAME2.split(" ", 1)[1]}), 45, r"frame 2: not a number: '1.0.0'"),
    "frame nan": (_edit({45: "nan " + _FRAME2.split(" ", 1)[1]}), 45, r"frame 2: not a number: 'nan'"),
    "frame overflow": (_edit({45: "1e400 " + _FRAME2.split(" ", 1)[1]}), 45, r"frame 2: not a finite number: '1e400'"),
    "too few values": (_edit({44: _FRAME1.rsplit(" ", 1)[0]}), 44, r"expected 19 values on frame 1, got 18"),
    "too many values": (_edit({45: _FRAME2 + " 1.0"}), 45, r"expected 19 values on frame 2, got 20"),
    "frame split over two lines": (
        _edit({45: " ".join(_FRAME2.split()[:10]) + "\n" + " ".join(_FRAME2.split()[10:])}), 45, r"expected 19 values on frame 2, got 10",
    ),
    "too few frames": (_edit({45: None}), 44, r"expected 3 frames, got 2 \(file ends\)"),
    "too many frames": (_edit({45: _FRAME2 + "\n" + _FRAME2}), 46, r"expected 3 frames, got more"),
}


@pytest.mark.parametrize("case", list(_ERROR_CASES))
def test_parse_errors(case):
    text, line, message = _ERROR_CASES[case]
    with pytest.raises(BVHParseError, match=message) as info:
        parse_bvh(text, path="case.bvh")
    assert info.value.line == line, f"{case}: reported line {info.value.line}, expected {line} ({info.value})"
    assert info.value.path == "case.bvh"
    assert str(info.value).startswith(f"case.bvh:{line}: ")


def test_read_errors(tmp_path):
    missing = tmp_path / "missing.bvh"
    with pytest.raises(BVHParseError, match="cannot read the file") as info:
        read_bvh(missing)
    assert info.value.line == 0 and info.value.path == str(missing)
    assert isinstance(info.value.__cause__, FileNotFoundError)
    with pytest.raises(BVHParseError, match="cannot read the file") as info:
        read_bvh(tmp_path)  # a directory
    assert info.value.line == 0
    latin1 = tmp_path / "latin1.bvh"
    latin1.write_bytes(_edit({20: "\tJOINT Left Arm:\xe9"}).encode("latin-1"))
    with pytest.raises(BVHParseError, match=r"not UTF-8 text: byte 0xe9") as info:
        read_bvh(latin1)
    assert info.value.line == 20
    with pytest.raises(BVHParseError, match="expected the BVH text as str or bytes"):
        parse_bvh(None)


# ------------------------------------------------------------------------------------------------
# fuzz: mutated files either parse or raise BVHParseError with a line number
# ------------------------------------------------------------------------------------------------
_INTERESTING_TOKENS = [
    "{", "}", "abc", "nan", "-inf", "1e999", "1.0.0", "JOINT", "ROOT", "End", "Site", "End Site", "OFFSET",
    "CHANNELS", "MOTION", "Frames:", "Frame Time:", "Xrotation", "Yposition", "-", ".", "0", "3", "7", "-1",
    "99999999999999999999", "\t", "\r", "\x00", "\u2028", "é",
]


@st.composite
def _mutated_small_file(draw):
    """The small file after 1 to 3 random edits (positions drawn uniformly through ``st.randoms``)."""
    rnd = draw(st.randoms(use_true_random=False))
    text = _small_text()
    for _ in range(draw(st.integers(1, 3))):
        lines = text.split("\n")
        op = draw(st.sampled_from(
            ["del_line", "dup_line", "swap_lines", "replace_token", "del_token", "truncate", "channel_count",
             "insert_text", "frame_value", "number", "whitespace", "bytes"]
        ))
        if op in ("del_line", "dup_line"):
            i = rnd.randrange(len(lines))
            lines[i:i + 1] = [] if op == "del_line" else [lines[i], lines[i]]
            text = "\n".join(lines)
        elif op == "swap_lines":
            i, k = rnd.randrange(len(lines)), rnd.randrange(len(lines))
            lines[i], lines[k] = lines[k], lines[i]
            text = "\n".join(lines)
        elif op in ("replace_token", "del_token", "number"):
            pattern = r"[-+.\d][-+.\deE]*" if op == "number" else r"\S+"
            spans = [m.span() for m in re.finditer(pattern, text)] or [(0, 0)]
            a, b = spans[rnd.randrange(len(spans))]
            if op == "number":  # usually harmless: another number
                new = draw(st.sampled_from(["0", "-1.5", "1e-3", ".25", "7", "-0", "+2", "1e999", "1.", "-"]))
            elif op == "replace_token":
                new = draw(st.sampled_from(_INTERESTING_TOKENS) | st.text(max_size=4))
            else:
                new = ""
            text = text[:a] + new + text[b:]
        elif op == "truncate":
            text = text[: rnd.randrange(len(text) + 1)]
        elif op == "channel_count":
            spans = [m.span(1) for m in re.finditer(r"CHANNELS (\d+)", text)]
            if spans:
                a, b = spans[rnd.randrange(len(spans))]
                text = text[:a] + str(draw(st.integers(0, 8))) + text[b:]
        elif op == "insert_text":
            i = rnd.randrange(len(text) + 1)
            text = text[:i] + draw(st.text(min_size=1, max_size=6) | st.sampled_from(_INTERESTING_TOKENS)) + text[i:]
        elif op == "frame_value":  # drop or add a value on a frame line
            i = rnd.randrange(min(len(_SMALL_HEADER), len(lines) - 1), len(lines))
            toks = lines[i].split()
            if rnd.random() < 0.5 and toks:
                del toks[rnd.randrange(len(toks))]
            else:
                toks.insert(rnd.randrange(len(toks) + 1), rnd.choice(["0.5", "-1", "abc", "1e5"]))
            lines[i] = " ".join(toks)
            text = "\n".join(lines)
        elif op == "whitespace":  # usually harmless: other separators, line ends, blank lines
            spans = [m.span() for m in re.finditer(r"[ \t]+|\n", text)] or [(0, 0)]
            a, b = spans[rnd.randrange(len(spans))]
            new = rnd.choice(["\t", "  ", " \t ", "\r\n", "\n\n", "\n \t\n", "\r", "\x0b", "\u00a0"])
            if text[a:b] != "\n":
                new = new.replace("\n", " ").replace("\r", " ")
            text = text[:a] + new + text[b:]
        else:  # raw bytes, possibly not UTF-8
            data = text.encode("utf-8")
            i = rnd.randrange(len(data) + 1)
            return data[:i] + draw(st.binary(min_size=1, max_size=3)) + data[i:]
    return text


@settings(max_examples=80, deadline=None, derandomize=True, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(_mutated_small_file())
def test_fuzz_mutated_files(text):
    try:
        skeleton, motion = parse_bvh(text, path="fuzz.bvh")
    except BVHParseError as exc:
        assert exc.line >= 1, f"line {exc.line}: {exc}"
        assert exc.path == "fuzz.bvh"
        return
    assert motion.num_joints == skeleton.num_joints
    assert np.isfinite(np.asarray(motion.rotations)).all() and np.isfinite(np.asarray(motion.translations)).all()


# ------------------------------------------------------------------------------------------------
# conversion API: vmap, shapes, dtypes, no mutation
# ------------------------------------------------------------------------------------------------
def test_vmap_equals_loop():
    skeleton, _ = _small()
    rng = np.random.default_rng(1)
    batch = _small_values()[None] + rng.uniform(-5.0, 5.0, size=(4, 3, _SMALL_NUM_CHANNELS))
    frame_time = jnp.asarray(0.04)
    motions = jax.vmap(lambda v: channels_to_motion(skeleton, v, frame_time))(batch)
    channels = jax.vmap(lambda m: motion_to_channels(skeleton, m))(motions)
    for b in range(batch.shape[0]):
        m = channels_to_motion(skeleton, batch[b], frame_time)
        np.testing.assert_allclose(np.asarray(motions.rotations[b]), np.asarray(m.rotations), rtol=0, atol=1e-14)
        np.testing.assert_allclose(np.asarray(motions.translations[b]), np.asarray(m.translations), rtol=0, atol=1e-14)
        np.testing.assert_allclose(np.asarray(channels[b]), np.asarray(motion_to_channels(skeleton, m)), rtol=0, atol=1e-10)


def test_conversion_dtypes_and_jit():
    skeleton, motion = _small()
    values = _small_values()
    m32 = channels_to_motion(skeleton, values.astype(np.float32), np.float32(0.04))
    assert m32.rotations.dtype == jnp.float64  # promoted with the float64 offsets
    skeleton32 = Skeleton(skeleton.names, skeleton.parents, np.asarray(skeleton.offsets, np.float32),
                          skeleton.channels, skeleton.end_site_parents, np.asarray(skeleton.end_site_offsets, np.float32))
    m32 = channels_to_motion(skeleton32, values.astype(np.float32), np.float32(0.04))
    assert m32.rotations.dtype == jnp.float32 and m32.translations.dtype == jnp.float32
    _assert_same_rotation(m32.rotations, motion.rotations, 1e-6, "float32 rotations")
    c32 = motion_to_channels(skeleton32, m32)
    assert c32.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(c32), values, rtol=0, atol=1e-3)
    mi = channels_to_motion(skeleton, np.round(values).astype(np.int64), 1)  # integers are promoted
    assert mi.rotations.dtype == jnp.float64 and mi.frame_time.dtype == jnp.float64
    jitted = jax.jit(lambda v: channels_to_motion(skeleton, v, 0.04).rotations)
    np.testing.assert_allclose(np.asarray(jitted(values)), np.asarray(motion.rotations), rtol=0, atol=1e-14)


def test_conversion_shape_errors():
    skeleton, motion = _small()
    values = _small_values()
    with pytest.raises(JaxanimError, match=r"values: expected shape \(frames, channels\) = \(\*, 19\), got \(3, 18\)"):
        channels_to_motion(skeleton, values[:, :-1], 0.04)
    with pytest.raises(JaxanimError, match=r"values: expected shape .* got \(19,\)"):
        channels_to_motion(skeleton, values[0], 0.04)
    with pytest.raises(JaxanimError, match=r"frame_time: expected shape \(\) \(a scalar\), got \(2,\)"):
        channels_to_motion(skeleton, values, [0.04, 0.04])
    with pytest.raises(JaxanimError, match=r"values: expected a real floating-point array"):
        channels_to_motion(skeleton, values.astype(np.complex128), 0.04)
    with pytest.raises(JaxanimError, match=r"skeleton: expected a Skeleton"):
        channels_to_motion(values, values, 0.04)
    other = Skeleton(("a", "b"), (-1, 0), np.zeros((2, 3)))
    with pytest.raises(JaxanimError, match=r"motion: expected 2 joints \(the skeleton's\), got 6"):
        motion_to_channels(other, motion)
    with pytest.raises(JaxanimError, match=r"motion: expected a Motion"):
        motion_to_channels(skeleton, values)


def test_inputs_not_modified():
    skeleton, motion = _small()
    values = _small_values()
    values_before = values.copy()
    offsets_before = np.array(skeleton.offsets)
    rotations_before = np.array(motion.rotations)
    channels_to_motion(skeleton, values, 0.04)
    format_bvh(skeleton, channels_to_motion(skeleton, values, 0.04))
    motion_to_channels(skeleton, motion)
    format_bvh(skeleton, motion)
    np.testing.assert_array_equal(values, values_before)
    np.testing.assert_array_equal(np.asarray(skeleton.offsets), offsets_before)
    np.testing.assert_array_equal(np.asarray(motion.rotations), rotations_before)
    text = _small_text()
    parse_bvh(text)
    assert text == _small_text()
