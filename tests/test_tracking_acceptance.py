"""Issue 13's acceptance runs of ``jaxanim track``, as a user types them (minutes each, so they are
left out of the default run; ``python -m pytest -m acceptance`` runs them).

Both run within the torque limits of ``tracking.joint_torque_limits`` (the report's peak torque is
checked against its bound).

- The shipped walk, 4 s with looping, 256 samples, a 100 N forward push on the torso at mid-clip:
  no fall (the root stays above 0.7 x the clip's lowest root height), mean joint error at most
  0.15 rad, mean horizontal root error at most 0.2 m; with the feedback gains the push does not
  fell the character, and the open-loop corrections alone do.
- The CMU clip in ../shared/data, frames 1-299 (frame 0 is an added T-pose; stand, crouch, a
  standing forward jump, landing): no fall, mean joint error at most 0.2 rad, mean horizontal root
  error at most 0.25 m.

The errors are read from the command's report, which computes them against the clip (the
reference, an independent input) in meters scaled from the file's units.
"""

from __future__ import annotations

import re

import pytest

import jaxanim
from jaxanim.app import _cli as cli

pytestmark = pytest.mark.acceptance


def _track(capsys, *argv):
    code = cli.main(["--no-compile-cache", "track", *(str(a) for a in argv)])
    captured = capsys.readouterr()
    out = captured.out
    joint = float(re.search(r"mean joint error ([0-9.]+) rad", out).group(1))
    root = float(re.search(r"mean horizontal root error ([0-9.]+) m", out).group(1))
    peak, bound = re.search(r"peak joint torque ([0-9]+) N m at \w+ \(limit ([0-9]+) N m", out).groups()
    assert int(peak) <= int(bound), out  # within the torque limits (tracking.joint_torque_limits)
    return code, out, captured.err, joint, root


def test_walk_4s_with_a_push(tmp_path, capsys):
    out = tmp_path / "walk.track.bvh"
    code, stdout, stderr, joint, root = _track(capsys, "--seconds", 4, "--samples", 256, "--push", 100, "--out", out)
    print(stdout)
    assert code == 0 and "tracking successful" in stdout, stdout + stderr
    assert joint <= 0.15 and root <= 0.2, stdout
    assert "open-loop controls fell, with the feedback gains stood" in stdout, stdout
    assert jaxanim.read_bvh(out)[1].num_frames == 121


def test_cmu_jump(tmp_path, capsys, shared_data):
    clip = shared_data / "bvh" / "cmu_01_01_trim300.bvh"
    out = tmp_path / "jump.track.bvh"
    code, stdout, stderr, joint, root = _track(capsys, clip, "--from-frame", 1, "--seconds", 2.48, "--samples", 256,
                                               "--out", out)
    print(stdout)
    assert code == 0 and "tracking successful" in stdout, stdout + stderr
    assert joint <= 0.2 and root <= 0.25, stdout
