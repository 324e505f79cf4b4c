"""A retargeted robot clip beside its source: reading the ``jaxanim retarget`` .npz, and laying it out.

:func:`load_retarget` reads and checks the .npz (or a dict with the same keys) into a
:class:`RetargetClip`, which ``jaxanim render RESULT.npz`` (and ``jaxanim retarget --render OUT.gif``,
through :func:`._render.render_retarget`) and ``jaxanim view RESULT.npz`` draw.

The .npz layout (every position in the robot's world frame: Z up, metres, ground at z = 0):

* ``fps`` scalar; ``body_names [B]``, ``body_parents [B]`` (body 0 is the world, parent -1;
  ``parents[b] < b``), ``body_positions [T, B, 3]`` (MuJoCo ``xpos``);
* ``source_names [J]``, ``source_parents [J]`` (-1: a root; ``parents[j] < j``),
  ``source_positions [T, J, 3]`` (the source clip's joints, scaled and aligned into the robot's
  frame);
* optional: ``qpos [T, nq]``, ``joint_names``, ``feet [F]`` with ``contacts [T, F]`` (the source's
  stance frames per foot), ``robot``, ``source``, ``map`` (file paths), per-frame diagnostics
  (ignored here);
* optional, all or none (the robot's collision geometry, :class:`RobotGeometry`; without them the
  robot is drawn as sticks between its body origins): ``body_xmat [T, B, 3, 3]`` (MuJoCo ``xmat``:
  body -> world rotations), the geoms ``geom_body [G]``, ``geom_type [G]`` (``"sphere"``,
  ``"capsule"``, ``"box"``, ``"cylinder"``, ``"ellipsoid"``, ``"mesh"``), ``geom_size [G, 3]``,
  ``geom_pos [G, 3]``, ``geom_quat [G, 4]`` (MuJoCo's fields, in the body's frame, wxyz), and the
  surface points ``point_body [P]``, ``point_pos [P, 3]`` (the robot's ``point_pos`` as retargeting
  prepared it: a mesh's extreme vertices, and the soles it gave feet without geometry).

:func:`retarget_arrays` builds these arrays from a solve, for ``jaxanim retarget`` and ``jaxanim demo``.

:func:`retarget_scene` lays the two out as one point set for drawing: the robot's bodies (not the
world body, nor the sticks to it), and the source skeleton beside it, shifted along world +Y by
:func:`source_shift` so the two never overlap. :func:`._render.render_retarget` draws it into a GIF
or MP4, and :func:`._view.build_viewer` into the browser.
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib
import zipfile
import zlib
from collections.abc import Mapping

import numpy as np

from .._errors import JaxanimError

__all__ = ["RetargetClip", "RetargetScene", "RobotGeometry", "is_retarget_file", "load_retarget", "retarget_arrays",
           "retarget_scene", "source_shift"]

_REQUIRED = ("fps", "body_names", "body_parents", "body_positions", "source_names", "source_parents",
             "source_positions")
#: The robot's geometry: all of these or none.
_GEOMETRY = ("body_xmat", "geom_body", "geom_type", "geom_size", "geom_pos", "geom_quat", "point_body", "point_pos")
_OPTIONAL = ("qpos", "joint_names", "feet", "contacts", "robot", "source", "map", *_GEOMETRY)
#: The geom types of a result (``jaxanim.robots.Robot``'s ``geom_types``).
GEOM_TYPES = ("sphere", "capsule", "box", "cylinder", "ellipsoid", "mesh")


@dataclasses.dataclass
class RobotGeometry:
    """A robot's collision geometry, as a retarget result holds it (MuJoCo's fields; body frames).

    Attributes:
        geom_body: ``[G]`` the body of each geom (never the world).
        geom_type: ``G`` types, each one of :data:`GEOM_TYPES`.
        geom_size: ``[G, 3]`` MuJoCo's ``geom_size``, m (sphere: radius; capsule, cylinder: radius and half
            length along the geom's z; box, ellipsoid: half sizes).
        geom_pos, geom_quat: ``[G, 3]``, ``[G, 4]`` the geom's frame in its body's frame (m; wxyz).
        point_body, point_pos: ``[P]``, ``[P, 3]`` the robot's surface points in their bodies' frames (m).
    """

    geom_body: np.ndarray
    geom_type: tuple[str, ...]
    geom_size: np.ndarray
    geom_pos: np.ndarray
    geom_quat: np.ndarray
    point_body: np.ndarray
    point_pos: np.ndarray


@dataclasses.dataclass
class RetargetClip:
    """A robot clip and its source, as read from a retarget result (:func:`load_retarget`).

    Attributes:
        label: what to call it in messages (the file, or ``"<mapping>"``).
        path: the file (``None`` for a mapping).
        fps: the clip's frame rate.
        body_names, body_parents: ``B`` bodies, body 0 the world.
        body_positions: ``[T, B, 3]`` world position of each body origin, m (Z up).
        source_names, source_parents: ``J`` joints of the source skeleton.
        source_positions: ``[T, J, 3]`` the source's joints in the robot's frame, m (not shifted).
        feet: ``F`` foot names (empty without contacts).
        contacts: ``[T, F]`` the source's stance frames per foot.
        robot, source: the robot file and the source BVH named in the result ("" where absent).
        geometry: the robot's collision geometry (``None`` in a result without it: sticks are drawn).
        body_xmat: ``[T, B, 3, 3]`` body -> world rotations (``None`` without ``geometry``).
    """

    label: str
    path: pathlib.Path | None
    fps: float
    body_names: tuple[str, ...]
    body_parents: np.ndarray
    body_positions: np.ndarray
    source_names: tuple[str, ...]
    source_parents: np.ndarray
    source_positions: np.ndarray
    feet: tuple[str, ...] = ()
    contacts: np.ndarray | None = None
    robot: str = ""
    source: str = ""
    geometry: RobotGeometry | None = None
    body_xmat: np.ndarray | None = None

    @property
    def num_frames(self) -> int:
        return self.body_positions.shape[0]

    @property
    def frame_time(self) -> float:
        return 1.0 / self.fps

    @property
    def stem(self) -> str:
        return self.path.stem if self.path is not None else "retarget"

    @property
    def name(self) -> str:
        return self.path.name if self.path is not None else "retarget result"

    @property
    def robot_name(self) -> str:
        return pathlib.Path(self.robot).name if self.robot else "robot"

    @property
    def source_name(self) -> str:
        return pathlib.Path(self.source).name if self.source else "source"

    def robot_sticks(self) -> np.ndarray:
        """``[sticks, 2]`` (body, parent) pairs of body indices, without the world and the sticks to it."""
        pairs = [(b, int(p)) for b, p in enumerate(self.body_parents) if b > 0 and p > 0]
        return np.array(pairs, np.int64).reshape(-1, 2)

    def source_bones(self) -> np.ndarray:
        """``[bones, 2]`` (joint, parent) pairs of source joint indices."""
        pairs = [(j, int(p)) for j, p in enumerate(self.source_parents) if p >= 0]
        return np.array(pairs, np.int64).reshape(-1, 2)

    def foot_points(self) -> list[tuple[str, int]]:
        """For each foot, ``("robot", body)`` or ``("source", joint)`` where the name is found, else
        ``("", -1)``."""
        out = []
        for f in self.feet:
            if f in self.body_names[1:]:
                out.append(("robot", self.body_names.index(f, 1)))
            elif f in self.source_names:
                out.append(("source", self.source_names.index(f)))
            else:
                out.append(("", -1))
        return out


# ------------------------------------------------------------------------------------------------
# Reading and checking
# ------------------------------------------------------------------------------------------------


def is_retarget_file(file) -> bool:
    """Whether a command-line file argument names a retarget result: an ``.npz`` with ``qpos`` (an AMASS clip,
    also an ``.npz``, has none; one that cannot be read is taken as a result, whose reader names the fault)."""
    if file is None or isinstance(file, Mapping) or not os.fspath(file).lower().endswith(".npz"):
        return False
    try:
        with zipfile.ZipFile(file) as z:
            return "qpos.npy" in z.namelist()
    except (OSError, zipfile.BadZipFile):
        return True


def _read_npz(path: pathlib.Path, label: str) -> dict[str, np.ndarray]:
    try:
        archive = np.load(path, allow_pickle=False)
    except OSError as exc:
        raise JaxanimError(f"{label}: cannot read the file: {exc.strerror or exc}") from None
    except ValueError as exc:  # not an npz / npy at all
        raise JaxanimError(f"{label}: not an .npz archive ({exc})") from None
    if not isinstance(archive, np.lib.npyio.NpzFile):
        raise JaxanimError(f"{label}: not an .npz archive (a single .npy array)")
    data = {}
    with archive:
        for key in (*_REQUIRED, *_OPTIONAL):
            if key not in archive.files:
                continue
            try:
                data[key] = archive[key]
            except ValueError as exc:
                if "pickle" in str(exc):  # an object array
                    raise JaxanimError(f"{label}: key {key!r}: an object array, which is not read (it would need "
                                       "pickle); save strings as np.array(names, dtype=str)") from None
                raise JaxanimError(f"{label}: key {key!r}: cannot read it ({exc})") from None
            except (OSError, EOFError, zipfile.BadZipFile, zlib.error) as exc:  # a corrupt member
                raise JaxanimError(f"{label}: key {key!r}: cannot read it ({exc})") from None
    return data


def _shape(label: str, key: str, a: np.ndarray, expected: tuple, what: str, why: str = "") -> None:
    if a.ndim != len(expected) or any(e is not None and s != e for s, e in zip(a.shape, expected)):
        raise JaxanimError(f"{label}: key {key!r}: expected shape {what}{why}, got {a.shape}")


def _numbers(label: str, key: str, a: np.ndarray) -> np.ndarray:
    if not (np.issubdtype(a.dtype, np.number) or a.dtype == np.bool_) or np.issubdtype(a.dtype, np.complexfloating):
        raise JaxanimError(f"{label}: key {key!r}: expected numbers, got dtype {a.dtype}")
    return a


def _strings(label: str, key: str, a: np.ndarray, n: int | None, what: str) -> tuple[str, ...]:
    if a.dtype.kind not in "US":
        raise JaxanimError(f"{label}: key {key!r}: expected strings, got dtype {a.dtype}")
    _shape(label, key, a, (n,), what)
    return tuple(x.decode() if isinstance(x, bytes) else str(x) for x in a.tolist())


def _scalar_string(label: str, key: str, a) -> str:
    if a is None:
        return ""
    a = np.asarray(a)
    if a.dtype.kind not in "US" or a.shape != ():
        raise JaxanimError(f"{label}: key {key!r}: expected a string (shape ()), got dtype {a.dtype}, shape {a.shape}")
    x = a.item()
    return x.decode() if isinstance(x, bytes) else str(x)


def _integers(label: str, key: str, a: np.ndarray, shape: tuple, what: str, kind: str) -> np.ndarray:
    """``a`` as int64 indices of ``shape``; a clear error naming the key otherwise."""
    _numbers(label, key, a)
    _shape(label, key, a, shape, what)
    if a.dtype == np.bool_ or (np.issubdtype(a.dtype, np.floating) and not np.all(a == np.round(a))):
        raise JaxanimError(f"{label}: key {key!r}: expected integer {kind} indices, got dtype {a.dtype}")
    return a.astype(np.int64)


def _parents(label: str, key: str, a: np.ndarray, n: int, what: str) -> np.ndarray:
    p = _integers(label, key, a, (n,), what, "parent")
    bad = [i for i, q in enumerate(p) if not -1 <= q < i]
    if bad:
        i = bad[0]
        raise JaxanimError(f"{label}: key {key!r}: entry {i} is {p[i]}: expected -1 (a root) or a parent index "
                           f"below {i} (parents come first)")
    return p


def _positions(label: str, key: str, a: np.ndarray, T: int | None, n: int, what: str, t_from: str) -> np.ndarray:
    _numbers(label, key, a)
    why = f" with T = {T} frames as in {t_from!r}" if T is not None else ""
    _shape(label, key, a, (T, n, 3), f"(T, {what}, 3) = ({'T' if T is None else T}, {n}, 3)", why)
    p = a.astype(np.float64)
    if not np.isfinite(p).all():
        t, i = np.argwhere(~np.isfinite(p).all(axis=-1))[0]
        raise JaxanimError(f"{label}: key {key!r}: not all finite (the first at frame {t}, index {i}: "
                           f"{p[t, i].tolist()}); cannot draw it")
    return p


def _finite(label: str, key: str, a: np.ndarray, shape: tuple, what: str) -> np.ndarray:
    _numbers(label, key, a)
    _shape(label, key, a, shape, what)
    a = a.astype(np.float64)
    if not np.isfinite(a).all():
        raise JaxanimError(f"{label}: key {key!r}: not all finite (the first at index "
                           f"{tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])}); cannot draw it")
    return a


def _bodies(label: str, key: str, a: np.ndarray, B: int, what: str) -> np.ndarray:
    b = _integers(label, key, a, (None,), what, "body")
    bad = [i for i, x in enumerate(b) if not 1 <= x < B]
    if bad:
        raise JaxanimError(f"{label}: key {key!r}: entry {bad[0]} is {b[bad[0]]}: expected a body index in [1, {B}) "
                           "(not the world)")
    return b


def _geometry(label: str, data: dict, T: int, B: int) -> tuple[RobotGeometry, np.ndarray] | None:
    """The robot's geometry and ``body_xmat``, checked, or ``None`` where the result has none."""
    have = [k for k in _GEOMETRY if k in data]
    if not have:
        return None
    lack = [k for k in _GEOMETRY if k not in data]
    if lack:
        raise JaxanimError(f"{label}: key {lack[0]!r} is missing: {have[0]!r} needs it (the robot's geometry is "
                           f"{', '.join(_GEOMETRY)}, all or none)")
    xmat = _finite(label, "body_xmat", data["body_xmat"], (T, B, 3, 3), f"(T, B, 3, 3) = ({T}, {B}, 3, 3)")
    body = _bodies(label, "geom_body", data["geom_body"], B, "(G,)")
    G = len(body)
    types = _strings(label, "geom_type", data["geom_type"], G, f"(G,) = ({G},)")
    bad = sorted({t for t in types if t not in GEOM_TYPES})
    if bad:
        raise JaxanimError(f"{label}: key 'geom_type': unknown geom types {bad}; valid: {list(GEOM_TYPES)}")
    size, pos, quat = (_finite(label, k, data[k], (G, n), f"(G, {n}) = ({G}, {n})")
                       for k, n in (("geom_size", 3), ("geom_pos", 3), ("geom_quat", 4)))
    point_body = _bodies(label, "point_body", data["point_body"], B, "(P,)")
    P = len(point_body)
    point_pos = _finite(label, "point_pos", data["point_pos"], (P, 3), f"(P, 3) = ({P}, 3)")
    return RobotGeometry(body, types, size, pos, quat, point_body, point_pos), xmat


def load_retarget(npz_path_or_mapping, *, label: str | None = None) -> RetargetClip:
    """Read and check a retarget result.

    Args:
        npz_path_or_mapping: the path of the .npz ``jaxanim retarget`` wrote, or a mapping with the
            same keys (arrays, lists or strings); see the module docstring for the layout.
        label: what to call it in messages (default: the path, or ``"<mapping>"``).

    Returns:
        A :class:`RetargetClip` (positions as float64 copies; the input is not modified).

    Raises:
        JaxanimError: the file cannot be read or is not an .npz; a key is missing, has the wrong
            shape or dtype, or a position is not finite; the message names the file and the key.
    """
    if isinstance(npz_path_or_mapping, Mapping):
        path = None
        label = label or "<mapping>"
        data = {k: np.asarray(os.fspath(v) if isinstance(v, os.PathLike) else v)
                for k, v in npz_path_or_mapping.items() if k in (*_REQUIRED, *_OPTIONAL)}
    else:
        path = pathlib.Path(npz_path_or_mapping)
        label = label or str(npz_path_or_mapping)
        data = _read_npz(path, label)
    missing = [k for k in _REQUIRED if k not in data]
    if missing:
        raise JaxanimError(f"{label}: not a retarget result: missing key {missing[0]!r}"
                           f"{' (and ' + ', '.join(map(repr, missing[1:])) + ')' if len(missing) > 1 else ''}; "
                           f"a retarget .npz holds {', '.join(_REQUIRED)}")

    fps = _numbers(label, "fps", data["fps"])
    if fps.size != 1 or not (math.isfinite(float(fps.reshape(-1)[0])) and float(fps.reshape(-1)[0]) > 0):
        raise JaxanimError(f"{label}: key 'fps': expected a positive number (shape ()), got {fps.tolist()!r}")
    names = data["body_names"]
    B = names.shape[0] if names.ndim == 1 else -1
    body_names = _strings(label, "body_names", names, None, "(B,)")
    if B < 2:
        raise JaxanimError(f"{label}: key 'body_names': expected the world and at least one body, got {B}")
    body_parents = _parents(label, "body_parents", data["body_parents"], B, f"(B,) = ({B},)")
    body_positions = _positions(label, "body_positions", data["body_positions"], None, B, "B", "")
    T = body_positions.shape[0]
    if T == 0:
        raise JaxanimError(f"{label}: key 'body_positions': no frames (T = 0)")
    source_names = _strings(label, "source_names", data["source_names"], None, "(J,)")
    J = len(source_names)
    if J == 0:
        raise JaxanimError(f"{label}: key 'source_names': no joints")
    source_parents = _parents(label, "source_parents", data["source_parents"], J, f"(J,) = ({J},)")
    source_positions = _positions(label, "source_positions", data["source_positions"], T, J, "J", "body_positions")
    if "qpos" in data:
        _numbers(label, "qpos", data["qpos"])
        _shape(label, "qpos", data["qpos"], (T, None), f"(T, nq) = ({T}, nq)", f" with T = {T} frames as in "
               "'body_positions'")

    feet: tuple[str, ...] = ()
    contacts = None
    if ("feet" in data) != ("contacts" in data):
        have, lack = ("feet", "contacts") if "feet" in data else ("contacts", "feet")
        raise JaxanimError(f"{label}: key {lack!r} is missing: {have!r} needs it")
    if "feet" in data:
        feet = _strings(label, "feet", data["feet"], None, "(F,)")
        F = len(feet)
        c = _numbers(label, "contacts", data["contacts"])
        _shape(label, "contacts", c, (T, F), f"(T, F) = ({T}, {F})", f" with T = {T} frames as in 'body_positions'")
        if not np.isin(c, (0, 1)).all():
            raise JaxanimError(f"{label}: key 'contacts': expected booleans (0 or 1)")
        contacts = c.astype(bool)
    geometry, body_xmat = _geometry(label, data, T, B) or (None, None)
    return RetargetClip(label, path, float(fps.reshape(-1)[0]), body_names, body_parents, body_positions,
                        source_names, source_parents, source_positions, feet, contacts,
                        _scalar_string(label, "robot", data.get("robot")),
                        _scalar_string(label, "source", data.get("source")), geometry, body_xmat)


def source_shift(clip: RetargetClip, shift: float | None = None) -> float:
    """How far along world +Y to move the source so it stands beside the robot (m).

    The default is the least shift that keeps the source's joints a gap (a quarter of the taller
    figure, at least 0.1 m) to the +Y side of the robot's bodies in every frame; 0 where it already
    stands that far away.

    Args:
        clip: the clip.
        shift: a shift to use instead (checked to be finite).
    """
    if shift is not None:
        if not math.isfinite(shift):
            raise JaxanimError(f"offset {shift}: expected a finite number of metres")
        return float(shift)
    robot = clip.body_positions[:, 1:]
    src = clip.source_positions
    height = max(float(np.ptp(robot[..., 2])), float(np.ptp(src[..., 2])))
    gap = max(0.25 * height, 0.1)
    return max(0.0, float((robot[..., 1].max(axis=1) - src[..., 1].min(axis=1)).max()) + gap)



@dataclasses.dataclass
class RetargetScene:
    """The points a renderer or viewer draws, the robot's bodies then the source's joints.

    Attributes:
        points: ``[T, R + J, 3]`` the robot's bodies but the world (``R = B - 1``), then the source's
            joints shifted by ``shift`` along +Y; robot frame, m, Z up.
        num_robot: ``R``.
        sticks: ``[sticks, 2]`` point indices (body, parent) of the robot's sticks.
        bones: ``[bones, 2]`` point indices (joint, parent) of the source's bones.
        track: ``[T, 2]`` the horizontal midpoint of the robot's first body and the source's root.
        feet: ``[F]`` the point marked while each foot stands (-1: the name is neither a body nor a joint).
        contacts: ``[T, F]`` (``None`` without feet).
        shift: the source's shift along +Y, m.
        robot_label, source_label: the legend's words.
        geometry: the robot's collision geometry (``None``: drawn as sticks).
        body_xmat: ``[T, B, 3, 3]`` body -> world rotations (with ``geometry``).
    """

    points: np.ndarray
    num_robot: int
    sticks: np.ndarray
    bones: np.ndarray
    track: np.ndarray
    feet: np.ndarray
    contacts: np.ndarray | None
    shift: float
    robot_label: str
    source_label: str
    geometry: RobotGeometry | None = None
    body_xmat: np.ndarray | None = None


def retarget_scene(clip: RetargetClip, shift: float | None = None) -> RetargetScene:
    """Lay the robot and its source out side by side (:func:`source_shift`) as one point set."""
    shift = source_shift(clip, shift)
    R = clip.body_positions.shape[1] - 1
    points = np.concatenate([clip.body_positions[:, 1:], clip.source_positions + np.array([0.0, shift, 0.0])], axis=1)
    root = next(j for j, p in enumerate(clip.source_parents) if p < 0)  # joint 0: parents[0] < 0
    track = 0.5 * (points[:, 0, :2] + points[:, R + root, :2])
    feet = np.array([-1 if w == "" else (i - 1 if w == "robot" else R + i) for w, i in clip.foot_points()], np.int64)
    source_label = f"source: {clip.source_name}" + (f" (+{shift:.2f} m Y)" if shift else "")
    return RetargetScene(points, R, clip.robot_sticks() - 1, clip.source_bones() + R, track, feet, clip.contacts,
                         shift, f"robot: {clip.robot_name}", source_label, clip.geometry, clip.body_xmat)


# ------------------------------------------------------------------------------------------------
# Writing
# ------------------------------------------------------------------------------------------------


def _result_fk(robot, qpos, skeleton, motion, problem):
    """The robot's body frames at every frame (NumPy, :func:`~jaxanim.robots._host.body_frames_host`: a compiled
    program per clip length cost seconds of compiling) and the source's joints in the robot's frame (the
    host kinematics that prepared the problem, :func:`~jaxanim.kinematics._host.clip_frames_host`)."""
    from ..kinematics._host import clip_frames_host  # noqa: PLC0415 (the reader above needs no JAX)
    from ..robots._host import body_frames_host  # noqa: PLC0415

    xpos, xmat = body_frames_host(robot, qpos)
    src = clip_frames_host(skeleton, motion.rotations, motion.translations)[1]
    p = src @ np.asarray(problem.axes, np.float64).T  # problem.in_robot_frame, on the host
    p[..., 2] -= float(problem.ground)
    p = float(problem.scale) * p
    p[..., 2] += float(problem.lift)
    return xpos, xmat, p


def retarget_arrays(skeleton, motion, robot, problem, result, *, robot_path="", source="",
                    map_path="") -> dict[str, np.ndarray]:
    """The arrays of a retarget result .npz (the layout in the module docstring), from a solve.

    Args:
        skeleton, motion: the source clip.
        robot: the robot as the problem was prepared on it (``retargeting.prepared_robot``): its ``qpos``
            layout, geoms and surface points (the soles added) are the result's.
        problem: the ``retargeting.RetargetProblem``.
        result: the ``retargeting.RetargetResult`` of ``retargeting.solve_retarget(robot, problem)``; of a
            problem padded to more frames than the clip's (``prepare_retarget(..., length=)``), the clip's
            frames are kept.
        robot_path, source, map_path: the files, recorded as they are.

    Returns:
        ``{key: numpy array}``, for ``np.savez``: FK of every frame (``body_positions``, ``body_xmat``), the
        source in the robot's frame, the robot's geometry, the diagnostics and the status.
    """
    T = motion.num_frames
    qpos = np.asarray(result.qpos)[:T]
    xpos, xmat, src = (x.astype(qpos.dtype) for x in _result_fk(robot, qpos, skeleton, motion, problem))
    d = result.diagnostics
    success = bool(result.success)
    return {
        "qpos": qpos, "fps": np.asarray(float(result.fps)), "joint_names": np.asarray(robot.jnt_names),
        "body_names": np.asarray(robot.body_names), "body_parents": np.asarray(robot.body_parents),
        "body_positions": xpos, "body_xmat": xmat,
        "source_positions": np.asarray(src), "source_names": np.asarray(skeleton.names),
        "source_parents": np.asarray(skeleton.parents), "feet": np.asarray([problem.names[k] for k in problem.feet]),
        "targets": np.asarray(problem.names),
        "geom_body": np.asarray(robot.geom_bodies, np.int64).reshape(-1),
        "geom_type": np.asarray(robot.geom_types, dtype=str).reshape(-1),
        **{k: np.asarray(getattr(robot, k)) for k in ("geom_size", "geom_pos", "geom_quat", "point_pos")},
        "point_body": np.asarray(robot.point_bodies, np.int64).reshape(-1),
        **{f: np.asarray(getattr(d, f))[:T] for f in d.__dataclass_fields__ if f != "mask"},  # the diagnostics
        "status": np.asarray("successful" if success else str(result.result)), "success": np.asarray(success),
        "robot": np.asarray(str(robot_path)), "source": np.asarray(str(source)), "map": np.asarray(str(map_path)),
    }
