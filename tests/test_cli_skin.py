"""``jaxanim skin`` (issue 15) and a reduced run of the ``skinning`` benchmark.

The commands run in-process through ``main([...])``. Their output is checked against the benchmark's
vectorised NumPy LBS / DQS (``benchmarks.skinning``, written apart from jaxanim's kernels; its DQS is jaxanim's
formulation, checked here against ``skin_motion`` to round-off on poses whose blends need flips; test_skinning
checks jaxanim's kernels against per-vertex loops). Compiled shapes: the shipped walk (120 frames, LBS,
float64), a 4-frame cut of it (DQS float32; LBS with a 250-vertex mesh), 5 random poses (DQS, 250 vertices,
K = 3) and the benchmark's two tiny kernels.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

import jaxanim
from benchmarks.skinning import numpy_dqs, numpy_lbs
from jaxanim import skinning
from jaxanim.app import _cli as cli
from jaxanim.app._common import _as_dtype

from .helpers import assert_close, numpy_fk, quick_bench_config

_ATOL_CLI64 = 1e-12  # float64 command output vs the NumPy skinning (m)
_ATOL_CLI32 = 2e-5  # --float32
_ATOL_PEER = 1e-10  # the benchmark's NumPy DQS vs skin_motion's, float64 (m): the same formulation, so round-off


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = cli.main(["--no-compile-cache", *(str(a) for a in argv)])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _numpy(method, skel, motion, verts, w) -> np.ndarray:
    fn = numpy_lbs if method == "lbs" else numpy_dqs
    return fn(skel.parents, np.asarray(skel.offsets, np.float64), np.asarray(motion.rotations, np.float64),
              np.asarray(motion.translations, np.float64), np.asarray(verts, np.float64), np.asarray(w.joints),
              np.asarray(w.weights, np.float64))


@pytest.fixture(scope="module")
def walk():
    return jaxanim.read_bvh(jaxanim.default_clip_path())[:2]


@pytest.fixture(scope="module")
def short_clip(tmp_path_factory, walk):
    """The walk's frames 30-33 as a BVH file."""
    skel, m = walk
    path = tmp_path_factory.mktemp("clip") / "short.bvh"
    jaxanim.write_bvh(path, skel, jaxanim.Motion(m.rotations[30:34], m.translations[30:34], m.frame_time))
    return path, jaxanim.read_bvh(path)[1]


@pytest.fixture(scope="module")
def small_mesh(tmp_path_factory, walk):
    """A 250-vertex capsule mesh as OBJ, and its K = 2 distance-to-bone weights as W.npz."""
    skel = walk[0]
    d = tmp_path_factory.mktemp("mesh")
    mesh = skinning.capsule_mesh(skel, sides=4, rings=1, cap_rings=1)
    w = skinning.heuristic_weights(skel, mesh, k=2)
    skinning.write_obj(d / "m.obj", mesh)
    np.savez(d / "w.npz", joints=np.asarray(w.joints), weights=np.asarray(w.weights))
    return d, mesh, w


def test_skin_writes_the_npz(tmp_path, capsys, walk):
    skel, motion = walk
    out = tmp_path / "walk.npz"
    code, stdout, stderr = _run(capsys, "skin", "--out", out)
    assert code == 0, stderr
    with np.load(out) as z:
        verts, faces = z["vertices"], z["faces"]
    mesh = skinning.capsule_mesh(skel)
    assert verts.shape == (120, mesh.num_vertices, 3) and verts.dtype == np.float64
    assert faces.shape == (mesh.num_faces, 3) and np.array_equal(faces, np.asarray(mesh.faces))
    ref = _numpy("lbs", skel, motion, mesh.vertices, skinning.heuristic_weights(skel, mesh))
    assert_close("vertices", verts, ref, atol=_ATOL_CLI64)
    assert f"wrote {out}: vertices [120, 2050, 3] (float64), faces [4000, 3]" in stdout
    assert "LBS skinning of the procedural capsule mesh" in stdout and "M vertex-frames/s" in stdout
    assert "skin compile" in stdout and "jaxanim: skinning 120 frames x 2050 vertices" in stderr


def test_skin_writes_an_obj_sequence_dqs_float32(tmp_path, capsys, walk, short_clip):
    skel = walk[0]
    path, motion = short_clip
    out = tmp_path / "frames" / "walk.obj"  # the folder is created
    code, stdout, stderr = _run(capsys, "skin", path, "--method", "dqs", "--float32", "--out", out)
    assert code == 0, stderr
    files = sorted(p.name for p in out.parent.iterdir())
    assert files == [f"walk_000{f}.obj" for f in range(4)]
    skel32 = _as_dtype(skel, np.float32)  # the command's skeleton, mesh and weights are float32's
    mesh = skinning.capsule_mesh(skel32)
    ref = _numpy("dqs", skel, motion, mesh.vertices, skinning.heuristic_weights(skel32, mesh))
    for f in range(4):
        back = skinning.read_obj(out.parent / f"walk_000{f}.obj")
        assert_close(f"frame {f}", back.vertices, ref[f], atol=_ATOL_CLI32)
        assert np.array_equal(np.asarray(back.faces), np.asarray(mesh.faces))
    assert "wrote 4 OBJ files" in stdout and "(float32)" in stdout and "DQS" in stdout


def test_skin_with_a_mesh_and_weights(tmp_path, capsys, walk, short_clip, small_mesh):
    skel = walk[0]
    path, motion = short_clip
    d, mesh, w = small_mesh
    out = tmp_path / "out.npz"
    code, stdout, stderr = _run(capsys, "skin", path, "--mesh", d / "m.obj", "--weights", d / "w.npz", "--out", out)
    assert code == 0, stderr
    with np.load(out) as z:
        assert z["vertices"].shape == (4, 250, 3) and z["faces"].shape == (mesh.num_faces, 3)
        assert_close("vertices", z["vertices"], _numpy("lbs", skel, motion, mesh.vertices, w), atol=_ATOL_CLI64)
    assert f"weights: {d / 'w.npz'} (K = 2)" in stdout


def _error(capsys, *argv) -> str:
    code, stdout, stderr = _run(capsys, *argv)
    assert code == 2, (stdout, stderr)
    assert "Traceback" not in stderr
    lines = [ln for ln in stderr.splitlines() if ln.startswith("error: ")]
    assert len(lines) == 1, stderr
    return lines[0]


def test_skin_bad_input(tmp_path, capsys, short_clip, small_mesh):
    path = short_clip[0]
    d, _, w = small_mesh
    msg = _error(capsys, "skin", path, "--method", "linear")
    assert msg == "error: --method: expected one of lbs, dqs, got 'linear'"
    msg = _error(capsys, "skin", path, "--out", tmp_path / "out.ply")
    assert msg.startswith(f"error: --out {tmp_path / 'out.ply'}: unknown output extension '.ply'; expected .npz")
    # weights that do not match the mesh
    short = tmp_path / "short.npz"
    np.savez(short, joints=np.asarray(w.joints)[:-1], weights=np.asarray(w.weights)[:-1])
    msg = _error(capsys, "skin", path, "--mesh", d / "m.obj", "--weights", short, "--out", tmp_path / "o.npz")
    assert msg.startswith(f"error: {short}: weights: expected one row per vertex") and "249 rows" in msg
    assert "the mesh's 250 vertices" in msg and f"mesh: {d / 'm.obj'}: 250 vertices" in msg
    # joint indices out of range (the walk has 21 joints)
    bad = np.asarray(w.joints).copy()
    bad[17, 1] = 21
    np.savez(tmp_path / "bad.npz", joints=bad, weights=np.asarray(w.weights))
    msg = _error(capsys, "skin", path, "--mesh", d / "m.obj", "--weights", tmp_path / "bad.npz")
    assert "vertex 17 has joint index 21 (slot 1), out of range for a skeleton of 21 joints" in msg
    # rows that do not sum to 1: an error, or normalised on request
    half = tmp_path / "half.npz"
    np.savez(half, joints=np.asarray(w.joints), weights=0.5 * np.asarray(w.weights))
    msg = _error(capsys, "skin", path, "--mesh", d / "m.obj", "--weights", half, "--out", tmp_path / "o.npz")
    assert "vertex 0's weights sum to 0.5, expected 1" in msg
    np.savez(tmp_path / "nokey.npz", indices=np.asarray(w.joints), weights=np.asarray(w.weights))
    msg = _error(capsys, "skin", path, "--mesh", d / "m.obj", "--weights", tmp_path / "nokey.npz")
    assert "missing array(s) ['joints']" in msg and "['indices', 'weights']" in msg
    np.savez(tmp_path / "float.npz", joints=np.asarray(w.joints, np.float64), weights=np.asarray(w.weights))
    msg = _error(capsys, "skin", path, "--mesh", d / "m.obj", "--weights", tmp_path / "float.npz")
    assert "'joints' must hold integer joint indices" in msg
    # a face past the vertices, with its line
    (tmp_path / "bad.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2 4\n")
    msg = _error(capsys, "skin", path, "--mesh", tmp_path / "bad.obj")
    assert msg.startswith(f"error: {tmp_path / 'bad.obj'}:5: face [1, 2, 4] points past the vertices")
    msg = _error(capsys, "skin", path, "--mesh", d / "m.obj", "--radius", "0.1")
    assert "--radius sizes the procedural capsule mesh" in msg
    assert not (tmp_path / "o.npz").exists()


def test_numpy_dqs_is_jaxanims_formulation(walk, small_mesh):
    """The benchmark's NumPy DQS (the skinning table's peer) computes what ``skin_motion``'s DQS computes: equal to
    round-off on random local rotations, where many (largest-weight joint, joint) pairs are antipodal and the blend
    must flip them, with random weights, a fifth of them tied for the largest (the pivot is the first of a tie)."""
    skel = walk[0]
    mesh = small_mesh[1]
    rng = np.random.default_rng(3)
    V, J, K, F = mesh.num_vertices, skel.num_joints, 3, 5
    joints = np.stack([rng.choice(J, K, replace=False) for _ in range(V)])
    weights = rng.uniform(0.1, 1.0, (V, K))
    weights[::5, 1] = weights[::5, 0]
    weights /= weights.sum(axis=1, keepdims=True)
    w = skinning.SkinWeights(joints, weights)
    q = rng.normal(size=(F, J, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    trans = np.repeat(np.asarray(skel.offsets, np.float64)[None], F, axis=0)
    trans[:, 0] = rng.normal(size=(F, 3))
    motion = jaxanim.Motion(q, trans, 1 / 30)
    # the rest pose's global rotations are the identity, so these are the skinning rotations' quaternions; the
    # global rotations of frame 0 by numpy FK, their quaternions by jaxanim's conversion, whose signs its DQS blends
    # with (an eager FK of the walk compiled ~20 small programs)
    world = numpy_fk(skel, q[0], trans[0]).rotations
    r = np.asarray(jax.jit(jaxanim.rotations.matrix_to_quat)(world))
    pivot = joints[np.arange(V), np.argmax(weights, axis=1)]
    assert np.any(np.einsum("vq,vkq->vk", r[pivot], r[joints]) < 0), "no pair needs a flip"
    want = np.asarray(skinning.skin_motion(skel, motion, mesh, w, "dqs"))
    assert_close("numpy_dqs vs skin_motion (DQS)", _numpy("dqs", skel, motion, mesh.vertices, w), want,
                 atol=_ATOL_PEER)


def test_skin_help_mentions_the_obj_sequence(capsys):
    with pytest.raises(SystemExit):
        cli._build_parser().parse_args(["skin", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "one file per frame" in text and "DIR/name_0000.obj" in text and "lbs|dqs" in text


def test_benchmark_reduced_run():
    """``python -m benchmarks skinning`` at 200 vertices x 4 frames: every row measured and accurate (the
    timings are not checked)."""
    from benchmarks import REGISTRY
    from benchmarks.skinning import SkinningSizes, run_skinning

    assert REGISTRY["skinning"].load() is run_skinning
    tables = run_skinning(quick_bench_config(dtypes=("float64",)), SkinningSizes(vertices=200, frames=4))
    assert [t.name for t in tables] == ["skinning-lbs", "skinning-dqs"]
    for table, method in zip(tables, ("LBS", "DQS"), strict=True):
        rows = {r.implementation: r for r in table.rows}
        assert set(rows) == {f"numpy, vectorised ({method})", f"jaxanim skin_motion ({method})"}
        for name, r in rows.items():
            assert r.measured and r.batch == 4 and r.us_per_char > 0, name
        jax_row = rows[f"jaxanim skin_motion ({method})"]
        assert jax_row.accuracy < 1e-12 and jax_row.compile_s > 0
        assert 150 <= jax_row.chars_per_call / 4 <= 300, "vertices"
