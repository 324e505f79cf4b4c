r"""One time step of the articulated bodies (:func:`step`; the method is in :mod:`jaxanim.physics._model`).

The loads and drives of a step are a :class:`~jaxanim.physics.Control`; the 0.1 keywords
(``force=``, ``torque=``, ``joint_torque=``, ``spd=(targets, kp, kd)``, ``servo=(body, x, q, ...)``)
are converted to one by :func:`~jaxanim.physics._control._as_control` at the boundary.
"""

from __future__ import annotations

from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

import solvers

from .. import rotations as rot
from .._errors import JaxanimError
from .._linalg import jit
from ._bodies import BodyState, _check_loads, _free_velocities, _integrate
from ._contact import contact_rows, penalty_loads
from ._control import Control, Servo, StablePD, _as_control
from ._joints import joint_errors, joint_rows, limit_rows
from ._model import PhysicsModel
from ._rows_solve import solve_rows
from ._tree_solve import _plan
from .._linalg import einsum

__all__ = ["spd_torques", "step"]


def _apply_joint_torques(model: PhysicsModel, torque: Array, joint_torque: Array) -> Array:
    par = np.asarray(model.joints.parent)
    chi = np.asarray(model.joints.child)
    torque = torque.at[chi].add(joint_torque)
    has = par >= 0
    if np.any(has):
        torque = torque.at[par[has]].add(-joint_torque[np.nonzero(has)[0]])
    return torque


def _joint_blocks(model: PhysicsModel, state: BodyState, h, spd: StablePD | None):
    """Each joint's rows ``(J_p, J_c, b [J, k], C [J, k])``: the 3 anchor rows, the type's angular rows
    (padded to the model's largest count with ``J = 0``, ``C = 1``) with targets ``-(erp / h) g``, and with
    ``spd`` 3 stable-PD rows on the relative angular velocity. ``J_p`` and ``J_c`` are ``(geometric
    [J, k_g, 6], drive [J, k_d, 6])``: the anchor and angular rows, then the stable-PD rows (``k_d`` 3, or 0
    without ``spd``), apart (:func:`._rows_solve.solve_rows`: the drive rows do not depend on the state).

    The stable-PD law ``tau = k_p (e - h w) - k_d w`` (``w`` the new relative angular velocity, ``e``
    the error at step ``n``) is the soft row ``w + C lambda = b`` on the impulse ``lambda = h tau``
    with ``b = k_p e / (h k_p + k_d)`` and ``C = 1 / (h (h k_p + k_d))`` (:func:`_soft_gains`).
    """
    joints = model.joints
    dtype = state.position.dtype
    Jp6, Jc6, g = joint_rows(joints, state)
    mask = joints.row_mask
    nh = int(mask.sum(axis=1).max())
    mask = jnp.asarray(mask[:, :nh])
    Jp, Jc = Jp6[:, :nh], Jc6[:, :nh]
    b = jnp.where(mask, -(model.erp / h) * g[:, :nh], 0.0)
    C = jnp.where(mask, model.cfm, 1.0)
    if spd is not None:
        e, _ = joint_errors(joints, state, rot.quat_normalize(spd.targets))
        bm, cm, active = _soft_gains(e, spd.kp[:, None], spd.kd[:, None], h)
        eye = jnp.where(active[:, :, None], jnp.eye(3, dtype=dtype)[None], 0.0)  # [J, 3, 3]
        zero = jnp.zeros_like(eye)
        b = jnp.concatenate([b, bm], axis=1)
        C = jnp.concatenate([C, jnp.where(active, cm + model.cfm, 1.0)], axis=1)
        return (Jp, jnp.concatenate([zero, -eye], axis=-1)), (Jc, jnp.concatenate([zero, eye], axis=-1)), b, C
    drive = jnp.zeros((Jp.shape[0], 0, 6), dtype)
    return (Jp, drive), (Jc, drive), b, C


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


def _servo_rows(state: BodyState, servo: Servo, h):
    """The stable-PD rows pulling one body to a world pose (the "hand of God") on the body's
    ``[v; omega]``, as the soft rows of :func:`_joint_blocks`: ``(b [6], cfm [6], active [6])``."""
    body = servo.body
    e_lin = servo.position - state.position[body]
    q_target_body = rot.quat_multiply(servo.orientation, rot.quat_conjugate(state.orientation[body]))
    e_ang = rot.quat_to_rotvec(rot.quat_canonical(q_target_body))
    e = jnp.stack([e_lin, e_ang])  # [2, 3]
    kp = jnp.stack([servo.kp_linear, servo.kp_angular])[:, None]
    kd = jnp.stack([servo.kd_linear, servo.kd_angular])[:, None]
    b, cfm, active = _soft_gains(e, kp, kd, h)
    return b.reshape(6), cfm.reshape(6), active.reshape(6)


def _inertia_and_momentum(model: PhysicsModel, state: BodyState, v, w, I_n, h, servo: Servo | None):
    """``((M_lin, M_ang) [bodies, 3, 3] each, p [bodies, 6])``: the blocks of ``M = diag(m I, I_n)`` and
    ``p = M [v*; omega*]``, with the servo's soft rows folded into its body's inertia and momentum."""
    dtype = v.dtype
    Mt = model.bodies.mass[:, None, None] * jnp.eye(3, dtype=dtype)[None]
    p = jnp.concatenate([model.bodies.mass[:, None] * v, einsum("bij,bj->bi", I_n, w)], axis=-1)
    Mr = I_n
    if servo is not None:
        bs, cs, active = _servo_rows(state, servo, h)
        k = jnp.where(active, 1.0 / (cs + model.cfm), 0.0)
        Mt = Mt.at[servo.body].add(jnp.diag(k[:3]))
        Mr = Mr.at[servo.body].add(jnp.diag(k[3:]))
        p = p.at[servo.body].add(k * bs)
    return (Mt, Mr), p


def _one_sided_rows(model: PhysicsModel, state: BodyState, h):
    """The one-sided rows: contacts (normal, t1, t2 per point) then joint limits, each on body
    ``owner_a`` (``rows_a [U, 6]``); the ``L`` limit rows (the last ones) also act on their parent
    body ``owner_b`` (``rows_b [L, 6]``; zero for a joint to the world).

    Returns:
        ``(owner_a [U], rows_a [U, 6], target [U], L, owner_b [L], rows_b [L, 6])``, or ``None``
        when there is no one-sided row.
    """
    owner_a, rows_a, target = [], [], []
    if model.ground.model == "complementarity":
        owner, rows, tc = contact_rows(model.ground, model.bodies, state, h)
        owner_a.append(owner)
        rows_a.append(rows)
        target.append(tc)
    lj, axes, phi = limit_rows(model.joints, state)
    L = lj.size
    owner_b = rows_b = None
    if L:
        zero3 = jnp.zeros_like(axes)
        par = np.asarray(model.joints.parent)[lj]
        chi = np.asarray(model.joints.child)[lj]
        owner_a.append(jnp.asarray(chi))
        rows_a.append(jnp.concatenate([zero3, axes], -1))
        owner_b = jnp.asarray(np.where(par >= 0, par, chi))
        rows_b = jnp.concatenate([zero3, jnp.where(jnp.asarray(par >= 0)[:, None], -axes, 0.0)], -1)
        target.append(jnp.where(phi > 0, -phi / h, (model.erp / h) * (-phi)))
    if not target:
        return None
    return jnp.concatenate(owner_a), jnp.concatenate(rows_a), jnp.concatenate(target), L, owner_b, rows_b


def _solve_constraints(model: PhysicsModel, state: BodyState, v, w, I_n, h, spd: StablePD | None,
                       servo: Servo | None):
    """Velocities after the joint, stable-PD, servo and (complementarity) contact impulses, and the
    stable-PD torques applied (``[joints, 3]``, world frame; ``None`` without ``spd``).

    The joints (with their stable-PD rows) are solved exactly by :func:`_tree_solve`; the servo's
    soft rows on one body are folded into that body's inertia; the one-sided rows' effect is found
    by the same solve for each row (their Delassus matrix ``A = J_u H^{-1} J_u'`` with the joints
    eliminated exactly) and projected Gauss-Seidel on ``A``. A stable PD with a ``torque_limit`` is
    then bounded by :func:`_limit_torques`.
    """
    dtype = v.dtype
    B = model.bodies.num_bodies
    Jn = model.joints.num_joints
    if Jn == 0 and servo is None and model.ground.model != "complementarity":
        return v, w, None
    M, p = _inertia_and_momentum(model, state, v, w, I_n, h, servo)
    if Jn:
        Jp, Jc, b, C = _joint_blocks(model, state, h, spd)
    else:
        Jp = Jc = (jnp.zeros((0, 1, 6), dtype), jnp.zeros((0, 0, 6), dtype))
        b, C = jnp.zeros((0, 1), dtype), jnp.ones((0, 1), dtype)
    plan = _plan(model.joints.parent, model.joints.child, B)
    one_sided = _one_sided_rows(model, state, h)
    if spd is not None and Jn and spd.torque_limit is not None:
        V, tau = _limit_torques(model, plan, one_sided, M, p, Jp, Jc, b, C, spd.torque_limit, h)
        return _split(V) + (tau,)
    V = solve_rows(model, plan, one_sided, M, p, Jp, Jc, b, C)
    if spd is None or not Jn:
        return _split(V) + (None,)
    return _split(V) + (_spd_torques(model, Jp, Jc, b, C, V, h),)


def _spd_torques(model: PhysicsModel, Jp, Jc, b, C, V, h):
    """``[joints, 3]`` the stable-PD torques (world frame, N m) that the velocities ``V`` imply:
    the impulse of each soft row ``J V + C lambda = b`` is ``lambda = (b - J V) / C`` and the
    torque ``lambda / h`` (the drive rows of :func:`_joint_blocks`, ``b`` and ``C``'s last 3)."""
    par = np.asarray(model.joints.parent)
    chi = np.asarray(model.joints.child)
    Vp = jnp.where(jnp.asarray(par >= 0)[:, None], V[np.maximum(par, 0)], 0.0)
    Jv = einsum("jkc,jc->jk", Jc[1], V[chi]) + einsum("jkc,jc->jk", Jp[1], Vp)
    return (b[:, -3:] - Jv) / (C[:, -3:] * h)


def _limit_torques(model: PhysicsModel, plan, one_sided, M, p, Jp, Jc, b, C, limit, h):
    """Bound the stable-PD torques' norms by ``limit [joints]`` (N m), an active-set correction of
    the unbounded solve: each joint whose implied torque exceeds its limit gets that torque
    scaled onto the limit as a fixed joint torque in place of its stable-PD rows, and the system is
    solved again; :data:`_LIMIT_PASSES` passes, a saturated joint staying saturated. Joints under
    their limit keep the implicit (stable) law. Returns ``(V, torques [joints, 3])``: the fixed
    torques of the saturated joints and the implicit ones of the others.

    The unbounded solve and the passes are one loop (the first iteration saturates nothing), so the
    solve (tree solve and contact rows) is compiled once for all passes (under ``vmap`` on the CPU
    once more, at the batch's width, for the unbounded solve); a pass runs only while a
    joint not yet saturated exceeds its bound (:func:`solvers.repeat_while`: under ``vmap`` the
    unbounded solve runs on the whole batch, and only the problems that need a pass go on to the
    narrow lanes of the passes, instead of every problem running every pass). A skipped pass is one
    that would change nothing."""
    par = np.asarray(model.joints.parent)
    chi = np.asarray(model.joints.child)
    has_parent = par >= 0
    limit = jnp.maximum(limit, 0.0)

    def one_pass(i, carry):
        V, tau, saturated, fixed, Jp, Jc, b, C = carry  # tau: the stable-PD torques that V implies
        norm = jnp.linalg.norm(tau, axis=-1)
        over = (i > 0) & ~saturated & (norm > limit)  # iteration 0: the unbounded solve
        scale = limit / jnp.where(over, norm, 1.0)
        fixed = jnp.where(over[:, None], tau * scale[:, None], fixed)
        saturated = saturated | over
        off = saturated[:, None]
        b = b.at[:, -3:].set(jnp.where(off, 0.0, b[:, -3:]))
        C = C.at[:, -3:].set(jnp.where(off, 1.0, C[:, -3:]))
        Jc = (Jc[0], jnp.where(off[..., None], 0.0, Jc[1]))
        Jp = (Jp[0], jnp.where(off[..., None], 0.0, Jp[1]))
        q = p.at[chi, 3:].add(h * fixed)
        if np.any(has_parent):
            q = q.at[par[has_parent], 3:].add(-h * fixed[np.nonzero(has_parent)[0]])
        V = solve_rows(model, plan, one_sided, M, q, Jp, Jc, b, C)
        return V, _spd_torques(model, Jp, Jc, b, C, V, h), saturated, fixed, Jp, Jc, b, C

    def needed(carry):  # a joint over its bound that the passes have not saturated yet
        _, tau, saturated = carry[:3]
        return jnp.any(~saturated & (jnp.linalg.norm(tau, axis=-1) > limit))

    zeros = jnp.zeros((limit.shape[0], 3), p.dtype)
    init = (jnp.zeros_like(p), zeros, jnp.zeros(limit.shape, bool), zeros, Jp, Jc, b, C)
    V, tau, saturated, fixed = solvers.repeat_while(one_pass, needed, init, times=1 + _LIMIT_PASSES,
                                                   lanes=_PASS_LANES, width=_SOLVE_WIDTH)[:4]
    tau = jnp.where(saturated[:, None], fixed, tau)
    return V, tau


_LIMIT_PASSES = 2
#: Lanes of the batched passes and the width of the unbounded solve before them (:func:`solvers.repeat_while`). On
#: the shipped walk about one sample-step in nine needs a pass, one or two solves in its lane. Measured on the 2-core
#: CPU, SAMCON per character-step at 256 / 1024 samples: 4 lanes 64.5 us at 256, 8 lanes 64-67 / 61 us, 16 lanes
#: 66-67 us at 256, 32 lanes 69 us at 256; the unbounded solve on all 1024 at once 73 us; every problem through 16
#: lanes from the unbounded solve on (no wide solve; the solve compiled at one width: 4-5 s less to compile the
#: search) 72-73 / 70 us; every pass on every sample 198 us at 1024.
_PASS_LANES = 8
_SOLVE_WIDTH = 256


def _split(V):
    return V[:, :3], V[:, 3:]


def _step(model: PhysicsModel, state: BodyState, control: Control, h) -> BodyState:
    """One step with a checked :class:`Control` (every load filled in: :func:`_as_control`)."""
    return step_and_torques(model, state, control, h)[0]


def step_and_torques(model: PhysicsModel, state: BodyState, control: Control, h):
    """:func:`_step` and the stable-PD torques it applied (``[joints, 3]`` world frame, N m, or
    ``None`` without ``control.spd``)."""
    force, torque = control.force, control.torque
    if model.joints.num_joints:
        torque = _apply_joint_torques(model, torque, control.joint_torque)
    if model.ground.model == "penalty":
        f_c, tau_c = penalty_loads(model.ground, model.bodies, state)
        force, torque = force + f_c, torque + tau_c
    v, w, I_n = _free_velocities(model.bodies, state, force, torque, h)
    v, w, tau = _solve_constraints(model, state, v, w, I_n, h, control.spd, control.servo)
    return _integrate(model.bodies, state, v, w, I_n, h), tau


def _check_state(model: PhysicsModel, state: BodyState) -> None:
    _check_loads(state, model.bodies.num_bodies, model.bodies.mass.dtype, ())


def control_for(model: PhysicsModel, control=None, **keywords) -> Control:
    """:func:`_as_control` for ``model``'s sizes and dtype."""
    return _as_control(model.bodies.num_bodies, model.joints.num_joints, model.bodies.mass.dtype, control, **keywords)


@jit
def _step_jit(model, state, control, h):
    return _step(model, state, control, h)


def step(
    model: PhysicsModel,
    state: BodyState,
    dt: Float[ArrayLike, ""],
    control: Control | Mapping | None = None,
    *,
    force: Float[ArrayLike, "bodies 3"] | None = None,
    torque: Float[ArrayLike, "bodies 3"] | None = None,
    joint_torque: Float[ArrayLike, "joints 3"] | None = None,
    spd: StablePD | tuple | None = None,
    servo: Servo | tuple | None = None,
) -> BodyState:
    """Advance the articulated bodies by one step of ``dt`` seconds (see :mod:`jaxanim.physics._model`).

    Give the inputs as a :class:`~jaxanim.physics.Control` (``step(model, state, dt, control)``)
    or as keywords (the 0.1 form); a ``dict`` with the keywords' names is accepted for ``control``.

    Args:
        model: the :class:`PhysicsModel`.
        state: the bodies' state.
        dt: the step, seconds.
        control: a :class:`~jaxanim.physics.Control` (or a ``dict`` of the keywords below).
        force: ``[bodies, 3]`` external forces at the centers of mass (world frame, N).
        torque: ``[bodies, 3]`` external torques (world frame, N m).
        joint_torque: ``[joints, 3]`` joint torques (world frame, N m): ``+tau`` on the child,
            ``-tau`` on the parent.
        spd: optional stable PD on every joint, a :class:`~jaxanim.physics.StablePD` or
            ``(targets [joints, 4], kp [joints], kd [joints])``: targets are the child's
            orientations relative to the parent (wxyz, ``q_p^{-1} q_c``), gains in N m / rad and
            N m s / rad (0 and 0: that joint is not driven). The law ``tau = k_p (e - h w) - k_d w``
            is implicit in the new relative angular velocity ``w`` and solved with the joint
            constraints (soft rows, the stable PD of Tan et al. 2011 in maximal coordinates); see
            :func:`jaxanim.physics.joint_errors` for ``e``.
        servo: optional stable PD of one body towards a world pose, the root force and torque
            ("hand of God"): a :class:`~jaxanim.physics.Servo` or ``(body (int), position [3],
            orientation [4], kp_lin, kd_lin, kp_ang, kd_ang)`` (N/m, N s/m, N m/rad, N m s/rad),
            implicit like ``spd``.

    Returns:
        The new :class:`~jaxanim.physics.BodyState`.

    Raises:
        JaxanimError: shapes do not match the model (the message names the argument and the
            expected shape), a malformed ``spd`` / ``servo``, both ``control`` and keywords, or a
            ``dt`` that is not a positive finite number.
    """
    control = control_for(model, control, force=force, torque=torque, joint_torque=joint_torque, spd=spd,
                           servo=servo)
    _check_state(model, state)
    _check_dt(dt)
    return _step_jit(model, state, control, jnp.asarray(dt, model.bodies.mass.dtype))


def _check_dt(dt) -> None:
    """``dt`` a positive finite number of seconds, when it is known here (a traced ``dt``, under ``jit``
    or ``vmap``, is the caller's to check): a negative or NaN step would run time backwards or fill the
    state with NaN without a word."""
    if isinstance(dt, jax.core.Tracer):
        return
    v = np.asarray(dt)
    if v.shape != () or not np.issubdtype(v.dtype, np.number) or not np.isfinite(v) or not v > 0:
        raise JaxanimError(f"dt: expected a positive finite number of seconds, got {dt!r}")


@jit
def _spd_torques_jit(model, state, control, h):
    return step_and_torques(model, state, control, h)[1]


def spd_torques(
    model: PhysicsModel, state: BodyState, dt: Float[ArrayLike, ""], control: Control | Mapping | None = None, **keywords
) -> Float[Array, "joints 3"]:
    """The stable-PD torques (world frame, N m, ``+tau`` on each joint's child) that
    ``step(model, state, dt, control)`` applies: the implicit law's torques, or for a joint held at
    its ``torque_limit`` the bounded torque. Zeros without ``spd``. Takes the arguments of
    :func:`step` (the same checks and errors)."""
    control = control_for(model, control, **keywords)
    _check_state(model, state)
    _check_dt(dt)
    tau = _spd_torques_jit(model, state, control, jnp.asarray(dt, model.bodies.mass.dtype))
    return jnp.zeros((model.joints.num_joints, 3), model.bodies.mass.dtype) if tau is None else tau
