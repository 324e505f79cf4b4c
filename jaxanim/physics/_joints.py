r"""Joints between rigid bodies in maximal coordinates: ball, hinge, universal and fixed.

A joint ``j`` connects a parent body ``p`` (or the world, ``p = -1``) to a child body ``c`` at an
anchor ``r_p`` (parent body frame) / ``r_c`` (child body frame). Its constraint rows act on the
bodies' velocities ``[v_p, omega_p, v_c, omega_c]`` (world frame) and come with a position error
``g`` that the step drives to zero with the error-reduction parameter (``J v = -(erp / h) g``):

- every type: the anchors coincide (course notes eq. 6.21-6.22), 3 rows
  ``J = [I, -[a_p]x, -I, [a_c]x]`` with ``a = R r`` the world anchor offsets, ``g = x_p + a_p -
  x_c - a_c``;
- **hinge**: the child's hinge axis ``n_c = R_c e_c`` stays on the parent's ``n_p = R_p e_p``, 2
  rows ``t_k' (omega_c - omega_p)`` for ``t_1, t_2`` perpendicular to ``n_p``, ``g_k =
  t_k . (n_p x n_c)``;
- **universal**: the parent's axis ``n_p`` and the child's ``m_c`` stay perpendicular, 1 row
  ``(n_p x m_c)' (omega_p - omega_c)``, ``g = n_p . m_c``;
- **fixed**: the relative orientation stays at its assembly value ``q_rest = q_p^{-1} q_c``, 3 rows
  ``omega_c - omega_p``, ``g`` the rotation vector of ``q_c (q_p q_rest)^{-1}``.

Rows are padded to 6 per joint; which rows exist is static (``Joints.row_mask``).

**Limits** (one-sided rows, solved with the contacts as a complementarity problem, see
:mod:`jaxanim.physics`), measured on the deviation ``q_d = (q_p^{-1} q_c) q_rest^{-1}`` from the
assembly pose (parent frame):

- **hinge range** ``[lower, upper]`` on the hinge angle ``theta`` (the rotation of ``q_d`` about
  the hinge axis, zero at assembly): one row ``+-n_p' (omega_c - omega_p)`` on the nearer bound;
- **ball swing cone**: the angle ``alpha`` between the parent's and the child's copies of the
  joint's ``axis`` (e.g. the bone direction) stays below ``swing``: one row ``-s' (omega_c -
  omega_p)`` with ``s = (n_p x n_c) / |n_p x n_c|`` (``alpha' = s' (omega_c - omega_p)``);
- **ball twist** ``[lower, upper]`` on the twist of ``q_d`` about the axis (swing-twist
  decomposition): one row on the bisector of ``n_p`` and ``n_c``, nearer bound.

Each row has a signed distance to its bound ``phi`` (radians, negative: violated) and, like a
contact, the target ``-phi / h`` while inside (it may reach the bound but not pass it within the
step) and ``(erp / h) (-phi)`` when violated.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import rotations as rot
from .._errors import JaxanimError
from ._bodies import BodyState, RigidBodies
from .._linalg import einsum

__all__ = ["JOINT_TYPES", "Joints", "joint_errors", "joint_rows", "limit_rows", "make_joints"]

JOINT_TYPES = ("ball", "hinge", "universal", "fixed")
_ANGULAR_ROWS = {"ball": 0, "hinge": 2, "universal": 1, "fixed": 3}


class Joints(eqx.Module):
    """Joints of an articulated set of bodies (constant; part of the model).

    Attributes:
        names: ``[J]`` joint names (static).
        types: ``[J]`` one of :data:`JOINT_TYPES` (static).
        parent: ``[J]`` parent body index, ``-1`` for the world (static).
        child: ``[J]`` child body index (static).
        anchor_parent: ``[J, 3]`` the anchor in the parent's body frame (world frame for the
            world), meters.
        anchor_child: ``[J, 3]`` the anchor in the child's body frame.
        axis_parent: ``[J, 3]`` unit axis in the parent frame: the hinge axis, or the universal
            joint's first axis (unused otherwise).
        axis_child: ``[J, 3]`` unit axis in the child frame: the hinge axis, or the universal
            joint's second axis.
        rest: ``[J, 4]`` the relative orientation ``q_p^{-1} q_c`` at assembly (wxyz).
        limited: ``[J]`` whether the joint has limits (static): a limited hinge has one limit row,
            a limited ball joint two (swing and twist).
        lower, upper: ``[J]`` the hinge angle range, or the ball joint's twist range (radians;
            ``-inf`` / ``inf``: none).
        swing: ``[J]`` the ball joint's swing-cone half angle (radians; ``inf``: none).
    """

    names: tuple[str, ...] = eqx.field(static=True)
    types: tuple[str, ...] = eqx.field(static=True)
    parent: tuple[int, ...] = eqx.field(static=True)
    child: tuple[int, ...] = eqx.field(static=True)
    anchor_parent: Float[Array, "J 3"]
    anchor_child: Float[Array, "J 3"]
    axis_parent: Float[Array, "J 3"]
    axis_child: Float[Array, "J 3"]
    rest: Float[Array, "J 4"]
    limited: tuple[bool, ...] = eqx.field(static=True)
    lower: Float[Array, " J"]
    upper: Float[Array, " J"]
    swing: Float[Array, " J"]

    @property
    def num_joints(self) -> int:
        return len(self.names)

    @property
    def row_mask(self) -> np.ndarray:
        """``[J, 6]`` bool (numpy, static): which of each joint's 6 padded rows exist."""
        mask = np.zeros((len(self.types), 6), bool)
        for j, kind in enumerate(self.types):
            mask[j, : 3 + _ANGULAR_ROWS[kind]] = True
        return mask


def _body_index(bodies: RigidBodies, name: Any, field: str, allow_world: bool) -> int:
    if name is None or (allow_world and name == "world"):
        if not allow_world:
            raise JaxanimError(f"{field}: a joint's child must be a body")
        return -1
    if isinstance(name, (int, np.integer)) and not isinstance(name, bool):
        if not 0 <= name < bodies.num_bodies:
            raise JaxanimError(f"{field}: body index {name} out of range [0, {bodies.num_bodies})")
        return int(name)
    if name not in bodies.names:
        raise JaxanimError(f"{field}: unknown body {name!r}; bodies are {list(bodies.names)}")
    return bodies.names.index(name)


def _unit(name: str, v) -> np.ndarray:
    v = np.asarray(v, float)
    if v.shape != (3,):
        raise JaxanimError(f"{name}: expected shape (3,), got {v.shape}")
    n = np.linalg.norm(v)
    if not n > 0:
        raise JaxanimError(f"{name}: expected a non-zero axis")
    return v / n


def make_joints(bodies: RigidBodies, state: BodyState, specs: Sequence[dict]) -> Joints:
    """Joints assembled at ``state`` (the anchors and axes are given in the world frame there).

    Args:
        bodies: the bodies.
        state: the assembly configuration (usually the initial state).
        specs: one dict per joint with keys ``name`` (default ``joint<i>``), ``type`` (one of
            :data:`JOINT_TYPES`), ``parent`` (a body name or index, or ``None`` / ``"world"``),
            ``child`` (a body name or index), ``anchor`` (``[3]`` world point), and ``axis``
            (``[3]`` world direction; hinge axis, or the universal joint's parent-side axis) and
            ``axis2`` (the universal joint's child-side axis, perpendicular to ``axis``).
            Limits (radians, see the module docstring): a hinge's ``limit`` ``(lower, upper)``;
            a ball joint's ``swing`` (cone half angle in ``(0, pi]``) and / or ``twist``
            ``(lower, upper)`` about its ``axis`` (required with either; e.g. the bone direction).

    Raises:
        JaxanimError: unknown types or bodies, missing or malformed anchors / axes, a universal
            joint whose axes are not perpendicular, a body that is the child of two joints, a
            joint between a body and itself, or limits that are malformed or not of the joint's
            type (``limit`` is for hinges, ``swing`` / ``twist`` for ball joints).
    """
    x = np.asarray(state.position, float)
    q = np.asarray(state.orientation, float)
    R = np.asarray(rot.quat_to_matrix(jnp.asarray(q)))
    names, types, parents, children = [], [], [], []
    ap, ac, ep, ec, rest = [], [], [], [], []
    limited, lower, upper, swing = [], [], [], []
    for i, spec in enumerate(specs):
        spec = dict(spec)
        name = spec.get("name", f"joint{i}")
        kind = spec.get("type")
        if kind not in JOINT_TYPES:
            raise JaxanimError(f"specs[{i}].type: expected one of {JOINT_TYPES}, got {kind!r}")
        p = _body_index(bodies, spec.get("parent"), f"specs[{i}].parent", True)
        if "child" not in spec:
            raise JaxanimError(f"specs[{i}].child: missing")
        c = _body_index(bodies, spec["child"], f"specs[{i}].child", False)
        if p == c:
            raise JaxanimError(f"specs[{i}]: a joint between body {bodies.names[c]!r} and itself")
        if c in children:
            raise JaxanimError(f"specs[{i}].child: body {bodies.names[c]!r} is already the child of a joint")
        if "anchor" not in spec:
            raise JaxanimError(f"specs[{i}].anchor: missing")
        a = np.asarray(spec["anchor"], float)
        if a.shape != (3,):
            raise JaxanimError(f"specs[{i}].anchor: expected shape (3,), got {a.shape}")
        Rp = np.eye(3) if p < 0 else R[p]
        xp = np.zeros(3) if p < 0 else x[p]
        qp = np.array([1.0, 0.0, 0.0, 0.0]) if p < 0 else q[p]
        axis, axis2 = _axes(i, kind, spec)
        axis, axis2, has_limit, lo, hi, sw = _limits(i, kind, spec, axis, axis2)
        limited.append(has_limit)
        lower.append(lo)
        upper.append(hi)
        swing.append(sw)
        names.append(str(name))
        types.append(kind)
        parents.append(p)
        children.append(c)
        ap.append(Rp.T @ (a - xp))
        ac.append(R[c].T @ (a - x[c]))
        ep.append(Rp.T @ axis)
        ec.append(R[c].T @ axis2)
        rest.append(np.asarray(rot.quat_multiply(rot.quat_conjugate(jnp.asarray(qp)), jnp.asarray(q[c]))))
    if len(set(names)) != len(names):
        raise JaxanimError(f"specs: joint names must be unique, got {names}")
    dtype = bodies.mass.dtype
    stack = lambda v, w: jnp.asarray(np.reshape(np.asarray(v, float), (-1, w)), dtype)  # noqa: E731
    return Joints(
        names=tuple(names), types=tuple(types), parent=tuple(parents), child=tuple(children),
        anchor_parent=stack(ap, 3), anchor_child=stack(ac, 3), axis_parent=stack(ep, 3), axis_child=stack(ec, 3),
        rest=stack(rest, 4), limited=tuple(limited), lower=jnp.asarray(lower, dtype), upper=jnp.asarray(upper, dtype),
        swing=jnp.asarray(swing, dtype),
    )


def _axes(i: int, kind: str, spec: dict) -> tuple[np.ndarray, np.ndarray]:
    """A hinge's axis, a universal joint's two axes (world frame); ``e_x`` for the other types."""
    axis = axis2 = np.array([1.0, 0.0, 0.0])
    if kind in ("hinge", "universal"):
        if "axis" not in spec:
            raise JaxanimError(f"specs[{i}].axis: missing (a {kind} joint needs one)")
        axis = _unit(f"specs[{i}].axis", spec["axis"])
        axis2 = axis
    if kind == "universal":
        if "axis2" not in spec:
            raise JaxanimError(f"specs[{i}].axis2: missing (a universal joint needs two axes)")
        axis2 = _unit(f"specs[{i}].axis2", spec["axis2"])
        if abs(axis @ axis2) > 1e-6:
            raise JaxanimError(f"specs[{i}]: a universal joint's axis and axis2 must be perpendicular")
    return axis, axis2


def _limits(i: int, kind: str, spec: dict, axis: np.ndarray, axis2: np.ndarray):
    """``(axis, axis2, limited, lower, upper, swing)``: a hinge's range, or a ball joint's swing cone
    and twist range about its ``axis`` (which then replaces both axes)."""
    lo, hi, swing = -np.inf, np.inf, np.inf
    limited = False
    if "limit" in spec:
        if kind != "hinge":
            raise JaxanimError(f"specs[{i}].limit: a range is for hinge joints (ball joints: swing / twist)")
        lo, hi = _range(f"specs[{i}].limit", spec["limit"])
        limited = True
    if "swing" in spec or "twist" in spec:
        if kind != "ball":
            raise JaxanimError(f"specs[{i}]: swing / twist limits are for ball joints")
        if "axis" not in spec:
            raise JaxanimError(f"specs[{i}].axis: missing (a ball joint's swing / twist limits need an axis)")
        axis = axis2 = _unit(f"specs[{i}].axis", spec["axis"])
        if "swing" in spec:
            swing = float(spec["swing"])
            if not 0 < swing <= np.pi:
                raise JaxanimError(f"specs[{i}].swing: expected a cone half angle in (0, pi], got {spec['swing']!r}")
        if "twist" in spec:
            lo, hi = _range(f"specs[{i}].twist", spec["twist"])
        limited = True
    return axis, axis2, limited, lo, hi, swing


def _range(name: str, value) -> tuple[float, float]:
    v = np.asarray(value, float)
    if v.shape != (2,) or not v[0] < v[1]:
        raise JaxanimError(f"{name}: expected (lower, upper) with lower < upper (radians), got {value!r}")
    if not (v[0] < np.pi and v[1] > -np.pi):
        raise JaxanimError(f"{name}: the range {value!r} excludes every angle in (-pi, pi]")
    return float(v[0]), float(v[1])


def joint_rows(joints: Joints, state: BodyState) -> tuple[Array, Array, Array]:
    """The constraint rows at ``state``: ``(J_parent [J, 6, 6], J_child [J, 6, 6], g [J, 6])``.

    Row ``k`` of joint ``j`` reads ``J_parent[j, k] . [v_p; omega_p] + J_child[j, k] . [v_c;
    omega_c]`` (world frame); rows beyond ``row_mask`` are zero. For a joint to the world the
    parent block multiplies zero velocities.
    """
    Jn = joints.num_joints
    dtype = state.position.dtype
    par = np.asarray(joints.parent)
    chi = np.asarray(joints.child)
    world = jnp.asarray(par < 0)[:, None]
    pidx = np.maximum(par, 0)
    qp = jnp.where(world, jnp.array([1.0, 0.0, 0.0, 0.0], dtype), state.orientation[pidx])
    xp = jnp.where(world, 0.0, state.position[pidx])
    qc = state.orientation[chi]
    xc = state.position[chi]
    a_p = rot.quat_apply(qp, joints.anchor_parent)
    a_c = rot.quat_apply(qc, joints.anchor_child)
    eye = jnp.broadcast_to(jnp.eye(3, dtype=dtype), (Jn, 3, 3))
    # Linear rows (every type).
    lin_p = jnp.concatenate([eye, -rot.skew(a_p)], axis=-1)  # [J, 3, 6]
    lin_c = jnp.concatenate([-eye, rot.skew(a_c)], axis=-1)
    g_lin = xp + a_p - xc - a_c
    # Angular rows of every type for every joint, then selected by the (static) type.
    n_p = rot.quat_apply(qp, joints.axis_parent)
    n_c = rot.quat_apply(qc, joints.axis_child)
    t1, t2 = rot.perpendicular_basis(n_p)
    zero = jnp.zeros((Jn, 3), dtype)
    hinge_T = jnp.stack([t1, t2, zero], axis=1)  # [J, 3, 3]
    hinge_g = einsum("jki,ji->jk", hinge_T, jnp.cross(n_p, n_c))
    u = jnp.cross(n_p, n_c)
    univ_T = jnp.stack([-u, zero, zero], axis=1)  # the row on omega_c; minus it on omega_p
    univ_g = jnp.stack([jnp.sum(n_p * n_c, axis=-1), zero[:, 0], zero[:, 0]], axis=1)
    q_err = rot.quat_multiply(qc, rot.quat_conjugate(rot.quat_multiply(qp, joints.rest)))
    kinds = np.asarray(joints.types)
    pick = lambda h, un, fx: jnp.where(  # noqa: E731
        jnp.asarray(kinds == "hinge").reshape((-1,) + (1,) * (h.ndim - 1)),
        h,
        jnp.where(
            jnp.asarray(kinds == "universal").reshape((-1,) + (1,) * (h.ndim - 1)),
            un,
            jnp.where(jnp.asarray(kinds == "fixed").reshape((-1,) + (1,) * (h.ndim - 1)), fx, jnp.zeros_like(h)),
        ),
    )
    ang_c = pick(hinge_T, univ_T, eye)  # [J, 3, 3] rows on omega_c; the parent gets minus them
    g_ang = pick(hinge_g, univ_g, rot.quat_to_rotvec(q_err))
    zeros33 = jnp.zeros((Jn, 3, 3), dtype)
    J_parent = jnp.concatenate([lin_p, jnp.concatenate([zeros33, -ang_c], axis=-1)], axis=1)
    J_child = jnp.concatenate([lin_c, jnp.concatenate([zeros33, ang_c], axis=-1)], axis=1)
    return J_parent, J_child, jnp.concatenate([g_lin, g_ang], axis=-1)


def limit_rows(joints: Joints, state: BodyState) -> tuple[np.ndarray, Array, Array]:
    """The limit rows at ``state``: ``(joint [L] (static), axis [L, 3], phi [L])``; row ``l`` reads
    ``axis[l]' (omega_c - omega_p) >= ...`` for joint ``joint[l]`` and ``phi[l]`` is its signed
    distance to the bound (radians, clipped to ``[-pi, 2 pi]``; see the module docstring)."""
    lim = np.asarray(joints.limited, bool)
    if not lim.any():
        return np.zeros((0,), int), jnp.zeros((0, 3), state.position.dtype), jnp.zeros((0,), state.position.dtype)
    dtype = state.position.dtype
    par = np.asarray(joints.parent)
    chi = np.asarray(joints.child)
    world = jnp.asarray(par < 0)[:, None]
    qp = jnp.where(world, jnp.array([1.0, 0.0, 0.0, 0.0], dtype), state.orientation[np.maximum(par, 0)])
    qc = state.orientation[chi]
    q_rel = rot.quat_multiply(rot.quat_conjugate(qp), qc)
    q_dev = rot.quat_canonical(rot.quat_multiply(q_rel, rot.quat_conjugate(joints.rest)))  # parent frame
    e = joints.axis_parent
    twist = 2.0 * jnp.arctan2(jnp.sum(q_dev[:, 1:] * e, axis=-1), q_dev[:, 0])
    twist = jnp.where(twist > jnp.pi, twist - 2 * jnp.pi, twist)
    n_p = rot.quat_apply(qp, e)
    n_c = rot.quat_apply(qc, joints.axis_child)
    cr = jnp.cross(n_p, n_c)
    sin = jnp.linalg.norm(cr, axis=-1)
    alpha = jnp.arctan2(sin, jnp.sum(n_p * n_c, axis=-1))
    t1, _ = rot.perpendicular_basis(n_p)
    s = jnp.where((sin > 1e-12)[:, None], cr / jnp.where(sin > 1e-12, sin, 1.0)[:, None], t1)
    bis = n_p + n_c
    bis = bis / jnp.maximum(jnp.linalg.norm(bis, axis=-1, keepdims=True), 1e-12)
    clip = lambda x: jnp.clip(x, -jnp.pi, 2 * jnp.pi)  # noqa: E731
    d_lo, d_hi = clip(twist - joints.lower), clip(joints.upper - twist)
    lower_near = d_lo < d_hi
    range_phi = jnp.where(lower_near, d_lo, d_hi)
    sign = jnp.where(lower_near, 1.0, -1.0)[:, None]
    hinge_axis = sign * n_p
    twist_axis = sign * bis
    swing_phi = clip(joints.swing - alpha)
    idx, axes, phis = [], [], []
    for j in np.nonzero(lim)[0]:
        if joints.types[j] == "hinge":
            idx.append(j)
            axes.append(hinge_axis[j])
            phis.append(range_phi[j])
        else:
            idx += [j, j]
            axes += [-s[j], twist_axis[j]]
            phis += [swing_phi[j], range_phi[j]]
    return np.asarray(idx, int), jnp.stack(axes), jnp.stack(phis)


def joint_errors(joints: Joints, state: BodyState, targets: Float[Array, "J 4"]) -> tuple[Array, Array]:
    """Per joint ``(e [J, 3], omega_rel [J, 3])`` in the world frame: the rotation vector taking the
    child's current orientation relative to its parent to ``targets`` (wxyz, ``q_p^{-1} q_c``),
    and ``omega_c - omega_p``."""
    par = np.asarray(joints.parent)
    chi = np.asarray(joints.child)
    world = jnp.asarray(par < 0)[:, None]
    dtype = state.position.dtype
    qp = jnp.where(world, jnp.array([1.0, 0.0, 0.0, 0.0], dtype), state.orientation[np.maximum(par, 0)])
    wp = jnp.where(world, 0.0, state.angular_velocity[np.maximum(par, 0)])
    qc = state.orientation[chi]
    target_world = rot.quat_multiply(qp, targets)  # the child's target orientation
    e = rot.quat_to_rotvec(rot.quat_canonical(rot.quat_multiply(target_world, rot.quat_conjugate(qc))))
    return e, state.angular_velocity[chi] - wp
