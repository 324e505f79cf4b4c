"""Robots as kinematic trees: the :class:`Robot` Module (a MuJoCo model's kinematic part).

A :class:`Robot` mirrors the kinematic fields of a compiled ``mujoco.MjModel`` (as MJX's ``Model``
does): the body tree, the joints on each body, the sites, the masses and centres of mass, and the
reference configuration ``qpos0``. Structure (names, parents, joint types and addresses) is static,
numbers are arrays, so a robot can be passed through ``jax.jit`` and closed over under ``jax.vmap``.

Conventions (MuJoCo's):
    * **bodies**: body 0 is the world (``"world"``, parent ``-1``; MuJoCo's ``body_parentid[0]`` is
      0), then the bodies in MuJoCo's order, which is depth first and topological
      (``body_parents[b] < b``). A body with no joint is fixed to its parent.
    * **joints**: in MuJoCo's order (by body, then in file order within a body). The types are
      ``"free"`` (7 qpos: position, then a wxyz quaternion; 6 dofs), ``"ball"`` (4 qpos: a wxyz
      quaternion; 3 dofs), ``"slide"`` and ``"hinge"`` (1 each). ``jnt_qposadr`` / ``jnt_dofadr``
      are each joint's first slot in ``qpos`` / ``qvel``.
    * a body's frame is its parent's frame times ``(body_pos, body_quat)``, then each of its joints
      in order: a hinge rotates by ``qpos - qpos0`` about ``jnt_axis`` through the anchor ``jnt_pos``
      (both in the body frame), a slide translates by ``qpos - qpos0`` along ``jnt_axis``, a ball
      rotates by the (normalised) qpos quaternion about the anchor, and a free joint sets the
      body's world pose from qpos (the body's own ``pos``/``quat`` only set ``qpos0``).
    * quaternions are wxyz; lengths in metres, angles in radians, masses in kilograms.
    * **ranges**: ``jnt_range [joints, 2]`` in radians (hinge, ball: ``[0, max angle]``) or metres
      (slide). A joint without a range (MuJoCo's ``jnt_limited`` false, every free joint) is
      recorded as unbounded: ``jnt_limited[j]`` is ``False`` and ``jnt_range[j] = (-inf, inf)``.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._errors import JaxanimError, check_shape
from .._types import Array, Float

JOINT_TYPES = ("free", "ball", "slide", "hinge")  # MuJoCo's mjtJoint order: mjJNT_FREE = 0, ...
JOINT_NQ = {"free": 7, "ball": 4, "slide": 1, "hinge": 1}
JOINT_NV = {"free": 6, "ball": 3, "slide": 1, "hinge": 1}
#: The geom types a :class:`Robot` keeps (MuJoCo's names; planes and height fields are not kept).
GEOM_TYPES = ("sphere", "capsule", "box", "cylinder", "ellipsoid", "mesh")


def _unknown(kind: str, name, valid: tuple[str, ...]) -> JaxanimError:
    return JaxanimError(f"unknown {kind} {name!r}; valid {kind} names: {[v for v in valid if v]}")


def _validate_structure(r: Robot) -> None:
    B, J, S = len(r.body_names), len(r.jnt_names), len(r.site_names)
    if B == 0:
        raise JaxanimError("body_names: a robot needs at least the world body")
    if len(r.body_parents) != B:
        raise JaxanimError(f"body_parents: expected {B} entries (one per body), got {len(r.body_parents)}")
    if r.body_parents[0] != -1:
        raise JaxanimError(f"body_parents: body 0 must be the world (parent -1), got parent {r.body_parents[0]}")
    for b, p in enumerate(r.body_parents[1:], start=1):
        if not 0 <= p < b:
            raise JaxanimError(
                f"body_parents: bodies must be topologically sorted (0 <= body_parents[b] < b); "
                f"body {b} ({r.body_names[b]!r}) has parent {p}"
            )
    for field in ("jnt_types", "jnt_bodies", "jnt_qposadr", "jnt_dofadr", "jnt_limited"):
        if len(getattr(r, field)) != J:
            raise JaxanimError(f"{field}: expected {J} entries (one per joint), got {len(getattr(r, field))}")
    bad = sorted({t for t in r.jnt_types if t not in JOINT_TYPES})
    if bad:
        raise JaxanimError(f"jnt_types: unknown joint types {bad}; valid: {list(JOINT_TYPES)}")
    qadr = vadr = 0
    for j in range(J):
        name, t, b = r.jnt_names[j], r.jnt_types[j], r.jnt_bodies[j]
        if not 1 <= b < B:
            raise JaxanimError(f"jnt_bodies: joint {j} ({name!r}) is on body {b}, expected 1 <= body < {B}")
        if j and b < r.jnt_bodies[j - 1]:
            raise JaxanimError(
                f"jnt_bodies: joints must be sorted by body (MuJoCo's order); joint {j} ({name!r}) is not"
            )
        if r.jnt_qposadr[j] != qadr or r.jnt_dofadr[j] != vadr:
            raise JaxanimError(
                f"jnt_qposadr / jnt_dofadr: joint {j} ({name!r}) starts at qpos {r.jnt_qposadr[j]} and dof "
                f"{r.jnt_dofadr[j]}, expected {qadr} and {vadr} (joints packed in order)"
            )
        if t == "free" and r.jnt_bodies.count(b) != 1:
            raise JaxanimError(f"jnt_types: the free joint {name!r} must be the only joint of its body")
        qadr += JOINT_NQ[t]
        vadr += JOINT_NV[t]
    if (qadr, vadr) != (r.nq, r.nv):
        raise JaxanimError(f"nq, nv: the joints need nq = {qadr} and nv = {vadr}, got nq = {r.nq} and nv = {r.nv}")
    if len(r.site_bodies) != S:
        raise JaxanimError(f"site_bodies: expected {S} entries (one per site), got {len(r.site_bodies)}")
    for s, b in enumerate(r.site_bodies):
        if not 0 <= b < B:
            raise JaxanimError(f"site_bodies: site {s} ({r.site_names[s]!r}) is on body {b}, expected 0 <= body < {B}")
    G = len(r.geom_bodies)
    if len(r.geom_types) != G:
        raise JaxanimError(f"geom_types: expected {G} entries (one per geom in geom_bodies), got {len(r.geom_types)}")
    bad = sorted({t for t in r.geom_types if t not in GEOM_TYPES})
    if bad:
        raise JaxanimError(f"geom_types: unknown geom types {bad}; valid: {list(GEOM_TYPES)}")
    for g, b in enumerate(r.geom_bodies):
        if not 1 <= b < B:
            raise JaxanimError(f"geom_bodies: geom {g} is on body {b}, expected 1 <= body < {B} (not the world)")


def _optional_array(x):
    return None if x is None else jnp.asarray(x)


class Robot(eqx.Module):
    """A robot's kinematic tree: bodies, joints (hinge, slide, ball, free), sites and masses.

    Build one with :func:`jaxanim.robots.load_robot` (MJCF or URDF) or
    :func:`jaxanim.robots.robot_from_mujoco` (a compiled ``mujoco.MjModel``). The fields are
    MuJoCo's, with MuJoCo's names; see the module docstring for the conventions.

    Attributes:
        name: the model's name. Static.
        body_names: ``[bodies]`` names, body 0 is ``"world"``. Static.
        body_parents: ``[bodies]`` parent body, ``-1`` for the world, ``body_parents[b] < b``. Static.
        jnt_names: ``[joints]`` names. Static.
        jnt_types: ``[joints]`` ``"free"``, ``"ball"``, ``"slide"`` or ``"hinge"``. Static.
        jnt_bodies: ``[joints]`` the body each joint moves (sorted). Static.
        jnt_qposadr, jnt_dofadr: ``[joints]`` first slot in ``qpos`` / ``qvel``. Static.
        jnt_limited: ``[joints]`` whether the joint has a range. Static.
        site_names, site_bodies: ``[sites]`` names and the body each is attached to. Static.
        nq, nv: sizes of ``qpos`` and ``qvel``. Static.
        body_pos: ``[bodies, 3]`` body frame origin in the parent frame (m).
        body_quat: ``[bodies, 4]`` body frame orientation in the parent frame, wxyz unit quaternion.
        body_ipos, body_iquat: ``[bodies, 3]``, ``[bodies, 4]`` centre of mass and principal axes in
            the body frame.
        body_mass: ``[bodies]`` mass (kg); the world's is 0.
        jnt_pos: ``[joints, 3]`` joint anchor in the body frame (m).
        jnt_axis: ``[joints, 3]`` unit axis of a hinge / slide in the body frame.
        jnt_range: ``[joints, 2]`` lower and upper bound (rad or m); ``(-inf, inf)`` where not limited.
        site_pos, site_quat: ``[sites, 3]``, ``[sites, 4]`` site pose in its body's frame.
        qpos0: ``[nq]`` the reference configuration (hinges and slides are measured from it).
        point_bodies: ``[points]`` the body of each surface point (static; empty: no geometry).
        point_pos: ``[points, 3]`` points of the bodies' geoms in the body frame (m): a sphere's or a
            capsule end's centre, a box's corners, points on a cylinder's rims and an ellipsoid's
            axes. A body's lowest surface point is ``min(z(point) - point_radius)`` over its points:
            what the retargeting keeps on and above the ground.
        point_radius: ``[points]`` the radius around each point (sphere, capsule; 0 for corners).
        geom_bodies: ``[geoms]`` the body of each collision geom (static; empty: no geometry). The geoms
            are MuJoCo's (``model.geom_*``), in its order, but those on the world and the planes and
            height fields.
        geom_types: ``[geoms]`` ``"sphere"``, ``"capsule"``, ``"box"``, ``"cylinder"``, ``"ellipsoid"`` or
            ``"mesh"`` (:data:`GEOM_TYPES`). Static.
        geom_size: ``[geoms, 3]`` MuJoCo's ``geom_size`` (m): a sphere's radius; a capsule's or a
            cylinder's radius and half length (along the geom's z); a box's and an ellipsoid's
            half sizes; a mesh's, what MuJoCo's compiler fitted (its points are in ``point_pos``).
        geom_pos, geom_quat: ``[geoms, 3]``, ``[geoms, 4]`` the geom's frame in its body's frame
            (m; wxyz unit quaternion).
        body_inertia: ``[bodies, 3]`` the diagonal inertia in the principal axes ``body_iquat``
            (kg m^2); ``None`` for a robot built without it (kinematics only).
        dof_armature, dof_damping, dof_frictionloss: ``[nv]`` each dof's armature (rotor inertia added
            to the mass matrix's diagonal), damping and dry friction; ``None``: 0.
        jnt_stiffness: ``[joints]`` the joints' springs, pulling toward ``qpos_spring`` ``[nq]``; ``None``: 0.
        gravity: ``[3]`` MuJoCo's ``opt.gravity`` (m/s^2); ``None``: ``(0, 0, -9.81)``.
        timestep: MuJoCo's ``opt.timestep`` (s); ``None``: 0.002.
        actuator_names: ``[actuators]`` names (static; empty: none).
        actuator_joints: ``[actuators]`` the hinge or slide each actuator drives, ``-1`` for one this
            library does not model (another transmission, activation dynamics or gain; static).
        actuator_gear: ``[actuators]`` the transmission's gear: the joint force is ``gear * force``.
        actuator_gain, actuator_bias: ``[actuators]``, ``[actuators, 3]`` MuJoCo's ``gainprm[0]`` and
            ``biasprm[:3]``: ``force = gain ctrl + bias[0] + bias[1] gear qpos + bias[2] gear qvel`` (a
            ``motor``: gain 1, bias 0; a ``position`` actuator: gain kp, bias ``(0, -kp, -kv)``).
        actuator_ctrlrange, actuator_forcerange: ``[actuators, 2]`` the clamps of ``ctrl`` and of the
            force (±inf where not limited).
        jnt_actfrcrange: ``[joints, 2]`` the clamp of all actuators' force on each joint (MuJoCo's
            ``actuatorfrcrange``; ±inf where not limited).
    """

    name: str = eqx.field(static=True)
    body_names: tuple[str, ...] = eqx.field(static=True)
    body_parents: tuple[int, ...] = eqx.field(static=True)
    jnt_names: tuple[str, ...] = eqx.field(static=True)
    jnt_types: tuple[str, ...] = eqx.field(static=True)
    jnt_bodies: tuple[int, ...] = eqx.field(static=True)
    jnt_qposadr: tuple[int, ...] = eqx.field(static=True)
    jnt_dofadr: tuple[int, ...] = eqx.field(static=True)
    jnt_limited: tuple[bool, ...] = eqx.field(static=True)
    site_names: tuple[str, ...] = eqx.field(static=True)
    site_bodies: tuple[int, ...] = eqx.field(static=True)
    nq: int = eqx.field(static=True)
    nv: int = eqx.field(static=True)
    body_pos: Float[Array, "bodies 3"] = eqx.field(converter=jnp.asarray)
    body_quat: Float[Array, "bodies 4"] = eqx.field(converter=jnp.asarray)
    body_ipos: Float[Array, "bodies 3"] = eqx.field(converter=jnp.asarray)
    body_iquat: Float[Array, "bodies 4"] = eqx.field(converter=jnp.asarray)
    body_mass: Float[Array, " bodies"] = eqx.field(converter=jnp.asarray)
    jnt_pos: Float[Array, "joints 3"] = eqx.field(converter=jnp.asarray)
    jnt_axis: Float[Array, "joints 3"] = eqx.field(converter=jnp.asarray)
    jnt_range: Float[Array, "joints 2"] = eqx.field(converter=jnp.asarray)
    site_pos: Float[Array, "sites 3"] = eqx.field(converter=jnp.asarray)
    site_quat: Float[Array, "sites 4"] = eqx.field(converter=jnp.asarray)
    qpos0: Float[Array, " nq"] = eqx.field(converter=jnp.asarray)
    point_bodies: tuple[int, ...] = eqx.field(static=True, default=())
    point_pos: Float[Array, "points 3"] = eqx.field(converter=jnp.asarray, default_factory=lambda: np.zeros((0, 3)))
    point_radius: Float[Array, " points"] = eqx.field(converter=jnp.asarray, default_factory=lambda: np.zeros((0,)))
    geom_bodies: tuple[int, ...] = eqx.field(static=True, default=())
    geom_types: tuple[str, ...] = eqx.field(static=True, default=())
    geom_size: Float[Array, "geoms 3"] = eqx.field(converter=jnp.asarray, default_factory=lambda: np.zeros((0, 3)))
    geom_pos: Float[Array, "geoms 3"] = eqx.field(converter=jnp.asarray, default_factory=lambda: np.zeros((0, 3)))
    geom_quat: Float[Array, "geoms 4"] = eqx.field(converter=jnp.asarray, default_factory=lambda: np.zeros((0, 4)))
    body_inertia: Float[Array, "bodies 3"] | None = eqx.field(converter=_optional_array, default=None)
    dof_armature: Float[Array, " nv"] | None = eqx.field(converter=_optional_array, default=None)
    dof_damping: Float[Array, " nv"] | None = eqx.field(converter=_optional_array, default=None)
    dof_frictionloss: Float[Array, " nv"] | None = eqx.field(converter=_optional_array, default=None)
    jnt_stiffness: Float[Array, " joints"] | None = eqx.field(converter=_optional_array, default=None)
    qpos_spring: Float[Array, " nq"] | None = eqx.field(converter=_optional_array, default=None)
    gravity: Float[Array, "3"] | None = eqx.field(converter=_optional_array, default=None)
    timestep: Float[Array, ""] | None = eqx.field(converter=_optional_array, default=None)
    actuator_names: tuple[str, ...] = eqx.field(static=True, default=())
    actuator_joints: tuple[int, ...] = eqx.field(static=True, default=())
    actuator_gear: Float[Array, " actuators"] | None = eqx.field(converter=_optional_array, default=None)
    actuator_gain: Float[Array, " actuators"] | None = eqx.field(converter=_optional_array, default=None)
    actuator_bias: Float[Array, "actuators 3"] | None = eqx.field(converter=_optional_array, default=None)
    actuator_ctrlrange: Float[Array, "actuators 2"] | None = eqx.field(converter=_optional_array, default=None)
    actuator_forcerange: Float[Array, "actuators 2"] | None = eqx.field(converter=_optional_array, default=None)
    jnt_actfrcrange: Float[Array, "joints 2"] | None = eqx.field(converter=_optional_array, default=None)

    def __check_init__(self):
        _validate_structure(self)
        B, J, S, U = self.num_bodies, self.num_joints, self.num_sites, len(self.actuator_names)
        if len(self.actuator_joints) != U or any(not -1 <= j < J for j in self.actuator_joints):
            raise JaxanimError(f"actuator_joints: expected {U} joint indices in [-1, {J}), got {self.actuator_joints}")
        for field, shape, what in (
            ("body_pos", (B, 3), "(bodies, 3)"), ("body_quat", (B, 4), "(bodies, 4)"),
            ("body_ipos", (B, 3), "(bodies, 3)"), ("body_iquat", (B, 4), "(bodies, 4)"),
            ("body_mass", (B,), "(bodies,)"),
            ("jnt_pos", (J, 3), "(joints, 3)"), ("jnt_axis", (J, 3), "(joints, 3)"),
            ("jnt_range", (J, 2), "(joints, 2)"),
            ("site_pos", (S, 3), "(sites, 3)"), ("site_quat", (S, 4), "(sites, 4)"),
            ("qpos0", (self.nq,), "(nq,)"),
            ("point_pos", (len(self.point_bodies), 3), "(points, 3)"),
            ("point_radius", (len(self.point_bodies),), "(points,)"),
            ("geom_size", (len(self.geom_bodies), 3), "(geoms, 3)"),
            ("geom_pos", (len(self.geom_bodies), 3), "(geoms, 3)"),
            ("geom_quat", (len(self.geom_bodies), 4), "(geoms, 4)"),
            ("body_inertia", (B, 3), "(bodies, 3)"),
            ("dof_armature", (self.nv,), "(nv,)"), ("dof_damping", (self.nv,), "(nv,)"),
            ("dof_frictionloss", (self.nv,), "(nv,)"), ("jnt_stiffness", (J,), "(joints,)"),
            ("qpos_spring", (self.nq,), "(nq,)"), ("gravity", (3,), "(3,)"), ("timestep", (), "()"),
            ("actuator_gear", (U,), "(actuators,)"), ("actuator_gain", (U,), "(actuators,)"),
            ("actuator_bias", (U, 3), "(actuators, 3)"), ("actuator_ctrlrange", (U, 2), "(actuators, 2)"),
            ("actuator_forcerange", (U, 2), "(actuators, 2)"), ("jnt_actfrcrange", (J, 2), "(joints, 2)"),
        ):  # fmt: skip
            if getattr(self, field) is not None:
                check_shape(field, getattr(self, field), shape, what=f"{what} = {tuple(shape)}")

    # --- cheap accessors -------------------------------------------------------------------------
    @property
    def num_bodies(self) -> int:
        """Number of bodies, the world included."""
        return len(self.body_names)

    @property
    def num_joints(self) -> int:
        return len(self.jnt_names)

    @property
    def num_sites(self) -> int:
        return len(self.site_names)

    @property
    def dof_joints(self) -> tuple[int, ...]:
        """``[nv]`` the joint of every dof (velocity coordinate / Jacobian column)."""
        return tuple(j for j, t in enumerate(self.jnt_types) for _ in range(JOINT_NV[t]))

    def body_index(self, name: str) -> int:
        """Index of a body by name; raises :class:`JaxanimError` listing the valid names."""
        if name in self.body_names and name:
            return self.body_names.index(name)
        raise _unknown("body", name, self.body_names)

    def joint_index(self, name: str) -> int:
        """Index of a joint by name; raises :class:`JaxanimError` listing the valid names."""
        if name in self.jnt_names and name:
            return self.jnt_names.index(name)
        raise _unknown("joint", name, self.jnt_names)

    def site_index(self, name: str) -> int:
        """Index of a site by name; raises :class:`JaxanimError` listing the valid names."""
        if name in self.site_names and name:
            return self.site_names.index(name)
        raise _unknown("site", name, self.site_names)

    def qpos_slice(self, name: str) -> slice:
        """The slots of joint ``name`` in ``qpos`` (7 for a free joint, 4 for a ball, else 1)."""
        j = self.joint_index(name)
        a = self.jnt_qposadr[j]
        return slice(a, a + JOINT_NQ[self.jnt_types[j]])

    def dof_slice(self, name: str) -> slice:
        """The slots of joint ``name`` in ``qvel`` and the Jacobians' columns."""
        j = self.joint_index(name)
        a = self.jnt_dofadr[j]
        return slice(a, a + JOINT_NV[self.jnt_types[j]])


def unbounded_range(jnt_range, jnt_limited) -> np.ndarray:
    """``jnt_range`` with the rows of joints that are not limited set to ``(-inf, inf)``."""
    rng = np.array(jnt_range, dtype=np.float64).reshape(-1, 2)
    lim = np.asarray(jnt_limited, dtype=bool).reshape(-1)
    rng[~lim] = (-np.inf, np.inf)
    return rng


def with_floating_base(robot: Robot, *, name: str = "root_joint") -> Robot:
    """The robot with a free joint on its root body: what ``load_robot(path, floating_base=True)`` gives.

    The joint, named ``name`` (Pinocchio's name for its free flyer), comes first in ``jnt_names``,
    ``qpos`` and ``qvel`` (MuJoCo's layout: its body is the first body), and its part of ``qpos0`` is the
    root body's pose in the file (``body_pos``, ``body_quat``), so the zero pose is unchanged.

    Raises:
        JaxanimError: if the robot has more than one body under the world, or its root body already has
            a joint.
    """
    roots = [b for b, p in enumerate(robot.body_parents) if p == 0]
    if len(roots) != 1:
        raise JaxanimError(f"robot: a floating base needs exactly one root body under the world, found "
                           f"{[robot.body_names[b] for b in roots]}")
    root = roots[0]
    if root in robot.jnt_bodies:
        raise JaxanimError(f"robot: the root body {robot.body_names[root]!r} already has joints "
                           f"{[n for n, b in zip(robot.jnt_names, robot.jnt_bodies) if b == root]}")
    if name in robot.jnt_names:
        raise JaxanimError(f"name: the robot already has a joint named {name!r}")
    dtype = robot.qpos0.dtype

    def first(row, x):
        return jnp.concatenate([jnp.asarray([row], dtype), x.astype(dtype)])

    return dataclasses.replace(
        robot, jnt_names=(name,) + robot.jnt_names, jnt_types=("free",) + robot.jnt_types,
        jnt_bodies=(root,) + robot.jnt_bodies, jnt_qposadr=(0,) + tuple(a + JOINT_NQ["free"] for a in robot.jnt_qposadr),
        jnt_dofadr=(0,) + tuple(a + JOINT_NV["free"] for a in robot.jnt_dofadr), jnt_limited=(False,) + robot.jnt_limited,
        nq=robot.nq + JOINT_NQ["free"], nv=robot.nv + JOINT_NV["free"], jnt_pos=first([0.0, 0.0, 0.0], robot.jnt_pos),
        jnt_axis=first([0.0, 0.0, 1.0], robot.jnt_axis), jnt_range=first([-np.inf, np.inf], robot.jnt_range),
        qpos0=jnp.concatenate([robot.body_pos[root].astype(dtype), robot.body_quat[root].astype(dtype), robot.qpos0]),
        **_free_joint_dynamics(robot, root))


def _free_joint_dynamics(robot: Robot, root: int) -> dict:
    """The dynamics fields of :func:`with_floating_base`'s robot: no armature, damping, friction or spring on
    the new free joint (its spring's rest is the root body's pose), no actuator force range on it, and the
    actuators' joint indices one further on."""
    out = {}
    for field, head in (("dof_armature", np.zeros(6)), ("dof_damping", np.zeros(6)),
                        ("dof_frictionloss", np.zeros(6)), ("jnt_stiffness", np.zeros(1))):
        x = getattr(robot, field)
        if x is not None:
            out[field] = jnp.concatenate([jnp.asarray(head, x.dtype), x])
    if robot.jnt_actfrcrange is not None:
        out["jnt_actfrcrange"] = jnp.concatenate([jnp.asarray([[-np.inf, np.inf]], robot.jnt_actfrcrange.dtype),
                                                  robot.jnt_actfrcrange])
    out["actuator_joints"] = tuple(j + 1 if j >= 0 else j for j in robot.actuator_joints)  # the new joint is first
    if robot.qpos_spring is not None:
        out["qpos_spring"] = jnp.concatenate([robot.body_pos[root], robot.body_quat[root],
                                              robot.qpos_spring]).astype(robot.qpos_spring.dtype)
    return out


def with_surface_points(robot: Robot, bodies, points, radii=None) -> Robot:
    """The robot with more surface points (:class:`Robot`'s ``point_pos``), appended after its own.

    Args:
        robot: the robot.
        bodies: ``[P]`` the body (index) each point is on.
        points: ``[P, 3]`` the points in their bodies' frames (m).
        radii: ``[P]`` the radius around each point (default 0: corners).
    """
    bodies = tuple(int(b) for b in bodies)
    points = np.asarray(points, np.float64).reshape(len(bodies), 3)
    radii = np.zeros(len(bodies)) if radii is None else np.asarray(radii, np.float64).reshape(len(bodies))
    bad = [b for b in bodies if not 0 < b < robot.num_bodies]
    if bad:
        raise JaxanimError(f"bodies: expected body indices in [1, {robot.num_bodies}), got {bad}")
    dtype = robot.point_pos.dtype
    return dataclasses.replace(
        robot, point_bodies=robot.point_bodies + bodies,
        point_pos=jnp.concatenate([robot.point_pos, jnp.asarray(points, dtype)]),
        point_radius=jnp.concatenate([robot.point_radius, jnp.asarray(radii, dtype)]))
