r"""Feedback around a tracked trajectory: the simulator linearized frame by frame, and time-varying LQR.

:func:`linearize` differentiates one frame of the simulation (``steps_per_frame`` physics steps,
contacts included) along a :class:`~jaxanim.tracking.TrackingResult`'s trajectory ``x_f``, with the
body states in tangent coordinates (:func:`~jaxanim.tracking.state_difference`: positions,
orientation rotation vectors, velocities; 12 per body) and the control ``u`` a rotation-vector
correction of every joint's stable-PD target on top of the window's open-loop one:

``dx_{f+1} = A_f dx_f + B_f u_f``, ``dx_f = state_difference(x, x_f)``.

:func:`feedback` solves the finite-horizon LQ problem on that model with :func:`solvers.lqr`,

``min sum_f dx_f' Q dx_f + u_f' R u_f``, ``Q = diag(w_position, w_orientation, w_velocity,
w_angular_velocity)`` per body and ``R = w_control I``,

and stores the gains ``K_f`` in the result: ``u_f = clip(K_f dx_f)``. The search's open-loop
corrections reproduce the clip only from the exact states they were found from; the gains pull a
disturbed character back onto the trajectory (a push, a different start, another contact model).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

import solvers

from .. import rotations as rot
from .._errors import JaxanimError, check_shape
from .._linalg import jit
from ..character._build import Character
from ._samcon import (
    Feedback, TrackingReference, TrackingResult, _check, _problem, state_difference, state_retract,
)

__all__ = ["FeedbackOptions", "feedback", "linearize"]


class FeedbackOptions(eqx.Module):
    """The LQR weights of :func:`feedback` (arrays: sweepable with ``vmap``).

    ``w_position`` (per m^2), ``w_orientation`` (per rad^2), ``w_velocity``, ``w_angular_velocity``
    weigh every body's tangent state error; ``w_control`` (per rad^2) the feedback corrections;
    ``limit`` clips each joint's feedback correction (radians). With the defaults, the shipped walk
    (4 s, 256 samples, seed 0, within :func:`~jaxanim.tracking.joint_torque_limits`) stands a push of
    100 N for 0.2 s on the chest at mid-clip, forward or backward, which fells the open-loop
    corrections (tests/test_tracking_acceptance.py). They were chosen on that run from a grid of
    ``w_position`` 3 / 10 / 30, ``w_orientation`` 3 / 10 / 30, ``w_control`` 300 / 1000: with the
    torque bounds the earlier (100, 10, 1000) held neither push, and no weights of the grid held
    200 N or a push at 1 s.
    """

    w_position: Float[Array, ""] = eqx.field(default=3.0, converter=jnp.asarray)
    w_orientation: Float[Array, ""] = eqx.field(default=10.0, converter=jnp.asarray)
    w_velocity: Float[Array, ""] = eqx.field(default=1.0, converter=jnp.asarray)
    w_angular_velocity: Float[Array, ""] = eqx.field(default=0.1, converter=jnp.asarray)
    w_control: Float[Array, ""] = eqx.field(default=300.0, converter=jnp.asarray)
    limit: Float[Array, ""] = eqx.field(default=0.5, converter=jnp.asarray)


def _linearize(character, reference, options, corrections, traj):
    # the joint tree's depth levels in a scan (physics.make_model's scan_levels): the same values to round-off; under
    # jacfwd the same run time (the substitutions are one column per tangent) and a program that traces and compiles
    # faster (the shipped walk, 9 frames: tracing 4.6 -> 1.4 s, XLA 8.0 -> 7.0 s, 43.6 ms per frame either way)
    model = dataclasses.replace(character.model, scan_levels=True)
    problem = _problem(eqx.tree_at(lambda c: c.model, character, model), reference, options)
    frames = traj.position.shape[0]
    corrections = jnp.repeat(corrections, options.window, axis=0)  # the correction of frame f + 1, at f
    n = 12 * traj.position.shape[1]
    m = 3 * problem.num_joints
    dtype = traj.position.dtype

    def one(f):
        x0 = jax.tree.map(lambda a: a[f], traj)
        x1 = jax.tree.map(lambda a: a[f + 1], traj)
        dq = rot.rotvec_to_quat(corrections[f])

        def frame(dx, u):
            s = problem.simulate_frame(state_retract(x0, dx), f + 1,
                                       rot.quat_multiply(dq, rot.rotvec_to_quat(u.reshape(-1, 3))))[0]
            return state_difference(s, x1)

        return jax.jacfwd(frame, argnums=(0, 1))(jnp.zeros(n, dtype), jnp.zeros(m, dtype))

    return jax.lax.map(one, jnp.arange(frames - 1))


_linearize_jit = jit(_linearize)


def linearize(character: Character, reference: TrackingReference, result: TrackingResult):
    """The simulator linearized along ``result.trajectory``, frame by frame (module docstring).

    Returns:
        ``(A, B)``: ``[frames - 1, 12 bodies, 12 bodies]`` and ``[frames - 1, 12 bodies, 3 joints]``.
    """
    options, _ = _check(character, reference, result.options)
    return _linearize_jit(character, reference, options, result.corrections, result.trajectory)


@jit
def _gains(A, B, options: FeedbackOptions) -> Feedback:
    T, n, m = B.shape
    dtype = A.dtype
    w = jnp.stack([options.w_position, options.w_orientation, options.w_velocity, options.w_angular_velocity])
    qd = jnp.repeat(w.astype(dtype), 3 * (n // 12))
    Q = jnp.broadcast_to(jnp.diag(qd), (T, n, n))
    R = jnp.broadcast_to(options.w_control.astype(dtype) * jnp.eye(m, dtype=dtype), (T, m, m))
    sol = solvers.lqr(A, B, Q, R, jnp.diag(qd), jnp.zeros(n, dtype))
    return Feedback(gains=sol.Ks, limit=options.limit.astype(dtype), result=sol.result)


def _check_linearization(linearization, result: TrackingResult) -> None:
    frames, bodies = result.trajectory.position.shape[:2]
    n, m = 12 * bodies, 3 * result.corrections.shape[1]
    if not (isinstance(linearization, tuple) and len(linearization) == 2):
        raise JaxanimError(f"linearization: expected the (A, B) of linearize, got {type(linearization).__name__}")
    for name, x, cols, dims in (("A", linearization[0], n, "12 bodies"), ("B", linearization[1], m, "3 joints")):
        check_shape(f"linearization {name}", x, (frames - 1, n, cols),
                    what=f"(frames - 1, 12 bodies, {dims}) = ({frames - 1}, {n}, {cols})")


def feedback(character: Character, reference: TrackingReference, result: TrackingResult,
             options: FeedbackOptions | None = None, *, linearization=None) -> TrackingResult:
    """Time-varying LQR feedback gains around a tracked trajectory (module docstring).

    Args:
        character, reference: as given to :func:`~jaxanim.tracking.samcon`.
        result: its :class:`~jaxanim.tracking.TrackingResult`.
        options: :class:`FeedbackOptions` (default ``FeedbackOptions()``).
        linearization: ``(A, B)`` from :func:`linearize` of the same result, to reuse: the
            linearization costs far more than the gains, so a sweep over LQR weights linearizes
            once. Default: computed here.

    Returns:
        ``result`` with ``feedback`` set (:class:`~jaxanim.tracking.Feedback`);
        :func:`~jaxanim.tracking.replay` applies it.
    """
    tracking_options, _ = _check(character, reference, result.options)
    options = FeedbackOptions() if options is None else options
    if not isinstance(options, FeedbackOptions):
        raise JaxanimError(f"options: expected a FeedbackOptions, got {type(options).__name__}")
    if linearization is None:
        linearization = _linearize_jit(character, reference, tracking_options, result.corrections, result.trajectory)
    else:
        _check_linearization(linearization, result)
    law = _gains(*linearization, options)
    return eqx.tree_at(lambda r: r.feedback, result, law, is_leaf=lambda x: x is None)
