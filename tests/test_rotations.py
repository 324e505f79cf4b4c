"""Tests for jaxanim.rotations.

References: scipy's ``Rotation`` (run here on fixed-seed inputs, and the stored values in
``shared/data/rotations/rotation_refs.json``), products of elementary matrices written out in
numpy, and the group axioms. scipy stores quaternions **xyzw**; jaxanim uses **wxyz**: every
comparison converts with ``_xyzw_to_wxyz`` / ``_wxyz_to_xyzw`` below.
"""

from __future__ import annotations

import functools
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from jaxanim import JaxanimError
from jaxanim import rotations as rot
from jaxanim.rotations._matrices import angle_between_matrices

_ATOL = 1e-12  # float64 conversions against scipy / closed forms
_ATOL_SINGULAR = 1e-9  # float64 round trips at angle 0 / pi
_ATOL_F32 = 2e-5  # float32 against float64
_N = 8  # batch size of the random tests: few distinct shapes keep compilation (and the suite) fast

TAIT_BRYAN = ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"]
PROPER = ["XYX", "XZX", "YXY", "YZY", "ZXZ", "ZYZ"]
ALL_ORDERS = TAIT_BRYAN + PROPER + [o.lower() for o in TAIT_BRYAN + PROPER]  # the 24 conventions


# ------------------------------------------------------------------------------------------------
# Helpers
# ------------------------------------------------------------------------------------------------


def _xyzw_to_wxyz(q):
    q = np.asarray(q, dtype=float)
    return np.concatenate([q[..., 3:], q[..., :3]], axis=-1)


def _wxyz_to_xyzw(q):
    q = np.asarray(q, dtype=float)
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def _close(actual, expected, atol, what, rtol=0.0):
    np.testing.assert_allclose(np.asarray(actual), np.asarray(expected), atol=atol, rtol=rtol, err_msg=what)


def _close_up_to_sign(q, p, atol, what):
    """Quaternions equal as rotations: q == p or q == -p, per batch element."""
    q, p = np.asarray(q), np.asarray(p)
    err = np.minimum(np.abs(q - p).max(axis=-1), np.abs(q + p).max(axis=-1))
    assert err.max() <= atol, f"{what}: quaternions differ (up to sign) by {err.max():.3g} > {atol}"


def _wrap(a, period=2 * np.pi):
    return (np.asarray(a) + period / 2) % period - period / 2


def _elem(axis: str, angle: float) -> np.ndarray:
    """Elementary rotation matrix (standard right-handed, column vectors), written out by hand."""
    c, s = math.cos(angle), math.sin(angle)
    return {
        "X": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "Y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "Z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis.upper()]


def _euler_reference(angles, order: str) -> np.ndarray:
    """Product of elementary matrices: intrinsic left to right, extrinsic right to left."""
    mats = [_elem(ax, a) for ax, a in zip(order, angles, strict=True)]
    if order.islower():
        mats = mats[::-1]
    out = np.eye(3)
    for m in mats:
        out = out @ m
    return out


def _random_quats(rng, shape):
    q = rng.normal(size=shape + (4,))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _random_unit(rng, shape):
    v = rng.normal(size=shape + (3,))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _sample_rotvecs(kind: str, shape: tuple[int, ...], seed: int = 0) -> np.ndarray:
    """Rotation vectors: 'uniform' angles in (0, pi), 'normal' components, 'singular' angles
    cycling through exactly 0, 1e-9, pi - 1e-9 and exactly pi."""
    rng = np.random.default_rng(seed)
    axis = _random_unit(rng, shape)
    if kind == "uniform":
        ang = rng.uniform(0, np.pi, shape)
    elif kind == "normal":
        return rng.normal(size=shape + (3,))
    else:
        ang = np.resize(np.array([0.0, 1e-9, np.pi - 1e-9, np.pi]), shape)
    return axis * ang[..., None]


def _is_rotation(R, atol, what):
    R = np.asarray(R)
    eye = np.broadcast_to(np.eye(3), R.shape)
    _close(np.swapaxes(R, -1, -2) @ R, eye, atol, f"{what}: R^T R != I")
    _close(np.linalg.det(R), np.ones(R.shape[:-2]), atol, f"{what}: det R != 1")


@functools.cache
def _refs() -> dict:
    from tests.conftest import shared_data_dir

    return json.loads((shared_data_dir() / "rotations" / "rotation_refs.json").read_text())


@pytest.fixture(scope="module")
def refs(shared_data):
    return _refs()


# ------------------------------------------------------------------------------------------------
# Stored scipy references (shared/data/rotations/rotation_refs.json)
# ------------------------------------------------------------------------------------------------

_REF_ORDERS = ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX", "xyz", "xzy", "yxz", "yzx", "zxy", "zyx", "XYX", "ZXZ"]


@pytest.mark.parametrize("order", _REF_ORDERS)
def test_refs_from_euler(refs, order):
    ang = np.array(refs["euler_deg"])
    ref = refs["from_euler"][order]
    R = rot.euler_to_matrix(ang, order, degrees=True)
    _close(R, ref["matrix"], _ATOL, f"euler_to_matrix {order}")
    q = rot.quat_canonical(rot.euler_to_quat(ang, order, degrees=True))
    _close(q, _xyzw_to_wxyz(ref["quat_xyzw"]), _ATOL, f"euler_to_quat {order}")
    # and back: the angles we return reproduce the matrix (the stored angles are not unique).
    for fn, arg in ((rot.matrix_to_euler, ref["matrix"]), (rot.quat_to_euler, _xyzw_to_wxyz(ref["quat_xyzw"]))):
        back = fn(np.array(arg), order, degrees=True)
        _close(rot.euler_to_matrix(back, order, degrees=True), ref["matrix"], 1e-9, f"{fn.__name__} {order}")


def test_refs_quaternion_conversions(refs):
    q = _xyzw_to_wxyz(refs["quat_xyzw"])
    _close(rot.quat_to_matrix(q), refs["quat_to_matrix"], _ATOL, "quat_to_matrix")
    _close(rot.quat_to_rotvec(q), refs["quat_to_rotvec"], _ATOL, "quat_to_rotvec")
    _close(
        rot.matrix_to_quat(np.array(refs["quat_to_matrix"])),
        _xyzw_to_wxyz(refs["matrix_to_quat_canonical_xyzw"]),
        _ATOL,
        "matrix_to_quat",
    )
    _close(
        rot.rotvec_to_quat(np.array(refs["rotvec"])),
        _xyzw_to_wxyz(refs["rotvec_to_quat_xyzw"]),
        _ATOL,
        "rotvec_to_quat",
    )
    for order, key in (("ZYX", "quat_to_euler_ZYX_deg"), ("xyz", "quat_to_euler_xyz_deg")):
        got = np.asarray(rot.quat_to_euler(q, order, degrees=True))
        _close(_wrap(got - np.array(refs[key]), 360.0), np.zeros_like(got), 1e-9, f"quat_to_euler {order}")
        got = np.asarray(rot.matrix_to_euler(np.array(refs["quat_to_matrix"]), order, degrees=True))
        _close(_wrap(got - np.array(refs[key]), 360.0), np.zeros_like(got), 1e-9, f"matrix_to_euler {order}")


def test_refs_compose_apply_slerp(refs):
    q = _xyzw_to_wxyz(refs["quat_xyzw"])
    a, b = q[:5], q[5:]
    _close_up_to_sign(rot.quat_multiply(a, b), _xyzw_to_wxyz(refs["compose_a_times_b_quat_xyzw"]), _ATOL, "compose")
    _close(rot.quat_apply(a, np.array(refs["apply_vectors"])), refs["apply_a_to_vectors"], _ATOL, "quat_apply")
    keys = _xyzw_to_wxyz(refs["slerp_keys_xyzw"])
    t = np.array(refs["slerp_t"])
    got = rot.slerp(keys[0], keys[1], t)
    _close_up_to_sign(got, _xyzw_to_wxyz(refs["slerp_quat_xyzw"]), 1e-12, "slerp")


def _scipy_case_ids():
    try:
        from tests.conftest import SHARED_DATA

        cases = json.loads((SHARED_DATA / "rotations" / "rotation_refs.json").read_text())["scipy_unit_test_cases"]
        return [f"{i}-{c['scipy_test']}" for i, c in enumerate(cases)]
    except OSError:
        return [f"{i}" for i in range(8)]


@pytest.mark.parametrize("index", range(8), ids=_scipy_case_ids())
def test_refs_scipy_unit_test_cases(refs, index):
    """The eight cases quoted from scipy's own test_rotation.py, with that test's tolerance."""
    case = refs["scipy_unit_test_cases"][index]
    atol = case["atol"] or 0.0
    kind = case["kind"]
    expected = np.array(case["expected"], dtype=float)
    if kind == "from_quat_as_matrix":
        got = rot.quat_to_matrix(_xyzw_to_wxyz(case["quat"]))  # unnormalized input
    elif kind == "from_matrix_as_quat":
        got = _wxyz_to_xyzw(rot.matrix_to_quat(np.array(case["matrix"])))
    elif kind == "from_rotvec_as_quat":
        got = _wxyz_to_xyzw(rot.rotvec_to_quat(np.array(case["rotvec"], dtype=float)))
    else:
        seq = case["seq"]
        ang = np.array(case["angles"], dtype=float).reshape(-1, len(seq))
        if kind == "from_euler_as_quat":
            got = _wxyz_to_xyzw(rot.euler_to_quat(ang, seq, degrees=case["degrees"]))
        else:
            got = rot.euler_to_matrix(ang, seq, degrees=case["degrees"])
        got = np.asarray(got).reshape(expected.shape)
    np.testing.assert_allclose(np.asarray(got), expected, rtol=1e-7, atol=atol, err_msg=case["scipy_test"])


# ------------------------------------------------------------------------------------------------
# scipy on random inputs: all 24 Euler conventions, both directions
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("order", ALL_ORDERS)
def test_euler_against_scipy(order):
    rng = np.random.default_rng(sum(map(ord, order)))
    ang = rng.uniform(-np.pi, np.pi, (_N, 3))
    r = Rotation.from_euler(order, ang)
    R, q = r.as_matrix(), _xyzw_to_wxyz(r.as_quat())
    _close(rot.euler_to_matrix(ang, order), R, _ATOL, f"euler_to_matrix {order}")
    _close_up_to_sign(rot.euler_to_quat(ang, order), q, _ATOL, f"euler_to_quat {order}")
    _close(rot.euler_to_matrix(np.degrees(ang), order, degrees=True), R, _ATOL, f"euler_to_matrix degrees {order}")
    expected = r.as_euler(order)
    for name, got in (
        ("matrix_to_euler", rot.matrix_to_euler(R, order)),
        ("quat_to_euler", rot.quat_to_euler(q, order)),
    ):
        got = np.asarray(got)
        _close(_wrap(got - expected), np.zeros_like(got), 1e-10, f"{name} {order} vs scipy")
        _close(rot.euler_to_matrix(got, order), R, 1e-12, f"{name} {order} round trip")
    got = np.asarray(rot.quat_to_euler(-q, order, degrees=True))  # sign-invariant
    _close(_wrap(got - np.degrees(expected), 360.0), np.zeros_like(got), 1e-8, f"quat_to_euler(-q) {order}")


@pytest.mark.parametrize("order", ["ZXY", "xyz", "ZXZ", "yxy"])
@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_matrix_to_euler_gimbal_lock(order, dtype):
    """At the singular middle angle the angles still reproduce the matrix, third angle 0, no NaN."""
    proper = order[0] == order[2]
    mids = [0.0, np.pi, 1e-9, np.pi - 1e-9] if proper else [np.pi / 2, -np.pi / 2, np.pi / 2 - 1e-9, -np.pi / 2 + 1e-9]
    rng = np.random.default_rng(1)
    ang = np.stack([rng.uniform(-3, 3, _N), np.resize(mids, _N), rng.uniform(-3, 3, _N)], axis=-1)
    R = rot.euler_to_matrix(jnp.asarray(ang, dtype), order)
    atol = 1e-6 if dtype == jnp.float32 else 1e-9
    for got in (rot.matrix_to_euler(R, order), rot.quat_to_euler(rot.matrix_to_quat(R), order)):
        assert got.dtype == dtype
        assert np.all(np.isfinite(np.asarray(got)))
        _close(rot.euler_to_matrix(got, order), R, atol, f"gimbal lock {order} reproduces R")
    if dtype == jnp.float64:
        exact = np.asarray(rot.matrix_to_euler(R, order))[:2]
        _close(exact[:, 2], np.zeros(2), 0.0, f"gimbal lock {order}: third angle")


_UNIT = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=20, deadline=None, derandomize=True)
@given(
    q=st.tuples(_UNIT, _UNIT, _UNIT, _UNIT).filter(lambda c: sum(x * x for x in c) > 1e-6),
    order=st.sampled_from(ALL_ORDERS),
)
def test_euler_round_trip_property(q, order):
    """Any quaternion (unnormalized, near-singular ones included) -> Euler -> same rotation."""
    q = np.array(q)
    R = np.asarray(rot.quat_to_matrix(q))
    ang = np.asarray(rot.quat_to_euler(q, order))
    assert np.all(np.isfinite(ang)) and np.all(np.abs(ang) <= np.pi)
    _close(rot.euler_to_matrix(ang, order), R, 1e-12, f"Euler round trip {order}")
    _close_up_to_sign(rot.euler_to_quat(ang, order), q / np.linalg.norm(q), 1e-12, f"euler_to_quat round trip {order}")


def test_euler_partial_and_repeated_orders():
    """Forward functions take 0 to 3 axes (BVH joints with 1 or 2 rotation channels), any axes."""
    rng = np.random.default_rng(2)
    for order in ["X", "Y", "Z", "ZX", "YZ", "XX", "XXY", "ZYY", "XYZ", "x", "zx", "yxx", "xyx"]:
        ang = rng.uniform(-np.pi, np.pi, (_N, len(order)))
        ref = np.stack([_euler_reference(a, order) for a in ang])
        _close(rot.euler_to_matrix(ang, order), ref, _ATOL, f"euler_to_matrix {order}")
        _close(rot.quat_to_matrix(rot.euler_to_quat(ang, order)), ref, _ATOL, f"euler_to_quat {order}")
    empty = np.zeros((2, 0))
    _close(rot.euler_to_matrix(empty, ""), np.broadcast_to(np.eye(3), (2, 3, 3)), 0.0, "order ''")
    _close(rot.euler_to_quat(empty, ""), np.array([[1.0, 0, 0, 0]] * 2), 0.0, "order ''")


def test_euler_worked_example_seed():
    """SEEDS 2.1 item 2: extrinsic x-y-z (10, 45, 90) is Rz(90) Ry(45) Rx(10); intrinsic XYZ is
    Rx(10) Ry(45) Rz(90); the two differ. Also the BVH convention ZXY = Rz Rx Ry."""
    a = np.radians([10.0, 45.0, 90.0])
    ext = rot.euler_to_matrix(np.degrees(a), "xyz", degrees=True)
    intr = rot.euler_to_matrix(a, "XYZ")
    _close(ext, _elem("Z", a[2]) @ _elem("Y", a[1]) @ _elem("X", a[0]), _ATOL, "extrinsic xyz")
    _close(intr, _elem("X", a[0]) @ _elem("Y", a[1]) @ _elem("Z", a[2]), _ATOL, "intrinsic XYZ")
    assert np.abs(np.asarray(ext) - np.asarray(intr)).max() > 0.1
    _close(rot.euler_to_matrix(a, "ZXY"), _elem("Z", a[0]) @ _elem("X", a[1]) @ _elem("Y", a[2]), _ATOL, "ZXY")


def test_euler_gimbal_lock_jacobian_rank():
    """SEEDS 2.1 item 4: at beta = 90 deg the Euler-to-matrix Jacobian has rank 2 (3 elsewhere)."""
    jac = jax.jacfwd(lambda a: rot.euler_to_matrix(a, "XYZ").reshape(9))
    locked = np.asarray(jac(jnp.array([0.3, np.pi / 2, -0.7])))
    free = np.asarray(jac(jnp.array([0.3, 0.4, -0.7])))
    assert np.linalg.matrix_rank(locked, tol=1e-9) == 2
    assert np.linalg.matrix_rank(free, tol=1e-9) == 3


# ------------------------------------------------------------------------------------------------
# Group properties on random and near-singular inputs
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["uniform", "normal", "singular"])
@pytest.mark.parametrize("shape", [(), (1,), (3, 2)])
def test_exp_log_round_trips(kind, shape):
    v = _sample_rotvecs(kind, shape, seed=len(shape))
    q = rot.rotvec_to_quat(v)
    R = rot.rotvec_to_matrix(v)
    assert q.shape == shape + (4,) and R.shape == shape + (3, 3)
    _close(jnp.linalg.norm(q, axis=-1), np.ones(shape), _ATOL, "|exp(v)| = 1")
    _is_rotation(R, 1e-12, "rotvec_to_matrix")
    _close(rot.quat_to_matrix(q), R, _ATOL, "quat_to_matrix(exp v) == Rodrigues(v)")
    # log(exp(v)) == v for |v| <= pi (at exactly pi the sign of the axis is ambiguous: compare R).
    theta = np.linalg.norm(v, axis=-1)
    inside = theta < np.pi - 1e-6
    v_back_q = np.asarray(rot.quat_to_rotvec(q))
    v_back_R = np.asarray(rot.matrix_to_rotvec(R))
    if kind != "normal":
        _close(v_back_q[inside], v[inside], _ATOL_SINGULAR, "log(exp(v)) == v (quat)")
        _close(v_back_R[inside], v[inside], _ATOL_SINGULAR, "log(exp(v)) == v (matrix)")
    for name, vb in (("quat", v_back_q), ("matrix", v_back_R)):
        assert np.all(np.linalg.norm(vb, axis=-1) <= np.pi + 1e-12), f"log ({name}) not shortest"
        _close(rot.rotvec_to_matrix(vb), R, _ATOL_SINGULAR, f"exp(log(R)) == R ({name})")
    # exp(log(q)) == q up to sign, for q and -q
    for sgn in (1.0, -1.0):
        _close_up_to_sign(rot.rotvec_to_quat(rot.quat_to_rotvec(sgn * np.asarray(q))), q, _ATOL_SINGULAR, "exp(log(q))")
    # axis-angle agrees with the rotation vector
    axis, angle = rot.quat_to_axis_angle(q)
    _close(np.asarray(axis) * np.asarray(angle)[..., None], v_back_q, _ATOL_SINGULAR, "axis * angle == log")
    _close_up_to_sign(rot.axis_angle_to_quat(axis, angle), q, _ATOL_SINGULAR, "axis_angle_to_quat")
    _close(rot.rotation_angle(q), np.linalg.norm(v_back_q, axis=-1), _ATOL_SINGULAR, "rotation_angle")


def test_log_shortest_for_both_signs():
    rng = np.random.default_rng(3)
    q = _random_quats(rng, (_N,))
    for sgn in (1.0, -1.0):
        v = np.asarray(rot.quat_to_rotvec(sgn * q))
        assert np.all(np.linalg.norm(v, axis=-1) <= np.pi + 1e-12)
        _close(v, Rotation.from_quat(_wxyz_to_xyzw(q)).as_rotvec(), _ATOL, f"log(sign={sgn} q) vs scipy")
    # an angle above pi in the rotation vector comes back as the shorter one
    v = np.array([0.0, 0.0, 1.5 * np.pi])
    _close(rot.quat_to_rotvec(rot.rotvec_to_quat(v)), np.array([0.0, 0.0, -0.5 * np.pi]), _ATOL, "wrap to [0, pi]")


@pytest.mark.parametrize("shape", [(), (3, 2)])
def test_composition_inverse_apply(shape):
    rng = np.random.default_rng(4)
    q1, q2 = _random_quats(rng, shape), _random_quats(rng, shape)
    R1, R2 = np.asarray(rot.quat_to_matrix(q1)), np.asarray(rot.quat_to_matrix(q2))
    _close(rot.quat_to_matrix(rot.quat_multiply(q1, q2)), R1 @ R2, _ATOL, "R(q1 q2) == R1 R2")
    q3 = _random_quats(rng, shape)
    _close(
        rot.quat_multiply(rot.quat_multiply(q1, q2), q3),
        rot.quat_multiply(q1, rot.quat_multiply(q2, q3)),
        _ATOL,
        "associativity",
    )
    ident = np.broadcast_to(np.array([1.0, 0, 0, 0]), shape + (4,))
    _close(rot.quat_multiply(q1, rot.quat_conjugate(q1)), ident, _ATOL, "q q* == 1")
    scaled = 3.0 * q1
    _close(rot.quat_multiply(scaled, rot.quat_inverse(scaled)), ident, _ATOL, "q q^-1 == 1 (non-unit)")
    _close(rot.quat_to_matrix(rot.quat_inverse(q1)), np.swapaxes(R1, -1, -2), _ATOL, "R(q^-1) == R^T")
    v = rng.normal(size=shape + (3,))
    _close(rot.quat_apply(q1, v), np.einsum("...ij,...j->...i", R1, v), _ATOL, "quat_apply == R v")
    _close(rot.quat_apply(scaled, v), np.einsum("...ij,...j->...i", R1, v), _ATOL, "quat_apply non-unit")
    _close(rot.quat_to_matrix(scaled), R1, _ATOL, "quat_to_matrix non-unit")
    _close(rot.matrix_to_quat(R1), rot.quat_canonical(q1), _ATOL, "matrix_to_quat(R(q)) == canonical q")
    _close(
        rot.quat_distance(q1, q2), rot.rotation_angle(rot.quat_multiply(rot.quat_conjugate(q1), q2)), _ATOL, "distance"
    )
    _close(rot.quat_distance(q1, -np.asarray(q2)), rot.quat_distance(q1, q2), _ATOL, "distance sign-invariant")
    cos = np.clip((np.trace(np.swapaxes(R1, -1, -2) @ R2, axis1=-2, axis2=-1) - 1) / 2, -1, 1)
    _close(rot.quat_distance(q1, q2), np.arccos(cos), 1e-9, "distance == angle of R1^T R2")


def test_matrix_to_quat_all_branches():
    """Shepperd: rotations where each of w, x, y, z is the largest component, and angle pi."""
    qs = np.array(
        [[0.9, 0.1, -0.3, 0.2], [0.1, -0.9, 0.3, 0.2], [-0.2, 0.1, 0.9, -0.3], [0.1, 0.2, -0.3, -0.9],
         [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [0.0, 0.6, 0.0, -0.8], [1.0, 0.0, 0.0, 0.0]]
    )  # fmt: skip
    qs = qs / np.linalg.norm(qs, axis=-1, keepdims=True)
    got = rot.matrix_to_quat(rot.quat_to_matrix(qs))
    _close(got, rot.quat_canonical(qs), _ATOL, "matrix_to_quat branches")
    _close(
        got, _xyzw_to_wxyz(Rotation.from_quat(_wxyz_to_xyzw(qs)).as_quat(canonical=True)), _ATOL, "vs scipy canonical"
    )


def test_quat_canonical_normalize_identity():
    q = np.array([[-1.0, 2, 0, 0], [0, -1, 2, 0], [0, 0, -3, 1], [0, 0, 0, -2], [0, 1, -1, 0], [0, 0, 0, 0]])
    expected = np.array([[1.0, -2, 0, 0], [0, 1, -2, 0], [0, 0, 3, -1], [0, 0, 0, 2], [0, 1, -1, 0], [0, 0, 0, 0]])
    _close(rot.quat_canonical(q), expected, 0.0, "quat_canonical")
    n = rot.quat_normalize(q)
    _close(n[-1], np.array([1.0, 0, 0, 0]), 0.0, "normalize(0) == identity")
    _close(jnp.linalg.norm(n, axis=-1), np.ones(6), _ATOL, "|normalize(q)| == 1")
    g = jax.jit(jax.jacfwd(rot.quat_normalize))(jnp.zeros(4))
    assert np.all(np.isfinite(np.asarray(g))), "normalize gradient at 0"
    zero = np.zeros(4)
    for fn in (
        rot.quat_inverse,
        rot.quat_to_rotvec,
        rot.rotation_angle,
        lambda z: rot.quat_to_axis_angle(z)[0],
        lambda z: rot.quat_to_euler(z, "ZXY"),
        lambda z: rot.slerp(z, z, 0.5),
        lambda z: rot.nlerp(z, z, 0.5),
    ):
        assert np.all(np.isfinite(np.asarray(fn(zero)))), "zero quaternion gives NaN"
    _close(rot.quat_to_matrix(np.zeros(4)), np.eye(3), 0.0, "quat_to_matrix(0) == I")
    assert rot.quat_identity().shape == (4,)
    ident = rot.quat_identity((2, 3), dtype=jnp.float32)
    assert ident.shape == (2, 3, 4) and ident.dtype == jnp.float32
    _close(ident[1, 2], np.array([1.0, 0, 0, 0]), 0.0, "quat_identity")
    assert rot.quat_identity(5).shape == (5, 4)


def test_skew():
    rng = np.random.default_rng(5)
    v, u = rng.normal(size=(_N, 3)), rng.normal(size=(_N, 3))
    S = np.asarray(rot.skew(v))
    _close(S, -np.swapaxes(S, -1, -2), 0.0, "skew antisymmetric")
    _close(np.einsum("...ij,...j->...i", S, u), np.cross(v, u), _ATOL, "skew(v) u == v x u")
    # Rodrigues against the series definition through the skew matrix (SEEDS 1.B)
    th = np.linalg.norm(v, axis=-1)[:, None, None]
    K = S / th
    ref = np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K
    _close(rot.rotvec_to_matrix(v), ref, _ATOL, "Rodrigues")


def test_sixd():
    rng = np.random.default_rng(6)
    R = np.asarray(rot.quat_to_matrix(_random_quats(rng, (_N,))))
    x = rot.matrix_to_sixd(R)
    assert x.shape == (_N, 6)
    _close(x, np.concatenate([R[..., :, 0], R[..., :, 1]], axis=-1), 0.0, "matrix_to_sixd")
    _close(rot.sixd_to_matrix(x), R, _ATOL, "sixd round trip")
    noisy = np.asarray(x) * 2.5 + 0.1 * rng.normal(size=(_N, 6))
    Rn = rot.sixd_to_matrix(noisy)
    _is_rotation(Rn, 1e-12, "sixd_to_matrix(noisy)")
    b1 = noisy[:, :3] / np.linalg.norm(noisy[:, :3], axis=-1, keepdims=True)
    _close(np.asarray(Rn)[..., :, 0], b1, _ATOL, "first column is a1 / |a1|")
    degenerate = np.array([[0.0, 0, 0, 0, 1, 0], [1.0, 2, 3, 2, 4, 6], [0.0, 0, 0, 0, 0, 0]])
    _is_rotation(rot.sixd_to_matrix(degenerate), 1e-12, "sixd_to_matrix(degenerate)")


def test_rotation_between():
    rng = np.random.default_rng(7)
    a, b = rng.normal(size=(8, 3)) * 3, rng.normal(size=(8, 3)) * 0.5
    q = rot.rotation_between(a, b)
    ua, ub = a / np.linalg.norm(a, axis=-1, keepdims=True), b / np.linalg.norm(b, axis=-1, keepdims=True)
    _close(rot.quat_apply(q, ua), ub, _ATOL, "rotation_between maps a to b")
    _close(rot.rotation_angle(q), np.arccos(np.clip(np.sum(ua * ub, -1), -1, 1)), 1e-9, "minimal angle")
    axis, _ = rot.quat_to_axis_angle(q)
    _close(np.sum(np.asarray(axis) * ua, -1), np.zeros(8), 1e-12, "axis perpendicular to a")
    # parallel, antiparallel (exact and within float error), zero vectors
    _close(rot.rotation_between(a[0], 2 * a[0]), np.array([1.0, 0, 0, 0]), _ATOL, "parallel")
    for target in (-a[0], -0.3 * a[0], -a[0] + 1e-12):
        qa = np.asarray(rot.rotation_between(a[0], target))
        assert np.all(np.isfinite(qa))
        _close(rot.rotation_angle(qa), np.pi, 1e-7, "antiparallel: rotation by pi")
        _close(rot.quat_apply(qa, ua[0]), -ua[0], 1e-7, "antiparallel: maps a to -a")
    for e in np.eye(3):
        _close(rot.quat_apply(rot.rotation_between(e, -e), e), -e, _ATOL, "antiparallel axes")
    _close(rot.rotation_between(np.zeros(3), b[0]), np.array([1.0, 0, 0, 0]), 0.0, "zero vector")
    jac = jax.jit(jax.jacfwd(rot.rotation_between, argnums=(0, 1)))
    for target, what in ((b[1], "generic"), (a[1], "a == b"), (-b[1], "a == -b")):
        g = jac(jnp.asarray(b[1]), jnp.asarray(target))
        assert all(np.all(np.isfinite(np.asarray(x))) for x in g), f"rotation_between gradient ({what})"


# ------------------------------------------------------------------------------------------------
# vmap, jit, broadcasting, dtypes, input checks
# ------------------------------------------------------------------------------------------------


def test_vmap_equals_loop():
    rng = np.random.default_rng(9)
    q0, q1 = jnp.asarray(_random_quats(rng, (_N,))), jnp.asarray(_random_quats(rng, (_N,)))
    ang = jnp.asarray(rng.uniform(-3, 3, (_N, 3)))
    t = jnp.asarray(rng.uniform(0, 1, _N))
    a, b = jnp.asarray(rng.normal(size=(_N, 3))), jnp.asarray(rng.normal(size=(_N, 3)))
    cases = [
        ("quat_multiply", rot.quat_multiply, (q0, q1)),
        ("euler_to_matrix", lambda x: rot.euler_to_matrix(x, "ZXY"), (ang,)),
        ("matrix_to_euler", lambda R: rot.matrix_to_euler(R, "zyz"), (rot.quat_to_matrix(q0),)),
        ("quat_to_rotvec", rot.quat_to_rotvec, (q0,)),
        ("slerp", rot.slerp, (q0, q1, t)),
        ("rotation_between", rot.rotation_between, (a, b)),
        ("sixd_to_matrix", rot.sixd_to_matrix, (jnp.concatenate([a, b], -1),)),
    ]
    for name, fn, args in cases:
        batched = jax.jit(jax.vmap(fn))(*args)
        loop = jnp.stack([fn(*(x[i] for x in args)) for i in range(_N)])
        _close(batched, loop, 1e-13, f"vmap {name}")


def test_jit_with_static_order():
    f = jax.jit(rot.euler_to_matrix, static_argnames=("order", "degrees"))
    ang = jnp.array([[10.0, 20.0, 30.0]])
    _close(f(ang, "ZXY", degrees=True), rot.euler_to_matrix(ang, "ZXY", degrees=True), _ATOL, "jit euler_to_matrix")
    g = jax.jit(rot.matrix_to_euler, static_argnames=("order",))
    R = f(ang, "ZXY", degrees=True)
    _close(g(R, "ZXY"), np.radians(ang), _ATOL, "jit matrix_to_euler")


def test_broadcasting():
    rng = np.random.default_rng(10)
    q = _random_quats(rng, (2, 1))
    p = _random_quats(rng, (3,))
    out = rot.quat_multiply(q, p)
    assert out.shape == (2, 3, 4)
    _close(out[1, 2], rot.quat_multiply(q[1, 0], p[2]), _ATOL, "broadcast quat_multiply")
    v = rng.normal(size=(5, 3))
    assert rot.quat_apply(q[0, 0], v).shape == (5, 3)
    assert rot.axis_angle_to_quat(np.array([0.0, 0, 1]), np.array([0.1, 0.2])).shape == (2, 4)
    assert rot.slerp(q, p, 0.5).shape == (2, 3, 4)
    with pytest.raises(JaxanimError, match="q1, q2: batch shapes do not broadcast"):
        rot.quat_multiply(_random_quats(rng, (2,)), _random_quats(rng, (3,)))


_BAD_SHAPES = [
    (rot.quat_multiply, (np.zeros(3), np.zeros(4)), r"q1: expected shape \(\.\.\., 4,?\), got \(3,\)"),
    (rot.quat_multiply, (np.zeros(4), np.zeros((2, 5))), r"q2: expected shape \(\.\.\., 4,?\), got \(2, 5\)"),
    (rot.quat_conjugate, (np.zeros(3),), r"q: expected shape \(\.\.\., 4,?\), got \(3,\)"),
    (rot.quat_inverse, (np.zeros(5),), r"q: expected shape"),
    (rot.quat_apply, (np.zeros(4), np.zeros(4)), r"v: expected shape \(\.\.\., 3,?\), got \(4,\)"),
    (rot.quat_normalize, (np.zeros(()),), r"q: expected shape \(\.\.\., 4,?\), got \(\)"),
    (rot.quat_canonical, (np.zeros((4, 3)),), r"q: expected shape"),
    (rot.quat_to_matrix, (np.zeros((3, 3)),), r"q: expected shape \(\.\.\., 4,?\), got \(3, 3\)"),
    (rot.matrix_to_quat, (np.zeros(4),), r"R: expected shape \(\.\.\., 3, 3\), got \(4,\)"),
    (rot.matrix_to_rotvec, (np.zeros((3, 4)),), r"R: expected shape \(\.\.\., 3, 3\)"),
    (rot.rotvec_to_quat, (np.zeros(4),), r"v: expected shape \(\.\.\., 3,?\), got \(4,\)"),
    (rot.rotvec_to_matrix, (np.zeros(2),), r"v: expected shape"),
    (rot.quat_to_rotvec, (np.zeros(3),), r"q: expected shape"),
    (rot.axis_angle_to_quat, (np.zeros(4), 0.1), r"axis: expected shape \(\.\.\., 3,?\)"),
    (rot.quat_to_axis_angle, (np.zeros(3),), r"q: expected shape"),
    (rot.slerp, (np.zeros(4), np.zeros(3), 0.5), r"q1: expected shape"),
    (rot.nlerp, (np.zeros(3), np.zeros(4), 0.5), r"q0: expected shape"),
    (rot.rotation_between, (np.zeros(3), np.zeros(2)), r"b: expected shape \(\.\.\., 3,?\), got \(2,\)"),
    (rot.matrix_to_sixd, (np.zeros((2, 3)),), r"R: expected shape"),
    (rot.sixd_to_matrix, (np.zeros(9),), r"x: expected shape \(\.\.\., 6,?\), got \(9,\)"),
    (rot.skew, (np.zeros(4),), r"v: expected shape"),
    (rot.rotation_angle, (np.zeros(3),), r"q: expected shape"),
    (rot.quat_distance, (np.zeros(4), np.zeros(3)), r"q1: expected shape"),
    (lambda a: rot.euler_to_matrix(a, "ZXY"), (np.zeros(2),), r"angles: expected shape \(\.\.\., 3,?\), got \(2,\)"),
    (lambda a: rot.euler_to_quat(a, "ZX"), (np.zeros(3),), r"angles: expected shape \(\.\.\., 2,?\), got \(3,\)"),
    (lambda q: rot.quat_to_euler(q, "ZXY"), (np.zeros(3),), r"q: expected shape"),
    (lambda R: rot.matrix_to_euler(R, "ZXY"), (np.zeros(9),), r"R: expected shape"),
    (rot.quat_to_matrix, ([[1.0, 0, 0, 0], [1.0, 0]],), r"q: expected an array"),
    (rot.quat_to_matrix, (np.zeros(4, dtype=complex),), r"q: expected a real floating-point array"),
]


@pytest.mark.parametrize("fn,args,match", _BAD_SHAPES, ids=[f"{i}" for i in range(len(_BAD_SHAPES))])
def test_wrong_shapes_raise(fn, args, match):
    with pytest.raises(JaxanimError, match=match):
        fn(*args)


@pytest.mark.parametrize(
    "fn,order,match",
    [
        (rot.euler_to_matrix, "XYZX", "order: expected 0 to 3 axes"),
        (rot.euler_to_quat, "XyZ", "order: expected axes all from"),
        (rot.euler_to_matrix, "abc", "order: expected axes all from"),
        (rot.euler_to_quat, 3, "order: expected a string"),
        (rot.matrix_to_euler, "ZX", "order: expected exactly 3 axes"),
        (rot.matrix_to_euler, "ZZX", "order: consecutive axes must differ"),
        (rot.quat_to_euler, "xyy", "order: consecutive axes must differ"),
        (rot.quat_to_euler, "XYW", "order: expected axes all from"),
    ],
)
def test_invalid_order_raises(fn, order, match):
    arg = {rot.matrix_to_euler: np.eye(3), rot.quat_to_euler: np.array([1.0, 0, 0, 0])}.get(fn, np.zeros(3))
    with pytest.raises(JaxanimError, match=match):
        fn(arg, order)


def test_inputs_not_modified():
    rng = np.random.default_rng(12)
    q, p = -np.abs(_random_quats(rng, (_N,))), _random_quats(rng, (_N,))  # w < 0: canonical flips
    v, ang = rng.normal(size=(_N, 3)), rng.uniform(-3, 3, (_N, 3))
    R = np.asarray(rot.quat_to_matrix(p))
    inputs = [q, p, v, ang, R]
    copies = [x.copy() for x in inputs]
    rot.quat_canonical(q)
    rot.quat_normalize(q)
    rot.quat_to_rotvec(q)
    rot.quat_to_axis_angle(q)
    rot.slerp(q, p, 0.5)
    rot.quat_apply(q, v)
    rot.euler_to_matrix(ang, "zyx", degrees=True)
    rot.matrix_to_euler(R, "XYX")
    rot.matrix_to_quat(R)
    rot.rotation_between(v, ang)
    rot.sixd_to_matrix(np.concatenate([v, ang], -1))
    for x, c in zip(inputs, copies, strict=True):
        np.testing.assert_array_equal(x, c)


def test_angle_between_matrices_against_scipy_at_every_angle():
    """The solvers' final checks' angle of ``R G^T`` (atan2 of the skew part and the trace) equals the angle of
    the rotation scipy built, from 1e-9 rad to pi (an arccos of the trace would lose half the digits at 1e-9)."""
    rng = np.random.default_rng(3)
    angles = np.array([1e-9, 1e-6, 1e-3, 0.5, 2.0, np.pi - 1e-3, np.pi - 1e-7])
    axes = rng.normal(size=(angles.size, 3))
    d = Rotation.from_rotvec(axes / np.linalg.norm(axes, axis=1, keepdims=True) * angles[:, None])
    G = Rotation.random(angles.size, random_state=4)
    R = d * G  # R G^-1 = d
    got = jax.jit(angle_between_matrices)(jnp.asarray(R.as_matrix()), jnp.asarray(G.as_matrix()))
    np.testing.assert_allclose(np.asarray(got), angles, rtol=0, atol=4e-15)
