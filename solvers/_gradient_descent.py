"""Gradient descent (the Jacobian-transpose method) with Buss's step length: a baseline."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx

from ._gauss_newton import _AbstractLineSearch


class GradientDescent(_AbstractLineSearch):
    r"""Gradient descent (the Jacobian-transpose method) with Buss's step length: a baseline.

    Each iteration steps along the negative projected gradient ``-g``, ``g = J^T r`` (variables at
    an active bound whose gradient pushes outwards are held fixed), with Buss's step length
    ``alpha = |g|^2 / |J g|^2``, the exact minimizer of the Gauss-Newton model
    ``F + g^T s + 0.5 |J s|^2`` along ``-g`` (the Cauchy step; Buss 2004, *Introduction to inverse
    kinematics with Jacobian transpose, pseudoinverse and damped least squares methods*). The
    trial point ``y + alpha p`` is clipped into the box and accepted by the same backtracking
    (Armijo) line search as :class:`GaussNewton`: ``alpha`` is halved up to ``max_backtracks``
    times until ``F(y + s) <= F(y) + c1 g^T s`` (``c1 = 1e-4``), or, where the cost change is
    below ``sqrt(eps) F(y)`` and so mostly rounding, until the same test holds with the cost
    change estimated from the gradients at both ends (Hager and Zhang's approximate Armijo test;
    see :func:`_line_search_step`). Without it, the last linearly convergent steps towards a
    minimum with a nonzero residual cannot be told from rounding noise and the solve stalls
    ``~sqrt(eps)`` from it; with it, ``cost_history`` may rise by a few ulps near the end.

    A first-order method: it needs no linear solve, but converges only linearly, at a rate set by
    the condition number ``kappa`` of ``J^T J`` (about ``((kappa - 1) / (kappa + 1))^2`` per
    iteration on a linear problem), and takes thousands of iterations on a badly conditioned or
    curved problem such as Rosenbrock. It is meant as the course notes' baseline to compare
    :class:`GaussNewton` and :class:`LevenbergMarquardt` against, not for production solves.

    Convergence is tested after every iteration on the pending projected step
    ``s = clip(y - alpha g) - y`` and its predicted decrease ``pred = -(g^T s + 0.5 |J s|^2)``
    (``= 0.5 alpha |g|^2`` without bounds)::

        (all |s_i| <= atol + rtol |y_i|  and  pred <= atol + rtol * cost)  or  |g_free|_inf <= atol

    (``rtol`` floored at ``4 eps`` of the dtype). This is the Gauss-Newton test of the module
    docstring with the gradient step in place of the Gauss-Newton step and without the damping
    condition.
    Because the gradient step underestimates the distance to the minimum by up to ``kappa``,
    the returned value is within about ``kappa rtol |y|`` of the minimum (not ``rtol |y|``):
    tighten ``rtol`` accordingly. When no trial point passes the line search the solve stops as
    ``successful`` if ``pred <= atol + rtol * cost`` (working precision), ``nonfinite`` if the last
    trial point was not finite, and ``singular`` otherwise; ``singular`` also when ``alpha``
    overflows (``J g`` underflows to zero). The statistic ``damping`` is 0 (there is no damping;
    the step length is not reported).

    Attributes:
        rtol: relative tolerance of the convergence test (array; sweepable under ``vmap``).
        atol: absolute tolerance of the convergence test (array).
        max_steps: the most iterations (static). Each iteration is one line search.
        fixed_steps: if true, run exactly ``max_steps`` iterations in a ``lax.scan`` (see
            :class:`GaussNewton`).
        max_backtracks: the most step halvings per line search (static).
    """

    steepest: ClassVar[bool] = True
    max_steps: int = eqx.field(default=1000, static=True)

