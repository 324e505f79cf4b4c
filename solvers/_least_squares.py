r"""Nonlinear least squares: Gauss-Newton, Levenberg-Marquardt, gradient descent; optimistix/jaxopt adapters.

Every solver minimizes

.. math::  F(y) = \tfrac12 \lVert r(y) \rVert^2, \qquad r: \mathbb{R}^n \to \mathbb{R}^m,
           \quad \text{optionally subject to } \ell \le y \le u,

from ``y0`` and returns the same :class:`~solvers.Solution` ``(value, result, stats)``. Around the
iterate ``y`` with residual ``r`` and Jacobian ``J`` (``[m, n]``) the model is
``F(y + s) ~ F(y) + g^T s + 0.5 s^T J^T J s`` with gradient ``g = J^T r``; the step solves

.. math::  (J^T J + \lambda D)\, p = -J^T r,

with ``lambda = 0`` for Gauss-Newton and an adaptive ``lambda > 0`` for Levenberg-Marquardt
(``D = I``, a per-variable weight matrix ``W``, or Marquardt's ``D = diag(J^T J)``). When the
Jacobian is short and fat (``m < n``) the same step is computed in residual space,
``p = -D^{-1} J^T (J D^{-1} J^T + lambda I)^{-1} r`` (the course notes' eq. 4.8, generalized to a
diagonal ``D`` by the push-through identity): an ``m x m`` Cholesky factorization instead of
``n x n``. For Gauss-Newton that is the minimum-norm step. The choice is made statically from the
shapes. :class:`GradientDescent` (the course notes' Jacobian-transpose method, a slow baseline)
steps along ``-g`` instead, by Buss's step length ``|g|^2 / |J g|^2``: the minimizer of the same
model along ``-g`` (the Cauchy step); no linear system is solved.

Bounds are handled by projection with an active set (projected Newton, Bertsekas 1982): a
variable at a bound whose gradient pushes outwards is frozen for the step (its row and column of
the normal equations are replaced by the identity and its step is zero), and every trial point is
clipped into the box, so every iterate satisfies the bounds exactly.

One driver, :func:`solvers._iterate.iterate`, owns ``max_steps``, the non-finite check and the
statistics; it runs either a ``lax.while_loop`` with early exit (adaptive mode) or a ``lax.scan``
of exactly ``max_steps`` iterations in which finished problems are frozen (``fixed_steps=True``,
for batches: under ``jax.vmap`` a while loop runs until its slowest element anyway, and a scan has
no per-iteration predicate). Both modes give the same iterates. The module layout: the problem
(``_ls_problem``), the shared model, state and run (``_ls_base``), one file per solver
(``_gauss_newton``, ``_levenberg_marquardt``, ``_gradient_descent``), the backends
(``_adapters``) and this entry point.

Convergence (checked after every iteration, on the step ``s`` that would be taken next, its
predicted decrease ``pred = -(g^T s + 0.5 |J s|^2)`` and the projected gradient)::

    (all |s_i| <= atol + rtol |y_i|  and  pred <= atol + rtol * cost  and  lambda <= tr(J D^-1 J^T))
    or   |g_free|_inf <= atol

with ``rtol`` floored at ``4 eps`` of the dtype so that float32 can meet the default tolerances.
Because the test looks at the *next* step, the returned value is about one step, ``~rtol |y|``,
from the minimum (a test on the last step taken, as in optimistix, costs one more iteration). The
damping condition stops a step that is short only because ``lambda`` is huge (after many rejected
trials) from passing as convergence. For :class:`GradientDescent` ``s`` is the (projected)
gradient step and there is no damping condition; its docstring says what that implies for the
accuracy. When no acceptable step exists (the line search of Gauss-Newton or gradient descent
fails, or Levenberg-Marquardt rejects a step at the largest ``lambda``) the solve stops: as
``successful`` if the model predicts no decrease above the tolerance (converged to working
precision, the usual end in float32), ``nonfinite`` if the last trial point was not finite, and
``singular`` otherwise. Cost decreases are computed as ``0.5 (r_new - r).(r_new + r)``, free of
the cancellation in ``F_new - F``, so nonzero-residual problems converge to full precision.
The solvers are pure functions of their inputs: ``least_squares`` is ``eqx.filter_jit``-ed and can
be ``jax.vmap``-ed over ``y0``, ``args``, ``bounds`` and the solvers' array fields.
"""


from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, PyTree

from ._adapters import JaxoptSolver, OptimistixSolver, _AbstractAdapter
from ._checks import _fmt
from ._gauss_newton import GaussNewton
from ._gradient_descent import GradientDescent
from ._levenberg_marquardt import LevenbergMarquardt
from ._ls_base import AbstractLeastSquaresSolver, _run
from ._ls_problem import JacobianFn, ResidualFn, _Problem
from ._implicit import attach_minimizer, stop_gradient_arrays
from ._results import RESULTS, Solution

__all__ = [
    "AbstractLeastSquaresSolver",
    "GaussNewton",
    "GradientDescent",
    "JaxoptSolver",
    "LevenbergMarquardt",
    "OptimistixSolver",
    "least_squares",
]


def least_squares(
    fn: ResidualFn,
    solver: AbstractLeastSquaresSolver | OptimistixSolver | JaxoptSolver,
    y0: Float[ArrayLike, " n"],
    args: PyTree = None,
    *,
    jac: JacobianFn | bool | None = None,
    bounds: tuple[Float[ArrayLike, " n"], Float[ArrayLike, " n"]] | None = None,
    stop: Callable[[Array, Array, PyTree], Bool[ArrayLike, ""]] | None = None,
    throw: bool = False,
) -> Solution:
    r"""Minimize ``0.5 * |fn(y, args)|^2`` over ``y`` (optionally in a box) from ``y0``.

    Solves one problem; batch with ``jax.vmap`` over ``y0``, ``args``, ``bounds`` or the solver's
    array fields (``fn`` and ``jac`` are closed-over callables). With ``throw=False`` (the default)
    every element keeps its own ``result`` and one failing element never aborts a batch; check
    ``sol.result == RESULTS.successful``. The solve is compiled once per ``fn``/``jac`` object,
    shapes and static solver settings: pass the same function objects (not fresh lambdas) to reuse
    it; array data belong in ``args``.

    Args:
        fn: the residual function ``fn(y, args) -> r``, ``y`` of shape ``[n]``, ``r`` of shape ``[m]``
            (with ``jac=True``: ``fn(y, args) -> (r, J)``).
        solver: :class:`GaussNewton`, :class:`LevenbergMarquardt`, :class:`GradientDescent`,
            :class:`OptimistixSolver` or :class:`JaxoptSolver`.
        y0: ``[n]`` the initial guess (integer input is converted to the default float dtype;
            the solve runs in ``y0``'s dtype). It is clipped into the box first.
        args: any pytree passed through to ``fn`` and ``jac``.
        jac: optional ``jac(y, args) -> J``, ``[m, n]``, ``J_ij = d r_i / d y_j``. Default:
            ``jax.jacfwd`` of ``fn`` when ``m >= n``, ``jax.jacrev`` otherwise. The backends get it
            through a ``jax.custom_jvp`` on ``fn``. ``jac=True`` (scipy's convention): ``fn``
            returns the residual and its Jacobian together, and each linearization calls it once.
        bounds: optional ``(lower, upper)``, each ``[n]`` (or a scalar), ``-inf``/``inf`` for free
            variables; own solvers only. Every iterate satisfies ``lower <= y <= upper`` exactly.
        stop: optional early-stop criterion ``stop(y, r, args) -> bool`` on an iterate and its
            residual (no extra evaluation of ``fn``), checked at ``y0`` and after every step; when
            it holds the solve ends there with ``RESULTS.successful`` (e.g. IK: every target within
            its tolerance, as in closed-loop IK). Every solver takes it: the adapters drive their
            backend's own iterations and check it on each accepted iterate (see
            :class:`OptimistixSolver` and :class:`JaxoptSolver` for what that costs).
        throw: if true, raise (through ``RESULTS.error_if``, an ``equinox.EquinoxRuntimeError``
            whose message is the result's advice) unless the solve succeeds. Under ``vmap`` one
            failing element raises for the whole batch.

    Returns:
        A :class:`Solution` ``(value [n], result, stats)``; see :class:`~solvers.Solution` for the
        statistics. ``value`` is never NaN when ``y0`` is finite: on ``RESULTS.nonfinite`` it is
        the last finite iterate. ``value`` carries the implicit derivative of the minimizer with
        respect to ``args`` (``jax.grad`` and ``jax.jvp`` through the solve; the loop itself is not
        differentiated). Where the solve did not reach a minimizer, that derivative is NaN: a result
        other than ``successful``, or ``stop`` ending it before the solver's own criterion held
        (``stats["stopped_early"]``).

    Raises:
        ValueError: ``y0`` is not 1-D, ``bounds`` do not match ``y0`` or ``lower > upper``,
            ``fn`` does not return a 1-D array, ``jac`` does not return ``[m, n]``, or bounds were
            given to a backend adapter. Raised in Python, before anything is computed.
        equinox.EquinoxRuntimeError: ``throw=True`` and the solve failed.
    """
    if not isinstance(solver, (AbstractLeastSquaresSolver, _AbstractAdapter)):
        raise ValueError(
            "solver: expected GaussNewton, LevenbergMarquardt, GradientDescent, OptimistixSolver or JaxoptSolver, "
            f"got {type(solver).__name__}"
        )
    y0 = jnp.asarray(y0)
    if jnp.issubdtype(y0.dtype, jnp.complexfloating):
        raise ValueError(f"y0: expected a real array, got dtype {y0.dtype}")
    if not jnp.issubdtype(y0.dtype, jnp.floating):
        y0 = y0.astype(jnp.result_type(float))
    if y0.ndim != 1 or y0.shape[0] == 0:
        raise ValueError(f"y0: expected shape (n,) with n >= 1, got {_fmt(y0.shape)}")
    n = y0.shape[0]
    weights = getattr(solver, "weights", None)
    if weights is not None and weights.shape != (n,):
        raise ValueError(f"weights: expected shape (n,) = ({n},) like y0, got {_fmt(weights.shape)}")
    lower = upper = None
    if bounds is not None:
        if isinstance(solver, _AbstractAdapter):
            raise ValueError(
                f"bounds: not supported by {type(solver).__name__}; use GaussNewton, LevenbergMarquardt or "
                "GradientDescent"
            )
        if not (isinstance(bounds, (tuple, list)) and len(bounds) == 2):
            raise ValueError(
                f"bounds: expected a pair (lower, upper) of shape (n,) = ({n},), got {type(bounds).__name__}"
            )
        lower, upper = (jnp.asarray(b, y0.dtype) for b in bounds)
        for name, b in (("lower", lower), ("upper", upper)):
            if b.shape not in ((), (n,)):
                raise ValueError(f"bounds: expected {name} of shape (n,) = ({n},), got {_fmt(b.shape)}")
        lower = jnp.broadcast_to(lower, (n,))
        upper = jnp.broadcast_to(upper, (n,))
        if not isinstance(lower, jax.core.Tracer) and not isinstance(upper, jax.core.Tracer):
            if np.any(np.asarray(lower) > np.asarray(upper)):
                raise ValueError("bounds: expected lower <= upper for every variable")
    return _least_squares(fn, jac, solver, y0, args, lower, upper, stop, throw)


@eqx.filter_jit
def _least_squares(fn, jac, solver, y0, args, lower, upper, stop, throw) -> Solution:
    n = y0.shape[0]
    out = eqx.filter_eval_shape(fn, y0, args)
    if jac is True:
        if not (isinstance(out, tuple) and len(out) == 2):
            raise ValueError(f"fn: with jac=True, expected fn(y, args) to return (r, J), got {type(out).__name__}")
        out, jout = out
    shape = getattr(out, "shape", None)
    if shape is None or len(shape) != 1:
        got = _fmt(shape) if shape is not None else type(out).__name__
        raise ValueError(f"fn: expected fn(y, args) to return residuals of shape (m,), got {got}")
    m = shape[0]
    if jac is not None:
        if jac is not True:
            jout = eqx.filter_eval_shape(jac, y0, args)
        jshape = getattr(jout, "shape", None)
        if jshape is None or tuple(jshape) != (m, n):
            got = _fmt(jshape) if jshape is not None else type(jout).__name__
            raise ValueError(f"jac: expected jac(y, args) to return shape (m, n) = ({m}, {n}), got {got}")
    problem = _Problem(fn=fn, jac=jac, lower=lower, upper=upper, m=m, stop=stop)
    # The loop is not differentiated: the answer carries the implicit derivative of the minimizer
    # with respect to args instead (solvers._implicit; free unless differentiated).
    y0, solve_args = jax.lax.stop_gradient(y0), stop_gradient_arrays(args)
    if isinstance(solver, _AbstractAdapter):
        sol = solver._solve(problem, y0, solve_args)
    else:
        sol = _run(solver, problem, problem.project(y0), solve_args)
    residual = (lambda y, a: fn(y, a)[0]) if jac is True else fn
    value = attach_minimizer(sol.value, lambda y, a: 0.5 * jnp.sum(residual(y, a) ** 2), args, lower, upper,
                             converged=(sol.result == RESULTS.successful) & ~sol.stats["stopped_early"])
    sol = eqx.tree_at(lambda s: s.value, sol, value)
    if throw:
        sol = eqx.tree_at(
            lambda s: s.value, sol, sol.result.error_if(sol.value, sol.result != RESULTS.successful)
        )
    return sol
