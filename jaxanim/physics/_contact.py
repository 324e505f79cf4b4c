r"""Contact of rigid bodies with a ground plane: detection, the penalty model and a complementarity
model with Coulomb friction.

**Detection.** Each shape carries static contact points in its body frame with a radius: a box its
8 corners (radius 0), a sphere its center (radius ``r``), a capsule the centers of its two caps
(radius ``r``). For the plane ``n . p = offset`` a point ``p`` (world) of radius ``r`` has the signed
distance ``phi = n . p - offset - r`` (negative: penetrating) and touches at ``c = p - r n``.

**Penalty** (course notes eq. 6.25): at every penetrating point a normal force
``f_n = max(0, -k_p phi - k_d v_n)`` and kinetic Coulomb friction ``f_t = -mu f_n v_t / |v_t|``
(``|v_t|`` regularized by 1 mm/s), applied at ``c`` as external loads for the step. Stiff
``k_p`` needs small steps (the notes' warning).

**Complementarity** (eq. 6.26-6.27, with friction): per point three velocity rows (normal ``n``,
tangents ``t_1, t_2``) solved together with the joints for impulses ``lambda_n >= 0`` with
``v_n >= b`` and ``lambda_n (v_n - b) = 0``, and ``|lambda_t| <= mu lambda_n`` (the Coulomb disc).
The target ``b`` is ``-phi / h`` for a point still above the plane (a speculative contact: it may
approach the plane but not pass it within the step) and ``(erp / h) max(-phi - slop, 0)`` for a
penetrating one. The joints are eliminated exactly (Schur complement of their block, see
:mod:`jaxanim.physics`); the contact rows are solved by projected Gauss-Seidel with a fixed number
of sweeps (``iterations``, static, so it vmaps): normal row, tangent rows, then the tangential
impulse projected onto the disc of radius ``mu lambda_n``.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._errors import JaxanimError
from ._bodies import BodyState, RigidBodies
from .. import rotations as rot
from .._linalg import einsum, matmul

__all__ = ["CONTACT_MODELS", "Ground", "contact_points", "make_ground"]

CONTACT_MODELS = ("none", "penalty", "complementarity")

_BOX_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)


class Ground(eqx.Module):
    """A ground plane ``normal . p = offset`` and the contact model's parameters.

    Attributes:
        model: ``"none"``, ``"penalty"`` or ``"complementarity"`` (static).
        iterations: projected Gauss-Seidel sweeps (static; complementarity).
        normal: ``[3]`` unit normal pointing out of the ground.
        offset: the plane's offset along the normal, meters.
        friction: Coulomb coefficient ``mu``.
        stiffness: penalty ``k_p``, N/m.
        damping: penalty ``k_d``, N s/m.
        erp: fraction of the penetration (beyond ``slop``) removed per step (complementarity).
        slop: penetration tolerated without correction, meters (complementarity).
        max_points: solve only this many contact points per step, the lowest ones (static;
            ``None``: all; complementarity).
    """

    model: str = eqx.field(static=True)
    iterations: int = eqx.field(static=True)
    max_points: int | None = eqx.field(static=True)
    normal: Float[Array, " 3"]
    offset: Float[Array, ""]
    friction: Float[Array, ""]
    stiffness: Float[Array, ""]
    damping: Float[Array, ""]
    erp: Float[Array, ""]
    slop: Float[Array, ""]


def make_ground(
    model: str = "complementarity",
    *,
    normal=(0.0, 1.0, 0.0),
    offset: float = 0.0,
    friction: float = 0.8,
    stiffness: float = 1e5,
    damping: float = 1e3,
    erp: float = 0.2,
    slop: float = 1e-4,
    iterations: int = 30,
    max_points: int | None = None,
    dtype=None,
) -> Ground:
    """A :class:`Ground`; the normal is normalized (default ``+Y``, BVH's up axis).

    ``max_points`` (complementarity) caps the contact points solved per step to the lowest ones
    (smallest signed distance): the cost of the contact solve grows with them, and a standing
    character touches the ground with a few (two box feet: 8 corners). Points beyond the cap are
    not held up in that step (a fallen character lying on more points sinks there).

    Raises:
        JaxanimError: an unknown model, a zero normal, negative friction / stiffness / damping /
            slop, ``erp`` outside ``[0, 1]`` or ``iterations < 1``.
    """
    if model not in CONTACT_MODELS:
        raise JaxanimError(f"model: expected one of {CONTACT_MODELS}, got {model!r}")
    n = np.asarray(normal, float)
    if n.shape != (3,) or not np.linalg.norm(n) > 0:
        raise JaxanimError(f"normal: expected a non-zero vector of shape (3,), got {normal!r}")
    for name, value in (("friction", friction), ("stiffness", stiffness), ("damping", damping), ("slop", slop)):
        if not value >= 0:
            raise JaxanimError(f"{name}: expected >= 0, got {value!r}")
    if not 0 <= erp <= 1:
        raise JaxanimError(f"erp: expected a value in [0, 1], got {erp!r}")
    if not isinstance(iterations, (int, np.integer)) or iterations < 1:
        raise JaxanimError(f"iterations: expected an int >= 1, got {iterations!r}")
    if max_points is not None and (not isinstance(max_points, (int, np.integer)) or max_points < 1):
        raise JaxanimError(f"max_points: expected None or an int >= 1, got {max_points!r}")
    dtype = jnp.asarray(0.0).dtype if dtype is None else jnp.dtype(dtype)
    a = lambda v: jnp.asarray(v, dtype)  # noqa: E731
    return Ground(model=model, iterations=int(iterations), max_points=None if max_points is None else int(max_points),
                  normal=a(n / np.linalg.norm(n)), offset=a(offset),
                  friction=a(friction), stiffness=a(stiffness), damping=a(damping), erp=a(erp), slop=a(slop))


def contact_points(bodies: RigidBodies) -> tuple[np.ndarray, Array, Array]:
    """The bodies' contact points: ``(body [K] (static), local [K, 3], radius [K])``."""
    owners, locals_, radii = [], [], []
    for b, kind in enumerate(bodies.shapes):
        size = bodies.size[b]
        if kind == "box":
            owners += [b] * 8
            locals_.append(0.5 * jnp.asarray(_BOX_SIGNS, size.dtype) * size[None, :])
            radii.append(jnp.zeros(8, size.dtype))
        elif kind == "sphere":
            owners.append(b)
            locals_.append(jnp.zeros((1, 3), size.dtype))
            radii.append(size[:1])
        else:
            owners += [b, b]
            half = 0.5 * size[1]
            z = jnp.stack([-half, half])
            locals_.append(jnp.stack([jnp.zeros_like(z), jnp.zeros_like(z), z], axis=1))
            radii.append(jnp.stack([size[0], size[0]]))
    return np.asarray(owners, int), jnp.concatenate(locals_), jnp.concatenate(radii)


def contact_geometry(ground: Ground, bodies: RigidBodies, state: BodyState):
    """Per contact point: owner (static), lever ``c - x`` [K, 3], distance ``phi`` [K], velocity [K, 3]."""
    owner, local, radius = contact_points(bodies)
    n = ground.normal
    p = state.position[owner] + rot.quat_apply(state.orientation[owner], local)
    phi = matmul(p, n) - ground.offset - radius
    c = p - radius[:, None] * n[None, :]
    r = c - state.position[owner]
    vel = state.linear_velocity[owner] + jnp.cross(state.angular_velocity[owner], r)
    return owner, r, phi, vel


def penalty_loads(ground: Ground, bodies: RigidBodies, state: BodyState) -> tuple[Array, Array]:
    """Penalty contact forces and torques on every body, ``([B, 3], [B, 3])`` (world frame)."""
    owner, r, phi, vel = contact_geometry(ground, bodies, state)
    n = ground.normal
    vn = matmul(vel, n)
    vt = vel - vn[:, None] * n[None, :]
    fn = jnp.where(phi < 0, jnp.maximum(0.0, -ground.stiffness * phi - ground.damping * vn), 0.0)
    speed = jnp.sqrt(jnp.sum(vt * vt, axis=-1) + 1e-6)
    f = fn[:, None] * n[None, :] - (ground.friction * fn / speed)[:, None] * vt
    B = bodies.num_bodies
    force = jnp.zeros((B, 3), f.dtype).at[owner].add(f)
    torque = jnp.zeros((B, 3), f.dtype).at[owner].add(jnp.cross(r, f))
    return force, torque


def _lowest(phi: Array, k: int) -> Array:
    """The indices of the ``k`` smallest entries of ``phi``, smallest first, ties to the lower index: those of
    ``lax.top_k(-phi, k)``, picked one at a time. For the few points of a step (``k`` up to 8 of 66) these ``k``
    reductions cost under a tenth of the sort that ``top_k`` runs on XLA:CPU (measured: the sort was 9 % of a
    complementarity step at a batch of 64)."""
    index = jnp.arange(phi.shape[0])
    free = jnp.ones(phi.shape, bool)
    picked = []
    for _ in range(k):
        lowest = jnp.min(jnp.where(free, phi, jnp.inf))
        i = jnp.argmax(free & (phi == lowest))  # the first free entry at the minimum
        picked.append(i)
        free = free & (index != i)
    return jnp.stack(picked)


def contact_rows(ground: Ground, bodies: RigidBodies, state: BodyState, h) -> tuple[Array, Array, Array]:
    """The complementarity rows in compact form: ``(owner [3K], rows [3K, 6], target [3K])``: row
    ``u`` acts on body ``owner[u]``'s ``[v; omega]``; rows are ordered (normal, t1, t2) per point;
    ``target`` is ``b`` for the normal rows and 0 for the tangent rows. With ``ground.max_points``
    only the lowest points, ``K = max_points``."""
    owner, r, phi, _ = contact_geometry(ground, bodies, state)
    owner = jnp.asarray(owner)
    if ground.max_points is not None and ground.max_points < phi.shape[0]:
        idx = _lowest(phi, ground.max_points)
        owner, r, phi = owner[idx], r[idx], phi[idx]
    K = phi.shape[0]
    n = ground.normal
    t1, t2 = (t[0] for t in rot.perpendicular_basis(n[None]))
    dirs = jnp.stack([n, t1, t2])  # [3, 3]
    lin = jnp.broadcast_to(dirs[None], (K, 3, 3))
    ang = jnp.cross(r[:, None, :], lin)  # (r x d) . omega
    rows = jnp.concatenate([lin, ang], axis=-1).reshape(3 * K, 6)
    b_n = jnp.where(phi > 0, -phi / h, (ground.erp / h) * jnp.maximum(-phi - ground.slop, 0.0))
    target = jnp.stack([b_n, jnp.zeros_like(b_n), jnp.zeros_like(b_n)], axis=1).reshape(3 * K)
    return jnp.repeat(owner, 3), rows, target


def projected_gauss_seidel(S: Array, rhs: Array, mu: Array, iterations: int, num_single: int = 0) -> Array:
    """Impulses ``lambda [3K + num_single]`` of the contact problem ``w = S lambda - rhs``: per point
    ``lambda_n >= 0``, ``w_n >= 0``, ``lambda_n w_n = 0`` and ``|(lambda_t1, lambda_t2)| <= mu
    lambda_n`` with the tangential ``w_t`` driven to zero where it is not on the disc's edge.

    Each sweep visits the points in order; at a point the normal row, then the two tangent rows
    are relaxed in turn (Gauss-Seidel within the point too, from one ``3 x 3K`` product), then the
    tangential impulse is projected onto the disc of radius ``mu lambda_n``. The last
    ``num_single`` rows are one-sided rows without friction (``lambda >= 0``, ``w >= 0``,
    ``lambda w = 0``; joint limits), relaxed after the points in each sweep. ``iterations`` sweeps
    from zero (static, so it vmaps)."""
    n = rhs.shape[0]
    K = (n - num_single) // 3
    S3 = S[: 3 * K].reshape(K, 3, n)
    blocks = S3[:, :, : 3 * K].reshape(K, 3, K, 3)[np.arange(K), :, np.arange(K), :]  # [K, 3, 3]
    rhs3 = rhs[: 3 * K].reshape(K, 3)
    diag = jnp.diagonal(S)

    def point(k, lam):
        w = einsum("in,n->i", S3[k], lam) - rhs3[k]  # [3]
        d = blocks[k]
        old = jax.lax.dynamic_slice(lam, (3 * k,), (3,))
        ln = jnp.maximum(old[0] - w[0] / d[0, 0], 0.0)
        dn = ln - old[0]
        l1 = old[1] - (w[1] + d[1, 0] * dn) / d[1, 1]
        d1 = l1 - old[1]
        l2 = old[2] - (w[2] + d[2, 0] * dn + d[2, 1] * d1) / d[2, 2]
        norm = jnp.sqrt(l1 * l1 + l2 * l2)
        scale = jnp.where(norm > mu * ln, mu * ln / jnp.where(norm > 0, norm, 1.0), 1.0)
        return jax.lax.dynamic_update_slice(lam, jnp.stack([ln, l1 * scale, l2 * scale]), (3 * k,))

    def single(i, lam):
        return lam.at[i].set(jnp.maximum(lam[i] - (jnp.sum(S[i] * lam) - rhs[i]) / diag[i], 0.0))

    def sweep(_, lam):
        if K:
            lam = jax.lax.fori_loop(0, K, point, lam)
        if num_single:
            lam = jax.lax.fori_loop(3 * K, n, single, lam)
        return lam

    return jax.lax.fori_loop(0, iterations, sweep, jnp.zeros_like(rhs))
