"""Inverse kinematics: exact Jacobian of the IK coordinates, reachable targets, pins, frozen joints."""

from __future__ import annotations

import contextlib
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import jaxanim
import solvers
from jaxanim import ik
from jaxanim.ik import _problem as ik_impl
from jaxanim import rotations as rot

from .conftest import shared_data_dir
from .helpers import (assert_close, jitted_limit_violation, numpy_fk, random_pose, random_site_targets,
                      scipy_rotation, shared_clip, small_skeleton, wxyz)
from .helpers import jitted_fk as _fk

_TOL_REACH = 1e-6


@eqx.filter_jit
def _residual_jacobians(skel, layout, targets, q, t, pin_ref, y, reg_w):
    """The IK residual at ``y``, its analytic Jacobian and forward-mode autodiff's of the residual.

    One module-level program per problem structure: the Jacobian test and the scipy test (same
    structure) share it, and each structure compiles once instead of twice (residual-and-Jacobian,
    then ``jacfwd``: 0.75 s + 1.3 s before)."""

    def residual(z):
        return ik_impl._residual_and_jacobian(skel, layout, targets, q, t, pin_ref, z, reg_w)[0]

    r, Jac, _ = ik_impl._residual_and_jacobian(skel, layout, targets, q, t, pin_ref, y, reg_w)
    return r, Jac, jax.jacfwd(residual)(y)


def _problem_fns(skel, targets, q, t, **kw):
    """``(y -> (r, J, J_autodiff), n)`` of the IK residual with ``regularization=1e-3``."""
    layout = ik_impl._layout(skel, targets, kw.get("pin"), kw.get("frozen", ()), kw.get("root_translation", "free"))
    pin_ref = None
    if layout.pin_idx is not None:
        out = _fk(skel, q, t)
        pin_ref = np.concatenate([np.asarray(out.positions), np.asarray(out.end_site_positions)])[layout.pin_idx]
    reg_w = jnp.full(skel.num_joints, 1e-3)
    n = (3 if layout.free_root else 0) + 3 * len(layout.free_joints)
    return functools.partial(_residual_jacobians, skel, layout, tuple(targets), q, t, pin_ref, reg_w=reg_w), n


@pytest.mark.parametrize("kw", [{}, {"pin": "leg"}, {"frozen": ("arm",), "root_translation": "fixed"}])
def test_ik_jacobian_is_exact(kw):
    skel = small_skeleton()
    q, t = random_pose(skel, 0)
    q2, t2 = random_pose(skel, 1)
    goal = _fk(skel, q2, t2)
    targets = (
        ik.Target("forearm_End", goal.end_site_positions[1], rot.matrix_to_quat(goal.rotations[4]), 2.0),
        ik.Target("head_End", position=goal.end_site_positions[0]),
    )
    fns, n = _problem_fns(skel, targets, q, t, **kw)
    y = jnp.asarray(np.random.default_rng(3).normal(size=n) * 0.3)
    r, Jac, auto = fns(y)
    assert_close("jacobian", Jac, auto, atol=1e-10)


@functools.lru_cache(maxsize=None)
def _cmu():
    skel, motion, _ = shared_clip("cmu_01_01_trim300")
    return skel, motion


EFFECTORS = ("LeftHand", "RightHand", "LeftToeBase_End", "RightToeBase_End", "Head_End")


def _random_targets(skel, seed):
    """Targets from FK of a random pose within +-45 deg of the rest pose, root rotated freely (numpy and scipy:
    a jitted pose-and-FK function compiled 1 s, here and in tests/test_ik_limits.py)."""
    return random_site_targets(skel, seed, EFFECTORS)


def test_reachable_targets_on_cmu_skeleton():
    shared_data_dir()
    skel, _ = _cmu()
    targets = _random_targets(skel, 0)
    q0 = skel.rest_rotations()
    sol = ik.solve_ik(skel, targets, q0, None, regularization=0.0, solver=solvers.LevenbergMarquardt(max_steps=200),
                      position_tolerance=1e-9, orientation_tolerance=1e-9)
    assert sol.result == solvers.RESULTS.successful, solvers.RESULTS[sol.result]
    assert float(jnp.max(sol.position_errors)) < _TOL_REACH
    assert float(jnp.max(sol.orientation_errors)) < _TOL_REACH


#: the options of the small-skeleton problems solved by ``solve_ik`` and ``solve_ik_clip`` in several tests
#: (pins, frozen joints, vmap against a loop, retracing, ``IKOptions``, a NaN target): one compiled solve
#: and one compiled 3-frame clip solve between them (each further structure compiles 1.4 to 2.3 s)
_PIN_FROZEN = dict(pin="head_End", frozen=("leg",))


def _three_frames(q, t):
    """A 3-frame clip of one pose: ``solve_ik_clip`` on it is ``solve_ik`` vmapped over three problems."""
    return jaxanim.Motion(jnp.stack([q, q, q]), jnp.stack([t, t, t]), 1 / 30)


def test_pin_frozen_and_vmap_equals_loop():
    """``solve_ik_clip`` (``solve_ik`` under ``vmap``, in one program) equals a loop of ``solve_ik``."""
    skel = small_skeleton()
    q, t = random_pose(skel, 4)
    base = _fk(skel, q, t)
    # reachable goals near the hand (an unreachable one leaves LM crawling to max_steps, and two
    # unconverged iterates need not agree to rounding)
    goals = [base.end_site_positions[1] + jnp.asarray(d) for d in ([0.1, 0, 0.05], [0, -0.1, 0.1], [0.05, 0.05, -0.1])]
    _, batched = ik.solve_ik_clip(skel, _three_frames(q, t), ik.Target("forearm_End", jnp.stack(goals)), **_PIN_FROZEN)
    assert bool(jnp.all(batched.success)), batched.result  # converged, every target met
    for i, g in enumerate(goals):
        one = ik.solve_ik(skel, ik.Target("forearm_End", g), q, t, **_PIN_FROZEN)
        # same problem, same solver, same iterates: equal up to rounding (fusion changes it)
        assert int(one.stats["num_steps"]) == int(batched.stats["num_steps"][i])
        assert_close("rotations", batched.rotations[i], one.rotations, atol=1e-8)
        out = _fk(skel, one.rotations, one.translations)
        assert_close("pinned head_End", out.end_site_positions[0], base.end_site_positions[0], atol=1e-9)
        assert_close("frozen leg", jnp.abs(jnp.sum(one.rotations[5] * q[5])), 1.0, atol=1e-12)


def test_bad_input():
    skel = small_skeleton()
    q, t = random_pose(skel, 8)
    with pytest.raises(jaxanim.JaxanimError, match="unknown joint or End Site 'hand'; valid:"):
        ik.solve_ik(skel, ik.Target("hand", jnp.zeros(3)), q, t)
    with pytest.raises(jaxanim.JaxanimError, match=r"targets\['leg'\].position: expected shape \(\.\.\., 3\), got \(2,\)"):
        ik.Target("leg", jnp.zeros(2))
    with pytest.raises(jaxanim.JaxanimError, match="unknown joint 'tail'"):
        ik.solve_ik(skel, ik.Target("leg", jnp.zeros(3)), q, t, frozen=("tail",))
    with pytest.raises(jaxanim.JaxanimError, match="root_translation: expected 'free' or 'fixed'"):
        ik.solve_ik(skel, ik.Target("leg", jnp.zeros(3)), q, t, root_translation="loose")


def _height(skel):
    _, p, ends = numpy_fk(skel, skel.rest_rotations(), skel.offsets)
    y = np.concatenate([p, ends])[:, 1]
    return float(y.max() - y.min())


def _position_tolerance(skel):
    """solve_ik's default position tolerance: 1e-5 x the sum of |offsets| (the README's claim)."""
    return 1e-5 * float(np.abs(np.asarray(skel.offsets)).sum())


def test_games105_single_frame_tasks():
    """Fixed root; left toe pinned; both hands with the left toe pinned (CMU skeleton, its units)."""
    shared_data_dir()
    skel, motion = _cmu()
    h = _height(skel)
    q, t = motion.rotations[100], motion.translations[100]
    _, p, ends = numpy_fk(skel, q, t)
    goal_l = p[skel.index("LeftHand")] + np.array([0.1, 0.05, 0.1]) * h
    goal_r = p[skel.index("RightHand")] + np.array([-0.05, 0.1, 0.05]) * h
    cases = [
        dict(targets=(ik.Target("LeftHand", goal_l),), root_translation="fixed", frozen=("Hips",)),
        dict(targets=(ik.Target("LeftHand", goal_l),), pin="LeftToeBase_End"),
        dict(targets=(ik.Target("LeftHand", goal_l), ik.Target("RightHand", goal_r)), pin="LeftToeBase_End"),
    ]
    toe = ends[skel.end_site_names.index("LeftToeBase_End")]
    tol = _position_tolerance(skel)
    for case in cases:
        targets = case.pop("targets")
        sol = ik.solve_ik(skel, targets, q, t, **case)
        # reachable: met within solve_ik's default tolerance (1e-5 x the skeleton's size)
        assert bool(sol.success), (case, solvers.RESULTS[sol.result], sol.position_errors)
        assert float(jnp.max(sol.position_errors)) <= tol, (case, sol.position_errors)
        _, p_res, ends_res = numpy_fk(skel, sol.rotations, sol.translations)
        if "pin" in case:
            assert_close("pinned toe", ends_res[skel.end_site_names.index("LeftToeBase_End")], toe, atol=1e-9 * h)
        else:
            assert_close("fixed root", p_res[0], p[0], atol=1e-12 * h)


def test_games105_wrist_holding_over_the_clip():
    """Keep the left wrist at a fixed offset in the root's heading frame, at a fixed height."""
    shared_data_dir()
    skel, motion = _cmu()
    h = _height(skel)
    R, p, _ = numpy_fk(skel, motion.rotations, motion.translations)
    # the goal in NumPy (eager jnp would compile each op for the clip's shapes)
    root = p[:, 0]
    fwd = R[:, 0, :, 2] * np.array([[1.0, 0.0, 1.0]])  # root z axis on the ground (Y up)
    fwd = fwd / np.linalg.norm(fwd, axis=-1, keepdims=True)
    side = np.cross(np.broadcast_to(np.array([0.0, 1.0, 0.0]), fwd.shape), fwd)
    goal = root + 0.25 * h * side + 0.2 * h * fwd
    goal[:, 1] = 0.55 * h + float(root[:, 1].min() - 0.5 * h)
    edited, sol = ik.solve_ik_clip(skel, motion, ik.Target("LeftHand", jnp.asarray(goal)))
    assert edited.num_frames == motion.num_frames
    assert np.isfinite(np.asarray(edited.rotations)).all()
    assert np.asarray(sol.success).all(), np.flatnonzero(~np.asarray(sol.success))
    err = float(np.asarray(sol.position_errors).max())
    assert err <= _position_tolerance(skel), err


def test_ik_matches_scipy_least_squares():
    """The same IK residual minimized by scipy (an independent solver) gives the same optimum.

    The targets have the structure of ``_tolerance_problem`` and the solve its options without the
    early stop, so this solve and the full solve of the stop-at-tolerance test are one compile, and
    scipy's residual and Jacobian are the Jacobian test's program (one structure)."""
    from scipy.optimize import least_squares as scipy_ls

    skel = small_skeleton()
    q, t = random_pose(skel, 9)
    base = _fk(skel, q, t)
    p = np.asarray(base.end_site_positions)
    # a goal frame for forearm_End (its owner's, joint 4) rotated by ~0.06 rad
    near = wxyz(Rotation.from_rotvec([0.04, -0.03, 0.03]).as_matrix() @ np.asarray(base.rotations[4]))
    cases = {
        # near the start: both solvers end in the same basin
        "near": (ik.Target("forearm_End", p[1] + 0.05, near), ik.Target("head_End", p[0] - 0.03, weight=0.5)),
    }
    for name, targets in cases.items():
        fns, n = _problem_fns(skel, targets, q, t)
        f = lambda y, fns=fns: fns(y)[0]  # noqa: E731
        jf = lambda y, fns=fns: fns(y)[1]  # noqa: E731  (the analytic Jacobian)
        sol = ik.solve_ik(skel, targets, q, t, **_FULL_SOLVE)
        assert bool(jnp.all(jnp.isfinite(sol.rotations))), name
        assert sol.result == solvers.RESULTS.successful, (name, solvers.RESULTS[sol.result])
        # the variables: root translation, then each joint's rotation vector of q_new q^-1 (in numpy:
        # eager jnp compiles op by op)
        y_ours = np.concatenate([
            np.asarray(sol.translations[0]) - np.asarray(t[0]),
            (scipy_rotation(sol.rotations) * scipy_rotation(q).inv()).as_rotvec().reshape(-1),
        ])
        ref = scipy_ls(lambda y: np.asarray(f(jnp.asarray(y))), np.zeros(n), jac=lambda y: np.asarray(jf(jnp.asarray(y))),
                       method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
        assert_close(f"{name}: cost", sol.stats["cost"], 0.5 * np.sum(ref.fun**2), rtol=1e-8)
        assert_close(f"{name}: pose", y_ours, ref.x, atol=1e-6)


def test_unreachable_target_gives_the_closest_pose_and_no_success():
    """Arm and forearm only, root fixed: the closest pose stretches the chain towards the target,
    at distance |target - shoulder| - (L1 + L2) (analytic)."""
    skel = small_skeleton()
    q, t = random_pose(skel, 11, scale=0.3)
    out = _fk(skel, q, t)
    shoulder = out.positions[skel.index("arm")]
    L = float(jnp.linalg.norm(t[4]) + jnp.linalg.norm(skel.end_site_offsets[1]))  # forearm bone as posed
    goal = shoulder + jnp.asarray([3.0, 1.0, -0.5])
    frozen = tuple(n for n in skel.names if n not in ("arm", "forearm"))
    solver = solvers.LevenbergMarquardt(max_steps=1000)
    sol = ik.solve_ik(skel, ik.Target("forearm_End", goal), q, t, frozen=frozen, root_translation="fixed",
                      regularization=0.0, solver=solver)
    # a large-residual problem: Gauss-Newton type methods converge only linearly here
    assert bool(jnp.all(jnp.isfinite(sol.rotations)))
    assert not bool(sol.success)
    expect = float(jnp.linalg.norm(goal - shoulder)) - L
    assert_close("distance to the unreachable target", sol.position_errors[0], expect, atol=1e-6)
    # a reachable one succeeds with the default solver (LevenbergMarquardt(), max_steps=100): solved
    # by the same compiled program as above (only max_steps differs, a static field; the iterates do
    # not depend on it), so success within the default's 100 steps is success with max_steps=100
    near = out.end_site_positions[1] + 0.01
    ok = ik.solve_ik(skel, ik.Target("forearm_End", near), q, t, frozen=frozen, root_translation="fixed",
                     regularization=0.0, solver=solver)
    assert bool(ok.success), (solvers.RESULTS[ok.result], ok.position_errors)
    assert int(ok.stats["num_steps"]) < solvers.LevenbergMarquardt().max_steps, ok.stats["num_steps"]


def test_nan_target_gives_no_nan_pose(small_problem):
    """A NaN target: ``nonfinite``, and a finite pose (``_PIN_FROZEN``: the compiled solve of other tests)."""
    skel, q, t, _ = small_problem
    sol = ik.solve_ik(skel, ik.Target("forearm_End", jnp.asarray([jnp.nan, 0.0, 0.0])), q, t, **_PIN_FROZEN)
    assert sol.result == solvers.RESULTS.nonfinite
    assert not bool(sol.success)
    assert bool(jnp.all(jnp.isfinite(sol.rotations))) and bool(jnp.all(jnp.isfinite(sol.translations)))


def test_cli_ik_writes_edited_bvh(tmp_path, monkeypatch):
    """`jaxanim ik FILE --targets TARGETS.json --out OUT.bvh` on a short clip of the shipped walk."""
    import json
    import os

    from jaxanim.cli import main

    from .conftest import _CACHE_ENV

    # the command's compilation cache is the run's (conftest), not ~/.cache/jaxanim: a clean start, as on CI
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", os.environ[_CACHE_ENV])

    skel, m = jaxanim.read_bvh(jaxanim.default_clip_path())
    short = jaxanim.Motion(m.rotations[:8], m.translations[:8], m.frame_time)
    src = tmp_path / "walk8.bvh"
    jaxanim.write_bvh(src, skel, short)
    hand = numpy_fk(skel, short.rotations, short.translations)[1][:, skel.index("LeftHand")]
    goal = hand + np.array([0.05, 0.1, 0.0])
    spec = {"pin": "LeftToeBase_End", "frozen": ["RightUpLeg"],
            "targets": [{"joint": "LeftHand", "position": goal.tolist(), "weight": 1.0}],
            "limits": [{"joint": "LeftForeArm", "swing": 150, "twist": [-90, 90]}]}
    (tmp_path / "t.json").write_text(json.dumps(spec))
    out = tmp_path / "out.bvh"
    assert main(["--quiet", "ik", str(src), "--targets", str(tmp_path / "t.json"), "--out", str(out)]) == 0
    skel2, edited = jaxanim.read_bvh(out)
    assert skel2.names == skel.names and skel2.channels == skel.channels
    got = numpy_fk(skel2, edited.rotations, edited.translations)[1][:, skel.index("LeftHand")]
    assert float(np.abs(got - goal).max()) < 1e-4  # file precision (6 decimals) bounds it
    limits = ik.targets_from_json(skel, spec, 8)[1]["limits"]
    assert float(jnp.max(jitted_limit_violation(skel, batched=True)(limits, edited.rotations))) < 1e-6
    # bad input: a clear error and exit code 2
    (tmp_path / "bad.json").write_text(json.dumps({"targets": [{"joint": "Tail", "position": [0, 0, 0]}]}))
    assert main(["--quiet", "ik", str(src), "--targets", str(tmp_path / "bad.json"), "--out", str(out)]) == 2
    (tmp_path / "bad2.json").write_text(json.dumps({"targets": [{"joint": "LeftHand", "position": [0, 0]}]}))
    assert main(["--quiet", "ik", str(src), "--targets", str(tmp_path / "bad2.json"), "--out", str(out)]) == 2


def _tolerance_problem():
    """``(skeleton, q, t, targets)``: a reachable two-target problem of the stop-at-tolerance tests."""
    skel = small_skeleton()
    q, t = random_pose(skel, 11)
    goal_q, goal_t = random_pose(skel, 12)
    out = _fk(skel, goal_q, goal_t)
    return skel, q, t, (ik.Target("forearm_End", out.end_site_positions[1], rot.matrix_to_quat(out.rotations[4])),
                        ik.Target("head_End", out.end_site_positions[0], weight=0.5))


#: a weakly regularized solve to the solver's own tolerances: the scipy comparison and the full
#: solve of the stop-at-tolerance test (the same structure of targets: one compile for both)
_FULL_SOLVE = dict(regularization=1e-3, solver=solvers.LevenbergMarquardt(max_steps=300), stop_at_tolerance=False)


def test_stop_at_tolerance_ends_the_solve_once_targets_are_met():
    """The default stops at the first iterate that meets every target's tolerance; without it the
    weakly regularized problem is solved to the solver's tolerances (many more steps)."""
    skel, q, t, targets = _tolerance_problem()
    # 1 cm / 0.6 deg on the ~1 m skeleton: the regularized optimum meets it (its errors: 8e-3 / 1e-3
    # rad), and the early stop is at step 10 of the full solve's 30
    tol = 1e-2
    kw = dict(_FULL_SOLVE, position_tolerance=tol, orientation_tolerance=tol)
    full = ik.solve_ik(skel, targets, q, t, **kw)
    early = ik.solve_ik(skel, targets, q, t, **dict(kw, stop_at_tolerance=True))
    assert bool(early.success) and early.result == solvers.RESULTS.successful
    assert float(jnp.max(early.position_errors)) <= tol and float(jnp.max(early.orientation_errors)) <= tol
    assert full.result == solvers.RESULTS.successful, solvers.RESULTS[full.result]
    assert int(early.stats["num_steps"]) < int(full.stats["num_steps"])
    # one step earlier the targets were not all met (it stopped at the first iterate that met them)
    fewer = ik.solve_ik(skel, targets, q, t, **dict(kw, stop_at_tolerance=True, solver=solvers.LevenbergMarquardt(
        max_steps=int(early.stats["num_steps"]) - 1)))
    assert not bool(fewer.success)
    assert (float(jnp.max(fewer.position_errors)) > tol or float(jnp.max(fewer.orientation_errors)) > tol), (
        fewer.position_errors, fewer.orientation_errors)
    # the reported errors are those of the returned pose, by an independent FK (numpy / scipy)
    fk = numpy_fk(skel, fewer.rotations, fewer.translations)
    goal = targets[0]
    forearm = skel.site_index("forearm_End") - skel.num_joints
    expect_p = np.linalg.norm(fk.end_site_positions[forearm] - np.asarray(goal.position))
    R_site = fk.rotations[skel.end_site_parents[forearm]]
    expect_o = (Rotation.from_matrix(R_site) * scipy_rotation(goal.orientation).inv()).magnitude()
    assert_close("position error", fewer.position_errors[0], expect_p, atol=1e-12)
    assert_close("orientation error", fewer.orientation_errors[0], expect_o, atol=1e-12)
    assert float(fewer.orientation_errors[0]) > 1e-4  # away from zero, where any formula agrees


def test_stop_at_tolerance_with_the_optimistix_adapter():
    """``stop_at_tolerance`` reaches the adapters too: optimistix LM stops once every target is met,
    long before its own tolerances would."""
    import optimistix as optx

    skel, q, t, targets = _tolerance_problem()
    tol = 1e-3
    solver = solvers.OptimistixSolver(optx.LevenbergMarquardt(rtol=1e-10, atol=1e-12), max_steps=500)

    def solve(tolerance):
        return ik.solve_ik(skel, targets, q, t, position_tolerance=tolerance, orientation_tolerance=tolerance,
                           stop_at_tolerance=True, solver=solver)

    # the reference: the same compiled solve (the tolerances are arrays) with a tolerance no iterate
    # meets, so that it ends by optimistix's own criterion (a stop_at_tolerance=False solve is a
    # second compile: 2.7 s)
    early, full = solve(tol), solve(-1.0)
    assert bool(early.success) and early.result == solvers.RESULTS.successful, solvers.RESULTS[early.result]
    assert float(jnp.max(early.position_errors)) <= tol and float(jnp.max(early.orientation_errors)) <= tol
    assert full.result == solvers.RESULTS.successful and not bool(full.stats["stopped_early"]), (
        solvers.RESULTS[full.result])
    assert int(early.stats["num_steps"]) < int(full.stats["num_steps"]), (early.stats["num_steps"],
                                                                          full.stats["num_steps"])


def test_targets_json_limits_and_tolerances():
    skel = small_skeleton()
    spec = {"targets": [{"joint": "forearm_End", "position": [0, 1, 2]}], "position_tolerance": 0.01,
            "limit_mode": "soft", "limit_weight": 10,
            "limits": [{"joint": "arm", "lower": [-10, -20, -30], "upper": [10, 20, 30], "order": "ZXY"},
                       {"joint": "forearm", "swing": [40, 20], "twist": [-5, 5]}]}
    targets, kw = ik.targets_from_json(skel, spec, 4)
    assert kw["position_tolerance"] == 0.01 and kw["limit_mode"] == "soft" and kw["limit_weight"] == 10.0
    euler, swing = kw["limits"]
    assert euler.order == "ZXY" and swing.axis is None
    np.testing.assert_allclose(euler.lower, np.radians([-10, -20, -30]))
    np.testing.assert_allclose(swing.swing, np.radians([40, 20]))
    np.testing.assert_allclose(swing.twist, np.radians([-5, 5]))
    bad = [({"joint": "elbow", "swing": 10}, "unknown joint 'elbow'"),
           ({"joint": "arm", "swing": 10, "lower": [0, 0, 0]}, "expected either 'lower', 'upper'"),
           ({"joint": "arm", "lower": [0, 0], "upper": [1, 1, 1]}, r"limits\[0\]: limits\['arm'\].lower: expected shape"),
           ({"joint": "arm", "swing": 200}, r"swing: expected angles in \(0, pi\)")]
    for item, msg in bad:
        with pytest.raises(jaxanim.JaxanimError, match=msg):
            ik.targets_from_json(skel, {**spec, "limits": [item]}, 4)
    with pytest.raises(jaxanim.JaxanimError, match="'limit_weight' must be a non-negative number"):
        ik.targets_from_json(skel, {**spec, "limit_weight": "stiff"}, 4)


def test_joint_weights_are_the_damping_metric():
    """A stiff joint (large w_j in (J^T J + lambda W)) moves less than with unit weights."""
    skel = small_skeleton()
    q, t = random_pose(skel, 13)
    goal = _fk(skel, q, t).end_site_positions[1] + jnp.asarray([0.2, -0.1, 0.1])
    w = jnp.ones(skel.num_joints).at[skel.index("arm")].set(1e4)
    # unit weights given as an array: the same compiled solve as the stiff one (one structure)
    plain = ik.solve_ik(skel, ik.Target("forearm_End", goal), q, t, root_translation="fixed",
                        joint_weights=jnp.ones(skel.num_joints))
    stiff = ik.solve_ik(skel, ik.Target("forearm_End", goal), q, t, root_translation="fixed", joint_weights=w)
    assert bool(plain.success) and bool(stiff.success)
    moved = [float(rot.quat_distance(s.rotations[3], q[3])) for s in (plain, stiff)]
    assert moved[1] < 0.1 * moved[0], moved
    with pytest.raises(jaxanim.JaxanimError, match="joint_weights: the solver already has weights"):
        ik.solve_ik(skel, ik.Target("forearm_End", goal), q, t, joint_weights=w,
                    solver=solvers.LevenbergMarquardt(weights=jnp.ones(3 + 3 * skel.num_joints)))


def test_float32_benchmark_batch_has_no_nan():
    """The benchmark's 1024 random problems in float32 (x64 on, as users mix): no NaN anywhere, and
    the solves succeed (the benchmark's success criterion is looser; this checks the solver's own)."""
    shared_data_dir()
    from benchmarks.ik import batched_solver, make_problems

    skel, _ = _cmu()
    skel32 = jax.tree.map(lambda x: x.astype(jnp.float32) if jnp.issubdtype(x.dtype, jnp.floating) else x, skel)
    targets, q0, t0 = make_problems(skel, 1024, seed=0, dtype=jnp.float32)
    sol = batched_solver(skel32, position_tolerance=1e-3 * _height(skel), orientation_tolerance=0.01)(targets, q0, t0)
    leaves = {"rotations": sol.rotations, "translations": sol.translations, "position_errors": sol.position_errors,
              "orientation_errors": sol.orientation_errors, **sol.stats}
    for name, x in leaves.items():  # checked in numpy: nothing to compile (a jit of the checks took 2.5 s)
        assert x.dtype != jnp.float64, name
        v = np.asarray(x)
        assert np.all(np.isfinite(v) | (v == np.inf)), name  # stats use inf for "not finite"
        assert not np.any(np.isnan(v)), name
    assert float(np.mean(np.asarray(sol.success))) >= 0.99, float(np.mean(np.asarray(sol.success)))


@contextlib.contextmanager
def _count_traces():
    """The jit traces (``/jax/core/compile/jaxpr_trace_duration`` events) inside the block."""
    events = []

    def listener(event, duration, **kwargs):
        if event == "/jax/core/compile/jaxpr_trace_duration":
            events.append(kwargs.get("fun_name", event))

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        yield events
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)


@pytest.fixture(scope="module")
def small_problem():
    skel = small_skeleton()
    q, t = random_pose(skel, 20)
    goal = _fk(skel, *random_pose(skel, 21, scale=0.3)).end_site_positions[1]
    return skel, q, t, goal


def _three_entry_points(skel):
    def clip(goal, q, t):  # the programs of test_pin_frozen_and_vmap_equals_loop (_PIN_FROZEN, 3 frames)
        goals = jnp.stack([goal, goal + 0.01, goal - 0.01])
        return ik.solve_ik_clip(skel, _three_frames(q, t), ik.Target("forearm_End", goals), **_PIN_FROZEN)[1]

    return {
        "solve_ik": lambda goal, q, t: ik.solve_ik(skel, ik.Target("forearm_End", goal), q, t, **_PIN_FROZEN),
        "solve_ik_clip": clip,
        "solve_ik_ccd": lambda goal, q, t: ik.solve_ik_ccd(skel, ik.Target("forearm_End", goal), q, t, max_sweeps=20),
    }


@pytest.mark.parametrize("name", ["solve_ik", "solve_ik_clip", "solve_ik_ccd"])
def test_second_call_with_new_values_does_not_retrace(small_problem, name):
    skel, q, t, goal = small_problem
    solve = _three_entry_points(skel)[name]
    jax.block_until_ready(solve(goal, q, t))
    q2, t2 = random_pose(skel, 22)
    goal2 = goal + jnp.asarray([0.02, -0.01, 0.03])
    with _count_traces() as traces:
        sol = jax.block_until_ready(solve(goal2, q2, t2))
    assert traces == [], traces
    assert bool(jnp.all(sol.success)), (name, solvers.RESULTS[sol.result] if sol.result.ndim == 0 else sol.result)


def test_options_module_and_keywords_agree(small_problem):
    """``options=IKOptions(...)`` is the keywords grouped; a keyword beside it wins (same compile)."""
    skel, q, t, goal = small_problem
    target = ik.Target("forearm_End", goal)
    by_keyword = ik.solve_ik(skel, target, q, t, **_PIN_FROZEN)  # the compiled solve of the tests above
    with _count_traces() as traces:
        by_options = ik.solve_ik(skel, target, q, t, options=ik.IKOptions(**_PIN_FROZEN))
        overridden = ik.solve_ik(skel, target, q, t, options=ik.IKOptions(pin="leg", frozen=("leg",)), pin="head_End")
    assert traces == [], traces
    for sol in (by_options, overridden):
        np.testing.assert_array_equal(np.asarray(sol.rotations), np.asarray(by_keyword.rotations))
        np.testing.assert_array_equal(np.asarray(sol.translations), np.asarray(by_keyword.translations))
    with pytest.raises(jaxanim.JaxanimError, match="options: expected a jaxanim.ik.IKOptions"):
        ik.solve_ik(skel, target, q, t, options={"pin": "leg"})
    with pytest.raises(TypeError, match=r"unexpected keyword arguments \['pinned'\]"):
        ik.solve_ik_clip(skel, jaxanim.rest_motion(skel, 2), target, pinned="leg")


def test_one_residual_and_jacobian_call_per_linearization(small_problem, monkeypatch):
    """The IK residual and its Jacobian come from one call (``least_squares(jac=True)``): tracing a
    solve calls ``_residual_and_jacobian`` exactly as often as the solver evaluates a ``jac=True``
    residual, i.e. once per linearization, not twice (residual, then Jacobian)."""
    skel, q, t, goal = small_problem
    solver = solvers.LevenbergMarquardt(max_steps=13)  # a structure no other test compiles: traced here
    calls = []
    original = ik_impl._residual_and_jacobian

    def counted(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(ik_impl, "_residual_and_jacobian", counted)
    # traced only (``eval_shape``): the calls happen while tracing; compiling would add 1.8 s
    jax.eval_shape(lambda: ik.solve_ik(skel, ik.Target("forearm_End", goal), q, t, solver=solver,
                                       stop_at_tolerance=False))
    toy_calls = []

    def toy(y, args):  # 2 residuals, 3 variables: the m < n path of the IK solve without regularizer
        toy_calls.append(1)
        r = jnp.stack([y[0] ** 2 + y[1] - 1.0, y[1] * y[2] - 0.5])
        return r, jax.jacfwd(lambda z: jnp.stack([z[0] ** 2 + z[1] - 1.0, z[1] * z[2] - 0.5]))(y)

    jax.eval_shape(lambda: solvers.least_squares(toy, solver, jnp.ones(3), None, jac=True))
    assert len(toy_calls) > 0 and len(calls) == len(toy_calls), (len(calls), len(toy_calls))
