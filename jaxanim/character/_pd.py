r"""PD and stable-PD control (course notes §1.O, eqs. 7.2-7.6; Tan, Liu & Turk 2011).

**Point forms** (one body or one degree of freedom of mass ``m``, step ``h``):

- :func:`pd_force`: ``f = k_p (xbar - x) + k_d (vbar - v)`` (eq. 7.2), applied explicitly. With
  semi-implicit Euler the spring ``m = 1, k_p = 200, k_d = 20`` is stable only for
  ``h < 0.0732 s``.
- :func:`stable_pd_force`, ``form="damping"`` (the notes' eq. 7.5-7.6): the damping is implicit,
  ``v_{n+1} = v_n + h (k_p (xbar - x_n) - k_d v_{n+1}) / m``, i.e. ``f = (k_p (xbar - x) -
  k_d v) / (1 + h k_d / m)``: stable for ``h < 0.273 s`` on the same spring.
- ``form="full"`` (Tan et al.): position and damping implicit, ``f = k_p (xbar - x - h v_{n+1}) -
  k_d v_{n+1}`` solved for ``v_{n+1}``: unconditionally stable for the spring.

**Joints** (articulated bodies): the error of joint ``j`` is the rotation vector ``e`` that takes the
child's current orientation relative to its parent, ``q_p^{-1} q_c``, to the target ``qbar``
(expressed in the world frame), and its rate the relative angular velocity ``omega_c - omega_p``.
:func:`pd_joint_torques` gives ``tau = k_p e - k_d (omega_c - omega_p)`` (optionally clipped to a
maximum norm), applied as ``+tau`` on the child and ``-tau`` on the parent by
:func:`jaxanim.physics.step`. Stable PD for joints is the same law made implicit inside the
step's constraint solve: see ``spd`` of :func:`jaxanim.physics.step`.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .. import rotations as rot
from .._errors import JaxanimError, check_positive
from ..physics._joints import Joints, joint_errors
from ..physics._bodies import BodyState

__all__ = ["joint_errors", "pd_force", "pd_joint_torques", "stable_pd_force"]


def _check_gains(kp, kd) -> None:
    """Gains ``>= 0`` when concrete: a negative one drives away from the target without a word."""
    check_positive("kp", kp, zero=True)
    check_positive("kd", kd, zero=True)


def pd_force(
    x: Float[ArrayLike, "*batch"], v: Float[ArrayLike, "*batch"], target: Float[ArrayLike, "*batch"],
    kp: Float[ArrayLike, "*batch"], kd: Float[ArrayLike, "*batch"], target_velocity: Float[ArrayLike, "*batch"] = 0.0,
) -> Float[Array, "*batch"]:
    """Explicit PD: ``k_p (target - x) + k_d (target_velocity - v)`` (broadcasts).

    Raises:
        JaxanimError: a concrete negative or non-finite ``kp`` or ``kd`` (traced gains pass unchecked).
    """
    _check_gains(kp, kd)
    x, v, target, kp, kd, tv = (jnp.asarray(a) for a in (x, v, target, kp, kd, target_velocity))
    return kp * (target - x) + kd * (tv - v)


def stable_pd_force(
    x: Float[ArrayLike, "*batch"], v: Float[ArrayLike, "*batch"], target: Float[ArrayLike, "*batch"],
    kp: Float[ArrayLike, "*batch"], kd: Float[ArrayLike, "*batch"], mass: Float[ArrayLike, "*batch"],
    dt: Float[ArrayLike, ""], *, form: str = "damping",
) -> Float[Array, "*batch"]:
    """The force of stable PD for a step ``dt`` of semi-implicit Euler (see the module docstring).

    Args:
        x, v: position and velocity (any units, broadcasting).
        target: the target position (target velocity 0).
        kp, kd: gains; mass: the (effective) mass the force acts on.
        dt: the step.
        form: ``"damping"`` (the notes' eq. 7.5: implicit damping) or ``"full"`` (Tan et al.
            2011: implicit position and damping).

    Raises:
        JaxanimError: an unknown ``form``, or a concrete negative or non-finite ``kp`` or ``kd``.
    """
    _check_gains(kp, kd)
    x, v, target, kp, kd, m, h = (jnp.asarray(a) for a in (x, v, target, kp, kd, mass, dt))
    if form == "damping":
        return (kp * (target - x) - kd * v) / (1 + h * kd / m)
    if form == "full":
        c = kp * h + kd
        return (kp * (target - x) - c * v) / (1 + h * c / m)
    raise JaxanimError(f"form: expected 'damping' or 'full', got {form!r}")


def pd_joint_torques(
    joints: Joints,
    state: BodyState,
    targets: Float[ArrayLike, "J 4"],
    kp: Float[ArrayLike, " J"],
    kd: Float[ArrayLike, " J"],
    *,
    max_torque: Float[ArrayLike, " J"] | None = None,
) -> Float[Array, "J 3"]:
    """Explicit PD joint torques ``k_p e - k_d (omega_c - omega_p)`` (world frame, N m), clipped to
    norm ``max_torque`` per joint if given (see :func:`joint_errors`).

    Raises:
        JaxanimError: a concrete negative or non-finite ``kp`` or ``kd`` (traced gains pass unchecked).
    """
    _check_gains(kp, kd)
    targets = rot.quat_normalize(jnp.asarray(targets, state.position.dtype))
    e, w = joint_errors(joints, state, targets)
    tau = jnp.asarray(kp)[:, None] * e - jnp.asarray(kd)[:, None] * w
    if max_torque is not None:
        lim = jnp.asarray(max_torque, tau.dtype)
        norm = jnp.linalg.norm(tau, axis=-1)
        tau = tau * jnp.minimum(1.0, lim / jnp.maximum(norm, jnp.finfo(tau.dtype).tiny))[:, None]
    return tau
