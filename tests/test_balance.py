"""Tests of jaxanim.balance on the CMU clip 01_01, its first frame as the target: the character
stands 10 s on complementarity ground with stable PD and the Jacobian-transpose balance law and no
root force, recovers from a documented push (and falls without the balance torques), the balance torques have the sign that
moves the center of mass towards the support center, a vmap over gain / push settings equals a
Python loop of the same compiled rollout, the sweep example runs, and bad input.

Cost: two compilations of the 10 s rollout (unbatched and vmapped, ~30 s each on 2 cores) shared by
module-scoped fixtures, 6 rollouts of 1200 steps, and one more compilation for the example's smoke
test (tiny grid, 0.25 s)."""

from __future__ import annotations

import importlib.util

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxanim
from jaxanim import JaxanimError, balance, character, contact, physics
from jaxanim import rotations as rot

from .conftest import REPO, shared_data_dir
from .helpers import phys_cmu_character, xla_compiles

DT = 1 / 120  # the notes' control rate
SECONDS = 10.0
NUM_STEPS = int(round(SECONDS / DT))
RECORD_EVERY = 12  # 10 Hz records
# The documented push: 150 N forwards (+Z, from the heels towards the toes in this clip) on the
# torso ("Spine" body) for 0.2 s from t = 1 s, an impulse of 30 N s (0.43 m/s on 70 kg).
PUSH_FORCE = np.array([0.0, 0.0, 150.0])
PUSH = (np.zeros(3), "Spine", 1.0, 0.2)
_ATOL_VMAP = 1e-12  # positions (m) and orientations
_ATOL_VMAP_VEL = 1e-10  # velocities (m/s, rad/s)


@pytest.fixture(scope="module")
def cmu():
    shared_data_dir()
    _, _, q0, t0, char, state = phys_cmu_character()  # complementarity ground; shared with test_character
    ctrl, args = balance.balance_controller(char, q0, t0, DT, push=PUSH)
    return char, q0, t0, state, ctrl, args


def _with(args, **changes):
    out = dict(args)
    for k, v in changes.items():
        out[k] = jnp.broadcast_to(jnp.asarray(v, out[k].dtype), out[k].shape)
    return out


def _settings(args):
    return {
        "stand": _with(args),
        "push": _with(args, push_force=PUSH_FORCE),
        "push_no_balance": _with(args, push_force=PUSH_FORCE, balance_kp=0.0, balance_kd=0.0),
    }


def _rollout(cmu_, a):
    char, *_, state, ctrl, _ = cmu_
    return physics.rollout(char.model, state, DT, NUM_STEPS, record_every=RECORD_EVERY, controller=ctrl,
                           controller_args=a)


@pytest.fixture(scope="module")
def loop_runs(cmu):
    """One compiled rollout called in a Python loop (the args are arrays: no recompilation)."""
    return {name: _rollout(cmu, a) for name, a in _settings(cmu[-1]).items()}


@pytest.fixture(scope="module")
def vmap_runs(cmu):
    settings = _settings(cmu[-1])
    batch = jax.tree.map(lambda *x: jnp.stack(x), *settings.values())
    runs = jax.vmap(lambda a: _rollout(cmu, a))(batch)
    return {name: jax.tree.map(lambda x, i=i: x[i], runs) for i, name in enumerate(settings)}


def _com(char, trajectory):
    m = char.model.bodies.mass / jnp.sum(char.model.bodies.mass)
    return np.asarray(jnp.einsum("b,...bi->...i", m, trajectory.position))


def _feet_region(char, state):
    """Axis-aligned horizontal bounds (x, z) of the feet bodies' contact points."""
    body, local, _ = contact.contact_points(char.model.bodies)
    feet = np.array([any(s in char.model.bodies.names[b] for s in ("Foot", "Toe")) for b in body])
    p = np.asarray(state.position[body] + rot.quat_apply(state.orientation[body], local))[feet]
    return p[:, [0, 2]].min(axis=0), p[:, [0, 2]].max(axis=0)


def test_first_frame_stands_on_both_soles(cmu):
    char, q0, t0, state, *_ = cmu
    body, local, _ = contact.contact_points(char.model.bodies)
    p = np.asarray(state.position[body] + rot.quat_apply(state.orientation[body], local))
    soles = {}
    for foot in ("LeftFoot", "RightFoot", "LeftToeBase", "RightToeBase"):
        heights = np.sort(p[np.asarray(body) == char.model.bodies.names.index(foot), 1])
        np.testing.assert_allclose(heights[:4], heights[0], atol=1e-9, err_msg=f"{foot}: sole not flat")
        soles[foot] = heights[0]
    np.testing.assert_allclose(list(soles.values()), min(soles.values()), atol=1e-9, err_msg="soles not level")
    c = np.asarray(physics.bodies_center_of_mass(char.model.bodies, state)[0])
    lo, hi = _feet_region(char, state)
    assert np.all(c[[0, 2]] > lo) and np.all(c[[0, 2]] < hi), "CoM not over the feet"


def test_standing_pose_is_flat_footed_and_balanced(cmu):
    char, q0, t0, *_ = cmu
    q, t = balance.standing_pose(char, q0, t0)
    state = character.character_state(char, q, t)
    body, local, radius = contact.contact_points(char.model.bodies)
    p = np.asarray(state.position[body] + rot.quat_apply(state.orientation[body], local))
    assert abs(p[:, 1].min()) < 1e-9
    for foot in ("LeftFoot", "RightFoot"):
        heights = p[np.asarray(body) == char.model.bodies.names.index(foot), 1]
        np.testing.assert_allclose(np.sort(heights)[:4], np.sort(heights)[0], atol=1e-9, err_msg=f"{foot} not flat")
    c = np.asarray(physics.bodies_center_of_mass(char.model.bodies, state)[0])
    lo, hi = _feet_region(char, state)
    assert np.all(c[[0, 2]] > lo) and np.all(c[[0, 2]] < hi)
    # Only the ankles (and the toes below them) changed.
    e = np.linalg.norm(np.asarray(jaxanim.control.joint_errors(
        char.model.joints, state, character.spd_targets(char, q0, t0))[0]), axis=-1)
    changed = {char.model.joints.names[j] for j in np.nonzero(e > 1e-9)[0]}
    assert changed <= {"LeftFoot", "RightFoot", "LeftToeBase", "RightToeBase"}, changed


def test_stance_legs_by_name(cmu):
    char = cmu[0]
    names = char.model.joints.names
    legs, signs = balance.stance_leg_joints(char)
    assert [[names[j] for j in leg] for leg in legs] == [["LeftFoot", "LeftLeg", "LeftUpLeg"],
                                                          ["RightFoot", "RightLeg", "RightUpLeg"]]
    assert signs == ((-1, -1, -1), (-1, -1, -1))
    explicit = balance.stance_leg_joints(char, leg_joints=(("LeftFoot", "LeftLeg", "LeftUpLeg"),
                                                           ("RightFoot", "RightLeg", "RightUpLeg")))
    assert explicit == (legs, signs)


def test_balance_torques_move_the_com_towards_the_support_center(cmu):
    """Power check of the sign convention: the torque each leg joint applies to the body on the
    center-of-mass side (``-joint_torque``, as the parent, by physics.step's +child / -parent) turns
    that side so that ``c`` moves along ``f``: ``f . ((-tau_j) x (c - p_j)) > 0``."""
    char, *_, state, ctrl, args = cmu
    c, _ = physics.bodies_center_of_mass(char.model.bodies, state)
    for offset in (np.array([0.0, 0.0, 0.05]), np.array([-0.04, 0.0, 0.0])):
        a = _with(args, support_weight=0.0, target=np.asarray(c) + offset)
        u = ctrl(state, jnp.asarray(0), a)
        f = float(args["balance_kp"]) * offset  # at rest: no damping term
        assert isinstance(u, physics.Control) and u["joint_torque"] is u.joint_torque  # 0.1 dict-style reads
        tau = np.asarray(u.joint_torque)
        p = np.asarray(balance.joint_anchors(char.model.joints, state))
        legs, _ = balance.stance_leg_joints(char)
        for leg in legs:
            for j in leg:
                np.testing.assert_allclose(-tau[j], np.cross(np.asarray(c) - p[j], f) / 2, rtol=1e-12, atol=1e-12)
                assert f @ np.cross(-tau[j], np.asarray(c) - p[j]) > 0
        others = [j for j in range(len(tau)) if all(j not in leg for leg in legs)]
        assert np.all(tau[others] == 0)
        assert np.all(np.asarray(u.force) == 0)  # no push at t = 0


def test_stands_10_s_without_root_force(cmu, loop_runs):
    char, _, _, state, _, _ = cmu
    run = loop_runs["stand"]
    assert run.result == physics.SimResult.successful and int(run.num_steps) == NUM_STEPS
    com = _com(char, run.trajectory)
    c0 = np.asarray(physics.bodies_center_of_mass(char.model.bodies, state)[0])
    heights = com[:, 1] / c0[1]
    assert heights.min() > 0.95 and heights.max() < 1.05, f"CoM height / start in [{heights.min()}, {heights.max()}]"
    drift = np.linalg.norm((com - c0)[:, [0, 2]], axis=-1)
    # The law moves the CoM towards the feet center (16 cm ahead of it in this frame) until the
    # stable PD holding the pose balances it.
    assert drift.max() < 0.06, f"CoM moved {drift.max():.4f} m horizontally"
    lo, hi = _feet_region(char, run.final)
    assert np.all(com[:, [0, 2]] > lo) and np.all(com[:, [0, 2]] < hi), "CoM left the feet region"
    assert bool(balance.stood(char, state, run.trajectory))
    assert float(jnp.max(physics.joint_error(char.model, run.final))) < 1e-3


def test_recovers_from_a_push(cmu, loop_runs):
    char, _, _, state, _, _ = cmu
    run = loop_runs["push"]
    assert run.result == physics.SimResult.successful
    assert bool(balance.stood(char, state, run.trajectory))
    com = _com(char, run.trajectory)
    still = _com(char, loop_runs["stand"].trajectory)  # the same character, not pushed
    t = np.arange(1, com.shape[0] + 1) * RECORD_EVERY * DT
    excursion = np.linalg.norm((com - still)[:, [0, 2]], axis=-1)
    assert excursion[t > 1.0].max() > 0.02, "the push did not move the character"
    assert excursion[t > 8.0].max() < 0.01, f"CoM {excursion[-1]:.4f} m from the unpushed one at 10 s"
    lo, hi = _feet_region(char, run.final)
    assert np.all(com[:, [0, 2]] > lo) and np.all(com[:, [0, 2]] < hi)
    # The balance law matters: the same push topples the character held by stable PD alone.
    passive = loop_runs["push_no_balance"]
    assert not bool(balance.stood(char, state, passive.trajectory))


def test_vmap_equals_python_loop(cmu, loop_runs, vmap_runs):
    """The batched and the unbatched compiled rollouts are different XLA programs (their reductions
    may be ordered differently), so the states agree to rounding, not bitwise: ~1e-13 per step,
    which stays below 1e-12 in positions and orientations (1e-10 in velocities) over the 10 s while
    the character stands. A falling character's ground impacts amplify it (1e-8 after the fall), so
    for the fall the records are compared up to t = 3 s and the outcome after it."""
    char, _, _, state, _, _ = cmu
    fall_start = int(3.0 / (RECORD_EVERY * DT))
    for name, run in loop_runs.items():
        vrun = vmap_runs[name]
        assert run.result == vrun.result, name
        assert int(run.num_steps) == int(vrun.num_steps), name
        assert bool(balance.stood(char, state, run.trajectory)) == bool(balance.stood(char, state, vrun.trajectory))
        upto = fall_start if name == "push_no_balance" else NUM_STEPS // RECORD_EVERY
        for field, atol in (("position", _ATOL_VMAP), ("orientation", _ATOL_VMAP), ("linear_velocity", _ATOL_VMAP_VEL),
                            ("angular_velocity", _ATOL_VMAP_VEL)):
            np.testing.assert_allclose(getattr(vrun.trajectory, field)[:upto], getattr(run.trajectory, field)[:upto],
                                       rtol=0, atol=atol, err_msg=f"{name}: trajectory.{field}")
        np.testing.assert_allclose(vrun.final.position, run.final.position, rtol=0, atol=1e-6, err_msg=f"{name}: final")


def test_a_second_balance_controller_does_not_recompile(cmu, loop_runs):
    """A balance controller for another pose of the same character (the same structure, new
    values) reuses the compiled rollout; the same pose gives the same states to the bit."""
    char, q0, t0, state, _, args = cmu
    motion = jaxanim.read_bvh(shared_data_dir() / "bvh" / "cmu_01_01_trim300.bvh")[1]
    with xla_compiles() as compiled:
        other, _ = balance.balance_controller(char, motion.rotations[20], motion.translations[20], DT, push=PUSH)
        same, _ = balance.balance_controller(char, q0, t0, DT, push=PUSH)
        runs = {ctrl: physics.rollout(char.model, state, DT, NUM_STEPS, record_every=RECORD_EVERY, controller=c,
                                      controller_args=_with(args)) for ctrl, c in (("other", other), ("same", same))}
    assert compiled == [], compiled
    np.testing.assert_array_equal(runs["same"].trajectory.position, loop_runs["stand"].trajectory.position)
    assert float(jnp.max(jnp.abs(runs["other"].final.position - runs["same"].final.position))) > 1e-3


def test_bad_input(cmu):
    char, q0, t0, *_ = cmu
    with pytest.raises(JaxanimError, match="support: expected one of"):
        balance.balance_controller(char, q0, t0, DT, support="hull")
    with pytest.raises(JaxanimError, match="push: expected"):
        balance.balance_controller(char, q0, t0, DT, push=(np.zeros(3), "Spine"))
    with pytest.raises(JaxanimError, match=r"push force: expected shape \(3,\)"):
        balance.balance_controller(char, q0, t0, DT, push=(np.zeros(2), "Spine", 0.0, 0.1))
    with pytest.raises(JaxanimError, match="push body: unknown body 'Torso'; bodies are"):
        balance.balance_controller(char, q0, t0, DT, push=(np.zeros(3), "Torso", 0.0, 0.1))
    with pytest.raises(JaxanimError, match="leg_joints: unknown joint 'LeftKnee'; joints are"):
        balance.balance_controller(char, q0, t0, DT, leg_joints=(("LeftFoot", "LeftKnee"),))
    with pytest.raises(JaxanimError, match="leg_joints: joint 'RightLeg' is not between 'LeftFoot' and the root"):
        balance.stance_leg_joints(char, leg_joints=(("LeftFoot", "RightLeg"),))
    with pytest.raises(JaxanimError, match="ankle_names: no joint name contains"):
        balance.stance_leg_joints(char, ankle_names=("Ankle",))
    with pytest.raises(JaxanimError, match="foot_names: no body name contains"):
        balance.balance_controller(char, q0, t0, DT, foot_names=("Paw",))
    with pytest.raises(JaxanimError, match="dt: expected > 0"):
        balance.balance_controller(char, q0, t0, 0.0)


def test_sweep_example_smoke(cmu, tmp_path):
    """examples/balance_sweep.py on a 2 x 2 x 1 grid for 0.25 s (one extra compilation, ~30 s)."""
    pytest.importorskip("matplotlib")
    shared_data_dir()
    spec = importlib.util.spec_from_file_location("balance_sweep", REPO / "examples" / "balance_sweep.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = tmp_path / "map.png"
    ok = mod.main(["--grid", "2", "2", "1", "--seconds", "0.25", "--push-min", "100", "--push-max", "100",
                   "--push-start", "0.05", "--push-duration", "0.1", "--out", str(out)])
    assert ok.shape == (2, 2, 1) and ok.dtype == bool
    assert ok.all()  # 0.25 s is too short to fall
    assert out.is_file() and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
