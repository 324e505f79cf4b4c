"""Loading robots: MJCF and URDF through MuJoCo's own compiler (the optional extra ``robots``).

Both formats are compiled by the ``mujoco`` package, so MJCF defaults, ``childclass``, degrees,
Euler angles, ``fromto``, quaternion normalisation and URDF ``<origin rpy>`` are all MuJoCo's; the
:class:`Robot` is then read from the compiled ``mujoco.MjModel``. Mesh files are never needed: an
MJCF whose mesh (or height-field, texture) files are missing is compiled without them.

A URDF keeps its ``<collision>`` geometry (what retargeting keeps on the ground), not its
``<visual>``: boxes, spheres and cylinders as they are; a mesh where its file resolves
(``package://NAME/...`` against the URDF's parent folders named ``NAME`` and the folders of
``ROS_PACKAGE_PATH``, a relative path against the URDF's folder) and MuJoCo reads its format (STL,
OBJ); each mesh whose file is missing or unreadable is skipped, all of them named in one warning.
A mesh's surface points are its extreme vertices along the 9 downward directions of its body's frame (its underside:
the sole, where the body is a foot).

URDF import (MuJoCo's): every link becomes a body (``fusestatic="false"``, so links behind fixed
joints, such as sole or sensor frames, stay bodies), named after the link; each ``revolute`` /
``continuous`` joint becomes a hinge, ``prismatic`` a slide and ``floating`` a free joint, named
after the URDF joint; ``fixed`` joints give no joint. Bodies (and so joints) come depth first from
the root link, the children of a link in the order of their ``<joint>`` elements in the file.
This is **not** Pinocchio's order (map by name). A ``continuous`` joint has no range, and a
``revolute`` one the range of its ``<limit>``. ``floating_base=True`` adds a free joint named
``"root_joint"`` (Pinocchio's name for its free flyer) on the root link, first in ``qpos``.
"""

from __future__ import annotations

import os
import pathlib
import warnings
import xml.etree.ElementTree as ET

import jax.numpy as jnp
import numpy as np

from .._errors import JaxanimError
from ._robot import GEOM_TYPES, JOINT_TYPES, Robot, unbounded_range

_INSTALL = "pip install 'jaxanim[robots]'"
#: The bound MuJoCo's compiler is given when a moving body has no mass (a kinematics-only URDF):
#: MuJoCo refuses to compile such a model; this mass changes the centre of mass by about 1e-12.
_TINY_MASS = 1e-12


class RobotLoadError(JaxanimError):
    """A robot description could not be read or compiled.

    Attributes:
        path: the file.
        message: the parser's or compiler's message.
    """

    def __init__(self, path, message: str):
        self.path = str(path)
        self.message = str(message).strip()
        super().__init__(f"{self.path}: {self.message}")


def _import_mujoco():
    try:
        import mujoco
    except ImportError as exc:
        raise ImportError(
            f"jaxanim.robots reads MJCF and URDF with MuJoCo, which is not installed: {_INSTALL}"
        ) from exc
    return mujoco


def _kind(path: pathlib.Path, text: str) -> str:
    """``"mjcf"`` or ``"urdf"`` from the root element (the suffix is not trusted)."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise RobotLoadError(path, f"not well-formed XML: {exc}") from None
    if root.tag == "mujoco":
        return "mjcf"
    if root.tag == "robot":
        return "urdf"
    raise RobotLoadError(path, f"expected an MJCF (<mujoco>) or URDF (<robot>) file, the root element is <{root.tag}>")


#: The mesh formats MuJoCo's compiler reads (a URDF's Collada ``.dae`` meshes are not among them).
_MESH_SUFFIXES = (".stl", ".obj", ".msh")
#: The URDF geometry MuJoCo imports besides meshes.
_PRIMITIVES = ("box", "sphere", "cylinder")


def _resolve_mesh(filename: str, urdf: pathlib.Path) -> pathlib.Path | None:
    """A URDF mesh's file on disk, or ``None``: ``package://NAME/rest`` is looked for under each parent
    folder of the URDF named ``NAME`` and under each folder of ``ROS_PACKAGE_PATH`` (``DIR/NAME/rest``, or
    ``DIR/rest`` where ``DIR`` is named ``NAME``); ``file://`` is a path; anything else is relative to the
    URDF's folder."""
    here = urdf.resolve().parent
    if filename.startswith("package://"):
        package, _, rest = filename[len("package://"):].partition("/")
        candidates = [parent / rest for parent in (here, *here.parents) if parent.name == package]
        for folder in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep):
            if folder:
                folder = pathlib.Path(folder)
                candidates += [folder / package / rest] + ([folder / rest] if folder.name == package else [])
    elif filename.startswith("file://"):
        candidates = [pathlib.Path(filename[len("file://"):])]
    else:
        candidates = [here / filename]
    return next((c.resolve() for c in candidates if c.is_file()), None)


def _urdf_text(text: str, path: pathlib.Path) -> str:
    """The URDF without ``<visual>``, its ``<collision>`` meshes resolved to absolute paths (those that do not
    resolve, or that MuJoCo cannot read, removed with one warning), with MuJoCo's compiler options."""
    root = ET.fromstring(text)
    skipped = []
    for link in root.iter("link"):
        for e in link.findall("visual"):
            link.remove(e)
        for e in link.findall("collision"):
            geometry = e.find("geometry")
            shape = geometry[0] if geometry is not None and len(geometry) else None
            if shape is None or shape.tag not in (*_PRIMITIVES, "mesh"):
                link.remove(e)
                continue
            if shape.tag != "mesh":
                continue
            name = shape.get("filename", "")
            found = _resolve_mesh(name, path)
            if found is None or found.suffix.lower() not in _MESH_SUFFIXES:
                why = "not found" if found is None else f"a {found.suffix} file, which MuJoCo does not read"
                skipped.append(f"{link.get('name')}: {name} ({why})")
                link.remove(e)
            else:
                shape.set("filename", str(found))
    if skipped:
        warnings.warn(f"{path}: {len(skipped)} collision mesh(es) skipped (the robot keeps its kinematics and its "
                      f"other collision geometry): {skipped}", stacklevel=3)
    mj = root.find("mujoco")
    if mj is None:
        mj = ET.SubElement(root, "mujoco")
    comp = mj.find("compiler")
    if comp is None:
        comp = ET.SubElement(mj, "compiler")
    # fusestatic="false": links behind fixed joints stay bodies; balanceinertia: some URDF inertias
    # break the triangle inequality (Romeo's), and MuJoCo refuses them; inertia is not read here.
    # strippath="false": the meshes' absolute paths are used as they are (MuJoCo keeps only the file name
    # of a URDF mesh by default).
    comp.attrib.update(fusestatic="false", discardvisual="true", balanceinertia="true", inertiafromgeom="false",
                       angle="radian", autolimits="true", strippath="false")
    return ET.tostring(root, encoding="unicode")


def _strip_files(spec) -> list[str]:
    """Delete the assets that need files (meshes, height fields, skins, textures) and the geoms that
    use them. Returns the bodies whose mass came from a deleted geom (no explicit inertial)."""
    mujoco = _import_mujoco()
    dropped_type = {mujoco.mjtGeom.mjGEOM_MESH, mujoco.mjtGeom.mjGEOM_HFIELD, mujoco.mjtGeom.mjGEOM_SDF}
    lost = []
    for geom in list(spec.geoms):
        if geom.type in dropped_type:
            body = geom.parent
            if not body.explicitinertial and body.name not in lost:
                lost.append(body.name)
            spec.delete(geom)
    for seq in ("skins", "meshes", "hfields"):
        for e in list(getattr(spec, seq)):
            spec.delete(e)
    for tex in list(spec.textures):
        if tex.file or any(tex.cubefiles):
            for mat in spec.materials:
                mat.textures = ["" if t == tex.name else t for t in mat.textures]
            spec.delete(tex)
    return lost


def _compile(spec, path):
    """Compile, recovering from missing asset files and massless moving bodies (kinematics only)."""
    stripped = False
    for _ in range(3):
        try:
            return spec.compile()
        except ValueError as exc:
            msg = str(exc)
            unreadable = "decoder" in msg or "mesh" in msg.lower()
            if not stripped and ("Error opening file" in msg or "resource not found" in msg.lower() or unreadable):
                lost = _strip_files(spec)
                stripped = True
                if unreadable:
                    warnings.warn(f"{path}: compiled without its meshes, one of which MuJoCo could not read: "
                                  f"{msg.strip()}", stacklevel=3)
                if lost:
                    warnings.warn(
                        f"{path}: compiled without its mesh / height-field files (kinematics only); these bodies "
                        f"took their mass from those geoms and now have less or none, so center_of_mass is off: {lost}",
                        stacklevel=3,
                    )
                continue
            if "mass and inertia of moving bodies" in msg and spec.compiler.boundmass < _TINY_MASS:
                spec.compiler.boundmass = _TINY_MASS
                spec.compiler.boundinertia = _TINY_MASS
                continue
            raise RobotLoadError(path, msg) from None
    raise RobotLoadError(path, "MuJoCo could not compile the model")  # pragma: no cover


def _add_free_joint(spec, path):
    roots = []
    b = spec.worldbody.first_body()
    while b is not None:
        roots.append(b)
        b = spec.worldbody.next_body(b)
    if len(roots) != 1:
        raise RobotLoadError(path, f"floating_base=True needs exactly one root body, found {len(roots)}: "
                                   f"{[r.name for r in roots]}")
    root = roots[0]
    if root.first_joint() is not None:
        raise RobotLoadError(path, f"floating_base=True: the root body {root.name!r} already has joints")
    root.add_freejoint(name="root_joint")


def load_robot(path: str | os.PathLike, *, floating_base: bool = False, dtype=None) -> Robot:
    """Read a robot from an MJCF or URDF file: its kinematic tree, masses and inertias, the joints'
    armature, damping and springs, and its actuators (mesh files are never needed).

    The format is taken from the root element (``<mujoco>`` or ``<robot>``), and both are compiled
    by MuJoCo (see the module docstring for the URDF import and its joint order).

    Args:
        path: the ``.xml`` (MJCF) or ``.urdf`` file. MJCF ``<include>``s are resolved relative to it.
        floating_base: add a free joint named ``"root_joint"`` to the root body (a URDF's root link,
            or the single top-level body of an MJCF that has no joint), as Pinocchio's
            ``JointModelFreeFlyer`` does. An MJCF's own free joints come from the file.
        dtype: floating dtype of the arrays (default: JAX's default float).

    Returns:
        The :class:`Robot`.

    Raises:
        ImportError: if ``mujoco`` is not installed (``pip install 'jaxanim[robots]'``).
        FileNotFoundError: if ``path`` does not exist.
        RobotLoadError: (a :class:`JaxanimError`) with the path and the parser's or compiler's message,
            if the file does not parse or compile.
    """
    mujoco = _import_mujoco()
    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"robot file not found: {path}")
    text = path.read_text()
    kind = _kind(path, text)
    try:
        if kind == "urdf":
            spec = mujoco.MjSpec.from_string(_urdf_text(text, path))
        else:
            spec = mujoco.MjSpec.from_file(str(path))
    except ValueError as exc:
        raise RobotLoadError(path, str(exc)) from None
    if floating_base:
        _add_free_joint(spec, path)
    model = _compile(spec, path)
    return robot_from_mujoco(model, dtype=dtype)


def _names(model, obj, n: int) -> tuple[str, ...]:
    mujoco = _import_mujoco()
    return tuple(mujoco.mj_id2name(model, obj, i) or "" for i in range(n))


#: The 9 downward directions (the cube's bottom face, its edges and corners) along which a mesh's extreme vertices
#: stand for it: its underside in its body's frame, the sole of a foot (all the surface points are for: the ground,
#: the sole's plane), which points around an ankle would tilt.
_DIRECTIONS = np.array([(x, y, -1) for x in (-1, 0, 1) for y in (-1, 0, 1)], np.float64)


def _surface_points(model) -> tuple[tuple[int, ...], np.ndarray, np.ndarray]:
    """``(bodies, points [P, 3], radii [P])``: each geom's points in its body's frame (see
    :class:`Robot`'s ``point_pos``). A mesh gives its extreme vertices along the 9 downward directions (its underside); planes and height fields give none."""
    mujoco = _import_mujoco()
    G = mujoco.mjtGeom
    bodies, points, radii = [], [], []
    ring = np.stack([np.cos(np.arange(8) * np.pi / 4), np.sin(np.arange(8) * np.pi / 4)], axis=1)
    for g in range(model.ngeom):
        b, t, size = int(model.geom_bodyid[g]), int(model.geom_type[g]), np.array(model.geom_size[g], np.float64)
        if b == 0:
            continue
        if t == G.mjGEOM_SPHERE:
            local, r = np.zeros((1, 3)), size[0]
        elif t == G.mjGEOM_CAPSULE:
            local, r = np.array([[0, 0, -size[1]], [0, 0, size[1]]]), size[0]
        elif t == G.mjGEOM_BOX:
            local, r = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * size, 0.0
        elif t == G.mjGEOM_CYLINDER:
            rim = np.concatenate([size[0] * ring, np.zeros((8, 1))], axis=1)
            local, r = np.concatenate([rim - [0, 0, size[1]], rim + [0, 0, size[1]]]), 0.0
        elif t == G.mjGEOM_ELLIPSOID:
            local, r = np.concatenate([np.diag(size), -np.diag(size)]), 0.0
        elif t == G.mjGEOM_MESH and model.geom_dataid[g] >= 0:
            m = int(model.geom_dataid[g])
            a, n = int(model.mesh_vertadr[m]), int(model.mesh_vertnum[m])
            local, r = np.array(model.mesh_vert[a:a + n], np.float64), 0.0
        else:
            continue
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, np.array(model.geom_quat[g], np.float64))
        pts = local @ R.reshape(3, 3).T + np.array(model.geom_pos[g], np.float64)
        if t == G.mjGEOM_MESH:  # its underside: the extreme vertices along the downward directions, body frame
            pts = pts[np.unique(np.argmax(pts @ _DIRECTIONS.T, axis=0))]
        bodies += [b] * len(pts)
        points.append(pts)
        radii += [r] * len(pts)
    pos = np.concatenate(points) if points else np.zeros((0, 3))
    return tuple(bodies), pos, np.asarray(radii, np.float64)


def _geoms(model) -> tuple[tuple[int, ...], tuple[str, ...], np.ndarray]:
    """``(bodies, types, index [G])``: the geoms a :class:`Robot` keeps (:data:`GEOM_TYPES`, not on the world),
    as MuJoCo's indices into ``model.geom_*``."""
    mujoco = _import_mujoco()
    kinds = {int(getattr(mujoco.mjtGeom, f"mjGEOM_{t.upper()}")): t for t in GEOM_TYPES}
    keep = [g for g in range(model.ngeom) if int(model.geom_bodyid[g]) > 0 and int(model.geom_type[g]) in kinds]
    return (tuple(int(model.geom_bodyid[g]) for g in keep), tuple(kinds[int(model.geom_type[g])] for g in keep),
            np.asarray(keep, np.int64))


def robot_from_mujoco(model, *, dtype=None) -> Robot:
    """The :class:`Robot` of a compiled ``mujoco.MjModel`` (its kinematic and dynamic fields, copied).

    Args:
        model: a ``mujoco.MjModel``.
        dtype: floating dtype of the arrays (default: JAX's default float).

    Raises:
        JaxanimError: if the model has mocap bodies (their pose is not in ``qpos``).
    """
    mujoco = _import_mujoco()
    if model.nmocap:
        raise JaxanimError("robot_from_mujoco: mocap bodies are not supported (their pose is not part of qpos)")
    dtype = jnp.result_type(float) if dtype is None else jnp.dtype(dtype)

    def arr(x, shape):
        return jnp.asarray(np.array(x, dtype=np.float64).reshape(shape), dtype=dtype)

    B, J, S = model.nbody, model.njnt, model.nsite
    parents = [int(p) for p in model.body_parentid]
    parents[0] = -1
    name = bytes(model.names).split(b"\0", 1)[0].decode()  # the model's name opens the names buffer
    point_bodies, point_pos, point_radius = _surface_points(model)
    geom_bodies, geom_types, geoms = _geoms(model)
    G = len(geoms)
    return Robot(
        name=name,
        body_names=_names(model, mujoco.mjtObj.mjOBJ_BODY, B),
        body_parents=tuple(parents),
        jnt_names=_names(model, mujoco.mjtObj.mjOBJ_JOINT, J),
        jnt_types=tuple(JOINT_TYPES[int(t)] for t in model.jnt_type),
        jnt_bodies=tuple(int(b) for b in model.jnt_bodyid),
        jnt_qposadr=tuple(int(a) for a in model.jnt_qposadr),
        jnt_dofadr=tuple(int(a) for a in model.jnt_dofadr),
        jnt_limited=tuple(bool(x) for x in model.jnt_limited),
        site_names=_names(model, mujoco.mjtObj.mjOBJ_SITE, S),
        site_bodies=tuple(int(b) for b in model.site_bodyid),
        nq=int(model.nq),
        nv=int(model.nv),
        body_pos=arr(model.body_pos, (B, 3)),
        body_quat=arr(model.body_quat, (B, 4)),
        body_ipos=arr(model.body_ipos, (B, 3)),
        body_iquat=arr(model.body_iquat, (B, 4)),
        body_mass=arr(model.body_mass, (B,)),
        jnt_pos=arr(model.jnt_pos, (J, 3)),
        jnt_axis=arr(model.jnt_axis, (J, 3)),
        jnt_range=arr(unbounded_range(model.jnt_range, model.jnt_limited), (J, 2)),
        site_pos=arr(model.site_pos, (S, 3)),
        site_quat=arr(model.site_quat, (S, 4)),
        qpos0=arr(model.qpos0, (model.nq,)),
        point_bodies=point_bodies,
        point_pos=arr(point_pos, (len(point_bodies), 3)),
        point_radius=arr(point_radius, (len(point_bodies),)),
        geom_bodies=geom_bodies,
        geom_types=geom_types,
        geom_size=arr(np.asarray(model.geom_size).reshape(-1, 3)[geoms], (G, 3)),
        geom_pos=arr(np.asarray(model.geom_pos).reshape(-1, 3)[geoms], (G, 3)),
        geom_quat=arr(np.asarray(model.geom_quat).reshape(-1, 4)[geoms], (G, 4)),
        body_inertia=arr(model.body_inertia, (B, 3)),
        dof_armature=arr(model.dof_armature, (model.nv,)),
        dof_damping=arr(model.dof_damping, (model.nv,)),
        dof_frictionloss=arr(model.dof_frictionloss, (model.nv,)),
        jnt_stiffness=arr(model.jnt_stiffness, (J,)),
        qpos_spring=arr(model.qpos_spring, (model.nq,)),
        gravity=arr(model.opt.gravity, (3,)),
        timestep=arr(model.opt.timestep, ()),
        **_actuators(model, arr, mujoco),
    )


def _actuators(model, arr, mujoco) -> dict:
    """The actuators' fields of :class:`Robot`: those on a hinge or slide, without activation dynamics, with
    a fixed gain and an affine bias or none (``motor``, ``position``, ``velocity``) are modelled; the others
    get joint -1."""
    U, J = model.nu, model.njnt
    hinge_or_slide = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    bias_kinds = (int(mujoco.mjtBias.mjBIAS_NONE), int(mujoco.mjtBias.mjBIAS_AFFINE))
    joints = []
    for i in range(U):  # the enums compared as ints (a NumPy integer is not `in` a tuple of them)
        j = int(model.actuator_trnid[i, 0])
        ok = (int(model.actuator_trntype[i]) == int(mujoco.mjtTrn.mjTRN_JOINT)
              and int(model.jnt_type[j]) in hinge_or_slide
              and int(model.actuator_dyntype[i]) == int(mujoco.mjtDyn.mjDYN_NONE)
              and int(model.actuator_gaintype[i]) == int(mujoco.mjtGain.mjGAIN_FIXED)
              and int(model.actuator_biastype[i]) in bias_kinds)
        joints.append(j if ok else -1)
    affine = np.asarray(model.actuator_biastype).reshape(U) == int(mujoco.mjtBias.mjBIAS_AFFINE)
    bias = np.where(affine[:, None], np.asarray(model.actuator_biasprm).reshape(U, mujoco.mjNBIAS)[:, :3], 0.0)
    return {
        "actuator_names": _names(model, mujoco.mjtObj.mjOBJ_ACTUATOR, U),
        "actuator_joints": tuple(joints),
        "actuator_gear": arr(np.asarray(model.actuator_gear).reshape(U, 6)[:, 0], (U,)),
        "actuator_gain": arr(np.asarray(model.actuator_gainprm).reshape(U, mujoco.mjNGAIN)[:, 0], (U,)),
        "actuator_bias": arr(bias, (U, 3)),
        "actuator_ctrlrange": arr(unbounded_range(model.actuator_ctrlrange, model.actuator_ctrllimited), (U, 2)),
        "actuator_forcerange": arr(unbounded_range(model.actuator_forcerange, model.actuator_forcelimited), (U, 2)),
        "jnt_actfrcrange": arr(unbounded_range(model.jnt_actfrcrange, model.jnt_actfrclimited), (J, 2)),
    }
