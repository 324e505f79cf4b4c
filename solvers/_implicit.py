r"""Derivatives of a minimizer by the implicit function theorem.

An iterative solver's loop (a ``lax.while_loop``) has no reverse-mode derivative, and its
forward-mode one follows the iterations rather than the answer. At a minimizer ``y*(a)`` of
``F(y, a)`` the gradient vanishes, ``g(y*(a), a) = grad_y F = 0``, so

.. math::  H\, \dot y = -\partial_a g\; \dot a, \qquad H = \nabla^2_{yy} F,

which :func:`attach_minimizer` attaches to the solver's answer as its JVP (``jax.grad`` transposes
it). ``H`` is the exact Hessian (``jax.hessian`` of ``F``, second-order residual terms included),
and the system is solved in the least-squares sense with the pseudo-inverse, so a minimizer that is
not unique (a redundant IK chain without regularization) gets the minimum-norm derivative (which
the solver's own answer need not follow: where it lands on the set of minimizers depends on the start;
a regularization makes the minimizer unique). With
bounds, the variables at a bound stay there (``\dot y_i = 0``) and the system is solved for the
others. The primal value is returned unchanged, and the rule costs nothing unless differentiated.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp

from ._linalg import matmul

__all__ = ["attach_minimizer", "stop_gradient_arrays"]

#: The pseudo-inverse's cut, relative to the Hessian's largest eigenvalue.
_RANK_RTOL = 1e-10


def stop_gradient_arrays(tree):
    """``lax.stop_gradient`` on the floating-point arrays of a pytree; other leaves unchanged."""
    return jax.tree.map(lambda x: jax.lax.stop_gradient(x) if eqx.is_inexact_array(x) else x, tree)


def attach_minimizer(y, objective: Callable, args, lower=None, upper=None, converged=True):
    """``y`` (a minimizer of ``objective(y, args)``, ``[n]``), carrying the derivative of the
    minimizer with respect to ``args`` (see the module docstring); ``lower`` / ``upper`` are the
    bounds the minimization respected, or ``None``. ``converged`` (a bool scalar): whether the solve
    reached a minimizer; where it did not, the derivative is NaN (the theorem holds only at a
    minimizer: a plausible number there would be wrong without a sign)."""
    return _attach(y, args, lower, upper, jnp.asarray(converged), objective=objective)


@eqx.filter_custom_jvp
def _attach(y, args, lower, upper, converged, *, objective):
    return y


@_attach.def_jvp
def _attach_jvp(primals, tangents, *, objective):
    y, args, lower, upper, converged = primals
    _, dargs, _, _, _ = tangents  # the minimizer does not depend on where the solve started
    y = jax.lax.stop_gradient(y)
    if dargs is None or all(t is None for t in jax.tree.leaves(dargs, is_leaf=lambda x: x is None)):
        return y, jnp.zeros_like(y)
    grad = jax.grad(objective)
    _, b = eqx.filter_jvp(lambda a: grad(y, a), (args,), (dargs,))
    H = jax.hessian(objective)(y, args)
    H = 0.5 * (H + H.T)
    if lower is not None:
        free = (y > lower) & (y < upper)
        H = jnp.where(free[:, None] & free[None, :], H, jnp.eye(y.shape[0], dtype=H.dtype))
        b = jnp.where(free, b, 0.0)
    # eigenvalues below 1e-10 of the largest are rounding (a redundant chain's null space): the default cut
    # (n eps) inverted them into a derivative of noise
    dy = -matmul(jnp.linalg.pinv(H, rtol=_RANK_RTOL, hermitian=True), b)
    # a factor, not a where: the rule must stay linear in the tangents for jax.grad to transpose it
    return y, dy * jnp.where(converged, 1.0, jnp.nan).astype(dy.dtype)
