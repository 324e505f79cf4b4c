"""Tests of jaxanim.contact through jaxanim.physics: a box dropped on the ground comes to rest
(complementarity: no sinking beyond 1 mm; penalty: the static deflection m g / (4 k_p)), a box on
a slope sticks below the friction angle and slides with the closed-form acceleration above it,
contact points of each shape, the choice of the lowest points (as top_k), and bad input."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxanim import JaxanimError, contact, physics, rigid
from jaxanim import rotations as rot

_SINK_TOL = 1e-3  # acceptance: a box at rest sinks less than 1 mm (complementarity)


def _min_distance(model, state):
    return jnp.min(contact.contact_geometry(model.ground, model.bodies, state)[2])


# jitted: eager, the contact geometry (and an eager vmap of it) compiles each of its ~30 primitives on its own
_min_distance_jit = eqx.filter_jit(_min_distance)
_min_distances = eqx.filter_jit(jax.vmap(_min_distance, in_axes=(None, 0)))


def _dropped_box(kind, dt, seconds=3.0):
    bodies = rigid.make_bodies([("box", (0.2, 0.2, 0.2))])  # 8 kg
    q0 = rot.axis_angle_to_quat(jnp.asarray([1.0, 0.3, 0.2]), 0.5)
    state = rigid.make_state(bodies, position=[[0.0, 0.5, 0.0]], orientation=q0[None],
                             angular_velocity=[[1.0, 0.0, 2.0]])
    model = physics.make_model(bodies, ground=contact.make_ground(kind))
    run = physics.rollout(model, state, dt, int(round(seconds / dt)))
    final, traj = run.final, run.trajectory
    return model, final, traj


def test_box_dropped_with_complementarity_contact_comes_to_rest_without_sinking():
    model, final, traj = _dropped_box("complementarity", 1 / 120)
    depth = -np.asarray(_min_distances(model, traj))
    assert depth.max() < _SINK_TOL, f"sank {depth.max():.2e} m"
    assert np.max(np.abs(np.asarray(final.linear_velocity))) < 1e-6
    assert np.max(np.abs(np.asarray(final.angular_velocity))) < 1e-6
    # At rest on a face: the center 0.1 m above the ground and a box axis along the normal.
    np.testing.assert_allclose(np.asarray(final.position)[0, 1], 0.1, atol=1e-6)
    w, x, y, z = np.asarray(final.orientation)[0]
    R = Rotation.from_quat([x, y, z, w]).as_matrix()  # scipy is xyzw (host side: eager jnp compiles each op)
    assert np.max(np.abs(R[1])) > 1 - 1e-6


def test_box_dropped_with_penalty_contact_rests_at_the_static_deflection():
    model, final, _ = _dropped_box("penalty", 1 / 1000)
    g = model.ground
    deflection = float(model.bodies.mass[0]) * 9.81 / (4 * float(g.stiffness))  # 4 corners share the load
    np.testing.assert_allclose(-float(_min_distance_jit(model, final)), deflection, rtol=0.05)
    assert np.max(np.abs(np.asarray(final.linear_velocity))) < 1e-2


@pytest.mark.parametrize("ratio", [0.8, 1.2])
def test_box_on_a_slope_sticks_below_the_friction_angle_and_slides_above(ratio):
    mu, dt, seconds = 0.5, 1 / 240, 1.0
    alpha = np.arctan(ratio * mu)  # tan(alpha) = ratio * mu
    n = np.array([-np.sin(alpha), np.cos(alpha), 0.0])
    downhill = -np.array([np.cos(alpha), np.sin(alpha), 0.0])
    bodies = rigid.make_bodies([("box", (0.2, 0.2, 0.2))])
    q = rot.axis_angle_to_quat(jnp.asarray([0.0, 0.0, 1.0]), alpha)  # a face on the slope
    x0 = (0.1 + 1e-6) * n
    state = rigid.make_state(bodies, position=x0[None], orientation=q[None])
    model = physics.make_model(bodies, ground=contact.make_ground(friction=mu, normal=n))
    steps = int(round(seconds / dt))
    final = physics.rollout(model, state, dt, steps, record_every=steps).final
    slide = float((np.asarray(final.position[0]) - x0) @ downhill)
    if ratio < 1:
        assert abs(slide) < 1e-9, f"slid {slide} m below the friction angle"
    else:
        # Kinetic friction: a = g (sin a - mu cos a); the scheme's closed form a h^2 N (N + 1) / 2.
        a = 9.81 * (np.sin(alpha) - mu * np.cos(alpha))
        np.testing.assert_allclose(slide, a * dt**2 * steps * (steps + 1) / 2, rtol=1e-3)


def test_contact_points_of_each_shape():
    bodies = rigid.make_bodies([("box", (0.2, 0.4, 0.6)), ("sphere", (0.3,)), ("capsule", (0.1, 0.5))])
    owner, local, radius = contact.contact_points(bodies)
    np.testing.assert_array_equal(owner, [0] * 8 + [1] + [2, 2])
    np.testing.assert_allclose(np.abs(np.asarray(local[:8])), np.tile([0.1, 0.2, 0.3], (8, 1)))
    np.testing.assert_allclose(local[9:], [[0, 0, -0.25], [0, 0, 0.25]])
    np.testing.assert_allclose(radius, [0] * 8 + [0.3, 0.1, 0.1])
    # A sphere resting on the plane touches it: distance 0.
    state = rigid.make_state(bodies, position=[[0, 5, 0], [1.0, 0.3, 0.0], [0, 5, 0]])
    g = contact.make_ground()
    phi = eqx.filter_jit(contact.contact_geometry)(g, bodies, state)[2]  # one program (eager: ~30)
    np.testing.assert_allclose(phi[8], 0.0, atol=1e-15)


def test_bad_input():
    with pytest.raises(JaxanimError, match="model: expected one of"):
        contact.make_ground("springs")
    with pytest.raises(JaxanimError, match="normal: expected a non-zero vector"):
        contact.make_ground(normal=(0, 0, 0))
    with pytest.raises(JaxanimError, match="friction: expected >= 0"):
        contact.make_ground(friction=-0.1)
    with pytest.raises(JaxanimError, match="iterations: expected an int >= 1"):
        contact.make_ground(iterations=0)


_ATOL_MAX_POINTS = 1e-5  # m: four coplanar corners share the load in more than one way (the normal
# impulses are not unique); projected Gauss-Seidel's split depends on the order of the points, which
# max_points sorts by height, and moves the sliding friction's yaw torque (5e-6 m, 3e-5 rad measured)


def test_max_points_solves_only_the_lowest_points():
    """A box sliding flat on a face (4 corners touching, 4 at 0.2 m): ``max_points=4`` keeps the 4
    that touch and gives the state of all 8 points; ``max_points=1`` holds one corner and the box
    tips into the ground."""
    bodies = rigid.make_bodies([("box", (0.2, 0.2, 0.2))])
    q = rot.axis_angle_to_quat(jnp.asarray([0.0, 1.0, 0.0]), 0.3)  # turned about up: still flat
    state = rigid.make_state(bodies, position=[[0.0, 0.1, 0.0]], orientation=q[None],
                             linear_velocity=[[0.5, 0.0, 0.2]])
    final = {}
    for max_points in (None, 4, 1):
        model = physics.make_model(bodies, ground=contact.make_ground(max_points=max_points))
        final[max_points] = physics.rollout(model, state, 1 / 120, 60, record_every=60).final
    for name, atol in (("position", _ATOL_MAX_POINTS), ("orientation", 10 * _ATOL_MAX_POINTS),
                       ("linear_velocity", 1e-12), ("angular_velocity", 1e-12)):
        np.testing.assert_allclose(getattr(final[4], name), getattr(final[None], name), atol=atol, err_msg=name)
    assert float(np.asarray(final[None].position)[0, 1]) == pytest.approx(0.1, abs=1e-6)  # held on its face
    assert float(np.asarray(final[1].position)[0, 1]) < 0.1 - 1e-3  # one corner held: it sinks and tips
    assert float(np.max(np.abs(np.asarray(final[1].angular_velocity)))) > 0.1


def test_lowest_points_are_top_k_of_the_negated_heights():
    """The complementarity step's choice of its lowest ``max_points`` points equals ``lax.top_k(-phi, k)``:
    same indices, same order, ties (equal heights, several at the minimum) to the lower index."""
    from jaxanim.physics._contact import _lowest

    rng = np.random.default_rng(3)
    lowest = jax.jit(jax.vmap(_lowest, in_axes=(0, None)), static_argnums=1)
    for k in (1, 2, 8):
        phi = rng.standard_normal((200, 66))
        phi[:50] = np.round(phi[:50], 1)  # many ties
        phi[50:60, :20] = -1.0  # more points at the minimum than k
        np.testing.assert_array_equal(lowest(jnp.asarray(phi), k), jax.lax.top_k(-jnp.asarray(phi), k)[1])
