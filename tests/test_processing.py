"""Motion processing (:mod:`jaxanim.skeleton._processing`) and the ``blend`` / ``loop`` commands.

References are written here independently, with numpy and ``scipy.spatial.transform.Rotation``
(scipy stores quaternions xyzw; jaxanim wxyz: :func:`_R` and :func:`_wxyz` convert explicitly).
Compiled shapes are few: the shipped walk (120 x 21), its first 97 frames (the loop tests and the
vmap test's clips) and one batch of 8 root poses; the CLI test blends at the same frames as the
library test, so its transition comes from the same jit cache. The references slice the clips on
the host (:func:`_host`): eager slicing of a jax array compiles a program per shape (~20-100 ms each,
about 40 of them in this file).
"""

from __future__ import annotations

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxanim import JaxanimError
from jaxanim.app import _cli
from jaxanim.skeleton._clips import resample
from jaxanim.skeleton import (
    Motion,
    Skeleton,
    align,
    concatenate,
    decay_spring,
    default_clip_path,
    facing_frame,
    inertialize,
    make_loop,
    mirror,
    mirror_pairs,
    read_bvh,
    split_facing,
    transition,
    write_bvh,
)

from .helpers import assert_close, batched_fk

_ATOL = 1e-10  # float64 processing vs the numpy / scipy references
_ATOL_BVH = 2e-6  # through a BVH file: 6 decimals (degrees and file units)
_CONT = 1.5  # continuity: a jump may be this many times the clips' own largest per-frame change
_Y = np.array([0.0, 1.0, 0.0])
_FA, _FB, _W = 60, 30, 10  # the transition the library and CLI tests share


# ------------------------------------------------------------------------------------------------
# Independent references (scipy, xyzw)
# ------------------------------------------------------------------------------------------------


def _host(m: Motion) -> Motion:
    """The clip with NumPy arrays (``jax.device_get``), for slicing and indexing without compiling eager programs."""
    return jax.device_get(m)


def _R(q_wxyz) -> Rotation:
    q = np.asarray(q_wxyz, np.float64)
    return Rotation.from_quat(q[..., [1, 2, 3, 0]])


def _wxyz(R: Rotation) -> np.ndarray:
    return R.as_quat()[..., [3, 0, 1, 2]]


def _ref_facing(q_wxyz, p, up=_Y):
    """Heading R' R (R' the smallest rotation taking R up to up, from the cross product) and the
    root projected on the ground, one pose."""
    u = np.asarray(up, np.float64) / np.linalg.norm(up)
    R = _R(q_wxyz)
    a = R.apply(u)
    c = np.cross(a, u)
    s, co = np.linalg.norm(c), float(a @ u)
    R_prime = Rotation.from_rotvec(c / s * np.arctan2(s, co)) if s > 1e-14 else Rotation.identity()
    p = np.asarray(p, np.float64)
    return R_prime * R, p - (p @ u) * u


def _ref_align(b: Motion, fb: int, a: Motion, fa: int):
    """Eq. 5.5 on B's root: ``(root quaternions wxyz [F, 4], root positions [F, 3])``."""
    a, b = _host(a), _host(b)
    R_A, t_A = _ref_facing(a.rotations[fa, 0], a.translations[fa, 0])
    R_B, t_B = _ref_facing(b.rotations[fb, 0], b.translations[fb, 0])
    D = R_A * R_B.inv()
    q = _wxyz(D * _R(b.rotations[:, 0]))
    p = D.apply(np.asarray(b.translations[:, 0]) - t_B) + t_A
    return q, p


def _same_rotation(name, q1, q2, atol):
    """Quaternions equal up to sign: |<q1, q2>| = 1."""
    d = np.abs(np.sum(np.asarray(q1) * np.asarray(q2), axis=-1))
    assert_close(name, d, np.ones_like(d), atol=atol)


def _angles(q1, q2) -> np.ndarray:
    """Angle between rotations (radians), by scipy, any batch shape."""
    q1, q2 = np.broadcast_arrays(np.asarray(q1, np.float64), np.asarray(q2, np.float64))
    return (_R(q1.reshape(-1, 4)) * _R(q2.reshape(-1, 4)).inv()).magnitude().reshape(q1.shape[:-1])


def _steps(p) -> np.ndarray:
    return np.linalg.norm(np.diff(np.asarray(p), axis=0), axis=-1)


def _accels(p) -> np.ndarray:
    return np.linalg.norm(np.diff(np.asarray(p), 2, axis=0), axis=-1)


def _turn(m: Motion, yaw: float, shift) -> Motion:
    """The clip turned about world Y by ``yaw`` and moved by ``shift``, written with scipy."""
    Q = Rotation.from_rotvec([0.0, yaw, 0.0])
    q = np.asarray(m.rotations).copy()
    t = np.asarray(m.translations).copy()
    q[:, 0] = _wxyz(Q * _R(q[:, 0]))
    t[:, 0] = Q.apply(t[:, 0]) + np.asarray(shift)
    return Motion(jnp.asarray(q), jnp.asarray(t), m.frame_time)


# ------------------------------------------------------------------------------------------------
# Fixtures
# ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def walk():
    return read_bvh(default_clip_path())


@pytest.fixture(scope="module")
def mirrored(walk):
    skel, m = walk
    return mirror(m, skel)


@pytest.fixture(scope="module")
def poses():
    """8 random root poses (tilted, any heading), one upside-down-free batch."""
    rng = np.random.default_rng(0)
    rv = rng.normal(size=(8, 3)) * np.array([0.5, 2.0, 0.5])
    return jnp.asarray(_wxyz(Rotation.from_rotvec(rv))), jnp.asarray(rng.normal(size=(8, 3)))


# ------------------------------------------------------------------------------------------------
# Facing frames and alignment
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("up", [(0.0, 1.0, 0.0), (0.0, 0.0, 2.0)])
def test_facing_frame_matches_scipy(poses, up):
    q, p = poses
    facing, origin = (np.asarray(x) for x in facing_frame(q, p, up=up))
    u = np.asarray(up) / np.linalg.norm(up)
    q, p = np.asarray(q), np.asarray(p)
    for i in range(q.shape[0]):
        R_y, o = _ref_facing(q[i], p[i], up)
        _same_rotation(f"facing[{i}]", facing[i], _wxyz(R_y), _ATOL)
        assert_close(f"origin[{i}]", origin[i], o, atol=_ATOL)
    assert_close("facing about up", _R(facing).apply(u), np.broadcast_to(u, (8, 3)), atol=_ATOL)
    R_y, R_xz = split_facing(q, up=up)
    _same_rotation("R_y R_xz", _wxyz(_R(R_y) * _R(R_xz)), q, _ATOL)
    assert_close("R_xz has no twist about up", np.asarray(R_xz)[:, 1:] @ u, np.zeros(8), atol=_ATOL)


def test_facing_frame_vmap_equals_loop(poses):
    q, p = poses
    batched = [np.asarray(x) for x in jax.jit(jax.vmap(lambda q, p: facing_frame(q, p)))(q, p)]
    q, p = np.asarray(q), np.asarray(p)
    for i in range(q.shape[0]):
        one = facing_frame(jnp.asarray(q[i]), jnp.asarray(p[i]))
        assert_close(f"facing[{i}]", batched[0][i], one[0], atol=1e-14)
        assert_close(f"origin[{i}]", batched[1][i], one[1], atol=1e-14)


def test_align_matches_eq_5_5(walk, mirrored):
    _, a = walk
    b = _turn(mirrored, 2.0, [3.0, 0.0, -1.0])
    out = _host(align(b, 17, a, 50))
    q_ref, p_ref = _ref_align(b, 17, a, 50)
    a, b = _host(a), _host(b)
    _same_rotation("root rotations", out.rotations[:, 0], q_ref, _ATOL)
    assert_close("root positions", out.translations[:, 0], p_ref, atol=_ATOL)
    assert_close("root height is B's own", out.translations[:, 0, 1], b.translations[:, 0, 1], atol=_ATOL)
    assert_close("joints are B's own", out.rotations[:, 1:], b.rotations[:, 1:])
    assert_close("ground position at the switch", out.translations[17, 0, ::2], a.translations[50, 0, ::2], atol=_ATOL)


def test_turned_clip_aligns_back(walk):
    _, m = walk
    turned = _turn(m, -2.5, [4.0, 0.0, 7.0])
    back = _host(align(turned, 40, m, 40))
    m = _host(m)
    _same_rotation("root rotations", back.rotations[:, 0], m.rotations[:, 0], _ATOL)
    assert_close("root positions", back.translations, m.translations, atol=_ATOL)


def test_align_vmap_equals_loop(walk):
    _, m = walk
    clips = [_turn(m, y, [y, 0.0, -y]) for y in (0.3, -1.0, 2.5)]
    stacked = jax.tree.map(lambda *x: jnp.asarray(np.stack([np.asarray(a) for a in x])), *clips)
    frames = [0, 33, 119]
    batched = _host(jax.jit(jax.vmap(lambda b, f: align(b, f, m, 7)))(stacked, jnp.asarray(frames)))
    for i, c in enumerate(clips):
        one = align(c, frames[i], m, 7)
        assert_close(f"rotations[{i}]", batched.rotations[i], one.rotations, atol=1e-13)
        assert_close(f"translations[{i}]", batched.translations[i], one.translations, atol=1e-13)


# ------------------------------------------------------------------------------------------------
# Transitions
# ------------------------------------------------------------------------------------------------


def _check_transition(out: Motion, a: Motion, b: Motion, fa: int, fb: int, w: int):
    out, a, b = _host(out), _host(a), _host(b)
    assert out.num_frames == fa + b.num_frames - fb
    assert_close("frames before the switch are A's", out.rotations[:fa], a.rotations[:fa])
    assert_close("frames before the switch are A's (translations)", out.translations[:fa], a.translations[:fa])
    q_ref, p_ref = _ref_align(b, fb, a, fa) if fa < a.num_frames else (None, None)
    tail = slice(fa + w, None)
    assert_close("after the window: B's own joint rotations", out.rotations[tail, 1:], b.rotations[fb + w:, 1:])
    if q_ref is not None:
        _same_rotation("after the window: aligned B's root", out.rotations[tail, 0], q_ref[fb + w:], _ATOL)
        assert_close("after the window: aligned B's root position", out.translations[tail, 0], p_ref[fb + w:], atol=_ATOL)
    p = np.asarray(out.translations[:, 0])
    own_step = max(_steps(a.translations[:, 0]).max(), _steps(b.translations[:, 0]).max())
    own_accel = max(_accels(a.translations[:, 0]).max(), _accels(b.translations[:, 0]).max())
    k = slice(max(fa - 2, 0), fa + w + 2)  # the switch and the blend
    assert _steps(p[k]).max() <= _CONT * own_step, ("root position jump", _steps(p[k]).max(), own_step)
    assert _accels(p[k]).max() <= _CONT * own_accel, ("root velocity jump", _accels(p[k]).max(), own_accel)


def test_transition(walk, mirrored):
    _, a = walk
    b = _turn(mirrored, 1.2, [2.0, 0.0, 5.0])
    out = transition(a, b, _FA, _FB, _W)
    _check_transition(out, a, b, _FA, _FB, _W)
    out, a, b = _host(out), _host(a), _host(b)
    # the blend: A's continuation at the switch, weights strictly between
    _same_rotation("switch frame is A's", out.rotations[_FA], a.rotations[_FA], _ATOL)
    assert_close("switch frame is A's (root)", out.translations[_FA], a.translations[_FA], atol=_ATOL)
    assert float(_angles(out.rotations[_FA + _W - 1, 6], b.rotations[_FB + _W - 1, 6])) > 0


def test_concatenate_blends_past_the_end(walk, mirrored):
    _, a = walk
    b = _turn(mirrored, -0.7, [1.0, 0.0, 1.0])
    out = _host(concatenate(a, b, window=8))
    a, b = _host(a), _host(b)
    F = a.num_frames
    assert out.num_frames == F + b.num_frames
    assert_close("A's frames", out.translations[:F], a.translations)
    # A's continuation past its end: its last frame, the root carried on by its last ground step
    step = np.asarray(a.translations[F - 1, 0] - a.translations[F - 2, 0]) * np.array([1.0, 0.0, 1.0])
    assert_close("switch frame: A extrapolated", out.translations[F, 0], np.asarray(a.translations[F - 1, 0]) + step,
                 atol=_ATOL)
    _same_rotation("switch frame: A's last rotations", out.rotations[F], a.rotations[F - 1], _ATOL)
    assert_close("after the window: B's joints", out.rotations[F + 8:, 1:], b.rotations[8:, 1:])
    p = np.asarray(out.translations[:, 0])
    own = max(_steps(a.translations[:, 0]).max(), _steps(b.translations[:, 0]).max())
    assert _steps(p[F - 3:F + 10]).max() <= _CONT * own


# ------------------------------------------------------------------------------------------------
# Loops (and concatenate, which plays the loop again)
# ------------------------------------------------------------------------------------------------


def _clip97(m: Motion) -> Motion:
    """The walk's first 97 frames (cut on the host)."""
    return Motion(jnp.asarray(np.asarray(m.rotations)[:97]), jnp.asarray(np.asarray(m.translations)[:97]), m.frame_time)


def test_make_loop_wraps_smoothly(walk):
    _, m = walk
    clip = _clip97(m)  # stops mid-stride: a bad loop
    loop = make_loop(clip)
    twice = _host(concatenate(loop, loop))
    loop, clip = _host(loop), _host(clip)
    F = clip.num_frames
    assert twice.num_frames == 2 * F
    assert_close("first half is the loop", twice.rotations[:F], loop.rotations)
    assert_close("frame 0 unchanged", loop.rotations[0], clip.rotations[0], atol=1e-15)
    assert_close("headings and ground positions kept", loop.translations[:, 0, ::2], clip.translations[:, 0, ::2])
    assert_close("second half: the loop's own joints", twice.rotations[F:, 1:], loop.rotations[:, 1:])
    # the wrap (frame F - 1 -> F) against the loop's own per-frame changes, every joint and the root
    q = np.asarray(twice.rotations)
    own = _angles(q[1:F], q[:F - 1])  # [F - 1, J]
    wrap = _angles(q[F], q[F - 1])
    assert (wrap <= _CONT * own.max(axis=0) + 1e-12).all(), ("rotation jump at the wrap", wrap, own.max(axis=0))
    p = np.asarray(twice.translations[:, 0])
    assert _steps(p[F - 2:F + 2]).max() <= _CONT * _steps(p[:F]).max()
    assert _accels(p[F - 3:F + 2]).max() <= _CONT * _accels(p[:F]).max()
    # without make_loop the same wrap jumps (the test means something)
    q0 = np.asarray(concatenate(_clip97(m), _clip97(m)).rotations)
    own0 = _angles(q0[1:F], q0[:F - 1])
    assert (_angles(q0[F], q0[F - 1]) > _CONT * own0.max(axis=0)).any()


# ------------------------------------------------------------------------------------------------
# Inertialization
# ------------------------------------------------------------------------------------------------


def test_decay_spring_solves_the_critical_spring():
    x0, v0, hl = np.array([0.3, -1.0, 2.0]), np.array([4.0, 0.5, -3.0]), 0.2
    y = 2 * np.log(2) / hl  # Holden: damping 4 ln2 / halflife, y = damping / 2
    t = np.linspace(0.0, 1.0, 2001)
    spring = jax.jit(decay_spring)  # two programs (two shapes) instead of ~16 eager ones
    x, v = spring(x0[None], v0[None], hl, t[:, None])
    x, v = np.asarray(x), np.asarray(v)
    h = t[1] - t[0]
    assert_close("x(0)", x[0], x0, atol=1e-15)
    assert_close("v(0)", v[0], v0, atol=1e-15)
    assert_close("v = dx/dt (central differences)", v[1:-1], (x[2:] - x[:-2]) / (2 * h), atol=2e-3)
    acc = (x[2:] - 2 * x[1:-1] + x[:-2]) / h**2
    assert_close("x'' + 2y x' + y^2 x = 0", acc + 2 * y * v[1:-1] + y * y * x[1:-1], np.zeros_like(acc), atol=0.05)
    # stepping (Holden's per-frame use) equals one long step, and it decays
    xs, vs = x0, v0
    for _ in range(10):
        xs, vs = spring(xs, vs, hl, 0.1)
    assert_close("10 steps of 0.1 s", xs, x[-1], atol=1e-12)
    assert np.abs(x[-1]).max() < 0.05 * np.abs(x0).max()


def test_inertialize_is_c1(walk, mirrored):
    _, src = walk
    tgt = align(mirrored, 40, src, 40)
    s, hl = 40, 0.1
    out = _host(inertialize(src, tgt, s, hl))
    src, tgt = _host(src), _host(tgt)
    assert out.num_frames == tgt.num_frames
    assert_close("before the switch: source", out.rotations[:s], src.rotations[:s])
    p, ps = np.asarray(out.translations[:, 0]), np.asarray(src.translations[:, 0])
    v_src = ps[s - 1] - ps[s - 2]
    assert_close("position continues the source's step", p[s] - p[s - 1], v_src, atol=_ATOL)
    own_accel = max(_accels(ps).max(), _accels(tgt.translations[:, 0]).max())
    assert np.linalg.norm((p[s + 1] - p[s]) - (p[s] - p[s - 1])) <= _CONT * own_accel, "velocity jump at the switch"
    q, qs = np.asarray(out.rotations), np.asarray(src.rotations)
    w_src = (_R(qs[s - 1]) * _R(qs[s - 2]).inv())
    np.testing.assert_allclose(_angles(q[s], _wxyz(w_src * _R(qs[s - 1]))), 0, atol=1e-9)
    # angular velocity continuous: the step after the switch is close to the step before it
    before = (_R(q[s]) * _R(q[s - 1]).inv()).as_rotvec()
    after = (_R(q[s + 1]) * _R(q[s]).inv()).as_rotvec()
    own = max(np.linalg.norm(np.diff((_R(x[1:]) * _R(x[:-1]).inv()).as_rotvec().reshape(-1, 21, 3), axis=0), axis=-1).max()
              for x in (np.asarray(src.rotations), np.asarray(tgt.rotations)))
    assert np.linalg.norm(after - before, axis=-1).max() <= _CONT * own, "angular velocity jump at the switch"
    # after ten halflives the offset is gone
    k = s + int(np.ceil(10 * hl / float(src.frame_time)))
    np.testing.assert_allclose(_angles(q[k:], tgt.rotations[k:]), 0, atol=2e-3)
    assert_close("root after 10 halflives", p[k:], tgt.translations[k:, 0], atol=1e-3)


def test_inertialize_vmap_over_halflife_equals_loop(walk, mirrored):
    _, src = walk
    tgt = align(mirrored, 40, src, 40)
    halflives = jnp.asarray([0.05, 0.1, 0.3])
    batched = _host(jax.jit(jax.vmap(lambda h: inertialize(src, tgt, 40, h)))(halflives))
    for i, h in enumerate(halflives.tolist()):
        one = inertialize(src, tgt, 40, h)  # the halflife is traced: the same program as in the C1 test
        assert_close(f"rotations[{i}]", batched.rotations[i], one.rotations, atol=1e-13)
        assert_close(f"translations[{i}]", batched.translations[i], one.translations, atol=1e-13)


# ------------------------------------------------------------------------------------------------
# Mirroring
# ------------------------------------------------------------------------------------------------


def test_mirror_pairs_by_name():
    names = ("Hips", "LeftArm", "RightArm", "lShoulder", "rShoulder", "Hand_L", "Hand_R", "LHipJoint", "RHipJoint",
             "mixamorig:LeftEye", "mixamorig:RightEye", "LowerBack", "Leg", "arm.l", "arm.r", "SPINE_LEFT", "SPINE_RIGHT",
             "lhand", "rhand")
    skel = Skeleton(names, (-1,) + (0,) * (len(names) - 1), np.zeros((len(names), 3)))
    pairs = mirror_pairs(skel)
    got = {names[i]: names[p] for i, p in enumerate(pairs)}
    assert got == {"Hips": "Hips", "LeftArm": "RightArm", "RightArm": "LeftArm", "lShoulder": "rShoulder",
                   "rShoulder": "lShoulder", "Hand_L": "Hand_R", "Hand_R": "Hand_L", "LHipJoint": "RHipJoint",
                   "RHipJoint": "LHipJoint", "mixamorig:LeftEye": "mixamorig:RightEye",
                   "mixamorig:RightEye": "mixamorig:LeftEye", "LowerBack": "LowerBack", "Leg": "Leg",
                   "arm.l": "arm.r", "arm.r": "arm.l", "SPINE_LEFT": "SPINE_RIGHT", "SPINE_RIGHT": "SPINE_LEFT",
                   "lhand": "rhand", "rhand": "lhand"}
    lonely = Skeleton(("Hips", "LeftArm", "Arm"), (-1, 0, 0), np.zeros((3, 3)))
    with pytest.raises(JaxanimError, match=r"'LeftArm' \(no 'RightArm'\)"):
        mirror_pairs(lonely)
    assert mirror_pairs(lonely, {"LeftArm": "Arm"}) == (0, 2, 1)
    with pytest.raises(JaxanimError, match="overrides: unknown joint 'Nope'"):
        mirror_pairs(lonely, {"LeftArm": "Nope"})


def test_mirror_reflects_fk(walk, mirrored):
    skel, m = walk
    pairs = mirror_pairs(skel)
    assert skel.names[pairs[skel.index("LeftForeArm")]] == "RightForeArm"
    twice = mirror(mirrored, skel)
    assert_close("mirror twice: rotations", twice.rotations, m.rotations)
    assert_close("mirror twice: translations", twice.translations, m.translations)
    fk = batched_fk()  # the tests' shared jit(vmap(forward_kinematics)): other files may have compiled it
    a, b = fk(skel, m.rotations, m.translations), fk(skel, mirrored.rotations, mirrored.translations)
    M = np.diag([-1.0, 1.0, 1.0])
    perm = np.asarray(pairs)
    assert_close("mirrored positions", b.positions, np.asarray(a.positions)[:, perm] @ M, atol=_ATOL)
    assert_close("mirrored rotations", b.rotations, M @ np.asarray(a.rotations)[:, perm] @ M, atol=_ATOL)
    # the quaternion rule against the matrix one, any rotation, any axis
    q = np.asarray(m.rotations)[5]
    t5 = jnp.asarray(np.asarray(m.translations)[5:6])
    for ax in range(3):
        Mx = np.eye(3)
        Mx[ax, ax] = -1.0
        rule = np.asarray(mirror(Motion(jnp.asarray(q[None]), t5, m.frame_time), skel, axis="xyz"[ax],
                                 pairs=tuple(range(21)), check=False).rotations)[0]
        assert_close(f"M R M, axis {ax}", _R(rule).as_matrix(), Mx @ _R(q).as_matrix() @ Mx, atol=_ATOL)


def test_transition_loop_and_mirror_vmap_equal_loops(walk, mirrored):
    """The processing functions under ``jax.vmap`` over a batch of clips (frames and windows stay
    static Python ints): the same as one call per clip. One jitted program for all three. The clips
    are the loop test's 97 frames: its compiled make_loop serves the single calls (a make_loop of 120
    frames compiled for ~1 s, a transition and a mirror of 97-frame clips take ~0.6 s)."""
    skel, m = walk
    clips = [_turn(_clip97(m), y, [y, 0.0, 2.0 * y]) for y in (0.4, -1.3)]
    stacked = jax.tree.map(lambda *x: jnp.asarray(np.stack([np.asarray(a) for a in x])), *clips)

    @jax.jit
    @jax.vmap
    def batched(b):
        return transition(mirrored, b, _FA, _FB, _W), make_loop(b), mirror(b, skel)

    out = [_host(o) for o in batched(stacked)]
    for i, c in enumerate(clips):
        for name, got, one in zip(("transition", "make_loop", "mirror"), out,
                                  (transition(mirrored, c, _FA, _FB, _W), make_loop(c), mirror(c, skel))):
            assert_close(f"{name}[{i}] rotations", got.rotations[i], one.rotations, atol=1e-13)
            assert_close(f"{name}[{i}] translations", got.translations[i], one.translations, atol=1e-13)


def test_mirror_needs_a_symmetric_skeleton(shared_data):
    skel, m = read_bvh(shared_data / "bvh" / "cmu_01_01_trim300.bvh")
    with pytest.raises(JaxanimError, match="do not mirror their partners'.*'LeftLeg'.*check=False"):
        mirror(m, skel)
    out = mirror(Motion(m.rotations[:2], m.translations[:2], m.frame_time), skel, check=False)
    assert out.num_frames == 2


# ------------------------------------------------------------------------------------------------
# Bad input
# ------------------------------------------------------------------------------------------------


def test_bad_input(walk):
    skel, m = walk
    with pytest.raises(JaxanimError, match=r"fps: expected a positive finite number of frames per second, got 0"):
        resample(m, fps=0)
    h = _host(m)  # the bad inputs cut on the host (eager slicing compiles a program per shape)
    short = Motion(jnp.asarray(h.rotations[:10, :5]), jnp.asarray(h.translations[:10, :5]), m.frame_time)
    slow = Motion(m.rotations, m.translations, 2 * h.frame_time)
    cases = [
        (lambda: transition(m, m, 121, 0, 0), r"frame_a: frame 121 is out of range"),
        (lambda: transition(m, m, 10, 120, 0), r"frame_b: frame 120 is out of range: b has 120 frames"),
        (lambda: transition(m, m, 10, 0, -1), r"window: expected a number of frames >= 0, got -1"),
        (lambda: transition(m, m, 115, 0, 6), r"window: 6 frames is longer than what remains of a from frame_a 115"),
        (lambda: transition(m, m, 10, 117, 4), r"window: 4 frames is longer than what remains of b from frame_b 117"),
        (lambda: transition(m, short, 10, 0, 0), r"b: expected 21 joints \(a's skeleton\), got 5"),
        (lambda: transition(m, slow, 10, 0, 0), r"b.frame_time: expected 0.0333333333 s"),
        (lambda: transition(m, m, 10.0, 0, 0), r"frame_a: expected a Python int"),
        (lambda: concatenate(m, short), r"b: expected 21 joints"),
        (lambda: concatenate(m, m, window=121), r"window: 121 frames is longer than b \(120 frames\)"),
        (lambda: align(m, 120, m, 0), r"frame_b: frame 120 is out of range: motion_b has 120 frames"),
        (lambda: align(m, 0, m, -1), r"frame_a: frame -1 is out of range"),
        (lambda: align(m, 0, m.rotations, 0), r"motion_a: expected a jaxanim Motion"),
        (lambda: facing_frame(h.rotations[0, 0], h.translations[0, 0], up=(0, 0, 0)), r"up: expected a nonzero"),
        (lambda: facing_frame(h.rotations[0, :2], h.translations[0, :3]), r"position: expected batch shape \(2,\)"),
        (lambda: facing_frame(h.rotations[0, 0, :3], h.translations[0, 0]), r"rotation: expected shape \(\.\.\., 4\)"),
        (lambda: make_loop(Motion(jnp.asarray(h.rotations[:1]), jnp.asarray(h.translations[:1]), m.frame_time)),
         r"motion: expected at least 2"),
        (lambda: inertialize(m, m, 0, 0.1), r"switch: frame 0 is out of range"),
        (lambda: inertialize(m, m, 120, 0.1), r"switch: frame 120 is out of range"),
        (lambda: inertialize(m, m, 10, -0.1), r"halflife: expected a positive number"),
        (lambda: inertialize(m, short, 5, 0.1), r"target: expected 21 joints"),
        (lambda: mirror(short, skel), r"motion: expected 21 joints"),
        (lambda: mirror(m, skel, axis="w"), r"axis: expected 'x', 'y' or 'z'"),
        (lambda: mirror(m, skel, pairs=(0, 1)), r"pairs: expected 21 joint indices"),
    ]
    for fn, match in cases:
        with pytest.raises(JaxanimError, match=match):
            fn()


# ------------------------------------------------------------------------------------------------
# The command line
# ------------------------------------------------------------------------------------------------


def _run(capsys, *argv):
    code = _cli.main(["--no-compile-cache", *(str(x) for x in argv)])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_cli_blend_and_loop(tmp_path, capsys, walk, mirrored, shared_data):
    skel, _ = walk
    a_path = default_clip_path()
    b_path = tmp_path / "mirrored.bvh"
    write_bvh(b_path, skel, _turn(mirrored, 1.2, [2.0, 0.0, 5.0]))
    out = tmp_path / "blend.bvh"
    code, stdout, err = _run(capsys, "blend", a_path, b_path, "--at", _FA, _FB, "--window", _W, "--out", out)
    assert code == 0, err
    assert "150 frames" in stdout and "blending" in err
    a, b, o = (_host(read_bvh(p)[1]) for p in (a_path, b_path, out))
    assert o.num_frames == _FA + b.num_frames - _FB
    _same_rotation("OUT before the switch: A's", o.rotations[:_FA], a.rotations[:_FA], 1e-10)
    assert_close("OUT before the switch: A's root", o.translations[:_FA], a.translations[:_FA], atol=_ATOL_BVH)
    _same_rotation("OUT after the window: B's joints", o.rotations[_FA + _W:, 1:], b.rotations[_FB + _W:, 1:], 1e-10)
    q_ref, p_ref = _ref_align(b, _FB, a, _FA)
    _same_rotation("OUT after the window: aligned B's root", o.rotations[_FA + _W:, 0], q_ref[_FB + _W:], 1e-10)
    assert_close("OUT after the window: aligned B's root position", o.translations[_FA + _W:, 0], p_ref[_FB + _W:],
                 atol=_ATOL_BVH)
    own = max(_steps(a.translations[:, 0]).max(), _steps(b.translations[:, 0]).max())
    assert _steps(o.translations[:, 0]).max() <= _CONT * own, "the root jumps"

    part = tmp_path / "part.bvh"  # the loop test's 97 frames: its compiled make_loop serves
    write_bvh(part, skel, Motion(jnp.asarray(a.rotations[:97]), jnp.asarray(a.translations[:97]), a.frame_time))
    _, part_clip = read_bvh(part)
    loop_out = tmp_path / "part.loop.bvh"
    code, stdout, err = _run(capsys, "loop", part, "--out", loop_out)
    assert code == 0, err
    assert "97 frames" in stdout
    _, lo = read_bvh(loop_out)
    want = make_loop(part_clip)
    _same_rotation("loop OUT", lo.rotations, want.rotations, 1e-10)
    assert_close("loop OUT root", lo.translations, want.translations, atol=_ATOL_BVH)

    # bad input: exit 2 and a message naming the file / frame
    cmu = shared_data / "bvh" / "cmu_01_01_trim300.bvh"
    slow = tmp_path / "slow.bvh"
    write_bvh(slow, skel, Motion(jnp.asarray(a.rotations), jnp.asarray(a.translations), 2 * a.frame_time))
    bad = [
        (("blend", a_path, cmu, "--at", 10, 0), rf"{a_path} and {cmu} have different skeletons"),
        (("blend", a_path, slow, "--at", 10, 0), rf"{a_path} and {slow} have different frame times"),
        (("blend", a_path, b_path, "--at", 121, 0), rf"--at: frame 121 of {a_path} is out of range"),
        (("blend", a_path, b_path, "--at", 10, 120), rf"--at: frame 120 of {b_path} is out of range"),
        (("blend", a_path, b_path, "--at", 115, 0, "--window", 6), rf"--window 6 is longer than what remains of {a_path}"),
        (("blend", a_path, b_path, "--at", 10, 0, "--window", -1), r"--window: expected a number of frames >= 0"),
        (("loop", tmp_path / "missing.bvh"), r"missing.bvh"),
    ]
    for argv, match in bad:
        code, _, err = _run(capsys, *argv, "--out", tmp_path / "x.bvh")
        assert code == 2, (argv, err)
        last = err.strip().splitlines()[-1]
        assert last.startswith("error: ") and re.search(match, last), (match, err)
