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
  (ignored here).

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

__all__ = ["RetargetClip", "RetargetScene", "is_retarget_file", "load_retarget", "retarget_scene", "source_shift"]

_REQUIRED = ("fps", "body_names", "body_parents", "body_positions", "source_names", "source_parents",
             "source_positions")
_OPTIONAL = ("qpos", "joint_names", "feet", "contacts", "robot", "source", "map")


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


def _parents(label: str, key: str, a: np.ndarray, n: int, what: str) -> np.ndarray:
    _numbers(label, key, a)
    _shape(label, key, a, (n,), what)
    if a.dtype == np.bool_ or (np.issubdtype(a.dtype, np.floating) and not np.all(a == np.round(a))):
        raise JaxanimError(f"{label}: key {key!r}: expected integer parent indices, got dtype {a.dtype}")
    p = a.astype(np.int64)
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
    return RetargetClip(label, path, float(fps.reshape(-1)[0]), body_names, body_parents, body_positions,
                        source_names, source_parents, source_positions, feet, contacts,
                        _scalar_string(label, "robot", data.get("robot")),
                        _scalar_string(label, "source", data.get("source")))


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
                         shift, f"robot: {clip.robot_name}", source_label)
