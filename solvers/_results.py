"""Result codes and the solution container shared by the solvers.

``RESULTS`` is an :class:`equinox.Enumeration` whose members *are* the user-facing messages (the
lineax / optimistix convention): ``RESULTS[sol.result]`` gives the advice for a failed solve, and
``sol.result == RESULTS.successful`` is a per-element boolean under ``jax.vmap``.
"""

from __future__ import annotations

import equinox as eqx
from jaxtyping import Array, Float


class RESULTS(eqx.Enumeration):
    """How a solve ended. Each member's value is the message shown to the user."""

    successful = ""
    max_steps_reached = (
        "The maximum number of steps was reached before the convergence test held: increase "
        "`max_steps`, loosen `rtol`/`atol`, or start closer to a minimum."
    )
    nonfinite = (
        "A non-finite value (NaN or inf) appeared in the residual or its Jacobian and could not be "
        "stepped around; the returned value is the last finite iterate. Check `y0`, `args` and "
        "that `fn`/`jac` are defined near the iterates."
    )
    singular = (
        "The normal equations are singular or too ill-conditioned to give a descent step: use "
        "LevenbergMarquardt (damping), add regularization residuals, or remove redundant "
        "variables."
    )
    not_positive_definite = (
        "The control Hessian Q_uu = R_t + B_t^T P_{t+1} B_t of the LQ subproblem is not positive "
        "definite at some time step t, or a non-finite value (NaN or inf) appeared, so there is no "
        "unique minimizer over the controls: make R_t positive definite, regularize (add mu * I to "
        "R_t), and check that the inputs are finite."
    )
    no_descent = (
        "No acceptable step was found: the regularization of the control Hessian Q_uu reached its "
        "maximum while the backward pass kept failing or the line search rejected every step "
        "size. Check that the cost is bounded below and that `dynamics`/`cost` are smooth and "
        "finite near the trajectory, or start from a better `us_init`."
    )
    no_stabilising_solution = (
        "No stabilizing solution of the algebraic Riccati equation was found: (A, B) is not "
        "stabilizable, an unstable mode is not seen by the cost (Q, after removing the cross term "
        "S, must weight every unstable mode), R is not positive definite, or the inputs are not "
        "finite. Check rank [A - lambda I, B] = n for every unstable eigenvalue lambda of A."
    )


class Solution(eqx.Module):
    """The result of a least-squares solve.

    Attributes:
        value: ``[n]`` the solution: the final iterate, or the last finite iterate when a
            non-finite value appeared (``result == RESULTS.nonfinite``). It satisfies the bounds
            exactly when bounds were given.
        result: a :class:`RESULTS` code; per element under ``jax.vmap``.
        stats: scalars and histories, all arrays:

            - ``num_steps`` (int): iterations performed (Levenberg-Marquardt counts rejected
              trial steps too; Gauss-Newton counts line searches, each one iteration).
            - ``cost``: ``0.5 * |r(value)|^2`` (``inf`` if it is not finite).
            - ``grad_norm``: ``|J^T r|_inf`` at ``value``, over the variables that are not held
              at an active bound (the projected gradient; without bounds, all of them).
            - ``step_norm``: ``|s|_inf`` of the last step tried.
            - ``damping``: the Levenberg-Marquardt damping ``lambda`` at the end (0 for
              Gauss-Newton).
            - ``cost_history``: ``[max_steps + 1]``; entry ``k`` is the cost after ``k``
              iterations (entry 0 is the initial cost), padded with the final cost after the
              last iteration.
            - ``stopped_early`` (bool): the user's ``stop`` ended the solve before the solver's own
              criterion held, so ``value`` is not a minimizer: its derivative is NaN (see
              :func:`solvers.least_squares`).
    """

    value: Float[Array, " n"]
    result: RESULTS
    stats: dict[str, Array]
