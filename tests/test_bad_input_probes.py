"""Bad input named in a clear error, or reported as a status (issue 31, item 6): each probe once
gave a plausible answer or a traceback from deep inside JAX. One small test per probe."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxanim
import solvers
from jaxanim import JaxanimError, character, joints, matching, physics, rigid, tracking


@functools.lru_cache(maxsize=None)
def _walk(frames: int = 40):
    """The shipped clip's skeleton and its first ``frames`` frames."""
    skel, motion = jaxanim.read_bvh(jaxanim.default_clip_path())[:2]
    return skel, jaxanim.Motion(motion.rotations[:frames], motion.translations[:frames], motion.frame_time)


def test_search_refuses_a_non_finite_query_and_flags_it_under_jit():
    skel, motion = _walk(60)
    db = matching.build_database([motion], skel)
    q = np.asarray(db.features[3]).copy()
    q[1] = np.nan
    with pytest.raises(JaxanimError, match=r"query: expected finite values"):
        matching.search(db, q)
    res = jax.jit(matching.search)(db, jnp.asarray(q))  # traced: the result says so, no plausible row
    assert int(res.index) == -1 and np.isnan(float(res.distance)), "search under jit"
    ok = jax.jit(matching.search)(db, db.features[3])
    assert int(ok.index) == 3, "a finite query under jit"


def test_a_clip_with_a_non_positive_frame_time_is_refused():
    skel, motion = _walk(4)
    for ft in (-1 / 30, 0.0, float("nan")):
        bad = jaxanim.Motion(motion.rotations, motion.translations, ft)
        with pytest.raises(JaxanimError, match=r"motion: frame_time must be a positive number of seconds"):
            jaxanim.resample(bad, fps=60)
        with pytest.raises(JaxanimError, match=r"motion: frame_time must be a positive number of seconds"):
            jaxanim.kinematics.detect_foot_contacts(skel, bad)
        with pytest.raises(JaxanimError, match=r"frame_time must be a positive number of seconds"):
            jaxanim.skeleton.format_bvh(skel, bad)


def test_a_negative_spring_halflife_is_refused():
    with pytest.raises(JaxanimError, match=r"halflife: expected a positive finite number \(seconds\), got -0.1"):
        jaxanim.skeleton.decay_spring(1.0, 0.0, -0.1, 0.5)
    for name in ("velocity_halflife", "facing_halflife", "blend_halflife", "adjust_halflife"):
        with pytest.raises(JaxanimError, match=rf"{name}: expected a positive finite number \(seconds\)"):
            matching.ControllerOptions(**{name: -0.2})
    # traced, the spring stays a formula (jit and vmap work)
    x, _ = jax.jit(jaxanim.skeleton.decay_spring)(1.0, 0.0, 0.1, 0.1)
    assert abs(float(x) - 0.25 * (1 + 2 * np.log(2))) < 1e-12  # e^{-y t} (x0 + y x0 t), y t = 2 ln 2


def test_a_negative_pd_gain_is_refused():
    bodies = rigid.make_bodies([("sphere", (0.1,)), ("sphere", (0.1,))])
    state = rigid.make_state(bodies, position=np.array([[0.0, 1.0, 0.0], [0.0, 0.8, 0.0]]))
    J = joints.make_joints(bodies, state, [
        dict(name="a", type="ball", parent=None, child=0, anchor=(0.0, 1.0, 0.0)),
        dict(name="b", type="ball", parent=0, child=1, anchor=(0.0, 0.9, 0.0))])
    model = physics.make_model(bodies, J)
    targets = jnp.tile(jnp.array([1.0, 0.0, 0.0, 0.0]), (2, 1))
    with pytest.raises(JaxanimError, match=r"spd kp: expected (a )?non-negative finite"):
        physics.step(model, state, 0.01, spd=(targets, -10.0, 1.0))
    with pytest.raises(JaxanimError, match=r"kp: expected (a )?non-negative finite"):
        character.pd_force(0.0, 0.0, 1.0, -5.0, 1.0)
    with pytest.raises(JaxanimError, match=r"kp: expected (a )?non-negative finite"):
        tracking.TrackingOptions(kp=-2000.0)


def test_a_sigma_of_the_wrong_length_is_named():
    skel, motion = _walk(8)
    char, _ = character.build_character(skel)
    ref = tracking.tracking_reference(char, motion)
    nj = char.model.joints.num_joints
    options = tracking.TrackingOptions(samples=2, elites=1, sigma=jnp.full((nj + 1,), 0.1))
    with pytest.raises(JaxanimError, match=rf"options.sigma: expected a scalar or shape \({nj},\)"):
        tracking.samcon(char, ref, jax.random.PRNGKey(0), options)


def test_ilqr_names_us_init_when_the_callbacks_reject_its_control_size():
    A = jnp.array([[1.0, 0.1], [0.0, 1.0]])
    B = jnp.array([[0.0], [1.0]])

    def dynamics(x, u, t, args):
        return A @ x + B @ u

    def cost(x, u, t, args):
        return x @ x + u @ u

    with pytest.raises(ValueError, match=r"us_init: .*shape \(T, m\) = \(5, 2\)"):
        solvers.ilqr(dynamics, cost, jnp.ones(2), jnp.zeros((5, 2)))
