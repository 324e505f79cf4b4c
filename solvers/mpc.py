r"""Model-predictive control: receding-horizon iLQR / DDP with shifted warm starts.

At every control step ``k`` with measured state ``x_k`` the controller solves the horizon-``T``
problem

.. math::
    \min_{u_{k..k+T-1}} \sum_{i=0}^{T-1} \ell(x_{k+i}, u_{k+i}, k+i) + \ell_T(x_{k+T}),
    \qquad x_{k+i+1} = f(x_{k+i}, u_{k+i}, k+i),

from the previous plan shifted by one step (its first control dropped, its last repeated), applies
the first control of the new plan to the plant, and moves on. The callbacks see the **absolute**
step ``t = k + i`` (time-varying references stay aligned; JAX clamps out-of-range array indices,
so a reference array should cover ``k + T`` steps). Few solver iterations per step
(``max_steps``) suffice once the warm start is good, which is the point of the shift.

:func:`mpc_step` is one control step, a pure function of arrays usable inside a user's
``lax.scan`` and under ``jax.vmap``; :func:`mpc` runs ``steps`` of them in a ``lax.scan`` against a
plant (the model itself unless ``plant`` is given) and is ``eqx.filter_jit``-ed.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, Int, PyTree

from ._checks import _fmt
from ._results import RESULTS
from .ilqr import Dynamics, ILQROptions, StageCost, TerminalCost, TrajectorySolution, _options, ddp, ilqr

__all__ = ["MPCSolution", "mpc", "mpc_step", "shift_controls"]

_METHODS = {"ilqr": ilqr, "ddp": ddp}
_MPC_DEFAULTS = dict(max_steps=10, fixed_steps=True, rtol=None, atol=1e-12)


class MPCSolution(eqx.Module):
    """The closed-loop result of :func:`mpc`.

    Attributes:
        xs: ``[steps+1, n]`` plant states (``xs[0] = x0``).
        us: ``[steps, m]`` the controls applied.
        plan_costs: ``[steps]`` the optimal horizon cost of each solve.
        results: ``[steps]`` the :class:`~solvers.RESULTS` code of each solve (``max_steps_reached``
            is normal for MPC with few iterations per step; ``nonfinite`` / ``no_descent`` are not).
        num_steps: ``[steps]`` solver iterations of each solve.
        us_plan: ``[T, m]`` the last plan, shifted: the warm start for continuing.
        result: ``nonfinite`` if a plant state or applied control is not finite, else
            ``successful``.
    """

    xs: Float[Array, "steps+1 n"]
    us: Float[Array, "steps m"]
    plan_costs: Float[Array, " steps"]
    results: Int[Array, " steps"]
    num_steps: Int[Array, " steps"]
    us_plan: Float[Array, "T m"]
    result: RESULTS


class _Shifted(eqx.Module):
    """A stage callback seen at absolute time: ``fn(x, u, t + k, args)`` with ``(k, args)`` packed."""

    fn: Callable = eqx.field(static=True)

    def __call__(self, x, u, t, packed):
        k, args = packed
        return self.fn(x, u, t + k, args)


class _Terminal(eqx.Module):
    fn: Callable = eqx.field(static=True)

    def __call__(self, x, packed):
        return self.fn(x, packed[1])


def shift_controls(us: Float[ArrayLike, "T m"]) -> Float[Array, "T m"]:
    """The warm start for the next step: ``us[1:]`` followed by ``us[-1]``."""
    us = jnp.asarray(us)
    return jnp.concatenate([us[1:], us[-1:]], axis=0)


def _method(method: str) -> Callable:
    if method not in _METHODS:
        raise ValueError(f"method: expected one of {sorted(_METHODS)}, got {method!r}")
    return _METHODS[method]


def mpc_step(
    dynamics: Dynamics,
    cost: StageCost,
    x: Float[ArrayLike, " n"],
    us_warm: Float[ArrayLike, "T m"],
    t: Int[ArrayLike, ""] = 0,
    *,
    terminal_cost: TerminalCost | None = None,
    args: PyTree = None,
    bounds: tuple[Float[ArrayLike, " m"], Float[ArrayLike, " m"]] | None = None,
    method: str = "ilqr",
    max_steps: int = 10,
    fixed_steps: bool = True,
    rtol: float | None = None,
    atol: float = 1e-12,
    options: ILQROptions | None = None,
) -> tuple[Float[Array, " m"], Float[Array, "T m"], TrajectorySolution]:
    """One receding-horizon step at absolute time ``t`` from the measured state ``x``.

    Args:
        dynamics, cost, terminal_cost, args, bounds: as for :func:`solvers.ilqr`; the stage
            callbacks receive the absolute step ``t + i``.
        x: ``[n]`` the current state.
        us_warm: ``[T, m]`` the warm start (the previous plan shifted, :func:`shift_controls`; at
            the first step, any initial guess). ``T`` is the horizon.
        t: the absolute step index (int, may be traced).
        method: ``"ilqr"`` or ``"ddp"``.
        max_steps, fixed_steps, rtol, atol: the solver's; by default exactly ``max_steps = 10``
            iterations (a finished solve is frozen), the usual real-time setting.
        options: an :class:`~solvers.ILQROptions` instead of ``max_steps``, ``fixed_steps``,
            ``rtol`` and ``atol`` (passing both is an error).

    Returns:
        ``(u, us_next, solution)``: the control to apply ``[m]`` (the plan's first), the warm start
        for the next step ``[T, m]``, and the horizon's :class:`~solvers.TrajectorySolution` (its
        times are relative to ``t``).
    """
    solve = _method(method)
    options = _options(options, _MPC_DEFAULTS, max_steps=max_steps, fixed_steps=fixed_steps, rtol=rtol, atol=atol)
    packed = (jnp.asarray(t), args)
    term = None if terminal_cost is None else _Terminal(terminal_cost)
    sol = solve(
        _Shifted(dynamics), _Shifted(cost), x, us_warm, terminal_cost=term, args=packed, bounds=bounds,
        options=options,
    )
    return sol.us[0], shift_controls(sol.us), sol


def mpc(
    dynamics: Dynamics,
    cost: StageCost,
    x0: Float[ArrayLike, " n"],
    us_init: Float[ArrayLike, "T m"],
    *,
    steps: int,
    terminal_cost: TerminalCost | None = None,
    args: PyTree = None,
    bounds: tuple[Float[ArrayLike, " m"], Float[ArrayLike, " m"]] | None = None,
    plant: Dynamics | None = None,
    plant_args: PyTree = None,
    method: str = "ilqr",
    max_steps: int = 10,
    fixed_steps: bool = True,
    rtol: float | None = None,
    atol: float = 1e-12,
    options: ILQROptions | None = None,
) -> MPCSolution:
    """Run ``steps`` receding-horizon control steps from ``x0`` (see the module docstring).

    Args:
        dynamics, cost, terminal_cost, args, bounds: the model the controller plans with, as for
            :func:`solvers.ilqr` (stage callbacks see absolute time).
        x0: ``[n]`` the plant's initial state.
        us_init: ``[T, m]`` the first warm start; ``T`` is the horizon.
        steps: control steps to run (static int >= 1).
        plant: ``plant(x, u, t, plant_args) -> x_next`` that the controls are applied to (default:
            ``dynamics`` with ``args``), e.g. a model with other parameters or disturbances.
        plant_args: the plant's ``args`` (default: ``args``).
        method, max_steps, fixed_steps, rtol, atol, options: see :func:`mpc_step`.

    Returns:
        An :class:`MPCSolution`. Jitted; ``jax.vmap`` over ``x0`` (or ``args``) batches
        controllers.

    Raises:
        ValueError: ``x0`` / ``us_init`` have the wrong shape, ``steps`` is not a positive int, or
            ``method`` is unknown.
    """
    _method(method)
    options = _options(options, _MPC_DEFAULTS, max_steps=max_steps, fixed_steps=fixed_steps, rtol=rtol, atol=atol)
    x0 = jnp.asarray(x0)
    us_init = jnp.asarray(us_init)
    if x0.ndim != 1:
        raise ValueError(f"x0: expected shape (n,), got {_fmt(x0.shape)}")
    if us_init.ndim != 2:
        raise ValueError(f"us_init: expected shape (T, m), got {_fmt(us_init.shape)}")
    if not isinstance(steps, int) or isinstance(steps, bool) or steps < 1:
        raise ValueError(f"steps: expected an int >= 1, got {steps!r}")
    if plant is None:
        plant, plant_args = dynamics, (args if plant_args is None else plant_args)
    elif plant_args is None:
        plant_args = args
    return _mpc(dynamics, cost, terminal_cost, plant, x0, us_init, args, plant_args, bounds, steps, method, options)


@eqx.filter_jit
def _mpc(
    dynamics, cost, terminal_cost, plant, x0, us_init, args, plant_args, bounds, steps, method, options
) -> MPCSolution:
    dtype = jnp.result_type(x0.dtype, us_init.dtype, float)
    x0 = x0.astype(dtype)
    us_init = us_init.astype(dtype)

    def body(carry, k):
        x, us_warm = carry
        u, us_next, sol = mpc_step(
            dynamics, cost, x, us_warm, k, terminal_cost=terminal_cost, args=args, bounds=bounds, method=method,
            options=options,
        )
        x_next = plant(x, u, k, plant_args).astype(dtype)
        out = (x_next, u, sol.cost, sol.result._value, sol.stats["num_steps"])
        return (x_next, us_next), out

    (_, us_plan), (xs, us, costs, results, iters) = jax.lax.scan(body, (x0, us_init), jnp.arange(steps))
    xs = jnp.concatenate([x0[None], xs])
    finite = jnp.all(jnp.isfinite(xs)) & jnp.all(jnp.isfinite(us))
    result = RESULTS.where(finite, RESULTS.successful, RESULTS.nonfinite)
    return MPCSolution(xs=xs, us=us, plan_costs=costs, results=results, num_steps=iters, us_plan=us_plan,
                       result=result)
