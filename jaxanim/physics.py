r"""Articulated rigid-body simulation: the model, one time step, and export to MuJoCo's MJCF.

:class:`PhysicsModel` holds the bodies (:class:`~jaxanim.rigid.RigidBodies`), the joints
(:class:`~jaxanim.joints.Joints`) and the constraint parameters; the state is a
:class:`~jaxanim.rigid.BodyState`. :func:`step` advances it by one step of the course notes'
eq. 6.28 (maximal coordinates, velocity-level constraints):

1. free velocities from the loads, ``v* = v + h (f/m + g)``, ``omega* = omega + h I_n^{-1} tau``
   (joint torques ``tau_j`` act as ``+tau_j`` on the child and ``-tau_j`` on the parent, eq. 7.1);
2. the joint impulses ``lambda`` from ``(J M^{-1} J' + cfm I) lambda = -(erp / h) g - J [v*; omega*]``
   (eq. 6.20 with ERP and CFM), ``[v; omega] = [v*; omega*] + M^{-1} J' lambda``, ``M = diag(m I,
   I_n)``, ``J`` and ``g`` at step ``n`` (:func:`~jaxanim.joints.joint_rows`);
3. ``x_{n+1} = x_n + h v``, ``q_{n+1} = normalise(q_n + (h/2) [0, omega] q_n)``, and the angular
   velocity re-expressed at ``q_{n+1}`` with the angular momentum ``I_n omega`` of each body
   (the gyroscopic term in momentum form, as :func:`~jaxanim.rigid.step_free`).

**Solver for step 2**: the ``R x R`` system (``R`` = constraint rows, 57 for a 19-ball-joint tree)
is assembled densely and solved exactly by a Cholesky factorisation (``O(R^3)``; exact, no
iteration count to tune). ``cfm`` keeps it positive definite for redundant rows (closed loops).
With complementarity contact (:mod:`jaxanim.contact`) the contact rows join the system: the joint
block is eliminated exactly (Schur complement) and the contact impulses are found by projected
Gauss-Seidel with a fixed number of sweeps; penalty contact instead adds forces to the loads of
step 1.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from . import rotations as rot
from ._errors import JaxanimError, check_shape
from .contact import Ground, contact_rows, make_ground, penalty_loads, projected_gauss_seidel
from .control import joint_errors
from .joints import Joints, joint_rows
from .rigid import BodyState, RigidBodies, _check_loads, _check_model, _free_velocities, _integrate

__all__ = ["PhysicsModel", "Rollout", "SimResult", "joint_error", "make_model", "rollout", "step", "to_mjcf"]


class PhysicsModel(eqx.Module):
    """Bodies, joints and constraint parameters (the constant part of a simulation).

    Attributes:
        bodies: the rigid bodies.
        joints: the joints (may be empty).
        erp: the error-reduction parameter in ``[0, 1]``: the fraction of each joint's position
            error removed per step (default 0.5: the first-order rotation update leaves an
            ``O(h^2 omega^2 r)`` anchor error per step, and the steady drift is that over ``erp``;
            a double pendulum of 0.5 m capsules drifts < 5e-5 m at 600 Hz).
        cfm: constraint-force mixing, added to the diagonal of ``J M^{-1} J'``.
        ground: the ground plane and contact model (:class:`~jaxanim.contact.Ground`; model
            ``"none"`` for no contact).
    """

    bodies: RigidBodies
    joints: Joints
    erp: Float[Array, ""]
    cfm: Float[Array, ""]
    ground: Ground


def make_model(
    bodies: RigidBodies, joints: Joints | None = None, *, ground: Ground | None = None, erp: float = 0.5,
    cfm: float = 1e-10,
) -> PhysicsModel:
    """A :class:`PhysicsModel`; ``erp`` in ``[0, 1]``, ``cfm >= 0``; no joints and no ground by
    default (:func:`~jaxanim.contact.make_ground` for one)."""
    _check_model(bodies)
    if not 0 <= erp <= 1:
        raise JaxanimError(f"erp: expected a value in [0, 1], got {erp!r}")
    if not cfm >= 0:
        raise JaxanimError(f"cfm: expected >= 0, got {cfm!r}")
    if joints is None:
        z = np.zeros((0, 3))
        joints = Joints(names=(), types=(), parent=(), child=(), anchor_parent=jnp.asarray(z), anchor_child=jnp.asarray(z),
                        axis_parent=jnp.asarray(z), axis_child=jnp.asarray(z), rest=jnp.zeros((0, 4)))
    for name, idx in (("parent", joints.parent), ("child", joints.child)):
        if any(i >= bodies.num_bodies for i in idx):
            raise JaxanimError(f"joints.{name}: a body index is out of range for {bodies.num_bodies} bodies")
    dtype = bodies.mass.dtype
    ground = make_ground("none", dtype=dtype) if ground is None else ground
    return PhysicsModel(bodies=bodies, joints=joints, erp=jnp.asarray(erp, dtype), cfm=jnp.asarray(cfm, dtype),
                        ground=ground)


def joint_error(model: PhysicsModel, state: BodyState) -> Float[Array, " J"]:
    """Per joint, the distance between its two anchors (metres): the constraint drift."""
    _, _, g = joint_rows(model.joints, state)
    return jnp.linalg.norm(g[:, :3], axis=-1)


def _apply_joint_torques(model: PhysicsModel, torque: Array, joint_torque: Array) -> Array:
    par = np.asarray(model.joints.parent)
    chi = np.asarray(model.joints.child)
    torque = torque.at[chi].add(joint_torque)
    has = par >= 0
    if np.any(has):
        torque = torque.at[par[has]].add(-joint_torque[np.nonzero(has)[0]])
    return torque


def _joint_matrix(model: PhysicsModel, state: BodyState, h):
    """Dense joint rows ``J [R, B, 6]`` and their targets ``-(erp / h) g [R]``."""
    joints = model.joints
    B = model.bodies.num_bodies
    dtype = state.position.dtype
    jj, rr = np.nonzero(joints.row_mask)
    R = jj.size
    if R == 0:
        return jnp.zeros((0, B, 6), dtype), jnp.zeros((0,), dtype)
    Jp, Jc, g = joint_rows(joints, state)
    par = np.asarray(joints.parent)[jj]
    chi = np.asarray(joints.child)[jj]
    rows = np.arange(R)
    Jd = jnp.zeros((R, B, 6), dtype).at[rows, chi].add(Jc[jj, rr])
    has = par >= 0
    if np.any(has):
        Jd = Jd.at[rows[has], par[has]].add(Jp[jj[has], rr[has]])
    return Jd, -(model.erp / h) * g[jj, rr]


def _soft_gains(e, kp, kd, h):
    """The soft constraint ``J v + cfm lambda = b`` of the implicit PD law
    ``tau = k_p (e - h J v) - k_d J v`` on the impulse ``lambda = h tau``: ``b = k_p e / (h k_p +
    k_d)``, ``cfm = 1 / (h (h k_p + k_d))``, broadcast to ``e``'s shape, with the mask of driven
    rows (``h k_p + k_d > 0``); rows not driven get ``b = 0``, ``cfm = 1`` and must have ``J = 0``."""
    c = jnp.broadcast_to(h * kp + kd, e.shape)
    active = c > 0
    c_safe = jnp.where(active, c, 1.0)
    b = jnp.where(active, jnp.broadcast_to(kp, e.shape) * e / c_safe, 0.0)
    cfm = jnp.where(active, 1.0 / (h * c_safe), 1.0)
    return b, cfm, active


def _motor_rows(model: PhysicsModel, state: BodyState, spd, h):
    """Stable-PD rows on every joint's relative angular velocity: ``(J [3J, B, 6], b [3J], cfm [3J])``.

    The implicit law ``tau = k_p (e - h w) - k_d w`` (``w`` the new relative angular velocity,
    ``e`` the error at step ``n``) is the soft constraint ``w + cfm lambda = b`` on the impulse
    ``lambda = h tau`` with ``b = k_p e / (h k_p + k_d)`` and ``cfm = 1 / (h (h k_p + k_d))``.
    """
    targets, kp, kd = spd
    joints = model.joints
    Jn, B = joints.num_joints, model.bodies.num_bodies
    dtype = state.position.dtype
    e, _ = joint_errors(joints, state, rot.quat_normalize(targets))
    b, cfm, active = _soft_gains(e, kp[:, None], kd[:, None], h)
    b, cfm = b.reshape(3 * Jn), cfm.reshape(3 * Jn)
    eye = jnp.eye(3, dtype=dtype)
    blk = jnp.where(active[:, :, None], eye[None], 0.0)  # [J, 3, 3], zero rows where not driven
    rows = np.arange(3 * Jn)
    chi = np.repeat(np.asarray(joints.child), 3)
    par = np.repeat(np.asarray(joints.parent), 3)
    Jm = jnp.zeros((3 * Jn, B, 6), dtype).at[rows, chi, 3:].set(blk.reshape(3 * Jn, 3))
    has = par >= 0
    if np.any(has):
        Jm = Jm.at[rows[has], par[has], 3:].set(-blk.reshape(3 * Jn, 3)[has])
    return Jm, b, cfm


def _servo_rows(model: PhysicsModel, state: BodyState, servo, h):
    """Stable-PD rows pulling one body to a world pose (the "hand of God"): ``(J [6, B, 6], b, cfm)``,
    the soft constraint of :func:`_motor_rows` on the body's linear and angular velocity."""
    body, x_t, q_t, kp_l, kd_l, kp_a, kd_a = servo
    B = model.bodies.num_bodies
    dtype = state.position.dtype
    e_lin = x_t - state.position[body]
    e_ang = rot.quat_to_rotvec(rot.quat_canonical(rot.quat_multiply(q_t, rot.quat_conjugate(state.orientation[body]))))
    e = jnp.stack([e_lin, e_ang])  # [2, 3]
    b, cfm, active = _soft_gains(e, jnp.stack([kp_l, kp_a])[:, None], jnp.stack([kd_l, kd_a])[:, None], h)
    rows = jnp.zeros((6, B, 6), dtype).at[np.arange(6), body, np.arange(6)].set(active.reshape(6).astype(dtype))
    return rows, b.reshape(6), cfm.reshape(6)


def _solve_constraints(model: PhysicsModel, state: BodyState, v, w, I_n, h, spd=None, servo=None):
    """Velocities after the joint, stable-PD, servo and (complementarity) contact impulses."""
    dtype = v.dtype
    Jj, bj = _joint_matrix(model, state, h)
    cfm_extra = jnp.zeros((Jj.shape[0],), dtype)
    if spd is not None:
        Jm, bm, cm = _motor_rows(model, state, spd, h)
        Jj, bj, cfm_extra = jnp.concatenate([Jj, Jm]), jnp.concatenate([bj, bm]), jnp.concatenate([cfm_extra, cm])
    if servo is not None:
        Js, bs, cs = _servo_rows(model, state, servo, h)
        Jj, bj, cfm_extra = jnp.concatenate([Jj, Js]), jnp.concatenate([bj, bs]), jnp.concatenate([cfm_extra, cs])
    contact = model.ground.model == "complementarity"
    if contact:
        Jc, bc = contact_rows(model.ground, model.bodies, state, h)
    else:
        Jc, bc = jnp.zeros((0,) + Jj.shape[1:], dtype), jnp.zeros((0,), dtype)
    Rj, Rc = Jj.shape[0], Jc.shape[0]
    if Rj + Rc == 0:
        return v, w
    J = jnp.concatenate([Jj, Jc])
    inv_m = (1.0 / model.bodies.mass)[:, None, None] * jnp.eye(3, dtype=dtype)[None]
    W_lin = jnp.einsum("rbi,bij->rbj", J[..., :3], inv_m)
    W_ang = jnp.einsum("rbi,bij->rbj", J[..., 3:], jnp.linalg.inv(I_n))
    W = jnp.concatenate([W_lin, W_ang], axis=-1)  # J M^{-1}, [R, B, 6]
    A = jnp.einsum("rbj,sbj->rs", W, J)
    A = 0.5 * (A + A.T) + model.cfm * jnp.eye(Rj + Rc, dtype=dtype)
    A = A + jnp.diag(jnp.concatenate([cfm_extra, jnp.zeros((Rc,), dtype)]))
    V = jnp.concatenate([v, w], axis=-1)
    rhs = jnp.concatenate([bj, bc]) - jnp.einsum("rbi,bi->r", J, V)
    if Rc == 0:
        lam = jax.scipy.linalg.cho_solve((jnp.linalg.cholesky(A), True), rhs)
    else:
        # Joints eliminated exactly (Schur complement of their block), contacts by PGS.
        Acc, rc = A[Rj:, Rj:], rhs[Rj:]
        if Rj:
            L = jnp.linalg.cholesky(A[:Rj, :Rj])
            X = jax.scipy.linalg.cho_solve((L, True), A[:Rj, Rj:])
            y = jax.scipy.linalg.cho_solve((L, True), rhs[:Rj])
            Acc = Acc - A[Rj:, :Rj] @ X
            rc = rc - A[Rj:, :Rj] @ y
        lam_c = projected_gauss_seidel(Acc, rc, model.ground.friction, model.ground.iterations)
        lam = lam_c if not Rj else jnp.concatenate([y - X @ lam_c, lam_c])
    V = V + jnp.einsum("rbj,r->bj", W, lam)
    return V[:, :3], V[:, 3:]


def _step(model: PhysicsModel, state: BodyState, force, torque, joint_torque, h, spd=None, servo=None) -> BodyState:
    torque = _apply_joint_torques(model, torque, joint_torque) if model.joints.num_joints else torque
    if model.ground.model == "penalty":
        f_c, tau_c = penalty_loads(model.ground, model.bodies, state)
        force, torque = force + f_c, torque + tau_c
    v, w, I_n = _free_velocities(model.bodies, state, force, torque, h)
    v, w = _solve_constraints(model, state, v, w, I_n, h, spd, servo)
    return _integrate(model.bodies, state, v, w, I_n, h)


def _check_inputs(model: PhysicsModel, state: BodyState, force, torque, joint_torque) -> list[Array]:
    B, Jn = model.bodies.num_bodies, model.joints.num_joints
    loads = (("force", force, B, "B"), ("torque", torque, B, "B"), ("joint_torque", joint_torque, Jn, "J"))
    return _check_loads(state, B, model.bodies.mass.dtype, loads)


@eqx.filter_jit
def _step_jit(model, state, force, torque, joint_torque, h, spd, servo):
    return _step(model, state, force, torque, joint_torque, h, spd, servo)


def step(
    model: PhysicsModel,
    state: BodyState,
    dt: Float[ArrayLike, ""],
    *,
    force: Float[ArrayLike, "B 3"] | None = None,
    torque: Float[ArrayLike, "B 3"] | None = None,
    joint_torque: Float[ArrayLike, "J 3"] | None = None,
    spd: tuple[Float[ArrayLike, "J 4"], Float[ArrayLike, " J"], Float[ArrayLike, " J"]] | None = None,
    servo: tuple | None = None,
) -> BodyState:
    """Advance the articulated bodies by one step of ``dt`` seconds (see the module docstring).

    Args:
        model: the :class:`PhysicsModel`.
        state: the bodies' state.
        dt: the step, seconds.
        force: ``[B, 3]`` external forces at the centres of mass (world frame, N).
        torque: ``[B, 3]`` external torques (world frame, N m).
        joint_torque: ``[J, 3]`` joint torques (world frame, N m): ``+tau`` on the child,
            ``-tau`` on the parent.
        spd: optional stable PD on every joint, ``(targets [J, 4], kp [J], kd [J])``: targets
            are the child's orientations relative to the parent (wxyz, ``q_p^{-1} q_c``), gains
            in N m / rad and N m s / rad (0 and 0: that joint is not driven). The law
            ``tau = k_p (e - h w) - k_d w`` is implicit in the new relative angular velocity ``w``
            and solved with the joint constraints (soft rows, the stable PD of Tan et al. 2011 in
            maximal coordinates); see :mod:`jaxanim.control` for ``e``.
        servo: optional stable PD of one body towards a world pose, the root force and torque
            ("hand of God"): ``(body (int), position [3], orientation [4], kp_lin, kd_lin,
            kp_ang, kd_ang)`` (N/m, N s/m, N m/rad, N m s/rad), implicit like ``spd``.

    Returns:
        The new :class:`~jaxanim.rigid.BodyState`.

    Raises:
        JaxanimError: shapes do not match the model.
    """
    loads = _check_inputs(model, state, force, torque, joint_torque)
    dtype = model.bodies.mass.dtype
    if spd is not None:
        Jn = model.joints.num_joints
        if not (isinstance(spd, (tuple, list)) and len(spd) == 3):
            raise JaxanimError("spd: expected (targets [J, 4], kp [J], kd [J])")
        targets, kp, kd = (jnp.asarray(a, dtype) for a in spd)
        check_shape("spd targets", targets, (Jn, 4), what=f"(J, 4) = ({Jn}, 4)")
        kp, kd = jnp.broadcast_to(kp, (Jn,)), jnp.broadcast_to(kd, (Jn,))
        spd = (targets, kp, kd)
    if servo is not None:
        if not (isinstance(servo, (tuple, list)) and len(servo) == 7):
            raise JaxanimError("servo: expected (body, position [3], orientation [4], kp_lin, kd_lin, kp_ang, kd_ang)")
        body = servo[0]
        if not isinstance(body, (int, np.integer)) or not 0 <= body < model.bodies.num_bodies:
            raise JaxanimError(f"servo: body must be an int in [0, {model.bodies.num_bodies}), got {body!r}")
        x_t, q_t = jnp.asarray(servo[1], dtype), rot.quat_normalize(jnp.asarray(servo[2], dtype))
        check_shape("servo position", x_t, (3,))
        check_shape("servo orientation", q_t, (4,))
        servo = (int(body), x_t, q_t, *(jnp.asarray(g, dtype) for g in servo[3:]))
    return _step_jit(model, state, *loads, jnp.asarray(dt, dtype), spd, servo)


class SimResult(eqx.Enumeration):
    """Status of a rollout, per character under ``vmap``."""

    successful = ""
    nonfinite = (
        "The state became non-finite (NaN or inf): the character was stopped at its last finite state. "
        "Reduce the step, the gains, or check the inputs."
    )
    exploded = (
        "A body moved faster than max_speed / max_angular_speed (a blow-up): the character was stopped at "
        "its last state below them. Reduce the step or the gains, or use stable PD."
    )


class Rollout(eqx.Module):
    """The result of :func:`rollout`.

    Attributes:
        final: the last state (the last good one if the character was stopped).
        trajectory: the recorded states, leading axis ``num_steps // record_every`` (a stopped
            character repeats its last good state).
        result: :class:`SimResult` (``successful``, ``nonfinite`` or ``exploded``).
        num_steps: steps completed (``< num_steps`` if stopped).
    """

    final: BodyState
    trajectory: BodyState
    result: SimResult
    num_steps: Int[Array, ""]


def _finite_state(s: BodyState) -> Array:
    return (
        jnp.all(jnp.isfinite(s.position)) & jnp.all(jnp.isfinite(s.orientation))
        & jnp.all(jnp.isfinite(s.linear_velocity)) & jnp.all(jnp.isfinite(s.angular_velocity))
    )


@eqx.filter_jit
def _rollout(model, state, h, num_steps, record_every, controller, controller_args, max_speed, max_angular_speed):
    B = model.bodies.num_bodies
    Jn = model.joints.num_joints
    dtype = h.dtype
    zeros = jnp.zeros((B, 3), dtype)
    jt0 = jnp.zeros((Jn, 3), dtype)

    def inner(carry, _):
        s, code, count = carry
        k = count
        u = {} if controller is None else controller(s, k, controller_args)
        new = _step(model, s, jnp.asarray(u.get("force", zeros), dtype), jnp.asarray(u.get("torque", zeros), dtype),
                    jnp.asarray(u.get("joint_torque", jt0), dtype), h, u.get("spd"), u.get("servo"))
        finite = _finite_state(new)
        fast = (jnp.max(jnp.abs(new.linear_velocity)) > max_speed) | (
            jnp.max(jnp.abs(new.angular_velocity)) > max_angular_speed
        )
        running = code == 0
        new_code = jnp.where(running, jnp.where(~finite, 1, jnp.where(fast, 2, 0)), code)
        ok = running & (new_code == 0)
        s = jax.tree.map(lambda a, b: jnp.where(ok, a, b), new, s)
        return (s, new_code, count + ok.astype(count.dtype)), None

    def outer(carry, _):
        carry, _ = jax.lax.scan(inner, carry, None, length=record_every)
        return carry, carry[0]

    init = (state, jnp.where(_finite_state(state), 0, 1), jnp.zeros((), jnp.int32))
    (final, code, count), traj = jax.lax.scan(outer, init, None, length=num_steps // record_every)
    result = SimResult.where(code == 0, SimResult.successful, SimResult.where(code == 1, SimResult.nonfinite,
                                                                               SimResult.exploded))
    return Rollout(final=final, trajectory=traj, result=result, num_steps=count)


def rollout(
    model: PhysicsModel,
    state: BodyState,
    dt: Float[ArrayLike, ""],
    num_steps: int,
    *,
    record_every: int = 1,
    controller: Callable | None = None,
    controller_args: Any = None,
    max_speed: float = 1e3,
    max_angular_speed: float = 1e4,
) -> Rollout:
    """``num_steps`` steps in a ``lax.scan``, with an optional controller, stopping a character that
    blows up.

    Args:
        model, state, dt: as for :func:`step`.
        num_steps: steps to take (static int, a multiple of ``record_every``).
        record_every: record the state every this many steps (static int >= 1).
        controller: ``controller(state, step, controller_args) -> dict`` with any of the keys
            ``force``, ``torque``, ``joint_torque``, ``spd``, ``servo`` of :func:`step` (default:
            passive; ``servo``'s body index must be a Python int).
            ``step`` is the step index (int array).
        controller_args: a pytree passed to the controller (``vmap`` over it to sweep gains).
        max_speed, max_angular_speed: a body faster than this (m/s, rad/s) counts as a blow-up.

    Returns:
        A :class:`Rollout`: the final state, the recorded trajectory, the :class:`SimResult` and the
        steps completed. A character whose state becomes non-finite or too fast is stopped at its
        last good state with that status; under ``vmap`` the others carry on.
    """
    for name, value in (("num_steps", num_steps), ("record_every", record_every)):
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 1:
            raise JaxanimError(f"{name}: expected an int >= 1, got {value!r}")
    if num_steps % record_every:
        raise JaxanimError(f"num_steps: expected a multiple of record_every = {record_every}, got {num_steps}")
    _check_inputs(model, state, None, None, None)
    dtype = model.bodies.mass.dtype
    return _rollout(model, state, jnp.asarray(dt, dtype), int(num_steps), int(record_every), controller,
                    controller_args, jnp.asarray(max_speed, dtype), jnp.asarray(max_angular_speed, dtype))


# --------------------------------------------------------------------------------------------
# MJCF export.
# --------------------------------------------------------------------------------------------


def _fmt(v) -> str:
    return " ".join(f"{float(x):.17g}" for x in np.ravel(v))


def _quat_between(q_parent: np.ndarray, q_child: np.ndarray) -> np.ndarray:
    return np.asarray(rot.quat_multiply(rot.quat_conjugate(jnp.asarray(q_parent)), jnp.asarray(q_child)))


def to_mjcf(
    model: PhysicsModel, state: BodyState, *, dt: float = 1 / 600, name: str = "jaxanim",
    stiffness: ArrayLike | None = None, damping: ArrayLike | None = None,
) -> str:
    """The model as MuJoCo XML, assembled at ``state``.

    Each body becomes a MuJoCo body whose frame is the body's frame (origin at its centre of
    mass), with an explicit ``inertial`` (mass and full inertia, so MuJoCo does not recompute them
    from the geoms) and its shape as a geom (capsules along body ``z``, as in MuJoCo). Bodies are
    nested along the joints; a ball joint becomes ``type="ball"``, a hinge ``type="hinge"``, a
    universal joint two hinges, a fixed joint no joint (welded), and a body that is no joint's
    child gets a ``freejoint``. Gravity and the time step are written in ``option``
    (``integrator="Euler"``).

    Contact: with ``model.ground`` of model ``"none"`` no geom collides. Otherwise the ground
    becomes a ``plane`` geom (its normal and offset, the ground's friction) and every body geom
    collides with it but not with other bodies (``contype="1" conaffinity="0"``, the plane
    ``contype="0" conaffinity="1"``), ``condim="3"`` (Coulomb friction), as jaxanim's contact model.

    Args:
        stiffness, damping: optional per-joint (``[J]`` or a scalar) spring stiffness (N m / rad)
            and damping (N m s / rad) pulling each joint to its assembly pose (MuJoCo's joint
            ``stiffness`` / ``damping``, whose spring reference is the assembly configuration
            ``qpos0``): a PD hold of the pose at ``state`` for comparisons with :func:`step`'s
            ``spd``; MuJoCo's Euler integrator treats the damping implicitly.

    Raises:
        JaxanimError: a body has two parent joints (the joints do not form a forest), or
            ``stiffness`` / ``damping`` of the wrong shape.
    """
    bodies, joints = model.bodies, model.joints
    Jn = joints.num_joints
    springs = {}
    for key, value in (("stiffness", stiffness), ("damping", damping)):
        if value is not None:
            arr = np.broadcast_to(np.asarray(value, float), (Jn,)) if np.ndim(value) == 0 else np.asarray(value, float)
            if arr.shape != (Jn,):
                raise JaxanimError(f"{key}: expected a scalar or shape ({Jn},) (one per joint), got {arr.shape}")
            springs[key] = arr
    collide = model.ground.model != "none"
    x = np.asarray(state.position, float)
    q = np.asarray(state.orientation, float)
    Rm = np.asarray(rot.quat_to_matrix(jnp.asarray(q)))
    parent_joint = {}
    for j, c in enumerate(joints.child):
        if c in parent_joint:
            raise JaxanimError(f"to_mjcf: body {bodies.names[c]!r} has two parent joints")
        parent_joint[c] = j
    children: dict[int, list[int]] = {}
    for c, j in parent_joint.items():
        children.setdefault(joints.parent[j], []).append(c)
    I = np.asarray(bodies.inertia, float)
    size = np.asarray(bodies.size, float)
    ap = np.asarray(joints.anchor_parent, float)
    ac = np.asarray(joints.anchor_child, float)
    ep = np.asarray(joints.axis_parent, float)
    ec = np.asarray(joints.axis_child, float)

    def geom(b):
        kind = bodies.shapes[b]
        if kind == "box":
            s = f'type="box" size="{_fmt(size[b] / 2)}"'
        elif kind == "sphere":
            s = f'type="sphere" size="{_fmt(size[b][:1])}"'
        else:
            s = f'type="capsule" size="{_fmt([size[b][0], size[b][1] / 2])}"'
        flags = (f'contype="1" conaffinity="0" condim="3" friction="{float(model.ground.friction):.17g} 0 0"'
                 if collide else 'contype="0" conaffinity="0"')
        return f'<geom name="{bodies.names[b]}_geom" {s} {flags}/>'

    def body_xml(b, parent, indent):
        pad = "  " * indent
        if parent < 0:
            pos, quat = x[b], q[b]
        else:
            pos = Rm[parent].T @ (x[b] - x[parent])
            quat = _quat_between(q[parent], q[b])
        lines = [f'{pad}<body name="{bodies.names[b]}" pos="{_fmt(pos)}" quat="{_fmt(quat)}">']
        Ib = I[b]
        lines.append(
            f'{pad}  <inertial pos="0 0 0" mass="{float(bodies.mass[b]):.17g}" '
            f'fullinertia="{_fmt([Ib[0, 0], Ib[1, 1], Ib[2, 2], Ib[0, 1], Ib[0, 2], Ib[1, 2]])}"/>'
        )
        j = parent_joint.get(b)
        if j is None:
            lines.append(f'{pad}  <freejoint name="{bodies.names[b]}_free"/>')
        else:
            kind = joints.types[j]
            jname = joints.names[j]
            anchor = _fmt(ac[j])
            extra = "".join(f' {k}="{v[j]:.17g}"' for k, v in springs.items())
            if kind == "ball":
                lines.append(f'{pad}  <joint name="{jname}" type="ball" pos="{anchor}"{extra}/>')
            elif kind == "hinge":
                lines.append(f'{pad}  <joint name="{jname}" type="hinge" pos="{anchor}" axis="{_fmt(ec[j])}"{extra}/>')
            elif kind == "universal":
                p = joints.parent[j]
                Rp = np.eye(3) if p < 0 else Rm[p]
                first = Rm[b].T @ (Rp @ ep[j])  # the parent-side axis in the child frame at assembly
                lines.append(f'{pad}  <joint name="{jname}_1" type="hinge" pos="{anchor}" axis="{_fmt(first)}"{extra}/>')
                lines.append(f'{pad}  <joint name="{jname}_2" type="hinge" pos="{anchor}" axis="{_fmt(ec[j])}"{extra}/>')
        lines.append(f"{pad}  {geom(b)}")
        for c in children.get(b, []):
            lines.extend(body_xml(c, b, indent + 1))
        lines.append(f"{pad}</body>")
        return lines

    g = np.asarray(bodies.gravity, float)
    out = [
        f'<mujoco model="{name}">',
        '  <compiler angle="radian" inertiafromgeom="false"/>',
        f'  <option timestep="{dt:.17g}" gravity="{_fmt(g)}" integrator="Euler"/>',
        "  <worldbody>",
    ]
    if collide:
        n = np.asarray(model.ground.normal, float)
        qz = np.asarray(rot.rotation_between(jnp.array([0.0, 0.0, 1.0]), jnp.asarray(n)))
        out.append(
            f'    <geom name="ground" type="plane" size="0 0 1" pos="{_fmt(float(model.ground.offset) * n)}" '
            f'quat="{_fmt(qz)}" contype="0" conaffinity="1" condim="3" '
            f'friction="{float(model.ground.friction):.17g} 0 0"/>'
        )
    roots = [b for b in range(bodies.num_bodies) if b not in parent_joint or joints.parent[parent_joint[b]] < 0]
    for b in roots:
        out.extend(body_xml(b, -1, 2))
    out += ["  </worldbody>", "</mujoco>", ""]
    del ap  # the parent anchor is implied by the assembly pose
    return "\n".join(out)
