"""``jaxanim simulate``: track a clip with the physics character and write the motion as BVH.

Physics compiles slowly, so the whole file runs ``simulate`` twice, in one module fixture, for
0.25 s (30 frames at 120 fps) of the CMU clip: with the root force and ``--plot``, and with
``--no-root-force``. The two runs track the same frames with the same step and differ only by the
root force, which is an argument of the compiled rollout, not a constant in it: with the
persistent compilation cache on (in a temporary directory), the second run loads the first one's
program. The written files are checked against independent references: the clip read back with
``read_bvh`` and its forward kinematics (one compiled shape: the clip's first 30 frames, which the
runs track, and the 30 written frames). Everything else (the frame / step plan, the loop of a short
clip, bad input) runs no physics.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import math
import os
import sys

import numpy as np
import pytest

import jaxanim
from jaxanim import cli

from .conftest import shared_data_dir
from .helpers import assert_close, batched_fk, phys_cmu_character

_CMU = "cmu_01_01_trim300"
_SECONDS = 0.25  # 30 frames at 120 fps
_FRAMES = 30
_SHORT = 10  # frames of the short clip that simulate loops; frames 1-9 of the two runs are compared
_ATOL_FIRST = 1e-5  # frame 0 vs the clip's frame 0, FK positions in file units (6-decimal BVH round-off)
# With the root force the root joint stays this close to the clip's (meters): the servo's 200 N/m
# per kg sags by g / 200 = 4.9 cm under the whole weight, less when the feet carry some (3.9 cm seen).
_ATOL_ROOT_M = 0.06
_ATOL_SINK_M = 0.02  # no joint goes further than this below the clip's lowest joint (meters)
_MIN_ROOT_EFFECT_M = 2e-3  # the root force moves the root at least this much by frame 9 (9.5 mm seen)
_PNG = b"\x89PNG\r\n\x1a\n"


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = cli.main(["--no-compile-cache", *(str(a) for a in argv)])  # in-process: no cache in the user's home
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _has_matplotlib() -> bool:
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return False
    return True


def _short_clip(path, frames: int) -> None:
    """The CMU file's header and first ``frames`` frame lines, verbatim."""
    text = (shared_data_dir() / "bvh" / f"{_CMU}.bvh").read_text(encoding="utf-8")
    head, body = text.split("MOTION\n")
    lines = body.splitlines()
    assert lines[0].startswith("Frames:") and lines[1].startswith("Frame Time:")
    path.write_text(head + "MOTION\n" + "\n".join([f"Frames: {frames}", lines[1], *lines[2:2 + frames]]) + "\n",
                    encoding="utf-8")


@pytest.fixture(scope="module")
def sims(tmp_path_factory):
    """The two simulate runs: ``(dir, cmu, {"root": (code, stdout, stderr), "free": (...)})``."""
    d = tmp_path_factory.mktemp("simulate")
    cmu = shared_data_dir() / "bvh" / f"{_CMU}.bvh"
    # Warm-up under the run's compilation cache: simulate builds this character op by op again (each
    # op then served from memory); only the cost moves, the runs below are unchanged.
    phys_cmu_character()
    runs = {}
    saved = os.environ.get("JAX_COMPILATION_CACHE_DIR")
    os.environ["JAX_COMPILATION_CACHE_DIR"] = str(d / "cache")  # the cache, but not in the user's home
    try:
        for key, argv in (
            ("root", ["simulate", cmu, "--seconds", _SECONDS, "--out", d / "root.bvh"]
             + (["--plot", d / "root.png"] if _has_matplotlib() else [])),
            ("free", ["simulate", cmu, "--seconds", _SECONDS, "--no-root-force", "--out", d / "free.bvh"]),
        ):
            out, err = io.StringIO(), io.StringIO()  # module scope: no capsys
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                code = cli.main([str(a) for a in argv])
            runs[key] = (code, out.getvalue(), err.getvalue())
    finally:
        if saved is None:
            del os.environ["JAX_COMPILATION_CACHE_DIR"]
        else:
            os.environ["JAX_COMPILATION_CACHE_DIR"] = saved
    return d, cmu, runs


@pytest.fixture(scope="module")
def cmu_clip():
    """The CMU clip, the FK of its first ``_FRAMES`` frames (those the runs track: the written
    frames' shape, one compiled FK for both) and its unit."""
    skel, motion = jaxanim.read_bvh(shared_data_dir() / "bvh" / f"{_CMU}.bvh")[:2]
    first = jaxanim.Motion(motion.rotations[:_FRAMES], motion.translations[:_FRAMES], motion.frame_time)
    return skel, motion, _fk(skel, first), _unit(skel)


def _fk(skel, motion):
    return batched_fk()(skel, motion.rotations, motion.translations)  # the same jit as cli.batched_fk(), cached


def _unit(skel) -> float:
    """Meters per file unit, as the character infers it: the rest pose is 1.7 m tall. With identity
    rotations every joint sits at its parent plus its OFFSET (NumPy, no compilation)."""
    offsets = np.asarray(skel.offsets)
    p = np.zeros_like(offsets)
    for j, parent in enumerate(skel.parents):  # parents[j] < j
        p[j] = offsets[j] + (p[parent] if parent >= 0 else 0.0)
    ends = p[np.asarray(skel.end_site_parents, dtype=int)] + np.asarray(skel.end_site_offsets)
    pts = np.concatenate([p, ends])
    return 1.7 / float(pts[:, 1].max() - pts[:, 1].min())


# --- the two runs -------------------------------------------------------------------------------------


def test_simulate_writes_the_tracked_clip(sims, cmu_clip):
    d, cmu, runs = sims
    code, out, err = runs["root"]
    assert code == 0, err
    assert "Traceback" not in err
    assert f"wrote {d / 'root.bvh'}: {_FRAMES} frames at 120 fps" in out, out
    assert "rollout successful: 29/29 steps" in out and "root force, complementarity contact" in out, out
    assert "tracking error (joint rotation vs the clip) mean" in out and "rollout compile" in out, out
    assert "ms per step" in out, out
    assert "compiling the rollout" in err  # progress on stderr
    skel, motion, a, unit = cmu_clip
    sim_skel, sim = jaxanim.read_bvh(d / "root.bvh")[:2]
    # The same skeleton, the clip's frame time, seconds x fps frames.
    assert sim_skel.names == skel.names and sim_skel.parents == skel.parents
    assert sim_skel.channels == skel.channels and sim_skel.end_site_parents == skel.end_site_parents
    assert_close("offsets", sim_skel.offsets, skel.offsets, atol=0.0)
    assert_close("end_site_offsets", sim_skel.end_site_offsets, skel.end_site_offsets, atol=0.0)
    assert float(sim.frame_time) == float(motion.frame_time)
    assert sim.num_frames == _FRAMES == round(_SECONDS / float(motion.frame_time))
    # Frame 0 is the clip's first pose; the root follows the clip's (root force); nothing sinks.
    b = _fk(sim_skel, sim)
    assert_close("frame 0 joint positions", b.positions[0], a.positions[0], atol=_ATOL_FIRST)
    assert_close("frame 0 End Sites", b.end_site_positions[0], a.end_site_positions[0], atol=_ATOL_FIRST)
    root_gap = float(np.abs(np.asarray(b.positions[:, 0] - a.positions[:_FRAMES, 0])).max()) * unit
    assert root_gap < _ATOL_ROOT_M, f"root is {root_gap:.3f} m from the clip's"
    lowest = float(np.asarray(b.positions[..., 1]).min()) * unit
    clip_lowest = float(np.asarray(a.positions[:_FRAMES, :, 1]).min()) * unit
    assert lowest > clip_lowest - _ATOL_SINK_M, f"a joint sank to {lowest:.3f} m (clip's lowest {clip_lowest:.3f} m)"
    # The printed mean error is that of the written frames: the run is not far off the clip.
    err_rad = float(out.split("vs the clip) mean ")[1].split(" rad")[0])
    assert 0.0 < err_rad < 0.5, out


def test_simulate_plot_is_a_png(sims):
    if not _has_matplotlib():
        pytest.skip("matplotlib is not installed")
    d, _, runs = sims
    assert runs["root"][0] == 0, runs["root"][2]
    data = (d / "root.png").read_bytes()
    assert data[:8] == _PNG and len(data) > 10_000
    assert f"plot {d / 'root.png'}" in runs["root"][1]


def test_no_root_force_differs_and_reuses_the_compiled_rollout(sims, cmu_clip):
    d, _, runs = sims
    code, out, err = runs["free"]
    assert code in (0, 1), err  # 1: the rollout stopped (then the frames hold the last good state)
    assert "Traceback" not in err
    assert "no root force" in out and f"{_FRAMES} frames at 120 fps" in out, out
    skel, motion, a, unit = cmu_clip
    sim = jaxanim.read_bvh(d / "free.bvh")[1]
    root = jaxanim.read_bvh(d / "root.bvh")[1]
    assert sim.num_frames == _FRAMES and np.isfinite(np.asarray(sim.translations)).all()
    b, c = _fk(skel, sim), _fk(skel, root)
    assert_close("frame 0 joint positions", b.positions[0], a.positions[0], atol=_ATOL_FIRST)
    # Frames 1-9 track the same clip frames as the root-force run with the same step: only the root
    # force differs, and it moves the root.
    gap = np.abs(np.asarray(b.positions[1:_SHORT, 0] - c.positions[1:_SHORT, 0])).max() * unit
    assert gap > _MIN_ROOT_EFFECT_M, f"--no-root-force changed the root by only {gap:.2e} m"
    # The same program as the first run's (the root force is an argument): loaded, not compiled.
    rollouts = [p.name for p in (d / "cache").iterdir() if p.name.startswith("jit_simulate-")]
    assert len(rollouts) == 1, rollouts  # one key for both runs: the second found the first's entry


# --- the plan and the loop (no physics) ---------------------------------------------------------------


@pytest.mark.parametrize(
    "seconds, dt, frame_time, frames, k, used_dt",
    [
        (0.25, 1 / 120, 1 / 120, 30, 1, 1 / 120),
        (1.0, 1 / 120, 1 / 30, 30, 4, 1 / 120),
        (1.0, 1 / 120, 1 / 25, 25, 5, 1 / 125),  # 1/120 does not divide 0.04 s: the step becomes 0.008 s
        (0.5, 0.1, 1 / 30, 15, 1, 1 / 30),  # a step longer than a frame: one step per frame
        (0.25, 1 / 120, 0.0083333, 30, 1, 0.0083333),  # the file's rounded frame time
    ],
)
def test_sim_plan(seconds, dt, frame_time, frames, k, used_dt):
    plan = cli._sim_plan(seconds, dt, frame_time)
    assert (plan.frames, plan.k, plan.steps) == (frames, k, (frames - 1) * k)
    assert math.isclose(plan.dt, used_dt, rel_tol=1e-12)
    assert math.isclose(plan.k * plan.dt, frame_time, rel_tol=1e-12)  # a recorded state per frame


def test_sim_plan_too_short():
    with pytest.raises(jaxanim.JaxanimError, match=r"--seconds 0.01 is shorter than two frames of the clip at 30 fps"):
        cli._sim_plan(0.01, 1 / 120, 1 / 30)


def test_looped_motion_carries_the_root_on(cmu_clip):
    _, motion, _, _ = cmu_clip
    clip = jaxanim.Motion(motion.rotations[:5], motion.translations[:5], motion.frame_time)
    assert cli._looped_motion(clip, 4).num_frames == 4
    assert_close("no loop", cli._looped_motion(clip, 5).translations, clip.translations, atol=0.0)
    looped = cli._looped_motion(clip, 12)
    idx = np.arange(12) % 5
    assert_close("rotations", looped.rotations, clip.rotations[idx], atol=0.0)
    assert_close("other joints", looped.translations[:, 1:], clip.translations[idx, 1:], atol=0.0)
    r = np.asarray(clip.translations[:, 0])
    step = (r[4] - r[0]) + (r[4] - r[3])
    expected = r[idx] + (np.arange(12) // 5)[:, None] * np.array([step[0], 0.0, step[2]])[None, :]
    assert_close("root", looped.translations[:, 0], expected, atol=1e-12)
    assert float(looped.frame_time) == float(clip.frame_time)


# --- bad input (no physics) ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--seconds", "0"], "--seconds: expected a positive finite number, got 0"),
        (["--seconds", "-1"], "--seconds: expected a positive finite number, got -1"),
        (["--seconds", "nan"], "--seconds: expected a positive finite number, got nan"),
        (["--dt", "0"], "--dt: expected a positive finite number, got 0"),
        (["--kp", "-5"], "--kp: expected a non-negative finite number, got -5"),
        (["--kd", "inf"], "--kd: expected a non-negative finite number, got inf"),
        (["--seconds", "0.001"], "--seconds 0.001 is shorter than two frames of the clip at 30 fps"),
        (["--float32"], "simulate: --float32 is not supported"),
    ],
)
def test_bad_values_exit_2(tmp_path, capsys, flags, message):
    out = tmp_path / "x.bvh"
    code, stdout, err = _run(capsys, "simulate", *flags, "--out", out)
    assert code == 2, err
    assert err.splitlines()[-1].startswith("error: ") and message in err, err
    assert "Traceback" not in err and not out.exists() and "wrote" not in stdout


def test_bad_file_and_output_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n\tOFFSET 0 0 zero\n")
    code, _, err = _run(capsys, "simulate", bad, "--seconds", "0.25", "--out", tmp_path / "x.bvh")
    assert code == 2 and err.splitlines()[-1].startswith(f"error: {bad}:4: ") and "'zero'" in err, err
    missing = tmp_path / "no" / "dir" / "x.bvh"
    code, _, err = _run(capsys, "simulate", "--seconds", "0.25", "--out", missing)
    assert code == 2 and "does not exist" in err and "Traceback" not in err, err
    code, _, err = _run(capsys, "simulate", "--controller", "pid")
    assert code == 2 and "invalid choice" in err
    code, _, err = _run(capsys, "simulate", "--contact", "glue")
    assert code == 2 and "invalid choice" in err


def test_plot_without_matplotlib_fails_before_simulating(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # as if it were not installed
    out = tmp_path / "x.bvh"
    code, _, err = _run(capsys, "simulate", "--seconds", "0.25", "--out", out, "--plot")
    assert code == 2 and "install jaxanim[plot]" in err, err
    assert "compiling" not in err and not out.exists()


def _blown_up(clip, args, plan, ui):
    """A stand-in for the rollout that blew up after 10 steps (held at frame 3 after that)."""
    from jaxanim.physics import SimResult

    idx = np.minimum(np.arange(plan.frames), 3)
    m = clip.motion
    return cli._SimRun(
        motion=jaxanim.Motion(m.rotations[idx], m.translations[idx], m.frame_time),
        com_height=np.full(plan.frames, 0.9), error=np.full(plan.frames, 0.1), ok=False, status="exploded",
        message=SimResult[SimResult.exploded], steps_done=10, setup_seconds=1.0, compile_seconds=2.0, run_seconds=0.5,
    )


def _fake_rollout(monkeypatch) -> None:
    # ``simulate`` looks ``_simulate`` up in its own module (``jaxanim.cli`` only re-exports it)
    monkeypatch.setattr(importlib.import_module("jaxanim.app._simulate"), "_simulate", _blown_up)


def test_a_short_clip_is_looped(tmp_path, capsys, monkeypatch):
    short = tmp_path / "short.bvh"
    _short_clip(short, _SHORT)
    _fake_rollout(monkeypatch)
    code, _, err = _run(capsys, "simulate", short, "--seconds", _SECONDS, "--out", tmp_path / "x.bvh")
    assert code == 1 and f"looping the clip: {_FRAMES} frames from {_SHORT}" in err, err


def test_a_rollout_that_stops_writes_its_frames_and_exits_1(tmp_path, capsys, monkeypatch):
    """The status path, with the rollout replaced by one that blew up after 10 of 116 steps."""
    _fake_rollout(monkeypatch)
    out = tmp_path / "x.bvh"
    code, stdout, err = _run(capsys, "simulate", "--seconds", "1", "--out", out)
    assert code == 1, err
    assert "rollout exploded: 10/116 steps" in stdout and "(4 per frame)" in stdout, stdout
    assert err.splitlines()[-1].startswith("error: the rollout stopped after 10 of 116 steps (exploded): A body")
    assert jaxanim.read_bvh(out)[1].num_frames == 30


def test_help_lists_simulate(capsys):
    code, out, _ = _run(capsys, "simulate", "--help")
    assert code == 0
    for flag in ("--controller", "--seconds", "--dt", "--kp", "--kd", "--no-root-force", "--contact", "--out",
                 "--plot"):
        assert flag in out
    code, out, _ = _run(capsys, "--help")
    assert code == 0 and "simulate" in out
