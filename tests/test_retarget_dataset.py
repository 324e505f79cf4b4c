"""``jaxanim retarget FOLDER --out OUT``: a dataset in one command (issue 59): an output and a manifest row per
clip, the corrupted file named and the exit status 1, a second run that skips everything, ``--map auto`` over
BVH dialects, the trainers' formats from the same command. The clips are short trims of the shipped walk onto the shipped humanoid, all in one
bucket (one compiled solve)."""

from __future__ import annotations

import contextlib
import csv
import io
import json
import pathlib
import re
import time

import jaxanim
import numpy as np
import pytest
from jaxanim.app._retarget_dataset import bucket_length, find_clips

pytest.importorskip("mujoco", reason="retargeting loads robots through MuJoCo (jaxanim[robots])")


def test_buckets_hold_each_length_with_at_most_half_again():
    lengths = [bucket_length(n) for n in range(1, 5000)]
    assert lengths[:32] == [32] * 32 and bucket_length(33) == 48 and bucket_length(49) == 64
    assert sorted(set(lengths))[:8] == [32, 48, 64, 96, 128, 192, 256, 384]
    n = np.arange(33, 5000)
    assert np.all(np.asarray(lengths[32:]) >= n) and np.all(np.asarray(lengths[32:]) <= 1.5 * n)


def test_find_clips_keeps_the_relative_paths_and_refuses_a_collision(tmp_path):
    (tmp_path / "a" / "deep").mkdir(parents=True)
    for f in ("a/x.bvh", "a/deep/y.npz", "a/notes.txt", "z.bvh"):
        (tmp_path / f).write_text("")
    out = tmp_path / "out"
    clips = find_clips([tmp_path / "a", tmp_path / "z.bvh"], out, ".csv")
    assert [(c.name, c.output.relative_to(out).as_posix()) for c in clips] == [
        ("deep/y.npz", "deep/y.csv"), ("x.bvh", "x.csv"), ("z.bvh", "z.csv")]
    (tmp_path / "a" / "z.bvh").write_text("")
    with pytest.raises(jaxanim.JaxanimError, match="would both write"):
        find_clips([tmp_path / "a", tmp_path / "z.bvh"], out, ".csv")


def _dialect(text: str, renames: dict, prefix: str) -> str:
    """A BVH's text with its joints renamed (``renames``, then ``prefix`` on every name)."""
    def name(m):
        return f"{m.group(1)} {prefix}{renames.get(m.group(2), m.group(2))}"
    return re.sub(r"^(\s*(?:ROOT|JOINT)) (\S+)", name, text, flags=re.M)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A folder of three trims of the walk (24, 28 and 30 frames: one bucket) in three dialects: the shipped
    names, LAFAN1's (in a subfolder) and Mixamo's, and a corrupted BVH."""
    skel, walk = jaxanim.read_bvh(jaxanim.default_clip_path())[:2]
    root = tmp_path_factory.mktemp("clips")
    (root / "sub").mkdir()
    dialects = {"walk_a.bvh": ({}, ""), "sub/walk_b.bvh": ({"Chest": "Spine2", "LeftToeBase": "LeftToe",
                                                             "RightToeBase": "RightToe"}, ""),
                "walk_c.bvh": ({"Chest": "Spine2"}, "mixamorig:")}
    for name, (a, b) in {"walk_a.bvh": (0, 24), "sub/walk_b.bvh": (10, 38), "walk_c.bvh": (20, 50)}.items():
        clip = jaxanim.Motion(walk.rotations[a:b], walk.translations[a:b], walk.frame_time)
        jaxanim.write_bvh(root / name, skel, clip)
        (root / name).write_text(_dialect((root / name).read_text(), *dialects[name]))
    (root / "broken.bvh").write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0\n")
    return root


def _manifest(path: pathlib.Path) -> dict[str, dict]:
    with open(path, newline="") as f:
        return {r["source"]: r for r in csv.DictReader(f)}


@pytest.fixture(scope="module")
def first_run(dataset, tmp_path_factory):
    """The dataset's first run: ``(arguments, output folder, exit status, stderr)``."""
    from jaxanim.app import main

    out = tmp_path_factory.mktemp("first") / "out"
    args = ["--no-compile-cache", "retarget", str(dataset), "--out", str(out), "--batch", "2", "--map", "auto"]
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(args)
    return args, out, code, err.getvalue()


def test_a_folder_writes_every_good_clip_names_the_broken_one_and_resumes(first_run, capsys):
    """``--map auto`` over three dialects: a map per skeleton, the same robot program for all."""
    from jaxanim.app import main

    args, out, code, err = first_run
    assert code == 1
    assert "broken.bvh" in err
    rows = _manifest(out / "manifest.csv")
    assert sorted(rows) == ["broken.bvh", "sub/walk_b.bvh", "walk_a.bvh", "walk_c.bvh"]
    assert rows["broken.bvh"]["status"] == "failed" and "broken.bvh" in rows["broken.bvh"]["error"]
    assert not (out / "broken.npz").exists()
    for name, frames in (("walk_a", 24), ("sub/walk_b", 28), ("walk_c", 30)):
        row = rows[name + ".bvh"]
        assert row["status"] == "successful", row
        assert int(row["frames"]) == frames and float(row["fps"]) == pytest.approx(1 / 0.033333, rel=1e-4)
        assert float(row["foot_slide"]) <= 1e-3 and float(row["penetration"]) <= 1e-3
        assert float(row["range_violation"]) <= 1e-6
        with np.load(out / (name + ".npz")) as data:
            assert data["qpos"].shape[0] == data["qvel"].shape[0] == data["body_positions"].shape[0] == frames
            assert np.all(np.isfinite(data["qpos"]))
        assert len(row["sha256"]) == 64
    assert (out / "manifest.png").stat().st_size > 0
    # a second run skips every good clip within seconds, and the broken one fails again
    stamp = (out / "walk_a.npz").stat().st_mtime_ns
    t0 = time.perf_counter()
    assert main(args) == 1
    assert time.perf_counter() - t0 < 10.0
    assert (out / "walk_a.npz").stat().st_mtime_ns == stamp
    assert "3 retargeted or up to date (3 skipped)" in capsys.readouterr().out
    assert _manifest(out / "manifest.csv")["walk_a.bvh"] == rows["walk_a.bvh"]
    assert '"robot_sha256": "' in rows["walk_a.bvh"]["options"]  # an edited robot file redoes the clips


def test_formats_from_the_dataset_command(dataset, tmp_path, capsys, monkeypatch):
    """The same folder into the trainers' formats (the solve's program is the previous test's)."""
    from jaxanim.app import main

    out = tmp_path / "bm"
    code = main(["--no-compile-cache", "retarget", str(dataset / "walk_a.bvh"), str(dataset / "sub"), "--out",
                 str(out), "--batch", "2", "--format", "beyondmimic", "--fps", "60", "--map", "auto"])
    assert code == 0, capsys.readouterr().err
    with np.load(out / "walk_a.npz") as bm:
        assert bm["fps"].tolist() == [60.0] and bm["joint_pos"].shape[0] == 47  # 24 frames at 30 fps, resampled
    assert (out / "walk_b.npz").exists()
    monkeypatch.chdir(tmp_path)  # a relative --out
    code = main(["--no-compile-cache", "retarget", str(dataset / "walk_a.bvh"), str(dataset / "walk_c.bvh"),
                 "--out", "csv", "--batch", "2", "--format", "csv", "--map", "auto"])
    assert code == 0
    assert _manifest(tmp_path / "csv" / "manifest.csv")["walk_a.bvh"]["output"] == "walk_a.csv"
    rows = np.loadtxt(tmp_path / "csv" / "walk_a.csv", delimiter=",")
    assert rows.shape[0] == 24 and np.allclose(np.linalg.norm(rows[:, 3:7], axis=1), 1.0)
    capsys.readouterr()
    assert main(["retarget", str(dataset), "--out", str(tmp_path / "x"), "--format", "bvh"]) != 0
    assert "--format" in capsys.readouterr().err
    assert main(["retarget", str(dataset), "--out", str(tmp_path / "x.npz")]) != 0
    assert "--out" in capsys.readouterr().err


def test_two_processes_share_the_clips_and_merge_the_manifest(dataset, tmp_path):
    """``--coordinator/--num-processes/--process-id``: two processes on localhost (the pattern of
    tests/test_distributed.py), a copy of one clip each; process 0 merges the parts; the two copies come out
    equal. The least work per process (each compiles its own programs, about 20 s of one core): the 4-hinge
    robot of the test helpers, the csv format, no one-process run to compare with (a clip's solve never spans
    the processes; the dataset's one-process runs are the tests above)."""
    import shutil
    import sys

    from benchmarks.scaling import check_processes, free_port, run_processes, subprocess_env
    from .helpers import TINY, TINY_MAP

    folder = tmp_path / "two"
    (folder / "sub").mkdir(parents=True)
    for name in ("walk_a.bvh", "sub/walk_a.bvh"):
        shutil.copy(dataset / "walk_a.bvh", folder / name)
    (tmp_path / "tiny.xml").write_text(TINY)
    (tmp_path / "tiny.json").write_text(json.dumps(TINY_MAP))
    common = ["retarget", str(folder), "--robot", str(tmp_path / "tiny.xml"), "--map", str(tmp_path / "tiny.json"),
              "--batch", "1", "--format", "csv"]
    out, port = tmp_path / "out2", free_port()
    argvs = [[sys.executable, "-m", "jaxanim", "--no-compile-cache", *common, "--out", str(out), "--coordinator",
              f"127.0.0.1:{port}", "--num-processes", "2", "--process-id", str(i)] for i in range(2)]
    results = run_processes(argvs, env=subprocess_env(), timeout_s=240.0)
    check_processes(results, "jaxanim retarget on two processes")
    assert "process 1 of 2: 1 clips, 0 failed" in results[1].stdout
    rows = _manifest(out / "manifest.csv")
    assert sorted(rows) == ["sub/walk_a.bvh", "walk_a.bvh"] and all(r["status"] == "successful" for r in rows.values())
    assert not list(out.glob("manifest.part-*"))
    assert (out / "manifest.png").exists()
    # the same clip, solved by each process on its own: the same numbers (no computation spans the processes)
    a, b = (np.loadtxt(out / name, delimiter=",") for name in ("walk_a.csv", "sub/walk_a.csv"))
    assert a.shape == (24, 7 + 4) and np.all(np.isfinite(a))
    np.testing.assert_array_equal(a, b)
