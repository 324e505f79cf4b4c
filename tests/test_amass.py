"""AMASS clips on SMPL-family body models (:func:`jaxanim.skeleton.read_amass`), and ``--body-model``.

No body model can ship with the tests (their licence), so the tests write small fakes of each layout:
SMPL (24 joints), SMPL+H (52) and SMPL-X (55) with the real trees and 40 vertices, as ``.npz`` and as a
``.pkl`` of fake chumpy arrays and a fake scipy csc ``J_regressor`` (loaded with chumpy and scipy
blocked). The clips are the shipped walk's rotations and root path. FK of what the reader returns is
checked against the SMPL chain computed here in NumPy (rodrigues, ``G_j = G_parent [R_j | J_j -
J_parent]``, world ``C (G translation + trans)``), which does not use the reader's code.
"""

from __future__ import annotations

import contextlib
import pickle
import sys
import types

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import jaxanim
from jaxanim import cli
from jaxanim.skeleton import AMASSError, default_clip_path, read_amass, read_bvh, read_clip

_ATOL_FK = 1e-12  # metres; and for the world rotation matrices
_V = 40  # vertices of the fake models
_C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # Y up from Z up
_ROOT = 4294967295  # kintree_table's parent of the root in the distributed files


def _finger_parents(first: int) -> list[int]:
    out = []
    for side, wrist in ((0, 20), (1, 21)):
        for finger in range(5):
            base = first + 15 * side + 3 * finger
            out += [wrist, base, base + 1]
    return out


_BODY_PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19]
_PARENTS = {24: _BODY_PARENTS + [20, 21], 52: _BODY_PARENTS + _finger_parents(22),
            55: _BODY_PARENTS + [15, 15, 15] + _finger_parents(25)}


def _model(joints: int, directions: int, seed: int, *, root=_ROOT, kintree_dtype=np.int64) -> dict[str, np.ndarray]:
    """A fake body model: the real tree, random template, positive normalized regressor, random shapedirs."""
    rng = np.random.default_rng(seed)
    regressor = rng.uniform(0.0, 1.0, size=(joints, _V)) * (rng.uniform(size=(joints, _V)) < 0.3)
    regressor[:, 0] += 1e-3  # no empty row
    regressor /= regressor.sum(axis=1, keepdims=True)
    parents = np.array(_PARENTS[joints])
    parents[0] = root
    return {"v_template": rng.normal(scale=0.4, size=(_V, 3)),
            "shapedirs": rng.normal(scale=0.02, size=(_V, 3, directions)),
            "J_regressor": regressor,
            "kintree_table": np.stack([parents, np.arange(joints)]).astype(kintree_dtype),
            "f": rng.integers(0, _V, size=(30, 3)), "weights": rng.uniform(size=(_V, joints))}


def _walk_rotvecs() -> tuple[np.ndarray, np.ndarray, float]:
    """The shipped walk: rotation vectors [T, 21, 3] (root in AMASS's Z-up world), root path [T, 3] (Z up), fps."""
    _, motion = read_bvh(default_clip_path())
    q = np.asarray(motion.rotations, np.float64)
    R = Rotation.from_quat(q[..., [1, 2, 3, 0]].reshape(-1, 4)).as_matrix().reshape(q.shape[:2] + (3, 3))
    R[:, 0] = _C.T @ R[:, 0]  # Y up -> AMASS's Z up
    rv = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(q.shape[:2] + (3,))
    return rv, np.asarray(motion.translations, np.float64)[:, 0] @ _C, 1.0 / float(motion.frame_time)


def _clip_rotvecs(joints: int, seed: int) -> np.ndarray:
    """[T, joints, 3] in SMPL+H (52) or SMPL-X (55) order: the walk's joints cycled over the body, random
    fingers, jaw and eyes; frame 0 all zero, frame 1 tiny angles, frame 2 angles of pi and next to it."""
    rv, _, _ = _walk_rotvecs()
    rng = np.random.default_rng(seed)
    out = rng.normal(scale=0.3, size=(rv.shape[0], joints, 3))
    out[:, :22] = rv[:, np.arange(22) % rv.shape[1]]
    out[0] = 0.0
    out[1] = rng.normal(size=(joints, 3)) * 1e-9
    axes = rng.normal(size=(joints, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    out[2] = axes * np.where(np.arange(joints) % 2 == 0, np.pi, np.pi - 1e-7)[:, None]
    return out


def _rodrigues(v: np.ndarray) -> np.ndarray:
    angle = np.linalg.norm(v, axis=-1)[..., None, None]
    safe = np.where(angle > 0, angle, 1.0)
    k = v / safe[..., 0]
    K = np.zeros(v.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = k[..., 2], -k[..., 1], k[..., 0]
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def _reference(model: dict, pose: np.ndarray, trans: np.ndarray, betas: np.ndarray, num_shape: int, up: str = "y"):
    """SMPL's chain in NumPy: world joint positions [T, J, 3] and rotations [T, J, 3, 3]; ``pose`` [T, J, 3] in the
    model's joint order."""
    b = min(len(betas), num_shape)
    joints = model["J_regressor"] @ (model["v_template"] + model["shapedirs"][..., :b] @ betas[:b])
    parents = _PARENTS[joints.shape[0]]
    R = _rodrigues(pose)
    G_R, G_t = [None] * len(parents), [None] * len(parents)
    for j, p in enumerate(parents):
        if p < 0:
            G_R[j], G_t[j] = R[:, j], np.broadcast_to(joints[j], trans.shape)
        else:
            G_R[j] = G_R[p] @ R[:, j]
            G_t[j] = G_t[p] + np.einsum("tab,b->ta", G_R[p], joints[j] - joints[p])
    positions = np.stack(G_t, axis=1) + trans[:, None]
    rotations = np.stack(G_R, axis=1)
    if up == "y":
        positions, rotations = positions @ _C.T, _C @ rotations
    return positions, rotations, joints


@contextlib.contextmanager
def _fake_modules(**classes):
    """``module.name`` -> class: fake modules holding them, so that pickle names e.g. ``chumpy.ch.Ch``."""
    with pytest.MonkeyPatch.context() as mp:
        for dotted, cls in classes.items():
            module, name = dotted.rsplit(".", 1)
            parts = module.split(".")
            for k in range(1, len(parts) + 1):
                mp.setitem(sys.modules, ".".join(parts[:k]), types.ModuleType(".".join(parts[:k])))
            cls.__module__, cls.__qualname__, cls.__name__ = module, name, name
            setattr(sys.modules[module], name, cls)
        yield


class _FakeCh:
    """Pickled as ``chumpy.ch.Ch``, with the state chumpy gives one (its ``__dict__`` less the caches)."""

    def __init__(self, x):
        self.x, self._dirty_vars, self._itr, self._depends_on_deps = x, set(), None, {}
        self._make_dense, self._make_sparse = False, False

    def __getstate__(self):
        return dict(self.__dict__)


class _FakeCsc:
    """Pickled as ``scipy.sparse.csc.csc_matrix`` (the module SMPL's 2015 pickles name)."""

    def __init__(self, dense):
        cols = [np.flatnonzero(dense[:, c]) for c in range(dense.shape[1])]
        self.data = np.concatenate([dense[r, c] for c, r in enumerate(cols)])
        self.indices = np.concatenate(cols).astype(np.int32)
        self.indptr = np.concatenate([[0], np.cumsum([len(r) for r in cols])]).astype(np.int32)
        self._shape, self.maxprint = dense.shape, 50

    def __getstate__(self):
        return dict(self.__dict__)


_TRAPPED: list[int] = []


def _trap():
    _TRAPPED.append(1)


class _Evil:
    def __reduce__(self):
        return _trap, ()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """The fake models and the clips, written once."""
    d = tmp_path_factory.mktemp("amass")
    rng = np.random.default_rng(7)
    _, root_path, fps = _walk_rotvecs()
    out = {"fps": fps, "trans": root_path, "betas": rng.normal(size=16)}
    out["smpl"] = _model(24, 10, 1, kintree_dtype=np.uint32)
    out["smplh"] = _model(52, 16, 2)
    out["smplx"] = _model(55, 400, 3, root=-1)  # 300 shape + 100 expression directions
    out["smplx_old"] = _model(55, 20, 4)  # 10 shape + 10 expression directions
    for name in ("smpl", "smplh", "smplx_old"):
        np.savez(d / f"{name}.npz", **out[name])
    with _fake_modules(**{"chumpy.ch.Ch": _FakeCh, "scipy.sparse.csc.csc_matrix": _FakeCsc}):
        model = dict(out["smplx"], v_template=_FakeCh(out["smplx"]["v_template"]),
                     shapedirs=_FakeCh(out["smplx"]["shapedirs"]), J_regressor=_FakeCsc(out["smplx"]["J_regressor"]),
                     joint2num={"pelvis": 0})
        (d / "smplx.pkl").write_bytes(pickle.dumps(model, protocol=2))
        (d / "smplx_p0.pkl").write_bytes(pickle.dumps(model, protocol=0))  # copy_reg._reconstructor, text opcodes
        # a sparse regressor saved into an .npz: an object array, a pickle inside
        sparse = np.array(_FakeCsc(out["smplh"]["J_regressor"]), dtype=object)
        np.savez(d / "smplh_sparse.npz", **dict(out["smplh"], J_regressor=sparse))
    assert "chumpy" not in sys.modules

    out["pose52"] = _clip_rotvecs(52, 5)
    np.savez(d / "walk_smplh.npz", poses=out["pose52"].reshape(-1, 156), trans=root_path, betas=out["betas"],
             gender=np.array("female"), mocap_framerate=np.array(fps), dmpls=np.zeros((len(root_path), 8)))
    out["pose55"] = _clip_rotvecs(55, 6)
    p = out["pose55"]
    np.savez(d / "walk_smplx.npz", root_orient=p[:, 0], pose_body=p[:, 1:22].reshape(-1, 63),
             pose_jaw=p[:, 22], pose_eye=p[:, 23:25].reshape(-1, 6), pose_hand=p[:, 25:].reshape(-1, 90),
             trans=root_path, betas=out["betas"], gender=np.array("male"), mocap_frame_rate=np.array(fps),
             surface_model_type=np.array("smplx"))
    out["dir"] = d
    return out


@pytest.fixture(scope="module")
def fk():
    """The CLI's ``jit(vmap(forward_kinematics))``: one compiled program per skeleton, shared with its tests."""
    return cli.batched_fk()


def _check_fk(fk, skeleton, motion, positions, rotations):
    got = fk(skeleton, motion.rotations, motion.translations)
    np.testing.assert_allclose(np.asarray(got.positions), positions, rtol=0, atol=_ATOL_FK, err_msg="field: positions")
    np.testing.assert_allclose(np.asarray(got.rotations), rotations, rtol=0, atol=_ATOL_FK, err_msg="field: rotations")


def _smplx_pose_on(joints: int, p55: np.ndarray) -> np.ndarray:
    """The SMPL-X clip's rotations in another model's order (its jaw and eyes dropped)."""
    return p55 if joints == 55 else np.concatenate([p55[:, :22], p55[:, 25:]], axis=1)


# ------------------------------------------------------------------------------------------------
# FK against the SMPL chain
# ------------------------------------------------------------------------------------------------


def test_smplh_clip_on_the_smplh_model_matches_the_smpl_chain(files, fk):
    skeleton, motion = read_amass(files["dir"] / "walk_smplh.npz", body_model=files["dir"] / "smplh.npz")
    pos, rot, joints = _reference(files["smplh"], files["pose52"], files["trans"], files["betas"], 16)
    _check_fk(fk, skeleton, motion, pos, rot)
    assert skeleton.names[:3] == ("pelvis", "left_hip", "right_hip")
    assert skeleton.names[20:26] == ("left_wrist", "right_wrist", "left_index1", "left_index2", "left_index3",
                                     "left_middle1")
    assert skeleton.names[-1] == "right_thumb3" and skeleton.parents == tuple(_PARENTS[52])
    assert skeleton.has_position_channels[0] and not any(skeleton.has_position_channels[1:])
    np.testing.assert_allclose(float(motion.frame_time), 1.0 / files["fps"], rtol=1e-15)
    # the rest pose is the model's template joints (Y up)
    rest = fk(skeleton, jaxanim.rest_motion(skeleton).rotations, jaxanim.rest_motion(skeleton).translations)
    np.testing.assert_allclose(np.asarray(rest.positions[0]), joints, rtol=0, atol=_ATOL_FK)
    # the root path is the walk's (the clip's trans is its root in Z up, J[0] added)
    _, walk = read_bvh(default_clip_path())
    np.testing.assert_allclose(np.asarray(motion.translations[:, 0]),
                               np.asarray(walk.translations[:, 0], np.float64) + _C @ joints[0], rtol=0, atol=1e-12)


def test_smplx_clip_on_a_chumpy_pickle_loads_without_chumpy_or_scipy(files, fk, monkeypatch):
    for name in ("chumpy", "chumpy.ch", "scipy", "scipy.sparse", "scipy.sparse.csc", "scipy.sparse._csc"):
        monkeypatch.setitem(sys.modules, name, None)  # importing them now fails
    skeleton, motion = read_amass(files["dir"] / "walk_smplx.npz", body_model=files["dir"] / "smplx.pkl")
    monkeypatch.undo()
    pos, rot, _ = _reference(files["smplx"], files["pose55"], files["trans"], files["betas"], 300)
    _check_fk(fk, skeleton, motion, pos, rot)
    assert skeleton.names[21:26] == ("right_wrist", "jaw", "left_eye_smplhf", "right_eye_smplhf", "left_index1")


@pytest.mark.parametrize("kind", ["csc_matrix", "csr_matrix", "csc_array", "csr_array"])
def test_scipy_sparse_regressors_pickled_by_scipy_itself(files, tmp_path, kind):
    import scipy.sparse

    model = dict(files["smplh"], J_regressor=getattr(scipy.sparse, kind)(files["smplh"]["J_regressor"]))
    (tmp_path / "model.pkl").write_bytes(pickle.dumps(model))
    skeleton, _ = read_amass(files["dir"] / "walk_smplh.npz", body_model=tmp_path / "model.pkl")
    expected, _ = read_amass(files["dir"] / "walk_smplh.npz", body_model=files["dir"] / "smplh.npz")
    np.testing.assert_array_equal(np.asarray(skeleton.offsets), np.asarray(expected.offsets))


def test_an_object_array_in_an_npz_model_goes_through_the_same_unpickler(files, monkeypatch):
    for name in ("scipy", "scipy.sparse", "scipy.sparse.csc"):
        monkeypatch.setitem(sys.modules, name, None)
    skeleton, _ = read_amass(files["dir"] / "walk_smplh.npz", body_model=files["dir"] / "smplh_sparse.npz")
    monkeypatch.undo()
    expected, _ = read_amass(files["dir"] / "walk_smplh.npz", body_model=files["dir"] / "smplh.npz")
    np.testing.assert_allclose(np.asarray(skeleton.offsets), np.asarray(expected.offsets), rtol=0, atol=1e-15)


def test_a_protocol_0_pickle_reads_the_same(files):
    skeleton, motion = read_amass(files["dir"] / "walk_smplx.npz", body_model=files["dir"] / "smplx_p0.pkl")
    expected, expected_motion = read_amass(files["dir"] / "walk_smplx.npz", body_model=files["dir"] / "smplx.pkl")
    np.testing.assert_array_equal(np.asarray(skeleton.offsets), np.asarray(expected.offsets))
    np.testing.assert_array_equal(np.asarray(motion.translations), np.asarray(expected_motion.translations))


def test_z_up_keeps_amass_world(files, fk):
    skeleton, motion = read_amass(files["dir"] / "walk_smplh.npz", body_model=files["dir"] / "smplh.npz", up="z")
    pos, rot, _ = _reference(files["smplh"], files["pose52"], files["trans"], files["betas"], 16, up="z")
    _check_fk(fk, skeleton, motion, pos, rot)


def test_old_smplx_model_uses_its_10_shape_directions_not_the_expressions(files, fk):
    skeleton, motion = read_amass(files["dir"] / "walk_smplx.npz", body_model=files["dir"] / "smplx_old.npz")
    pos, rot, _ = _reference(files["smplx_old"], files["pose55"], files["trans"], files["betas"], 10)
    _check_fk(fk, skeleton, motion, pos, rot)


def test_roles_move_between_layouts(files, fk, tmp_path):
    """A SMPL+H clip on a SMPL-X model (jaw and eyes at rest); a SMPL-X clip whose jaw and eyes are at rest on a
    SMPL+H model; a SMPL+H clip whose fingers are at rest on SMPL (its two hand joints at rest)."""
    d = files["dir"]
    p52 = files["pose52"]
    skeleton, motion = read_amass(d / "walk_smplh.npz", body_model=d / "smplx_old.npz")
    on55 = np.concatenate([p52[:, :22], np.zeros((len(p52), 3, 3)), p52[:, 22:]], axis=1)
    pos, rot, _ = _reference(files["smplx_old"], on55, files["trans"], files["betas"], 10)
    _check_fk(fk, skeleton, motion, pos, rot)

    with np.load(d / "walk_smplx.npz") as z:
        still = dict(z, pose_jaw=np.zeros_like(z["pose_jaw"]), pose_eye=np.zeros_like(z["pose_eye"]))
    np.savez(tmp_path / "still.npz", **still)
    skeleton, motion = read_amass(tmp_path / "still.npz", body_model=d / "smplh.npz")
    pos, rot, _ = _reference(files["smplh"], _smplx_pose_on(52, files["pose55"]), files["trans"], files["betas"], 16)
    _check_fk(fk, skeleton, motion, pos, rot)

    no_fingers = p52[:, :24].copy()
    no_fingers[:, 22:] = 0.0
    poses = np.concatenate([p52[:, :22], np.zeros((len(p52), 30, 3))], axis=1).reshape(-1, 156)
    np.savez(tmp_path / "body.npz", poses=poses, trans=files["trans"], betas=files["betas"][:10],
             mocap_frame_rate=np.array(files["fps"]))
    skeleton, motion = read_amass(tmp_path / "body.npz", body_model=d / "smpl.npz")
    pos, rot, _ = _reference(files["smpl"], no_fingers, files["trans"], files["betas"][:10], 10)
    _check_fk(fk, skeleton, motion, pos, rot)
    assert skeleton.names[-2:] == ("left_hand", "right_hand")


def test_quaternions_are_unit_and_exact_at_rest(files):
    _, motion = read_amass(files["dir"] / "walk_smplh.npz", body_model=files["dir"] / "smplh.npz")
    q = np.asarray(motion.rotations)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, rtol=0, atol=1e-15)
    assert (q[0, 1:] == [1.0, 0.0, 0.0, 0.0]).all()  # frame 0 is all zero: exactly the identity
    np.testing.assert_allclose(q[1, 1:, 1:], 0.5 * files["pose52"][1, 1:], rtol=1e-15, atol=0)  # tiny angles


def test_read_clip_dispatches_on_the_suffix(files):
    skeleton, motion = read_clip(files["dir"] / "walk_smplh.npz", body_model=files["dir"] / "smplh.npz")
    assert skeleton.num_joints == 52 and motion.num_frames == len(files["trans"])
    bvh_skeleton, bvh_motion = read_clip(default_clip_path(), body_model=files["dir"] / "smplh.npz")
    walk_skeleton, walk = read_bvh(default_clip_path())
    assert bvh_skeleton.names == walk_skeleton.names
    np.testing.assert_array_equal(np.asarray(bvh_motion.rotations), np.asarray(walk.rotations))


def test_the_clip_gender_is_not_the_models_business(files, tmp_path):
    """The clip says female, male or neutral: any model reads it, without a word (warnings are errors here)."""
    with np.load(files["dir"] / "walk_smplh.npz") as z:
        np.savez(tmp_path / "neutral.npz", **dict(z, gender=np.array(b"neutral")))
    for clip in (files["dir"] / "walk_smplh.npz", tmp_path / "neutral.npz"):
        assert read_amass(clip, body_model=files["dir"] / "smplx_old.npz")[0].num_joints == 55


# ------------------------------------------------------------------------------------------------
# Errors
# ------------------------------------------------------------------------------------------------


def test_a_missing_body_model_says_where_to_get_one(files, tmp_path):
    clip = files["dir"] / "walk_smplh.npz"
    with pytest.raises(AMASSError, match=r"walk_smplh\.npz: .*needs the SMPL-family body model.*--body-model.*"
                                         r"smpl\.is\.tue\.mpg\.de.*licence"):
        read_amass(clip)
    with pytest.raises(AMASSError, match=r"nowhere\.npz: body model file not found; .*registering"):
        read_amass(clip, body_model=tmp_path / "nowhere.npz")
    with pytest.raises(AMASSError, match=r"model\.json: expected a body model as \.npz or \.pkl"):
        (tmp_path / "model.json").write_text("{}")
        read_amass(clip, body_model=tmp_path / "model.json")
    with np.load(files["dir"] / "smplh.npz") as z:
        np.savez(tmp_path / "partial.npz", **{k: v for k, v in z.items() if k != "J_regressor"})
    with pytest.raises(AMASSError, match=r"partial\.npz: J_regressor: missing; .*this file has \['f', 'kintree_table'"):
        read_amass(clip, body_model=tmp_path / "partial.npz")


def test_joint_counts_that_do_not_fit(files, tmp_path):
    d = files["dir"]
    np.savez(tmp_path / "short.npz", poses=np.zeros((4, 150)), mocap_framerate=np.array(30.0))
    with pytest.raises(AMASSError, match=r"short\.npz: poses: expected shape \(frames, 72 \| 156 \| 165\) "
                                         r"\(the 24, 52 or 55 joints.*got \(4, 150\)"):
        read_amass(tmp_path / "short.npz", body_model=d / "smplh.npz")
    with pytest.raises(AMASSError, match=r"walk_smplh\.npz: poses: joint count mismatch: the SMPL\+H clip rotates 30 "
                                         r"finger joint\(s\) that the body model .*smpl\.npz \(SMPL, 24 joints\)"):
        read_amass(d / "walk_smplh.npz", body_model=d / "smpl.npz")
    with pytest.raises(AMASSError, match=r"walk_smplx\.npz: pose_jaw: joint count mismatch: .*1 jaw joint"
                                         r".*SMPL\+H, 52"):
        read_amass(d / "walk_smplx.npz", body_model=d / "smplh.npz")
    np.savez(tmp_path / "hand.npz", root_orient=np.zeros((4, 3)), pose_body=np.zeros((4, 63)),
             pose_hand=np.zeros((4, 24)), mocap_frame_rate=np.array(30.0))
    with pytest.raises(AMASSError, match=r"pose_hand: expected shape \(frames, 90\)"):
        read_amass(tmp_path / "hand.npz", body_model=d / "smplh.npz")


def test_unknown_keys_are_listed(files, tmp_path):
    np.savez(tmp_path / "shape.npz", betas=np.zeros(16), gender=np.array("male"))
    with pytest.raises(AMASSError, match=r"shape\.npz: not an AMASS clip: it has the keys \['betas', 'gender'\]; "
                                         r"expected poses \[T, 156\].*root_orient"):
        read_amass(tmp_path / "shape.npz", body_model=files["dir"] / "smplh.npz")
    np.savez(tmp_path / "norate.npz", poses=np.zeros((4, 156)))
    with pytest.raises(AMASSError, match=r"mocap_framerate: missing \(nor mocap_frame_rate\)"):
        read_amass(tmp_path / "norate.npz", body_model=files["dir"] / "smplh.npz")


def test_nan_in_the_clip_or_the_model(files, tmp_path):
    d = files["dir"]
    with np.load(d / "walk_smplh.npz") as z:
        clip = dict(z)
    clip["trans"] = clip["trans"].copy()
    clip["trans"][5, 1] = np.nan
    np.savez(tmp_path / "nan.npz", **clip)
    with pytest.raises(AMASSError, match=r"nan\.npz: trans: 1 NaN or inf value\(s\), the first at index \(5, 1\)"):
        read_amass(tmp_path / "nan.npz", body_model=d / "smplh.npz")
    model = dict(files["smplh"])
    model["v_template"] = model["v_template"].copy()
    model["v_template"][3, 0] = np.inf
    np.savez(tmp_path / "bad_model.npz", **model)
    with pytest.raises(AMASSError, match=r"bad_model\.npz: v_template: 1 NaN or inf"):
        read_amass(d / "walk_smplh.npz", body_model=tmp_path / "bad_model.npz")


def test_a_pickle_naming_anything_else_is_refused_unrun(files, tmp_path):
    (tmp_path / "evil.pkl").write_bytes(pickle.dumps({"v_template": _Evil()}, protocol=2))
    with pytest.raises(AMASSError, match=r"evil\.pkl: cannot unpickle the body model: .*names "
                                         r"tests\.test_amass\._trap, which a body model may not"):
        read_amass(files["dir"] / "walk_smplh.npz", body_model=tmp_path / "evil.pkl")
    assert _TRAPPED == []


def test_up_must_be_y_or_z(files):
    with pytest.raises(jaxanim.JaxanimError, match=r"up: expected 'y' .* or 'z'"):
        read_amass(files["dir"] / "walk_smplh.npz", body_model=files["dir"] / "smplh.npz", up="x")


# ------------------------------------------------------------------------------------------------
# The command line
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("where", ["after", "before"])
def test_cli_fk_of_an_amass_clip(files, tmp_path, where):
    d, out = files["dir"], tmp_path / "fk.npz"
    flag = ["--body-model", str(d / "smplh.npz")]
    cmd = ["fk", str(d / "walk_smplh.npz"), "--out", str(out)]
    argv = cmd + flag if where == "after" else flag + cmd
    assert cli.main(["--quiet", "--no-compile-cache", *argv]) == 0
    pos, _, _ = _reference(files["smplh"], files["pose52"], files["trans"], files["betas"], 16)
    with np.load(out) as z:
        np.testing.assert_allclose(z["positions"], pos, rtol=0, atol=_ATOL_FK)
        assert list(z["joint_names"][:2]) == ["pelvis", "left_hip"]


def test_cli_without_body_model_is_a_clear_error(files, capsys):
    code = cli.main(["--no-compile-cache", "info", str(files["dir"] / "walk_smplh.npz")])
    err = capsys.readouterr().err
    assert code == 2
    assert "Traceback" not in err
    assert err.splitlines()[-1].startswith(f"error: {files['dir'] / 'walk_smplh.npz'}: an AMASS clip holds no skeleton")
    assert "--body-model MODEL" in err and "cannot ship one" in err


def test_render_and_view_tell_an_amass_clip_from_a_retarget_result(files, tmp_path):
    """``render`` and ``view`` read an ``.npz`` with ``qpos`` as a ``retarget`` result and any other as a clip."""
    from jaxanim.app._retarget_clip import is_retarget_file

    result = tmp_path / "retarget.npz"
    np.savez(result, qpos=np.zeros((2, 7)))
    assert is_retarget_file(result) and is_retarget_file(tmp_path / "absent.npz")  # its reader names the fault
    assert not is_retarget_file(files["dir"] / "walk_smplh.npz") and not is_retarget_file(default_clip_path())
