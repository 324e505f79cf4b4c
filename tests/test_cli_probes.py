"""The command-line probes of issue 31: sizes and outputs are checked before any work, and bad targets
are named. Every case fails in argument checking (nothing is compiled), so the file runs in seconds."""

from __future__ import annotations

import json

import pytest

from jaxanim import cli


def _run(capsys, *argv) -> tuple[int, str]:
    code = cli.main(["--no-compile-cache", *(str(a) for a in argv)])
    return code, capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["simulate", "--seconds", "1e9", "--out", "x.bvh"], "--seconds: expected a positive finite number, got "
                                                             "1e+09 (at most 3600"),
        (["simulate", "--seconds", "0.2", "--dt", "1e-9", "--out", "x.bvh"], "physics steps, more than 10,000,000"),
        (["track", "--seconds", "1e9", "--out", "x.bvh"], "got 1e+09 (at most 3600: an hour)"),
        (["match", "--input", "in.json", "--seconds", "1e9", "--out", "x.bvh"], "at most 3600"),
        (["simulate", "--seconds", "0.2", "--out", "."], "--out .: cannot write it: it is a directory"),
        (["track", "--seconds", "0.2", "--out", "."], "--out .: cannot write it: it is a directory"),
        (["match", "--input", "in.json", "--seconds", "1", "--out", "."], "it is a directory"),
        (["fk", "--out", "."], "--out .: cannot write it: it is a directory"),
        (["plot", "--out", "."], "--out .: cannot write it: it is a directory"),
        (["ik", "--targets", "t.json", "--out", "."], "--out .: cannot write it: it is a directory"),
    ],
    ids=["simulate-seconds", "simulate-dt", "track-seconds", "match-seconds", "simulate-out", "track-out",
         "match-out", "fk-out", "plot-out", "ik-out"],
)
def test_sizes_and_outputs_are_checked_first(tmp_path, capsys, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "t.json").write_text(json.dumps({"targets": [{"joint": "LeftHand", "position": [0, 0, 0]}]}))
    (tmp_path / "in.json").write_text(json.dumps({"velocity": [[0, 1, 0]]}))
    code, err = _run(capsys, *argv)
    assert code == 2, err
    assert err.strip().splitlines()[-1].startswith("error: ") and message in err, err
    assert "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.json", "t.json"]  # nothing written


@pytest.mark.parametrize(
    ("target", "message"),
    [
        ({"joint": "LeftHand", "orientation": [0, 0, 0, 0]}, "targets[0].orientation: expected a rotation quaternion"),
        ({"joint": "LeftHand", "position": [0, float("nan"), 0]}, "targets[0].position: expected finite numbers"),
        ({"joint": "LeftHand", "position": [0, 0, 0], "weight": float("nan")},
         "targets[0].weight: expected a non-negative"),
    ],
    ids=["zero-quaternion", "nan-position", "nan-weight"],
)
def test_ik_targets_are_checked(tmp_path, capsys, target, message):
    path = tmp_path / "t.json"
    path.write_text(json.dumps({"targets": [target]}))
    code, err = _run(capsys, "ik", "--targets", path, "--out", tmp_path / "x.bvh")
    assert code == 2 and message in err, err
    assert "Traceback" not in err and not (tmp_path / "x.bvh").exists()


def test_ik_targets_not_utf8(tmp_path, capsys):
    path = tmp_path / "t.json"
    path.write_text(json.dumps({"targets": [{"joint": "LeftHand", "position": [0, 0, 0]}]}), encoding="utf-16")
    code, err = _run(capsys, "ik", "--targets", path, "--out", tmp_path / "x.bvh")
    assert code == 2 and "not UTF-8 text" in err, err
    assert "Traceback" not in err
