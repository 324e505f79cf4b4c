"""Export of a :class:`~jaxanim.physics.PhysicsModel` to MuJoCo's MJCF (:func:`to_mjcf`)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .. import rotations as rot
from .._errors import JaxanimError
from ._bodies import BodyState
from ._model import PhysicsModel

__all__ = ["to_mjcf"]


def _fmt(v) -> str:
    return " ".join(f"{float(x):.17g}" for x in np.ravel(v))


def _quat_between(q_parent: np.ndarray, q_child: np.ndarray) -> np.ndarray:
    return np.asarray(rot.quat_multiply(rot.quat_conjugate(jnp.asarray(q_parent)), jnp.asarray(q_child)))


def _springs(num_joints: int, **values) -> dict[str, np.ndarray]:
    """Each given per-joint spring parameter (``[joints]`` or a scalar) as a ``[joints]`` array."""
    springs = {}
    for key, value in values.items():
        if value is not None:
            arr = np.broadcast_to(np.asarray(value, float), (num_joints,)) if np.ndim(value) == 0 else np.asarray(
                value, float)
            if arr.shape != (num_joints,):
                raise JaxanimError(f"{key}: expected a scalar or shape ({num_joints},) (one per joint), got {arr.shape}")
            springs[key] = arr
    return springs


def _geom(model: PhysicsModel, b: int, size: np.ndarray, collide: bool) -> str:
    """Body ``b``'s shape as a MuJoCo geom (capsules along body ``z``), colliding with the ground only."""
    bodies = model.bodies
    kind = bodies.shapes[b]
    if kind == "box":
        shape = f'type="box" size="{_fmt(size / 2)}"'
    elif kind == "sphere":
        shape = f'type="sphere" size="{_fmt(size[:1])}"'
    else:
        shape = f'type="capsule" size="{_fmt([size[0], size[1] / 2])}"'
    flags = (f'contype="1" conaffinity="0" condim="3" friction="{float(model.ground.friction):.17g} 0 0"'
             if collide else 'contype="0" conaffinity="0"')
    return f'<geom name="{bodies.names[b]}_geom" {shape} {flags}/>'


def to_mjcf(
    model: PhysicsModel, state: BodyState, *, dt: float = 1 / 600, name: str = "jaxanim",
    stiffness: ArrayLike | None = None, damping: ArrayLike | None = None,
) -> str:
    """The model as MuJoCo XML, assembled at ``state``.

    Each body becomes a MuJoCo body whose frame is the body's frame (origin at its center of
    mass), with an explicit ``inertial`` (mass and full inertia, so MuJoCo does not recompute them
    from the geoms) and its shape as a geom (capsules along body ``z``, as in MuJoCo). Bodies are
    nested along the joints; a ball joint becomes ``type="ball"``, a hinge ``type="hinge"``, a
    universal joint two hinges, a fixed joint no joint (welded), and a body that is no joint's
    child gets a ``freejoint``. A hinge's range becomes MuJoCo's ``range`` (MuJoCo's ball ``range``
    bounds the total rotation angle, not a swing cone and twist, so ball limits are not exported).
    Gravity and the time step are written in ``option``
    (``integrator="Euler"``).

    Contact: with ``model.ground`` of model ``"none"`` no geom collides. Otherwise the ground
    becomes a ``plane`` geom (its normal and offset, the ground's friction) and every body geom
    collides with it but not with other bodies (``contype="1" conaffinity="0"``, the plane
    ``contype="0" conaffinity="1"``), ``condim="3"`` (Coulomb friction), as jaxanim's contact model.

    Args:
        stiffness, damping: optional per-joint (``[J]`` or a scalar) spring stiffness (N m / rad)
            and damping (N m s / rad) pulling each joint to its assembly pose (MuJoCo's joint
            ``stiffness`` / ``damping``, whose spring reference is the assembly configuration
            ``qpos0``): a PD hold of the pose at ``state`` for comparisons with :func:`step`'s
            ``spd``; MuJoCo's Euler integrator treats the damping implicitly.

    Raises:
        JaxanimError: a body has two parent joints (the joints do not form a forest), or
            ``stiffness`` / ``damping`` of the wrong shape.
    """
    bodies, joints = model.bodies, model.joints
    springs = _springs(joints.num_joints, stiffness=stiffness, damping=damping)
    collide = model.ground.model != "none"
    x = np.asarray(state.position, float)
    q = np.asarray(state.orientation, float)
    Rm = np.asarray(rot.quat_to_matrix(jnp.asarray(q)))
    parent_joint = {}
    for j, c in enumerate(joints.child):
        if c in parent_joint:
            raise JaxanimError(f"to_mjcf: body {bodies.names[c]!r} has two parent joints")
        parent_joint[c] = j
    children: dict[int, list[int]] = {}
    for c, j in parent_joint.items():
        children.setdefault(joints.parent[j], []).append(c)
    I = np.asarray(bodies.inertia, float)
    size = np.asarray(bodies.size, float)
    ap = np.asarray(joints.anchor_parent, float)
    ac = np.asarray(joints.anchor_child, float)
    ep = np.asarray(joints.axis_parent, float)
    ec = np.asarray(joints.axis_child, float)

    def body_xml(b, parent, indent):
        pad = "  " * indent
        if parent < 0:
            pos, quat = x[b], q[b]
        else:
            pos = Rm[parent].T @ (x[b] - x[parent])
            quat = _quat_between(q[parent], q[b])
        lines = [f'{pad}<body name="{bodies.names[b]}" pos="{_fmt(pos)}" quat="{_fmt(quat)}">']
        Ib = I[b]
        lines.append(
            f'{pad}  <inertial pos="0 0 0" mass="{float(bodies.mass[b]):.17g}" '
            f'fullinertia="{_fmt([Ib[0, 0], Ib[1, 1], Ib[2, 2], Ib[0, 1], Ib[0, 2], Ib[1, 2]])}"/>'
        )
        j = parent_joint.get(b)
        if j is None:
            lines.append(f'{pad}  <freejoint name="{bodies.names[b]}_free"/>')
        else:
            kind = joints.types[j]
            jname = joints.names[j]
            anchor = _fmt(ac[j])
            extra = "".join(f' {k}="{v[j]:.17g}"' for k, v in springs.items())
            if kind == "ball":
                lines.append(f'{pad}  <joint name="{jname}" type="ball" pos="{anchor}"{extra}/>')
            elif kind == "hinge":
                if joints.limited[j]:
                    extra += f' limited="true" range="{_fmt([joints.lower[j], joints.upper[j]])}"'
                lines.append(f'{pad}  <joint name="{jname}" type="hinge" pos="{anchor}" axis="{_fmt(ec[j])}"{extra}/>')
            elif kind == "universal":
                p = joints.parent[j]
                Rp = np.eye(3) if p < 0 else Rm[p]
                first = Rm[b].T @ (Rp @ ep[j])  # the parent-side axis in the child frame at assembly
                lines.append(f'{pad}  <joint name="{jname}_1" type="hinge" pos="{anchor}" axis="{_fmt(first)}"{extra}/>')
                lines.append(f'{pad}  <joint name="{jname}_2" type="hinge" pos="{anchor}" axis="{_fmt(ec[j])}"{extra}/>')
        lines.append(f"{pad}  {_geom(model, b, size[b], collide)}")
        for c in children.get(b, []):
            lines.extend(body_xml(c, b, indent + 1))
        lines.append(f"{pad}</body>")
        return lines

    g = np.asarray(bodies.gravity, float)
    out = [
        f'<mujoco model="{name}">',
        '  <compiler angle="radian" inertiafromgeom="false"/>',
        f'  <option timestep="{dt:.17g}" gravity="{_fmt(g)}" integrator="Euler"/>',
        "  <worldbody>",
    ]
    if collide:
        n = np.asarray(model.ground.normal, float)
        qz = np.asarray(rot.rotation_between(jnp.array([0.0, 0.0, 1.0]), jnp.asarray(n)))
        out.append(
            f'    <geom name="ground" type="plane" size="0 0 1" pos="{_fmt(float(model.ground.offset) * n)}" '
            f'quat="{_fmt(qz)}" contype="0" conaffinity="1" condim="3" '
            f'friction="{float(model.ground.friction):.17g} 0 0"/>'
        )
    roots = [b for b in range(bodies.num_bodies) if b not in parent_joint or joints.parent[parent_joint[b]] < 0]
    for b in roots:
        out.extend(body_xml(b, -1, 2))
    out += ["  </worldbody>", "</mujoco>", ""]
    del ap  # the parent anchor is implied by the assembly pose
    return "\n".join(out)
