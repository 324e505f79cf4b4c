"""Reading AMASS clips (SMPL, SMPL+H and SMPL-X bodies) as a :class:`Skeleton` and a :class:`Motion`.

An AMASS clip is an ``.npz`` of per-joint axis-angle rotations, a root translation, the body's shape
coefficients and a frame rate, in one of two layouts:

* SMPL+H: ``poses [T, 156]`` (52 joints x 3: root, 21 body joints, 15 left then 15 right finger
  joints), ``trans [T, 3]``, ``betas [16]``, ``gender``, ``mocap_framerate``;
* SMPL-X: ``root_orient [T, 3]``, ``pose_body [T, 63]``, ``pose_hand [T, 90]`` and optionally
  ``pose_jaw [T, 3]``, ``pose_eye [T, 6]``, ``trans``, ``betas``, ``gender``, ``mocap_frame_rate``.

Either frame-rate key is accepted in either layout; a ``poses`` of 72 (SMPL) or 165 (SMPL-X) columns
is read too. The clip holds no skeleton: the rest joints come from the body model it was fitted with,
the ``.npz`` or ``.pkl`` file distributed by the SMPL / SMPL+H (MANO) / SMPL-X project websites to
registered users (its licence does not allow jaxanim to ship one). The model gives
``J = J_regressor @ (v_template + shapedirs[..., :B] @ betas[:B])`` (``B`` the number of betas the
clip and the model's shape space both have; a SMPL-X model's shapedirs hold 300 shape directions
then the expression ones, or 10 and 10 in the oldest files, and only the shape ones are used), the
tree (``kintree_table``, row 0 the parents) and, from its joint count, the standard joint names:
SMPL 24 joints, SMPL+H 52, SMPL-X 55.

The clip's rotations are placed by role (root, body, jaw, eyes, fingers, SMPL's two hand joints) into
the model's joint order; a role the clip lacks is the rest pose (zero rotation), and a role the
model lacks is dropped when it is the rest pose in every frame and an error otherwise. So a SMPL+H
clip reads with a SMPL-X model (no jaw or eye motion) and a SMPL-X clip with a SMPL+H model while
its jaw and eyes stay still; a clip whose fingers move needs a model with fingers.

The result is BVH-like (see :mod:`jaxanim.skeleton._skeleton`): joint ``j``'s OFFSET is ``J[j] -
J[parent]`` (metres; the root's is ``J[0]``, so the rest pose of the skeleton is the model's template
joints), its local rotation the clip's axis-angle as a wxyz quaternion, and the root's translation
``trans + J[0]`` (SMPL rotates the body about ``J[0]``, then adds ``trans``). AMASS's world is Z up;
by default (``up="y"``) it is turned Y up like a BVH clip with ``C = [[1, 0, 0], [0, 0, 1], [0, -1,
0]]``: the root's rotation becomes ``C R_root`` and its translation ``C (trans + J[0])``, while the
offsets and the other joints' rotations stay as they are (the model's template is already Y up).

Reading is NumPy on the host, with neither chumpy, scipy, torch nor smplx: a ``.pkl`` model (often a
Python-2 pickle of chumpy arrays and a scipy sparse ``J_regressor``) goes through a restricted
unpickler that stands in for those classes (see :func:`_load_pickle`). Every problem raises
:class:`AMASSError` naming the file and the key.
"""

from __future__ import annotations

import builtins
import codecs
import collections
import copyreg
import os
import pathlib
import pickle
import zipfile
from typing import NamedTuple

import numpy as np

from .._errors import JaxanimError
from ..rotations._numpy import quat_exp, quat_mul
from ._bvh import read_bvh
from ._skeleton import Motion, Skeleton

__all__ = ["AMASSError", "read_amass", "read_clip"]


class AMASSError(JaxanimError):
    """An AMASS clip or its body model could not be read.

    Attributes:
        path: the file the problem is in (the clip or the body model).
        message: what was expected and what was found, naming the key.
    """

    def __init__(self, path, message: str):
        self.path = str(path)
        self.message = message
        super().__init__(f"{self.path}: {message}")


_WHERE = ("download it from the project website of the model the clip was fitted with (SMPL: smpl.is.tue.mpg.de, "
          "SMPL+H: mano.is.tue.mpg.de, SMPL-X: smpl-x.is.tue.mpg.de; AMASS's SMPL+H and SMPL-X models are on "
          "amass.is.tue.mpg.de), free after registering; jaxanim cannot ship one, their licence does not allow it")

# ------------------------------------------------------------------------------------------------
# Joint names and the roles of the pose vectors
# ------------------------------------------------------------------------------------------------

_BODY = ("pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
         "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
         "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist")
_FINGERS = tuple(f"{side}_{finger}{k}" for side in ("left", "right")
                 for finger in ("index", "middle", "pinky", "ring", "thumb") for k in (1, 2, 3))

#: Joints per role, in the order roles appear in a pose vector.
_ROLE_SIZE = {"root": 1, "body": 21, "jaw": 1, "eyes": 2, "hands": 30, "smpl_hands": 2}
_ROLE_WHAT = {"root": "root", "body": "body", "jaw": "jaw", "eyes": "eye", "hands": "finger",
              "smpl_hands": "SMPL hand"}

#: Per model joint count: the family, the joint names and the roles in joint order.
_MODELS = {
    24: ("SMPL", _BODY + ("left_hand", "right_hand"), ("root", "body", "smpl_hands")),
    52: ("SMPL+H", _BODY + _FINGERS, ("root", "body", "hands")),
    55: ("SMPL-X", _BODY + ("jaw", "left_eye_smplhf", "right_eye_smplhf") + _FINGERS,
         ("root", "body", "jaw", "eyes", "hands")),
}

#: The roles of a single ``poses`` array, by its number of columns.
_POSES_LAYOUTS = {72: ("SMPL", _MODELS[24][2]), 156: ("SMPL+H", _MODELS[52][2]), 165: ("SMPL-X", _MODELS[55][2])}

#: The SMPL-X layout's keys and their roles (the first two required).
_SMPLX_KEYS = {"root_orient": "root", "pose_body": "body", "pose_jaw": "jaw", "pose_eye": "eyes", "pose_hand": "hands"}

_FRAME_RATE_KEYS = ("mocap_framerate", "mocap_frame_rate")

#: Y up from AMASS's Z up: ``p_y_up = C p_z_up`` (a rotation of -90 degrees about x).
_C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
_Q_C = np.array([np.sqrt(0.5), -np.sqrt(0.5), 0.0, 0.0])

# ------------------------------------------------------------------------------------------------
# A restricted unpickler: chumpy and scipy.sparse stand-ins, numpy's own reconstruction, nothing else
# ------------------------------------------------------------------------------------------------


class _Pickled:
    """A stand-in for a chumpy or scipy.sparse object: it keeps the arguments and state the pickle
    gives it, and does nothing else."""

    origin = "?"  # "module.name" of the class it stands in for
    args: tuple = ()
    state = None

    def __new__(cls, *args, **kwargs):
        obj = object.__new__(cls)
        obj.args = args
        return obj

    def __init__(self, *args, **kwargs):
        pass

    def __setstate__(self, state):
        self.state = state


_STAND_INS: dict[tuple[str, str], type] = {}
_SPARSE = ("csc_matrix", "csr_matrix", "csc_array", "csr_array")


def _numpy_globals() -> dict[tuple[str, str], object]:
    try:  # numpy >= 2 (numpy.core is a deprecated alias there: not imported)
        from numpy._core import multiarray, numeric
    except ImportError:  # numpy 1
        from numpy.core import multiarray, numeric
    found = {"_reconstruct": getattr(multiarray, "_reconstruct", None), "scalar": getattr(multiarray, "scalar", None),
             "_frombuffer": getattr(numeric, "_frombuffer", None), "ndarray": np.ndarray, "dtype": np.dtype}
    out = {}
    for module in ("numpy", "numpy.core.multiarray", "numpy._core.multiarray", "numpy.core.numeric",
                   "numpy._core.numeric"):
        for name, obj in found.items():
            if obj is not None:
                out[(module, name)] = obj
    return out


#: What a model pickle may name besides the stand-ins (Python 2 spells builtins and copyreg differently).
_ALLOWED: dict[tuple[str, str], object] = {
    **{(m, n): getattr(builtins, n) for m in ("builtins", "__builtin__") for n in ("object", "set", "frozenset")},
    **{(m, "_reconstructor"): copyreg._reconstructor for m in ("copyreg", "copy_reg")},
    ("_codecs", "encode"): codecs.encode,
    ("collections", "OrderedDict"): collections.OrderedDict,
}


class _ModelUnpickler(pickle.Unpickler):
    """Resolves chumpy.* classes and scipy.sparse's csc/csr matrices to :class:`_Pickled` stand-ins,
    numpy's array, dtype and scalar reconstruction to numpy's own, a few builtins (object, set,
    frozenset, OrderedDict, copyreg's reconstructor, codecs.encode) to themselves; any other global is
    refused, so unpickling a model calls nothing that the file chooses."""

    _numpy: dict | None = None

    def find_class(self, module, name):
        if module == "chumpy" or module.startswith("chumpy.") or (
                (module == "scipy.sparse" or module.startswith("scipy.sparse.")) and name in _SPARSE):
            key = (module, name)
            if key not in _STAND_INS:
                _STAND_INS[key] = type(f"_Pickled_{name}", (_Pickled,), {"origin": f"{module}.{name}"})
            return _STAND_INS[key]
        if _ModelUnpickler._numpy is None:
            _ModelUnpickler._numpy = _numpy_globals()
        obj = _ModelUnpickler._numpy.get((module, name), _ALLOWED.get((module, name)))
        if obj is None:
            raise pickle.UnpicklingError(
                f"the pickle names {module}.{name}, which a body model may not (only chumpy arrays, scipy.sparse "
                "csc/csr matrices and numpy arrays are read, so loading a model runs nothing the file chooses)")
        return obj


def _load_pickle(fh, path) -> object:
    """Unpickle a body model with :class:`_ModelUnpickler` (``encoding="latin1"`` for Python-2 files)."""
    try:
        return _ModelUnpickler(fh, encoding="latin1").load()
    except AMASSError:
        raise
    except Exception as exc:  # a refused global, a truncated or corrupt file, not a pickle at all
        raise AMASSError(path, f"cannot unpickle the body model: {type(exc).__name__}: {exc}") from None


def _sparse_to_dense(obj: _Pickled, path, key: str) -> np.ndarray:
    state = obj.state[0] if isinstance(obj.state, tuple) and obj.state and isinstance(obj.state[0], dict) else obj.state
    if not isinstance(state, dict):
        raise AMASSError(path, f"{key}: the {obj.origin} holds no data, indices, indptr and shape")
    try:
        shape = tuple(int(s) for s in state.get("_shape", state.get("shape")))
        data, indices, indptr = (np.asarray(state[k]) for k in ("data", "indices", "indptr"))
        rows, cols = shape
        major = cols if obj.origin.split(".")[-1].startswith("csc") else rows
        counts = np.diff(indptr.astype(np.int64))
        ok = (len(shape) == 2 and indptr.shape == (major + 1,) and indptr[0] == 0 and (counts >= 0).all()
              and data.shape == indices.shape == (int(indptr[-1]),))
        if not ok:
            raise ValueError("inconsistent sizes")
        outer = np.repeat(np.arange(major), counts)
        inner = indices.astype(np.int64)
        dense = np.zeros(shape, dtype=np.float64)
        if major == cols:  # csc: indices are rows
            np.add.at(dense, (inner, outer), data.astype(np.float64))
        else:
            np.add.at(dense, (outer, inner), data.astype(np.float64))
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise AMASSError(path, f"{key}: a malformed {obj.origin} ({type(exc).__name__}: {exc})") from None
    return dense


def _to_array(value, path, key: str) -> np.ndarray:
    """A model entry (ndarray, chumpy stand-in, sparse stand-in, nested list) as a numeric ndarray."""
    if isinstance(value, _Pickled):
        if value.origin.split(".")[-1] in _SPARSE:
            return _sparse_to_dense(value, path, key)
        state = value.state[0] if isinstance(value.state, tuple) and value.state else value.state
        if isinstance(state, dict) and "x" in state:
            return _to_array(state["x"], path, key)
        raise AMASSError(path, f"{key}: a chumpy {value.origin} without a stored array (a chumpy expression, not "
                               "data); re-export the model with its arrays evaluated")
    arr = np.asarray(value)
    if arr.dtype == object and arr.ndim == 0:
        return _to_array(arr.item(), path, key)
    if arr.dtype.kind not in "biuf":
        raise AMASSError(path, f"{key}: expected a numeric array, got dtype {arr.dtype}")
    return arr


def _npz_entry(archive: np.lib.npyio.NpzFile, path, key: str):
    """``archive[key]``, an object array (a pickled sparse matrix, say) read by the restricted unpickler."""
    try:
        return archive[key]
    except ValueError as exc:
        if "allow_pickle" not in str(exc):
            raise AMASSError(path, f"{key}: cannot read it: {exc}") from None
    with archive.zip.open(f"{key}.npy") as fh:  # an object array: a .npy header, then a pickle
        version = np.lib.format.read_magic(fh)
        read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        read_header(fh)
        return _load_pickle(fh, path)


# ------------------------------------------------------------------------------------------------
# The body model
# ------------------------------------------------------------------------------------------------


def _open_npz(path: pathlib.Path, what: str) -> np.lib.npyio.NpzFile:
    try:
        archive = np.load(path, allow_pickle=False)
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:  # missing, unreadable, not NumPy's
        raise AMASSError(path, f"cannot read the {what}: {exc}") from None
    if not isinstance(archive, np.lib.npyio.NpzFile):
        raise AMASSError(path, f"expected an .npz archive of the {what}'s arrays, got a single .npy array")
    return archive


def _read_model_file(path: pathlib.Path) -> tuple[dict, list[str]]:
    """The model's needed entries (raw: ndarray or stand-in) and all its keys."""
    needed = ("v_template", "shapedirs", "J_regressor", "kintree_table", "num_betas")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        with _open_npz(path, "body model") as archive:
            keys = list(archive.files)
            try:
                return {k: _npz_entry(archive, path, k) for k in needed if k in keys}, keys
            except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
                if isinstance(exc, AMASSError):
                    raise
                raise AMASSError(path, f"cannot read the body model: {exc}") from None
    if suffix == ".pkl":
        try:
            with open(path, "rb") as fh:
                data = _load_pickle(fh, path)
        except OSError as exc:
            raise AMASSError(path, f"cannot read the body model: {exc}") from None
        if not isinstance(data, dict):
            raise AMASSError(path, f"expected a pickled dict of the model's arrays, got {type(data).__name__}")
        keys = [str(k) for k in data]
        return {k: data[k] for k in needed if k in data}, keys
    raise AMASSError(path, f"expected a body model as .npz or .pkl (as distributed), got a {suffix or 'suffix-less'} "
                           "file")


def _finite(path, key: str, arr) -> np.ndarray:
    """``arr`` as float64, or an :class:`AMASSError` naming ``key`` for NaN, inf or non-numbers."""
    arr = np.asarray(arr)
    if arr.dtype.kind not in "biuf":
        raise AMASSError(path, f"{key}: expected numbers, got dtype {arr.dtype}")
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        first = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise AMASSError(path, f"{key}: {int((~np.isfinite(arr)).sum())} NaN or inf value(s), the first at index "
                               f"{first[0] if len(first) == 1 else first}")
    return arr


class _Model(NamedTuple):
    path: pathlib.Path
    family: str  # "SMPL", "SMPL+H" or "SMPL-X"
    names: tuple[str, ...]
    roles: tuple[str, ...]  # the pose roles in joint order
    parents: tuple[int, ...]
    v_template: np.ndarray  # [V, 3]
    J_regressor: np.ndarray  # [J, V]
    shapedirs: np.ndarray  # [V, 3, shape directions] (no expression directions)


def _load_model(body_model, clip_path) -> _Model:
    if body_model is None:
        raise AMASSError(clip_path, "an AMASS clip holds no skeleton: reading it needs the SMPL-family body model it "
                                    "was fitted with (body_model=MODEL.npz or .pkl; on the command line "
                                    f"--body-model MODEL); {_WHERE}")
    path = pathlib.Path(os.fspath(body_model))
    if not path.is_file():
        raise AMASSError(path, f"body model file not found{' (a directory)' if path.is_dir() else ''}; {_WHERE}")
    raw, keys = _read_model_file(path)
    missing = [k for k in ("v_template", "shapedirs", "J_regressor", "kintree_table") if k not in raw]
    if missing:
        raise AMASSError(path, f"{missing[0]}: missing; a SMPL / SMPL+H / SMPL-X body model has v_template, shapedirs, "
                               f"J_regressor and kintree_table; this file has {sorted(keys)}")
    arrays = {k: _to_array(v, path, k) for k, v in raw.items()}
    v_template, shapedirs, regressor, kintree = (arrays[k] for k in ("v_template", "shapedirs", "J_regressor",
                                                                      "kintree_table"))
    if kintree.ndim != 2 or kintree.shape[0] != 2 or kintree.shape[1] not in _MODELS:
        raise AMASSError(path, f"kintree_table: expected shape (2, joints) with 24 (SMPL), 52 (SMPL+H) or 55 (SMPL-X) "
                               f"joints, got {kintree.shape}")
    n = kintree.shape[1]
    if v_template.ndim != 2 or v_template.shape[1] != 3:
        raise AMASSError(path, f"v_template: expected shape (vertices, 3), got {v_template.shape}")
    v = v_template.shape[0]
    if regressor.shape != (n, v):
        raise AMASSError(path, f"J_regressor: expected shape (joints, vertices) = ({n}, {v}), got {regressor.shape}")
    if shapedirs.ndim != 3 or shapedirs.shape[:2] != (v, 3):
        raise AMASSError(path, f"shapedirs: expected shape (vertices, 3, directions) = ({v}, 3, *), got "
                               f"{shapedirs.shape}")
    # the tree: row 1 the joint ids, row 0 their parents (the root's a huge number or -1)
    table = kintree.astype(np.float64)
    if not (np.isfinite(table).all() and (table == np.round(table)).all()):
        raise AMASSError(path, "kintree_table: expected integer joint ids")
    ids, par = kintree[1].astype(np.int64), kintree[0].astype(np.int64)
    if sorted(ids.tolist()) != list(range(n)):
        raise AMASSError(path, f"kintree_table: row 1 should number the joints 0 to {n - 1}, got {ids.tolist()}")
    parents = np.empty(n, dtype=np.int64)
    parents[ids] = np.where((par < 0) | (par >= n), -1, par)
    family, names, roles = _MODELS[n]
    k = shapedirs.shape[2]
    num_betas = arrays.get("num_betas", np.zeros(0)).reshape(-1)
    if num_betas.shape == (1,) and num_betas[0] == int(num_betas[0]) >= 0:  # a model that says so
        num_shape = int(num_betas[0])
    elif family == "SMPL-X":  # 300 shape directions then the expressions; the oldest files: 10 then 10
        num_shape = 300 if k >= 300 else min(k, 10)
    else:
        num_shape = k
    return _Model(path, family, names, roles, tuple(parents.tolist()), _finite(path, "v_template", v_template),
                  _finite(path, "J_regressor", regressor), shapedirs[..., :min(num_shape, k)])


# ------------------------------------------------------------------------------------------------
# The clip
# ------------------------------------------------------------------------------------------------


def _clip_array(path, archive, key: str) -> np.ndarray:
    try:
        return np.asarray(archive[key])
    except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:  # an object array, a corrupt member
        raise AMASSError(path, f"{key}: cannot read it: {exc}") from None


def _clip_parts(path, archive, keys: list[str]) -> tuple[str, dict[str, tuple[str, np.ndarray]]]:
    """The clip's layout name and its rotations by role: ``role -> (key, [T, joints, 3])``."""
    def get(key):
        return _clip_array(path, archive, key)

    def rotations(key, arr, joints):
        if arr.ndim != 2 or arr.shape[1] != 3 * joints:
            raise AMASSError(path, f"{key}: expected shape (frames, {3 * joints}) ({joints} joint(s) x 3 axis-angle "
                                   f"values), got {arr.shape}")
        return _finite(path, key, arr).reshape(arr.shape[0], joints, 3)

    if "root_orient" in keys and "pose_body" in keys:
        parts = {role: (key, rotations(key, get(key), _ROLE_SIZE[role]))
                 for key, role in _SMPLX_KEYS.items() if key in keys}
        return "SMPL-X", parts
    if "poses" in keys:
        poses = get("poses")
        width = poses.shape[1] if poses.ndim == 2 else None
        if width not in _POSES_LAYOUTS:
            raise AMASSError(path, f"poses: expected shape (frames, 72 | 156 | 165) (the 24, 52 or 55 joints of SMPL, "
                                   f"SMPL+H or SMPL-X, 3 axis-angle values each), got {poses.shape}")
        layout, roles = _POSES_LAYOUTS[width]
        flat = rotations("poses", poses, width // 3)
        parts, start = {}, 0
        for role in roles:
            parts[role] = ("poses", flat[:, start:start + _ROLE_SIZE[role]])
            start += _ROLE_SIZE[role]
        return layout, parts
    raise AMASSError(path, f"not an AMASS clip: it has the keys {sorted(keys)}; expected poses [T, 156] (SMPL+H) or "
                           "root_orient [T, 3] and pose_body [T, 63] (SMPL-X; pose_hand, pose_jaw, pose_eye optional), "
                           "with trans [T, 3], betas and mocap_framerate or mocap_frame_rate")


def read_amass(path: str | os.PathLike, *, body_model: str | os.PathLike | None = None,
               up: str = "y") -> tuple[Skeleton, Motion]:
    """Read an AMASS clip (SMPL+H or SMPL-X layout) with the SMPL-family body model it was fitted with.

    See the module docstring for the layouts and the conventions. With ``up="y"`` (the default) the
    world is turned Y up, ``p = C (trans + J[0])`` and ``R_root = C R_clip`` with ``C = [[1, 0, 0],
    [0, 0, 1], [0, -1, 0]]``; ``up="z"`` keeps AMASS's Z-up world. The joints are named as in SMPL
    (``pelvis``, ``left_hip``, ..., ``left_index1``, ...). The clip's ``gender`` is not checked
    against the model: the user chooses the model.

    A ``.pkl`` body model is read without chumpy or scipy by a restricted unpickler: chumpy objects
    and scipy.sparse csc/csr matrices become stand-ins holding their state (converted to dense
    NumPy), numpy's own array reconstruction is allowed, and any other class or function a pickle
    names is refused with :class:`AMASSError`: loading a model never calls what the file chooses
    (``pickle.load`` would). The same holds for an object array inside an ``.npz`` model.

    Args:
        path: the AMASS ``.npz`` clip.
        body_model: the body model file, ``.npz`` or ``.pkl``, as distributed by the SMPL (24
            joints), SMPL+H (52) or SMPL-X (55) project (free after registering there; jaxanim cannot
            ship one, their licence does not allow it).
        up: ``"y"`` (default) for a Y-up world like BVH clips, ``"z"`` for AMASS's own.

    Returns:
        ``(skeleton, motion)``: the model's joints (root with position channels, offsets in metres,
        rest pose = the model's template joints for the clip's betas) and the clip (``[T, joints, 4]``
        wxyz local rotations, ``[T, joints, 3]`` local translations, ``frame_time = 1 / frame rate``).
        Arrays are float64 when ``jax_enable_x64`` is on, float32 otherwise.

    Raises:
        AMASSError: ``body_model`` not given or not found (saying where to get one), an unreadable
            file, keys that are not an AMASS layout (listing the keys found), a clip whose joints do
            not fit the model (a wrong ``poses`` width, or finger / jaw / eye motion the model has no
            joints for), NaN or inf in the clip or the model, a pickle naming a class it may not.
        JaxanimError: ``up`` is not ``"y"`` or ``"z"``.
    """
    if up not in ("y", "z"):
        raise JaxanimError(f"up: expected 'y' (a Y-up world, like BVH) or 'z' (AMASS's own), got {up!r}")
    clip = pathlib.Path(os.fspath(path))
    model = _load_model(body_model, clip)
    archive = _open_npz(clip, "clip")
    with archive:
        keys = list(archive.files)
        layout, parts = _clip_parts(clip, archive, keys)
        rate_key = next((k for k in _FRAME_RATE_KEYS if k in keys), None)
        if rate_key is None:
            raise AMASSError(clip, f"mocap_framerate: missing (nor mocap_frame_rate); the clip has {sorted(keys)}")
        def numbers(key, default):
            return _finite(clip, key, _clip_array(clip, archive, key)) if key in keys else default

        rate = numbers(rate_key, None).reshape(-1)
        if rate.shape != (1,) or not rate[0] > 0:
            raise AMASSError(clip, f"{rate_key}: expected one positive number of frames per second, got "
                                   f"{rate.tolist()}")
        frames = next(iter(parts.values()))[1].shape[0]
        trans, betas = numbers("trans", np.zeros((frames, 3))), numbers("betas", np.zeros(0))
    for key, arr in parts.values():
        if arr.shape[0] != frames:
            raise AMASSError(clip, f"{key}: {arr.shape[0]} frames, but {next(iter(parts.values()))[0]} has {frames}")
    if trans.shape != (frames, 3):
        raise AMASSError(clip, f"trans: expected shape (frames, 3) = ({frames}, 3), got {trans.shape}")
    if betas.ndim == 2 and betas.shape[0] == 1:
        betas = betas[0]
    if betas.ndim != 1:
        raise AMASSError(clip, f"betas: expected one shape vector (betas,), got shape {betas.shape}")

    # the rotations in the model's joint order: missing roles at rest, roles the model lacks must be at rest
    for role, (key, arr) in parts.items():
        if role not in model.roles and np.any(arr != 0):
            n = _ROLE_SIZE[role]
            raise AMASSError(clip, f"{key}: joint count mismatch: the {layout} clip rotates {n} {_ROLE_WHAT[role]} "
                                   f"joint(s) that the body model {model.path} ({model.family}, "
                                   f"{len(model.names)} joints) does not have; use the {layout} model the clip "
                                   "was fitted with")
    rotvecs = np.concatenate([parts[role][1] if role in parts else np.zeros((frames, _ROLE_SIZE[role], 3))
                              for role in model.roles], axis=1)

    # the rest joints for the clip's betas
    b = min(betas.shape[0], model.shapedirs.shape[2])
    vertices = model.v_template + _finite(model.path, "shapedirs", model.shapedirs[..., :b]) @ betas[:b]
    joints = model.J_regressor @ vertices
    parents = np.asarray(model.parents)
    offsets = joints - np.where(parents[:, None] >= 0, joints[np.maximum(parents, 0)], 0.0)

    quats = quat_exp(rotvecs)
    root = trans + joints[0]
    if up == "y":
        quats[:, 0] = quat_mul(_Q_C, quats[:, 0])
        root = root @ _C.T
    translations = np.broadcast_to(offsets, (frames,) + offsets.shape).copy()
    translations[:, 0] = root
    try:
        skeleton = Skeleton(model.names, model.parents, offsets)
    except JaxanimError as exc:  # a tree that is not topologically sorted
        raise AMASSError(model.path, f"kintree_table: {exc}") from None
    return skeleton, Motion(quats, translations, np.asarray(1.0 / rate[0]))


def read_clip(path: str | os.PathLike, *, body_model: str | os.PathLike | None = None) -> tuple[Skeleton, Motion]:
    """Read a clip of either kind: an ``.npz`` as an AMASS clip (:func:`read_amass` with ``body_model``,
    Y up), anything else as BVH (:func:`read_bvh`; ``body_model`` unused).

    Args:
        path: the clip.
        body_model: the SMPL-family body model an ``.npz`` clip needs.

    Returns:
        ``(skeleton, motion)``.

    Raises:
        AMASSError: as :func:`read_amass` (an ``.npz`` without ``body_model`` among them).
        BVHParseError: as :func:`read_bvh`.
    """
    if os.fspath(path).lower().endswith(".npz"):
        return read_amass(path, body_model=body_model)
    return read_bvh(path)
