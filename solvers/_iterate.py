r"""The one iteration driver behind every iterative solver of the project.

:func:`iterate` runs ``state -> step(state)`` until ``done(state)`` holds or ``max_steps`` steps
have been taken, in one of two modes that give the same iterates (also under ``jax.vmap``):

- adaptive (``fixed_steps=False``): a ``lax.while_loop`` with early exit. Under ``vmap`` the
  batch runs through a fixed number of lanes (:mod:`solvers._lanes`): a finished element's lane
  takes the next waiting element, so a batch costs its mean step count, not its maximum;
- fixed (``fixed_steps=True``): a ``lax.scan`` of exactly ``max_steps`` iterations in which a
  finished element is frozen (its step is computed and discarded), for batches: a scan has no
  per-iteration predicate and its cost is known in advance.

It also owns the **non-finite guard**: a step whose new state is not finite (by default, any
floating leaf holding a NaN or an inf; ``finite=`` replaces the test) is not taken. The element
stops there with ``nonfinite=True`` and keeps its last finite state, so a solver built on the
driver never returns NaN from finite input. The guard also looks at the initial state: a
non-finite ``init`` stops before the first step. And it collects the **stats**: the number of
steps taken and, with ``record=``, a fixed-length history of a scalar, or of a pytree of arrays
(``[max_steps + 1, ...]``, entry ``k`` after ``k`` steps, padded with the final value), as jaxls's
``cost_history``.

The loop state is an :class:`Iteration` (an ``equinox.Module``), and so is the solver's own
state: no tuples. Usage, for a solver outside ``solvers`` too (the API is private to the project,
``from solvers._iterate import iterate``)::

    class SweepState(eqx.Module):
        q: Array
        error: Array

    def sweep(s: SweepState) -> SweepState:
        ...  # one CCD sweep

    it = iterate(sweep, SweepState(q0, error0), done=lambda s: s.error <= tol,
                 max_steps=max_sweeps, fixed_steps=False, record=lambda s: s.error)
    it.state.q, it.num_steps, it.converged, it.nonfinite, it.history

Inner retry loops (a line search, a damping retry, a small QP) are ordinary ``lax.while_loop``\ s
inside ``step``; the driver is for the outer iteration, whose count is a user-facing ``max_steps``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Generic, TypeVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, PyTree

from . import _lanes

__all__ = ["Iteration", "all_finite", "iterate"]

State = TypeVar("State")


def all_finite(tree) -> Bool[Array, ""]:
    """True when every floating (or complex) array leaf of ``tree`` is finite; the default guard."""
    out = jnp.array(True)
    for leaf in jax.tree.leaves(tree):
        if eqx.is_inexact_array(leaf):
            out = out & jnp.all(jnp.isfinite(leaf))
    return out


class Iteration(eqx.Module, Generic[State]):
    """The driver's loop state, and what :func:`iterate` returns.

    Attributes:
        state: the solver's state after the last step taken (the last finite one when the guard
            stopped the loop).
        num_steps: ``int32`` steps performed, including one that the non-finite guard rejected.
        done: ``done(state)`` held, or the guard stopped the loop (``False``: ``max_steps`` ran
            out first).
        nonfinite: the guard stopped the loop: the initial state, or the state that a step
            produced, was not finite.
        history: ``[max_steps + 1]`` the recorded scalar after ``0, 1, ...`` steps, padded with
            its final value (``None`` without ``record``); a pytree of such arrays when ``record``
            returns a pytree.
    """

    state: State
    num_steps: Int[Array, ""]
    done: Bool[Array, ""]
    nonfinite: Bool[Array, ""]
    history: Float[Array, " max_steps+1"] | PyTree | None

    @property
    def converged(self) -> Bool[Array, ""]:
        """``done(state)`` held (the loop did not run out of steps and met no non-finite state)."""
        return self.done & jnp.invert(self.nonfinite)


def _select(pred, a, b):
    return jax.tree.map(lambda x, y: jnp.where(pred, x, y), a, b)


def iterate(
    step: Callable[[State], State],
    init: State,
    *,
    done: Callable[[State], Bool[Array, ""]],
    max_steps: int,
    fixed_steps: bool = False,
    finite: Callable[[State], Bool[Array, ""]] | None = all_finite,
    record: Callable[[State], Float[Array, ""] | PyTree] | None = None,
    lanes: int = _lanes.LANES,
) -> Iteration[State]:
    """Iterate ``step`` from ``init`` until ``done`` holds, at most ``max_steps`` times.

    Args:
        step: one iteration, ``state -> state`` (the same pytree structure, shapes and dtypes).
        init: the initial state (a Module or any pytree of arrays).
        done: ``state -> bool``: the element has finished (converged, or failed in a way the
            solver reports itself). Evaluated on ``init`` and after every step.
        max_steps: the most steps (static int >= 0).
        fixed_steps: run a ``lax.scan`` of exactly ``max_steps`` iterations with finished elements
            frozen, instead of a ``lax.while_loop`` (static; the same iterates).
        finite: ``state -> bool``, the non-finite guard's test (default :func:`all_finite`);
            ``None`` turns the guard off (then a solver must stop on non-finite values itself,
            through ``done``).
        record: optional ``state -> scalar`` (or a pytree of arrays) whose values form
            ``Iteration.history``.
        lanes: a batched (``jax.vmap``) call of the adaptive loop runs on this many lanes
            (:func:`solvers._lanes.while_loop`, static): a finished element's lane takes the
            next waiting one, so the batch costs its mean step count rather than its maximum,
            and the lanes' working set stays in cache. The same iterates for every element.

    Returns:
        An :class:`Iteration` ``(state, num_steps, done, nonfinite, history)``.
    """
    bad0 = jnp.array(False) if finite is None else jnp.invert(jnp.asarray(finite(init), bool))
    history = None
    if record is not None:
        history = jax.tree.map(lambda v: jnp.broadcast_to(v, (max_steps + 1, *jnp.shape(v))), record(init))
    it0 = Iteration(
        state=init,
        num_steps=jnp.zeros((), jnp.int32),
        done=jnp.asarray(done(init), bool) | bad0,
        nonfinite=bad0,
        history=history,
    )

    def body(it: Iteration) -> Iteration:
        new = step(it.state)
        k = it.num_steps + 1
        if finite is None:
            state, bad = new, jnp.array(False)
        else:
            bad = jnp.invert(jnp.asarray(finite(new), bool))
            state = _select(bad, it.state, new)
        hist = it.history
        if record is not None:
            hist = jax.tree.map(lambda h, v: h.at[k].set(v), hist, record(state))
        finished = jnp.asarray(done(state), bool) | bad
        return Iteration(state=state, num_steps=k, done=finished, nonfinite=bad, history=hist)

    if fixed_steps:

        def scan_body(it, _):
            return _select(it.done, it, body(it)), None

        it, _ = jax.lax.scan(scan_body, it0, None, length=max_steps)
    else:
        it = _lanes.while_loop(lambda it: jnp.invert(it.done) & (it.num_steps < max_steps), body, it0, lanes=lanes)
    if record is not None:
        kept = jnp.arange(max_steps + 1) <= it.num_steps

        def pad(h, final):
            return jnp.where(kept.reshape((-1,) + (1,) * jnp.ndim(final)), h, final)

        it = eqx.tree_at(lambda i: i.history, it, jax.tree.map(pad, it.history, record(it.state)))
    return it
