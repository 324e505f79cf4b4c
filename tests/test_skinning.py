"""Skinning (jaxanim.skinning): LBS and DQS, bind transforms, weights, the capsule mesh, OBJ (issue 15).

Independent references: LBS and DQS against per-vertex NumPy loops of the formulas (their own FK with
scipy's quaternion -> matrix, their own dual-quaternion product, the sandwich ``q v q-bar*`` to apply
it); a single-weight vertex against the FK transform; the half-angle blend and the candy wrapper
analytically; gradients against central finite differences.

Compiled shapes (kept few): the 6-joint test skeleton with 24 vertices, K = 3 (``skin`` of each
method, bind rest / given, their vmaps and gradients) and the 2-joint tube with 80 vertices, K = 2.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import jaxanim
from jaxanim import skinning
from jaxanim.skinning import Mesh, SkinWeights

from .helpers import assert_close, jitted_fk, random_pose, small_skeleton

_ATOL_SKIN = 1e-12  # float64 skinning vs the NumPy loops (file units, |v| <= ~3)
_ATOL_RIGID = 1e-12
_RTOL_ANALYTIC = 1e-12
_RTOL_FD = 1e-6  # directional derivatives vs central differences (h = 1e-6)
METHODS = ("lbs", "dqs")
#: ``bind_transforms`` of a posed bind as one program (eager, its FK compiles ~40 primitives one by one: ~1 s)
_bind_transforms = jax.jit(skinning.bind_transforms)
#: jaxanim's matrix -> quaternion (the signs its DQS blends with), one program instead of ~15 eager ones
_matrix_to_quat = jax.jit(jaxanim.rotations.matrix_to_quat)


# ------------------------------------------------------------------------------------------------
# NumPy references
# ------------------------------------------------------------------------------------------------


def _np_quat_matrix(q) -> np.ndarray:
    q = np.asarray(q, np.float64)
    return Rotation.from_quat(q[..., [1, 2, 3, 0]]).as_matrix()  # scipy is xyzw: converted here


def _np_fk(skel, q, t):
    """Global 4x4 transforms ``[J, 4, 4]``, one joint at a time."""
    q, t = np.asarray(q, np.float64), np.asarray(t, np.float64)
    G = np.zeros((skel.num_joints, 4, 4))
    for j, p in enumerate(skel.parents):
        L = np.eye(4)
        L[:3, :3], L[:3, 3] = _np_quat_matrix(q[j]), t[j]
        G[j] = L if p < 0 else G[p] @ L
    return G


def _np_skinning_matrices(skel, q, t, bind_G):
    return np.stack([g @ np.linalg.inv(b) for g, b in zip(_np_fk(skel, q, t), bind_G, strict=True)])


def _np_lbs(M, verts, joints, weights):
    out = np.zeros((len(verts), 3))
    for v in range(len(verts)):
        A = sum(weights[v, k] * M[joints[v, k]] for k in range(joints.shape[1]))
        out[v] = (A @ np.append(verts[v], 1.0))[:3]
    return out


def _qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def _qconj(a):
    return a * np.array([1.0, -1.0, -1.0, -1.0])


def _dq_mul(a, b):
    """``(r1 + eps d1)(r2 + eps d2) = r1 r2 + eps (r1 d2 + d1 r2)`` (the notes swap the last term)."""
    (r1, d1), (r2, d2) = a, b
    return _qmul(r1, r2), _qmul(r1, d2) + _qmul(d1, r2)


def _dq_from_matrix(M):
    r = Rotation.from_matrix(M[:3, :3]).as_quat()[[3, 0, 1, 2]]
    return r, 0.5 * _qmul(np.concatenate([[0.0], M[:3, 3]]), r)


def _np_dqs(M, verts, joints, weights):
    dqs = [_dq_from_matrix(m) for m in M]
    out = np.zeros((len(verts), 3))
    for v in range(len(verts)):
        pivot = dqs[joints[v, np.argmax(weights[v])]][0]
        br, bd = np.zeros(4), np.zeros(4)
        for k in range(joints.shape[1]):
            r, d = dqs[joints[v, k]]
            s = -1.0 if np.dot(r, pivot) < 0 else 1.0
            br, bd = br + weights[v, k] * s * r, bd + weights[v, k] * s * d
        n = np.linalg.norm(br)
        b = (br / n, bd / n)
        point = (np.array([1.0, 0, 0, 0]), np.concatenate([[0.0], verts[v]]))  # 1 + eps (0, v)
        third_conj = (_qconj(b[0]), -_qconj(b[1]))  # r* - eps d*
        _, moved = _dq_mul(_dq_mul(b, point), third_conj)
        out[v] = moved[1:]
    return out


# ------------------------------------------------------------------------------------------------
# Fixtures
# ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small():
    """The 6-joint skeleton, 24 vertices near it, K = 3 random weights (the first 6 vertices one-hot)."""
    skel = small_skeleton()
    rng = np.random.default_rng(3)
    verts = rng.normal(size=(24, 3)) * 0.4 + np.array([0.0, 1.2, 0.0])
    joints = np.stack([rng.choice(skel.num_joints, 3, replace=False) for _ in range(24)]).astype(np.int32)
    w = rng.random((24, 3)) + 0.05
    w[:6] = [1.0, 0.0, 0.0]
    w /= w.sum(axis=1, keepdims=True)
    q, t = random_pose(skel, seed=5, scale=1.5)  # large angles: DQS's hemisphere flips happen
    bq, bt = random_pose(skel, seed=6, scale=0.4)
    return skel, jnp.asarray(verts), SkinWeights(joints, w), q, t, (bq, bt)


def _tube(twist_axis_ring: float = 1.0, sides: int = 16):
    """A 2-joint skeleton along x (``a`` at 0, ``b`` at 1, End Site at 2) and a tube of radius 0.2 around
    it: 5 rings of 16 vertices at x = 0, 0.5, 1, 1.5, 2; distance-to-bone weights, K = 2."""
    skel = jaxanim.Skeleton(("a", "b"), (-1, 0), jnp.asarray([[0.0, 0, 0], [1.0, 0, 0]]),
                            end_site_parents=(1,), end_site_offsets=jnp.asarray([[1.0, 0, 0]]))
    phi = 2 * np.pi * np.arange(sides) / sides
    verts = np.concatenate([np.stack([np.full(sides, x), 0.2 * np.cos(phi), 0.2 * np.sin(phi)], axis=1)
                            for x in (0.0, 0.5, 1.0, 1.5, 2.0)])
    w = skinning.heuristic_weights(skel, verts, k=2)
    return skel, jnp.asarray(verts), w


@pytest.fixture(scope="module")
def tube():
    return _tube()


def _twist(angle_a: float, angle_b: float):
    """Root rotated by ``angle_a`` about x, the child by ``angle_b`` about x (local)."""
    q = jnp.stack([jnp.asarray([np.cos(a / 2), np.sin(a / 2), 0.0, 0.0]) for a in (angle_a, angle_b)])
    return q, jnp.asarray([[0.0, 0, 0], [1.0, 0, 0]])


def _ring_area(points: np.ndarray) -> float:
    """Shoelace area of a ring's projection on the yz plane."""
    y, z = points[:, 1], points[:, 2]
    return 0.5 * abs(np.dot(y, np.roll(z, -1)) - np.dot(z, np.roll(y, -1)))


# ------------------------------------------------------------------------------------------------
# Against the formulas
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("posed_bind", [False, True], ids=["rest bind", "given bind"])
def test_skin_matches_numpy_loop(small, method, posed_bind):
    skel, verts, w, q, t, (bq, bt) = small
    bind = _bind_transforms(skel, bq, bt) if posed_bind else None
    bind_G = _np_fk(skel, bq, bt) if posed_bind else _np_fk(skel, skel.rest_rotations(), skel.offsets)
    got = skinning.skin(skel, q, t, verts, w, method, bind)
    M = _np_skinning_matrices(skel, q, t, bind_G)
    ref = (_np_lbs if method == "lbs" else _np_dqs)(M, np.asarray(verts), np.asarray(w.joints), np.asarray(w.weights))
    assert_close(f"{method} vertices", got, ref, atol=_ATOL_SKIN)
    r = np.asarray(_matrix_to_quat(M[:, :3, :3]))  # the signs jaxanim blends with
    j = np.asarray(w.joints)
    pivot = j[np.arange(len(j)), np.argmax(np.asarray(w.weights), axis=1)]
    assert (np.einsum("vkq,vq->vk", r[j], r[pivot]) < 0).any(), "the pose should exercise DQS's hemisphere flip"


def test_one_product_forms_match_the_gathers(small, monkeypatch):
    """LBS as one matrix product and the DQS blend over (pivot, joint) pairs (used whenever they fit, and
    for DQS when the weights are concrete) against the per-vertex gathers (very large meshes, traced weights)."""
    from jaxanim.skinning import _skin

    skel, verts, w, q, t, _ = small
    # the skinning transforms by the NumPy reference (jitting jaxanim's compiled two programs, ~0.4 s)
    M = _np_skinning_matrices(skel, q, t, _np_fk(skel, skel.rest_rotations(), skel.offsets))
    R, tr = jnp.asarray(M[:, :3, :3]), jnp.asarray(M[:, :3, 3])
    pairs = _skin._dqs_pairs(np.asarray(w.joints), np.asarray(w.weights), skel.num_joints)
    assert pairs is not None and pairs.index.shape == w.joints.shape

    def run():  # a fresh jitted function per call: the branch is chosen at trace time
        lbs = jax.jit(lambda *a: _skin._lbs(*a))(R, tr, verts, w.joints, w.weights)
        return {"lbs": lbs, "dqs": jax.jit(lambda *a: _skin._dqs(*a))(R, tr, verts, w.joints, w.weights, pairs)}

    product = run()
    monkeypatch.setattr(_skin, "_DENSE_MAX", 0)
    assert _skin._dqs_pairs(np.asarray(w.joints), np.asarray(w.weights), skel.num_joints) is None
    pairs = None
    gather = run()
    for m in METHODS:
        assert_close(f"{m}: gather vs product", gather[m], product[m], atol=_ATOL_SKIN)


@pytest.mark.parametrize("method", METHODS)
def test_single_weight_vertex_moves_rigidly_with_its_joint(small, method):
    skel, verts, w, q, t, _ = small
    got = np.asarray(skinning.skin(skel, q, t, verts, w, method))[:6]
    fk = jitted_fk(skel, q, t)  # one program for both poses (eager FK compiles ~40 primitives one by one)
    rest = jitted_fk(skel, skel.rest_rotations(), skel.offsets)
    for v in range(6):
        j = int(w.joints[v, 0])
        local = np.asarray(rest.rotations[j]).T @ (np.asarray(verts[v]) - np.asarray(rest.positions[j]))
        want = np.asarray(fk.rotations[j]) @ local + np.asarray(fk.positions[j])
        assert_close(f"vertex {v} on joint {j}", got[v], want, atol=_ATOL_RIGID)


@pytest.mark.parametrize("method", METHODS)
def test_bind_pose_leaves_the_mesh_in_place(small, method):
    skel, verts, w, _, _, (bq, bt) = small
    at_rest = skinning.skin(skel, skel.rest_rotations(), skel.offsets, verts, w, method)
    assert_close("rest pose, rest bind", at_rest, verts, atol=_ATOL_RIGID)
    bind = _bind_transforms(skel, bq, bt)
    at_bind = skinning.skin(skel, bq, bt, verts, w, method, bind)
    assert_close("bind pose, given bind", at_bind, verts, atol=_ATOL_RIGID)


def test_bind_transforms_default_is_the_rest_pose(small):
    skel = small[0]
    T = np.asarray(skinning.bind_transforms(skel))
    fk = jitted_fk(skel, skel.rest_rotations(), skel.offsets)
    assert T.shape == (skel.num_joints, 4, 4)
    assert_close("R", T[:, :3, :3], fk.rotations, atol=0)
    assert_close("p", T[:, :3, 3], fk.positions, atol=0)
    assert_close("last row", T[:, 3], np.tile([0.0, 0, 0, 1], (skel.num_joints, 1)), atol=0)
    assert_close("as (R, p)", _bind_transforms(skel, skel.rest_rotations(), None), T, atol=1e-15)


# ------------------------------------------------------------------------------------------------
# Analytic cases: the half-angle blend and the candy wrapper
# ------------------------------------------------------------------------------------------------


def test_heuristic_weights_on_the_tube(tube):
    _, verts, w = tube
    j, wt = np.asarray(w.joints), np.asarray(w.weights)

    def ring(x):
        return np.nonzero(np.isclose(np.asarray(verts)[:, 0], x))[0]

    assert_close("x = 1: 50/50", wt[ring(1.0)], 0.5, atol=1e-12)
    assert (j[ring(0.0), 0] == 0).all() and (j[ring(2.0), 0] == 1).all()
    # at x = 0.5 the distances are 0.2 and hypot(0.5, 0.2), each plus the floor 1e-6 x the size (2)
    d0, d1 = 0.2 + 2e-6, np.hypot(0.5, 0.2) + 2e-6
    assert_close("x = 0.5: inverse squared distance", wt[ring(0.5), 0], 1.0 / (1.0 + (d0 / d1) ** 2), rtol=1e-12)
    assert_close("rows sum to 1", wt.sum(axis=1), 1.0, atol=1e-12)


def test_half_angle_blend_dqs_rotates_lbs_shrinks(tube):
    """At the joint (weights 50/50) of two rotations about one axis (x): DQS rotates the ring by the mean
    angle and keeps its radius; LBS rotates it by the same angle but shrinks it by cos(half the difference)."""
    skel, verts, w = tube
    alpha, beta = 0.3, 2.0  # the root by alpha, the child by alpha + beta in the world
    q, t = _twist(alpha, beta)
    ring = np.nonzero(np.isclose(np.asarray(verts)[:, 0], 1.0))[0]
    v0 = np.asarray(verts)[ring]
    phi0 = np.arctan2(v0[:, 2], v0[:, 1])
    for method, radius in (("dqs", 0.2), ("lbs", 0.2 * np.cos(beta / 2))):
        v = np.asarray(skinning.skin(skel, q, t, verts, w, method))[ring]
        assert_close(f"{method} x", v[:, 0], 1.0, atol=1e-12)
        assert_close(f"{method} radius", np.hypot(v[:, 1], v[:, 2]), radius, rtol=_RTOL_ANALYTIC)
        turned = np.angle(np.exp(1j * (np.arctan2(v[:, 2], v[:, 1]) - phi0)))
        assert_close(f"{method} angle", turned, alpha + beta / 2, rtol=_RTOL_ANALYTIC)


def test_candy_wrapper_lbs_collapses_dqs_keeps_the_cross_section(tube):
    skel, verts, w = tube
    ring = np.nonzero(np.isclose(np.asarray(verts)[:, 0], 1.0))[0]
    rest = _ring_area(np.asarray(verts)[ring])
    q, t = _twist(0.0, np.radians(175.0))
    lbs = _ring_area(np.asarray(skinning.skin(skel, q, t, verts, w, "lbs"))[ring])
    dqs = _ring_area(np.asarray(skinning.skin(skel, q, t, verts, w, "dqs"))[ring])
    assert lbs < 0.01 * rest, f"LBS cross-section {lbs / rest:.4f} of the rest area"
    assert_close("LBS area: cos^2 of half the twist", lbs / rest, np.cos(np.radians(87.5)) ** 2, rtol=1e-9)
    assert_close("DQS area", dqs / rest, 1.0, rtol=1e-12)


# ------------------------------------------------------------------------------------------------
# Batching and gradients
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", METHODS)
def test_vmap_over_frames_and_characters_equals_a_loop(small, method):
    """``skin_motion`` (``jax.vmap`` of the skinning kernel over frames, one mesh: the pose-only batch) and
    ``jax.vmap(skin)`` over poses and characters together (each frame its own vertices and weights) against
    single calls. One ``vmap(skin)`` batches the pose and the mesh at once: a ``vmap(skin)`` over the poses
    alone (what ``skin_motion`` compiles) and one over the meshes alone compiled a program each (~0.8 s per
    method). Inputs are stacked and sliced on the host (eager stacking and indexing compile a program each)."""
    skel, verts, w, _, _, _ = small
    qs, ts = (np.asarray(x) for x in random_pose(skel, seed=11, n=3, scale=1.0))
    loop = np.stack([np.asarray(skinning.skin(skel, jnp.asarray(qs[i]), jnp.asarray(ts[i]), verts, w, method))
                     for i in range(3)])
    motion = jaxanim.Motion(jnp.asarray(qs), jnp.asarray(ts), 1 / 30)
    assert_close("skin_motion", skinning.skin_motion(skel, motion, verts, w, method), loop, atol=1e-13)
    # frames and characters: each frame its own pose, vertices and weights
    v0, j0, w0 = np.asarray(verts), np.asarray(w.joints), np.asarray(w.weights)
    vs = jnp.asarray(np.stack([v0, v0 * 1.1, v0[::-1]]))
    ws = jnp.asarray(np.stack([w0, w0[::-1], w0]))
    js = jnp.asarray(np.stack([j0, j0[::-1], j0]))
    batched = np.asarray(jax.vmap(lambda q, t, v, j, ww: skinning.skin(skel, q, t, v, SkinWeights(j, ww), method))(
        jnp.asarray(qs), jnp.asarray(ts), vs, js, ws))
    assert_close("vmap over frames, character 0 (skin's own mesh)", batched[0], loop[0], atol=1e-13)
    for i in range(3):
        one = skinning.skin(skel, jnp.asarray(qs[i]), jnp.asarray(ts[i]), vs[i], SkinWeights(js[i], ws[i]), method)
        assert_close(f"frame and character {i}", batched[i], one, atol=1e-13)


@pytest.mark.parametrize("method", METHODS)
def test_gradients_match_central_differences(small, method):
    """Directional derivatives of ``sum(c * skin)`` along random directions of the weights, the local
    rotations (quaternions, not normalised: FK normalises) and the translations."""
    skel, verts, w, q, t, _ = small
    c = jnp.asarray(np.random.default_rng(0).normal(size=verts.shape))

    def loss(weights, q, t):
        return jnp.sum(c * skinning.skin(skel, q, t, verts, SkinWeights(w.joints, weights), method))

    # one program for the gradient and the loss values of the differences (a jitted loss apart compiled a
    # second one: ~0.7 s per method)
    value_and_grad = jax.jit(jax.value_and_grad(loss, argnums=(0, 1, 2)))
    grads = value_and_grad(w.weights, q, t)[1]
    rng = np.random.default_rng(1)
    h = 1e-6
    args = [np.asarray(x) for x in (w.weights, q, t)]  # the steps on the host: eager jnp compiles each op
    for i, name in enumerate(("weights", "rotations", "translations")):
        g = np.asarray(grads[i])
        assert np.isfinite(g).all(), name
        d = rng.normal(size=g.shape)
        args_p, args_m = list(args), list(args)
        args_p[i], args_m[i] = args[i] + h * d, args[i] - h * d
        fd = (float(value_and_grad(*args_p)[0]) - float(value_and_grad(*args_m)[0])) / (2 * h)
        assert_close(f"d/d{name}", np.sum(g * d), fd, rtol=_RTOL_FD)


# ------------------------------------------------------------------------------------------------
# The capsule mesh
# ------------------------------------------------------------------------------------------------


def _edges_twice(faces: np.ndarray) -> bool:
    """Every directed edge once and its reverse once: a closed, consistently oriented surface."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    directed = {tuple(x) for x in e.tolist()}
    return len(directed) == len(e) and all((b, a) in directed for a, b in directed)


def test_capsule_mesh_of_the_shipped_walk():
    skel = jaxanim.read_bvh(jaxanim.default_clip_path())[0]
    mesh = skinning.capsule_mesh(skel)
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    assert 1000 <= V.shape[0] <= 3000 and mesh.faces.dtype == jnp.int32
    assert F.min() >= 0 and F.max() < V.shape[0]
    assert _edges_twice(F), "the capsules must be closed and consistently oriented"
    from jaxanim.skinning._mesh import bone_segments, skeleton_size

    a, b, owner = bone_segments(skel)
    r = 0.035 * skeleton_size(skel)
    assert len(owner) == 25 and V.shape[0] == 25 * 82
    lengths = np.linalg.norm(b - a, axis=1)
    capsules = np.sum(np.pi * r**2 * lengths + 4 / 3 * np.pi * r**3)
    volume = np.einsum("ti,ti->t", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6
    assert 0.8 * capsules < volume < capsules, f"signed volume {volume} vs capsules {capsules} (outward faces)"
    w = skinning.heuristic_weights(skel, mesh)
    wt, jt = np.asarray(w.weights), np.asarray(w.joints)
    assert w.joints.shape == (V.shape[0], 4) and np.all(wt >= 0)
    assert_close("rows sum to 1", wt.sum(axis=1), 1.0, atol=1e-12)
    # the middle rings (at 2/5 and 3/5) of the left forearm's capsule go with LeftForeArm, which owns it
    s = int(np.nonzero(owner == skel.index("LeftForeArm"))[0][0])
    for f in (0.4, 0.6):
        ring = np.nonzero(np.abs(np.linalg.norm(V - (a[s] + f * (b[s] - a[s])), axis=1) - r) < 1e-9)[0]
        assert ring.size == 10 and (jt[ring, 0] == skel.index("LeftForeArm")).all()
    assert skinning.capsule_mesh(skel, radius=0.05, sides=6, rings=1, cap_rings=1).num_vertices == 25 * (6 * 2 + 2)


def test_capsule_mesh_of_a_lone_joint_is_a_sphere():
    skel = jaxanim.Skeleton(("only",), (-1,), jnp.zeros((1, 3)))
    mesh = skinning.capsule_mesh(skel, radius=0.5, sides=8, cap_rings=3)
    V = np.asarray(mesh.vertices)
    assert V.shape[0] == 8 * 5 + 2 and _edges_twice(np.asarray(mesh.faces))
    assert_close("on the sphere", np.linalg.norm(V, axis=1), 0.5, rtol=1e-12)
    w = skinning.heuristic_weights(skel, mesh, k=3)
    assert w.joints.shape == (V.shape[0], 3)
    assert_close("padded slots", w.weights, np.tile([1.0, 0, 0], (V.shape[0], 1)), atol=0)


# ------------------------------------------------------------------------------------------------
# OBJ
# ------------------------------------------------------------------------------------------------


def test_obj_round_trip(tmp_path, tube):
    skel = tube[0]
    mesh = skinning.capsule_mesh(skel, sides=5, rings=1, cap_rings=1)
    path = tmp_path / "m.obj"
    skinning.write_obj(path, mesh)
    back = skinning.read_obj(path)
    assert_close("vertices", back.vertices, mesh.vertices, atol=0)
    assert_close("faces", back.faces, mesh.faces, atol=0)
    skinning.write_obj(path, np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces))
    assert_close("float32 vertices", skinning.read_obj(path, np.float32).vertices,
                 np.asarray(mesh.vertices, np.float32), atol=0)


def test_obj_reader_forms(tmp_path):
    text = ("# a comment\nmtllib x.mtl\no thing\nv 0 0 0\nv 1 0 0 1.0\nv 1 1 0 0.5 0.5 0.5  # coloured\n"
            "v 0 1 0\nvt 0 0\nvn 0 0 1\ng part\ns off\nusemtl red\n\n"
            "f 1/1/1 2/1/1 3/1/1 4/1/1\nf -4//1 -3//1 -1//1\nf 1/1 3/1 4/1\nv 0.5 0.5 1\nf 1 2 3 4 5\n")
    path = tmp_path / "forms.obj"
    path.write_text(text)
    mesh = skinning.read_obj(path)
    assert mesh.vertices.shape == (5, 3)
    want = [[0, 1, 2], [0, 2, 3], [0, 1, 3], [0, 2, 3], [0, 1, 2], [0, 2, 3], [0, 3, 4]]
    assert np.asarray(mesh.faces).tolist() == want


@pytest.mark.parametrize("text, line, match", [
    ("v 0 0 0\nv 1 0\n", 2, "3 coordinates"),
    ("v 0 0 0\n# c\nv 1 x 0\n", 3, "3 numbers"),
    ("v 0 0 nan\n", 1, "not finite"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", 4, "at least 3 vertices"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\nv 1 1 1\nv 1 1 2\nf 1 2 9\n", 7, r"points past the vertices.*has 5"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", 4, "start at 1"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf a b c\n", 4, "bad face vertex reference 'a'"),
    ("v 0 0 0\nv 1 0 0\nf -3 1 2\nv 0 1 0\n", 3, "before the first vertex"),
])
def test_obj_errors_name_the_line(tmp_path, text, line, match):
    path = tmp_path / "bad.obj"
    path.write_text(text)
    with pytest.raises(skinning.OBJParseError, match=match) as info:
        skinning.read_obj(path)
    assert info.value.line == line and str(info.value).startswith(f"{path}:{line}: ")
    assert isinstance(info.value, jaxanim.JaxanimError)


def test_obj_unreadable_or_empty(tmp_path):
    with pytest.raises(jaxanim.JaxanimError, match="cannot read it"):
        skinning.read_obj(tmp_path / "missing.obj")
    (tmp_path / "empty.obj").write_text("# nothing\nvt 0 0\n")
    with pytest.raises(jaxanim.JaxanimError, match="no vertices"):
        skinning.read_obj(tmp_path / "empty.obj")
    with pytest.raises(jaxanim.JaxanimError, match=r"faces: face 1 has vertex indices \[0, 1, 3\], outside \[0, 3\)"):
        skinning.write_obj(tmp_path / "x.obj", np.zeros((3, 3)), [[0, 1, 2], [0, 1, 3]])


# ------------------------------------------------------------------------------------------------
# Bad input
# ------------------------------------------------------------------------------------------------


def test_weight_errors_name_the_vertex(small):
    skel, verts, w, q, t, _ = small
    j, wt = np.asarray(w.joints), np.asarray(w.weights)
    with pytest.raises(jaxanim.JaxanimError, match=r"weights: expected one row per vertex.*got 23 rows.*24 vertices"):
        skinning.skin(skel, q, t, verts, SkinWeights(j[:23], wt[:23]))
    bad = j.copy()
    bad[7, 2] = 6
    with pytest.raises(jaxanim.JaxanimError, match=r"vertex 7 has joint index 6 \(slot 2\), out of range.*6 joints"):
        skinning.check_weights(skel, SkinWeights(bad, wt))
    bad[7, 2] = -1
    with pytest.raises(jaxanim.JaxanimError, match="vertex 7 has joint index -1"):
        skinning.skin(skel, q, t, verts, SkinWeights(bad, wt), "dqs")
    neg = wt.copy()
    neg[9] = [1.2, -0.2, 0.0]
    with pytest.raises(jaxanim.JaxanimError, match=r"vertex 9 has a negative weight -0.2 \(slot 1\)"):
        skinning.skin(skel, q, t, verts, SkinWeights(j, neg))
    off = wt.copy()
    off[12] *= 0.8
    with pytest.raises(jaxanim.JaxanimError, match=r"vertex 12's weights sum to 0.8, expected 1.*normalize=True"):
        skinning.skin(skel, q, t, verts, SkinWeights(j, off))
    fixed = skinning.check_weights(skel, SkinWeights(j, off), 24, normalize=True)
    assert_close("normalised", fixed.weights, wt, atol=1e-15)
    assert_close("normalised and skinned", skinning.skin(skel, q, t, verts, SkinWeights(j, off), normalize=True),
                 skinning.skin(skel, q, t, verts, w), atol=1e-13)
    zero = wt.copy()
    zero[3] = 0.0
    with pytest.raises(jaxanim.JaxanimError, match="vertex 3 has all its weights zero"):
        skinning.check_weights(skel, SkinWeights(j, zero), normalize=True)
    with pytest.raises(jaxanim.JaxanimError, match="non-finite"):
        skinning.check_weights(skel, SkinWeights(j, np.where(np.arange(24)[:, None] == 2, np.nan, wt)))
    assert skinning.check_weights(skel, w, 24) is w


def test_module_and_argument_errors(small):
    skel, verts, w, q, t, _ = small
    with pytest.raises(jaxanim.JaxanimError, match="joints: expected an integer array of indices, got dtype float"):
        SkinWeights(np.asarray(w.joints, np.float64), w.weights)
    with pytest.raises(jaxanim.JaxanimError, match=r"weights: expected shape \(V, K\) = \(24, 3\)"):
        SkinWeights(w.joints, w.weights[:, :2])
    with pytest.raises(jaxanim.JaxanimError, match=r"vertices: expected shape \(V, 3\), got \(24, 2\)"):
        Mesh(verts[:, :2], None)
    with pytest.raises(jaxanim.JaxanimError, match=r"faces: face 0 has vertex indices \[0, 1, 24\]"):
        Mesh(verts, [[0, 1, 24]])
    with pytest.raises(jaxanim.JaxanimError, match="method: expected one of 'lbs', 'dqs', got 'slerp'"):
        skinning.skin(skel, q, t, verts, w, "slerp")
    with pytest.raises(jaxanim.JaxanimError, match=r"vertices: expected shape \(V, 3\)"):
        skinning.skin(skel, q, t, verts[:, :2], w)
    with pytest.raises(jaxanim.JaxanimError, match=r"rotations: expected shape \(joints, 4\) = \(6, 4\)"):
        skinning.skin(skel, q[:5], t, verts, w)
    with pytest.raises(jaxanim.JaxanimError, match=r"bind: expected shape \(joints, 4, 4\) = \(6, 4, 4\)"):
        skinning.skin(skel, q, t, verts, w, "lbs", np.zeros((6, 3, 4)))
    with pytest.raises(jaxanim.JaxanimError, match="weights: expected a jaxanim.skinning.SkinWeights"):
        skinning.skin(skel, q, t, verts, (w.joints, w.weights))
    with pytest.raises(jaxanim.JaxanimError, match="k: expected an integer >= 1"):
        skinning.heuristic_weights(skel, verts, k=0)
    with pytest.raises(jaxanim.JaxanimError, match="radius: expected a positive finite number"):
        skinning.capsule_mesh(skel, radius=-1.0)
    with pytest.raises(jaxanim.JaxanimError, match=r"motion: expected 6 joints \(the skeleton's\), got 5"):
        skinning.skin_motion(skel, jaxanim.Motion(q[None, :5], t[None, :5], 1 / 30), verts, w)
