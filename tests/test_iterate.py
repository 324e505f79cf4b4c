"""Tests of solvers._iterate, the one iteration driver: fixed scan equals adaptive while loop (also
under vmap, with finished elements frozen), the non-finite guard keeps the last finite state, and
the step count and history follow their documented definitions."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jaxtyping import Array

from solvers._iterate import iterate


class _Newton(eqx.Module):
    """Newton's iteration for sqrt(a): the state of a tiny solver."""

    a: Array
    y: Array


def _step(s: _Newton) -> _Newton:
    return _Newton(a=s.a, y=0.5 * (s.y + s.a / s.y))


def _done(s: _Newton):
    return jnp.abs(s.y * s.y - s.a) <= 1e-12 * s.a


def _run(a, fixed: bool, max_steps: int = 30):
    it = iterate(
        _step, _Newton(a=a, y=jnp.ones_like(a)), done=_done, max_steps=max_steps, fixed_steps=fixed,
        record=lambda s: s.y,
    )
    return it.state.y, it.num_steps, it.done, it.nonfinite, it.history


_RUN = {fixed: jax.jit(jax.vmap(lambda a, fixed=fixed: _run(a, fixed))) for fixed in (False, True)}


def test_fixed_scan_equals_while_loop_under_vmap():
    a = jnp.asarray([2.0, 1e6, 1.0, 0.25])
    adaptive = _RUN[False](a)
    fixed = _RUN[True](a)
    for name, x, y in zip(("y", "num_steps", "done", "nonfinite", "history"), adaptive, fixed):
        np.testing.assert_array_equal(x, y, err_msg=name)
    y, num_steps, done, nonfinite, history = adaptive
    np.testing.assert_allclose(y, np.sqrt(a), rtol=1e-12)
    assert np.all(done) and not np.any(nonfinite)
    assert int(num_steps[2]) == 0, "a = 1 is solved by the initial state"
    assert int(num_steps[1]) > int(num_steps[0]), "elements finish at their own step"
    # history: entry k after k steps, padded with the final value
    h = np.asarray(history)
    k = int(num_steps[1])
    assert h[1, 0] == 1.0 and h[1, 1] == 0.5 * (1 + 1e6)
    np.testing.assert_array_equal(h[1, k:], np.full(h.shape[1] - k, y[1]))


@pytest.mark.parametrize("fixed", [False, True])
def test_guard_keeps_the_last_finite_state(fixed):
    # y -> 1e100 y overflows to inf at step 4: the loop stops there and keeps the last finite y, 1e300.
    def run(y0):
        return iterate(lambda y: 1e100 * y, y0, done=lambda y: jnp.array(False), max_steps=10, fixed_steps=fixed)

    it = jax.jit(run)(jnp.asarray(1.0))
    assert bool(it.nonfinite) and bool(it.done) and not bool(it.converged)
    assert float(it.state) == 1e300, "the last finite state"
    assert int(it.num_steps) == 4, "the rejected step counts"
    bad = jax.jit(run)(jnp.asarray(jnp.nan))
    assert bool(bad.nonfinite) and int(bad.num_steps) == 0, "a non-finite initial state stops at once"


def test_max_steps_and_guard_off():
    it = jax.jit(
        lambda y0: iterate(lambda y: 1e100 * y, y0, done=lambda y: jnp.array(False), max_steps=5, finite=None)
    )(jnp.asarray(1.0))
    assert not bool(it.done) and not bool(it.nonfinite), "ran out of steps"
    assert int(it.num_steps) == 5 and np.isinf(float(it.state)), "no guard: the inf is kept"
