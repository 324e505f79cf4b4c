r"""Rigid bodies in maximal coordinates: mass properties from geometry, state, and Newton-Euler
stepping of free bodies.

Each body has its center of mass ``x`` (world), orientation ``q`` (wxyz, body to world), linear
velocity ``v`` and angular velocity ``omega`` (both world frame), a mass ``m`` and an inertia
``I0`` about the center of mass in its body frame; the world inertia is ``I = R I0 R'``
(course notes §1.L). The model (:class:`RigidBodies`: masses, inertias, shapes, gravity) is split
from the state (:class:`BodyState`) in the manner of MJX's Model / Data.

**Time stepping** (:func:`step_free`), semi-implicit Euler with the gyroscopic term in momentum
form. Newton-Euler ``m dv/dt = f``, ``d(I omega)/dt = tau`` (which is
``I domega/dt + omega x I omega = tau``, eq. 6.13) is stepped as::

    v_{n+1}  = v_n + h (f / m + g)
    L        = I_n omega_n + h tau                          (angular momentum, world frame)
    x_{n+1}  = x_n + h v_{n+1}
    q_{n+1}  = normalize(q_n + (h/2) [0, I_n^{-1} L] q_n)
    omega_{n+1} = I_{n+1}^{-1} L,   I_{n+1} = R_{n+1} I0 R_{n+1}'

The translation is exactly the notes' eq. 6.15-6.16. The rotation differs from eq. 6.15, which
evaluates ``omega x I omega`` explicitly at step ``n``: that explicit term gains
``|L|^2 h^2 |omega x L|^2`` per step (it is orthogonal to ``L``), so a spinning body's angular
momentum grows without bound (about 1e-2 relative over 10 s at 600 Hz for a body spinning at
1 rad/s). Carrying ``L`` through the step and re-expressing it at the new orientation makes the
angular momentum of a torque-free body exactly constant (to round-off) and still shows the
gyroscopic effects, such as the instability of rotation about the intermediate axis.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .. import rotations as rot
from .._errors import JaxanimError, check_shape
from .._linalg import einsum, matmul

__all__ = [
    "BodyState",
    "RigidBodies",
    "SHAPES",
    "angular_momentum",
    "bodies_center_of_mass",
    "box_inertia",
    "capsule_inertia",
    "force_at_point",
    "kinetic_energy",
    "linear_momentum",
    "make_bodies",
    "make_state",
    "potential_energy",
    "shape_mass_properties",
    "sphere_inertia",
    "step_free",
    "world_inertia",
]

SHAPES = ("box", "sphere", "capsule")


# --------------------------------------------------------------------------------------------
# Mass properties of primitive shapes (about the center of mass, principal axes).
# --------------------------------------------------------------------------------------------


def box_inertia(mass: Float[ArrayLike, ""], size: Float[ArrayLike, " 3"]) -> Float[Array, "3 3"]:
    """Inertia of a solid box of full side lengths ``size = [a, b, c]``:
    ``m/12 diag(b^2 + c^2, a^2 + c^2, a^2 + b^2)``."""
    m = jnp.asarray(mass)
    a, b, c = jnp.asarray(size)
    return jnp.diag(m / 12 * jnp.stack([b * b + c * c, a * a + c * c, a * a + b * b]))


def sphere_inertia(mass: Float[ArrayLike, ""], radius: Float[ArrayLike, ""]) -> Float[Array, "3 3"]:
    """Inertia of a solid sphere: ``2/5 m r^2 I``."""
    return 0.4 * jnp.asarray(mass) * jnp.asarray(radius) ** 2 * jnp.eye(3)


def capsule_inertia(
    mass: Float[ArrayLike, ""], radius: Float[ArrayLike, ""], length: Float[ArrayLike, ""]
) -> Float[Array, "3 3"]:
    """Inertia of a solid capsule along the body ``z`` axis: a cylinder of radius ``r`` and length
    ``length`` (between the centers of the end caps) plus two hemispheres, uniform density.

    Along the axis ``I_zz = m_c r^2 / 2 + 2/5 m_s r^2``; across it
    ``I_xx = m_c (l^2/12 + r^2/4) + m_s (2/5 r^2 + l^2/4 + 3/8 l r)`` with ``m_c``, ``m_s`` the
    masses of the cylinder and of the two caps together (the caps' parallel-axis offset is
    ``l/2 + 3r/8``; the cap's inertia about its own center of mass is ``83/320 m r^2`` across).
    """
    m, r, l = (jnp.asarray(v) for v in (mass, radius, length))
    v_cyl = jnp.pi * r * r * l
    v_sph = 4.0 / 3.0 * jnp.pi * r**3
    mc = m * v_cyl / (v_cyl + v_sph)
    ms = m - mc
    izz = mc * r * r / 2 + 0.4 * ms * r * r
    ixx = mc * (l * l / 12 + r * r / 4) + ms * (0.4 * r * r + l * l / 4 + 3.0 / 8.0 * l * r)
    return jnp.diag(jnp.stack([ixx, ixx, izz]))


def _shape_volume(kind: str, size: np.ndarray) -> float:
    if kind == "box":
        return float(np.prod(size))
    if kind == "sphere":
        return float(4.0 / 3.0 * np.pi * size[0] ** 3)
    r, l = size[0], size[1]
    return float(np.pi * r * r * l + 4.0 / 3.0 * np.pi * r**3)


def shape_mass_properties(
    kind: str, size: Float[ArrayLike, " k"], *, mass: float | None = None, density: float | None = None
) -> tuple[Array, Array]:
    """``(mass, I0)`` of a shape from its mass or its density (exactly one of them).

    Args:
        kind: ``"box"`` (``size = [a, b, c]`` full side lengths), ``"sphere"`` (``size = [r]``) or
            ``"capsule"`` (``size = [r, length]``, axis along body ``z``, ``length`` between the
            cap centers).
        size: the dimensions, positive.
        mass: the body's mass, or
        density: its density (mass = density x volume).
    """
    if kind not in SHAPES:
        raise JaxanimError(f"kind: expected one of {SHAPES}, got {kind!r}")
    expected = {"box": 3, "sphere": 1, "capsule": 2}[kind]
    size_np = np.asarray(size, dtype=float)
    if size_np.shape != (expected,):
        raise JaxanimError(f"size: expected shape ({expected},) for a {kind}, got {size_np.shape}")
    if not np.all(size_np > 0):
        raise JaxanimError(f"size: expected positive dimensions, got {size_np.tolist()}")
    if (mass is None) == (density is None):
        raise JaxanimError("shape_mass_properties: give exactly one of mass and density")
    if mass is None:
        if not density > 0:
            raise JaxanimError(f"density: expected > 0, got {density!r}")
        mass = density * _shape_volume(kind, size_np)
    if not mass > 0:
        raise JaxanimError(f"mass: expected > 0, got {mass!r}")
    size_j = jnp.asarray(size_np)
    if kind == "box":
        inertia = box_inertia(mass, size_j)
    elif kind == "sphere":
        inertia = sphere_inertia(mass, size_j[0])
    else:
        inertia = capsule_inertia(mass, size_j[0], size_j[1])
    return jnp.asarray(mass, inertia.dtype), inertia


# --------------------------------------------------------------------------------------------
# Model and state.
# --------------------------------------------------------------------------------------------


class RigidBodies(eqx.Module):
    """The constant part of a set of rigid bodies (the model).

    Attributes:
        names: ``[B]`` body names (static).
        shapes: ``[B]`` shape kinds (``"box"``, ``"sphere"``, ``"capsule"``; static).
        mass: ``[B]`` masses, kg, positive.
        inertia: ``[B, 3, 3]`` inertias about the center of mass in the body frame, kg m^2,
            symmetric positive definite.
        size: ``[B, 3]`` shape dimensions (box sides; sphere ``[r, 0, 0]``; capsule
            ``[r, length, 0]``), meters.
        gravity: ``[3]`` gravitational acceleration, m/s^2 (default ``[0, -9.81, 0]``: BVH clips are
            Y-up).
    """

    names: tuple[str, ...] = eqx.field(static=True)
    shapes: tuple[str, ...] = eqx.field(static=True)
    mass: Float[Array, " B"]
    inertia: Float[Array, "B 3 3"]
    size: Float[Array, "B 3"]
    gravity: Float[Array, " 3"]

    @property
    def num_bodies(self) -> int:
        return len(self.names)


class BodyState(eqx.Module):
    """The evolving part (the state) of a set of rigid bodies.

    Attributes:
        position: ``[B, 3]`` centers of mass, world frame, meters.
        orientation: ``[B, 4]`` unit quaternions (wxyz), body to world.
        linear_velocity: ``[B, 3]`` center-of-mass velocities, world frame.
        angular_velocity: ``[B, 3]`` angular velocities, world frame, rad/s.
        time: seconds.
    """

    position: Float[Array, "B 3"]
    orientation: Float[Array, "B 4"]
    linear_velocity: Float[Array, "B 3"]
    angular_velocity: Float[Array, "B 3"]
    time: Float[Array, ""]


def make_bodies(
    shapes: Sequence[tuple[str, ArrayLike]],
    *,
    names: Sequence[str] | None = None,
    mass: ArrayLike | None = None,
    density: float | None = 1000.0,
    gravity: ArrayLike = (0.0, -9.81, 0.0),
    dtype=None,
) -> RigidBodies:
    """Build :class:`RigidBodies` from primitive shapes.

    Args:
        shapes: ``[(kind, size), ...]`` one per body (see :func:`shape_mass_properties`).
        names: body names (default ``body0, body1, ...``), unique.
        mass: ``[B]`` masses; if omitted each mass is ``density`` x volume.
        density: kg/m^3 (default water, 1000), used when ``mass`` is omitted.
        gravity: ``[3]`` m/s^2.
        dtype: float dtype (default: JAX's default float).

    Raises:
        JaxanimError: unknown shape kinds, wrong sizes, non-positive masses or dimensions,
            duplicate names, or a gravity that is not ``[3]``.
    """
    shapes = list(shapes)
    B = len(shapes)
    if B == 0:
        raise JaxanimError("shapes: expected at least one body")
    names = tuple(f"body{i}" for i in range(B)) if names is None else tuple(names)
    if len(names) != B:
        raise JaxanimError(f"names: expected {B} names (one per shape), got {len(names)}")
    if len(set(names)) != B:
        raise JaxanimError(f"names: expected unique names, got {list(names)}")
    masses = None
    if mass is not None:
        masses = np.asarray(mass, dtype=float)
        if masses.shape != (B,):
            raise JaxanimError(f"mass: expected shape (B,) = ({B},), got {masses.shape}")
    m_list, I_list, s_list = [], [], []
    for i, (kind, size) in enumerate(shapes):
        m_i, I_i = shape_mass_properties(
            kind, size, mass=None if masses is None else float(masses[i]), density=None if masses is not None else density
        )
        m_list.append(m_i)
        I_list.append(I_i)
        s = np.zeros(3)
        s[: np.asarray(size).size] = np.asarray(size, dtype=float)
        s_list.append(s)
    dtype = jnp.asarray(0.0).dtype if dtype is None else jnp.dtype(dtype)
    g = jnp.asarray(gravity, dtype)
    check_shape("gravity", g, (3,))
    return RigidBodies(
        names=names,
        shapes=tuple(kind for kind, _ in shapes),
        mass=jnp.stack(m_list).astype(dtype),
        inertia=jnp.stack(I_list).astype(dtype),
        size=jnp.asarray(np.stack(s_list), dtype),
        gravity=g,
    )


def _check_model(model: RigidBodies) -> None:
    B = model.num_bodies
    check_shape("model.mass", model.mass, (B,))
    check_shape("model.inertia", model.inertia, (B, 3, 3))
    if not isinstance(model.mass, jax.core.Tracer) and not np.all(np.asarray(model.mass) > 0):
        raise JaxanimError(f"model.mass: expected positive masses, got {np.asarray(model.mass).tolist()}")
    if not isinstance(model.inertia, jax.core.Tracer):
        I = np.asarray(model.inertia)
        if not np.allclose(I, np.swapaxes(I, -1, -2), rtol=1e-10, atol=1e-12 * np.max(np.abs(I))):
            raise JaxanimError("model.inertia: expected symmetric matrices")
        eig = np.linalg.eigvalsh(I)
        bad = np.nonzero(~(eig[:, 0] > 0))[0]
        if bad.size:
            raise JaxanimError(
                f"model.inertia: expected positive-definite inertias; not so for {[model.names[i] for i in bad]}"
            )


def make_state(
    model: RigidBodies,
    position: Float[ArrayLike, "B 3"] | None = None,
    orientation: Float[ArrayLike, "B 4"] | None = None,
    linear_velocity: Float[ArrayLike, "B 3"] | None = None,
    angular_velocity: Float[ArrayLike, "B 3"] | None = None,
    time: float = 0.0,
) -> BodyState:
    """A :class:`BodyState` for ``model`` (omitted fields: origin, identity, at rest); the
    orientations are normalized.

    Raises:
        JaxanimError: a field does not have shape ``[B, 3]`` / ``[B, 4]``, or a quaternion is zero.
    """
    B = model.num_bodies
    dtype = model.mass.dtype

    def field(name, value, width, default):
        if value is None:
            return jnp.broadcast_to(jnp.asarray(default, dtype), (B, width))
        arr = jnp.asarray(value, dtype)
        check_shape(name, arr, (B, width), what=f"(B, {width}) = ({B}, {width})")
        return arr

    q = field("orientation", orientation, 4, (1.0, 0.0, 0.0, 0.0))
    if not isinstance(q, jax.core.Tracer) and np.any(np.linalg.norm(np.asarray(q), axis=-1) == 0):
        raise JaxanimError("orientation: expected non-zero quaternions")
    return BodyState(
        position=field("position", position, 3, 0.0),
        orientation=rot.quat_normalize(q),
        linear_velocity=field("linear_velocity", linear_velocity, 3, 0.0),
        angular_velocity=field("angular_velocity", angular_velocity, 3, 0.0),
        time=jnp.asarray(time, dtype),
    )


# --------------------------------------------------------------------------------------------
# Quantities.
# --------------------------------------------------------------------------------------------


def world_inertia(model: RigidBodies, orientation: Float[Array, "B 4"]) -> Float[Array, "B 3 3"]:
    """``I = R I0 R'`` per body."""
    R = rot.quat_to_matrix(orientation)
    return _bmm(_bmm(R, model.inertia), jnp.swapaxes(R, -1, -2))


def _world_inverse_inertia(model: RigidBodies, orientation: Float[Array, "B 4"]) -> Float[Array, "B 3 3"]:
    """``I^{-1} = R I0^{-1} R'`` per body."""
    R = rot.quat_to_matrix(orientation)
    return _bmm(_bmm(R, _spd_inverse(model.inertia)), jnp.swapaxes(R, -1, -2))


def _bmm(a: Array, b: Array) -> Array:
    """``a @ b`` over leading axes for small matrices. A product with several columns is written as
    the sum of its rank-one terms ``a[..., :, k] b[..., k, :]``: XLA:CPU fuses that into one
    elementwise loop, where a batched ``dot`` of 6 x 6 matrices runs as a loop of tiny matrix
    products (2-2.5x slower under ``vmap``; a broadcast multiply and ``sum`` is slower still).
    Matrix-vector products stay ``dot``s."""
    if b.shape[-1] == 1 or not 6 <= a.shape[-1] <= 9:
        return matmul(a, b)
    out = a[..., :, 0, None] * b[..., None, 0, :]
    for k in range(1, a.shape[-1]):
        out = out + a[..., :, k, None] * b[..., None, k, :]
    return out


def _spd_inverse(A):
    """Inverse of symmetric positive definite matrices ``[..., k, k]``, written out as array
    arithmetic (vectorized over the leading axes, no LAPACK call per matrix): closed forms for
    ``k <= 3`` (adjugate over determinant), otherwise a 2 x 2 block inverse with the Schur
    complement ``D - C A^{-1} B`` (symmetric positive definite again, so no pivoting is needed).

    For ``k = 3`` every entry of the adjugate and the determinant (Sarrus' rule) are written from
    ``A``'s entries, with one division per entry: XLA:CPU compiles that into one kernel, where
    cofactors shared by the determinant (rows' cross products) were five kernels and ran at half the
    speed under ``vmap``; a 6 x 6 inverse is 8 kernels instead of 16. The tree solve factors one 6 x 6
    and one 3 x 3 block per joint and level, so these were a fifth of a physics step's kernels."""
    k = A.shape[-1]
    if k == 1:
        return 1.0 / A
    if k == 2:
        a, b, d = A[..., 0, 0], A[..., 0, 1], A[..., 1, 1]
        det = a * d - b * b
        return jnp.stack([jnp.stack([d, -b], -1), jnp.stack([-b, a], -1)], -2) / det[..., None, None]
    if k == 3:
        a = [[A[..., i, j] for j in range(3)] for i in range(3)]
        det = (a[0][0] * a[1][1] * a[2][2] + a[0][1] * a[1][2] * a[2][0] + a[0][2] * a[1][0] * a[2][1]
               - a[0][2] * a[1][1] * a[2][0] - a[0][0] * a[1][2] * a[2][1] - a[0][1] * a[1][0] * a[2][2])
        # entry (i, j) of the inverse: the cofactor of A's (j, i), over the determinant (indices mod 3)
        cof = [[a[(j + 1) % 3][(i + 1) % 3] * a[(j + 2) % 3][(i + 2) % 3]
                - a[(j + 1) % 3][(i + 2) % 3] * a[(j + 2) % 3][(i + 1) % 3] for j in range(3)] for i in range(3)]
        return jnp.stack([jnp.stack([cof[i][j] / det for j in range(3)], -1) for i in range(3)], -2)
    h = k // 2 if k != 6 else 3
    Ai = _spd_inverse(A[..., :h, :h])
    Bm = A[..., :h, h:]
    AiB = _bmm(Ai, Bm)
    Si = _spd_inverse(A[..., h:, h:] - _bmm(jnp.swapaxes(Bm, -1, -2), AiB))
    top_right = -_bmm(AiB, Si)
    top_left = Ai - _bmm(top_right, jnp.swapaxes(AiB, -1, -2))
    return jnp.concatenate([jnp.concatenate([top_left, top_right], -1),
                            jnp.concatenate([jnp.swapaxes(top_right, -1, -2), Si], -1)], -2)




def bodies_center_of_mass(bodies: RigidBodies, state: BodyState) -> tuple[Float[Array, " 3"], Float[Array, " 3"]]:
    """The bodies' center of mass and its velocity ``(c [3], c_dot [3])`` (world frame, m, m/s).

    (Not :func:`jaxanim.center_of_mass`, the center of mass of a skeleton pose from segment masses.)
    """
    m = bodies.mass / jnp.sum(bodies.mass)
    return matmul(m, state.position), matmul(m, state.linear_velocity)


def linear_momentum(model: RigidBodies, state: BodyState) -> Float[Array, " 3"]:
    """Total linear momentum ``sum m v``."""
    return jnp.sum(model.mass[:, None] * state.linear_velocity, axis=0)


def angular_momentum(
    model: RigidBodies, state: BodyState, about: Float[ArrayLike, " 3"] = (0.0, 0.0, 0.0)
) -> Float[Array, " 3"]:
    """Total angular momentum about the point ``about`` (world): ``sum (x - a) x m v + I omega``."""
    r = state.position - jnp.asarray(about, state.position.dtype)[None, :]
    spin = einsum("bij,bj->bi", world_inertia(model, state.orientation), state.angular_velocity)
    return jnp.sum(jnp.cross(r, model.mass[:, None] * state.linear_velocity) + spin, axis=0)


def kinetic_energy(model: RigidBodies, state: BodyState) -> Float[Array, ""]:
    """``sum 0.5 m |v|^2 + 0.5 omega' I omega``."""
    I = world_inertia(model, state.orientation)
    w = state.angular_velocity
    return 0.5 * jnp.sum(model.mass * jnp.sum(state.linear_velocity**2, axis=-1)) + 0.5 * jnp.sum(
        einsum("bi,bij,bj->b", w, I, w)
    )


def potential_energy(model: RigidBodies, state: BodyState) -> Float[Array, ""]:
    """Gravitational potential ``-sum m g . x`` (zero at the origin)."""
    return -jnp.sum(model.mass * matmul(state.position, model.gravity))


def force_at_point(
    position: Float[ArrayLike, "*batch 3"], force: Float[ArrayLike, "*batch 3"], point: Float[ArrayLike, "*batch 3"]
) -> tuple[Float[Array, "*batch 3"], Float[Array, "*batch 3"]]:
    """A force applied at a world point, reduced to the center of mass ``position``:
    ``(force, (point - position) x force)``."""
    f = jnp.asarray(force)
    return f, jnp.cross(jnp.asarray(point) - jnp.asarray(position), f)


# --------------------------------------------------------------------------------------------
# Stepping.
# --------------------------------------------------------------------------------------------


def _integrate_orientation(q: Float[Array, "B 4"], omega: Float[Array, "B 3"], h) -> Float[Array, "B 4"]:
    """``normalize(q + (h/2) [0, omega] q)`` (omega in the world frame)."""
    w = jnp.concatenate([jnp.zeros_like(omega[:, :1]), omega], axis=-1)
    return rot.quat_normalize(q + 0.5 * h * rot.quat_multiply(w, q))


def _free_velocities(model: RigidBodies, state: BodyState, force, torque, h):
    """The velocities after one step of the loads alone: ``(v*, omega*, I_n)`` with
    ``v* = v + h (f/m + g)`` and ``omega* = I_n^{-1} (I_n omega + h tau)``."""
    v = state.linear_velocity + h * (force / model.mass[:, None] + model.gravity[None, :])
    I_n = world_inertia(model, state.orientation)
    tau = einsum("bij,bj->bi", _world_inverse_inertia(model, state.orientation), torque)
    return v, state.angular_velocity + h * tau, I_n


def _integrate(model: RigidBodies, state: BodyState, v, omega, I_n, h) -> BodyState:
    """Positions with the new velocities, then the angular velocity re-expressed at the new
    orientation with the same angular momentum ``L = I_n omega``."""
    q = _integrate_orientation(state.orientation, omega, h)
    L = einsum("bij,bj->bi", I_n, omega)
    omega_new = einsum("bij,bj->bi", _world_inverse_inertia(model, q), L)
    return BodyState(
        position=state.position + h * v,
        orientation=q,
        linear_velocity=v,
        angular_velocity=omega_new,
        time=state.time + h,
    )


def _momentum_step(model: RigidBodies, state: BodyState, force, torque, h) -> BodyState:
    """The step of the module docstring with given total forces and torques (no checks)."""
    v, omega, I_n = _free_velocities(model, state, force, torque, h)
    return _integrate(model, state, v, omega, I_n, h)


@eqx.filter_jit
def _step_free(model, state, force, torque, dt):
    return _momentum_step(model, state, force, torque, dt)


def step_free(
    model: RigidBodies,
    state: BodyState,
    dt: Float[ArrayLike, ""],
    *,
    force: Float[ArrayLike, "B 3"] | None = None,
    torque: Float[ArrayLike, "B 3"] | None = None,
) -> BodyState:
    """Advance unconnected bodies by one step of ``dt`` seconds under gravity and the given loads.

    Args:
        model: the bodies.
        state: their state.
        dt: the step, seconds.
        force: ``[B, 3]`` external forces at the centers of mass, world frame, N (default 0; use
            :func:`force_at_point` for a force elsewhere).
        torque: ``[B, 3]`` external torques, world frame, N m (default 0).

    Returns:
        The new :class:`BodyState` (semi-implicit Euler, gyroscopic term in momentum form: see
        the module docstring).

    Raises:
        JaxanimError: shapes do not match the model, a mass is not positive or an inertia is not
            symmetric positive definite.
    """
    _check_model(model)
    B = model.num_bodies
    force, torque = _check_loads(state, B, model.mass.dtype, (("force", force, B, "B"), ("torque", torque, B, "B")))
    return _step_free(model, state, force, torque, jnp.asarray(dt, model.mass.dtype))


def _check_loads(state: BodyState, B: int, dtype, loads) -> list[Array]:
    """Check the state's shapes against ``B`` bodies and each ``(name, value, rows, dim)`` load
    against ``[rows, 3]``; return the loads as arrays (zeros for ``None``)."""
    out = []
    for name, value, rows, dim in loads:
        if value is None:
            out.append(jnp.zeros((rows, 3), dtype))
        else:
            arr = jnp.asarray(value, dtype)
            check_shape(name, arr, (rows, 3), what=f"({dim}, 3) = ({rows}, 3)")
            out.append(arr)
    for name in ("position", "linear_velocity", "angular_velocity"):
        check_shape(f"state.{name}", getattr(state, name), (B, 3), what=f"(B, 3) = ({B}, 3)")
    check_shape("state.orientation", state.orientation, (B, 4), what=f"(B, 4) = ({B}, 4)")
    return out
