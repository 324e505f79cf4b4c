"""Tests for jaxanim.rotations, continued from test_rotations.py (split to keep files under 700 lines): derivatives
at the singular points (angle 0 and pi: finite, and equal to central differences) and interpolation (slerp, squad
paths against closed forms), and float32 throughout.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanim import rotations as rot

from .test_rotations import (
    _ATOL,
    _ATOL_F32,
    _N,
    _close,
    _close_up_to_sign,
    _elem,
    _is_rotation,
    _random_quats,
    _sample_rotvecs,
)

# ------------------------------------------------------------------------------------------------
# Gradients at the singular points
# ------------------------------------------------------------------------------------------------


def _finite(tree, what):
    for leaf in jax.tree_util.tree_leaves(tree):
        assert np.all(np.isfinite(np.asarray(leaf))), f"{what}: non-finite gradient"


_AXIS = np.array([0.6, -0.8, 0.0])


def _sum_cubed(fn):
    return lambda *args: jnp.sum(fn(*args) ** 3)


# Derivatives checked at the singular points, jitted once (module scope) and reused by every
# parametrization: eager jacfwd dispatches each primitive separately and is far slower.
_EXP_LOG_DERIVATIVES = {
    "jacfwd rotvec_to_quat": (jax.jit(jax.jacfwd(rot.rotvec_to_quat)), "v"),
    "jacfwd rotvec_to_matrix": (jax.jit(jax.jacfwd(rot.rotvec_to_matrix)), "v"),
    "grad rotvec_to_matrix": (jax.jit(jax.grad(_sum_cubed(rot.rotvec_to_matrix))), "v"),
    "jacfwd quat_to_rotvec": (jax.jit(jax.jacfwd(rot.quat_to_rotvec)), "q"),
    "jacrev quat_to_rotvec": (jax.jit(jax.jacrev(rot.quat_to_rotvec)), "q"),
    "jacfwd quat_to_rotvec(-q)": (jax.jit(jax.jacfwd(rot.quat_to_rotvec)), "-q"),
    "jacfwd matrix_to_rotvec": (jax.jit(jax.jacfwd(rot.matrix_to_rotvec)), "R"),
    "grad matrix_to_rotvec": (jax.jit(jax.grad(_sum_cubed(rot.matrix_to_rotvec))), "R"),
    "jacfwd quat_to_axis_angle": (jax.jit(jax.jacfwd(rot.quat_to_axis_angle)), "q"),
    "jacfwd axis_angle_to_quat": (jax.jit(jax.jacfwd(rot.axis_angle_to_quat, argnums=(0, 1))), "axis, angle"),
    "grad rotation_angle": (jax.jit(jax.grad(rot.rotation_angle)), "q"),
    "grad quat_distance": (jax.jit(jax.grad(rot.quat_distance, argnums=(0, 1))), "q, q"),
}


@pytest.mark.parametrize("angle", [0.0, 1e-9, np.pi - 1e-9, np.pi])
def test_gradients_finite_exp_log(angle):
    v = jnp.asarray(_AXIS * angle)
    q = rot.rotvec_to_quat(v)
    args = {
        "v": (v,), "q": (q,), "-q": (-q,), "R": (rot.rotvec_to_matrix(v),),
        "axis, angle": (jnp.asarray(_AXIS), jnp.asarray(angle)), "q, q": (q, q),
    }  # fmt: skip
    for name, (fn, arg) in _EXP_LOG_DERIVATIVES.items():
        _finite(fn(*args[arg]), f"{name} at angle {angle}")


def test_gradients_correct_at_zero():
    """The Taylor branches give the true derivatives: d exp / d v at 0 and d log / d q at 1."""
    d_exp_q = _EXP_LOG_DERIVATIVES["jacfwd rotvec_to_quat"][0]
    d_exp_R = _EXP_LOG_DERIVATIVES["jacfwd rotvec_to_matrix"][0]
    d_log = _EXP_LOG_DERIVATIVES["jacfwd quat_to_rotvec"][0]
    J = np.asarray(d_exp_q(jnp.zeros(3)))
    _close(J, np.vstack([np.zeros((1, 3)), 0.5 * np.eye(3)]), _ATOL, "d exp(v)/dv at 0")
    J = np.asarray(d_log(jnp.array([1.0, 0, 0, 0])))
    _close(J, np.hstack([np.zeros((3, 1)), 2.0 * np.eye(3)]), _ATOL, "d log(q)/dq at 1")
    J = np.asarray(d_exp_R(jnp.zeros(3)))  # d R / d v_k = [e_k]x
    _close(np.moveaxis(J, -1, 0), np.asarray(rot.skew(np.eye(3))), _ATOL, "d R(v)/dv at 0")
    # away from 0: compare with central differences (log at a generic point and near pi)
    for q in (np.array([0.8, 0.2, -0.5, 0.26]), np.array([1e-4, 0.6, 0.0, -0.8])):
        q = q / np.linalg.norm(q)
        J = np.asarray(d_log(jnp.asarray(q)))
        h = 1e-6
        fd = np.stack(
            [
                (np.asarray(rot.quat_to_rotvec(q + h * e)) - np.asarray(rot.quat_to_rotvec(q - h * e))) / (2 * h)
                for e in np.eye(4)
            ],
            axis=-1,
        )
        _close(J, fd, 1e-6, "d log(q)/dq vs finite differences")


_INTERP_DERIVATIVES = {
    "jacfwd slerp": jax.jit(jax.jacfwd(rot.slerp, argnums=(0, 1, 2))),
    "jacrev slerp": jax.jit(jax.jacrev(rot.slerp, argnums=(0, 1, 2))),
    "grad slerp": jax.jit(jax.grad(_sum_cubed(rot.slerp), argnums=(0, 1, 2))),
    "jacfwd nlerp": jax.jit(jax.jacfwd(rot.nlerp, argnums=(0, 1, 2))),
}


@pytest.mark.parametrize("t", [0.0, 0.3, 1.0])
def test_gradients_finite_slerp(t):
    q = jnp.asarray(rot.rotvec_to_quat(_AXIS * 0.7))
    near = rot.rotvec_to_quat(_AXIS * (0.7 + 1e-9))
    far = rot.rotvec_to_quat(_AXIS * 2.0)
    for q0, q1 in ((q, q), (q, -q), (q, near), (q, far)):
        for name, fn in _INTERP_DERIVATIVES.items():
            _finite(fn(q0, q1, jnp.asarray(t)), f"{name} at t={t}")
    # q0 == q1: the value is q0 for every t and the derivatives are those of the identity path
    _close(rot.slerp(q, q, t), q, _ATOL, "slerp(q, q, t) == q")
    d_q0, d_q1, d_t = _INTERP_DERIVATIVES["jacfwd slerp"](q, q, jnp.asarray(t))
    _close(d_t, np.zeros(4), _ATOL, "d slerp(q, q, t)/dt")
    _close(np.asarray(d_q0) + np.asarray(d_q1), np.eye(4) - np.outer(q, q), 1e-9, "d slerp(q, q, t)/dq")


# ------------------------------------------------------------------------------------------------
# Interpolation
# ------------------------------------------------------------------------------------------------


def test_slerp_properties():
    rng = np.random.default_rng(8)
    q0, q1 = _random_quats(rng, (_N,)), _random_quats(rng, (_N,))
    _close(rot.slerp(q0, q1, 0.0), q0, _ATOL, "slerp t=0")
    _close_up_to_sign(rot.slerp(q0, q1, 1.0), q1, _ATOL, "slerp t=1")
    _close(rot.slerp(q0, q1, 0.4), rot.slerp(q0, -q1, 0.4), _ATOL, "slerp shortest path: q1 ~ -q1")
    # constant angular speed along the shortest arc
    total = np.asarray(rot.quat_distance(q0, q1))
    ts = np.linspace(0.0, 1.0, 7)
    path = rot.slerp(q0[:, None], q1[:, None], ts)  # t broadcasts against the batch: [6, 7, 4]
    assert path.shape == (_N, 7, 4)
    _close(jnp.linalg.norm(path, axis=-1), np.ones((_N, 7)), _ATOL, "slerp unit")
    _close(rot.quat_distance(q0[:, None], path), total[:, None] * ts, 1e-9, "constant angular speed")
    # against the exp/log form q0 exp(t log(q0^-1 q1))
    rel = rot.quat_to_rotvec(rot.quat_multiply(rot.quat_conjugate(q0), q1))
    ref = rot.quat_multiply(q0, rot.rotvec_to_quat(0.4 * np.asarray(rel)))
    _close_up_to_sign(rot.slerp(q0, q1, 0.4), ref, 1e-12, "slerp == q0 exp(t log(q0^-1 q1))")
    # nlerp: unit, same endpoints and same midpoint, but not constant speed
    n = rot.nlerp(q0[:, None], q1[:, None], ts)
    _close(jnp.linalg.norm(n, axis=-1), np.ones((_N, 7)), _ATOL, "nlerp unit")
    _close_up_to_sign(n[:, 3], path[:, 3], _ATOL, "nlerp midpoint == slerp midpoint")
    assert np.abs(np.asarray(rot.quat_distance(q0[:, None], n)) - total[:, None] * ts).max() > 1e-4
    # antipodal inputs do not break nlerp (SEEDS 3.1)
    assert np.all(np.isfinite(np.asarray(rot.nlerp(q0, -q0, 0.5))))


def test_slerp_seed_example_matrix_lerp_fails():
    """SEEDS 2.1 item 1: lerp of R_y(-90) and R_y(90) is not a rotation; slerp's midpoint is I."""
    R0, R1 = _elem("Y", -np.pi / 2), _elem("Y", np.pi / 2)
    lerp = 0.5 * (R0 + R1)
    _close(lerp, np.diag([0.0, 1.0, 0.0]), 1e-15, "matrix lerp")
    assert abs(np.linalg.det(lerp)) < 1e-12, "matrix lerp is singular, not in SO(3)"
    # R0 and R1 are 180 degrees apart, so q0 . q1 = 0 and both arcs are shortest: slerp keeps q1 as
    # given (independent of how q0 . q1 rounds, e.g. under jit) and passes through the identity.
    q0, q1 = rot.matrix_to_quat(R0), rot.matrix_to_quat(R1)
    for name, fn in (("eager", rot.slerp), ("jit", jax.jit(rot.slerp))):
        mid = rot.quat_to_matrix(fn(q0, q1, 0.5))
        _close(mid, np.eye(3), _ATOL, f"slerp midpoint is the identity ({name})")
    _is_rotation(rot.quat_to_matrix(rot.slerp(q0, q1, np.linspace(0, 1, 5))), 1e-12, "slerp path")


def test_float32():
    rng = np.random.default_rng(11)
    q64 = _random_quats(rng, (8,))
    v64 = _sample_rotvecs("singular", (8,)) + _sample_rotvecs("uniform", (8,)) * (np.arange(8) % 2)[:, None]
    ang64 = rng.uniform(-3, 3, (8, 3))
    f32 = functools.partial(jnp.asarray, dtype=jnp.float32)
    cases = [
        ("quat_to_matrix", rot.quat_to_matrix, (q64,)),
        ("matrix_to_quat", rot.matrix_to_quat, (np.asarray(rot.quat_to_matrix(q64)),)),
        ("rotvec_to_quat", rot.rotvec_to_quat, (v64,)),
        ("rotvec_to_matrix", rot.rotvec_to_matrix, (v64,)),
        ("quat_to_rotvec", rot.quat_to_rotvec, (np.asarray(rot.rotvec_to_quat(0.5 * v64)),)),
        ("euler_to_matrix", lambda a: rot.euler_to_matrix(a, "ZXY"), (ang64,)),
        ("euler_to_quat", lambda a: rot.euler_to_quat(a, "xzx"), (ang64,)),
        ("slerp", lambda a, b: rot.slerp(a, b, 0.3), (q64, q64[::-1])),
        ("quat_apply", rot.quat_apply, (q64, ang64)),
        ("rotation_between", rot.rotation_between, (ang64, ang64[::-1])),
    ]
    for name, fn, args in cases:
        got = fn(*(f32(x) for x in args))
        assert got.dtype == jnp.float32, f"{name}: dtype {got.dtype}"
        _close(got, fn(*args), _ATOL_F32, f"{name} float32")
    R = rot.euler_to_matrix(f32(ang64), "ZXY")
    _close(rot.euler_to_matrix(rot.matrix_to_euler(R, "ZXY"), "ZXY"), R, _ATOL_F32, "float32 Euler round trip")
    for angle in (0.0, np.pi):
        v = f32(_AXIS * angle)
        _finite(_EXP_LOG_DERIVATIVES["jacfwd rotvec_to_quat"][0](v), f"float32 exp gradient at {angle}")
        _finite(
            _EXP_LOG_DERIVATIVES["jacfwd quat_to_rotvec"][0](rot.rotvec_to_quat(v)), f"float32 log gradient at {angle}"
        )
    q = f32(q64[0])
    _finite(_INTERP_DERIVATIVES["jacfwd slerp"](q, q, f32(0.5)), "float32 slerp gradient at q0 == q1")
    assert rot.quat_to_matrix(np.array([1, 0, 0, 0])).dtype == jnp.float64  # ints promote
