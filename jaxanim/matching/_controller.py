"""The motion-matching controller: a time-varying input -> a spring-damper trajectory -> periodic
searches -> inertialized playback of the database, one ``lax.scan`` over frames for one agent.

Per output frame (time ``t``):

1. the **simulated trajectory** follows the input: the ground position, velocity and acceleration
   of a critically damped spring towards the desired velocity, and the facing yaw and its rate
   towards the desired facing (Holden's ``spring_character_update`` and ``simple_spring_damper``
   closed forms). Its future at the feature times (0.5, 1.0, 1.5 s) is predicted by the same closed
   forms, stepped twice per interval with the input sampled ahead;
2. the **query** is the current database row's pose features with the predicted trajectory in place
   of the row's own: the simulated future positions relative to the simulated current one and the
   simulated future facings, both turned into the character's facing frame (relative to the
   simulation, not to the character, so a gap between the two does not read as a demand to move;
   step 5 closes the gap);
3. a **search** runs every ``search_period`` seconds (on frames that are multiples of it, the same
   for every agent), and at once when the desired velocity or
   facing moved away from those of the last search by more than ``velocity_change`` or
   ``facing_change``, or when the current row is its clip's last. The character switches to the
   found row (and plays on from the frame after it) when the row is better than the current one;
4. on a switch, **inertialization** keeps the pose continuous: the offsets between the pose that
   would have played and the new one (joint rotations as rotation vectors, the root translation in
   the facing frame, and their velocities) are added and decay to 0 (``decay_spring``, halflife
   ``blend_halflife``);
5. the **root** moves in the world by the database's root motion: each played row's facing-origin
   step and yaw change, taken in the character's current facing frame. The character is then
   pulled towards the simulated trajectory (Holden's "adjustment"), at most ``adjust_turn_rate``
   radians per second and ``adjust_speed_ratio`` times its own speed: this lets a database without
   turns (the shipped walk) follow a turn, and keeps the character on the simulated path.

Under ``jax.vmap`` over agents (a crowd) the search runs, for all agents at once, only on frames
where some agent needs one (a custom batching rule), not on every frame.
"""

from __future__ import annotations

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .. import rotations as rot
from .._errors import JaxanimError, check_positive, check_shape
from .._linalg import HIGHEST, check_precision, dot
from .._types import Array, Bool, Float, Int
from ..skeleton._skeleton import Motion
from ._database import MatchingDatabase
from ..skeleton._processing import decay_spring
from ._search import DEFAULT_CHUNK, _search

__all__ = ["ControlInput", "ControllerOptions", "MatchResult", "control_input", "motion_matching"]

_LN2 = math.log(2.0)


class ControlInput(eqx.Module):
    """A time-varying input, piecewise linear in time (held constant outside ``times``).

    Attributes:
        times: ``[keys]`` increasing seconds.
        velocity: ``[keys, 2]`` desired ground velocity ``(vx, vz)`` in the world (file units/s).
        yaw: ``[keys]`` desired facing as a yaw angle about ``+y`` (0 faces ``+z``, ``pi/2`` faces ``+x``),
            unwrapped so that linear interpolation turns the short way.
    """

    times: Float[Array, " keys"] = eqx.field(converter=jnp.asarray)
    velocity: Float[Array, "keys 2"] = eqx.field(converter=jnp.asarray)
    yaw: Float[Array, " keys"] = eqx.field(converter=jnp.asarray)

    def __check_init__(self):
        check_shape("times", self.times, (None,), what="(keys,)")
        k = self.times.shape[0]
        check_shape("velocity", self.velocity, (k, 2), what=f"(keys, 2) = ({k}, 2)")
        check_shape("yaw", self.yaw, (k,), what=f"(keys,) = ({k},)")

    def at(self, t) -> tuple[Array, Array]:
        """``(velocity [2], yaw)`` at time ``t`` (linear between keys, held outside)."""
        v = jnp.stack([jnp.interp(t, self.times, self.velocity[:, 0]), jnp.interp(t, self.times, self.velocity[:, 1])])
        return v, jnp.interp(t, self.times, self.yaw)


def control_input(times, velocity, facing=None, *, dtype=None) -> ControlInput:
    """Build a :class:`ControlInput` from keys (host-side; checks them).

    Args:
        times: ``[keys]`` strictly increasing seconds.
        velocity: ``[keys, 2]`` desired ground velocity ``(vx, vz)``, file units per second.
        facing: ``[keys, 2]`` desired facing directions ``(fx, fz)`` (any nonzero length), or ``None``: the
            velocity's direction (where the velocity is 0, the nearest key's with a direction, else ``+z``).
        dtype: the arrays' dtype (default float64 when x64 is on).

    Raises:
        JaxanimError: on shapes, non-finite values, times that do not increase, or a zero facing.
    """
    t = np.asarray(times, dtype=np.float64)
    v = np.asarray(velocity, dtype=np.float64)
    check_shape("times", t, (None,), what="(keys,)")
    k = t.shape[0]
    if k == 0:
        raise JaxanimError("times: expected at least one key")
    check_shape("velocity", v, (k, 2), what=f"(keys, 2) = ({k}, 2)")
    for name, x in (("times", t), ("velocity", v)):
        if not np.all(np.isfinite(x)):
            raise JaxanimError(f"{name}: expected finite values, got {x.tolist()}")
    bad = np.nonzero(np.diff(t) <= 0)[0]
    if bad.size:
        i = int(bad[0]) + 1
        raise JaxanimError(f"times: expected strictly increasing times, but key {i} ({t[i]:g}) follows {t[i - 1]:g}")
    if facing is None:
        speed = np.linalg.norm(v, axis=1)
        have = np.nonzero(speed > 1e-9)[0]
        if have.size == 0:
            yaw = np.zeros(k)
        else:
            nearest = have[np.argmin(np.abs(np.arange(k)[:, None] - have[None, :]), axis=1)]
            yaw = np.arctan2(v[nearest, 0], v[nearest, 1])
    else:
        f = np.asarray(facing, dtype=np.float64)
        check_shape("facing", f, (k, 2), what=f"(keys, 2) = ({k}, 2)")
        if not np.all(np.isfinite(f)):
            raise JaxanimError(f"facing: expected finite values, got {f.tolist()}")
        zero = np.nonzero(np.linalg.norm(f, axis=1) <= 1e-12)[0]
        if zero.size:
            raise JaxanimError(f"facing: key {int(zero[0])} is a zero vector; a facing needs a direction")
        yaw = np.arctan2(f[:, 0], f[:, 1])
    yaw = np.unwrap(yaw)
    dtype = dtype or jnp.result_type(float)
    return ControlInput(jnp.asarray(t, dtype), jnp.asarray(v, dtype), jnp.asarray(yaw, dtype))


class ControllerOptions(eqx.Module):
    """Settings of :func:`motion_matching` (arrays unless noted, so a crowd may sweep them).

    Attributes:
        search_period: seconds between scheduled searches (rounded to frames, at least 1).
        velocity_halflife: halflife of the trajectory spring towards the desired velocity (s).
        facing_halflife: halflife of the facing spring towards the desired facing (s).
        blend_halflife: halflife of the inertialization offsets (s).
        velocity_change: search at once when the desired velocity moved by more than this fraction
            of the database's mean speed since the last search.
        facing_change: ... or the desired facing by more than this angle (radians).
        adjust_halflife: halflife of the pull of the character towards the simulated trajectory (s).
        adjust_turn_rate: the pull turns the character by at most this rate (rad/s; 0: off).
        adjust_speed_ratio: the pull moves it by at most this fraction of its own speed (0: off).
        ignore_surrounding: a found row of the current clip within this many seconds of the current
            row does not count as a switch (the character plays on; no jumps of a frame or two).
        chunk: rows per step of the search's scan (static).
        precision: of the search's distance product (static; see :func:`search`): ``"highest"``
            (default) or the fast ``"default"`` (TF32 for float32 on NVIDIA GPUs).

    Raises:
        JaxanimError: a concrete halflife that is not a positive finite number of seconds.
    """

    search_period: float = eqx.field(default=0.15, converter=jnp.asarray)
    velocity_halflife: float = eqx.field(default=0.27, converter=jnp.asarray)
    facing_halflife: float = eqx.field(default=0.27, converter=jnp.asarray)
    blend_halflife: float = eqx.field(default=0.1, converter=jnp.asarray)
    velocity_change: float = eqx.field(default=0.25, converter=jnp.asarray)
    facing_change: float = eqx.field(default=0.35, converter=jnp.asarray)
    adjust_halflife: float = eqx.field(default=0.5, converter=jnp.asarray)
    adjust_turn_rate: float = eqx.field(default=math.pi / 2, converter=jnp.asarray)
    adjust_speed_ratio: float = eqx.field(default=0.5, converter=jnp.asarray)
    ignore_surrounding: float = eqx.field(default=0.2, converter=jnp.asarray)
    chunk: int = eqx.field(default=DEFAULT_CHUNK, static=True)
    precision: lax.Precision = eqx.field(default=HIGHEST, static=True,
                                         converter=lambda p: check_precision("precision", p))

    def __check_init__(self):
        # a negative halflife makes a spring grow without bound, zero divides by zero (checked when
        # concrete: options built under jit or vmap are the caller's to check)
        for name in ("velocity_halflife", "facing_halflife", "blend_halflife", "adjust_halflife"):
            check_positive(name, getattr(self, name), units="seconds")


class MatchResult(eqx.Module):
    """What :func:`motion_matching` produced.

    Attributes:
        motion: the animation, ``frames`` frames at the database's frame time (local rotations and
            translations on the database's skeleton; the root in the world).
        rows: ``[frames]`` the database row played at each frame.
        searched: ``[frames]`` whether a search ran at that frame.
        switched: ``[frames]`` whether the character switched rows there (an inertialized transition).
        simulated_position: ``[frames, 2]`` the simulated trajectory's ground position ``(x, z)``.
        simulated_yaw: ``[frames]`` its facing yaw.
        yaw: ``[frames]`` the character's facing yaw.
    """

    motion: Motion
    rows: Int[Array, " frames"]
    searched: Bool[Array, " frames"]
    switched: Bool[Array, " frames"]
    simulated_position: Float[Array, "frames 2"]
    simulated_yaw: Float[Array, " frames"]
    yaw: Float[Array, " frames"]


class _State(eqx.Module):
    row: Array
    last_velocity: Array
    last_yaw: Array
    root: Array  # [3] facing origin in the world
    yaw: Array
    sim_position: Array  # [2]
    sim_velocity: Array
    sim_acceleration: Array
    sim_yaw: Array
    sim_yaw_rate: Array
    off_rotation: Array  # [J, 3]
    off_angular: Array
    off_position: Array  # [3] root translation in the facing frame
    off_velocity: Array


# --- springs (closed forms, Holden) ---------------------------------------------------------------


def _spring_velocity(x, v, a, v_goal, halflife, dt):
    """Position, velocity, acceleration of a critically damped spring on the velocity towards ``v_goal``."""
    y = 2.0 * _LN2 / halflife
    j0 = v - v_goal
    j1 = a + j0 * y
    e = jnp.exp(-y * dt)
    x = e * (-j1 / (y * y) + (-j0 - j1 * dt) / y) + j1 / (y * y) + j0 / y + v_goal * dt + x
    return x, e * (j0 + j1 * dt) + v_goal, e * (a - j1 * y * dt)


def _wrap(a):
    return jnp.arctan2(jnp.sin(a), jnp.cos(a))


def _spring_angle(x, v, goal, halflife, dt):
    """A critically damped spring of an angle towards ``goal`` (the short way round)."""
    y = 2.0 * _LN2 / halflife
    j0 = -_wrap(goal - x)
    j1 = v + j0 * y
    e = jnp.exp(-y * dt)
    return x + j0 * (e - 1.0) + e * j1 * dt, e * (v - j1 * y * dt)


def _rotate_y(yaw, v):
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    return jnp.stack([c * v[..., 0] + s * v[..., 2], v[..., 1], -s * v[..., 0] + c * v[..., 2]], axis=-1)


def _yaw_quat(yaw):
    h = 0.5 * yaw
    z = jnp.zeros_like(h)
    return jnp.stack([jnp.cos(h), z, jnp.sin(h), z], axis=-1)


# --- the search, run only where needed under vmap ------------------------------------------------


@functools.lru_cache(maxsize=None)
def _maybe_search_fn(chunk: int, precision):
    """``(index, distance)`` of the nearest row if ``due``, else ``(0, inf)``. Batched over agents, the
    search runs for all of them when any is due (one matrix product per chunk), and not at all
    otherwise: a plain ``lax.cond`` would become a select and search on every frame."""

    def skip(features, query):
        return jnp.zeros(query.shape[:-1], jnp.int32), jnp.full(query.shape[:-1], jnp.inf, features.dtype)

    @jax.custom_batching.custom_vmap
    def maybe(features, squared_norms, query, due):
        return lax.cond(due, lambda: _search(features, squared_norms, query, chunk, precision),
                        lambda: skip(features, query))

    @maybe.def_vmap
    def _rule(axis_size, in_batched, features, squared_norms, query, due):
        fb, sb, qb, db_ = in_batched
        if fb or sb:  # a database per agent: search them all, every time
            axes = (0 if fb else None, 0 if sb else None, 0 if qb else None)
            i, d = jax.vmap(lambda f, s, q: _search(f, s, q, chunk, precision), in_axes=axes,
                            axis_size=axis_size)(features, squared_norms, query)
        else:
            q = query if qb else jnp.broadcast_to(query, (axis_size,) + query.shape)
            i, d = lax.cond(jnp.any(due),
                            lambda: jax.vmap(lambda x: _search(features, squared_norms, x, chunk, precision))(q),
                            lambda: skip(features, q))
        due_b = due if db_ else jnp.broadcast_to(due, (axis_size,))
        i = jnp.where(due_b, i, 0)
        d = jnp.where(due_b, d, jnp.inf)
        return (i, d), (True, True)

    return maybe


# --- the controller -------------------------------------------------------------------------------


def _predict(inputs: ControlInput, t, state: _State, times: tuple[float, ...], o: ControllerOptions):
    """Simulated ground positions ``[T, 2]`` and yaws ``[T]`` at ``t + times``, stepping the closed forms
    twice per interval with the input sampled at each sub-step's middle."""
    x, v, a = state.sim_position, state.sim_velocity, state.sim_acceleration
    yaw, rate = state.sim_yaw, state.sim_yaw_rate
    ps, ys, prev = [], [], 0.0
    for tau in times:
        h = (tau - prev) / 2.0
        for k in range(2):
            vg, yg = inputs.at(t + prev + (k + 0.5) * h)
            x, v, a = _spring_velocity(x, v, a, vg, o.velocity_halflife, h)
            yaw, rate = _spring_angle(yaw, rate, yg, o.facing_halflife, h)
        prev = tau
        ps.append(x)
        ys.append(yaw)
    return jnp.stack(ps), jnp.stack(ys)


def _trajectory_raw(positions, yaws, origin_xz, char_yaw):
    """Raw trajectory features: future ground positions relative to ``origin_xz`` and directions, both
    in the character's facing frame, laid out as the database's trajectory blocks."""
    d = positions - origin_xz[None]
    d3 = jnp.stack([d[:, 0], jnp.zeros_like(d[:, 0]), d[:, 1]], axis=-1)
    loc = _rotate_y(-char_yaw, d3)
    rel = yaws - char_yaw
    return jnp.concatenate([loc[:, [0, 2]].reshape(-1), jnp.stack([jnp.sin(rel), jnp.cos(rel)], axis=-1).reshape(-1)])


def _query(db: MatchingDatabase, row, traj_raw):
    s = db.layout.trajectory_start
    traj = (traj_raw - db.mean[s:]) * db.scale[s:]
    return jnp.concatenate([db.features[row, :s], traj])


def _pose(db: MatchingDatabase, state: _State):
    """The output pose of ``state``: local rotations ``[J, 4]`` and translations ``[J, 3]``, the root in the world."""
    r = state.row
    q = rot.quat_multiply(rot.rotvec_to_quat(state.off_rotation), db.rotations[r])
    q = q.at[0].set(rot.quat_multiply(_yaw_quat(state.yaw), q[0]))
    t = db.translations[r]
    t = t.at[0].set(state.root + _rotate_y(state.yaw, t[0] + state.off_position))
    return rot.quat_normalize(q), t


def _run(db: MatchingDatabase, inputs: ControlInput, num_frames: int, start_position, start_yaw, o: ControllerOptions):
    dt = db.frame_time
    dtype = db.features.dtype
    o = jax.tree.map(lambda x: x.astype(dtype) if jnp.issubdtype(x.dtype, jnp.floating) else x, o)
    times = db.layout.trajectory_times
    J = db.rotations.shape[1]
    maybe_search = _maybe_search_fn(o.chunk, o.precision)
    interval = jnp.maximum(jnp.round(o.search_period / dt), 1.0).astype(jnp.int32)
    N = db.num_rows
    surround = jnp.round(o.ignore_surrounding / dt).astype(jnp.int32)

    v0, yaw_in0 = inputs.at(jnp.zeros((), dtype))
    yaw0 = jnp.where(jnp.isnan(start_yaw), yaw_in0, start_yaw)
    zero2 = jnp.zeros(2, dtype)
    state = _State(
        row=jnp.asarray(0, jnp.int32), last_velocity=v0, last_yaw=yaw_in0,
        root=jnp.stack([start_position[0], jnp.zeros((), dtype), start_position[1]]), yaw=yaw0,
        sim_position=start_position, sim_velocity=v0, sim_acceleration=zero2, sim_yaw=yaw0,
        sim_yaw_rate=jnp.zeros((), dtype), off_rotation=jnp.zeros((J, 3), dtype), off_angular=jnp.zeros((J, 3), dtype),
        off_position=jnp.zeros(3, dtype), off_velocity=jnp.zeros(3, dtype))
    # the first row: the trajectory alone (the pose features at the database's mean)
    p, y = _predict(inputs, jnp.zeros((), dtype), state, times, o)
    traj = _trajectory_raw(p, y, state.sim_position, state.yaw)
    s = db.layout.trajectory_start
    q0 = jnp.concatenate([jnp.zeros(s, dtype), (traj - db.mean[s:]) * db.scale[s:]])
    first, _ = maybe_search(db.features, db.squared_norms, q0, jnp.asarray(True))
    state = eqx.tree_at(lambda st: st.row, state, first)

    def step(state: _State, i):
        t = (i + 1).astype(dtype) * dt
        v_goal, yaw_goal = inputs.at(t)
        sx, sv, sa = _spring_velocity(state.sim_position, state.sim_velocity, state.sim_acceleration, v_goal,
                                      o.velocity_halflife, dt)
        sy, sr = _spring_angle(state.sim_yaw, state.sim_yaw_rate, yaw_goal, o.facing_halflife, dt)
        state = eqx.tree_at(lambda st: (st.sim_position, st.sim_velocity, st.sim_acceleration, st.sim_yaw,
                                        st.sim_yaw_rate), state, (sx, sv, sa, sy, sr))
        row = state.row
        changed = ((jnp.linalg.norm(v_goal - state.last_velocity) > o.velocity_change * db.mean_speed)
                   | (jnp.abs(yaw_goal - state.last_yaw) > o.facing_change))
        # scheduled searches on a clock shared by all agents (frames interval, 2 interval, ...), so
        # that in a crowd they fall on the same frames; forced ones whenever needed
        due = db.last[row] | changed | ((i + 1) % interval == 0)
        p, y = _predict(inputs, t, state, times, o)
        query = _query(db, row, _trajectory_raw(p, y, sx, state.yaw))
        best, best_d = maybe_search(db.features, db.squared_norms, query, due)
        # both distances computed directly (the same way batched or not); the found row must be better
        # beyond round-off, so a tie (a periodic clip's repeated frames) never switches
        diff = query - db.features[row]
        row_d = jnp.where(db.searchable[row], dot(diff, diff), jnp.inf)
        diff = query - db.features[best]
        best_d = dot(diff, diff)
        near = (db.clip[best] == db.clip[row]) & (jnp.abs(db.frame[best] - db.frame[row]) <= surround)
        better = best_d < row_d - 1e-9 * (1.0 + row_d)
        switch = due & (db.last[row] | (~near & better))
        cont = jnp.where(db.last[row], row, row + 1)
        dst = jnp.minimum(best + 1, N - 1)
        new_row = jnp.where(switch, dst, cont)
        # inertialization: the offsets take up the difference between the pose that would have played
        # (cont) and the new one (dst), then decay
        q_src = rot.quat_multiply(rot.rotvec_to_quat(state.off_rotation), db.rotations[cont])
        off_q = rot.quat_to_rotvec(rot.quat_multiply(q_src, rot.quat_conjugate(db.rotations[dst])))
        off_w = state.off_angular + db.angular_velocities[cont] - db.angular_velocities[dst]
        off_p = state.off_position + db.translations[cont, 0] - db.translations[dst, 0]
        off_v = state.off_velocity + db.root_velocity[cont] - db.root_velocity[dst]
        off_q = jnp.where(switch, off_q, state.off_rotation)
        off_w = jnp.where(switch, off_w, state.off_angular)
        off_p = jnp.where(switch, off_p, state.off_position)
        off_v = jnp.where(switch, off_v, state.off_velocity)
        off_q, off_w = decay_spring(off_q, off_w, o.blend_halflife, dt)
        off_p, off_v = decay_spring(off_p, off_v, o.blend_halflife, dt)
        # the root: the played row's step in the character's facing frame, then the pull to the trajectory
        step_p = _rotate_y(state.yaw, db.step_position[new_row])
        root = state.root + step_p
        yaw = state.yaw + db.step_yaw[new_row]
        pull = 1.0 - jnp.exp(-_LN2 * dt / o.adjust_halflife)
        max_turn = o.adjust_turn_rate * dt
        yaw = yaw + jnp.clip(_wrap(sy - yaw) * pull, -max_turn, max_turn)
        gap = (sx - root[jnp.array([0, 2])]) * pull
        limit = o.adjust_speed_ratio * jnp.linalg.norm(step_p)
        n = jnp.linalg.norm(gap)
        gap = gap * jnp.where(n > limit, limit / jnp.where(n > 0, n, 1.0), 1.0)
        root = root + jnp.stack([gap[0], jnp.zeros((), dtype), gap[1]])
        state = _State(
            row=new_row, last_velocity=jnp.where(due, v_goal,
            state.last_velocity), last_yaw=jnp.where(due, yaw_goal, state.last_yaw), root=root, yaw=yaw,
            sim_position=sx, sim_velocity=sv, sim_acceleration=sa, sim_yaw=sy, sim_yaw_rate=sr,
            off_rotation=off_q, off_angular=off_w, off_position=off_p, off_velocity=off_v)
        q, tr = _pose(db, state)
        return state, (q, tr, new_row, due, switch, sx, sy, yaw)

    q0, t0 = _pose(db, state)
    first_out = (q0, t0, state.row, jnp.asarray(True), jnp.asarray(False), state.sim_position, state.sim_yaw,
                 state.yaw)
    _, outs = lax.scan(step, state, jnp.arange(num_frames - 1))
    outs = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), first_out, outs)
    q, tr, rows, searched, switched, sp, sy, yaw = outs
    return MatchResult(Motion(q, tr, dt), rows, searched, switched, sp, sy, yaw)


_run_jit = eqx.filter_jit(_run)


def check_input_speed(db: MatchingDatabase, inputs: ControlInput, *, slack: float = 1.25) -> str | None:
    """Whether the database can follow the input's speeds: a message when it cannot, else ``None``.

    Motion matching only replays the database's frames, so an input faster than its fastest
    searchable frame is followed at that speed at best (plus what the trajectory adjustment adds,
    ``adjust_speed_ratio``, by sliding the feet), and the character falls behind. The
    database's fastest is the largest ground step of a searchable row per frame time; the input's
    peak is the largest ``|velocity|`` of its keys (it is linear between them). Host-side: needs
    concrete arrays (not inside ``jit`` / ``vmap``).

    Args:
        db: the database.
        inputs: the input (:func:`control_input`).
        slack: how much faster than the database's fastest frame the input may ask before this
            reports (default 1.25: the controller's spring and the blend make up a little).

    Returns:
        ``None``, or a sentence naming the input's peak speed, when it is asked, and the database's fastest.
    """
    searchable = np.asarray(db.searchable)
    steps = np.asarray(db.step_position)[searchable][:, [0, 2]]
    fastest = float(np.linalg.norm(steps, axis=1).max(initial=0.0)) / float(db.frame_time)
    speed = np.linalg.norm(np.asarray(inputs.velocity), axis=1)
    k = int(np.argmax(speed))
    if speed[k] <= slack * fastest:
        return None
    return (f"the input asks for a ground speed of {speed[k]:.3g} per s (at t = {float(np.asarray(inputs.times)[k]):g} s), "
            f"but the database's fastest frames move at {fastest:.3g} per s: the character falls behind the "
            f"input, and its feet slide where the trajectory adjustment pulls it on (add faster clips, or slow "
            f"the input down)")


def motion_matching(
    db: MatchingDatabase,
    inputs: ControlInput,
    num_frames: int,
    *,
    start_position: Float[Array, "2"] | None = None,
    start_yaw: Float[Array, ""] | None = None,
    options: ControllerOptions | None = None,
) -> MatchResult:
    """Animate one agent by motion matching for ``num_frames`` frames (see the module docstring).

    One compiled ``lax.scan`` over frames; batch over agents (a crowd) with ``jax.vmap`` over
    ``inputs`` (and the start): the searches of all agents become one matrix product.

    Args:
        db: the database (:func:`build_database`).
        inputs: the desired velocity and facing over time (:func:`control_input`).
        num_frames: frames to produce (static), at ``db.frame_time``; frame 0 is the first matched
            pose at the start.
        start_position: ``[2]`` start ``(x, z)`` on the ground (default the origin).
        start_yaw: start facing yaw (default the input's at time 0).
        options: :class:`ControllerOptions` (default ``ControllerOptions()``).

    Returns:
        :class:`MatchResult` with the :class:`Motion` (write it with :func:`jaxanim.write_bvh` on
        ``db.skeleton``).

    Raises:
        JaxanimError: on a wrong shape or a non-positive ``num_frames``.
    """
    if not isinstance(num_frames, (int, np.integer)) or num_frames < 1:
        raise JaxanimError(f"num_frames: expected a positive int, got {num_frames!r}")
    if not isinstance(inputs, ControlInput):
        raise JaxanimError(f"inputs: expected a ControlInput (see control_input), got {type(inputs).__name__}")
    dtype = db.features.dtype
    start_position = jnp.zeros(2, dtype) if start_position is None else jnp.asarray(start_position, dtype)
    check_shape("start_position", start_position, (2,), what="(2,) = (x, z)")
    start_yaw = jnp.asarray(jnp.nan if start_yaw is None else start_yaw, dtype)
    check_shape("start_yaw", start_yaw, (), what="() (a scalar)")
    inputs = jax.tree.map(lambda x: x.astype(dtype), inputs)
    options = ControllerOptions() if options is None else options
    return _run_jit(db, inputs, int(num_frames), start_position, start_yaw, options)
