"""Levenberg-Marquardt with Nielsen's damping update."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._checks import _all_finite, _check_int, _fmt
from ._ls_base import (
    AbstractLeastSquaresSolver,
    _cost_change,
    _model,
    _placeholder,
    _State,
    _stats,
    _terminate,
    _tolerances,
)


class LevenbergMarquardt(AbstractLeastSquaresSolver):
    r"""Levenberg-Marquardt with Nielsen's damping update.

    Each iteration solves ``(J^T J + lambda D) p = -J^T r`` (in residual space when ``m < n``),
    evaluates the trial point ``y + s`` (``s`` the step clipped into the box) and the gain ratio
    ``rho = (F(y) - F(y + s)) / pred(s)``, ``pred(s) = -(g^T s + 0.5 |J s|^2)``. The step is
    accepted when ``rho > 0``: then ``lambda *= max(1/3, 1 - (2 rho - 1)^3)``, ``nu = 2``;
    otherwise ``lambda *= nu``, ``nu *= 2`` (Nielsen 1999; Madsen, Nielsen & Tingleff, *Methods for
    non-linear least squares problems*, 2004, alg. 3.16). A trial point with a non-finite residual
    or Jacobian is rejected like a bad step, so the solver backs away from it; it fails with
    ``RESULTS.nonfinite`` only if no finite step remains. ``lambda`` is kept in
    ``[eps, 1/eps] * lambda_scale`` (``lambda_scale = max_i (J^T J)_ii / D_ii`` at ``y0``).

    Attributes:
        rtol: relative tolerance of the convergence test (array; sweepable under ``vmap``).
        atol: absolute tolerance of the convergence test (array).
        max_steps: the most iterations (static); rejected trial steps count.
        fixed_steps: if true, run exactly ``max_steps`` iterations in a ``lax.scan`` (see
            :class:`GaussNewton`).
        lambda0: initial damping *relative* to the curvature, ``lambda = lambda0 * lambda_scale``
            (Madsen-Nielsen's ``tau``; 1e-3 for a good start, up to 1 for a poor one). An array, so
            ``vmap`` can sweep it.
        scaling: if true, use Marquardt's scaling ``D = diag(J^T J)``, accumulated as the running
            maximum over accepted iterates (zero columns at ``y0`` get 1), instead of ``D = I``.
            Makes the method invariant to the scale of the variables.
        weights: optional ``[n]`` positive per-variable weights ``w``: ``D = diag(w)`` (the
            course notes' joint weight matrix ``W``: a variable with a large weight resists
            moving while the damping is large), or ``D = diag(w * J^T J)`` with ``scaling``. An
            array, so ``vmap`` can sweep it; the ``m x m`` form is kept for ``m < n``.
    """

    rtol: Float[Array, ""] = eqx.field(default=1e-8, converter=jnp.asarray)
    atol: Float[Array, ""] = eqx.field(default=1e-10, converter=jnp.asarray)
    max_steps: int = eqx.field(default=100, static=True)
    fixed_steps: bool = eqx.field(default=False, static=True)
    lambda0: Float[Array, ""] = eqx.field(default=1e-3, converter=jnp.asarray)
    scaling: bool = eqx.field(default=False, static=True)
    weights: Float[Array, " n"] | None = eqx.field(
        default=None, converter=lambda w: None if w is None else jnp.asarray(w)
    )

    def __check_init__(self):
        _check_int("max_steps", self.max_steps, 1)
        if self.weights is not None and not isinstance(self.weights, jax.core.Tracer):
            if self.weights.ndim != 1:
                raise ValueError(f"weights: expected shape (n,), got {_fmt(self.weights.shape)}")
            if not np.all(np.asarray(self.weights) > 0):
                raise ValueError("weights: expected positive per-variable weights")

    def _short_fat(self, m: int, n: int) -> bool:
        return m < n

    def _initial_damping(self, J):
        """``(lambda, lambda_scale, D)`` at ``y0`` from its Jacobian."""
        dtype = J.dtype
        eps = jnp.finfo(dtype).eps
        colsq = jnp.sum(J * J, axis=0)
        diag = jnp.where(colsq > 0, colsq, 1) if self.scaling else None
        if self.weights is not None:
            w = jnp.asarray(self.weights, dtype)
            diag = w if diag is None else diag * w
        lam_scale = jnp.max(colsq if diag is None else colsq / diag)
        lam_scale = jnp.where(jnp.isfinite(lam_scale) & (lam_scale > 0), lam_scale, 1)
        lam = jnp.clip(jnp.asarray(self.lambda0, dtype) * lam_scale, eps * lam_scale, lam_scale / eps)
        return lam, lam_scale, diag

    def init_placeholder(self, problem, y, args):
        """The state before the first linearization: its trial point is ``y`` itself, which the
        first ``step`` linearizes and accepts with the initial damping, so the residual and its
        Jacobian are compiled once, in the loop."""
        dtype = y.dtype
        diag = None if not self.scaling and self.weights is None else jnp.ones(y.shape[0], dtype)
        return _placeholder(problem, y, args, nu=jnp.asarray(2, dtype), lam_scale=jnp.ones((), dtype), diag=diag)

    def step(self, problem, y, args, state):
        dtype = y.dtype
        eps = jnp.finfo(dtype).eps
        rtol, atol = _tolerances(self, dtype)
        m, n = state.J.shape
        y_t = state.y_trial
        r_t, J_t = problem.linearize(y_t, args)
        finite = _all_finite(r_t, J_t)
        valid = state.step_ok & (state.pred > 0)
        rho = -_cost_change(state.r, r_t) / jnp.where(valid, state.pred, 1)
        first = state.placeholder
        accept = first | (finite & valid & (rho > 0))  # the first linearization is init's: taken
        lam_max = state.lam_scale / eps
        lam_acc = jnp.maximum(state.lam * jnp.maximum(1 / 3, 1 - (2 * rho - 1) ** 3), eps * state.lam_scale)
        lam = jnp.where(accept, lam_acc, jnp.minimum(state.lam * state.nu, lam_max))
        nu = jnp.where(accept, 2, 2 * state.nu)
        stalled = jnp.invert(accept) & (state.lam >= lam_max)
        y_new = jnp.where(accept, y_t, y)
        r = jnp.where(accept, r_t, state.r)
        J = jnp.where(accept, J_t, state.J)
        diag, lam_scale = state.diag, state.lam_scale
        if self.scaling:
            colsq = jnp.sum(J * J, axis=0)
            if self.weights is not None:
                colsq = colsq * jnp.asarray(self.weights, dtype)
            diag = jnp.where(accept, jnp.maximum(diag, colsq), diag)
        # from the placeholder: the initial damping at y0
        lam0, scale0, diag0 = self._initial_damping(J)
        lam, lam_scale = jnp.where(first, lam0, lam), jnp.where(first, scale0, lam_scale)
        diag = diag if diag is None else jnp.where(first, diag0, diag)
        model = _model(problem, y_new, r, J, lam, diag, self._short_fat(m, n), rtol, atol)
        new_state = _State(
            **model, lam=lam, nu=nu, lam_scale=lam_scale, diag=diag,
            stalled=stalled, stall_nonfinite=stalled & jnp.invert(finite),
            step_norm=jnp.max(jnp.abs(y_t - y)), placeholder=jnp.array(False),
        )
        return y_new, new_state

    def terminate(self, problem, y, args, state):
        rtol, atol = _tolerances(self, y.dtype)
        return _terminate(state, rtol, atol, singular_stops=False)

    def postprocess(self, problem, y, args, state, result):
        return y, _stats(state)

