"""Crocoddyl 3.2.1 as the peer of the ``oc`` benchmark: the same problems as :mod:`solvers.problems`.

* the unicycle is Crocoddyl's own C++ ``ActionModelUnicycle`` (:func:`unicycle_problem`), which is
  exactly :func:`solvers.problems.unicycle`; :class:`UnicycleModel` is the same model written in
  Python, to measure what a Python action model costs Crocoddyl (the swing-up models below are
  Python too);
* the LQ problem is the C++ ``ActionModelLQR`` with its matrices set (:func:`lqr_problem`): its
  cost is ``0.5 x'Qx + 0.5 u'Ru + x'N u + q'x + r'u`` and its dynamics ``x+ = A x + B u + f``; the
  terminal node (called without ``u``) costs ``0.5 x'Qx + q'x``;
* the pendulum and the cart-pole are Python subclasses of ``crocoddyl.ActionModelAbstract``
  (:class:`PendulumModel`, :class:`CartPoleModel`) with the explicit-Euler dynamics and the
  quadratic cost of :mod:`solvers.problems`, and analytic first derivatives (``Fx, Fu``; the cost
  derivatives are exact, Crocoddyl's DDP solvers use first-order dynamics). Their ``args`` are the
  float64 numpy values of a :class:`solvers.problems.ControlProblem`'s ``args`` dict, so the two
  sides cannot drift apart.

**Bimodal Crocoddyl timings on this machine.** While this module was written (AMD EPYC, 2 cores
shared with other work), ``SolverDDP`` / ``SolverFDDP`` / ``SolverBoxDDP`` on the C++ unicycle
(T = 200) ran either at the usual ~1-2 ms per solve or ~100x slower (~150 ms, ~19 ms per
iteration), with the same iterations, cost and result. The slow solves are CPU time
(``process_time`` equals the wall time, no page faults, few context switches); the mode changes
over time within one process and even between calls of one solver instance, also in a process
that never imported jax; ``OMP_NUM_THREADS=1``, ``ShootingProblem.nthreads = 1`` (this build says
multithreading is not enabled) and fixed glibc malloc thresholds did not remove it. The cause was
not found. The benchmark therefore times single solves one call per sample and reports the
spread (min / median / max) next to the median.

Every function imports Crocoddyl through :func:`load_crocoddyl`, which raises
:class:`benchmarks.peers.PeerUnavailable` when it is missing.
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from . import PeerUnavailable, require

__all__ = [
    "SOLVERS",
    "CrocoddylRun",
    "load_crocoddyl",
    "lqr_problem",
    "make_solver",
    "python_model_class",
    "run_solver",
    "swing_up_problem",
    "unicycle_problem",
]

SOLVERS = ("SolverDDP", "SolverFDDP", "SolverBoxDDP")
_HINT = "pip install crocoddyl==3.2.1"


def load_crocoddyl():
    """The ``crocoddyl`` module, or :class:`PeerUnavailable`."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        croc = require("crocoddyl", _HINT)
    if not hasattr(croc, "ActionModelAbstract"):
        raise PeerUnavailable(f"crocoddyl {getattr(croc, '__version__', '?')} has no ActionModelAbstract")
    return croc


# --- models ------------------------------------------------------------------------------------------
_CLASSES: dict[str, type] = {}


def python_model_class(name: str) -> type:
    """The Python action-model class ``name`` (``"pendulum"``, ``"cart_pole"``, ``"unicycle"``).

    Built on first use (the base class comes from Crocoddyl, which may be absent). Every class is
    constructed as ``cls(args, terminal=False)`` from a dict of float64 numpy arrays laid out as
    :mod:`solvers.problems`' ``args`` (``dt``, ``goal``, ``Q``, ``R``, ``QT`` and the physical
    constants); a terminal model (``terminal=True``) uses ``QT`` and ignores ``u``.
    """
    if name not in _CLASSES:
        _CLASSES.update(_build_classes(load_crocoddyl()))
    return _CLASSES[name]


def _build_classes(croc) -> dict[str, type]:
    class _Quadratic(croc.ActionModelAbstract):
        """Cost ``0.5 (x-g)'diag(W)(x-g) + 0.5 u'diag(R)u`` and Euler dynamics ``x + dt xdot``."""

        nx = 0
        nu_ = 0

        def __init__(self, args: dict[str, Any], terminal: bool = False):
            croc.ActionModelAbstract.__init__(self, croc.StateVector(self.nx), self.nu_, self.nx + self.nu_)
            self.a = {k: np.asarray(v, dtype=np.float64) for k, v in args.items()}
            self.terminal = bool(terminal)
            self.dt = float(self.a["dt"])
            self.goal = self.a["goal"]
            self.W = self.a["QT"] if terminal else self.a["Q"]
            self.Rw = self.a["R"]
            self._Lxx = np.diag(self.W)
            self._Luu = np.diag(self.Rw)

        def xdot(self, x, u):  # [nx]
            raise NotImplementedError

        def jac(self, x, u):  # (d xdot / dx [nx, nx], d xdot / du [nx, nu])
            raise NotImplementedError

        def calc(self, data, x, u=None):
            dx = x - self.goal
            if u is None or self.terminal:
                data.xnext = x
                data.cost = 0.5 * float(dx @ (self.W * dx))
                return
            data.xnext = x + self.dt * self.xdot(x, u)
            data.cost = 0.5 * float(dx @ (self.W * dx) + u @ (self.Rw * u))

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
            self.ml2 = float(a["mass"] * a["length"] ** 2)
            self.mgl = float(a["mass"] * a["gravity"] * a["length"])
            self.b = float(a["damping"])

        def xdot(self, x, u):
            th, om = x
            return np.array([om, (u[0] - self.b * om - self.mgl * np.sin(th)) / self.ml2])

        def jac(self, x, u):
            th = x[0]
            fx = np.array([[0.0, 1.0], [-self.mgl * np.cos(th) / self.ml2, -self.b / self.ml2]])
            fu = np.array([[0.0], [1.0 / self.ml2]])
            return fx, fu

    class CartPoleModel(_Quadratic):
        """:func:`solvers.problems.cart_pole` (Tedrake's cart-pole, ``theta = 0`` hanging down)."""

        nx, nu_ = 4, 1

        def __init__(self, args, terminal=False):
            super().__init__(args, terminal)
            a = self.a
            self.mc, self.mp = float(a["cart_mass"]), float(a["pole_mass"])
            self.l, self.g = float(a["pole_length"]), float(a["gravity"])

        def xdot(self, x, u):
            _, th, v, om = x
            mc, mp, l, g = self.mc, self.mp, self.l, self.g
            s, c = np.sin(th), np.cos(th)
            f = u[0]
            den = mc + mp * s * s
            acc = (f + mp * s * (l * om * om + g * c)) / den
            alpha = (-f * c - mp * l * om * om * c * s - (mc + mp) * g * s) / (l * den)
            return np.array([v, om, acc, alpha])

        def jac(self, x, u):
            _, th, _, om = x
            mc, mp, l, g = self.mc, self.mp, self.l, self.g
            s, c = np.sin(th), np.cos(th)
            f = u[0]
            den = mc + mp * s * s
            dden = 2.0 * mp * s * c
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
            fu = np.array([[0.0], [0.0], [1.0 / den], [-c / (l * den)]])
            return fx, fu

    class UnicycleModel(_Quadratic):
        """Crocoddyl's ``ActionModelUnicycle`` in Python (as :func:`solvers.problems.unicycle`)."""

        nx, nu_ = 3, 2

        def xdot(self, x, u):
            return np.array([u[0] * np.cos(x[2]), u[0] * np.sin(x[2]), u[1]])

        def jac(self, x, u):
            c, s = np.cos(x[2]), np.sin(x[2])
            fx = np.array([[0.0, 0.0, -s * u[0]], [0.0, 0.0, c * u[0]], [0.0, 0.0, 0.0]])
            fu = np.array([[c, 0.0], [s, 0.0], [0.0, 1.0]])
            return fx, fu

    return {"pendulum": PendulumModel, "cart_pole": CartPoleModel, "unicycle": UnicycleModel}


def _numpy_args(args: dict[str, Any]) -> dict[str, np.ndarray]:
    return {k: np.asarray(v, dtype=np.float64) for k, v in args.items()}


def _set_bounds(model, bounds) -> None:
    if bounds is not None:
        model.u_lb = np.asarray(bounds[0], dtype=np.float64)
        model.u_ub = np.asarray(bounds[1], dtype=np.float64)


# --- problems ----------------------------------------------------------------------------------------
def _shooting(croc, x0, running: list, terminal):
    """``ShootingProblem(x0, running, terminal)``, ``x0`` as float64."""
    return croc.ShootingProblem(np.asarray(x0, dtype=np.float64), running, terminal)


def unicycle_problem(
    T: int, x0: Sequence[float], *, state_weight: float, control_weight: float, dt: float,
    bounds: tuple[np.ndarray, np.ndarray] | None = None, python_model: bool = False,
):
    """A ``ShootingProblem`` of ``T`` unicycle knots (C++ ``ActionModelUnicycle``, or the Python
    :class:`UnicycleModel` with ``python_model=True``); ``bounds`` sets ``u_lb``/``u_ub`` (BoxDDP)."""
    croc = load_crocoddyl()
    if python_model:
        args = dict(dt=dt, goal=np.zeros(3), Q=np.full(3, state_weight**2), R=np.full(2, control_weight**2),
                    QT=np.full(3, state_weight**2))
        cls = python_model_class("unicycle")
        running, terminal = cls(args), cls(args, terminal=True)
    else:
        running, terminal = croc.ActionModelUnicycle(), croc.ActionModelUnicycle()
        for mdl in (running, terminal):
            mdl.costWeights = np.array([state_weight, control_weight], dtype=np.float64)
            mdl.dt = float(dt)
    _set_bounds(running, bounds)
    return _shooting(croc, x0, [running] * T, terminal)


def lqr_problem(A, B, Q, R, N, f, q, r, x0, T: int, bounds=None):
    """A time-invariant LQ ``ShootingProblem`` of ``T`` knots with ``ActionModelLQR`` nodes.

    Cost per knot ``0.5 x'Qx + 0.5 u'Ru + x'N u + q'x + r'u`` (``N [n, m]``: jaxanim's ``S`` is
    ``N'``), dynamics ``x+ = A x + B u + f``, terminal ``0.5 x'Qx + q'x``. Crocoddyl requires
    ``[[Q, N], [N', R]]`` positive semi-definite.
    """
    croc = load_crocoddyl()
    arr = lambda z: np.ascontiguousarray(np.asarray(z, dtype=np.float64))  # noqa: E731
    running = croc.ActionModelLQR(arr(A), arr(B), arr(Q), arr(R), arr(N), arr(f), arr(q), arr(r))
    terminal = croc.ActionModelLQR(arr(A), arr(B), arr(Q), arr(R), arr(N), arr(f), arr(q), arr(r))
    _set_bounds(running, bounds)
    return _shooting(croc, arr(x0), [running] * T, terminal)


def swing_up_problem(name: str, args: dict[str, Any], x0, T: int):
    """A ``ShootingProblem`` of the Python model ``name`` (``"pendulum"``/``"cart_pole"``) with the
    float64 values of a :class:`solvers.problems.ControlProblem`'s ``args``."""
    croc = load_crocoddyl()
    cls = python_model_class(name)
    a = _numpy_args(args)
    return _shooting(croc, x0, [cls(a)] * T, cls(a, terminal=True))


# --- solving ------------------------------------------------------------------------------------------
@dataclasses.dataclass
class CrocoddylRun:
    """One Crocoddyl solve: ``xs [T+1, n]``, ``us [T, m]``, the final cost, iterations, whether
    ``solve`` returned ``True`` (converged), and the wall-clock seconds of ``solve``."""

    xs: np.ndarray
    us: np.ndarray
    cost: float
    iterations: int
    converged: bool
    seconds: float


def make_solver(problem, solver: str = "SolverDDP", th_stop: float | None = None):
    """``crocoddyl.<solver>(problem)``; ``th_stop`` sets the stopping threshold (default 1e-9)."""
    croc = load_crocoddyl()
    s = getattr(croc, solver)(problem)
    if th_stop is not None:
        s.th_stop = float(th_stop)
    return s


def run_solver(problem, solver: str = "SolverDDP", *, us_init=None, maxiter: int = 100,
               th_stop: float | None = None) -> CrocoddylRun:
    """Build ``solver`` on ``problem`` and solve from the rollout of ``us_init`` (default zeros,
    ``is_feasible=True``); ``seconds`` times ``solve`` alone."""
    s = make_solver(problem, solver, th_stop)
    T, m = problem.T, problem.runningModels[0].nu
    us0 = [np.zeros(m)] * T if us_init is None else [np.asarray(u, dtype=np.float64) for u in us_init]
    xs0 = problem.rollout(us0)
    t0 = time.perf_counter()
    ok = s.solve(xs0, us0, maxiter, True, 1e-9)
    dt = time.perf_counter() - t0
    return CrocoddylRun(np.array(s.xs), np.array(s.us), float(s.cost), int(s.iter), bool(ok), dt)
