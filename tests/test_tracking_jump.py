"""The CMU jump tracked in the default run (issue 31, item 4), reduced from the acceptance run
(tests/test_tracking_acceptance.py: frames 1-299, 256 samples): the CMU clip of ../shared/data from
frame 200 (0.2 s before take-off) through the landing (frame about 280) and 0.5 s after it, the clip's
last frame held for the 0.35 s it does not cover, at 64 samples per window. The character must not fall,
and track within absolute bounds: mean joint error at most 0.2 rad and mean horizontal root error at
most 0.25 m (the acceptance run's bounds; measured 0.174 rad and 0.097 m). The errors are against the
clip, an independent input.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

import jaxanim
from jaxanim import character, tracking
from jaxanim.physics import make_ground

START, LANDING, HOLD = 200, 280, 48  # frames at 120 fps; the held frames take the run 0.5 s past the landing


def test_jump_through_its_landing_plus_half_a_second(shared_data):
    skel, clip = jaxanim.read_bvh(shared_data / "bvh" / "cmu_01_01_trim300.bvh")
    ground = make_ground("complementarity", max_points=8, iterations=10, dtype=jnp.float64)
    char, _ = character.build_character(skel, ground=ground)
    options = tracking.tracking_options(char, float(clip.frame_time), 64)
    rotations = jnp.concatenate([clip.rotations[START:], jnp.repeat(clip.rotations[-1:], HOLD, axis=0)])
    translations = jnp.concatenate([clip.translations[START:], jnp.repeat(clip.translations[-1:], HOLD, axis=0)])
    frames = (rotations.shape[0] - 1) // options.window * options.window + 1  # whole control windows
    assert (frames - 1 - (LANDING - START)) * float(clip.frame_time) >= 0.5  # the run goes 0.5 s past the landing
    motion = jaxanim.Motion(rotations[:frames], translations[:frames], clip.frame_time)
    result = tracking.samcon(char, tracking.tracking_reference(char, motion), jax.random.PRNGKey(0), options)
    joint, root = float(np.mean(result.joint_error[1:])), float(np.mean(result.root_error))
    assert not bool(result.fell), (joint, root)
    assert joint <= 0.2 and root <= 0.25, (joint, root)
