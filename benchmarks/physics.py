"""Physics benchmark (``python -m benchmarks physics``): a ~20-body character standing under PD control
against MuJoCo C and MJX (throughput, standing accuracy), and a double pendulum; float64 only."""

from __future__ import annotations

import dataclasses
import functools
import pathlib
import time
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxanim import character, physics, read_bvh
from jaxanim import rotations as rot

from .peers import PeerUnavailable
from .peers import mujoco_physics as mp
from .report import Row, Table, Target, sel, usable_cores
from .timing import Runner, Timing, status_counts

__all__ = ["ACCELERATOR_SIZES", "CLIP", "DT", "PhysicsSizes", "StandingCharacter", "double_pendulum",
           "root_velocities", "run_physics", "standing_character"]

CLIP = "bvh/cmu_01_01_trim300.bvh"
STAND_FRAME = 200  # both feet flat, center of mass over them
BATCHES = (1, 64, 1024)
DT = 1 / 600
KP, KD = 2000.0, 200.0  # N m / rad, N m s / rad, every joint
ROOT_SPEED = 0.05  # m/s, seeded initial root velocity per character (x, z)
SEED = 0
PENDULUM_REF_DT = 1 / 19200
_MJ_LOOP = "MuJoCo C mj_step (Python loop)"
_MJ_ROLLOUT = "MuJoCo C rollout.rollout"
_MJX = "MJX jit(vmap(scan(mjx.step)))"


@dataclasses.dataclass(frozen=True)
class PhysicsSizes:
    """Sizes (``--quick`` and tests shrink them); ``contact_models``: ``"complementarity"``, ``"penalty"``, or
    ``"complementarity:8"`` (its 8 lowest points); 0 seconds skip a table; ``mjx_batches=None``: all batches."""

    batches: tuple[int, ...] = BATCHES
    steps_per_call: int = 20
    mjx_steps: int = 10
    mjx_batches: tuple[int, ...] | None = None
    contact_models: tuple[str, ...] = ("complementarity", "complementarity:8", "penalty")
    stand_seconds: float = 1.0
    pendulum_seconds: float = 1.0
    pendulum_dts: tuple[float, ...] = (1 / 600, 1 / 1200)


#: ``--gpu`` on a machine with an accelerator: the throughput table at 1,024 and 65,536 characters (each batch
#: compiles every row again, so the ladder is short) in the two contact models with targets, and MJX on the same
#: device at 65,536; the unbatched standing and pendulum tables (one character: latency, not throughput) are left
#: to the CPU run.
ACCELERATOR_SIZES = PhysicsSizes(batches=(1024, 65536), mjx_batches=(65536,), contact_models=("complementarity:8",
                                                                                               "penalty"),
                                 stand_seconds=0.0, pendulum_seconds=0.0)


#: Issue 29's targets on one H200 (``--gpu`` on an accelerator): µs per character-step at the best batch.
ACCELERATOR_TARGETS = [
    Target("accelerator: penalty contact ≥ 3 M character-steps/s at the best batch (≤ 0.333 µs per step)",
           sel("jaxanim rollout (penalty)"), 1 / 3),
    Target("accelerator: penalty contact ≥ MJX's character-steps/s at batch 65536 on the same device (speedup ≥ 1x)",
           sel("jaxanim rollout (penalty)", batch=65536), 1.0, versus=sel(_MJX, batch=65536)),
    Target("accelerator: complementarity on 8 points ≥ 1 M character-steps/s at the best batch (≤ 1 µs per step)",
           sel("jaxanim rollout (complementarity:8)"), 1.0)]


def clearance(state, body, local, radius) -> jax.Array:
    """The least signed distance (m; negative: penetrating) to the ground of contact points ``body, local, radius``."""
    return jnp.min(state.position[body, 1] + rot.quat_apply(state.orientation[body], local)[:, 1] - radius)


@dataclasses.dataclass(frozen=True)
class StandingCharacter:
    """The character, its start state, its SPD targets ``[J, 4]``, the free body's index, the ``contact`` points
    ``(body, local offset, radius)`` of one contact model and the controller args ``gains`` (``KP``, ``KD``)."""

    char: Any
    state: Any
    targets: Any
    root: int
    contact: tuple
    gains: dict

    def controller(self, state, step, args):
        return dict(spd=(self.targets, args["kp"], args["kd"]))

    def mjcf(self, dt: float) -> str:
        return character.export_mjcf(self.char, self.state, dt=dt, stiffness=KP, damping=KD)

    def batch_states(self, batch: int):
        """The start state broadcast to ``[batch, ...]`` with each character's root velocity."""
        states = jax.tree.map(lambda a: jnp.broadcast_to(a, (batch,) + a.shape), self.state)
        lv = states.linear_velocity.at[:, self.root].set(jnp.asarray(root_velocities(batch)))
        return eqx.tree_at(lambda s: s.linear_velocity, states, lv)


def root_velocities(batch: int) -> np.ndarray:
    """``[batch, 3]`` seeded root velocities (x, z uniform in ±ROOT_SPEED; y 0); a prefix of any larger batch."""
    v = np.random.default_rng(SEED).uniform(-ROOT_SPEED, ROOT_SPEED, size=(max(batch, 1024), 3))
    v[:, 1] = 0.0
    return v[:batch]


@functools.lru_cache(maxsize=None)
def standing_character(data_dir: pathlib.Path | str, contact_model: str = "complementarity") -> StandingCharacter:
    """The benchmark character (see the module docstring) with ``contact_model`` ground contact."""
    skel, motion = read_bvh(str(pathlib.Path(data_dir) / CLIP))[:2]
    name, _, cap = contact_model.partition(":")
    ground = physics.make_ground(name, max_points=int(cap) if cap else None, dtype=jnp.float64)
    q0, t0 = motion.rotations[STAND_FRAME], motion.translations[STAND_FRAME]
    char, state = character.build_character(skel, q0, t0, ground=ground)
    own, loc, rad = physics.contact_points(char.model.bodies)
    contact = (np.asarray(own), loc, rad)
    t0 = jnp.asarray(t0).at[skel.parents.index(-1), 1].add(-float(clearance(state, *contact)) / char.unit)
    char, state = character.build_character(skel, q0, t0, ground=ground)
    n = char.model.joints.num_joints
    return StandingCharacter(char, state, character.spd_targets(char, q0, t0), character.root_body(char), contact,
                             dict(kp=jnp.full((n,), KP), kd=jnp.full((n,), KD)))


def double_pendulum():
    """``(model, state)`` of the pendulum table's two capsules (see its description)."""
    r, length = 0.05, 0.4
    half = length / 2 + r
    bodies = physics.make_bodies([("capsule", (r, length)), ("capsule", (r, length))], names=("upper", "lower"),
                                 dtype=jnp.float64)
    d1, d2 = np.array([np.sin(0.6), -np.cos(0.6), 0.0]), np.array([0.0, -np.cos(0.5), np.sin(0.5)])
    elbow = 2 * half * d1
    toward = lambda d: rot.rotation_between(jnp.array([0.0, 0.0, 1.0]), jnp.asarray(d))  # noqa: E731
    state = physics.make_state(bodies, position=np.stack([half * d1, elbow + half * d2]),
                               orientation=jnp.stack([toward(d1), toward(d2)]))
    joints = physics.make_joints(bodies, state, [
        dict(name="shoulder", type="ball", parent=None, child="upper", anchor=(0.0, 0.0, 0.0)),
        dict(name="elbow", type="ball", parent="upper", child="lower", anchor=elbow)])
    return physics.make_model(bodies, joints), state


def _throughput_table(config, sz: PhysicsSizes) -> Table:
    batches = config.batches_for(sz.batches)
    mjx_batches = batches if sz.mjx_batches is None else tuple(sz.mjx_batches)
    n, nthread = sz.steps_per_call, usable_cores()
    ch0 = standing_character(config.data_dir, "complementarity")
    table = Table(
        "physics", f"Physics: a {ch0.char.num_bodies}-body character standing under PD control (character-steps per "
        "second)", accuracy_label="max |Δx| vs MuJoCo C, char 0 (m)", description=(
            f"The CMU skeleton (`{CLIP}`, frame {STAND_FRAME}: both feet flat) as {ch0.char.num_bodies} bodies with "
            f"{ch0.char.model.joints.num_joints} ball joints (70 kg), each held at its pose by stable PD (kp {KP:g} N "
            f"m/rad, kd {KD:g} N m s/rad); MuJoCo runs its `character.export_mjcf` (joint springs of the same "
            "stiffness and damping, Euler, condim 3 plane contact, μ 0.8). Character b starts with a seeded root "
            f"velocity (±{ROOT_SPEED} m/s along x, z). **µs / char is per character-step**: a call is {n} steps of "
            f"`batch` characters (MJX: {sz.mjx_steps}), dt = 1/{round(1 / DT)} s. jaxanim: "
            "`jax.jit(jax.vmap(physics.rollout))` (on the CPU a batch over 64 runs in chunks of 64, "
            "`physics._rollout.ROLLOUT_LANES`); MuJoCo C: a Python loop of `mj_step` per character (each `MjData` "
            f"reset to its start state every call), and `mujoco.rollout.rollout` on {nthread} threads (one `MjData` "
            f"per usable core, shared with the other rows); MJX: `jax.jit(jax.vmap(scan of mjx.step))` on the same "
            f"device as jaxanim ({jax.default_backend()}). "
            "Accuracy: character 0's body positions after the call vs MuJoCo C's (different contact and PD models: a "
            "difference, not an error)."),
        targets=[Target("penalty contact at batch 1024 at most 0.5x MuJoCo C's time per character-step (rollout on "
                        "all threads; speedup ≥ 2x)", sel("jaxanim rollout (penalty)", batch=1024, exact=True), 2.0,
                        versus=sel((_MJ_ROLLOUT, _MJ_LOOP), batch=1024)),
                 Target("complementarity on 8 points at batch 1024 at most MuJoCo C's time per character-step "
                        "(speedup ≥ 1x)", sel("jaxanim rollout (complementarity:8)", batch=1024, exact=True), 1.0,
                        versus=sel((_MJ_ROLLOUT, _MJ_LOOP), batch=1024)),
                 Target("one character's step within 5x MuJoCo C mj_step (speedup ≥ 0.2x)", sel("jaxanim", batch=1),
                        0.2, versus=sel(_MJ_LOOP, batch=1)),
                 Target("rollout compile ≤ 5 s (jaxanim rows)", sel("jaxanim"), 5.0, "compile", worst=True)]
        + (ACCELERATOR_TARGETS if config.accelerator else []))
    run = Runner(config, table)

    @functools.cache
    def mujoco() -> mp.MujocoSim:  # every batch's start states at once (PeerUnavailable without MuJoCo)
        return mp.MujocoSim(ch0.mjcf(DT), ch0.char.model.bodies.names, ch0.root, root_velocities(max(batches)))

    @functools.cache
    def mj_reference(nstep: int) -> np.ndarray:  # character 0's body positions after nstep MuJoCo C steps
        mujoco().step_loop(nstep, count=1)
        return mujoco().positions(0)

    def diff(pos, nstep: int) -> float | str:
        try:
            return float(np.max(np.abs(np.asarray(pos) - mj_reference(nstep))))
        except PeerUnavailable:
            return "n/a (no MuJoCo)"

    def mj_loop_row(b: int) -> Row:
        count = min(b, config.loop_cap)
        _, tm = run.python(mujoco().step_loop, n, count)
        return run.row(_MJ_LOOP, "float64", b, tm, count * n, accuracy="reference",
                       note=f"Python loop over {count} of {b} characters" if count < b else "Python loop")

    def mj_rollout_row(b: int) -> Row:
        sim = mujoco()
        out, tm = run.python(sim.rollout, n, [sim.mujoco.MjData(sim.model) for _ in range(nthread)], b)
        return run.row(_MJ_ROLLOUT, "float64", b, tm, b * n, accuracy=diff(sim.positions(state=out[0, -1]), n),
                       note=f"nthread = {nthread}, persistent C++ thread pool")

    def mjx_row(b: int) -> Row:
        qpos, tm, comp = run.jax(*mp.mjx_rollout(mujoco(), sz.mjx_steps, b))
        return run.row(_MJX, "float64", b, tm, b * sz.mjx_steps, comp, diff(
            mujoco().positions(qpos=np.asarray(qpos[0])), sz.mjx_steps),
            note=f"{sz.mjx_steps} steps per call, {jax.default_backend()}")

    def jax_row(model: str, b: int, impl: str) -> Row:
        ch = standing_character(config.data_dir, model)

        def one(s, args):
            r = physics.rollout(ch.char.model, s, DT, n, record_every=n, controller=ch.controller, controller_args=args)
            return r.final.position, r.result, r.num_steps

        (pos, result, steps), tm, comp = run.jax(jax.vmap(one, in_axes=(0, None)), ch.batch_states(b), ch.gains)
        ok = np.asarray(result == physics.SimResult.successful) & (np.asarray(steps) == n)
        return run.row(impl, "float64", b, tm, b * n, comp, diff(np.asarray(pos[0]), n), success=float(ok.mean()),
                       status=status_counts(result, physics.SimResult), note=f"{model} contact")

    for b in batches:
        run.add(_MJ_LOOP, "float64", b, lambda: mj_loop_row(b), peer=True)
        run.add(_MJ_ROLLOUT, "float64", b, lambda: mj_rollout_row(b), peer=True)
        for model in sz.contact_models:
            impl = f"jaxanim rollout ({model})"
            run.add(impl, "float64", b, lambda: jax_row(model, b, impl))
        if b in mjx_batches:
            run.add(_MJX, "float64", b, lambda: mjx_row(b), peer=True)
    if any(r.implementation == _MJ_ROLLOUT and r.measured for r in table.rows):
        from mujoco import rollout as mj_rollout

        mj_rollout.shutdown_persistent_pool()
    return table


def _summary(ys: np.ndarray, y0: float, penetration: float, separation: float, total: int, wall: float) -> str:
    return (f"root y {y0:.4f} → {ys[-1]:.4f} m (change {ys.min() - y0:+.4f} / {ys.max() - y0:+.4f}), penetration "
            f"{max(-penetration, 0):.2e} m, joint separation {separation:.1e} m; {total} steps in {wall:.2f} s")


def _standing_table(config, sz: PhysicsSizes) -> Table:
    secs = sz.stand_seconds
    table = Table(
        "physics-standing", f"Physics: standing character, {secs:g} s, accuracy",
        accuracy_label="max |root y − MuJoCo's| (m)", description=(
            f"One character (the table above's character 0, no initial velocity) for {secs:g} s of simulated time, one "
            "unbatched run per call (µs / char is per step). Root height `y` of the free body's center of mass: start "
            "→ end and min / max change (sampled every 10 ms); penetration: the deepest contact point under the plane "
            "(jaxanim: signed distance of its contact points, every 10 ms; MuJoCo: `contact.dist`, every step; its "
            "contacts are soft); joint separation: jaxanim's max constraint drift (`physics.joint_error`; MuJoCo's "
            "reduced coordinates have none). Accuracy: max |root y − MuJoCo C's| over the samples."))
    run = Runner(config, table)
    ch0 = standing_character(config.data_dir, "complementarity")
    y0, k = float(ch0.state.position[ch0.root, 1]), max(1, round(0.01 / DT))  # samples every k steps (10 ms)
    total, mj = int(round(secs / DT)) // k * k, {}

    def mj_row(impl: str) -> Row:
        sim = mp.MujocoSim(ch0.mjcf(DT), ch0.char.model.bodies.names, ch0.root, np.zeros((1, 3)))
        d, ys, pen = sim.reset(0), [], 0.0
        t0 = time.perf_counter()
        for i in range(total):
            sim.mujoco.mj_step(sim.model, d)
            pen = min(pen, float(d.contact.dist[:d.ncon].min())) if d.ncon else pen
            if (i + 1) % k == 0:
                ys.append(sim.positions(0)[ch0.root, 1])
        wall = time.perf_counter() - t0
        mj["ys"] = np.asarray(ys)
        return run.row(impl, "float64", 1, Timing(wall, None, 1), total, accuracy="reference",
                       note=f"dt 1/{round(1 / DT)}: " + _summary(mj["ys"], y0, pen, 0.0, total, wall))

    def jax_row(model: str, impl: str) -> Row:
        ch = standing_character(config.data_dir, model)
        fn = lambda s, a: physics.rollout(ch.char.model, s, DT, total, record_every=k,  # noqa: E731
                                          controller=ch.controller, controller_args=a)
        out, tm, comp = run.jax(fn, ch.state, ch.gains)
        ys = np.asarray(out.trajectory.position[:, ch.root, 1])
        clear = float(np.min(jax.vmap(lambda s: clearance(s, *ch.contact))(out.trajectory)))
        drift = float(np.max(jax.vmap(lambda s: physics.joint_error(ch.char.model, s))(out.trajectory)))
        ok = bool(out.result == physics.SimResult.successful) and int(out.num_steps) == total
        acc = float(np.max(np.abs(ys - mj["ys"]))) if mj else "n/a (no MuJoCo)"
        return run.row(impl, "float64", 1, tm, total, comp, acc, success=float(ok), note=(
            f"{model} contact, dt 1/{round(1 / DT)}: " + _summary(ys, y0, clear, drift, total, tm.median)))

    impl = f"MuJoCo C mj_step (dt 1/{round(1 / DT)})"
    run.add(impl, "float64", 1, lambda: mj_row(impl), peer=True)
    for model in sz.contact_models:
        impl = f"jaxanim rollout ({model})"
        run.add(impl, "float64", 1, lambda: jax_row(model, impl))
    return table


def _pendulum_table(config, sz: PhysicsSizes) -> Table:
    secs = sz.pendulum_seconds
    table = Table(
        "physics-pendulum", f"Physics: double pendulum (2 capsules, ball joints), {secs:g} s, accuracy",
        accuracy_label=f"max body position error vs MuJoCo dt 1/{round(1 / PENDULUM_REF_DT)} (m)", description=(
            "Two capsules (radius 0.05 m, 0.4 m between cap centers, 1000 kg/m³) hanging from the origin by ball "
            "joints, released with the lower link out of the upper one's plane (3-D motion), no contact, exported "
            "with `physics.to_mjcf`. jaxanim `physics.rollout` and MuJoCo C (`mj_step`, Euler, one unbatched run per "
            f"call) at each dt, against MuJoCo at dt 1/{round(1 / PENDULUM_REF_DT)} (the reference); both schemes are "
            "first order. Notes: the difference to MuJoCo at the same dt, the max joint separation (drift)."))
    run = Runner(config, table)
    model, state = double_pendulum()

    @functools.cache
    def mujoco_run(dt: float) -> tuple[np.ndarray, float]:  # final body positions, wall seconds
        mujoco = mp.load_mujoco()
        m = mujoco.MjModel.from_xml_string(physics.to_mjcf(model, state, dt=dt))
        d = mujoco.MjData(m)
        t0 = time.perf_counter()
        for _ in range(int(round(secs / dt))):
            mujoco.mj_step(m, d)
        wall = time.perf_counter() - t0
        mujoco.mj_kinematics(m, d)
        return d.xpos[[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in model.bodies.names]], wall

    def error(pos, dt: float) -> float | str:
        try:
            return float(np.max(np.abs(np.asarray(pos) - mujoco_run(dt)[0])))
        except PeerUnavailable:
            return "n/a (no MuJoCo)"

    def mj_row(dt: float, impl: str) -> Row:
        (pos, wall), n = mujoco_run(dt), int(round(secs / dt))
        return run.row(impl, "float64", 1, Timing(wall, None, 1), n, accuracy=error(pos, PENDULUM_REF_DT),
                       note=f"{n} steps, Python loop")

    def jax_row(dt: float, impl: str) -> Row:
        n = int(round(secs / dt))
        k = max(1, n // 100)
        n = n // k * k
        out, tm, comp = run.jax(lambda s: physics.rollout(model, s, dt, n, record_every=k), state)
        pos = np.asarray(out.final.position)
        drift = float(np.max(jax.vmap(lambda s: physics.joint_error(model, s))(out.trajectory)))
        same = error(pos, dt)
        same = f"{same:.2e} m vs MuJoCo at the same dt" if isinstance(same, float) else "no MuJoCo"
        return run.row(impl, "float64", 1, tm, n, comp, error(pos, PENDULUM_REF_DT),
                       success=float(bool(out.result == physics.SimResult.successful)),
                       note=f"{same}; joint separation {drift:.1e} m (max over the run); {n} steps")

    for dt in sz.pendulum_dts:
        mj, ja = f"MuJoCo C mj_step (dt 1/{round(1 / dt)})", f"jaxanim rollout (dt 1/{round(1 / dt)})"
        run.add(mj, "float64", 1, lambda: mj_row(dt, mj), peer=True)
        run.add(ja, "float64", 1, lambda: jax_row(dt, ja))
    return table

TABLES = ("throughput", "standing", "pendulum")


def run_physics(config, sizes: PhysicsSizes | None = None, tables: tuple[str, ...] = TABLES) -> list[Table]:
    """The ``physics`` benchmark (see the module docstring); ``sizes`` and ``tables`` shrink it for tests."""
    unknown = set(tables) - set(TABLES)
    if unknown:
        raise ValueError(f"tables: unknown {sorted(unknown)}; expected some of {TABLES}")
    sz = sizes or config.pick(PhysicsSizes(), accelerator=ACCELERATOR_SIZES, quick=PhysicsSizes(
        steps_per_call=5, mjx_steps=2, mjx_batches=(max(config.batches_for(BATCHES)),), stand_seconds=0.1,
        pendulum_seconds=0.2))
    config.float64_only("physics", "MuJoCo is float64")
    out: list[Table] = []
    path = config.data_file(CLIP)
    for name, make, title in (("throughput", _throughput_table, "physics"),
                              ("standing", _standing_table, "physics-standing")):
        if name in tables and isinstance(path, str):
            out.append(Table(title, f"Physics: {name}", skipped=path))
        elif name in tables and (name != "standing" or sz.stand_seconds > 0):
            out.append(make(config, sz))
    if "pendulum" in tables and sz.pendulum_seconds > 0:
        out.append(_pendulum_table(config, sz))
    return out
