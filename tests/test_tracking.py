"""Tracking without root force (jaxanim.tracking.samcon, ``jaxanim track``), issue 13 items 1-3 so far.

One small search shape is compiled for the whole file: the shipped walk's first second, 10 windows
of 0.1 s, 16 samples, 4 elites and the per-joint spreads of joint_sigma; the CLI runs the same. What is checked against an
independent reference: the search beats the clip's own uncorrected stable-PD targets (the open-loop
baseline, the same simulator) on the tracking cost; the replay of the kept corrections reproduces
the cost the search recorded (the simulation is deterministic); vmap over seeds equals a loop.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxanim
from jaxanim import character, tracking
from jaxanim.app import _cli as cli
from jaxanim.app._simulate import _looped_motion
from jaxanim.physics import make_ground

def _options(char):
    """The options of every search here, the CLI's for --samples 16 (one compiled program)."""
    return tracking.TrackingOptions(samples=16, elites=4, sigma=tracking.joint_sigma(char))


@pytest.fixture(scope="module")
def problem():
    skel, clip = jaxanim.read_bvh(jaxanim.default_clip_path())
    ground = make_ground("complementarity", max_points=8, iterations=10, dtype=jnp.float64)
    char, _ = character.build_character(skel, ground=ground)
    motion = _looped_motion(clip, 31)  # 1 s: 10 windows of 3 frames
    return char, tracking.tracking_reference(char, motion), motion


@pytest.fixture(scope="module")
def result(problem):
    char, ref, _ = problem
    return tracking.samcon(char, ref, jax.random.PRNGKey(0), _options(char))


def test_the_reference_stands_on_the_ground(problem):
    char, ref, _ = problem
    from jaxanim.physics._contact import _geometry

    lowest = np.asarray(jax.vmap(lambda s: jnp.min(_geometry(char.model.ground, char.model.bodies, s)[2]))(ref.states))
    assert abs(float(np.median(lowest))) < 1e-9  # lifted by the median
    assert 0.0 < float(ref.lift) < 0.1  # the walk's joints sit on the ground; the soles are added below them
    assert ref.states.position.shape[0] == 31


def test_search_beats_the_uncorrected_targets_and_replays_exactly(problem, result):
    char, ref, _ = problem
    assert result.corrections.shape == (10, char.model.joints.num_joints, 3)
    assert result.trajectory.position.shape[0] == 31 and result.joint_error.shape == (31,)
    zero = tracking.replay(char, ref, tracking.TrackingResult(
        corrections=jnp.zeros_like(result.corrections), trajectory=result.trajectory, joint_error=result.joint_error,
        root_error=result.root_error, window_cost=result.window_cost, status=result.status, options=result.options))
    assert float(jnp.sum(result.window_cost)) < 0.8 * float(jnp.sum(zero.window_cost))
    again = tracking.replay(char, ref, result)
    np.testing.assert_allclose(np.asarray(again.window_cost), np.asarray(result.window_cost), rtol=1e-12)
    assert not bool(result.fell) and float(result.root_error[-1]) < float(zero.root_error[-1])


def test_search_is_deterministic_and_vmap_over_seeds_equals_a_loop(problem, result):
    char, ref, _ = problem
    opts = _options(char)
    keys = jnp.stack([jax.random.PRNGKey(0), jax.random.PRNGKey(1)])
    batched = jax.vmap(lambda k: tracking.samcon(char, ref, k, opts))(keys)
    np.testing.assert_array_equal(np.asarray(batched.corrections[0]), np.asarray(result.corrections))
    one = tracking.samcon(char, ref, jax.random.PRNGKey(1), opts)
    np.testing.assert_allclose(np.asarray(batched.corrections[1]), np.asarray(one.corrections), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.asarray(batched.window_cost[1]), np.asarray(one.window_cost), rtol=1e-9)
    assert not np.array_equal(np.asarray(one.corrections), np.asarray(result.corrections))


def test_bad_input(problem):
    char, ref, motion = problem
    with pytest.raises(jaxanim.JaxanimError, match="samples: expected an int >= 2"):
        tracking.TrackingOptions(samples=1)
    with pytest.raises(jaxanim.JaxanimError, match="elites: expected at most samples = 4"):
        tracking.TrackingOptions(samples=4, elites=8)
    short = tracking.tracking_reference(char, jaxanim.Motion(motion.rotations[:3], motion.translations[:3],
                                                             motion.frame_time))
    with pytest.raises(jaxanim.JaxanimError, match="too short for one control window of 3 frames"):
        tracking.samcon(char, short, jax.random.PRNGKey(0))
    with pytest.raises(jaxanim.JaxanimError, match="at least 2 frames"):
        tracking.tracking_reference(char, jaxanim.Motion(motion.rotations[:1], motion.translations[:1], motion.frame_time))


def _run(capsys, *argv):
    code = cli.main(["--no-compile-cache", *(str(a) for a in argv)])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_track_command(tmp_path, capsys):
    out = tmp_path / "walk.track.bvh"
    code, stdout, stderr = _run(capsys, "track", "--seconds", 1, "--samples", 16, "--out", out)
    assert code in (0, 1), stderr
    assert "window 10/10" in stderr and "samples/s" in stdout and "mean joint error" in stdout
    assert ("tracking successful" in stdout) == (code == 0)
    skel, motion = jaxanim.read_bvh(out)
    assert motion.num_frames == 31 and skel.num_joints == 21 and abs(float(motion.frame_time) - 1 / 30) < 1e-9
    for argv, message in (
        (["--seconds", "0"], "--seconds: expected a positive finite number"),
        (["--seconds", "1", "--samples", "1"], "--samples: expected at least 2 samples"),
        (["--seconds", "1", "--contact", "soft"], "--contact: expected one of complementarity, penalty"),
        (["--seconds", "0.05"], "shorter than one control window"),
    ):
        code, _, stderr = _run(capsys, "track", *argv, "--out", out)
        assert code == 2 and message in stderr, stderr
