r"""Iterative LQR and differential dynamic programming for discrete-time optimal control.

Both solvers minimize, over the controls ``u_0..u_{T-1}`` (single shooting from ``x0``),

.. math::
    J = \sum_{t=0}^{T-1} \ell(x_t, u_t, t) + \ell_T(x_T), \qquad x_{t+1} = f(x_t, u_t, t),

with user callbacks ``dynamics(x, u, t, args) -> x_next``, ``cost(x, u, t, args) -> scalar`` and
``terminal_cost(x, args) -> scalar``. Every iteration

1. **linearizes** the dynamics (``A_t = f_x``, ``B_t = f_u``) and **quadratises** the cost
   (``l_x, l_u, l_xx, l_uu, l_ux``) along the nominal trajectory with ``jax.jacfwd`` /
   ``jax.hessian``, ``vmap``-ed over time;
2. runs the **backward pass** (``lax.scan``) on the value function ``V_t(x_t + dx) ~ V + V_x dx +
   0.5 dx' V_xx dx`` (``V_x, V_xx`` at ``T`` from ``l_T``)::

       Q_x  = l_x + A' V_x'          Q_u  = l_u + B' V_x'
       Q_xx = l_xx + A' V_xx' A      Q_uu = l_uu + B' V_xx' B      Q_ux = l_ux + B' V_xx' A
       K = -(Q_uu + mu I)^{-1} Q_ux,  k = -(Q_uu + mu I)^{-1} Q_u
       V_x  = Q_x + K' Q_uu k + K' Q_u + Q_ux' k
       V_xx = Q_xx + K' Q_uu K + K' Q_ux + Q_ux' K

   (primes: step ``t+1``; the value update is Tassa, Erez & Todorov 2012, eq. 11, exact for the
   regularized gains). **DDP** (:func:`ddp`) adds the second-order dynamics terms
   ``d^2 (V_x' . f) / d(x, u)^2`` to ``Q_xx, Q_uu, Q_ux``: one ``jax.hessian`` of the scalar
   ``V_x' . f(x, u)`` per step (a Hessian-vector contraction; the ``n x (n+m) x (n+m)`` tensor of
   ``f`` is never formed). When those terms make some ``Q_uu + mu I`` indefinite (typically far
   from a minimum, where ``V_x`` is large) the backward pass is first redone without them (an
   iLQR pass) before ``mu`` is raised, so DDP starts like iLQR instead of throttling its steps
   with a huge ``mu``, and keeps its quadratic convergence near a minimum. ``mu`` follows the Levenberg-Marquardt schedule of Tassa et al.
   (``mu_min = 1e-6``, factor ``Delta_0 = 2``): it grows when a Cholesky factorization of
   ``Q_uu + mu I`` fails (the backward pass is retried) or the line search fails, and shrinks
   after every accepted step, to exactly 0 below ``mu_min``;
3. runs the **forward pass** ``u_t = ubar_t + alpha k_t + K_t (x_t - xbar_t)`` with a
   backtracking line search ``alpha = 1, 1/2, ..., 2^-10``, accepting the first step whose actual
   decrease is at least ``0.1`` of the expected decrease
   ``-(alpha sum k'Q_u + 0.5 alpha^2 sum k'Q_uu k)`` (the Armijo-like test of Tassa et al.).

**Box-DDP** (``bounds=(u_min, u_max)``, Tassa, Mansard & Todorov 2014): the backward pass gets
``k_t`` from the box QP ``min 0.5 k'(Q_uu + mu I)k + Q_u'k`` s.t. ``u_min <= ubar_t + k <= u_max``,
solved by projected Newton (``_ilqr_passes._box_qp``); the rows of ``K_t`` of clamped controls are zero and
the free rows use ``Q_uu`` restricted to the free controls. The forward pass clips the controls,
and the gradient test uses the projected gradient (components held at a bound whose gradient
pushes outwards are dropped).

The solve has **converged** when, after a backward pass at the current trajectory, the expected
decrease of the full step is at most ``atol + rtol |J|`` (a relative-cost-decrease test on the
step that would be taken next, trusted only while ``mu`` is not larger than the curvature of
``Q_uu``), or when the gradient of ``J`` with respect to the controls (the adjoint/costate
gradient ``l_u + B' lambda_{t+1}``) has infinity norm at most ``atol``. On a linear-quadratic
problem the first iteration gives the exact LQR solution (:func:`solvers.lqr`); the second
confirms convergence.

Iterations run in a ``lax.while_loop`` (adaptive) or, with ``fixed_steps=True``, in a
``lax.scan`` of exactly ``max_steps`` iterations in which a finished problem is frozen (same
iterates; for large batches, where a while loop runs until its slowest element anyway). Both
functions solve one problem and are ``eqx.filter_jit``-ed; batch them with ``jax.vmap``, where
each element keeps its own ``result`` and a diverging element never aborts the batch
(``throw=False``, the default).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, PyTree

from ._checks import _all_finite, _as_float, _fmt
from ._ilqr_passes import Dynamics, StageCost, TerminalCost, _Problem
from ._implicit import attach_minimizer, stop_gradient_arrays
from ._iterate import iterate
from ._linalg import einsum
from ._results import RESULTS

__all__ = ["ILQROptions", "TrajectorySolution", "ddp", "ilqr"]


_MU_MIN = 1e-6  # below this the regularization snaps to 0 (Tassa et al. 2012)
_MU_MAX = 1e10  # above this the solve gives up (RESULTS.no_descent)
_DELTA0 = 2.0  # the regularization schedule's base factor
_ACCEPT = 0.1  # line search: accept when actual >= _ACCEPT * expected decrease
_ALPHA_MIN_EXPONENT = 10  # step sizes 1, 1/2, ..., 2^-10
_BACKWARD_RETRIES = 64  # regularization increases tried within one backward pass


class TrajectorySolution(eqx.Module):
    """The result of :func:`ilqr` or :func:`ddp`.

    Attributes:
        xs: ``[T+1, n]`` the state trajectory, the rollout of ``us`` from ``x0`` (``xs[0] = x0``).
            When the initial rollout is not finite (``result == RESULTS.nonfinite``) it is that
            rollout, unchanged.
        us: ``[T, m]`` the controls.
        Ks: ``[T, m, n]`` feedback gains of the last backward pass.
        ks: ``[T, m]`` feed-forward terms of the last backward pass, in the absolute convention
            of :func:`solvers.lqr`: the policy is ``u_t = Ks[t] @ x_t + ks[t]`` (**plus** sign;
            ``ks[t] = ubar_t + k_t - K_t xbar_t`` for the nominal trajectory of that pass). After
            convergence that pass was made at ``(xs, us)``, so the policy reproduces ``us`` along
            ``xs`` to the tolerance and is the local optimal feedback around it.
        cost: the total cost ``J`` of ``(xs, us)``.
        result: a :class:`~solvers.RESULTS` code, per element under ``jax.vmap``:
            ``successful``, ``max_steps_reached``, ``nonfinite`` (the initial rollout or cost is
            not finite) or ``no_descent`` (the regularization reached its maximum).
        stats: arrays:

            - ``num_steps`` (int): iterations (backward passes) performed, including the last
              one that confirms convergence.
            - ``cost_history``: ``[max_steps + 1]``; entry ``k`` is the cost after ``k``
              iterations (entry 0 the initial cost), padded with the final cost.
            - ``grad_norm``: ``max_t |dJ/du_t|_inf`` at ``(xs, us)`` (adjoint gradient).
            - ``expected_decrease``: the expected decrease of the full step of the last
              backward pass.
            - ``regularization``: ``mu`` at the end.
            - ``step_size``: ``alpha`` of the last accepted step (0 if none).
    """

    xs: Float[Array, "T+1 n"]
    us: Float[Array, "T m"]
    Ks: Float[Array, "T m n"]
    ks: Float[Array, "T m"]
    cost: Float[Array, ""]
    result: RESULTS
    stats: dict[str, Array]


_DEFAULTS = dict(max_steps=100, fixed_steps=False, rtol=None, atol=1e-12)


class ILQROptions(eqx.Module):
    """The iteration settings of :func:`ilqr` and :func:`ddp` (also accepted by :func:`solvers.mpc`).

    Pass ``options=ILQROptions(...)`` instead of the keywords ``max_steps``, ``fixed_steps``,
    ``rtol`` and ``atol`` (which keep working); one settings object to share between calls.

    Attributes:
        max_steps: the most iterations (static int >= 1).
        fixed_steps: if true, run exactly ``max_steps`` iterations in a ``lax.scan``, freezing the
            problem once it has finished (same iterates as the adaptive ``lax.while_loop``).
        rtol: relative tolerance on the expected cost decrease (default ``1e-13``, floored at
            ``16 eps`` of the dtype). A float is static under jit; an array may be swept by ``vmap``.
        atol: absolute tolerance on the expected decrease and on ``max_t |dJ/du_t|_inf``.
    """

    max_steps: int = eqx.field(default=100, static=True)
    fixed_steps: bool = eqx.field(default=False, static=True)
    rtol: float | Array | None = None
    atol: float | Array = 1e-12

    def __check_init__(self):
        if not isinstance(self.max_steps, (int, np.integer)) or isinstance(self.max_steps, bool) or self.max_steps < 1:
            raise ValueError(f"max_steps: expected an int >= 1, got {self.max_steps!r}")


def _options(options: ILQROptions | None, defaults: dict = _DEFAULTS, **keywords) -> ILQROptions:
    """``options``, or the 0.1 keywords as an :class:`ILQROptions`; both at once (a keyword away from
    its default in ``defaults``) is an error."""
    if options is None:
        max_steps = keywords["max_steps"]
        if isinstance(max_steps, np.integer):
            max_steps = int(max_steps)
        return ILQROptions(
            max_steps=max_steps, fixed_steps=bool(keywords["fixed_steps"]), rtol=keywords["rtol"], atol=keywords["atol"]
        )
    if not isinstance(options, ILQROptions):
        raise ValueError(f"options: expected an ILQROptions, got {type(options).__name__}")

    def is_default(value, default):
        return value is default or (type(value) in (int, float, bool) and value == default)

    given = sorted(k for k, v in keywords.items() if not is_default(v, defaults[k]))
    if given:
        raise ValueError(f"options: given together with {', '.join(given)}; pass those inside options")
    return options


# --------------------------------------------------------------------------------------------
# The iteration.
# --------------------------------------------------------------------------------------------


class _State(eqx.Module):
    """The state of one iLQR / DDP solve between iterations (the driver counts the steps)."""

    xs: Float[Array, "T+1 n"]
    us: Float[Array, "T m"]
    cost: Float[Array, ""]
    Ks: Float[Array, "T m n"]
    ks: Float[Array, "T m"]  # absolute feed-forward of the last backward pass
    mu: Float[Array, ""]
    delta: Float[Array, ""]
    expected: Float[Array, ""]  # expected decrease of the full step of the last backward pass
    alpha: Float[Array, ""]
    converged: Bool[Array, ""]
    failed: Bool[Array, ""]  # the regularization exceeded its maximum


class _Backward(eqx.Module):
    """The outcome of a backward pass: gains, expected-decrease terms, success, curvature."""

    Ks: Float[Array, "T m n"]
    ks: Float[Array, "T m"]
    dV1: Float[Array, ""]
    dV2: Float[Array, ""]
    ok: Bool[Array, ""]
    curvature: Float[Array, ""]


def _increase(mu, delta):
    delta = jnp.maximum(_DELTA0, delta * _DELTA0)
    return jnp.maximum(_MU_MIN, mu * delta), delta


def _decrease(mu, delta):
    delta = jnp.minimum(1 / _DELTA0, delta / _DELTA0)
    mu = mu * delta
    return jnp.where(mu > _MU_MIN, mu, 0.0).astype(mu.dtype), delta


def _backward_with_retries(problem: _Problem, s: _State, ex, args):
    """The backward pass at ``s``, retried while ``Q_uu + mu I`` is not PD: ``(bw, mu, delta)``.

    DDP first retries without its second-order terms (far from a minimum they can make ``Q_uu``
    indefinite; raising ``mu`` until they are swamped would throttle the steps), then with a
    larger regularization. An inner retry loop, not an iteration of the driver.
    """
    dtype = s.xs.dtype

    def cond(c):
        i, mu, delta, second, bw = c
        return ~bw.ok & (mu <= _MU_MAX) & (i < _BACKWARD_RETRIES)

    def body(c):
        i, mu, delta, second, _ = c
        drop = second > 0
        mu_up, delta_up = _increase(mu, delta)
        mu = jnp.where(drop, mu, mu_up)
        delta = jnp.where(drop, delta, delta_up)
        second = jnp.zeros_like(second)
        return i + 1, mu, delta, second, _Backward(*problem.backward(s.xs, s.us, ex, mu, args, second))

    second0 = jnp.asarray(1.0 if problem.second_order else 0.0, dtype)
    first = _Backward(*problem.backward(s.xs, s.us, ex, s.mu, args, second0))
    _, mu, delta, _, bw = jax.lax.while_loop(cond, body, (jnp.array(0), s.mu, s.delta, second0, first))
    return bw, mu, delta


def _line_search(problem: _Problem, x0, s: _State, Ks, ks, dV1, dV2, search, args):
    """Backtracking on the feed-forward, ``alpha = 1, 1/2, ..., 2^-10``: ``(accepted, xs, us, J, alpha)``.

    Accepts the first ``alpha`` whose actual decrease is at least ``_ACCEPT`` of the expected
    ``-(alpha dV1 + alpha^2 dV2)`` with a finite rollout; skipped when ``search`` is false.
    """
    dtype = s.xs.dtype

    def cond(c):
        j, accepted, _ = c
        return ~accepted & (j <= _ALPHA_MIN_EXPONENT)

    def body(c):
        j, _, _ = c
        alpha = jnp.asarray(0.5, dtype) ** j
        xs_new, us_new, J = problem.closed_loop(x0, s.xs, s.us, Ks, ks, alpha, args)
        exp_a = -(alpha * dV1 + alpha**2 * dV2)
        accepted = jnp.isfinite(J) & _all_finite(xs_new, us_new) & (s.cost - J >= _ACCEPT * exp_a) & (exp_a > 0)
        return j + 1, accepted, (xs_new, us_new, J, alpha)

    init = (s.xs, s.us, s.cost, jnp.zeros((), dtype))
    j0 = jnp.where(search, 0, _ALPHA_MIN_EXPONENT + 1)
    _, accepted, (xs_new, us_new, J, alpha) = jax.lax.while_loop(cond, body, (j0, jnp.array(False), init))
    return accepted & search, xs_new, us_new, J, alpha


def _iteration(problem: _Problem, x0, args, rtol, atol, s: _State) -> _State:
    """One iLQR / DDP iteration: expand, backward pass (with retries), convergence test, line search."""
    ex = problem.expand(s.xs, s.us, args)
    g_norm = jnp.max(jnp.abs(problem.projected(problem.gradient(ex), s.us)))
    bw, mu, delta = _backward_with_retries(problem, s, ex, args)
    ok = bw.ok & (mu <= _MU_MAX)
    Ks = jnp.where(ok, bw.Ks, 0)
    ks = jnp.where(ok, bw.ks, 0)
    expected = jnp.where(ok, -(bw.dV1 + bw.dV2), 0)
    trusted = mu <= bw.curvature
    converged = (ok & trusted & (expected <= atol + rtol * jnp.abs(s.cost))) | (g_norm <= atol)
    ks_abs = s.us + ks - einsum("tmn,tn->tm", Ks, s.xs[:-1])
    accepted, xs_new, us_new, J, alpha = _line_search(problem, x0, s, Ks, ks, bw.dV1, bw.dV2, ok & ~converged, args)

    mu_dec, delta_dec = _decrease(mu, delta)
    mu_inc, delta_inc = _increase(mu, delta)
    mu_next = jnp.where(accepted, mu_dec, jnp.where(converged, mu, mu_inc))
    delta_next = jnp.where(accepted, delta_dec, jnp.where(converged, delta, delta_inc))
    failed = ~converged & ~accepted & (~ok | (mu_next > _MU_MAX))
    return _State(
        xs=jnp.where(accepted, xs_new, s.xs),
        us=jnp.where(accepted, us_new, s.us),
        cost=jnp.where(accepted, J, s.cost),
        Ks=jnp.where(ok, Ks, s.Ks),
        ks=jnp.where(ok, ks_abs, s.ks),
        mu=mu_next,
        delta=delta_next,
        expected=expected,
        alpha=jnp.where(accepted, alpha, s.alpha),
        converged=converged,
        failed=failed,
    )


def _solve(problem, x0, us, args, options: ILQROptions, throw) -> TrajectorySolution:
    # The iterations are not differentiated: the controls carry the implicit derivative of the
    # minimizer of the total cost (solvers._implicit), and the trajectory and cost that of the rollout.
    x0_d, args_d = x0, args
    x0, us, args = jax.lax.stop_gradient(x0), jax.lax.stop_gradient(us), stop_gradient_arrays(args)
    dtype = x0.dtype
    T, m = us.shape
    n = x0.shape[0]
    eps = jnp.finfo(dtype).eps
    rtol = jnp.maximum(jnp.asarray(1e-13 if options.rtol is None else options.rtol, dtype), 16 * eps)
    atol = jnp.asarray(options.atol, dtype)
    xs, J = problem.rollout(x0, us, args)
    zero = jnp.zeros((), dtype)
    s0 = _State(
        xs=xs, us=us, cost=J, Ks=jnp.zeros((T, m, n), dtype), ks=us, mu=zero, delta=jnp.ones((), dtype),
        expected=zero, alpha=zero, converged=jnp.array(False), failed=jnp.array(False),
    )
    # The guard looks at the trajectory and its cost: the initial rollout may be non-finite
    # (RESULTS.nonfinite); afterwards the line search accepts finite rollouts only.
    it = iterate(
        lambda s: _iteration(problem, x0, args, rtol, atol, s),
        s0,
        done=lambda s: s.converged | s.failed,
        max_steps=options.max_steps,
        fixed_steps=options.fixed_steps,
        finite=lambda s: jnp.isfinite(s.cost) & _all_finite(s.xs),
        record=lambda s: s.cost,
    )
    s = it.state
    ex = problem.expand(s.xs, s.us, args)
    grad_norm = jnp.max(jnp.abs(problem.projected(problem.gradient(ex), s.us)))
    result = RESULTS.where(
        it.nonfinite,
        RESULTS.nonfinite,
        RESULTS.where(
            s.converged,
            RESULTS.successful,
            RESULTS.where(s.failed, RESULTS.no_descent, RESULTS.max_steps_reached),
        ),
    )
    T, m = s.us.shape

    def total(u, a):
        return problem.rollout(a[0], u.reshape(T, m), a[1])[1]

    bounds = (None, None) if not problem.bounded else (jnp.tile(problem.lower, T), jnp.tile(problem.upper, T))
    us_out = attach_minimizer(s.us.reshape(T * m), total, (x0_d, args_d), *bounds,
                              converged=result == RESULTS.successful).reshape(T, m)
    xs_out, cost_out = _with_rollout_tangent(s.xs, s.cost, us_out, x0_d, args_d, rollout=problem.rollout)
    if throw:
        xs_out = result.error_if(xs_out, result != RESULTS.successful)
    stats = dict(
        num_steps=it.num_steps,
        cost_history=it.history,
        grad_norm=grad_norm,
        expected_decrease=s.expected,
        regularization=s.mu,
        step_size=s.alpha,
    )
    return TrajectorySolution(xs=xs_out, us=us_out, Ks=s.Ks, ks=s.ks, cost=cost_out, result=result, stats=stats)


@eqx.filter_custom_jvp
def _with_rollout_tangent(xs, cost, us, x0, args, *, rollout):
    """``(xs, cost)`` of the solution, differentiated as the rollout of ``us`` from ``x0``."""
    return xs, cost


@_with_rollout_tangent.def_jvp
def _with_rollout_tangent_jvp(primals, tangents, *, rollout):
    xs, cost, us, x0, args = primals
    _, _, dus, dx0, dargs = tangents
    _, (dxs, dcost) = eqx.filter_jvp(lambda u, x, a: rollout(x, u, a), (us, x0, args), (dus, dx0, dargs))
    return (xs, cost), (dxs, dcost)


@eqx.filter_jit
def _solve_jit(problem, x0, us, args, options, throw):
    n = x0.shape[0]
    t0 = jnp.array(0)
    out = _eval_callback("dynamics", problem.dynamics, x0, us, t0, args)
    if getattr(out, "shape", None) != (n,):
        got = _fmt(out.shape) if hasattr(out, "shape") else type(out).__name__
        raise ValueError(f"dynamics: expected dynamics(x, u, t, args) to return shape (n,) = ({n},), got {got}")
    out = _eval_callback("cost", problem.cost, x0, us, t0, args)
    if getattr(out, "shape", None) != ():
        got = _fmt(out.shape) if hasattr(out, "shape") else type(out).__name__
        raise ValueError(f"cost: expected cost(x, u, t, args) to return a scalar, shape (), got {got}")
    if problem.terminal_cost is not None:
        out = eqx.filter_eval_shape(problem.terminal_cost, x0, args)
        if getattr(out, "shape", None) != ():
            got = _fmt(out.shape) if hasattr(out, "shape") else type(out).__name__
            raise ValueError(f"terminal_cost: expected terminal_cost(x, args) to return a scalar, shape (), got {got}")
    return _solve(problem, x0, us, args, options, throw)


def _eval_callback(name, fn, x0, us, t0, args):
    """The output shape of ``fn(x0, us[0], t0, args)``; a shape error inside it (most often a control
    size ``m`` that is not the one the callback expects) raises a ValueError naming ``us_init``."""
    try:
        return eqx.filter_eval_shape(fn, x0, us[0], t0, args)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"us_init: {name}(x, u, t, args) failed on x0 of shape (n,) = {_fmt(x0.shape)} and us_init of shape "
            f"(T, m) = {_fmt(us.shape)}: give us_init the control size m that {name} expects ({type(exc).__name__}: "
            f"{str(exc).splitlines()[0] if str(exc) else ''})"
        ) from exc


def _check_bounds(bounds, m: int, dtype):
    if bounds is None:
        return None, None
    if not (isinstance(bounds, (tuple, list)) and len(bounds) == 2):
        raise ValueError(f"bounds: expected a pair (u_min, u_max) of shape (m,) = ({m},), got {type(bounds).__name__}")
    lower, upper = (jnp.asarray(b, dtype) for b in bounds)
    for name, b in (("u_min", lower), ("u_max", upper)):
        if b.shape not in ((), (m,)):
            raise ValueError(f"bounds: expected {name} of shape (m,) = ({m},), got {_fmt(b.shape)}")
    lower = jnp.broadcast_to(lower, (m,))
    upper = jnp.broadcast_to(upper, (m,))
    if not isinstance(lower, jax.core.Tracer) and not isinstance(upper, jax.core.Tracer):
        if np.any(np.asarray(lower) > np.asarray(upper)):
            raise ValueError("bounds: expected u_min <= u_max for every control")
    return lower, upper


def _entry(second_order, dynamics, cost, x0, us_init, terminal_cost, args, bounds, options, throw):
    x0 = _as_float("x0", x0)
    if x0.ndim != 1 or x0.shape[0] == 0:
        raise ValueError(f"x0: expected shape (n,) with n >= 1, got {_fmt(x0.shape)}")
    us = _as_float("us_init", us_init)
    if us.ndim != 2 or us.shape[0] == 0 or us.shape[1] == 0:
        raise ValueError(f"us_init: expected shape (T, m) with T >= 1 and m >= 1, got {_fmt(us.shape)}")
    dtype = jnp.result_type(x0.dtype, us.dtype)
    lower, upper = _check_bounds(bounds, us.shape[1], dtype)
    if lower is not None:
        us = jnp.clip(us.astype(dtype), lower[None], upper[None])
    problem = _Problem(
        dynamics=dynamics, cost=cost, terminal_cost=terminal_cost, second_order=second_order, lower=lower, upper=upper
    )
    return _solve_jit(problem, x0.astype(dtype), us.astype(dtype), args, options, bool(throw))


_ARGS_DOC = """
    Args:
        dynamics: ``dynamics(x, u, t, args) -> x_next``, ``[n]``; discrete time, ``t`` an int
            array (the step index).
        cost: ``cost(x, u, t, args) -> scalar``, the stage cost, summed over ``t = 0..T-1``.
        x0: ``[n]`` the initial state.
        us_init: ``[T, m]`` the initial controls (``T`` the horizon).
        terminal_cost: optional ``terminal_cost(x, args) -> scalar`` added at ``x_T``.
        args: any pytree passed to the callbacks (``vmap`` over it to batch problems).
        bounds: optional ``(u_min, u_max)``, each ``[m]`` or a scalar (``-inf``/``inf`` for
            free controls): box-DDP. ``us_init`` is clipped into the box, the backward pass solves
            a box QP for ``k_t`` and the forward pass clips, so every iterate is feasible.
        max_steps: the most iterations (static int >= 1).
        fixed_steps: if true, run exactly ``max_steps`` iterations in a ``lax.scan``, freezing the
            problem once it has finished (same iterates as the adaptive ``lax.while_loop``).
        rtol: relative tolerance on the expected cost decrease (default ``1e-13``, floored at
            ``16 eps`` of the dtype).
        atol: absolute tolerance on the expected decrease and on ``max_t |dJ/du_t|_inf``.
        options: an :class:`ILQROptions` holding ``max_steps``, ``fixed_steps``, ``rtol`` and
            ``atol`` instead of those keywords (passing both is an error).
        throw: if true, raise unless the solve succeeds (under ``vmap``: if any element fails).

    Returns:
        A :class:`TrajectorySolution` ``(xs, us, Ks, ks, cost, result, stats)``.

    Raises:
        ValueError: ``x0``/``us_init`` have the wrong shape or are complex, a callback returns the
            wrong shape, ``bounds`` do not match ``m`` or ``u_min > u_max``, or ``max_steps`` is
            not a positive int. Raised before the solve runs.
        equinox.EquinoxRuntimeError: ``throw=True`` and the solve failed.
"""


def ilqr(
    dynamics: Dynamics,
    cost: StageCost,
    x0: Float[ArrayLike, " n"],
    us_init: Float[ArrayLike, "T m"],
    *,
    terminal_cost: TerminalCost | None = None,
    args: PyTree = None,
    bounds: tuple[Float[ArrayLike, " m"], Float[ArrayLike, " m"]] | None = None,
    max_steps: int = 100,
    fixed_steps: bool = False,
    rtol: float | None = None,
    atol: float = 1e-12,
    options: ILQROptions | None = None,
    throw: bool = False,
) -> TrajectorySolution:
    options = _options(options, max_steps=max_steps, fixed_steps=fixed_steps, rtol=rtol, atol=atol)
    return _entry(False, dynamics, cost, x0, us_init, terminal_cost, args, bounds, options, throw)


def ddp(
    dynamics: Dynamics,
    cost: StageCost,
    x0: Float[ArrayLike, " n"],
    us_init: Float[ArrayLike, "T m"],
    *,
    terminal_cost: TerminalCost | None = None,
    args: PyTree = None,
    bounds: tuple[Float[ArrayLike, " m"], Float[ArrayLike, " m"]] | None = None,
    max_steps: int = 100,
    fixed_steps: bool = False,
    rtol: float | None = None,
    atol: float = 1e-12,
    options: ILQROptions | None = None,
    throw: bool = False,
) -> TrajectorySolution:
    options = _options(options, max_steps=max_steps, fixed_steps=fixed_steps, rtol=rtol, atol=atol)
    return _entry(True, dynamics, cost, x0, us_init, terminal_cost, args, bounds, options, throw)


ilqr.__doc__ = (
    """Minimize a discrete-time optimal-control problem by iterative LQR (first-order dynamics).

    See the module docstring for the algorithm, the regularization, the line search and the
    convergence test. Solves one problem; batch with ``jax.vmap`` (``throw=False`` and
    ``sol.result == RESULTS.successful`` give a per-element status). Compiled once per callback
    objects, shapes and static settings: pass the same function objects, and data in ``args``.
"""
    + _ARGS_DOC
)
ddp.__doc__ = (
    """Minimize a discrete-time optimal-control problem by differential dynamic programming.

    As :func:`ilqr`, plus the second-order dynamics terms ``d^2 (V_x' . f) / d(x, u)^2`` in the
    backward pass (one Hessian of a scalar per time step, no dense 3-tensor). Converges
    quadratically near a minimum; more work per iteration than iLQR.
"""
    + _ARGS_DOC
)
