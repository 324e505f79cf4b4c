r"""Typed inputs of a physics step: :class:`Control`, with its :class:`StablePD` and :class:`Servo`.

A :class:`Control` is what controllers return and what :func:`jaxanim.physics.step` accepts:

- ``force`` ``[bodies, 3]``, ``torque`` ``[bodies, 3]``: external loads at the centers of mass
  (world frame, N and N m);
- ``joint_torque`` ``[joints, 3]``: ``+tau`` on each joint's child, ``-tau`` on its parent (world
  frame, N m);
- ``spd``: stable PD on every joint (:class:`StablePD`), implicit in the constraint solve;
- ``servo``: stable PD of one body towards a world pose (:class:`Servo`, the "hand of God").

Every field may be left out (``None``). The 0.1 forms, ``step(..., spd=(targets, kp, kd),
servo=(body, x, q, kp_l, kd_l, kp_a, kd_a))`` and controllers returning ``dict(...)`` with those
keys, are converted here, in :func:`_as_control`, the one place at the boundary; only a checked
:class:`Control` with every load filled in flows inside the step.
"""

from __future__ import annotations

from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .. import rotations as rot
from .._errors import JaxanimError, check_positive, check_shape

__all__ = ["Control", "Servo", "StablePD"]


def optional_array(x):
    """``None`` or ``jnp.asarray(x)``: the converter of optional array fields (internal interface: also
    used by :mod:`jaxanim.tracking`)."""
    return None if x is None else jnp.asarray(x)


class StablePD(eqx.Module):
    """Stable PD on every joint (Tan et al. 2011, implicit in the step's constraint solve).

    Attributes:
        targets: ``[joints, 4]`` each joint's target: the child's orientation relative to its
            parent (wxyz, ``q_p^{-1} q_c``; normalized by the step).
        kp: ``[joints]`` (or a scalar) stiffness, N m / rad.
        kd: ``[joints]`` (or a scalar) damping, N m s / rad (``kp = kd = 0``: that joint is not driven).
        torque_limit: optional ``[joints]`` (or a scalar) bound on the norm of each joint's
            stable-PD torque, N m (``inf``: unbounded). A joint whose implicit torque would exceed
            it gets that torque scaled onto the bound instead, applied explicitly (active-set
            passes: the step solves the constraints again, up to twice). ``None``: no bound, one solve.
    """

    targets: Float[Array, "joints 4"] = eqx.field(converter=jnp.asarray)
    kp: Float[Array, "#joints"] = eqx.field(converter=jnp.asarray)
    kd: Float[Array, "#joints"] = eqx.field(converter=jnp.asarray)
    torque_limit: Float[Array, "#joints"] | None = eqx.field(default=None, converter=optional_array)


class Servo(eqx.Module):
    """Stable PD of one body towards a world pose: the root force and torque ("hand of God").

    Attributes:
        body: the body's index (a static int).
        position: ``[3]`` the target position of its center of mass (world frame, m).
        orientation: ``[4]`` its target orientation (wxyz, normalized by the step).
        kp_linear, kd_linear: N/m and N s/m.
        kp_angular, kd_angular: N m / rad and N m s / rad.
    """

    body: int = eqx.field(static=True)
    position: Float[Array, " 3"] = eqx.field(converter=jnp.asarray)
    orientation: Float[Array, " 4"] = eqx.field(converter=jnp.asarray)
    kp_linear: Float[Array, ""] = eqx.field(converter=jnp.asarray)
    kd_linear: Float[Array, ""] = eqx.field(converter=jnp.asarray)
    kp_angular: Float[Array, ""] = eqx.field(converter=jnp.asarray)
    kd_angular: Float[Array, ""] = eqx.field(converter=jnp.asarray)


class Control(eqx.Module):
    """The inputs of one step (see the module docstring); every field may be ``None``.

    ``control["joint_torque"]`` reads a field as the 0.1 controllers' ``dict`` did (``spd`` and
    ``servo`` come back as :class:`StablePD` and :class:`Servo`).
    """

    force: Float[Array, "bodies 3"] | None = eqx.field(default=None, converter=optional_array)
    torque: Float[Array, "bodies 3"] | None = eqx.field(default=None, converter=optional_array)
    joint_torque: Float[Array, "joints 3"] | None = eqx.field(default=None, converter=optional_array)
    spd: StablePD | None = None
    servo: Servo | None = None

    def __getitem__(self, key: str):
        if key not in _KEYS:
            raise KeyError(key)
        return getattr(self, key)


_KEYS = ("force", "torque", "joint_torque", "spd", "servo")
_SPD_FORM = ("spd: expected StablePD(targets [J, 4], kp [J], kd [J][, torque_limit [J]]) or the tuple "
             "(targets, kp, kd[, torque_limit])")
_SERVO_FORM = ("servo: expected Servo(body, position [3], orientation [4], kp_linear, kd_linear, kp_angular, "
               "kd_angular) or the tuple (body, position [3], orientation [4], kp_lin, kd_lin, kp_ang, kd_ang)")


def _as_spd(spd, num_joints: int, dtype) -> StablePD:
    if not isinstance(spd, StablePD):
        if not (isinstance(spd, (tuple, list)) and len(spd) in (3, 4)):
            raise JaxanimError(_SPD_FORM)
        spd = StablePD(*spd)
    # a negative gain pushes a joint away from its target (checked when concrete, as torque_limit)
    check_positive("spd kp", spd.kp, zero=True, units="N m / rad")
    check_positive("spd kd", spd.kd, zero=True, units="N m s / rad")
    targets, kp, kd = (jnp.asarray(a, dtype) for a in (spd.targets, spd.kp, spd.kd))
    check_shape("spd targets", targets, (num_joints, 4), what=f"(J, 4) = ({num_joints}, 4)")
    gains = [_per_joint(f"spd {name}", g, num_joints) for name, g in (("kp", kp), ("kd", kd))]
    limit = spd.torque_limit
    if limit is not None:
        # checked in numpy: a concrete limit closed over by a jitted function is not a tracer, but
        # jnp ops on it inside the trace would be (and bool() of them an error)
        if not isinstance(limit, jax.core.Tracer) and np.any(np.isnan(host := np.asarray(limit)) | (host < 0)):
            raise JaxanimError(f"spd torque_limit: expected non-negative N m (inf for no bound), got {host}")
        limit = _per_joint("spd torque_limit", jnp.asarray(limit, dtype), num_joints)
    return StablePD(targets, *gains, limit)


def _per_joint(name: str, value: Array, num_joints: int) -> Array:
    """``value`` (a scalar or ``[joints]``) broadcast to ``[joints]``, or a clear error."""
    if value.ndim > 1 or (value.ndim == 1 and value.shape[0] not in (1, num_joints)):
        raise JaxanimError(f"{name}: expected a scalar or shape ({num_joints},) (one per joint), got shape "
                           f"{tuple(value.shape)}")
    return jnp.broadcast_to(value, (num_joints,))


def _as_servo(servo, num_bodies: int, dtype) -> Servo:
    if not isinstance(servo, Servo):
        if not (isinstance(servo, (tuple, list)) and len(servo) == 7):
            raise JaxanimError(_SERVO_FORM)
        body = servo[0]
        if not isinstance(body, (int, np.integer)) or isinstance(body, bool) or not 0 <= body < num_bodies:
            raise JaxanimError(f"servo: body must be an int in [0, {num_bodies}), got {body!r}")
        servo = Servo(int(body), *servo[1:])
    elif not 0 <= servo.body < num_bodies:
        raise JaxanimError(f"servo: body must be an int in [0, {num_bodies}), got {servo.body!r}")
    position = jnp.asarray(servo.position, dtype)
    orientation = rot.quat_normalize(jnp.asarray(servo.orientation, dtype))
    check_shape("servo position", position, (3,))
    check_shape("servo orientation", orientation, (4,))
    for name, g in (("kp_linear", servo.kp_linear), ("kd_linear", servo.kd_linear), ("kp_angular", servo.kp_angular),
                    ("kd_angular", servo.kd_angular)):
        check_positive(f"servo {name}", g, zero=True)
    gains = (jnp.asarray(g, dtype) for g in (servo.kp_linear, servo.kd_linear, servo.kp_angular, servo.kd_angular))
    return Servo(int(servo.body), position, orientation, *gains)


def _load(name: str, value, rows: int, dim: str, dtype) -> Array:
    if value is None:
        return jnp.zeros((rows, 3), dtype)
    arr = jnp.asarray(value, dtype)
    check_shape(name, arr, (rows, 3), what=f"({dim}, 3) = ({rows}, 3)")
    return arr


def _as_control(
    num_bodies: int, num_joints: int, dtype, control: Control | Mapping | None = None, **keywords: ArrayLike | None
) -> Control:
    """The one conversion at the boundary: a :class:`Control`, a 0.1 ``dict`` (keys ``force``,
    ``torque``, ``joint_torque``, ``spd``, ``servo``; tuples for ``spd`` / ``servo``), ``None``, or
    those keywords -> a checked :class:`Control` in ``dtype`` with every load filled in (zeros),
    ``kp`` / ``kd`` broadcast to ``[joints]`` and the servo's orientation normalized.

    Raises:
        JaxanimError: an unknown key, a malformed ``spd`` / ``servo``, a shape that does not
            match the model (the message names the argument and the expected shape), or both a
            ``control`` and keywords.
    """
    given = {k: v for k, v in keywords.items() if v is not None}
    if control is not None and given:
        raise JaxanimError(f"control: give a Control or the keywords {tuple(given)}, not both")
    if control is None:
        control = given
    if isinstance(control, Mapping):
        unknown = sorted(set(control) - set(_KEYS))
        if unknown:
            raise JaxanimError(f"control: unknown key(s) {unknown}; the valid keys are {_KEYS}")
        fields = dict(control)
    elif isinstance(control, Control):
        fields = {k: getattr(control, k) for k in _KEYS}
    else:
        raise JaxanimError(f"control: expected a Control, a dict with keys {_KEYS} or None, got "
                           f"{type(control).__name__}")
    spd, servo = fields.get("spd"), fields.get("servo")
    return Control(
        force=_load("force", fields.get("force"), num_bodies, "B", dtype),
        torque=_load("torque", fields.get("torque"), num_bodies, "B", dtype),
        joint_torque=_load("joint_torque", fields.get("joint_torque"), num_joints, "J", dtype),
        spd=None if spd is None else _as_spd(spd, num_joints, dtype),
        servo=None if servo is None else _as_servo(servo, num_bodies, dtype),
    )
