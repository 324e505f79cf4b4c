"""Tests of jaxanim.rigid: mass properties against numerical integration over a grid, torque-free
spinning (angular momentum conserved, intermediate-axis instability), free fall against the closed
forms, forces at points, vmap against a loop, and bad input."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanim import JaxanimError, rigid
from jaxanim import rotations as rot

_RTOL_GRID = 3e-3  # analytic inertia vs a 128^3 grid
_RTOL_MOMENTUM = 1e-6  # acceptance: |L(t) - L(0)| / |L(0)| over 10 s


def _grid_inertia(inside, half_extent, n=128):
    """Mass-normalized inertia of the set ``inside(p)`` by the midpoint rule on a grid."""
    ax = (np.arange(n) + 0.5) / n * 2 - 1
    ax = [a * h for a, h in zip(np.broadcast_to(ax, (3, n)), half_extent)]
    X, Y, Z = np.meshgrid(*ax, indexing="ij")
    P = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    P = P[inside(P)]
    S = P.T @ P / len(P)  # second moments
    return np.trace(S) * np.eye(3) - S


@pytest.mark.parametrize(
    "kind, size, inside, half",
    [
        ("box", (0.4, 1.0, 0.2), lambda P: np.ones(len(P), bool), (0.2, 0.5, 0.1)),
        ("sphere", (0.3,), lambda P: np.sum(P**2, 1) <= 0.09, (0.3, 0.3, 0.3)),
        (
            "capsule",
            (0.1, 0.5),
            lambda P: np.sum(P[:, :2] ** 2, 1) + np.maximum(np.abs(P[:, 2]) - 0.25, 0) ** 2 <= 0.01,
            (0.1, 0.1, 0.35),
        ),
    ],
)
def test_mass_properties_match_grid_integration(kind, size, inside, half):
    mass, I0 = rigid.shape_mass_properties(kind, size, mass=2.5)
    ref = 2.5 * _grid_inertia(inside, half)
    np.testing.assert_allclose(I0, ref, rtol=_RTOL_GRID, atol=_RTOL_GRID * np.max(ref), err_msg=kind)
    # Density: mass = density x volume.
    m_d, _ = rigid.shape_mass_properties(kind, size, density=1000.0)
    vol = 4 / 3 * np.pi * size[0] ** 3 + (np.pi * size[0] ** 2 * size[1] if kind == "capsule" else 0.0)
    vol = np.prod(size) if kind == "box" else vol
    np.testing.assert_allclose(m_d, 1000.0 * vol, rtol=1e-12)


@functools.lru_cache(maxsize=None)
def _rollout_fn(steps):
    @jax.jit
    def run(model, state, dt):
        def body(s, _):
            s = rigid._momentum_step(model, s, jnp.zeros((1, 3)), jnp.zeros((1, 3)), dt)
            return s, (rigid.angular_momentum(model, s), rigid.kinetic_energy(model, s), s)

        return jax.lax.scan(body, state, None, length=steps)

    return run


def _spinning_box(omega_body, q0=(1.0, 0.0, 0.0, 0.0)):
    # Principal moments I1 < I2 < I3 about body x, y, z; no gravity.
    model = rigid.make_bodies([("box", (1.0, 0.6, 0.3))], mass=[2.0], gravity=(0.0, 0.0, 0.0))
    q0 = rot.quat_normalize(jnp.asarray(q0))
    omega = rot.quat_apply(q0, jnp.asarray(omega_body))
    return model, rigid.make_state(model, orientation=q0[None], angular_velocity=omega[None])


def test_torque_free_spin_conserves_angular_momentum_and_flips_about_the_intermediate_axis():
    dt, steps = 1 / 600, 6000  # 10 s
    run = _rollout_fn(steps)
    # Near the intermediate axis (body y): unstable, the body flips (Dzhanibekov effect).
    model, state = _spinning_box((0.01, 3.0, 0.01), q0=(0.9, 0.1, -0.2, 0.3))
    L0 = rigid.angular_momentum(model, state)
    _, (L, E, traj) = run(model, state, dt)
    rel = np.max(np.linalg.norm(np.asarray(L) - np.asarray(L0), axis=1)) / np.linalg.norm(L0)
    assert rel < _RTOL_MOMENTUM, f"angular momentum drift {rel:.2e}"
    omega_body = np.asarray(rot.quat_apply(rot.quat_conjugate(traj.orientation[:, 0]), traj.angular_velocity[:, 0]))
    assert omega_body[:, 1].min() < -2.0 and omega_body[:, 1].max() > 2.0, "no flip about the intermediate axis"
    E0 = float(rigid.kinetic_energy(model, state))
    assert np.max(np.abs(np.asarray(E) - E0)) / E0 < 1e-2, "kinetic energy drift"
    # Near the major (z) and minor (x) axes: stable, the spin stays about that axis.
    for axis, omega0 in ((2, (0.01, 0.01, 3.0)), (0, (3.0, 0.01, 0.01))):
        model, state = _spinning_box(omega0)
        _, (L, _, traj) = run(model, state, dt)
        L0 = rigid.angular_momentum(model, state)
        assert np.max(np.linalg.norm(np.asarray(L) - np.asarray(L0), axis=1)) / np.linalg.norm(L0) < _RTOL_MOMENTUM
        w = np.asarray(rot.quat_apply(rot.quat_conjugate(traj.orientation[:, 0]), traj.angular_velocity[:, 0]))
        assert np.min(w[:, axis]) > 2.9, f"spin about axis {axis} not stable"


def test_free_fall_matches_closed_forms():
    model = rigid.make_bodies([("sphere", (0.1,)), ("capsule", (0.05, 0.3))], mass=[1.0, 3.0])
    x0 = np.array([[0.0, 2.0, 0.0], [1.0, 5.0, -1.0]])
    v0 = np.array([[1.0, 3.0, 0.0], [0.0, 0.0, 2.0]])
    state = rigid.make_state(model, position=x0, linear_velocity=v0, angular_velocity=[[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])
    dt, n = 0.01, 150
    s = state
    for _ in range(n):
        s = rigid.step_free(model, s, dt)
    g = np.asarray(model.gravity)
    # The scheme's own closed form (v first, then x with the new v) ...
    np.testing.assert_allclose(s.position, x0 + n * dt * v0 + dt**2 * g * n * (n + 1) / 2, atol=1e-12, rtol=0)
    np.testing.assert_allclose(s.linear_velocity, v0 + n * dt * g, atol=1e-12, rtol=0)
    # ... is the exact parabola up to its first-order error 0.5 g h t.
    t = n * dt
    err = np.abs(np.asarray(s.position) - (x0 + v0 * t + 0.5 * g * t * t))
    np.testing.assert_allclose(err, np.abs(0.5 * g * dt * t) * np.ones((2, 1)), atol=1e-12)
    np.testing.assert_allclose(s.time, t, rtol=1e-12)
    # Spin does not disturb the fall, and the free capsule keeps its angular momentum about its COM.
    L_com = lambda st: rigid.world_inertia(model, st.orientation)[1] @ st.angular_velocity[1]  # noqa: E731
    np.testing.assert_allclose(L_com(s), L_com(state), rtol=1e-12)


def test_force_at_point_and_torque():
    f, tau = rigid.force_at_point(jnp.array([1.0, 0.0, 0.0]), jnp.array([0.0, 0.0, 2.0]), jnp.array([1.0, 1.0, 0.0]))
    np.testing.assert_allclose(tau, np.cross([0.0, 1.0, 0.0], [0.0, 0.0, 2.0]))
    model = rigid.make_bodies([("box", (1.0, 1.0, 1.0))], mass=[6.0], gravity=(0.0, 0.0, 0.0))  # I = 1
    state = rigid.make_state(model)
    s = rigid.step_free(model, state, 0.1, force=f[None], torque=tau[None])
    np.testing.assert_allclose(s.linear_velocity[0], [0.0, 0.0, 0.2 / 6.0], atol=1e-15)
    np.testing.assert_allclose(s.angular_velocity[0], 0.1 * np.asarray(tau), atol=1e-12)


def test_vmap_equals_loop():
    model = rigid.make_bodies([("box", (0.5, 0.3, 0.2)), ("sphere", (0.2,))])
    rng = np.random.default_rng(0)
    states = [
        rigid.make_state(model, position=rng.standard_normal((2, 3)), orientation=rng.standard_normal((2, 4)),
                         linear_velocity=rng.standard_normal((2, 3)), angular_velocity=rng.standard_normal((2, 3)))
        for _ in range(3)
    ]
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *states)
    batched = jax.vmap(lambda s: rigid.step_free(model, s, 0.01))(stacked)
    for i, s in enumerate(states):
        single = rigid.step_free(model, s, 0.01)
        for name in ("position", "orientation", "linear_velocity", "angular_velocity"):
            np.testing.assert_allclose(getattr(batched, name)[i], getattr(single, name), atol=1e-14, err_msg=name)


def test_bad_input():
    with pytest.raises(JaxanimError, match="kind: expected one of"):
        rigid.make_bodies([("cone", (1.0,))])
    with pytest.raises(JaxanimError, match=r"size: expected shape \(2,\) for a capsule"):
        rigid.make_bodies([("capsule", (1.0,))])
    with pytest.raises(JaxanimError, match="mass: expected > 0"):
        rigid.make_bodies([("sphere", (1.0,))], mass=[-1.0])
    with pytest.raises(JaxanimError, match="size: expected positive"):
        rigid.make_bodies([("box", (1.0, 0.0, 1.0))])
    with pytest.raises(JaxanimError, match="names: expected unique"):
        rigid.make_bodies([("sphere", (1.0,)), ("sphere", (1.0,))], names=["a", "a"])
    model = rigid.make_bodies([("sphere", (1.0,))])
    with pytest.raises(JaxanimError, match=r"position: expected shape \(B, 3\) = \(1, 3\), got \(2, 3\)"):
        rigid.make_state(model, position=np.zeros((2, 3)))
    state = rigid.make_state(model)
    with pytest.raises(JaxanimError, match=r"force: expected shape \(B, 3\) = \(1, 3\)"):
        rigid.step_free(model, state, 0.01, force=np.zeros(3))
    bad = rigid.RigidBodies(names=("a",), shapes=("box",), mass=jnp.array([1.0]),
                            inertia=jnp.diag(jnp.array([1.0, -1.0, 1.0]))[None], size=jnp.ones((1, 3)),
                            gravity=jnp.zeros(3))
    with pytest.raises(JaxanimError, match="model.inertia: expected positive-definite inertias; not so for \\['a'\\]"):
        rigid.step_free(bad, state, 0.01)
    bad = rigid.RigidBodies(names=("a",), shapes=("box",), mass=jnp.array([0.0]), inertia=jnp.eye(3)[None],
                            size=jnp.ones((1, 3)), gravity=jnp.zeros(3))
    with pytest.raises(JaxanimError, match="model.mass: expected positive masses"):
        rigid.step_free(bad, state, 0.01)
