"""Crocoddyl 3.2.1 as the peer of the ``oc`` benchmark: C++ ``ActionModelUnicycle`` / ``ActionModelLQR``, the swing-ups
as Pinocchio models under Crocoddyl's C++ free forward dynamics (:func:`swing_problem`), and the unicycle as a Python
action model (:func:`python_model_class`, to show what a Python model costs)."""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

import numpy as np

from . import PeerUnavailable, require

__all__ = ["load_crocoddyl", "lqr_problem", "pinocchio_model", "python_model_class", "python_problem", "swing_problem",
           "unicycle_problem"]


def load_crocoddyl():
    """The ``crocoddyl`` module, or :class:`PeerUnavailable`."""
    croc = require("crocoddyl", "pip install crocoddyl==3.2.1", quiet=True)
    if not hasattr(croc, "ActionModelAbstract"):
        raise PeerUnavailable(f"crocoddyl {getattr(croc, '__version__', '?')} has no ActionModelAbstract")
    return croc


def python_model_class(name: str) -> type:
    """The Python action-model class ``name`` (only ``"unicycle"``: Crocoddyl's unicycle): explicit Euler,
    quadratic cost, exact cost derivatives and first derivatives ``Fx, Fu`` of the dynamics; ``cls(args,
    terminal=False)`` takes :mod:`solvers.problems`' ``args`` (a terminal model uses ``QT``, no ``u``). Once one is
    built, Crocoddyl runs every later ``ShootingProblem`` of the process on one thread."""
    return _classes()[name]


@functools.cache
def _classes() -> dict[str, type]:
    croc = load_crocoddyl()

    class _Quadratic(croc.ActionModelAbstract):
        """Cost ``0.5 (x-g)'diag(W)(x-g) + 0.5 u'diag(R)u``, dynamics ``x + dt xdot(x, u)`` (``jac``: its
        derivatives ``(d xdot / dx, d xdot / du)``), both defined by the subclasses."""

        nx, nu_ = 0, 0

        def __init__(self, args: dict[str, Any], terminal: bool = False):
            croc.ActionModelAbstract.__init__(self, croc.StateVector(self.nx), self.nu_, self.nx + self.nu_)
            self.a = a = {k: np.asarray(v, dtype=np.float64) for k, v in args.items()}
            self.terminal, self.dt, self.goal = bool(terminal), float(a["dt"]), a["goal"]
            self.W, self.Rw = (a["QT"] if terminal else a["Q"]), a["R"]
            self._Lxx, self._Luu = np.diag(self.W), np.diag(self.Rw)

        def calc(self, data, x, u=None):
            dx, running = x - self.goal, u is not None and not self.terminal
            data.xnext = x + self.dt * self.xdot(x, u) if running else x
            data.cost = 0.5 * float(dx @ (self.W * dx) + (u @ (self.Rw * u) if running else 0.0))

        def calcDiff(self, data, x, u=None):
            dx = x - self.goal
            data.Lx = self.W * dx
            data.Lxx = self._Lxx
            if u is None or self.terminal:
                return
            fx, fu = self.jac(x, u)
            data.Fx = np.eye(self.nx) + self.dt * fx
            data.Fu = self.dt * fu
            data.Lu = self.Rw * u
            data.Luu = self._Luu

    class UnicycleModel(_Quadratic):
        """Crocoddyl's ``ActionModelUnicycle`` in Python (as :func:`solvers.problems.unicycle`)."""

        nx, nu_ = 3, 2

        def xdot(self, x, u):
            return np.array([u[0] * np.cos(x[2]), u[0] * np.sin(x[2]), u[1]])

        def jac(self, x, u):
            c, s = np.cos(x[2]), np.sin(x[2])
            return (np.array([[0.0, 0.0, -s * u[0]], [0.0, 0.0, c * u[0]], [0.0, 0.0, 0.0]]),
                    np.array([[c, 0.0], [s, 0.0], [0.0, 1.0]]))

    return {"unicycle": UnicycleModel}


def _shooting(croc, x0, running, terminal, T: int, bounds=None):
    """``ShootingProblem(x0, [running] * T, terminal)``; ``bounds`` sets the running model's ``u_lb``/``u_ub``."""
    if bounds is not None:
        running.u_lb, running.u_ub = (np.asarray(b, dtype=np.float64) for b in bounds)
    return croc.ShootingProblem(np.asarray(x0, dtype=np.float64), [running] * T, terminal)


def unicycle_problem(T: int, x0: Sequence[float], *, state_weight: float, control_weight: float, dt: float,
                     bounds: tuple[np.ndarray, np.ndarray] | None = None):
    """A ``ShootingProblem`` of ``T`` C++ ``ActionModelUnicycle`` knots; ``bounds`` sets ``u_lb``/``u_ub`` (BoxDDP)."""
    croc = load_crocoddyl()
    running, terminal = croc.ActionModelUnicycle(), croc.ActionModelUnicycle()
    for mdl in (running, terminal):
        mdl.costWeights = np.array([state_weight, control_weight], dtype=np.float64)
        mdl.dt = float(dt)
    return _shooting(croc, x0, running, terminal, T, bounds)


def lqr_problem(A, B, Q, R, N, f, q, r, x0, T: int):
    """A time-invariant LQ ``ShootingProblem`` of ``T`` ``ActionModelLQR`` knots (``N [n, m]``: jaxanim's
    ``S`` is ``N'``; Crocoddyl requires ``[[Q, N], [N', R]]`` positive semi-definite)."""
    croc = load_crocoddyl()
    arr = lambda z: np.ascontiguousarray(np.asarray(z, dtype=np.float64))  # noqa: E731
    return _shooting(croc, x0, *(croc.ActionModelLQR(*(arr(z) for z in (A, B, Q, R, N, f, q, r))) for _ in range(2)), T)


def python_problem(name: str, args: dict[str, Any], x0, T: int):
    """A ``ShootingProblem`` of ``T`` knots of the Python model ``name`` with a ``ControlProblem``'s ``args``."""
    cls = python_model_class(name)  # its models take the args as float64 numpy
    return _shooting(load_crocoddyl(), x0, cls(args), cls(args, terminal=True), T)


def pinocchio_model(name: str, args: dict[str, Any]):
    """The ``pinocchio.Model`` of :func:`solvers.problems.pendulum` (``"pendulum"``: a point mass ``mass`` at
    ``length`` below a revolute x joint) or :func:`~solvers.problems.cart_pole` (``"cart_pole"``: a point-mass cart
    on a prismatic y joint carrying a point-mass pole of ``pole_length`` on a revolute x joint), ``theta = 0``
    hanging down (then ``+theta`` swings the mass to ``+y``, as ``+x`` in the problems), gravity ``-gravity e_z``.

    Raises ``ValueError`` for a damped pendulum: Pinocchio's ABA and Crocoddyl's free forward dynamics have no
    viscous joint damping (``model.damping`` is not used by ``pinocchio.aba``).
    """
    pin = require("pinocchio", "pip install pin==4.0.0")
    a = {k: np.asarray(v, dtype=np.float64) for k, v in args.items()}
    if name == "pendulum" and float(a["damping"]) != 0.0:
        raise ValueError(f"damping: Crocoddyl's free forward dynamics has none; expected 0, got {float(a['damping'])}")
    model = pin.Model()
    model.gravity = pin.Motion(np.array([0.0, 0.0, -float(a["gravity"])]), np.zeros(3))

    def body(parent: int, joint, label: str, mass, drop) -> int:  # a point mass ``drop`` below the joint
        j = model.addJoint(parent, joint, pin.SE3.Identity(), label)
        model.appendBodyToJoint(j, pin.Inertia(float(mass), np.array([0.0, 0.0, -float(drop)]), np.zeros((3, 3))),
                                pin.SE3.Identity())
        return j

    if name == "pendulum":
        body(0, pin.JointModelRX(), "pole", a["mass"], a["length"])
    elif name == "cart_pole":
        body(body(0, pin.JointModelPY(), "cart", a["cart_mass"], 0.0), pin.JointModelRX(), "pole", a["pole_mass"],
             a["pole_length"])
    else:
        raise ValueError(f"name: expected 'pendulum' or 'cart_pole', got {name!r}")
    return model


def swing_problem(name: str, args: dict[str, Any], x0, T: int):
    """A ``ShootingProblem`` of ``T`` C++ knots for a swing-up of :func:`pinocchio_model` with a ``ControlProblem``'s
    ``args``: ``DifferentialActionModelFreeFwdDynamics`` (ABA, ``ActuationModelFull``) under
    ``IntegratedActionModelEuler`` (semi-implicit: ``v+ = v + dt a``, ``q+ = q + dt v+``), cost ``CostModelSum`` of
    ``ResidualModelState`` (to ``goal``) and ``ResidualModelControl`` with ``ActivationModelWeightedQuad`` weights
    ``Q / dt`` and ``R / dt`` (the integrator multiplies by ``dt``), terminal ``QT``.

    The cart-pole's pole joint gets a torque too (Crocoddyl's C++ actuation models leave only a *first* joint
    unactuated): it is pinned to 0 by ``u_lb = u_ub = 0``, which the box solvers (``SolverBoxDDP`` / ``BoxFDDP``)
    enforce exactly, so ``u = [force, 0]``.
    """
    croc, pin_model = load_crocoddyl(), pinocchio_model(name, args)
    a = {k: np.asarray(v, dtype=np.float64) for k, v in args.items()}
    state = croc.StateMultibody(pin_model)
    actuation = croc.ActuationModelFull(state)
    nu, dt = actuation.nu, float(a["dt"])

    def differential(state_weights, control_weight=None):
        costs = croc.CostModelSum(state, nu)
        costs.addCost("state", croc.CostModelResidual(state, croc.ActivationModelWeightedQuad(state_weights),
                                                      croc.ResidualModelState(state, a["goal"], nu)), 1.0)
        if control_weight is not None:
            costs.addCost("control", croc.CostModelResidual(state, croc.ActivationModelWeightedQuad(
                np.full(nu, control_weight)), croc.ResidualModelControl(state, nu)), 1.0)
        return croc.DifferentialActionModelFreeFwdDynamics(state, actuation, costs)

    running = croc.IntegratedActionModelEuler(differential(a["Q"] / dt, float(a["R"][0]) / dt), dt)
    terminal = croc.IntegratedActionModelEuler(differential(a["QT"]), 0.0)
    pinned = (np.r_[-np.inf, 0.0], np.r_[np.inf, 0.0]) if name == "cart_pole" else None
    return _shooting(croc, x0, running, terminal, T, pinned)
