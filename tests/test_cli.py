"""The ``jaxanim`` command line, the shipped default clip and the stick-figure plot.

Commands run in-process through ``main([...])`` (one real subprocess checks the entry point). The
float64 FK of the walk (120 x 21) and of the CMU clip (300 x 31, float64 and float32) are the only
compiled shapes; the jit cache is shared between the tests through ``jaxanim.cli.batched_fk``.
"""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys

import jax
import numpy as np
import pytest

import jaxanim
from jaxanim import cli
from jaxanim.bvh import format_bvh, parse_bvh
from jaxanim.default_clip import default_clip_path, make_default_clip

from .conftest import REPO, shared_data_dir
from .helpers import assert_close

_RTOL_FK64 = 1e-9  # CLI float64 FK vs the shared (scipy, float64) reference, relative to the largest |position|
_RTOL_FK32 = 1e-4  # --float32
_ATOL_ROT64 = 1e-12
_ATOL_ROT32 = 1e-5
_ATOL_SHIPPED = 1.01e-6  # frame values of the shipped file vs the generator: one 6-decimal rounding
_CMU = "cmu_01_01_trim300"
_FK_KEYS = {"joint_names", "parents", "positions", "rotations", "end_site_names", "end_site_positions", "frame_time"}

# A BVH file with a bad number on line 4.
_BAD_BVH = "HIERARCHY\nROOT Hips\n{\n\tOFFSET 0 0 zero\n\tCHANNELS 3 Xposition Yposition Zposition\n}\n"


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = cli.main(["--no-compile-cache", *(str(a) for a in argv)])  # in-process: no cache in the user's home
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture(scope="module")
def walk_npz(tmp_path_factory) -> dict[str, np.ndarray]:
    """``jaxanim fk --out ...`` on the shipped clip, loaded."""
    out = tmp_path_factory.mktemp("fk") / "walk.npz"
    assert cli.main(["--quiet", "--no-compile-cache", "fk", "--out", str(out)]) == 0
    with np.load(out) as z:
        return dict(z)


@pytest.fixture(scope="module")
def walk_fk():
    """The generator's clip and its batched FK (same compiled function as the CLI's)."""
    skel, motion = make_default_clip()
    return skel, motion, cli.batched_fk()(skel, motion.rotations, motion.translations)


# --- info -------------------------------------------------------------------------------------------


def test_info_reports_the_shipped_clip(capsys):
    code, out, err = _run(capsys, "info")
    assert code == 0, err
    assert "joints      21 (+ 5 End Sites), 66 channels" in out
    assert "frames      120 at 30 fps" in out
    assert "frame time  0.0333333 s" in out
    assert "duration    4 s" in out
    assert "LeftToeBase_End" in out and "pos XYZ, rot ZXY" in out
    assert "bounding box" in out
    assert "forward kinematics" in err  # progress goes to stderr


def test_info_quiet_keeps_the_report_only(capsys):
    code, out, err = _run(capsys, "info", "--quiet")  # a global flag after the command
    assert code == 0
    assert "120 at 30 fps" in out and err == ""


def test_help_lists_the_commands(capsys):
    code, out, _ = _run(capsys, "--help")
    assert code == 0
    for command in ("info", "fk", "plot", "demo", "--float32", "--quiet"):
        assert command in out


# --- fk -----------------------------------------------------------------------------------------------


def test_fk_npz_keys_shapes_dtypes(walk_npz):
    skel, _ = make_default_clip()
    z = walk_npz
    assert _FK_KEYS <= set(z)
    assert z["positions"].shape == (120, 21, 3) and z["positions"].dtype == np.float64
    assert z["rotations"].shape == (120, 21, 3, 3) and z["rotations"].dtype == np.float64
    assert z["end_site_positions"].shape == (120, 5, 3) and z["end_site_positions"].dtype == np.float64
    assert z["joint_names"].dtype.kind == "U" and list(z["joint_names"]) == list(skel.names)
    assert list(z["end_site_names"]) == list(skel.end_site_names) == [
        "Head_End", "LeftHand_End", "RightHand_End", "LeftToeBase_End", "RightToeBase_End",
    ]
    assert list(z["parents"]) == list(skel.parents)
    assert z["frame_time"].shape == () and abs(float(z["frame_time"]) - 1 / 30) < 1e-12
    R = z["rotations"]
    assert_close("R^T R", np.einsum("fjba,fjbc->fjac", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)


def test_fk_matches_the_shared_reference_float64(tmp_path, capsys):
    data = shared_data_dir()
    out = tmp_path / "cmu.npz"
    code, stdout, err = _run(capsys, "fk", data / "bvh" / f"{_CMU}.bvh", "--out", out)
    assert code == 0, err
    assert "µs per frame" in stdout
    ref = np.load(data / "fk" / f"{_CMU}.fk.npz")
    with np.load(out) as z:
        scale = np.abs(ref["positions"]).max()
        assert z["positions"].dtype == np.float64
        assert_close("positions", z["positions"], ref["positions"], atol=_RTOL_FK64 * scale)
        assert_close("rotations", z["rotations"], ref["rotations"], atol=_ATOL_ROT64)
        assert_close("end_site_positions", z["end_site_positions"], ref["end_site_positions"], atol=_RTOL_FK64 * scale)
        assert list(z["end_site_names"]) == list(ref["end_site_names"])
        assert list(z["joint_names"]) == list(ref["joint_names"])
        assert list(z["parents"]) == list(ref["parents"])


def test_fk_float32_flag(tmp_path, capsys):
    data = shared_data_dir()
    out = tmp_path / "cmu32.npz"
    code, _, err = _run(capsys, "fk", "--float32", data / "bvh" / f"{_CMU}.bvh", "-o", out)
    assert code == 0, err
    assert jax.config.jax_enable_x64  # the flag does not leak out of main()
    ref = np.load(data / "fk" / f"{_CMU}.fk.npz")
    with np.load(out) as z:
        for key in ("positions", "rotations", "end_site_positions", "frame_time"):
            assert z[key].dtype == np.float32, key
        scale = np.abs(ref["positions"]).max()
        assert_close("positions", z["positions"], ref["positions"], atol=_RTOL_FK32 * scale)
        assert_close("rotations", z["rotations"], ref["rotations"], atol=_ATOL_ROT32)
        assert_close("end_site_positions", z["end_site_positions"], ref["end_site_positions"], atol=_RTOL_FK32 * scale)


# --- plot -----------------------------------------------------------------------------------------------


def test_plot_writes_a_png(tmp_path, capsys):
    pytest.importorskip("matplotlib", reason="matplotlib is not installed (the plot extra)")
    out = tmp_path / "pose.png"
    code, stdout, err = _run(capsys, "plot", "--frame", 7, "--out", out)
    assert code == 0, err
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    assert f"wrote {out}" in stdout


def test_plot_frame_out_of_range(tmp_path, capsys):
    code, _, err = _run(capsys, "plot", "--frame", 120, "--out", tmp_path / "x.png")
    assert code == 2
    assert "error: --frame 120 is out of range" in err and "valid: 0 to 119" in err
    assert not (tmp_path / "x.png").exists()


def test_plot_pose_api(walk_fk, monkeypatch):
    pytest.importorskip("matplotlib", reason="matplotlib is not installed (the plot extra)")
    from jaxanim.plot import plot_pose

    skel, motion, fk = walk_fk
    one = jax.tree.map(lambda x: x[3], fk)
    ax = plot_pose(skel, one, title="frame 3")
    try:
        assert ax.name == "3d" and ax.get_title() == "frame 3"
        lo, hi = ax.get_zlim()
        assert lo < 0.0 < 1.7 < hi  # y (up) is the vertical axis, equal scaling keeps the whole body
        assert np.allclose(np.diff(ax.get_xlim()), np.diff(ax.get_zlim()))
    finally:
        import matplotlib.pyplot as plt

        plt.close(ax.figure)
    with pytest.raises(jaxanim.JaxanimError, match=r"fk_result.positions: expected shape \(joints, 3\) = \(21, 3\)"):
        plot_pose(skel, fk)  # all frames at once
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # as if it were not installed
    with pytest.raises(jaxanim.JaxanimError, match=r"install jaxanim\[plot\]"):
        plot_pose(skel, one)


# --- demo -----------------------------------------------------------------------------------------------


# test_tracking.py runs the demo: its tracking step compiles that file's search program
# (a module there shares it in one process).


# --- errors -----------------------------------------------------------------------------------------------


def test_bad_file_exits_2_with_the_line(tmp_path, capsys):
    bad = tmp_path / "bad.bvh"
    bad.write_text(_BAD_BVH)
    for command in ("info", "fk", "plot"):
        code, _, err = _run(capsys, command, bad, "--quiet")
        assert code == 2, command
        assert err.startswith(f"error: {bad}:4: ") and "'zero'" in err, err
        assert "Traceback" not in err


def test_missing_file_and_unwritable_output(tmp_path, capsys):
    code, _, err = _run(capsys, "info", tmp_path / "nope.bvh")
    assert code == 2 and err.splitlines()[-1].startswith(f"error: {tmp_path / 'nope.bvh'}: cannot read the file")
    code, _, err = _run(capsys, "-q", "fk", "--out", tmp_path / "no" / "such" / "dir.npz")
    assert code == 2 and err.startswith("error: ") and "Traceback" not in err


def test_usage_error_exits_2(capsys):
    code, _, err = _run(capsys, "frobnicate")
    assert code == 2 and "invalid choice" in err


def test_entry_point_in_a_subprocess(tmp_path):
    bad = tmp_path / "bad.bvh"
    bad.write_text(_BAD_BVH)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run(
        [sys.executable, "-m", "jaxanim", "info", str(bad)],
        capture_output=True, text=True, cwd=tmp_path, env=env, timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.splitlines()[-1].startswith(f"error: {bad}:4: "), proc.stderr
    assert "Traceback" not in proc.stderr


# --- the persistent compilation cache ---------------------------------------------------------------


def test_compile_cache_dir_rules(tmp_path):
    from jaxanim.app._cache import compile_cache_dir

    home, xdg, override = tmp_path / "home", tmp_path / "xdg", tmp_path / "override"
    assert compile_cache_dir({"HOME": str(home)}) == home / ".cache" / "jaxanim"
    assert compile_cache_dir({"HOME": str(home), "XDG_CACHE_HOME": ""}) == home / ".cache" / "jaxanim"
    assert compile_cache_dir({"HOME": str(home), "XDG_CACHE_HOME": "rel/cache"}) == home / ".cache" / "jaxanim"
    assert compile_cache_dir({"HOME": str(home), "XDG_CACHE_HOME": str(xdg)}) == xdg / "jaxanim"
    env = {"HOME": str(home), "XDG_CACHE_HOME": str(xdg), "JAX_COMPILATION_CACHE_DIR": str(override)}
    assert compile_cache_dir(env) == override


def test_no_compile_cache_is_a_global_flag_of_every_command():
    parser = cli._build_parser()
    commands = {"info": [], "fk": [], "plot": [], "ik": ["--targets", "t.json"], "simulate": [], "demo": []}
    for command, rest in commands.items():
        assert parser.parse_args([command, *rest]).no_compile_cache is False, command
        assert parser.parse_args(["--no-compile-cache", command, *rest]).no_compile_cache is True, command
        assert parser.parse_args([command, *rest, "--no-compile-cache"]).no_compile_cache is True, command


def test_compile_cache_settings_are_restored(tmp_path):
    from jaxanim.app._cache import compile_cache

    names = ("jax_enable_compilation_cache", "jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs")
    before = [getattr(jax.config, n) for n in names]
    with compile_cache(tmp_path / "c"):
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "c")
        assert jax.config.jax_persistent_cache_min_compile_time_secs == 0.0
    assert [getattr(jax.config, n) for n in names] == before
    with compile_cache(None):  # --no-compile-cache: off, even where JAX_COMPILATION_CACHE_DIR asks JAX for one
        assert jax.config.jax_enable_compilation_cache is False
    assert [getattr(jax.config, n) for n in names] == before


def test_a_command_fills_the_cache_and_import_leaves_it_off(tmp_path):
    """One subprocess: importing jaxanim turns nothing on; ``fk`` fills $XDG_CACHE_HOME/jaxanim and
    puts JAX's settings back when it returns."""
    script = (
        "import sys, jax, jaxanim\n"
        "from jaxanim.app import main\n"
        "print(jax.config.jax_compilation_cache_dir, jax.config.jax_persistent_cache_min_compile_time_secs)\n"
        "code = main(['-q', 'fk', '--out', sys.argv[1]])\n"
        "print(code, jax.config.jax_compilation_cache_dir, jax.config.jax_persistent_cache_min_compile_time_secs)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env.update(XDG_CACHE_HOME=str(tmp_path / "xdg"), HOME=str(tmp_path / "home"),
               PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run([sys.executable, "-c", script, str(tmp_path / "walk.npz")],
                          capture_output=True, text=True, cwd=tmp_path, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines() == ["None 1.0", "0 None 1.0"], proc.stdout
    entries = [p.name for p in (tmp_path / "xdg" / "jaxanim").iterdir()]
    assert any(name.startswith("jit_forward_kinematics-") for name in entries), entries
    assert not (tmp_path / "home").exists()


# --- the default clip ---------------------------------------------------------------------------------


def test_shipped_clip_equals_the_generator_output():
    path = default_clip_path()
    assert path.parent.name == "data" and path.parent.parent == pathlib.Path(jaxanim.__file__).parent
    shipped = path.read_text(encoding="utf-8")
    generated = format_bvh(*make_default_clip())
    head_s, frames_s = shipped.split("MOTION\n")
    head_g, frames_g = generated.split("MOTION\n")
    hint = "the shipped clip drifted from the generator: run `python -m jaxanim.skeleton._default_clip`"
    assert head_s == head_g, hint
    lines_s, lines_g = frames_s.splitlines(), frames_g.splitlines()
    assert lines_s[:2] == lines_g[:2] == ["Frames: 120", f"Frame Time: {1 / 30!r}"], hint
    values_s = np.array([line.split() for line in lines_s[2:]], dtype=np.float64)
    values_g = np.array([line.split() for line in lines_g[2:]], dtype=np.float64)
    assert_close("frame values (" + hint + ")", values_s, values_g, atol=_ATOL_SHIPPED)
    skel, _ = parse_bvh(shipped)
    assert skel.num_joints == 21 and skel.num_end_sites == 5


def test_default_clip_is_a_walk(walk_fk):
    skel, motion, fk = walk_fk
    p, e = np.asarray(fk.positions), np.asarray(fk.end_site_positions)
    dt = float(motion.frame_time)
    feet = np.concatenate(
        [p[:, [skel.index(n) for n in ("LeftFoot", "LeftToeBase", "RightFoot", "RightToeBase")]],
         e[:, [skel.end_site_names.index(n) for n in ("LeftToeBase_End", "RightToeBase_End")]]], axis=1
    )
    lowest = feet[..., 1].min(axis=1)  # per frame, meters (the heel is 7 cm below the ankle)
    assert lowest.min() > -1e-3 and lowest.max() < 0.03, "feet are not near the ground on every frame"
    root = p[:, 0]
    speed = np.diff(root[:, 2]) / dt
    assert (speed > 0).all() and 0.9 < speed.mean() < 1.6, "the root does not move forward at walking speed"
    assert np.abs(root[:, 0]).max() < 0.05 and 0.9 < root[:, 1].min() < root[:, 1].max() < 1.1
    head = e[:, skel.end_site_names.index("Head_End"), 1]
    assert 1.65 < head.min() and head.max() < 1.85
    # the legs alternate: the left ankle is ahead of the right one twice per second, and behind it twice
    ahead = p[:, skel.index("LeftFoot"), 2] > p[:, skel.index("RightFoot"), 2]
    assert np.count_nonzero(ahead[1:] != ahead[:-1]) == 8
    # the arms swing opposite to the legs
    hand_ahead = e[:, 1, 2] > e[:, 2, 2]
    assert np.mean(hand_ahead != ahead) >= 0.75  # the ankles cross at mid-swing, the hands at mid-stance
    # the stance foot does not skate (issue 13): the lower toe joint of each frame, the one on the ground,
    # moves at a median of at most 0.1 m/s (central differences, 3-D); the root moves at ~1.2 m/s
    toes = p[:, [skel.index("LeftToeBase"), skel.index("RightToeBase")]]
    toe_speed = np.linalg.norm(np.gradient(toes, dt, axis=0), axis=-1)[1:-1]
    lower = np.argmin(toes[1:-1, :, 1], axis=1)
    assert np.median(toe_speed[np.arange(lower.size), lower]) <= 0.1, "the stance foot slides"
    assert np.abs(toes[..., 1].min(axis=1)).max() < 1e-9, "a toe joint is not on the ground in every frame"
    # one gait cycle per second: frame 30 repeats frame 0, 1 s further on
    assert_close("rotations period", motion.rotations[30], motion.rotations[0], atol=1e-12)
    assert_close("root period", root[30, :2], root[0, :2], atol=1e-12)


def test_make_default_clip_arguments():
    skel, motion = make_default_clip(num_frames=3, fps=60.0)
    assert motion.rotations.shape == (3, 21, 4) and abs(float(motion.frame_time) - 1 / 60) < 1e-15
    with pytest.raises(jaxanim.JaxanimError, match="num_frames: expected a positive integer"):
        make_default_clip(num_frames=0)
    with pytest.raises(jaxanim.JaxanimError, match="fps: expected a positive finite number"):
        make_default_clip(fps=-1.0)
