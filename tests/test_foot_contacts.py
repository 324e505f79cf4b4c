"""Foot contacts: detection and the IK cleanup (jaxanim.ik.clean_foot_contacts), issue 13 item 0.

References: the shipped walk's generator pins each toe joint for a known phase of its leg's cycle
(10 %-60 %), which the detection must find; foot speeds are NumPy central differences of the clip's
FK (itself checked against scipy in test_fk). The skated clip is the shipped walk with hips and
knees rocked at 1.7 Hz, a frequency the gait does not have, so its stance feet slide at ~0.3 m/s.
Both walk clips share one compiled IK (same skeleton, frame count and targets). The clips' FK is
``clip_positions``, the batched FK the detection and the cleanup compile for the same clip shapes
(a batched FK of our own compiled once more per skeleton: ~0.8 s for the walk, ~1.1 s for CMU).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxanim
from jaxanim import rotations as rot
from jaxanim.ik import clean_foot_contacts, detect_foot_contacts, foot_joints
from jaxanim.kinematics._contacts import clip_positions

from .conftest import shared_data_dir
from .helpers import shared_clip

_FEET = ("LeftToeBase", "RightToeBase")


def _positions(skel, motion):
    return np.asarray(clip_positions(skel, motion))


def _speeds(skel, motion, feet=_FEET):
    """``[frames, feet]`` 3-D speeds and ``[frames, feet]`` heights of the foot joints."""
    P = _positions(skel, motion)[:, [skel.index(f) for f in feet]]
    return np.linalg.norm(np.gradient(P, float(motion.frame_time), axis=0), axis=-1), P[..., 1]


def _stance_speed(skel, motion) -> float:
    """The issue's measure: median speed of the lower toe joint of each frame (interior frames)."""
    speed, height = _speeds(skel, motion)
    lower = np.argmin(height[1:-1], axis=1)
    return float(np.median(speed[1:-1][np.arange(lower.size), lower]))


@pytest.fixture(scope="module")
def walk():
    return jaxanim.read_bvh(jaxanim.default_clip_path())


@pytest.fixture(scope="module")
def skated(walk):
    skel, m = walk
    t = np.arange(m.num_frames) * float(m.frame_time)
    q = np.array(m.rotations)
    # one program for the four joints (eager, the quaternion functions compile ~20 small ones)
    rock = jax.jit(lambda q, rotvec: rot.quat_multiply(q, rot.rotvec_to_quat(rotvec)))
    for name, amp, phase in (("LeftUpLeg", 0.04, 0.0), ("RightUpLeg", 0.04, 1.0), ("LeftLeg", 0.03, 2.0),
                             ("RightLeg", 0.03, 0.5)):
        j = skel.index(name)
        angle = amp * np.sin(2 * np.pi * 1.7 * t + phase)
        q[:, j] = np.asarray(rock(q[:, j], np.array([1.0, 0.0, 0.0]) * angle[:, None]))
    return jaxanim.Motion(jnp.asarray(q), m.translations, m.frame_time)


@pytest.fixture(scope="module")
def cleaned(walk, skated):
    skel, _ = walk
    before = (np.array(skated.rotations), np.array(skated.translations))
    result = clean_foot_contacts(skel, skated)
    return result, before


def test_foot_joints_are_the_lowest_leaves(walk):
    skel, _ = walk
    assert foot_joints(skel) == _FEET
    shared_data_dir()
    cmu, _, _ = shared_clip("cmu_01_01_trim300")
    assert foot_joints(cmu) == ("LeftToeBase", "RightToeBase")
    with pytest.raises(jaxanim.JaxanimError, match="up: expected the index of the up axis"):
        foot_joints(skel, up=3)


def test_detection_finds_the_generator_stance_phases(walk):
    skel, m = walk
    feet, contacts = detect_foot_contacts(skel, m)
    assert feet == _FEET and contacts.shape == (m.num_frames, 2) and contacts.dtype == bool
    t = np.arange(m.num_frames) * float(m.frame_time)
    for k, offset in enumerate((0.0, 0.5)):  # the right leg's cycle is half a cycle later
        p = np.mod(t + offset, 1.0)
        pinned = (p >= 0.1 + 1 / 30) & (p <= 0.6 - 1 / 30)  # the generator's stance, less a frame each side
        mid_swing = (p >= 0.7) & (p <= 0.95)
        assert contacts[pinned, k].all(), f"{feet[k]}: a stance frame was missed"
        assert not contacts[mid_swing, k].any(), f"{feet[k]}: a swing frame was taken for a contact"


def test_cleanup_plants_the_skated_feet(walk, skated, cleaned):
    skel, m = walk
    result, _ = cleaned
    assert _stance_speed(skel, m) < 1e-3, "the shipped walk skates"  # issue 13 item 0 (also in test_cli)
    assert _stance_speed(skel, skated) > 0.2  # the clip does skate
    assert _stance_speed(skel, result.motion) <= 2e-3  # the README: 0.0002 m/s
    assert bool(result.success.all()) and float(result.errors.max()) < 1e-4
    # in every run of contact frames the foot stays where it landed (to the IK tolerance)
    speed, _ = _speeds(skel, result.motion)
    contacts = np.asarray(result.contacts)
    P = _positions(skel, result.motion)[:, [skel.index(f) for f in _FEET]]
    for k in range(2):
        m_ = np.concatenate([[False], contacts[:, k], [False]])
        edges = np.flatnonzero(m_[1:] != m_[:-1])
        assert len(edges) >= 4
        for a, b in zip(edges[0::2], edges[1::2]):
            assert np.abs(P[a:b, k] - P[a, k]).max() < 2e-4
    # only the legs move: the root and every joint above the hips keep the clip's values
    legs = {skel.index(n) for s in ("Left", "Right") for n in (f"{s}UpLeg", f"{s}Leg", f"{s}Foot", f"{s}ToeBase")}
    others = [j for j in range(skel.num_joints) if j not in legs]
    np.testing.assert_array_equal(np.asarray(result.motion.rotations)[:, others], np.asarray(skated.rotations)[:, others])
    np.testing.assert_array_equal(np.asarray(result.motion.translations), np.asarray(skated.translations))
    # the foot's path stays continuous: no frame-to-frame jump beyond the clip's own largest step
    step = np.linalg.norm(np.diff(P, axis=0), axis=-1).max()
    P0 = _positions(skel, skated)[:, [skel.index(f) for f in _FEET]]
    assert step <= 1.1 * np.linalg.norm(np.diff(P0, axis=0), axis=-1).max()


def test_cleanup_does_not_modify_its_input(skated, cleaned):
    _, (q, t) = cleaned
    np.testing.assert_array_equal(np.asarray(skated.rotations), q)
    np.testing.assert_array_equal(np.asarray(skated.translations), t)


def test_cleanup_keeps_a_planted_clip(walk):
    skel, m = walk
    result = clean_foot_contacts(skel, m)  # the same compiled solve as the skated clip
    assert float(jnp.abs(result.motion.rotations - m.rotations).max()) < 1e-5
    assert bool(result.success.all())


def test_cleanup_on_motion_capture():
    """The CMU clip (frames 1-299; frame 0 is an added T-pose): a stand, a crouch, a jump, a landing."""
    shared_data_dir()
    skel, m, _ = shared_clip("cmu_01_01_trim300")
    m = jaxanim.Motion(m.rotations[1:], m.translations[1:], m.frame_time)
    feet, contacts = detect_foot_contacts(skel, m)
    assert contacts[:, 0].mean() > 0.3 and contacts[:, 1].mean() > 0.3  # mostly standing
    result = clean_foot_contacts(skel, m)
    np.testing.assert_array_equal(np.asarray(result.contacts), contacts)
    before, _ = _speeds(skel, m, feet)
    after, _ = _speeds(skel, result.motion, feet)
    inside = contacts.copy()
    inside[1:] &= contacts[:-1]
    inside[:-1] &= contacts[1:]  # contact frames whose neighbours are contacts too
    scale = float(np.max(np.abs(np.asarray(skel.offsets)))) * 10
    assert np.median(after[inside]) < 0.2 * np.median(before[inside])
    assert float(after[inside].max()) < 1e-2 * scale
    assert float(result.errors.max()) < 1e-3 * scale


def test_bad_input(walk):
    skel, m = walk
    with pytest.raises(jaxanim.JaxanimError, match=r"feet: unknown joint names \['LeftToe'\]"):
        detect_foot_contacts(skel, m, feet=["LeftToe"])
    with pytest.raises(jaxanim.JaxanimError, match=r"contacts: expected shape \(frames, feet\) = \(120, 2\), got \(120, 3\)"):
        clean_foot_contacts(skel, m, contacts=np.zeros((120, 3), bool))
    with pytest.raises(jaxanim.JaxanimError, match="blend: expected a number of frames >= 0"):
        clean_foot_contacts(skel, m, blend=-1)
    with pytest.raises(jaxanim.JaxanimError, match="height: expected a positive threshold"):
        detect_foot_contacts(skel, m, height=0.0)
    nan = jaxanim.Motion(m.rotations.at[7, 4, 0].set(jnp.nan), m.translations, m.frame_time)
    with pytest.raises(jaxanim.JaxanimError, match=r"motion: the clip has NaN or inf values in 1 frame\(s\), the first \[7\]"):
        clean_foot_contacts(skel, nan)  # it reported success on the NaN frames
    with pytest.raises(jaxanim.JaxanimError, match="motion: the clip has no frames"):
        clean_foot_contacts(skel, jaxanim.Motion(m.rotations[:0], m.translations[:0], m.frame_time))
    with pytest.raises(jaxanim.JaxanimError, match="motion: frame_time must be a positive number of seconds"):
        clean_foot_contacts(skel, jaxanim.Motion(m.rotations, m.translations, -m.frame_time))
