"""Rollouts: :func:`rollout` runs :func:`~jaxanim.physics.step` in a ``lax.scan`` with an optional
controller, and stops a character that blows up (:class:`SimResult`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

import solvers

from .._errors import JaxanimError
from .._linalg import jit
from ._bodies import BodyState
from ._model import PhysicsModel
from ._step import _check_dt, _check_state, control_for, _step

__all__ = ["Rollout", "SimResult", "rollout"]


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


#: Characters per chunk of a batched rollout (:func:`solvers.lane_map`): under ``vmap`` with a larger batch the
#: rollout runs ``lax.map`` over chunks of this many, whose working set (the tree solve's ``[chunk, bodies, 6, 25]``
#: blocks with the contact rows) stays in cache, where the whole batch's streams from memory. Measured on the 2-core
#: CPU, standing character, 1024 characters, us per character-step: complementarity on 8 points 95 unchunked,
#: 72 / 69 / 68 / 75 in chunks of 128 / 64 / 32 / 16; penalty 27 unchunked, 21.5 / 21.0 in chunks of 256 / 64.
ROLLOUT_LANES = 64


@jit
def _rollout(model, state, h, num_steps, record_every, controller, controller_args, max_speed, max_angular_speed):
    def run(state, h, controller_args, max_speed, max_angular_speed):
        def inner(carry, _):
            s, code, count = carry
            u = None if controller is None else controller(s, count, controller_args)
            new = _step(model, s, control_for(model, u), h)
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

    return solvers.lane_map(run, state, h, controller_args, max_speed, max_angular_speed, lanes=ROLLOUT_LANES)


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
        controller: ``controller(state, step, controller_args) -> Control`` (a
            :class:`~jaxanim.physics.Control`, or the 0.1 ``dict`` with any of the keys ``force``,
            ``torque``, ``joint_torque``, ``spd``, ``servo`` of :func:`step`; default: passive;
            ``servo``'s body index must be a Python int). ``step`` is the step index (int array).
            A module-level function or an ``eqx.Module`` with ``__call__`` keeps the compiled
            rollout across calls (its arrays are traced); a fresh closure per call recompiles.
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
    _check_state(model, state)
    _check_dt(dt)
    dtype = model.bodies.mass.dtype
    return _rollout(model, state, jnp.asarray(dt, dtype), int(num_steps), int(record_every), controller,
                    controller_args, jnp.asarray(max_speed, dtype), jnp.asarray(max_angular_speed, dtype))


