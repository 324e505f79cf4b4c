"""``jaxanim render``: GIFs (and MP4 where ffmpeg is installed) of the shipped clip and of two clips
side by side, read back with Pillow, and the errors for bad input.

Every render is small (a few frames, panels of about 100 pixels) and runs in-process through
``main([...])``, sharing the jitted batched FK with the other CLI tests.
"""

from __future__ import annotations

import pathlib

import numpy as np
import pytest

PIL = pytest.importorskip("PIL", reason="rendering needs Pillow (it comes with matplotlib: jaxanim[plot])")
pytest.importorskip("matplotlib", reason="rendering needs matplotlib (jaxanim[plot])")
from PIL import Image, ImageSequence

import jaxanim
from jaxanim import cli

_SIZE = 100  # pixels: each panel's width and height
# matplotlib's "tab:blue" and "tab:red" (the left and right bones), after the GIF palette
_BONE_RGB = {"left": (31, 119, 180), "right": (214, 39, 40)}
_COLOUR_TOL = 40  # per channel, for the GIF's quantized palette
_MIN_BONE_PIXELS = 20  # per colour and panel, at 100 x 100 pixels


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = cli.main(["--no-compile-cache", *(str(a) for a in argv)])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _frames(path: pathlib.Path) -> list[np.ndarray]:
    with Image.open(path) as im:
        assert im.format == "GIF", f"{path}: not a GIF ({im.format})"
        return [np.asarray(f.convert("RGB"), dtype=np.int64) for f in ImageSequence.Iterator(im)]


def _durations(path: pathlib.Path) -> list[int]:
    with Image.open(path) as im:
        return [f.info["duration"] for f in ImageSequence.Iterator(im)]


def _count(img: np.ndarray, rgb) -> int:
    return int((np.abs(img - np.array(rgb)).max(axis=-1) <= _COLOUR_TOL).sum())


def _assert_figure_drawn(img: np.ndarray, where: str) -> None:
    for side, rgb in _BONE_RGB.items():
        n = _count(img, rgb)
        assert n >= _MIN_BONE_PIXELS, f"{where}: {n} pixels of the {side} bone colour {rgb}, expected a stick figure"
    assert (img < 250).any(axis=-1).mean() < 0.5, f"{where}: mostly not background; expected a white figure"


@pytest.fixture(scope="module")
def short_clips(tmp_path_factory) -> tuple[pathlib.Path, pathlib.Path]:
    """The shipped walk cut to 4 and to 8 frames, as BVH files."""
    d = tmp_path_factory.mktemp("clips")
    skel, motion = jaxanim.read_bvh(jaxanim.default_clip_path())
    paths = []
    for n in (4, 8):
        path = d / f"walk{n}.bvh"
        jaxanim.write_bvh(path, skel, jaxanim.Motion(motion.rotations[:n], motion.translations[:n], motion.frame_time))
        paths.append(path)
    return paths[0], paths[1]


def test_render_gif_of_the_shipped_clip(tmp_path, capsys):
    out = tmp_path / "walk.gif"
    code, stdout, err = _run(capsys, "render", "--frames", "10:16", "--size", _SIZE, "--out", out)
    assert code == 0, err
    assert f"wrote {out}: 6 frames at 30 fps" in stdout
    assert "forward kinematics of 120 frames" in err  # progress on stderr, FK of the whole clip in one call
    frames = _frames(out)
    assert len(frames) == 6
    assert frames[0].shape == (_SIZE, _SIZE, 3)
    for k in (0, 5):
        _assert_figure_drawn(frames[k], f"frame {k}")
    for k in range(1, 6):
        assert np.abs(frames[k] - frames[k - 1]).max() > 0, f"frames {k - 1} and {k} are the same"
    assert _durations(out) == [30, 40, 30, 30, 40, 30], "frame durations (ms): GIF's centiseconds keeping 30 fps"


def test_render_fps_picks_frames_by_time(tmp_path, capsys):
    """--fps 10 over frames 0..29 of a 30 fps clip: t = 0, 0.1, ..., 0.9 s -> 10 frames, fixed camera."""
    out = tmp_path / "slow.gif"
    code, stdout, err = _run(capsys, "render", "--frames", ":30", "--fps", "10", "--camera", "fixed",
                             "--size", _SIZE, "--out", out)
    assert code == 0, err
    assert "10 frames at 10 fps" in stdout
    frames = _frames(out)
    assert len(frames) == 10
    assert _durations(out) == [100] * 10
    _assert_figure_drawn(frames[9], "frame 9")


def test_render_compare_side_by_side(tmp_path, capsys, short_clips):
    """A 4-frame clip beside an 8-frame one: 8 output frames; the left panel holds its last frame."""
    short, long = short_clips
    out = tmp_path / "compare.gif"
    code, stdout, err = _run(capsys, "render", short, "--compare", long, "--size", _SIZE, "--out", out)
    assert code == 0, err
    assert "8 frames at 30 fps" in stdout and f"{2 * _SIZE}x{_SIZE} px" in stdout
    frames = _frames(out)
    assert len(frames) == 8
    assert frames[0].shape == (_SIZE, 2 * _SIZE, 3)
    body = slice(0, int(0.85 * _SIZE))  # above the time label in the bottom corner
    for k in (0, 7):
        _assert_figure_drawn(frames[k][:, :_SIZE], f"frame {k}, left panel")
        _assert_figure_drawn(frames[k][:, _SIZE:], f"frame {k}, right panel")
    # left: frames 3..7 show the clip's last frame (held); right: the clip goes on
    assert np.array_equal(frames[4][body, :_SIZE], frames[7][body, :_SIZE]), "left panel not held at its last frame"
    assert np.abs(frames[4][body, _SIZE:] - frames[7][body, _SIZE:]).max() > 0, "right panel does not move"
    assert np.abs(frames[0][body, :_SIZE] - frames[3][body, :_SIZE]).max() > 0, "left panel does not move"


def _ffmpeg_available() -> bool:
    from matplotlib import animation

    return animation.writers.is_available("ffmpeg")


@pytest.mark.skipif(not _ffmpeg_available(), reason="ffmpeg is not installed (apt-get install ffmpeg): no MP4")
def test_render_mp4(tmp_path, capsys):
    out = tmp_path / "walk.mp4"
    code, stdout, err = _run(capsys, "render", "--frames", "0:4", "--size", _SIZE, "--out", out)
    assert code == 0, err
    assert "4 frames at 30 fps" in stdout
    data = out.read_bytes()
    assert data[4:8] == b"ftyp", "not an MP4 file"


def test_render_mp4_without_ffmpeg_names_the_fix(tmp_path, capsys, monkeypatch):
    from matplotlib import animation

    real = animation.writers.is_available
    monkeypatch.setattr(animation.writers, "is_available", lambda name: False if name == "ffmpeg" else real(name))
    out = tmp_path / "walk.mp4"
    code, _, err = _run(capsys, "render", "--out", out)
    assert code == 2
    assert "error: --out" in err and "needs ffmpeg" in err and "apt-get install ffmpeg" in err and ".gif" in err
    assert "Traceback" not in err
    assert not out.exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--out", "walk.avi"], "unknown output extension '.avi': expected .gif or .mp4"),
        (["--out", "walk"], "unknown output extension '(none)'"),
        (["--fps", "0", "--out", "x.gif"], "--fps 0: expected a positive number"),
        (["--fps", "-5", "--out", "x.gif"], "--fps -5: expected a positive number"),
        (["--fps", "nan", "--out", "x.gif"], "--fps nan: expected a positive number"),
        (["--frames", "5:3", "--out", "x.gif"], "--frames 5:3: expected A:B with 0 <= A < B <= 120"),
        (["--frames", "0:500", "--out", "x.gif"], "--frames 0:500: expected A:B with 0 <= A < B <= 120"),
        (["--frames", "three", "--out", "x.gif"], "--frames three: expected A:B"),
        (["--size", "8", "--out", "x.gif"], "--size 8: expected 32 to 4096 pixels"),
        (["--size", "70000", "--out", "x.gif"], "--size 70000: expected 32 to 4096 pixels"),
        (["--fps", "1e6", "--out", "x.gif"], "--fps 1e+06: expected a positive number of frames per second, at most 240"),
        (["missing.bvh", "--out", "x.gif"], "missing.bvh: cannot read the file"),
        (["--compare", "missing.bvh", "--out", "x.gif"], "missing.bvh: cannot read the file"),
        (["--out", "no/such/dir/x.gif"], "cannot write it: the directory"),
    ],
    ids=["ext", "no-ext", "fps0", "fps-neg", "fps-nan", "frames-order", "frames-range", "frames-syntax", "size",
         "size-huge", "fps-huge", "missing", "compare-missing", "out-dir"],
)
def test_render_bad_input(tmp_path, capsys, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    code, _, err = _run(capsys, "render", *argv)
    assert code == 2, err
    assert err.strip().splitlines()[-1].startswith("error: ") and message in err, err
    assert "Traceback" not in err
    assert not list(tmp_path.glob("x.*"))


def test_render_malformed_bvh(tmp_path, capsys):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n\tOFFSET 0 0 zero\n\tCHANNELS 3 Xposition Yposition Zposition\n}\n")
    code, _, err = _run(capsys, "render", bad, "--out", tmp_path / "x.gif")
    assert code == 2
    assert f"error: {bad}:4:" in err


def test_render_mesh(tmp_path, capsys):
    out = tmp_path / "mesh.gif"
    code, stdout, err = _run(capsys, "render", "--mesh", "--frames", "0:3", "--size", _SIZE, "--out", out)
    assert code == 0, err
    assert "skinning" in stdout
    frames = _frames(out)
    assert len(frames) == 3
    # the skin: light blue-grey faces shaded between 0.45 and 1 of (0.55, 0.68, 0.85), half transparent
    skin = (frames[0][..., 2] > frames[0][..., 0] + 20) & (frames[0][..., 2] > 120) & (frames[0][..., 0] > 90)
    assert skin.sum() >= 200, f"{skin.sum()} skin-coloured pixels: is the mesh drawn?"
