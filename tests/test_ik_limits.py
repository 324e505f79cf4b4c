"""Joint limits: the limit coordinates, the violation measure, hard and soft limits in IK."""

from __future__ import annotations

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize
from scipy.spatial.transform import Rotation

import jaxanim
import solvers
from jaxanim import ik
from jaxanim.ik import _problem
from jaxanim import rotations as rot
from jaxanim.limits import EulerLimit, SwingTwistLimit, limit_charts

from .conftest import shared_data_dir
from .helpers import jitted_fk, jitted_limit_violation, random_pose, shared_clip, small_skeleton

_VIOLATION_ATOL = 1e-12  # hard limits hold exactly up to round-off of the quaternion <-> chart maps


def _chart(skel, lim, hard):
    j = skel.index(lim.joint)
    (group,) = limit_charts(skel, [lim], [j], [0], hard, jnp.float64)
    return jax.tree.map(lambda x: x[0], group.chart)


_LIMITS = [
    EulerLimit("arm", [-40, -30, -20], [50, 60, 70], "ZXY", degrees=True),
    EulerLimit("arm", [-40, -30, -20], [50, 60, 70], "xzx", degrees=True),
    SwingTwistLimit("arm", [40, 25], [-30, 60], degrees=True),
]


@pytest.mark.parametrize("hard", [True, False])
@pytest.mark.parametrize("lim", _LIMITS, ids=["euler", "proper-extrinsic", "swing-twist"])
def test_chart_round_trip_and_rotation_columns(lim, hard):
    """``from_quat(quat(theta)) == theta`` inside the box, and ``E`` = finite differences of ``R``."""
    skel = small_skeleton()
    chart = _chart(skel, lim, hard)
    lo, hi = (np.asarray(b) for b in chart.bounds()) if hard or chart.kind == "euler" else (None, None)
    rng = np.random.default_rng(0)
    from jaxanim.limits import _omega_columns

    for _ in range(5):
        if lo is not None:
            theta = jnp.asarray(lo + (hi - lo) * rng.uniform(0.05, 0.95, 3))
        else:
            theta = jnp.asarray(rng.uniform(-0.3, 0.3, 3))
        q = chart.quat(theta)
        np.testing.assert_allclose(chart.from_quat(q), theta, atol=1e-12)
        _, E = _omega_columns(chart, theta)
        R = np.asarray(rot.quat_to_matrix(q))
        h = 1e-6
        for k in range(3):
            dR = (np.asarray(rot.quat_to_matrix(chart.quat(theta.at[k].add(h))))
                  - np.asarray(rot.quat_to_matrix(chart.quat(theta.at[k].add(-h))))) / (2 * h)
            W = dR @ R.T  # skew(omega_k)
            np.testing.assert_allclose([W[2, 1], W[0, 2], W[1, 0]], E[:, k], atol=1e-8)


def test_euler_violation_matches_scipy():
    """The violation of an Euler box is the smallest over both Euler branches scipy reports."""
    skel = small_skeleton()
    lower, upper = np.radians([-40, -100, -20]), np.radians([50, 120, 70])
    lim = EulerLimit("arm", lower, upper, "ZXY")
    rng = np.random.default_rng(1)
    violation = jitted_limit_violation(skel)
    for _ in range(20):
        q, _ = random_pose(skel, int(rng.integers(1 << 30)))
        a = Rotation.from_quat(np.roll(np.asarray(q[3]), -1)).as_euler("ZXY")
        b = np.array([a[0] + np.pi, np.pi - a[1], a[2] + np.pi])
        best = np.inf
        for cand in (a, b):
            c = 0.5 * (lower + upper)
            cand = c + (cand - c + np.pi) % (2 * np.pi) - np.pi
            best = min(best, np.max(np.maximum(np.maximum(cand - upper, lower - cand), 0)))
        np.testing.assert_allclose(violation(lim, q)[0], best, atol=1e-12)


def test_swing_twist_violation_matches_geometry():
    """Circular cone: swing = angle between the axis and its image; twist = what is left about it."""
    skel = small_skeleton()
    axis = np.array([0.2, -0.4, 0.9]) / np.linalg.norm([0.2, -0.4, 0.9])
    cone, twist = 0.5, (-0.3, 0.4)
    lim = SwingTwistLimit("arm", cone, twist, axis=axis)
    rng = np.random.default_rng(2)
    violation = jitted_limit_violation(skel)
    for _ in range(20):
        q, _ = random_pose(skel, int(rng.integers(1 << 30)))
        R = Rotation.from_quat(np.roll(np.asarray(q[3]), -1))
        image = R.apply(axis)
        swing = math.acos(np.clip(axis @ image, -1, 1))
        Rs = Rotation.from_rotvec(np.cross(axis, image) / np.linalg.norm(np.cross(axis, image)) * swing)
        tau = (Rs.inv() * R).as_rotvec() @ axis
        expected = max(swing - cone, 0, tau - twist[1], twist[0] - tau)
        np.testing.assert_allclose(violation(lim, q)[0], expected, atol=1e-10)


def _setup(skel, targets, q, t, *, limits=(), root_translation="free", frozen=(), regularization=1e-3):
    """The residual ``(fn, jac)``, ``y0``, ``bounds`` and pose map that solve_ik builds (hard limits).

    The setup is one compiled program, and the residual, Jacobian and pose another (eager, each op
    of the setup and of the pose map would compile on its own: seconds)."""
    layout = _problem._layout(skel, targets, None, frozen, root_translation, limits, "hard")
    reg_w = jnp.full(skel.num_joints, regularization)
    # ``skel`` a constant: a swing-twist limit without an axis takes it from the concrete offsets
    data, y0, bounds = eqx.filter_jit(functools.partial(_problem._setup, skel))(
        layout, targets, q, t, q, t, reg_w, limits, 1.0)
    every = jax.jit(lambda y, data: (_problem._residual(y, data), _problem._pose(y, data)))
    return dict(fn=lambda y: every(y, data)[0][0], jac=lambda y: every(y, data)[0][1], y0=y0, bounds=bounds,
                pose=lambda y: every(y, data)[1])


@pytest.fixture(scope="module")
def limited_problem():
    """Position and orientation of forearm_End made by a pose just outside the arm's and forearm's
    limits: the constrained optimum lies on the limits, close to the start."""
    skel = small_skeleton()
    q, t = random_pose(skel, 3)
    limits = (EulerLimit("arm", [-0.3, -0.2, -0.4], [0.3, 0.5, 0.4], "ZXY"),
              SwingTwistLimit("forearm", 0.4, (-0.2, 0.2)))
    q_goal = q.at[3].set(rot.euler_to_quat(jnp.asarray([0.45, 0.6, 0.1]), "ZXY"))
    q_goal = q_goal.at[4].set(rot.rotvec_to_quat(jnp.asarray([0.1, 0.5, 0.3])))
    out = jitted_fk(skel, q_goal, t)
    targets = (ik.Target("forearm_End", out.end_site_positions[1], rot.matrix_to_quat(out.rotations[4]), weight=1.0),)
    kw = dict(limits=limits, root_translation="fixed", frozen=("leg", "spine", "head", "root"))
    # the hard-limit and the unlimited solutions, shared by the tests (each solve_ik call compiles)
    hard = ik.solve_ik(skel, targets, q, t, regularization=1e-3, **kw)
    free = ik.solve_ik(skel, targets, q, t, regularization=1e-3, **{**kw, "limits": ()})
    return skel, targets, q, t, kw, hard, free


def test_hard_limits_reach_the_bounded_optimum_of_scipy(limited_problem):
    """The constrained optimum equals scipy's bounded trust-region solver on the same residual."""
    skel, targets, q, t, kw, sol, free = limited_problem
    assert sol.result == solvers.RESULTS.successful
    assert not bool(sol.success)  # the goal is out of reach within the limits
    violation = jitted_limit_violation(skel)
    v = violation(kw["limits"], sol.rotations)
    assert float(jnp.max(v)) <= _VIOLATION_ATOL
    problem = _setup(skel, targets, q, t, **kw)
    lo, hi = (np.asarray(b) for b in problem["bounds"])
    ref = scipy.optimize.least_squares(
        lambda y: np.asarray(problem["fn"](jnp.asarray(y))), np.asarray(problem["y0"]),
        jac=lambda y: np.asarray(problem["jac"](jnp.asarray(y))), bounds=(lo, hi),
        method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-15,
    )
    np.testing.assert_allclose(sol.stats["cost"], ref.cost, rtol=1e-8)
    q_ref, _ = problem["pose"](jnp.asarray(ref.x))
    assert float(jnp.max(rot.quat_distance(sol.rotations, q_ref))) < 1e-6
    # some limit is active: without limits the cost is lower and the limits are broken
    assert float(free.stats["cost"]) < ref.cost - 1e-6
    assert float(jnp.max(violation(kw["limits"], free.rotations))) > 1e-3


def test_soft_limits_approach_the_hard_solution(limited_problem):
    skel, targets, q, t, kw, hard, free = limited_problem

    def soft(w):
        return ik.solve_ik(skel, targets, q, t, regularization=1e-3, limit_mode="soft", limit_weight=w, **kw)

    sols = jax.jit(jax.vmap(soft))(jnp.asarray([0.0, 1e2, 1e4]))  # one program (eager vmap: op by op)
    viol = jnp.max(jitted_limit_violation(skel, batched=True)(kw["limits"], sols.rotations), axis=-1)
    assert np.all(np.diff(np.asarray(viol)) < 0), viol  # stiffer penalty, smaller violation
    assert float(viol[-1]) < 1e-4  # ~1/weight: 1.5e-5 here
    assert float(jnp.max(rot.quat_distance(sols.rotations[-1], hard.rotations))) < 1e-4
    np.testing.assert_allclose(sols.stats["cost"][0], free.stats["cost"], rtol=1e-8)


def test_hard_euler_limits_on_cmu_batch():
    """Targets from random poses inside +-45 deg boxes: met to 1e-6 under those limits (vmap), and
    never a violation; tighter +-20 deg boxes: no violation on any result."""
    shared_data_dir()
    skel, _, _ = shared_clip("cmu_01_01_trim300")
    from .test_ik import EFFECTORS, _random_targets

    batch = jax.tree.map(lambda *x: jnp.stack(x), *[_random_targets(skel, s) for s in range(4)])
    q0 = skel.rest_rotations()

    def boxes(half_width):
        return tuple(EulerLimit(n, -half_width * jnp.ones(3), half_width * jnp.ones(3), "ZYX")
                     for n in skel.names[1:])

    def solve(tg, half_width):
        return ik.solve_ik(skel, tg, q0, None, limits=boxes(half_width), regularization=0.0,
                           solver=solvers.LevenbergMarquardt(max_steps=300),
                           position_tolerance=1e-9, orientation_tolerance=1e-9)

    f = jax.jit(jax.vmap(solve, in_axes=(0, None)))
    violation = jitted_limit_violation(skel, batched=True)
    # both widths NumPy float64: one compile (a Python float is weakly typed, np.float64 is not, and
    # each would compile the solve on its own)
    for width, reachable in ((np.radians(45.0), True), (np.radians(20.0), False)):
        sol = f(batch, width)
        limits = boxes(width)
        v = violation(limits, sol.rotations)
        assert float(jnp.max(v)) <= _VIOLATION_ATOL
        assert bool(jnp.all(jnp.isfinite(sol.rotations)))
        if reachable:
            assert float(jnp.max(sol.position_errors)) < 1e-6, sol.position_errors
            assert float(jnp.max(sol.orientation_errors)) < 1e-6
    assert len(EFFECTORS) == 5


def test_frozen_joint_ignores_its_limit_and_bad_limits_are_reported():
    skel = small_skeleton()
    q, t = random_pose(skel, 5)
    goal = jnp.asarray([1.0, 2.0, 3.0])
    sol = ik.solve_ik(skel, ik.Target("forearm_End", goal), q, t, frozen=("arm",),
                      limits=(EulerLimit("arm", [0, 0, 0], [0.01, 0.01, 0.01], "XYZ"),))
    np.testing.assert_allclose(jnp.abs(jnp.sum(sol.rotations[3] * q[3])), 1.0, atol=1e-12)
    tg = ik.Target("forearm_End", goal)
    with pytest.raises(jaxanim.JaxanimError, match="unknown joint 'elbow'"):
        ik.solve_ik(skel, tg, q, t, limits=(EulerLimit("elbow", [0, 0, 0], [1, 1, 1]),))
    with pytest.raises(jaxanim.JaxanimError, match="expected lower <= upper"):
        EulerLimit("arm", [0, 0, 0], [1, -1, 1])
    with pytest.raises(jaxanim.JaxanimError, match=r"limits\['arm'\].lower: expected shape \(3,\)"):
        EulerLimit("arm", [0, 0], [1, 1, 1])
    with pytest.raises(jaxanim.JaxanimError, match="more than one limit"):
        ik.solve_ik(skel, tg, q, t, limits=(SwingTwistLimit("arm", 0.5), SwingTwistLimit("arm", 0.5)))
    with pytest.raises(jaxanim.JaxanimError, match="no child bone"):  # 'leg' is a leaf without End Site
        ik.solve_ik(skel, tg, q, t, limits=(SwingTwistLimit("leg", 0.5),))
    with pytest.raises(jaxanim.JaxanimError, match="limit_mode: expected 'hard' or 'soft'"):
        ik.solve_ik(skel, tg, q, t, limits=(SwingTwistLimit("arm", 0.5),), limit_mode="stiff")
    with pytest.raises(ValueError, match="bounds: not supported by OptimistixSolver"):
        import optimistix as optx

        ik.solve_ik(skel, tg, q, t, limits=(SwingTwistLimit("arm", 0.5),),
                    solver=solvers.OptimistixSolver(optx.LevenbergMarquardt(1e-8, 1e-8)))
