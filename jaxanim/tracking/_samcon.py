r"""Tracking a clip with joint torques only: sampling-based control (the SAMCON family).

The character (:func:`jaxanim.character.build_character`) is driven by stable PD towards the clip's
joint targets (:func:`jaxanim.character.spd_targets`), each target corrected per control window by a
rotation ``exp(c_j)`` (``c_j`` a rotation vector, right-multiplied: in the child body's frame).
There is no root force or torque: the character has to balance on its joints and feet.

:func:`samcon` searches the corrections window by window (Liu et al. 2010, "Sampling-based contact-
rich motion control"). It keeps ``elites`` start states; in each window it draws ``samples``
corrections around the mean of the last window's elite corrections, each sample starting from one
elite state (round robin), simulates every sample over the window in one ``vmap``-ed rollout,
scores it against the clip, and keeps the best ``elites`` end states with their corrections and
parents. Each sample is scored over its window plus ``lookahead`` frames simulated on with the same
correction, so that a state about to fall scores badly although its window looked fine; the state
kept is the one at the window's end. At the end the lineage of the best final state is traced
back: its corrections and the frames recorded along it are the result (:func:`replay` simulates
the corrections again from the start, and gives the same motion: the simulation is deterministic).

The whole search is one ``lax.scan`` over the windows: it is a pure function of one problem
(character, reference, key, options), compiled once per structure, and ``jax.vmap`` over keys,
clips of the same length or options runs many searches at once. Runs are deterministic for a key.

The cost of a frame ``f`` (summed over the window's frames) is

``w_pose mean_j |e_j|^2 + w_position mean_b |x_b - x_b^ref|^2 + w_velocity mean_b |v_b - v_b^ref|^2
+ w_root angle(q_root, q_root^ref)^2``

with ``e_j`` the joints' rotation errors (:func:`jaxanim.physics.joint_errors`), ``x_b`` and ``v_b``
the bodies' centers of mass and velocities in meters and m/s, and the root body's orientation.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float
from solvers import RESULTS

from .. import rotations as rot
from .._errors import JaxanimError, check_positive
from .._linalg import dot, jit, matmul
from ..character._build import Character, clip_targets, root_body
from ..physics._bodies import BodyState
from ..physics._contact import contact_geometry
from ..physics._control import Control, StablePD, optional_array
from ..physics._joints import joint_errors
from ..physics._step import control_for, step_and_torques
from ..skeleton._skeleton import Motion

__all__ = [
    "Feedback", "TrackingOptions", "TrackingReference", "TrackingResult", "TrackingStatus", "joint_sigma", "replay", "samcon",
    "state_difference", "state_retract", "torso_body", "tracking_options", "tracking_reference", "windows_of",
]


class TrackingStatus(eqx.Enumeration):
    """Status of a tracking result, per problem under ``vmap``."""

    successful = ""
    fell = "The character fell: its root went below 0.7 times the clip's lowest root height."


def _positive_int(name, value, low=1):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise JaxanimError(f"{name}: expected an int >= {low}, got {value!r}")
    return int(value)


class TrackingOptions(eqx.Module):
    """The settings of :func:`samcon`.

    Structure (static): ``samples`` per window (>= 2), ``elites`` kept (1 <= elites <= samples),
    ``window`` frames per control window (3 at 30 fps: 0.1 s), ``steps_per_frame`` physics steps
    per frame, ``lookahead`` frames simulated past a window with the same correction to score it
    (a sample that will fall shortly after the window scores badly; its state at the window's end
    is the one kept). Numbers (arrays, sweepable with ``vmap``): ``sigma`` the standard deviation
    of the sampled corrections (radians, per axis; a scalar or one per physics joint), the
    stable-PD gains ``kp`` (N m / rad) and ``kd`` (N m s / rad), scalars or one per physics joint,
    and the cost weights, and ``torque_limit``: the bound on each joint's stable-PD torque norm
    (N m, a scalar or one per physics joint; :func:`joint_torque_limits` gives a human-like table,
    and :func:`tracking_options` uses it), or ``None`` for none (a bound costs the physics step a
    second and third constraint solve, see :class:`~jaxanim.physics.StablePD`). The defaults (kp 2000, kd 200, w_pose 3, w_position 30) were chosen on the
    shipped walk, 4 s, 256 samples, seeds 0-2: every run stood with mean joint error 0.135-0.149 rad
    and mean horizontal root error 0.05-0.14 m (kp 1000, w_pose 1, w_position 10: seed 1 fell).
    """

    samples: int = eqx.field(static=True, default=256)
    elites: int = eqx.field(static=True, default=16)
    window: int = eqx.field(static=True, default=3)
    steps_per_frame: int = eqx.field(static=True, default=4)
    lookahead: int = eqx.field(static=True, default=6)
    sigma: Float[Array, "#joints"] = eqx.field(default=0.15, converter=jnp.asarray)
    kp: Float[Array, "#joints"] = eqx.field(default=2000.0, converter=jnp.asarray)
    kd: Float[Array, "#joints"] = eqx.field(default=200.0, converter=jnp.asarray)
    w_pose: Float[Array, ""] = eqx.field(default=3.0, converter=jnp.asarray)
    w_position: Float[Array, ""] = eqx.field(default=30.0, converter=jnp.asarray)
    w_velocity: Float[Array, ""] = eqx.field(default=0.1, converter=jnp.asarray)
    w_root: Float[Array, ""] = eqx.field(default=2.0, converter=jnp.asarray)
    torque_limit: Float[Array, "#joints"] | None = eqx.field(default=None, converter=optional_array)

    def __check_init__(self):
        _positive_int("samples", self.samples, 2)
        _positive_int("elites", self.elites)
        _positive_int("window", self.window)
        _positive_int("steps_per_frame", self.steps_per_frame)
        _positive_int("lookahead", self.lookahead, 0)
        if self.elites > self.samples:
            raise JaxanimError(f"elites: expected at most samples = {self.samples}, got {self.elites}")
        # checked when concrete (options swept under vmap are the caller's to check)
        check_positive("sigma", self.sigma, zero=True, units="radians")
        check_positive("kp", self.kp, zero=True, units="N m / rad")
        check_positive("kd", self.kd, zero=True, units="N m s / rad")


class TrackingReference(eqx.Module):
    """What :func:`samcon` tracks: a clip as the character's targets and body states.

    Attributes:
        targets: ``[frames, joints, 4]`` stable-PD targets of the physics joints.
        states: the bodies' reference states per frame (a :class:`~jaxanim.physics.BodyState` with
            a leading frames axis), velocities by central differences.
        frame_time: seconds.
        lift: meters the clip was raised (or lowered) so that its feet stand on the ground.
    """

    targets: Float[Array, "frames joints 4"]
    states: BodyState
    frame_time: Float[Array, ""]
    lift: Float[Array, ""]

    @property
    def num_frames(self) -> int:
        return self.targets.shape[0]


def _velocities(states: BodyState, dt: float) -> BodyState:
    """The states with linear and angular velocities from central differences of the poses."""
    v = jnp.gradient(states.position, dt, axis=0)
    dq = rot.quat_multiply(states.orientation[2:], rot.quat_conjugate(states.orientation[:-2]))
    w = rot.quat_to_rotvec(rot.quat_canonical(dq)) / (2.0 * dt)
    dq0 = rot.quat_multiply(states.orientation[1:2], rot.quat_conjugate(states.orientation[:1]))
    dq1 = rot.quat_multiply(states.orientation[-1:], rot.quat_conjugate(states.orientation[-2:-1]))
    w = jnp.concatenate([rot.quat_to_rotvec(rot.quat_canonical(dq0)) / dt, w,
                         rot.quat_to_rotvec(rot.quat_canonical(dq1)) / dt])
    return BodyState(states.position, states.orientation, v, w, states.time)


def tracking_reference(character: Character, motion: Motion, *, ground_clip: bool = True) -> TrackingReference:
    """The reference of :func:`samcon` for a clip (file units) on a character.

    Args:
        character: the physics character (with a ground; :func:`~jaxanim.character.build_character`).
        motion: the clip, at least 2 frames; loop it first for a longer run.
        ground_clip: raise or lower the whole clip so that its feet stand on the ground: by the
            median over frames of the lowest contact point's signed distance (a skeleton's joints
            are inside the feet, whose soles the character adds below them).

    Raises:
        JaxanimError: fewer than 2 frames, NaN or inf in a frame (named), or a frame time that is not
            positive (a search would otherwise report success on a NaN reference).
    """
    motion.check_skeleton(character.skeleton, "motion")
    motion.check_finite("motion")
    if motion.num_frames < 2:
        raise JaxanimError(f"motion: expected at least 2 frames to track, got {motion.num_frames}")
    dt = float(motion.frame_time)
    targets, states = clip_targets(character, motion.rotations, motion.translations)
    states, lift = _grounded_states(character, states, jnp.asarray(dt, states.position.dtype),
                                    ground_clip and character.model.ground.model != "none")
    return TrackingReference(targets=targets, states=states, frame_time=jnp.asarray(dt, states.position.dtype), lift=lift)


@eqx.filter_jit
def _grounded_states(character: Character, states: BodyState, dt, ground_clip: bool):
    """The clip's body states lifted onto the ground (``ground_clip``), with velocities: one
    program (op by op, the lift and the differences compiled about a hundred small programs)."""
    lift = jnp.zeros((), states.position.dtype)
    ground = character.model.ground
    if ground_clip:
        lowest = jax.vmap(lambda s: jnp.min(contact_geometry(ground, character.model.bodies, s)[2]))(states)
        lift = -jnp.median(lowest)
        states = eqx.tree_at(lambda s: s.position, states, states.position + lift * ground.normal[None, None, :])
    return _velocities(states, dt), lift


class Feedback(eqx.Module):
    """Time-varying linear feedback around a tracked trajectory (:func:`~jaxanim.tracking.feedback`).

    At frame ``f`` (simulating ``f -> f + 1``) every physics joint's target correction gets
    ``clip(gains[f] @ state_difference(state, trajectory[f]), limit)`` added (a rotation vector per
    joint, its norm clipped to ``limit``), on top of its window's open-loop correction.

    Attributes:
        gains: ``[frames - 1, 3 joints, 12 bodies]`` (the LQR gains, applied with a plus sign).
        limit: the largest feedback correction per joint (radians).
        result: the status of the Riccati recursion (:class:`solvers.RESULTS`).
    """

    gains: Float[Array, "steps controls states"]
    limit: Float[Array, ""]
    result: RESULTS


class TrackingResult(eqx.Module):
    """The result of :func:`samcon`.

    Attributes:
        corrections: ``[windows, joints, 3]`` the rotation-vector correction of every physics
            joint's target in each control window (radians).
        trajectory: the simulated states at every frame (frame 0: the start; the frames the
            windows cover, ``windows * window + 1``).
        joint_error: ``[frames]`` mean joint rotation error against the clip (radians).
        root_error: ``[frames]`` horizontal distance of the root body from the clip's (meters).
        window_cost: ``[windows]`` the cost of each window along the kept lineage.
        status: :class:`TrackingStatus`.
        options: the options used.
        feedback: the time-varying feedback gains around ``trajectory``
            (:class:`~jaxanim.tracking.Feedback`, from :func:`~jaxanim.tracking.feedback`), or None.
        torque: ``[frames, joints]`` the largest stable-PD torque norm of each joint over each
            frame's physics steps (N m; frame 0, the start, is 0): within ``options.torque_limit``.
    """

    corrections: Float[Array, "windows joints 3"]
    trajectory: BodyState
    joint_error: Float[Array, " frames"]
    root_error: Float[Array, " frames"]
    window_cost: Float[Array, " windows"]
    status: TrackingStatus
    options: TrackingOptions
    feedback: Feedback | None = None
    torque: Float[Array, "frames joints"] | None = None

    @property
    def fell(self) -> Bool[Array, ""]:
        return self.status == TrackingStatus.fell


_UPPER_BODY = ("arm", "hand", "shoulder", "clavicle", "collar", "neck", "head", "finger", "thumb", "wrist", "elbow")


def joint_sigma(character: Character, body: float = 0.15, upper: float = 0.05) -> Float[Array, " joints"]:
    """Per physics joint sampling spreads for :class:`TrackingOptions` ``sigma``: ``upper`` for the
    joints that move an arm, the neck or the head (by the child joint's name), ``body`` for the legs
    and the spine, which carry the balance. Sampling the arms and head less keeps them close to the
    clip (on the shipped walk, 4 s, with the earlier defaults kp 1000, w_pose 1: mean joint error
    0.16 rad instead of 0.19) while they still help the balance (with 0.02 the walk fell)."""
    skel = character.skeleton
    child_joint = np.asarray(character.body_joint)[np.asarray(character.model.joints.child)]
    names = [skel.names[j].lower() for j in child_joint]
    dtype = character.model.bodies.mass.dtype
    return jnp.asarray([upper if any(k in n for k in _UPPER_BODY) else body for n in names], dtype)


_TORQUE_PER_KG = {  # N m per kg of the character's mass: roughly adult maximal voluntary joint torques
    "hip": 4.0, "knee": 3.5, "ankle": 3.0, "toe": 1.0, "trunk": 4.0, "neck": 1.0,
    "shoulder": 1.5, "elbow": 1.0, "wrist": 0.3,
}
_TORQUE_ROLES = (  # (role, words of the child joint's name), first match wins; else "trunk"
    ("toe", ("toe",)), ("ankle", ("foot", "ankle")), ("hip", ("upleg", "thigh", "hip")),
    ("knee", ("leg", "knee", "shin", "calf")), ("wrist", ("hand", "wrist", "finger", "thumb")),
    ("elbow", ("forearm", "elbow", "lowerarm")), ("shoulder", ("arm", "shoulder", "clavicle", "collar")),
    ("neck", ("neck", "head")),
)


def joint_torque_limits(character: Character, per_kg: Mapping[str, float] | None = None) -> Float[Array, " joints"]:
    """A human-like bound on each physics joint's torque norm (N m), for :class:`TrackingOptions`
    ``torque_limit``: the joint's role, from its child joint's name (hip, knee, ankle, toe, trunk,
    neck, shoulder, elbow, wrist; a name with none of their words counts as trunk), times the
    character's mass, times the role's N m / kg: by default hip 4, knee 3.5, ankle 3, toe 1, trunk 4,
    neck 1, shoulder 1.5, elbow 1, wrist 0.3, roughly an adult's maximal voluntary torques (for 70 kg:
    280 N m at the hip, 245 at the knee, 210 at the ankle). ``per_kg`` overrides some roles.

    Raises:
        JaxanimError: an unknown role in ``per_kg`` or a negative value.
    """
    table = dict(_TORQUE_PER_KG)
    for role, value in (per_kg or {}).items():
        if role not in table:
            raise JaxanimError(f"per_kg: unknown role {role!r}; the roles are {sorted(table)}")
        if not value >= 0:
            raise JaxanimError(f"per_kg[{role!r}]: expected N m / kg >= 0, got {value!r}")
        table[role] = float(value)
    skel = character.skeleton
    child_joint = np.asarray(character.body_joint)[np.asarray(character.model.joints.child)]
    mass = float(np.sum(np.asarray(character.model.bodies.mass)))

    def role(name: str) -> str:
        name = name.lower()
        return next((r for r, words in _TORQUE_ROLES if any(w in name for w in words)), "trunk")

    limits = [mass * table[role(skel.names[j])] for j in child_joint]
    return jnp.asarray(limits, character.model.bodies.mass.dtype)


def state_difference(state: BodyState, nominal: BodyState) -> Float[Array, " 12*bodies"]:
    """The tangent-space difference ``state - nominal`` of two body states, flattened:
    ``[positions (m), orientations (rotation vectors of q q_nominal^-1, world frame, rad), linear
    velocities, angular velocities]``, each ``[bodies, 3]``. This is the state of the feedback
    gains (:func:`jaxanim.tracking.feedback`); :func:`state_retract` is its inverse."""
    dq = rot.quat_canonical(rot.quat_multiply(state.orientation, rot.quat_conjugate(nominal.orientation)))
    return jnp.stack([state.position - nominal.position, rot.quat_to_rotvec(dq),
                      state.linear_velocity - nominal.linear_velocity,
                      state.angular_velocity - nominal.angular_velocity]).reshape(-1)


def state_retract(nominal: BodyState, dx: Float[Array, " 12*bodies"]) -> BodyState:
    """The state ``nominal + dx`` (``dx`` as :func:`state_difference` gives it)."""
    dx = dx.reshape(4, nominal.position.shape[0], 3)
    q = rot.quat_multiply(rot.rotvec_to_quat(dx[1]), nominal.orientation)
    return BodyState(nominal.position + dx[0], q, nominal.linear_velocity + dx[2],
                     nominal.angular_velocity + dx[3], nominal.time)


def _clip_norm(u: Float[Array, "joints 3"], limit) -> Float[Array, "joints 3"]:
    """``u`` with each row's norm clipped to ``limit``."""
    n = jnp.linalg.norm(u, axis=-1, keepdims=True)
    return u * jnp.minimum(1.0, limit / jnp.maximum(n, jnp.finfo(u.dtype).tiny))


class _Problem(NamedTuple):
    window: Callable
    simulate_frame: Callable
    start_state: Callable
    frame_cost: Callable
    errors: Callable
    fell: Callable
    num_joints: int


_TORSO = ("chest", "spine", "torso", "thorax", "back", "abdomen")


def torso_body(character: Character) -> int:
    """The body to push "on the torso": the first body (in the model's order, parents first) whose
    joint's name contains chest, else the last one with spine, torso, thorax, back or abdomen in it,
    else the root body."""
    names = [character.skeleton.names[j].lower() for j in character.body_joint]
    chest = [b for b, n in enumerate(names) if "chest" in n]
    if chest:
        return chest[0]
    spine = [b for b, n in enumerate(names) if any(k in n for k in _TORSO)]
    return spine[-1] if spine else root_body(character)


_WINDOW_SECONDS = 0.1  # a control window
_LOOKAHEAD_WINDOWS = 2  # the look-ahead of a sample, in windows
_PHYSICS_RATE = 120.0  # physics steps per second, at least


def tracking_options(character: Character, frame_time: float, samples: int = 256, **numbers) -> TrackingOptions:
    """The options ``jaxanim track --samples N`` uses for a clip of ``frame_time`` seconds per frame:
    windows of 0.1 s (3 frames at 30 fps, 12 at 120 fps), two windows of look-ahead, at least 120
    physics steps per second, ``elites = clamp(samples // 4, 1, 32)`` and the spreads of
    :func:`joint_sigma`; ``numbers`` override the array fields (``kp=...``, ``w_pose=...``)."""
    frame_time = float(frame_time)
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise JaxanimError(f"frame_time: expected a positive number of seconds, got {frame_time!r}")
    samples = _positive_int("samples", samples, 2)
    window = max(1, round(_WINDOW_SECONDS / frame_time))
    return TrackingOptions(samples=samples, elites=max(1, min(samples // 4, 32)), window=window,
                           lookahead=_LOOKAHEAD_WINDOWS * window,
                           steps_per_frame=max(1, math.ceil(_PHYSICS_RATE * frame_time - 1e-9)),
                           **{"sigma": joint_sigma(character), "torque_limit": joint_torque_limits(character),
                              **numbers})


def _problem(character: Character, reference: TrackingReference, options: TrackingOptions):
    """The window simulation and its cost, closed over the model, the reference and the options."""
    model = character.model
    nj = model.joints.num_joints
    root = root_body(character)
    ref = reference.states
    dtype = ref.position.dtype
    h = reference.frame_time / options.steps_per_frame
    kp = jnp.broadcast_to(options.kp.astype(dtype), (nj,))
    kd = jnp.broadcast_to(options.kd.astype(dtype), (nj,))
    normal = model.ground.normal
    limit = None if options.torque_limit is None else jnp.broadcast_to(options.torque_limit.astype(dtype), (nj,))

    def frame_cost(s: BodyState, f):
        e, _ = joint_errors(model.joints, s, reference.targets[f])
        pose = jnp.mean(jnp.sum(e * e, -1))
        pos = jnp.mean(jnp.sum((s.position - ref.position[f]) ** 2, -1))
        vel = jnp.mean(jnp.sum((s.linear_velocity - ref.linear_velocity[f]) ** 2, -1))
        r = rot.quat_distance(s.orientation[root], ref.orientation[f, root])
        return options.w_pose * pose + options.w_position * pos + options.w_velocity * vel + options.w_root * r * r

    last = reference.num_frames - 1

    def simulate_frame(s: BodyState, f, dq, push=None):
        """Simulate frame ``f`` (from frame ``f - 1``'s state ``s``) towards the targets of frame ``f``
        corrected by ``dq`` (``[joints, 4]``, right-multiplied): ``(state, the largest stable-PD
        torque norm per joint over the frame's steps [joints])``."""
        spd = StablePD(rot.quat_multiply(reference.targets[f], dq), kp, kd, limit)

        def physics_step(s, k):
            force = None
            if push is not None:  # (body, force [3], first step, last step) of the whole run
                body, fvec, first, stop = push
                n = (f - 1) * options.steps_per_frame + k
                on = (n >= first) & (n < stop)
                force = jnp.zeros_like(s.position).at[body].set(jnp.where(on, 1.0, 0.0) * fvec)
            s, tau = step_and_torques(model, s, control_for(model, Control(spd=spd, force=force)), h)
            return s, jnp.linalg.norm(tau, axis=-1)

        s, tau = jax.lax.scan(physics_step, s, jnp.arange(options.steps_per_frame))
        return s, jnp.max(tau, axis=0)

    def window(s: BodyState, f0, correction, push=None, lookahead: int = 0, feedback=None):
        """Simulate the frames ``f0 + 1 .. f0 + window`` (and ``lookahead`` more with the same
        correction, for the cost only): ``(state at the window's end, cost, (states, peak torque
        norms [joints]) per frame of the window)``. ``feedback``: ``(gains [frames - 1, 3 joints, 12 bodies], nominal states [frames],
        limit)`` adds ``clip(gains[f - 1] @ state_difference(s, nominal[f - 1]), limit)`` per joint to
        the correction of frame ``f``."""
        dq = rot.rotvec_to_quat(correction)

        def frame(carry, i):
            s, c = carry
            f = jnp.minimum(f0 + i + 1, last)
            dqf = dq
            if feedback is not None:
                gains, nominal, limit = feedback
                dx = state_difference(s, jax.tree.map(lambda x: x[f - 1], nominal))
                u = matmul(gains[f - 1], dx).reshape(nj, 3)
                dqf = rot.quat_multiply(dq, rot.rotvec_to_quat(_clip_norm(u, limit)))
            s, tau = simulate_frame(s, f, dqf, push)
            return (s, c + frame_cost(s, f)), (s, tau)

        (s, c), states = jax.lax.scan(frame, (s, jnp.zeros((), dtype)), jnp.arange(options.window + lookahead))
        if lookahead:
            states = jax.tree.map(lambda x: x[: options.window], states)
            s = jax.tree.map(lambda x: x[-1], states[0])
        return s, c, states

    def start_state():
        return jax.tree.map(lambda x: x[0], ref)

    def errors(states: BodyState):
        """``(mean joint error [frames], horizontal root error [frames])`` of frames 0 ..."""
        F = states.position.shape[0]

        def one(s, f):
            e, _ = joint_errors(model.joints, s, reference.targets[f])
            d = s.position[root] - ref.position[f, root]
            d = d - dot(d, normal) * normal
            return jnp.mean(jnp.linalg.norm(e, axis=-1)), jnp.linalg.norm(d)

        return jax.vmap(one)(states, jnp.arange(F))

    def fell(states: BodyState):
        height = matmul(states.position[:, root], normal)
        lowest = jnp.min(matmul(ref.position[:, root], normal))
        return jnp.any(height < 0.7 * lowest)

    return _Problem(window, simulate_frame, start_state, frame_cost, errors, fell, nj)


def _check_key(key) -> None:
    """A ``jax.random`` key: a typed key, or a raw ``uint32[2]`` one (a batch of keys under ``vmap``)."""
    dtype = getattr(key, "dtype", None)
    if dtype is not None and (jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key)
                              or (dtype == jnp.uint32 and getattr(key, "shape", ())[-1:] == (2,))):
        return
    raise JaxanimError(f"key: expected a jax.random key (jax.random.PRNGKey(seed) or jax.random.key(seed)), got "
                       f"{key!r}" if dtype is None else f"key: expected a jax.random key (jax.random.PRNGKey(seed) "
                       f"or jax.random.key(seed)), got an array of dtype {dtype} and shape {key.shape}")


def _check(character, reference, options):
    if not isinstance(character, Character):
        raise JaxanimError(f"character: expected a jaxanim.character.Character, got {type(character).__name__}")
    if not isinstance(reference, TrackingReference):
        raise JaxanimError(f"reference: expected a TrackingReference (tracking_reference), got {type(reference).__name__}")
    options = TrackingOptions() if options is None else options
    if not isinstance(options, TrackingOptions):
        raise JaxanimError(f"options: expected a TrackingOptions, got {type(options).__name__}")
    nj = character.model.joints.num_joints
    for name in ("sigma", "kp", "kd", "torque_limit"):  # broadcast to [joints] inside: name a bad length here
        shape = getattr(getattr(options, name), "shape", ())
        if shape not in ((), (1,), (nj,)):
            raise JaxanimError(f"options.{name}: expected a scalar or shape ({nj},) (one per physics joint), "
                               f"got shape {tuple(shape)}")
    windows = windows_of(reference, options)
    if windows < 1:
        raise JaxanimError(
            f"reference: {reference.num_frames} frames are too short for one control window of {options.window} "
            f"frames (need at least {options.window + 1})"
        )
    return options, windows


def samcon(
    character: Character,
    reference: TrackingReference,
    key: Array,
    options: TrackingOptions | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
) -> TrackingResult:
    """Track ``reference`` with joint torques only by sampling-based control (see the module docstring).

    Args:
        character: the physics character, with a ground (:func:`~jaxanim.character.build_character`).
        reference: :func:`tracking_reference` of the clip (loop the clip first for a longer run).
        key: a ``jax.random`` key: the search is deterministic for a key.
        options: :class:`TrackingOptions` (default ``TrackingOptions()``).
        progress: ``progress(window, windows)`` called from the compiled search after every window
            (host callback; for progress bars).

    Returns:
        :class:`TrackingResult`; ``(reference.num_frames - 1) // window`` windows are tracked.

    Raises:
        JaxanimError: a reference too short for one window, or arguments of the wrong type.
    """
    options, windows = _check(character, reference, options)
    _check_key(key)
    if progress is None:
        return _samcon(character, reference, key, options, windows)
    _PROGRESS.append(progress)
    try:  # the callbacks run while the search does: wait for it before taking the callback away
        return jax.block_until_ready(_samcon(character, reference, key, options, windows))
    finally:
        _PROGRESS.pop()


_PROGRESS: list[Callable[[int, int], None]] = []  # the callbacks of the searches running now (innermost last)


def _report(window, windows) -> None:
    """The host side of the compiled search's progress callback: tell the current callback, if any
    (a module-level function, so that a search with a callback and one without share a program)."""
    if _PROGRESS:
        _PROGRESS[-1](int(window), int(windows))


@jit
def _samcon(character, reference, key, options: TrackingOptions, windows: int):
    window, _, start_state, frame_cost, errors, fell, nj = _problem(character, reference, options)
    N, K, W = options.samples, options.elites, options.window
    start = start_state()
    elites = jax.tree.map(lambda x: jnp.broadcast_to(x, (K,) + x.shape), start)
    dtype = start.position.dtype

    def per_window(carry, w):
        elites, mean, key = carry
        key, sub = jax.random.split(key)
        sigma = jnp.broadcast_to(options.sigma.astype(dtype), (nj,))[None, :, None]
        corr = mean[None] + sigma * jax.random.normal(sub, (N, nj, 3), dtype)
        parent = jnp.arange(N) % K
        starts = jax.tree.map(lambda x: x[parent], elites)
        ends, costs, states = jax.vmap(lambda s, c: window(s, w * W, c, None, options.lookahead))(starts, corr)
        costs = jnp.where(jnp.isfinite(costs), costs, jnp.inf)
        _, best = jax.lax.top_k(-costs, K)
        jax.debug.callback(_report, w + 1, windows)
        kept = jax.tree.map(lambda x: x[best], states)  # [K, W, ...]: the elites' frames, for the result
        return (jax.tree.map(lambda x: x[best], ends), jnp.mean(corr[best], axis=0), key), (corr[best], parent[best], kept)

    init = (elites, jnp.zeros((nj, 3), dtype), key)
    _, (corrections, parents, kept) = jax.lax.scan(per_window, init, jnp.arange(windows))

    # the lineage of the best final state (elite 0), traced back through the parents
    def back(i, x):
        corr, parent, states = x
        return parent[i], (corr[i], jax.tree.map(lambda a: a[i], states))

    _, (lineage, states) = jax.lax.scan(back, jnp.zeros((), parents.dtype), (corrections, parents, kept), reverse=True)
    return _result(reference, options, start, lineage, states, frame_cost, errors, fell)


def _result(reference, options, start, corrections, states, frame_cost, errors, fell) -> TrackingResult:
    """The result from the kept corrections and the (states, peak torques) of every window's frames
    ``[windows, W, ...]``."""
    windows, W = corrections.shape[0], options.window
    states, torque = states
    torque = jnp.concatenate([jnp.zeros_like(torque[0, :1]), torque.reshape((-1,) + torque.shape[2:])])
    traj = jax.tree.map(lambda a0, a: jnp.concatenate([a0[None], a.reshape((-1,) + a.shape[2:])]), start, states)
    frames = jnp.arange(1, windows * W + 1)
    costs = jax.vmap(frame_cost)(jax.tree.map(lambda a: a[1:], traj), frames).reshape(windows, W).sum(axis=1)
    joint_error, root_error = errors(traj)
    status = TrackingStatus.where(fell(traj), TrackingStatus.fell, TrackingStatus.successful)
    return TrackingResult(corrections=corrections, trajectory=traj, joint_error=joint_error, root_error=root_error,
                          window_cost=costs, status=status, options=options, torque=torque)


def _replay(character, reference, options, corrections, push, law: Feedback, nominal: BodyState):
    """Simulate the corrections from the start with ``push`` ``(body, force, first step, last step)``
    and the feedback ``law`` around ``nominal``; the :class:`TrackingResult` (without feedback)."""
    problem = _problem(character, reference, options)
    start = problem.start_state()
    W = options.window
    law = (law.gains, nominal, law.limit)

    def per_window(s, x):
        w, corr = x
        s, _, states = problem.window(s, w * W, corr, push, 0, law)
        return s, states

    _, states = jax.lax.scan(per_window, start, (jnp.arange(corrections.shape[0]), corrections))
    return _result(reference, options, start, corrections, states, problem.frame_cost, problem.errors, problem.fell)


def replay(
    character: Character,
    reference: TrackingReference,
    result: TrackingResult,
    *,
    push: tuple[int, Float[Array, "3"], float, float] | None = None,
    feedback: bool | None = None,
) -> TrackingResult:
    """Simulate a result's corrections again from the start, optionally with a push and feedback.

    Args:
        character, reference: as given to :func:`samcon`.
        result: a :class:`TrackingResult`.
        push: ``(body, force [3] (N, world), start (s), duration (s))``: an external force on one
            body's center of mass for a while (a disturbance: the open-loop controls do not change).
        feedback: apply the result's feedback gains (:func:`~jaxanim.tracking.feedback`) around its
            trajectory: ``None`` (default) when the result has them, ``True`` to require them,
            ``False`` for the open-loop corrections alone.

    Returns:
        The :class:`TrackingResult` of the replay (without a push it equals ``result``: with
        feedback too, since the state never leaves the trajectory the gains were made for).

    Raises:
        JaxanimError: ``feedback=True`` for a result without gains, or a ``push`` whose body is not one
            of the character's, whose force is not 3 finite numbers, or whose start or duration is
            negative or not finite.
    """
    options, _ = _check(character, reference, result.options)
    dtype = reference.states.position.dtype
    # One program for every replay: no push is a zero force, no feedback zero gains (u = 0 exactly).
    body, force, start, duration = (0, jnp.zeros(3, dtype), 0.0, 0.0) if push is None else _check_push(
        push, result.trajectory.position.shape[1])
    steps = options.steps_per_frame / float(reference.frame_time)
    push = (jnp.asarray(int(body)), jnp.asarray(force, dtype), jnp.asarray(round(float(start) * steps)),
            jnp.asarray(round(float(start + duration) * steps)))
    if feedback and result.feedback is None:
        raise JaxanimError("feedback=True: the result has no feedback gains (compute them with tracking.feedback)")
    if feedback is False or result.feedback is None:
        frames, nb = result.trajectory.position.shape[:2]
        law = Feedback(gains=jnp.zeros((frames - 1, result.corrections.shape[1] * 3, 12 * nb), dtype),
                       limit=jnp.zeros((), dtype), result=RESULTS.successful)
    else:
        law = result.feedback
    replayed = _replay_jit(character, reference, options, result.corrections, push, law, result.trajectory)
    if law is not result.feedback:  # open loop
        return replayed
    return eqx.tree_at(lambda r: r.feedback, replayed, law, is_leaf=lambda x: x is None)


_replay_jit = jit(_replay)


def _check_push(push, num_bodies: int):
    """``(body, force [3], start, duration)`` checked in Python (a wrong body or a negative duration would
    otherwise push nothing without a word)."""
    if not isinstance(push, (tuple, list)) or len(push) != 4:
        raise JaxanimError(f"push: expected (body, force [3], start, duration), got {push!r}")
    body, force, start, duration = push
    if isinstance(body, bool) or not isinstance(body, (int, np.integer)) or not 0 <= int(body) < num_bodies:
        raise JaxanimError(f"push: body {body!r} is not one of the character's {num_bodies} bodies (0 to {num_bodies - 1})")
    f = np.asarray(force, dtype=np.float64)
    if f.shape != (3,) or not np.isfinite(f).all():
        raise JaxanimError(f"push: the force must be 3 finite numbers (N, world), got {force!r}")
    for name, value in (("start", start), ("duration", duration)):
        v = np.asarray(value, dtype=np.float64)
        if v.shape != () or not np.isfinite(v) or v < 0:
            raise JaxanimError(f"push: {name} must be a finite number of seconds >= 0, got {value!r}")
    return int(body), force, float(start), float(duration)


def windows_of(reference: TrackingReference, options: TrackingOptions | None = None) -> int:
    """How many control windows :func:`samcon` tracks for a reference."""
    options = TrackingOptions() if options is None else options
    return (reference.num_frames - 1) // options.window

