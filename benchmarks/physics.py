"""Physics benchmark (``python -m benchmarks physics``): a ~20-body character standing under PD control.

Problem: the CMU skeleton of ``bvh/cmu_01_01_trim300.bvh`` (shared data) built with
:func:`jaxanim.character.build_character` (21 bodies, 20 ball joints, 70 kg) at clip frame
:data:`STAND_FRAME`, a crouch with both feet flat and the centre of mass over them (frame 0 stands on
one foot and tips over at once), lowered so that its lowest contact point touches the ground plane.
Every joint is held at that pose by stable PD (``spd`` of :func:`jaxanim.physics.step`, ``kp`` =
:data:`KP`, ``kd`` = :data:`KD` on every joint); MuJoCo runs
:func:`jaxanim.character.export_mjcf` of the same character with joint springs of the same
stiffness and damping (explicit spring, implicit damping, ``integrator="Euler"``), the same ``dt``
and gravity, Coulomb friction ``mu`` = 0.8 on a plane. Character ``b`` of a batch starts with a seeded
root velocity (``±`` :data:`ROOT_SPEED` m/s along x and z), the same in every implementation.

Tables:

1. **Step throughput** (``physics``), batches 1, 64, 1024: ``time / call`` is one call of
   ``steps_per_call`` steps of ``batch`` characters; **µs / char is per character-step** (time /
   (batch x steps)). Rows: jaxanim ``jax.jit(jax.vmap(rollout))`` with complementarity contact and
   with penalty contact (penalty at its own ``dt`` if it needs a smaller one; the row says so);
   MuJoCo C as a Python loop of ``mj_step`` over ``B`` ``MjData`` (capped at ``loop_cap``
   characters, reset to the start state every call); MuJoCo ``mujoco.rollout.rollout`` (C++ thread
   pool, one ``MjData`` per usable core); MJX ``jax.jit(jax.vmap(scan of mjx.step))`` over fewer steps
   (MJX on CPU is slow). Compile: ``lower + compile`` of the jitted function. Accuracy: max body
   position difference (m) of character 0 after the call's steps against MuJoCo C (``mj_step``) at
   the same ``dt`` (a different contact and PD model: a difference, not an error).
2. **Standing accuracy** (``physics-standing``): one character, :attr:`PhysicsSizes.stand_seconds`
   of simulated time: root height (start, end, min / max drift), deepest penetration of a contact
   point (jaxanim: signed distance of its contact points; MuJoCo: ``contact.dist``), max joint
   separation (jaxanim's constraint drift; MuJoCo has none, reduced coordinates). Accuracy: max
   |root height − MuJoCo's| over the run.
3. **Double pendulum** (``physics-pendulum``): two capsules (r 0.05 m, 0.4 m between cap centres)
   with ball joints, released out of plane (as ``tests/test_physics.py``), no contact:
   jaxanim and MuJoCo C at dt 1/600 and 1/1200 against MuJoCo at dt 1/19200 (reference);
   accuracy: max body position error after :attr:`PhysicsSizes.pendulum_seconds` against the
   reference; notes: against MuJoCo at the same dt, and the max joint separation over the run.

Targets (benchmark targets, not tests; the notes say met / missed): ≤ 35 µs per character-step at
batch 1024; one character's step within 5x MuJoCo C's (``mj_step``); rollout compile ≤ 5 s.

Runs in float64 only (MuJoCo is float64); ``--dtype`` is ignored.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import pathlib
import time
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import BenchConfig
from .peers import PeerUnavailable
from .report import Row, Table, measure_row
from .timing import SampledTiming, compile_time, load_note, sample_call

__all__ = [
    "BATCHES",
    "CLIP",
    "DT",
    "KD",
    "KP",
    "PhysicsSizes",
    "STAND_FRAME",
    "StandingCharacter",
    "double_pendulum",
    "run_physics",
    "standing_character",
]

CLIP = "bvh/cmu_01_01_trim300.bvh"
STAND_FRAME = 200  # both feet flat, centre of mass over them
BATCHES = (1, 64, 1024)
DT = 1 / 600
PENALTY_DT = 1 / 600
KP, KD = 2000.0, 200.0  # N m / rad, N m s / rad, every joint
ROOT_SPEED = 0.05  # m/s, seeded initial root velocity per character (x, z)
SEED = 0
PENDULUM_DTS = (1 / 600, 1 / 1200)
PENDULUM_REF_DT = 1 / 19200
_CALL_BUDGET_FACTOR = 4.0
_MJ_LOOP = "MuJoCo C mj_step (Python loop)"
_MJ_ROLLOUT = "MuJoCo C rollout.rollout"
_MJX = "MJX jit(vmap(scan(mjx.step)))"


@dataclasses.dataclass(frozen=True)
class PhysicsSizes:
    """Sizes; the defaults are the issue's (``--quick`` and tests shrink them).

    Attributes:
        batches: batch sizes (``config.batches`` overrides them).
        steps_per_call: steps per timed call (jaxanim, MuJoCo C).
        mjx_steps: steps per timed MJX call.
        mjx_batches: MJX batch sizes (``None``: the same as ``batches``; each costs a compilation).
        contact_models: jaxanim contact models to time (``"complementarity"``, ``"penalty"``;
            ``"complementarity:8"``: only the 8 lowest contact points, ``make_ground(max_points=8)``).
        penalty_dt: the penalty model's step.
        stand_seconds: simulated time of the standing-accuracy runs (0 skips the table).
        pendulum_seconds: simulated time of the double-pendulum runs (0 skips the table).
        pendulum_dts: the double pendulum's steps (the reference is MuJoCo at ``PENDULUM_REF_DT``).
    """

    batches: tuple[int, ...] = BATCHES
    steps_per_call: int = 20
    mjx_steps: int = 10
    mjx_batches: tuple[int, ...] | None = None
    contact_models: tuple[str, ...] = ("complementarity", "complementarity:8", "penalty")
    penalty_dt: float = PENALTY_DT
    stand_seconds: float = 1.0
    pendulum_seconds: float = 1.0
    pendulum_dts: tuple[float, ...] = PENDULUM_DTS

    @classmethod
    def quick(cls, batches: tuple[int, ...]) -> PhysicsSizes:
        """Few steps, MJX at the largest batch only, short accuracy runs."""
        return cls(steps_per_call=5, mjx_steps=2, mjx_batches=(max(batches),), stand_seconds=0.1,
                   pendulum_seconds=0.2)


# --- problem ----------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class StandingCharacter:
    """The character, its start state and its PD targets, for one contact model.

    Attributes:
        char: the :class:`jaxanim.character.Character`.
        state: the start state (assembly pose, at rest, lowest contact point on the ground).
        targets: ``[J, 4]`` SPD targets (the assembly pose).
        root: the free body's index.
        contact_body, contact_local, contact_radius: the contact points (see
            :func:`jaxanim.contact.contact_points`).
    """

    char: Any
    state: Any
    targets: Any
    root: int
    contact_body: np.ndarray
    contact_local: Any
    contact_radius: Any

    @property
    def num_joints(self) -> int:
        return self.char.model.joints.num_joints

    def gains(self, kp: float = KP, kd: float = KD) -> dict:
        """Controller args ``dict(kp=[J], kd=[J])``."""
        return dict(kp=jnp.full((self.num_joints,), kp), kd=jnp.full((self.num_joints,), kd))

    def controller(self, state, step, args):
        return dict(spd=(self.targets, args["kp"], args["kd"]))

    def clearance(self, state) -> jax.Array:
        """The smallest signed distance of a contact point to the ground (m; negative: penetrating)."""
        from jaxanim import rotations as rot

        b = self.contact_body
        y = state.position[b, 1] + rot.quat_apply(state.orientation[b], self.contact_local)[:, 1]
        return jnp.min(y - self.contact_radius)

    def mjcf(self, dt: float) -> str:
        from jaxanim import character

        return character.export_mjcf(self.char, self.state, dt=dt, stiffness=KP, damping=KD)

    def batch_states(self, batch: int):
        """The start state broadcast to ``[batch, ...]`` with each character's root velocity."""
        v = root_velocities(batch)
        states = jax.tree.map(lambda a: jnp.broadcast_to(a, (batch,) + a.shape), self.state)
        lv = states.linear_velocity.at[:, self.root].set(jnp.asarray(v))
        return eqx.tree_at(lambda s: s.linear_velocity, states, lv)


def root_velocities(batch: int) -> np.ndarray:
    """``[batch, 3]`` seeded root velocities (x, z uniform in ±ROOT_SPEED; y 0); a prefix of any larger batch."""
    rng = np.random.default_rng(SEED)
    v = rng.uniform(-ROOT_SPEED, ROOT_SPEED, size=(max(batch, 1024), 3))
    v[:, 1] = 0.0
    return v[:batch]


@functools.lru_cache(maxsize=None)
def _load_clip(path: str):
    import jaxanim

    skel, motion = jaxanim.read_bvh(path)[:2]
    return skel, motion


def standing_character(data_dir: pathlib.Path | str, contact_model: str = "complementarity") -> StandingCharacter:
    """The benchmark character (see the module docstring) with ``contact_model`` ground contact."""
    from jaxanim import character, contact
    from jaxanim import rotations as rot

    skel, motion = _load_clip(str(pathlib.Path(data_dir) / CLIP))
    name, _, cap = contact_model.partition(":")
    ground = contact.make_ground(name, max_points=int(cap) if cap else None, dtype=jnp.float64)
    q0, t0 = motion.rotations[STAND_FRAME], motion.translations[STAND_FRAME]
    char, state = character.build_character(skel, q0, t0, ground=ground)
    own, loc, rad = contact.contact_points(char.model.bodies)
    own = np.asarray(own)

    def lowest(s):
        return float(jnp.min(s.position[own, 1] + rot.quat_apply(s.orientation[own], loc)[:, 1] - rad))

    root_joint = skel.parents.index(-1)
    t0 = jnp.asarray(t0).at[root_joint, 1].add(-lowest(state) / char.unit)
    char, state = character.build_character(skel, q0, t0, ground=ground)
    targets = character.spd_targets(char, q0, t0)
    return StandingCharacter(char, state, targets, character.root_body(char), own, loc, rad)


# --- double pendulum (as tests/test_physics.py) -------------------------------------------------------
def double_pendulum():
    """``(model, state)``: two capsules (radius 0.05 m, 0.4 m between cap centres) hanging from the
    origin by ball joints, released with the lower link out of the upper one's plane."""
    from jaxanim import joints, physics, rigid
    from jaxanim import rotations as rot

    r, length = 0.05, 0.4
    half = length / 2 + r
    bodies = rigid.make_bodies([("capsule", (r, length)), ("capsule", (r, length))], names=("upper", "lower"),
                               dtype=jnp.float64)
    d1 = np.array([np.sin(0.6), -np.cos(0.6), 0.0])
    d2 = np.array([0.0, -np.cos(0.5), np.sin(0.5)])
    elbow = 2 * half * d1
    toward = lambda d: rot.rotation_between(jnp.array([0.0, 0.0, 1.0]), jnp.asarray(d))  # noqa: E731
    state = rigid.make_state(bodies, position=np.stack([half * d1, elbow + half * d2]),
                             orientation=jnp.stack([toward(d1), toward(d2)]))
    J = joints.make_joints(bodies, state, [
        dict(name="shoulder", type="ball", parent=None, child="upper", anchor=(0.0, 0.0, 0.0)),
        dict(name="elbow", type="ball", parent="upper", child="lower", anchor=elbow),
    ])
    return physics.make_model(bodies, J), state


# --- row machinery ------------------------------------------------------------------------------------
@dataclasses.dataclass
class _Context:
    config: BenchConfig
    sizes: PhysicsSizes
    chars: dict = dataclasses.field(default_factory=dict)  # contact model -> StandingCharacter | str
    sims: dict = dataclasses.field(default_factory=dict)  # dt -> MujocoSim
    refs: dict = dataclasses.field(default_factory=dict)  # (dt, nstep) -> positions of character 0
    records: dict = dataclasses.field(default_factory=dict)  # (impl, batch) -> dict
    compiles: list = dataclasses.field(default_factory=list)  # (impl, batch, CompileStats)


_sample = sample_call


def _timing_note(tm: SampledTiming) -> str:
    return f"; {tm.samples} timed call{'s' if tm.samples != 1 else ''}" if tm.samples < 3 else ""


def _log_row(config: BenchConfig, table: str, row: Row) -> None:
    if row.skipped is not None:
        config.log(f"physics {table} B={row.batch}: {row.implementation}: {row.skipped}")
        return
    comp = "" if row.compile_s is None else f", compile {row.compile_s:.2f} s"
    us = "" if row.us_per_char is None else f"{row.us_per_char:.4g} µs/char-step"
    config.log(f"physics {table} B={row.batch}: {row.implementation}: {us}{comp}, accuracy {row.accuracy}")


def _add_row(config: BenchConfig, table: Table, impl: str, batch: int | None, make_row: Callable[[], Row],
             is_peer: bool, failures: dict) -> Row | None:
    return measure_row(config, table, impl, batch, make_row, is_peer, failures,
                       lambda row: _log_row(config, table.name, row))


def _character(ctx: _Context, model: str) -> StandingCharacter:
    if model not in ctx.chars:
        ctx.chars[model] = standing_character(ctx.config.data_dir, model)
    return ctx.chars[model]


def _sim(ctx: _Context, dt: float, batch: int):
    """The MuJoCo model of the character at ``dt`` with ``batch`` characters (cached per dt, grown)."""
    from .peers import mujoco_physics as mp

    sim = ctx.sims.get(dt)
    if sim is None or sim.batch < batch:
        ch = _character(ctx, "complementarity")
        sim = mp.MujocoSim(ch.mjcf(dt), ch.char.model.bodies.names, ch.root, root_velocities(batch))
        ctx.sims[dt] = sim
    return sim


def _reference(ctx: _Context, dt: float, nstep: int) -> np.ndarray | None:
    """Character 0's body positions after ``nstep`` MuJoCo C steps at ``dt`` (``None`` without MuJoCo)."""
    key = (dt, nstep)
    if key not in ctx.refs:
        try:
            sim = _sim(ctx, dt, 1)
        except PeerUnavailable:
            ctx.refs[key] = None
        else:
            sim.step_loop(nstep, count=1)
            ctx.refs[key] = sim.positions(0)
    return ctx.refs[key]


def _diff(pos: np.ndarray, ref: np.ndarray | None) -> float | str:
    return "n/a (no MuJoCo)" if ref is None else float(np.max(np.abs(np.asarray(pos) - ref)))


def _budget_skip(ctx: _Context, impl: str, b: int) -> str | None:
    prev = sorted((bb, r) for (i, bb), r in ctx.records.items() if i == impl and bb < b)
    if not prev:
        return None
    bb, rec = prev[-1]
    est = rec["call_s"] * b / bb
    budget = _CALL_BUDGET_FACTOR * ctx.config.max_row_s
    if est > budget:
        return f"not run (time budget): ~{est:.0f} s per call expected from batch {bb}, over {budget:.0f} s"
    return None


# --- 1. throughput -------------------------------------------------------------------------------------
def _jax_fn(ch: StandingCharacter, dt: float, nstep: int):
    from jaxanim import physics

    def one(s, args):
        r = physics.rollout(ch.char.model, s, dt, nstep, record_every=nstep, controller=ch.controller,
                            controller_args=args)
        return r.final.position, r.result._value, r.num_steps

    return jax.jit(jax.vmap(one, in_axes=(0, None)))


def _throughput_table(ctx: _Context) -> Table:
    from .peers import mujoco_physics as mp

    config, sz = ctx.config, ctx.sizes
    batches = config.batches_for(sz.batches)
    mjx_batches = tuple(sz.mjx_batches) if sz.mjx_batches is not None else batches
    n = sz.steps_per_call
    nthread = mp.cpu_threads()
    table = Table(
        "physics", f"Physics: a {_character(ctx, 'complementarity').char.num_bodies}-body character standing under "
        "PD control (character-steps per second)",
        accuracy_label="max |Δx| vs MuJoCo C, char 0 (m)",
        description=(
            f"The CMU skeleton (`{CLIP}`, frame {STAND_FRAME}: both feet flat) as "
            f"{_character(ctx, 'complementarity').char.num_bodies} bodies with "
            f"{_character(ctx, 'complementarity').num_joints} ball joints (70 kg), every joint held at its pose by "
            f"stable PD (kp {KP:g} N m/rad, kd {KD:g} N m s/rad); MuJoCo runs `character.export_mjcf` of it "
            "(joint springs of the same stiffness and damping, Euler, condim 3 plane contact, μ 0.8). Character b "
            f"starts with a seeded root velocity (±{ROOT_SPEED} m/s along x, z). **µs / char is per "
            f"character-step**: a call is {n} steps of `batch` characters (MJX: {sz.mjx_steps} steps); "
            f"dt = 1/{round(1 / DT)} s unless the row says otherwise. jaxanim: `jax.jit(jax.vmap(physics.rollout))` "
            "over the characters' states. MuJoCo C: a Python loop of `mj_step` per character (each `MjData` reset "
            f"to its start state every call), and `mujoco.rollout.rollout` with {nthread} threads (one `MjData` "
            "per usable core). MJX: `jax.jit(jax.vmap(scan of mjx.step))`. Accuracy: max body-position difference "
            "of character 0 after the call's steps against MuJoCo C at the same dt (different contact and PD "
            "models: a difference, not an error)."
        ),
    )
    failures: dict = {}
    try:
        _sim(ctx, DT, max(batches))  # every batch's start states at once
    except PeerUnavailable:
        pass

    def mj_loop_row(b: int) -> Row:
        sim = _sim(ctx, DT, b)
        count = min(b, config.loop_cap)
        t0 = time.perf_counter()
        sim.step_loop(n, count)
        tm = _sample(config, lambda: sim.step_loop(n, count), (), time.perf_counter() - t0)
        acc = "reference"
        ctx.records[(_MJ_LOOP, b)] = dict(us=tm.median / (count * n) * 1e6, call_s=tm.median)
        note = f"Python loop over {count} of {b} characters" if count < b else "Python loop"
        return Row(_MJ_LOOP, "float64", b, tm.median, tm.min, count * n, None, acc, is_peer=True,
                   note=note + _timing_note(tm))

    def mj_rollout_row(b: int) -> Row:
        sim = _sim(ctx, DT, b)
        pool = [sim.mujoco.MjData(sim.model) for _ in range(nthread)]
        t0 = time.perf_counter()
        out = sim.rollout(n, pool, b)
        tm = _sample(config, lambda: sim.rollout(n, pool, b), (), time.perf_counter() - t0)
        acc = _diff(sim.positions_from_state(out[0, -1]), _reference(ctx, DT, n))
        ctx.records[(_MJ_ROLLOUT, b)] = dict(us=tm.median / (b * n) * 1e6, call_s=tm.median)
        return Row(_MJ_ROLLOUT, "float64", b, tm.median, tm.min, b * n, None, acc, is_peer=True,
                   note=f"nthread = {nthread}, persistent C++ thread pool" + _timing_note(tm))

    def mjx_row(b: int) -> Row:
        sim = _sim(ctx, DT, b)
        fn, args = mp.mjx_rollout(sim, sz.mjx_steps, b)
        cs = compile_time(fn, *args)
        ctx.compiles.append((_MJX, b, cs))
        t0 = time.perf_counter()
        qpos = jax.block_until_ready(cs.compiled(*args))
        tm = _sample(config, cs.compiled, args, time.perf_counter() - t0)
        acc = _diff(sim.positions_from_qpos(np.asarray(qpos[0])), _reference(ctx, DT, sz.mjx_steps))
        ctx.records[(_MJX, b)] = dict(us=tm.median / (b * sz.mjx_steps) * 1e6, call_s=tm.median)
        return Row(_MJX, "float64", b, tm.median, tm.min, b * sz.mjx_steps, cs.total, acc, is_peer=True,
                   note=f"mujoco-mjx {mp.mjx_version()}, {sz.mjx_steps} steps per call, CPU" + _timing_note(tm))

    def jax_row(model: str, b: int, impl: str) -> Row:
        ch = _character(ctx, model)
        dt = sz.penalty_dt if model == "penalty" else DT
        args = (ch.batch_states(b), ch.gains())
        cs = compile_time(_jax_fn(ch, dt, n), *args)
        ctx.compiles.append((impl, b, cs))
        t0 = time.perf_counter()
        pos, code, steps = jax.block_until_ready(cs.compiled(*args))
        tm = _sample(config, cs.compiled, args, time.perf_counter() - t0)
        ok = (np.asarray(code) == 0) & (np.asarray(steps) == n)
        acc = _diff(np.asarray(pos[0]), _reference(ctx, dt, n))
        ctx.records[(impl, b)] = dict(us=tm.median / (b * n) * 1e6, call_s=tm.median)
        note = f"{model} contact" + (f", dt = 1/{round(1 / dt)} s" if dt != DT else "")
        return Row(impl, "float64", b, tm.median, tm.min, b * n, cs.total, acc, success=float(ok.mean()),
                   note=note + _timing_note(tm))

    for b in batches:
        _add_row(config, table, _MJ_LOOP, b, lambda b=b: mj_loop_row(b), True, failures)
        _add_row(config, table, _MJ_ROLLOUT, b, lambda b=b: mj_rollout_row(b), True, failures)
        if b in mjx_batches:
            _add_row(config, table, _MJX, b, lambda b=b: mjx_row(b), True, failures)
        for model in sz.contact_models:
            impl = f"jaxanim rollout ({model})"
            why = _budget_skip(ctx, impl, b)
            if why is not None and config.selects(impl):
                table.rows.append(Row(impl, "float64", b, skipped=why))
                config.log(f"physics B={b}: {impl}: {why}")
                continue
            _add_row(config, table, impl, b, lambda m=model, b=b, i=impl: jax_row(m, b, i), False, failures)
    table.notes += _throughput_notes(ctx, batches, nthread)
    if any(r.implementation == _MJ_ROLLOUT and r.skipped is None for r in table.rows):
        from mujoco import rollout as mj_rollout

        mj_rollout.shutdown_persistent_pool()
    return table


def _throughput_notes(ctx: _Context, batches, nthread: int) -> list[str]:
    r = ctx.records
    notes = []
    big = max(batches)
    own = [(v["us"], i) for (i, b), v in r.items() if b == big and i.startswith("jaxanim")]
    if own:
        us, impl = min(own)
        line = f"Target: ≤ 35 µs per character-step at batch 1024: {impl} {us:.3g} µs at batch {big}"
        line += f": {'met' if us <= 35 else 'missed'}." if big == 1024 else " (batch 1024 not run)."
        peers = [f"{i} {v['us']:.3g} µs" for (i, b), v in r.items() if b == big and not i.startswith("jaxanim")]
        if peers:
            line += " Peers at that batch: " + ", ".join(peers) + "."
        notes.append(line)
    mj1 = r.get((_MJ_LOOP, 1))
    own1 = [(v["us"], i) for (i, b), v in r.items() if b == 1 and i.startswith("jaxanim")]
    if mj1 and own1:
        us, impl = min(own1)
        ratio = us / mj1["us"]
        notes.append(f"Target: one character's step within 5x MuJoCo C: {impl} {us:.3g} µs vs mj_step "
                     f"{mj1['us']:.3g} µs = {ratio:.3g}x: {'met' if ratio <= 5 else 'missed'}.")
    comp = [(cs.total, f"{i} batch {b}") for i, b, cs in ctx.compiles if i.startswith("jaxanim")]
    if comp:
        worst, what = max(comp)
        notes.append(f"Target: rollout compile ≤ 5 s: {min(comp)[0]:.1f}–{worst:.1f} s over {len(comp)} "
                     f"compilations (worst: {what}): {'met' if worst <= 5 else 'missed'}.")
    mjx = [(cs.total, b) for i, b, cs in ctx.compiles if i == _MJX]
    if mjx:
        notes.append("MJX compile: " + ", ".join(f"{c:.1f} s (batch {b})" for c, b in mjx) + ".")
    notes.append(
        f"MuJoCo rollout uses {nthread} threads (the cores usable by this process); the mj_step loop and jaxanim "
        "share the same cores (XLA's CPU backend parallelises inside an op). Versions: "
        + _versions() + "."
    )
    return notes


def _versions() -> str:
    import importlib.metadata as md

    out = []
    for dist in ("mujoco", "mujoco-mjx"):
        try:
            out.append(f"{dist} {md.version(dist)}")
        except md.PackageNotFoundError:
            out.append(f"{dist} not installed")
    return ", ".join(out)


# --- 2. standing accuracy -----------------------------------------------------------------------------
def _standing_table(ctx: _Context) -> Table:
    from jaxanim import physics

    config, sz = ctx.config, ctx.sizes
    secs = sz.stand_seconds
    table = Table(
        "physics-standing", f"Physics: standing character, {secs:g} s, accuracy",
        accuracy_label="max |root y − MuJoCo's| (m)",
        description=(
            f"One character (the table above's character 0, no initial velocity) for {secs:g} s of simulated time. "
            "Root height `y` of the free body's centre of mass: start → end and min / max change over the run "
            "(sampled every 10 ms); penetration: the deepest contact point under the plane over the run (jaxanim: "
            "signed distance of its contact points, sampled every 10 ms; MuJoCo: `contact.dist`, every step; MuJoCo's "
            "contacts are soft, so some penetration is its model); joint separation: jaxanim's max constraint "
            "drift (`physics.joint_error`; MuJoCo's reduced coordinates have none). Accuracy: max |root y − "
            "MuJoCo C's at the same dt| over the samples."
        ),
    )
    failures: dict = {}
    mj: dict = {}

    def record_steps(dt: float) -> int:
        return max(1, round(0.01 / dt))

    def mj_row(dt: float) -> Row:
        from .peers import mujoco_physics as mp

        ch = _character(ctx, "complementarity")
        sim = mp.MujocoSim(ch.mjcf(dt), ch.char.model.bodies.names, ch.root, np.zeros((1, 3)))
        k = record_steps(dt)
        total = int(round(secs / dt)) // k * k
        d = sim.reset(0)
        m = sim.model
        ys, pen = [], 0.0
        t0 = time.perf_counter()
        for i in range(total):
            sim.mujoco.mj_step(m, d)
            if d.ncon:
                pen = min(pen, float(d.contact.dist[:d.ncon].min()))
            if (i + 1) % k == 0:
                ys.append(sim.positions(0)[ch.root, 1])
        wall = time.perf_counter() - t0
        ys = np.asarray(ys)
        mj[dt] = ys
        y0 = float(ch.state.position[ch.root, 1])
        note = (f"dt 1/{round(1 / dt)}: root y {y0:.4f} → {ys[-1]:.4f} m (change {ys.min() - y0:+.4f} / "
                f"{ys.max() - y0:+.4f}), penetration {max(-pen, 0):.2e} m, joint separation 0; {total} steps "
                f"in {wall:.2f} s")
        return Row(f"MuJoCo C mj_step (dt 1/{round(1 / dt)})", "float64", 1, wall, None, total, None, "reference",
                   is_peer=True, note=note)

    def jax_row(model: str, dt: float, impl: str) -> Row:
        ch = _character(ctx, model)
        k = record_steps(dt)
        total = int(round(secs / dt)) // k * k
        fn = jax.jit(lambda s, a: physics.rollout(ch.char.model, s, dt, total, record_every=k,
                                                  controller=ch.controller, controller_args=a))
        cs = compile_time(fn, ch.state, ch.gains())
        t0 = time.perf_counter()
        run = jax.block_until_ready(cs.compiled(ch.state, ch.gains()))
        wall = time.perf_counter() - t0
        traj = run.trajectory
        ys = np.asarray(traj.position[:, ch.root, 1])
        clear = np.asarray(jax.vmap(ch.clearance)(traj))
        drift = np.asarray(jax.vmap(lambda s: physics.joint_error(ch.char.model, s))(traj))
        y0 = float(ch.state.position[ch.root, 1])
        ref = mj.get(dt)
        acc = "n/a (no MuJoCo)" if ref is None else float(np.max(np.abs(ys - ref)))
        ok = bool(run.result == physics.SimResult.successful) and int(run.num_steps) == total
        note = (f"{model} contact, dt 1/{round(1 / dt)}: root y {y0:.4f} → {ys[-1]:.4f} m (change "
                f"{ys.min() - y0:+.4f} / {ys.max() - y0:+.4f}), penetration {max(-clear.min(), 0):.2e} m, joint "
                f"separation {drift.max():.1e} m; {total} steps in {wall:.2f} s")
        return Row(impl, "float64", 1, wall, None, total, cs.total, acc, success=float(ok), note=note)

    dts = sorted({DT} | ({sz.penalty_dt} if "penalty" in sz.contact_models else set()), reverse=True)
    for dt in dts:
        impl = f"MuJoCo C mj_step (dt 1/{round(1 / dt)})"
        _add_row(config, table, impl, 1, lambda dt=dt: mj_row(dt), True, failures)
    for model in sz.contact_models:
        dt = sz.penalty_dt if model == "penalty" else DT
        impl = f"jaxanim rollout ({model})"
        _add_row(config, table, impl, 1, lambda m=model, dt=dt, i=impl: jax_row(m, dt, i), False, failures)
    table.notes.append(
        "Time / call here is one unbatched run of the whole duration (jaxanim: the compiled rollout, "
        "recording every 10 ms); µs / char is per step. The first table measures throughput properly."
    )
    return table


# --- 3. double pendulum -------------------------------------------------------------------------------
def _pendulum_table(ctx: _Context) -> Table:
    from jaxanim import physics

    config, sz = ctx.config, ctx.sizes
    secs = sz.pendulum_seconds
    table = Table(
        "physics-pendulum", f"Physics: double pendulum (2 capsules, ball joints), {secs:g} s, accuracy",
        accuracy_label=f"max body position error vs MuJoCo dt 1/{round(1 / PENDULUM_REF_DT)} (m)",
        description=(
            "Two capsules (radius 0.05 m, 0.4 m between cap centres, 1000 kg/m³) hanging from the origin by ball "
            "joints, released with the lower link out of the upper one's plane (3-D motion), no contact, exported "
            "with `physics.to_mjcf`. jaxanim `physics.rollout` and MuJoCo C (`mj_step`, Euler) at each dt, against "
            f"MuJoCo at dt 1/{round(1 / PENDULUM_REF_DT)} (the reference). Both schemes are first order: the error "
            "should halve with dt. Notes: the difference to MuJoCo at the same dt and jaxanim's max joint "
            "separation over the run (constraint drift)."
        ),
    )
    model, state = double_pendulum()
    failures: dict = {}
    cache: dict = {}

    def mujoco_final(dt: float) -> np.ndarray:
        if dt not in cache:
            from .peers import mujoco_physics as mp

            mujoco = mp.load_mujoco()
            m = mujoco.MjModel.from_xml_string(physics.to_mjcf(model, state, dt=dt))
            d = mujoco.MjData(m)
            t0 = time.perf_counter()
            for _ in range(int(round(secs / dt))):
                mujoco.mj_step(m, d)
            wall = time.perf_counter() - t0
            mujoco.mj_kinematics(m, d)
            ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in model.bodies.names]
            cache[dt] = (d.xpos[ids].copy(), wall)
        return cache[dt][0]

    def ref() -> np.ndarray | None:
        try:
            return mujoco_final(PENDULUM_REF_DT)
        except PeerUnavailable:
            return None

    def mj_row(dt: float, impl: str) -> Row:
        pos = mujoco_final(dt)
        r = ref()
        n = int(round(secs / dt))
        return Row(impl, "float64", 1, cache[dt][1], None, n, None, _diff(pos, r), is_peer=True,
                   note=f"{n} steps, Python loop")

    def jax_row(dt: float, impl: str) -> Row:
        n = int(round(secs / dt))
        k = max(1, n // 100)
        n = n // k * k
        fn = jax.jit(lambda s: physics.rollout(model, s, dt, n, record_every=k))
        cs = compile_time(fn, state)
        t0 = time.perf_counter()
        run = jax.block_until_ready(cs.compiled(state))
        wall = time.perf_counter() - t0
        pos = np.asarray(run.final.position)
        drift = float(np.max(np.asarray(jax.vmap(lambda s: physics.joint_error(model, s))(run.trajectory))))
        try:
            same = f"{float(np.max(np.abs(pos - mujoco_final(dt)))):.2e} m vs MuJoCo at the same dt"
        except PeerUnavailable:
            same = "no MuJoCo"
        ok = bool(run.result == physics.SimResult.successful)
        return Row(impl, "float64", 1, wall, None, n, cs.total, _diff(pos, ref()), success=float(ok),
                   note=f"{same}; joint separation {drift:.1e} m (max over the run); {n} steps")

    for dt in sz.pendulum_dts:
        _add_row(config, table, f"MuJoCo C mj_step (dt 1/{round(1 / dt)})", 1,
                 lambda dt=dt, i=f"MuJoCo C mj_step (dt 1/{round(1 / dt)})": mj_row(dt, i), True, failures)
        _add_row(config, table, f"jaxanim rollout (dt 1/{round(1 / dt)})", 1,
                 lambda dt=dt, i=f"jaxanim rollout (dt 1/{round(1 / dt)})": jax_row(dt, i), False, failures)
    return table


# --- entry point --------------------------------------------------------------------------------------
TABLES = ("throughput", "standing", "pendulum")


def run_physics(config: BenchConfig, sizes: PhysicsSizes | None = None,
                tables: tuple[str, ...] = TABLES) -> list[Table]:
    """The ``physics`` benchmark (see the module docstring); ``sizes`` and ``tables`` shrink it for tests."""
    unknown = set(tables) - set(TABLES)
    if unknown:
        raise ValueError(f"tables: unknown {sorted(unknown)}; expected some of {TABLES}")
    if sizes is None:
        sizes = PhysicsSizes.quick(config.batches_for(BATCHES)) if config.quick else PhysicsSizes()
    if not jax.config.jax_enable_x64:
        jax.config.update("jax_enable_x64", True)
    if "float64" not in config.dtypes:
        config.log("physics: runs in float64 only (MuJoCo is float64); --dtype is ignored")
    ctx = _Context(config, sizes)
    out: list[Table] = []
    path = pathlib.Path(config.data_dir) / CLIP
    load0 = os.getloadavg() if hasattr(os, "getloadavg") else None
    start = time.perf_counter()
    if not path.is_file():
        why = f"{path} not found (the shared data sits beside the clone; set JAXANIM_SHARED_DATA or --data-dir)"
        config.log(f"physics: skipped: {why}")
        for name in ("throughput", "standing"):
            if name in tables:
                out.append(Table(f"physics{'' if name == 'throughput' else '-standing'}",
                                 f"Physics: {name}", skipped=why))
    else:
        if "throughput" in tables:
            out.append(_throughput_table(ctx))
        if "standing" in tables and sizes.stand_seconds > 0:
            out.append(_standing_table(ctx))
    if "pendulum" in tables and sizes.pendulum_seconds > 0:
        out.append(_pendulum_table(ctx))
    note = load_note("physics", start, load0)
    if out and note:
        out[-1].notes.append(note)
    return out
