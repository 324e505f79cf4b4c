"""Crocoddyl 3.2.1 as the peer of the ``oc`` benchmark: C++ ``ActionModelUnicycle`` / ``ActionModelLQR`` and Python
action models of :mod:`solvers.problems` (with all that Crocoddyl's DDP solvers use: see :func:`python_model_class`)."""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

import numpy as np

from . import PeerUnavailable, require

__all__ = ["load_crocoddyl", "lqr_problem", "python_model_class", "python_problem", "unicycle_problem"]


def load_crocoddyl():
    """The ``crocoddyl`` module, or :class:`PeerUnavailable`."""
    croc = require("crocoddyl", "pip install crocoddyl==3.2.1", quiet=True)
    if not hasattr(croc, "ActionModelAbstract"):
        raise PeerUnavailable(f"crocoddyl {getattr(croc, '__version__', '?')} has no ActionModelAbstract")
    return croc


def python_model_class(name: str) -> type:
    """The Python action-model class ``name`` (``"pendulum"``, ``"cart_pole"``, ``"unicycle"``): explicit Euler,
    quadratic cost, exact cost derivatives and first derivatives ``Fx, Fu`` of the dynamics; ``cls(args,
    terminal=False)`` takes :mod:`solvers.problems`' ``args`` (a terminal model uses ``QT``, no ``u``)."""
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

    class PendulumModel(_Quadratic):
        """:func:`solvers.problems.pendulum`: ``m l^2 theta'' = u - b theta' - m g l sin(theta)``."""

        nx, nu_ = 2, 1

        def __init__(self, args, terminal=False):
            super().__init__(args, terminal)
            a = self.a
            self.ml2, self.mgl, self.b = (float(a["mass"] * a["length"] ** 2),
                                          float(a["mass"] * a["gravity"] * a["length"]), float(a["damping"]))

        def xdot(self, x, u):
            th, om = x
            return np.array([om, (u[0] - self.b * om - self.mgl * np.sin(th)) / self.ml2])

        def jac(self, x, u):
            fx = np.array([[0.0, 1.0], [-self.mgl * np.cos(x[0]) / self.ml2, -self.b / self.ml2]])
            return fx, np.array([[0.0], [1.0 / self.ml2]])

    class CartPoleModel(_Quadratic):
        """:func:`solvers.problems.cart_pole` (Tedrake's cart-pole, ``theta = 0`` hanging down)."""

        nx, nu_ = 4, 1

        def __init__(self, args, terminal=False):
            super().__init__(args, terminal)
            self.mc, self.mp, self.l, self.g = (float(self.a[k]) for k in ("cart_mass", "pole_mass", "pole_length",
                                                                            "gravity"))

        def xdot(self, x, u):
            _, th, v, om = x
            mc, mp, l, g = self.mc, self.mp, self.l, self.g
            s, c, f = np.sin(th), np.cos(th), u[0]
            den = mc + mp * s * s
            return np.array([v, om, (f + mp * s * (l * om * om + g * c)) / den,
                             (-f * c - mp * l * om * om * c * s - (mc + mp) * g * s) / (l * den)])

        def jac(self, x, u):
            _, th, _, om = x
            mc, mp, l, g = self.mc, self.mp, self.l, self.g
            s, c, f = np.sin(th), np.cos(th), u[0]
            den, dden = mc + mp * s * s, 2.0 * mp * s * c
            na = f + mp * s * (l * om * om + g * c)
            na_th = mp * (c * (l * om * om + g * c) - g * s * s)
            na_om = 2.0 * mp * s * l * om
            nb = -f * c - mp * l * om * om * c * s - (mc + mp) * g * s
            nb_th = f * s - mp * l * om * om * (c * c - s * s) - (mc + mp) * g * c
            nb_om = -2.0 * mp * l * om * c * s
            fx = np.zeros((4, 4))
            fx[0, 2] = fx[1, 3] = 1.0
            fx[2, 1] = (na_th * den - na * dden) / (den * den)
            fx[2, 3] = na_om / den
            fx[3, 1] = (nb_th * den - nb * dden) / (l * den * den)
            fx[3, 3] = nb_om / (l * den)
            return fx, np.array([[0.0], [0.0], [1.0 / den], [-c / (l * den)]])

    class UnicycleModel(_Quadratic):
        """Crocoddyl's ``ActionModelUnicycle`` in Python (as :func:`solvers.problems.unicycle`)."""

        nx, nu_ = 3, 2

        def xdot(self, x, u):
            return np.array([u[0] * np.cos(x[2]), u[0] * np.sin(x[2]), u[1]])

        def jac(self, x, u):
            c, s = np.cos(x[2]), np.sin(x[2])
            return (np.array([[0.0, 0.0, -s * u[0]], [0.0, 0.0, c * u[0]], [0.0, 0.0, 0.0]]),
                    np.array([[c, 0.0], [s, 0.0], [0.0, 1.0]]))

    return {"pendulum": PendulumModel, "cart_pole": CartPoleModel, "unicycle": UnicycleModel}


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
