r"""A library of optimal-control test problems for :func:`solvers.ilqr`, :func:`solvers.ddp` and
:func:`solvers.lqr`.

Every nonlinear problem is a :class:`ControlProblem`: module-level callbacks (so repeated solves
reuse one compilation) and arrays (``x0``, ``us_init`` and the ``args`` dict of physical constants,
cost weights and the goal), so ``jax.vmap`` sweeps over initial states, masses or weights without
recompiling. All use explicit (forward) Euler, ``x_{t+1} = x_t + dt * xdot(x_t, u_t)`` (the
double integrator and the unicycle are exact discretizations), and the quadratic cost

.. math::
    \ell(x, u) = \tfrac12 (x - g)^\top \mathrm{diag}(Q) (x - g) + \tfrac12 u^\top \mathrm{diag}(R) u,
    \qquad \ell_T(x) = \tfrac12 (x - g)^\top \mathrm{diag}(Q_T) (x - g),

per step (not multiplied by ``dt``), with ``g`` the goal state.

=================== ======= ============================================ =====================
problem             n, m    state ``x``                                  goal
=================== ======= ============================================ =====================
double_integrator   2d, d   positions, velocities                        0
pendulum            2, 1    angle (0 hanging down), angular velocity     ``[pi, 0]``
cart_pole           4, 1    cart position, pole angle (0 down), rates    ``[0, pi, 0, 0]``
acrobot             4, 1    shoulder, elbow angle (0 down), rates        ``[pi, 0, 0, 0]``
unicycle            3, 2    x, y, heading; controls speed, turn rate     0
=================== ======= ============================================ =====================

:func:`pd_servo_tracking` is the course notes' linear-quadratic tracking problem (a mass driven by a
PD servo whose target is the control, tracking ``sin t``; notes eq. 7.7 / 8.9) as an
:class:`LQProblem`, solved exactly by one call of :func:`solvers.lqr`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._linalg import dot, matmul
from .ilqr import TrajectorySolution, ddp, ilqr
from .lqr import LQRSolution, lqr

__all__ = [
    "ControlProblem",
    "LQProblem",
    "acrobot",
    "cart_pole",
    "double_integrator",
    "pd_servo_tracking",
    "pendulum",
    "unicycle",
]

_METHODS = {"ilqr": ilqr, "ddp": ddp}


class ControlProblem(eqx.Module):
    """A discrete-time optimal-control problem: callbacks plus the data they read.

    Attributes:
        name: a short label.
        dynamics: ``dynamics(x, u, t, args) -> x_next`` (static; a module-level function).
        cost: ``cost(x, u, t, args) -> scalar`` (static).
        terminal_cost: ``terminal_cost(x, args) -> scalar`` (static).
        x0: ``[n]`` the initial state.
        us_init: ``[T, m]`` the initial controls (zeros unless given).
        args: dict of arrays read by the callbacks (``dt``, physical constants, ``goal``, the
            diagonal weights ``Q [n]``, ``R [m]``, ``QT [n]``).
        bounds: ``(u_min, u_max)`` each ``[m]``, or ``None`` (unbounded).
    """

    name: str = eqx.field(static=True)
    dynamics: Callable = eqx.field(static=True)
    cost: Callable = eqx.field(static=True)
    terminal_cost: Callable = eqx.field(static=True)
    x0: Float[Array, " n"]
    us_init: Float[Array, "T m"]
    args: dict[str, Array]
    bounds: tuple[Float[Array, " m"], Float[Array, " m"]] | None = None

    @property
    def goal(self) -> Float[Array, " n"]:
        return self.args["goal"]

    @property
    def horizon(self) -> int:
        return self.us_init.shape[0]

    def solve(
        self,
        method: str = "ilqr",
        *,
        x0: Float[ArrayLike, " n"] | None = None,
        us_init: Float[ArrayLike, "T m"] | None = None,
        bounded: bool = True,
        **kwargs: Any,
    ) -> TrajectorySolution:
        """Solve with ``method`` (``"ilqr"`` or ``"ddp"``) from ``x0`` (default ``self.x0``).

        ``bounded=False`` ignores ``self.bounds``; other keyword arguments (``max_steps``,
        ``fixed_steps``, ``rtol``, ``atol``, ``throw``) go to the solver.
        """
        if method not in _METHODS:
            raise ValueError(f"method: expected one of {sorted(_METHODS)}, got {method!r}")
        return _METHODS[method](
            self.dynamics,
            self.cost,
            self.x0 if x0 is None else x0,
            self.us_init if us_init is None else us_init,
            terminal_cost=self.terminal_cost,
            args=self.args,
            bounds=self.bounds if bounded else None,
            **kwargs,
        )

    def rollout(
        self, us: Float[ArrayLike, "T m"], x0: Float[ArrayLike, " n"] | None = None
    ) -> tuple[Float[Array, "T+1 n"], Float[Array, ""]]:
        """States ``[T+1, n]`` and total cost of the controls ``us`` from ``x0`` (no clipping)."""
        return _rollout(self, jnp.asarray(self.x0 if x0 is None else x0), jnp.asarray(us))


@eqx.filter_jit
def _rollout(problem: ControlProblem, x0, us):
    def step(x, ut):
        u, t = ut
        return problem.dynamics(x, u, t, problem.args), (x, problem.cost(x, u, t, problem.args))

    xT, (xs, costs) = jax.lax.scan(step, x0, (us, jnp.arange(us.shape[0])))
    return jnp.concatenate([xs, xT[None]]), jnp.sum(costs) + problem.terminal_cost(xT, problem.args)


# --------------------------------------------------------------------------------------------
# Shared cost and construction helpers.
# --------------------------------------------------------------------------------------------


def _quadratic_cost(x, u, t, a):
    dx = x - a["goal"]
    return 0.5 * (dot(dx, a["Q"] * dx) + dot(u, a["R"] * u))


def _quadratic_terminal(x, a):
    dx = x - a["goal"]
    return 0.5 * dot(dx, a["QT"] * dx)


def _vector(name: str, value, size: int, dtype) -> Array:
    v = jnp.asarray(value, dtype)
    if v.shape not in ((), (size,)):
        raise ValueError(f"{name}: expected a scalar or shape ({size},), got {v.shape}")
    return jnp.broadcast_to(v, (size,))


def _positive(name: str, value) -> None:
    if not np.all(np.asarray(value) > 0):
        raise ValueError(f"{name}: expected > 0, got {value!r}")


def _make(
    name, dynamics, n, m, *, T, dt, x0, goal, Q, R, QT, us_init, u_max, dtype, **constants
) -> ControlProblem:
    if not isinstance(T, (int, np.integer)) or isinstance(T, bool) or T < 1:
        raise ValueError(f"T: expected an int >= 1, got {T!r}")
    _positive("dt", dt)
    for key, value in constants.items():
        if key == "damping":
            if not np.all(np.asarray(value) >= 0):
                raise ValueError(f"damping: expected >= 0, got {value!r}")
        else:
            _positive(key, value)
    x0 = _vector("x0", x0, n, dtype)
    us = jnp.zeros((T, m), dtype) if us_init is None else jnp.asarray(us_init, dtype)
    if us.shape != (T, m):
        raise ValueError(f"us_init: expected shape (T, m) = ({T}, {m}), got {us.shape}")
    args = dict(
        dt=jnp.asarray(dt, dtype),
        goal=_vector("goal", goal, n, dtype),
        Q=_vector("Q", Q, n, dtype),
        R=_vector("R", R, m, dtype),
        QT=_vector("QT", QT, n, dtype),
        **{k: jnp.asarray(v, dtype) for k, v in constants.items()},
    )
    bounds = None
    if u_max is not None:
        hi = _vector("u_max", u_max, m, dtype)
        _positive("u_max", hi)
        bounds = (-hi, hi)
    return ControlProblem(
        name=name,
        dynamics=dynamics,
        cost=_quadratic_cost,
        terminal_cost=_quadratic_terminal,
        x0=x0,
        us_init=us,
        args=args,
        bounds=bounds,
    )


# --------------------------------------------------------------------------------------------
# Problems.
# --------------------------------------------------------------------------------------------


def _double_integrator_dynamics(x, u, t, a):
    d = u.shape[0]
    p, v = x[:d], x[d:]
    dt = a["dt"]
    return jnp.concatenate([p + dt * v + 0.5 * dt**2 * u, v + dt * u])


def double_integrator(
    *,
    dim: int = 1,
    T: int = 50,
    dt: float = 0.1,
    x0: Float[ArrayLike, " n"] = 1.0,
    Q: Float[ArrayLike, " n"] = 1.0,
    R: Float[ArrayLike, " m"] = 0.1,
    QT: Float[ArrayLike, " n"] = 100.0,
    us_init: Float[ArrayLike, "T m"] | None = None,
    u_max: Float[ArrayLike, " m"] | None = None,
    dtype: Any = None,
) -> ControlProblem:
    """A point mass in ``dim`` dimensions driven by its acceleration, brought to rest at 0.

    ``x = [p (dim), v (dim)]``, ``u = a``; the exact zero-order-hold discretization
    ``p+ = p + dt v + dt^2 a / 2``, ``v+ = v + dt a``. Linear-quadratic: iLQR and DDP solve it in one
    iteration. Default ``x0`` is 1 in every coordinate.
    """
    if not isinstance(dim, (int, np.integer)) or dim < 1:
        raise ValueError(f"dim: expected an int >= 1, got {dim!r}")
    return _make(
        "double_integrator", _double_integrator_dynamics, 2 * dim, dim, T=T, dt=dt, x0=x0, goal=0.0, Q=Q, R=R,
        QT=QT, us_init=us_init, u_max=u_max, dtype=_dtype(dtype),
    )


def _pendulum_dynamics(x, u, t, a):
    theta, omega = x
    ml2 = a["mass"] * a["length"] ** 2
    alpha = (u[0] - a["damping"] * omega - a["mass"] * a["gravity"] * a["length"] * jnp.sin(theta)) / ml2
    return x + a["dt"] * jnp.stack([omega, alpha])


def pendulum(
    *,
    T: int = 100,
    dt: float = 0.05,
    x0: Float[ArrayLike, " 2"] = (0.0, 0.0),
    mass: float = 1.0,
    length: float = 1.0,
    gravity: float = 9.81,
    damping: float = 0.1,
    Q: Float[ArrayLike, " 2"] = (0.1, 0.01),
    R: float = 0.01,
    QT: Float[ArrayLike, " 2"] = (100.0, 10.0),
    us_init: Float[ArrayLike, "T 1"] | None = None,
    u_max: float | None = None,
    dtype: Any = None,
) -> ControlProblem:
    """Pendulum swing-up: ``m l^2 theta'' = u - b theta' - m g l sin(theta)``, ``theta = 0`` hanging
    down, goal ``[pi, 0]`` (upright, at rest), viscous ``damping`` ``b >= 0``.

    The torque ``u`` needed to hold the pendulum horizontal is ``m g l`` (9.81 N m by default):
    with ``u_max`` below it the solution must pump energy (box-DDP).
    """
    return _make(
        "pendulum", _pendulum_dynamics, 2, 1, T=T, dt=dt, x0=x0, goal=(np.pi, 0.0), Q=Q, R=R, QT=QT,
        us_init=us_init, u_max=u_max, dtype=_dtype(dtype), mass=mass, length=length, gravity=gravity, damping=damping,
    )


def _cart_pole_dynamics(x, u, t, a):
    _, theta, v, omega = x
    mc, mp, l, g = a["cart_mass"], a["pole_mass"], a["pole_length"], a["gravity"]
    s, c = jnp.sin(theta), jnp.cos(theta)
    f = u[0]
    den = mc + mp * s**2
    acc = (f + mp * s * (l * omega**2 + g * c)) / den
    alpha = (-f * c - mp * l * omega**2 * c * s - (mc + mp) * g * s) / (l * den)
    return x + a["dt"] * jnp.stack([v, omega, acc, alpha])


def cart_pole(
    *,
    T: int = 100,
    dt: float = 0.05,
    x0: Float[ArrayLike, " 4"] = (0.0, 0.0, 0.0, 0.0),
    cart_mass: float = 1.0,
    pole_mass: float = 0.3,
    pole_length: float = 0.5,
    gravity: float = 9.81,
    Q: Float[ArrayLike, " 4"] = (0.1, 0.1, 0.01, 0.01),
    R: float = 0.01,
    QT: Float[ArrayLike, " 4"] = (100.0, 100.0, 10.0, 10.0),
    us_init: Float[ArrayLike, "T 1"] | None = None,
    u_max: float | None = None,
    dtype: Any = None,
) -> ControlProblem:
    """Cart-pole swing-up (Tedrake, *Underactuated Robotics*, ch. 3; point-mass pole of length
    ``l``): ``x = [p, theta, p', theta']`` with ``theta = 0`` hanging down, force ``u`` on the cart,

    ``p''     = (u + m_p sin(theta) (l theta'^2 + g cos(theta))) / (m_c + m_p sin^2(theta))``,
    ``theta'' = (-u cos(theta) - m_p l theta'^2 cos(theta) sin(theta) - (m_c + m_p) g sin(theta))
    / (l (m_c + m_p sin^2(theta)))``; goal ``[0, pi, 0, 0]``.
    """
    return _make(
        "cart_pole", _cart_pole_dynamics, 4, 1, T=T, dt=dt, x0=x0, goal=(0.0, np.pi, 0.0, 0.0), Q=Q, R=R, QT=QT,
        us_init=us_init, u_max=u_max, dtype=_dtype(dtype), cart_mass=cart_mass, pole_mass=pole_mass,
        pole_length=pole_length, gravity=gravity,
    )


def _acrobot_dynamics(x, u, t, a):
    th1, th2, dth1, dth2 = x
    m1, m2, l1, lc1, lc2, I1, I2, g = (a[k] for k in ("m1", "m2", "l1", "lc1", "lc2", "I1", "I2", "gravity"))
    d1 = m1 * lc1**2 + m2 * (l1**2 + lc2**2 + 2 * l1 * lc2 * jnp.cos(th2)) + I1 + I2
    d2 = m2 * (lc2**2 + l1 * lc2 * jnp.cos(th2)) + I2
    phi2 = m2 * lc2 * g * jnp.cos(th1 + th2 - jnp.pi / 2)
    phi1 = (
        -m2 * l1 * lc2 * dth2**2 * jnp.sin(th2)
        - 2 * m2 * l1 * lc2 * dth2 * dth1 * jnp.sin(th2)
        + (m1 * lc1 + m2 * l1) * g * jnp.cos(th1 - jnp.pi / 2)
        + phi2
    )
    ddth2 = (u[0] + d2 / d1 * phi1 - m2 * l1 * lc2 * dth1**2 * jnp.sin(th2) - phi2) / (m2 * lc2**2 + I2 - d2**2 / d1)
    ddth1 = -(d2 * ddth2 + phi1) / d1
    return x + a["dt"] * jnp.stack([dth1, dth2, ddth1, ddth2])


def acrobot(
    *,
    T: int = 50,
    dt: float = 0.1,
    x0: Float[ArrayLike, " 4"] = (0.0, 0.0, 0.0, 0.0),
    m1: float = 1.0,
    m2: float = 1.0,
    l1: float = 1.0,
    lc1: float = 0.5,
    lc2: float = 0.5,
    I1: float = 1.0,
    I2: float = 1.0,
    gravity: float = 9.8,
    Q: Float[ArrayLike, " 4"] = 0.1,
    R: float = 0.01,
    QT: Float[ArrayLike, " 4"] = 1000.0,
    us_init: Float[ArrayLike, "T 1"] | None = None,
    u_max: float | None = None,
    dtype: Any = None,
) -> ControlProblem:
    """Acrobot swing-up with the equations of Sutton & Barto's Acrobot (the "book" dynamics of
    Gymnasium's ``AcrobotEnv``): two links, torque ``u`` on the elbow only, ``x = [theta1, theta2,
    theta1', theta2']`` with both angles 0 hanging straight down, goal ``[pi, 0, 0, 0]`` (balanced
    upright). Unlike the Gym environment the angles are not wrapped, the rates not clipped and the
    torque is continuous; the integrator is explicit Euler. Defaults: ``m1 = m2 = l1 = 1``,
    ``lc1 = lc2 = 0.5``, ``I1 = I2 = 1``, ``g = 9.8``, ``dt = 0.1``, ``T = 50``, weights 0.1 (state),
    0.01 (control), 1000 (terminal).
    """
    return _make(
        "acrobot", _acrobot_dynamics, 4, 1, T=T, dt=dt, x0=x0, goal=(np.pi, 0.0, 0.0, 0.0), Q=Q, R=R, QT=QT,
        us_init=us_init, u_max=u_max, dtype=_dtype(dtype), m1=m1, m2=m2, l1=l1, lc1=lc1, lc2=lc2, I1=I1, I2=I2,
        gravity=gravity,
    )


def _unicycle_dynamics(x, u, t, a):
    dt = a["dt"]
    return jnp.stack([x[0] + dt * u[0] * jnp.cos(x[2]), x[1] + dt * u[0] * jnp.sin(x[2]), x[2] + dt * u[1]])


def unicycle(
    *,
    T: int = 20,
    dt: float = 0.1,
    x0: Float[ArrayLike, " 3"] = (-1.0, -1.0, 1.0),
    state_weight: float = 10.0,
    control_weight: float = 1.0,
    us_init: Float[ArrayLike, "T 2"] | None = None,
    u_max: Float[ArrayLike, " 2"] | None = None,
    dtype: Any = None,
) -> ControlProblem:
    """Crocoddyl's ``ActionModelUnicycle``: ``x = [x, y, heading]``, ``u = [speed, turn rate]``,
    ``x+ = [x + dt v cos(h), y + dt v sin(h), h + dt w]``, cost ``0.5 (w_x^2 |x|^2 + w_u^2 |u|^2)``
    per knot and ``0.5 w_x^2 |x_T|^2`` at the end (``w_x = state_weight``,
    ``w_u = control_weight``). The defaults are the problem of ``../shared/data/ddp``
    (optimal cost 249.56089793082 at ``T = 20``).
    """
    wx, wu = float(state_weight), float(control_weight)
    return _make(
        "unicycle", _unicycle_dynamics, 3, 2, T=T, dt=dt, x0=x0, goal=0.0, Q=wx**2, R=wu**2, QT=wx**2,
        us_init=us_init, u_max=u_max, dtype=_dtype(dtype),
    )


def _dtype(dtype):
    return jnp.asarray(0.0).dtype if dtype is None else jnp.dtype(dtype)


# --------------------------------------------------------------------------------------------
# Linear-quadratic problems.
# --------------------------------------------------------------------------------------------


class LQProblem(eqx.Module):
    """A finite-horizon LQ problem in the form of :func:`solvers.lqr` (see its docstring), plus the
    constant ``constant`` of the cost that :func:`solvers.lqr` does not carry, so that
    ``solve().cost + constant`` is the problem's own cost.
    """

    A: Float[Array, "T n n"]
    B: Float[Array, "T n m"]
    Q: Float[Array, "T n n"]
    R: Float[Array, "T m m"]
    QT: Float[Array, "n n"]
    x0: Float[Array, " n"]
    S: Float[Array, "T m n"]
    q: Float[Array, "T n"]
    r: Float[Array, "T m"]
    qT: Float[Array, " n"]
    c: Float[Array, "T n"]
    constant: Float[Array, ""]

    def solve(self, **kwargs: Any) -> LQRSolution:
        """The exact solution by :func:`solvers.lqr` (``kwargs``: ``throw``)."""
        return lqr(
            self.A, self.B, self.Q, self.R, self.QT, self.x0, S=self.S, q=self.q, r=self.r, qT=self.qT, c=self.c,
            **kwargs,
        )

    def as_control_problem(self, name: str = "lq") -> ControlProblem:
        """The same problem as a :class:`ControlProblem` (for :func:`solvers.ilqr` / :func:`solvers.ddp`),
        with the constant included in the terminal cost."""
        T, m = self.r.shape
        args = dict(
            A=self.A, B=self.B, c=self.c, Q=self.Q, R=self.R, S=self.S, q=self.q, r=self.r, QT=self.QT, qT=self.qT,
            constant=self.constant, goal=jnp.zeros_like(self.x0),
        )
        return ControlProblem(
            name=name, dynamics=_lq_dynamics, cost=_lq_cost, terminal_cost=_lq_terminal, x0=self.x0,
            us_init=jnp.zeros((T, m), self.x0.dtype), args=args,
        )


def _lq_dynamics(x, u, t, a):
    return matmul(a["A"][t], x) + matmul(a["B"][t], u) + a["c"][t]


def _lq_cost(x, u, t, a):
    return (
        0.5 * dot(matmul(x, a["Q"][t]), x)
        + 0.5 * dot(matmul(u, a["R"][t]), u)
        + dot(matmul(u, a["S"][t]), x)
        + dot(a["q"][t], x)
        + dot(a["r"][t], u)
    )


def _lq_terminal(x, a):
    return 0.5 * dot(matmul(x, a["QT"]), x) + dot(a["qT"], x) + a["constant"]


def pd_servo_tracking(
    *,
    T: int = 200,
    h: float = 0.05,
    kp: float = 100.0,
    kd: float = 20.0,
    w: float = 1.0,
    x0: Float[ArrayLike, " 2"] = (0.0, 0.0),
    dtype: Any = None,
) -> LQProblem:
    r"""The course notes' PD-servo tracking problem (eq. 7.7, restated as LQR in eq. 8.9).

    A unit mass at ``x`` with velocity ``v`` is driven by a PD servo whose target ``xbar_n`` is the
    control; it should follow ``sin(t_n)``, ``t_n = n h``:

    .. math::
        \min_{\bar x_0..\bar x_{T-1}} \sum_{n=0}^{T} (\sin t_n - x_n)^2 + w \sum_{n=0}^{T-1} \bar x_n^2
        \quad\text{s.t.}\quad v_{n+1} = v_n + h (k_p (\bar x_n - x_n) - k_d v_n),\
        x_{n+1} = x_n + h v_{n+1}.

    With the state ``s = [x, v]``: ``A = [[1 - h^2 k_p, h (1 - h k_d)], [-h k_p, 1 - h k_d]]``,
    ``B = [h^2 k_p, h k_p]``; the cost is ``0.5 s'Qs + q's + 0.5 u'Ru + const`` with
    ``Q = diag(2, 0)``, ``q_n = [-2 sin t_n, 0]``, ``R = 2 w`` and ``const = sum_n sin^2 t_n``. The
    notes leave ``h, k_p, k_d`` and the horizon open; the defaults are a critically damped servo
    (``k_d = 2 sqrt(k_p)``) over 10 s.
    """
    if not isinstance(T, (int, np.integer)) or isinstance(T, bool) or T < 1:
        raise ValueError(f"T: expected an int >= 1, got {T!r}")
    for name, value in (("h", h), ("kp", kp), ("w", w)):
        _positive(name, value)
    if kd < 0:
        raise ValueError(f"kd: expected >= 0, got {kd!r}")
    dtype = _dtype(dtype)
    A = jnp.asarray([[1 - h * h * kp, h * (1 - h * kd)], [-h * kp, 1 - h * kd]], dtype)
    B = jnp.asarray([[h * h * kp], [h * kp]], dtype)
    s = jnp.sin(h * jnp.arange(T + 1, dtype=dtype))
    zeros2 = jnp.zeros((T, 2), dtype)
    return LQProblem(
        A=jnp.broadcast_to(A, (T, 2, 2)),
        B=jnp.broadcast_to(B, (T, 2, 1)),
        Q=jnp.broadcast_to(jnp.diag(jnp.asarray([2.0, 0.0], dtype)), (T, 2, 2)),
        R=jnp.full((T, 1, 1), 2 * w, dtype),
        QT=jnp.diag(jnp.asarray([2.0, 0.0], dtype)),
        x0=_vector("x0", x0, 2, dtype),
        S=jnp.zeros((T, 1, 2), dtype),
        q=zeros2.at[:, 0].set(-2 * s[:T]),
        r=jnp.zeros((T, 1), dtype),
        qT=jnp.asarray([-2 * s[T], 0.0], dtype),
        c=zeros2,
        constant=jnp.sum(s**2),
    )
