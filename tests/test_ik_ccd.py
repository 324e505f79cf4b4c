"""CCD inverse kinematics: the per-joint Wahba step against scipy, convergence, frozen joints, vmap.

Few distinct problem structures (each one is a separate compile): a 4-joint chain, the small
tree with three targets, the small tree with one free joint, and optionally the CMU skeleton.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import jaxanim
import solvers
from jaxanim import ik
from jaxanim.ik_ccd import solve_ik_ccd

from .conftest import shared_data_dir
from .helpers import (assert_close, numpy_fk, random_pose, random_site_targets, scipy_rotation, shared_clip,
                      small_skeleton, wxyz)

_ATOL_STEP = 1e-7  # the Wahba step against scipy (the step is damped by a relative ~1.5e-8)
_ATOL_VMAP = 1e-6  # vmap against a loop: same sweeps, rounding amplified over ~100 of them


def _chain():
    """A 4-joint chain with an End Site (total reach 2.8)."""
    offsets = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.8, 0.0], [0.0, 0.6, 0.0]])
    return jaxanim.Skeleton(
        ("j0", "j1", "j2", "j3"), (-1, 0, 1, 2), jnp.asarray(offsets),
        end_site_parents=(3,), end_site_offsets=jnp.asarray([[0.0, 0.4, 0.0]]),
    )


def _canonical(q):
    """numpy: the sign of ``q`` with w >= 0 (the test poses never have w == 0)."""
    q = np.asarray(q)
    return np.where(q[..., :1] < 0, -q, q)


def _angle(q0, q1):
    """numpy/scipy: the angle between two wxyz rotations."""
    return float((scipy_rotation(q0).inv() * scipy_rotation(q1)).magnitude())


@functools.lru_cache(maxsize=None)
def _chain_problem():
    """Chain, one position target at the End Site from FK of a pose with the same ``j1`` (frozen)
    and root translation (fixed): reachable. Solved once, shared by two tests."""
    skel = _chain()
    q_init = np.array(random_pose(skel, 10, scale=0.5)[0])
    q_goal = np.array(random_pose(skel, 11, scale=0.7)[0])
    q_goal[1] = q_init[1]
    t = np.asarray(skel.offsets).copy()
    t[0] = [0.3, -0.2, 0.1]
    goal = np.asarray(numpy_fk(skel, q_goal, t).end_site_positions[0])
    args = (q_init.copy(), t.copy(), goal.copy())
    sol = solve_ik_ccd(skel, ik.Target("j3_End", goal), q_init, t, frozen=("j1",), root_translation="fixed")
    # nothing the caller passed was modified
    np.testing.assert_array_equal(q_init, args[0])
    np.testing.assert_array_equal(t, args[1])
    np.testing.assert_array_equal(goal, args[2])
    return skel, q_init, t, goal, sol


def test_chain_reaches_single_position_target():
    skel, _, _, goal, sol = _chain_problem()
    tol = 1e-4 * float(np.abs(np.asarray(skel.offsets)).sum())
    assert bool(sol.success), (solvers.RESULTS[sol.result], sol.position_errors)
    assert sol.result == solvers.RESULTS.successful
    # independent check by FK of the returned pose
    end = np.asarray(numpy_fk(skel, sol.rotations, sol.translations).end_site_positions[0])
    assert np.linalg.norm(end - goal) <= tol
    assert_close("position_errors", sol.position_errors[0], np.linalg.norm(end - goal), atol=1e-12)
    assert_close("unit rotations", np.linalg.norm(np.asarray(sol.rotations), axis=-1), np.ones(4), atol=1e-12)
    assert int(sol.stats["num_steps"]) >= 1


def test_frozen_joint_and_fixed_root_translation_do_not_move():
    _, q_init, t, _, sol = _chain_problem()
    # the frozen joint keeps its rotation exactly (up to the canonical sign)
    assert_close("frozen j1", sol.rotations[1], _canonical(q_init[1]), atol=0.0)
    assert_close("translations", sol.translations, t, atol=0.0)
    # the other joints did move
    assert _angle(sol.rotations[2], q_init[2]) > 1e-3


def test_one_sweep_is_the_weighted_wahba_optimum():
    """One sweep with a single free joint is one Kabsch step: compare with scipy's align_vectors
    on the same vectors, and check no nearby rotation does better."""
    skel = small_skeleton()
    q, t = random_pose(skel, 20)
    goal = numpy_fk(skel, *random_pose(skel, 21))
    targets = (
        ik.Target("forearm_End", goal.end_site_positions[1], wxyz(goal.rotations)[4], 2.0),
        ik.Target("forearm", position=goal.positions[4], weight=0.5),
    )
    s = 0.3
    frozen = tuple(n for n in skel.names if n != "arm")
    sol = solve_ik_ccd(skel, targets, q, t, frozen=frozen, root_translation="fixed", max_sweeps=1, orientation_scale=s)
    assert int(sol.stats["num_steps"]) == 1

    # reference: the optimal world rotation dR about the arm's pivot, from scipy
    out = numpy_fk(skel, q, t)
    arm, fore = skel.index("arm"), skel.index("forearm")
    p = np.asarray(out.positions[arm])
    x = np.stack([np.asarray(out.end_site_positions[1]), np.asarray(out.positions[fore])])
    x_goal = np.stack([np.asarray(goal.end_site_positions[1]), np.asarray(goal.positions[4])])
    R_s = np.asarray(out.rotations[fore])
    R_goal = np.asarray(goal.rotations[4])
    # positions: the lever arms, weights w; orientation: the three frame axes, weights w s^2 / 2
    # (w s^2 (3 - tr(dR R_s R_goal^T)) = w s^2 / 2 sum_k |dR R_s e_k - R_goal e_k|^2)
    current = np.concatenate([x - p, R_s.T])
    wanted = np.concatenate([x_goal - p, R_goal.T])
    weights = np.array([2.0, 0.5] + [2.0 * s * s / 2] * 3)
    dR, _ = Rotation.align_vectors(wanted, current, weights=weights)
    dR = dR.as_matrix()
    Q_par = np.asarray(out.rotations[skel.parents[arm]])
    expected = Q_par.T @ dR @ np.asarray(out.rotations[arm])
    got = scipy_rotation(sol.rotations[arm]).as_matrix()
    assert_close("arm rotation after one sweep", got, expected, atol=_ATOL_STEP)
    # every other joint is frozen, the root translation fixed
    others = [j for j in range(skel.num_joints) if j != arm]
    assert_close("frozen joints", np.asarray(sol.rotations)[others], _canonical(np.asarray(q)[others]), atol=0.0)

    # and no perturbation of dR does better on the step's objective
    def objective(R):
        pos = np.sum(weights[:2] * np.sum((np.einsum("ab,sb->sa", R, x - p) - (x_goal - p)) ** 2, axis=-1))
        return pos + 2.0 * s * s * (3.0 - np.trace(R @ R_s @ R_goal.T))

    best = objective(dR)
    rng = np.random.default_rng(0)
    for scale in (1e-3, 1e-1, 1.0):
        for v in rng.normal(size=(50, 3)) * scale:
            assert objective(Rotation.from_rotvec(v).as_matrix() @ dR) >= best - 1e-12


def _tree_targets(skel, seed):
    """Three targets from FK of a random pose (with the offsets as translations: reachable)."""
    q, _ = random_pose(skel, seed)
    goal = numpy_fk(skel, q, skel.offsets)
    quats = wxyz(goal.rotations)
    return (
        ik.Target("forearm_End", goal.end_site_positions[1], quats[4], 2.0),
        ik.Target("head_End", position=goal.end_site_positions[0]),
        ik.Target("leg", position=goal.positions[5], orientation=quats[5]),
    )


_TREE_KW = dict(max_sweeps=400)


def test_multi_target_cost_decreases_and_errors_end_small():
    skel = small_skeleton()
    q0, _ = random_pose(skel, 31)
    sol = solve_ik_ccd(skel, _tree_targets(skel, 30), q0, None, **_TREE_KW)
    assert bool(sol.success), (solvers.RESULTS[sol.result], sol.position_errors, sol.orientation_errors)
    n = int(sol.stats["num_steps"])
    G = np.asarray(sol.stats["ccd_cost_history"])[: n + 1]
    cost = np.asarray(sol.stats["cost_history"])[: n + 1]
    # the sweep objective never increases (each block step is its exact minimizer) ...
    assert np.all(np.diff(G) <= 1e-13 * G[0]), np.diff(G).max()
    # ... and the reported cost goes from O(1) to nearly nothing
    assert cost[0] > 1e-2 and cost[-1] < 1e-7 * cost[0], (cost[0], cost[-1])
    assert_close("cost", sol.stats["cost"], cost[-1], atol=0.0)
    # errors by an independent FK
    out = numpy_fk(skel, sol.rotations, sol.translations)
    tol = 1e-4 * float(np.abs(np.asarray(skel.offsets)).sum())
    goal = _tree_targets(skel, 30)
    assert np.linalg.norm(out.end_site_positions[0] - np.asarray(goal[1].position)) <= tol
    assert np.linalg.norm(out.end_site_positions[1] - np.asarray(goal[0].position)) <= tol
    R_leg = Rotation.from_matrix(np.asarray(out.rotations[5]))
    assert (R_leg.inv() * scipy_rotation(goal[2].orientation)).magnitude() <= 1e-4


def test_vmap_equals_loop_and_fixed_sweeps():
    skel = small_skeleton()
    q0, _ = random_pose(skel, 41)
    sets = [_tree_targets(skel, s) for s in (42, 43, 44)]
    stacked = jax.tree.map(lambda *a: jnp.stack(a), *sets)
    batched = jax.vmap(lambda tg: solve_ik_ccd(skel, tg, q0, None, fixed_sweeps=True, **_TREE_KW))(stacked)
    for i, tg in enumerate(sets):
        one = solve_ik_ccd(skel, tg, q0, None, **_TREE_KW)
        assert_close(f"rotations[{i}]", batched.rotations[i], one.rotations, atol=_ATOL_VMAP)
        assert_close(f"translations[{i}]", batched.translations[i], one.translations, atol=_ATOL_VMAP)
        assert_close(f"position_errors[{i}]", batched.position_errors[i], one.position_errors, atol=_ATOL_VMAP)
        assert int(batched.stats["num_steps"][i]) == int(one.stats["num_steps"])
        assert bool(batched.success[i]) == bool(one.success)
        assert int(batched.result._value[i]) == int(one.result._value)


def test_nan_target_gives_no_nan_pose():
    skel = small_skeleton()
    q0, _ = random_pose(skel, 41)
    good = _tree_targets(skel, 42)
    bad = (ik.Target("forearm_End", jnp.asarray([jnp.nan, 0.0, 0.0]), good[0].orientation, 2.0),) + good[1:]
    sol = solve_ik_ccd(skel, bad, q0, None, **_TREE_KW)
    assert sol.result == solvers.RESULTS.nonfinite
    assert not bool(sol.success)
    assert np.all(np.isfinite(np.asarray(sol.rotations))) and np.all(np.isfinite(np.asarray(sol.translations)))
    assert_close("initial pose returned", sol.rotations, _canonical(q0), atol=1e-12)


def test_bad_input():
    skel = small_skeleton()
    q, t = random_pose(skel, 8)
    with pytest.raises(jaxanim.JaxanimError, match="unknown joint or End Site 'hand'; valid:.*'forearm_End'"):
        solve_ik_ccd(skel, ik.Target("hand", jnp.zeros(3)), q, t)
    with pytest.raises(jaxanim.JaxanimError, match="unknown joint 'tail'; valid joints:"):
        solve_ik_ccd(skel, ik.Target("leg", jnp.zeros(3)), q, t, frozen=("tail",))
    with pytest.raises(jaxanim.JaxanimError, match="root_translation: expected 'free' or 'fixed'"):
        solve_ik_ccd(skel, ik.Target("leg", jnp.zeros(3)), q, t, root_translation="loose")
    with pytest.raises(jaxanim.JaxanimError, match=r"rotations: expected shape \(joints, 4\) = \(6, 4\), got \(5, 4\)"):
        solve_ik_ccd(skel, ik.Target("leg", jnp.zeros(3)), q[:5], t)
    with pytest.raises(jaxanim.JaxanimError, match=r"targets\['leg'\].position: expected shape \(3,\), got \(2, 3\)"):
        solve_ik_ccd(skel, ik.Target("leg", jnp.zeros((2, 3))), q, t)
    with pytest.raises(jaxanim.JaxanimError, match="targets: expected a non-empty sequence"):
        solve_ik_ccd(skel, (), q, t)
    with pytest.raises(jaxanim.JaxanimError, match="nothing can move"):
        solve_ik_ccd(skel, ik.Target("leg", jnp.zeros(3)), q, t, frozen=skel.names, root_translation="fixed")
    with pytest.raises(jaxanim.JaxanimError, match="max_sweeps: expected a non-negative int"):
        solve_ik_ccd(skel, ik.Target("leg", jnp.zeros(3)), q, t, max_sweeps=-1)


EFFECTORS = ("LeftHand", "RightHand", "LeftToeBase_End", "RightToeBase_End", "Head_End")


def test_cmu_skeleton_five_effectors():
    """Reachable position + orientation targets on the 31-joint CMU skeleton from the rest pose:
    CCD gets there, but needs ~100 sweeps (Levenberg-Marquardt needs ~10 iterations)."""
    shared_data_dir()
    skel, _, _ = shared_clip("cmu_01_01_trim300")
    sol = solve_ik_ccd(skel, random_site_targets(skel, 0, EFFECTORS), skel.rest_rotations(), None, max_sweeps=400)
    cost = np.asarray(sol.stats["cost_history"])
    n = int(sol.stats["num_steps"])
    assert bool(sol.success), (solvers.RESULTS[sol.result], sol.position_errors, sol.orientation_errors)
    assert cost[n] < 1e-6 * cost[0], (cost[0], cost[n])
    assert 20 < n < 400, n  # CCD is slow: dozens to hundreds of sweeps
