"""Splines and keyframes (:mod:`jaxanim.splines`) against independent references.

Positional curves against ``scipy.interpolate`` (``CubicHermiteSpline``, ``CubicSpline`` with
natural ends) and a numpy Bernstein sum; arc length against ``scipy.integrate.quad`` of the speed
of the scipy spline; the slerp chain against ``scipy.spatial.transform.Slerp`` (scipy stores
quaternions xyzw, jaxanim wxyz: :func:`_R` converts explicitly). Squad has no scipy peer: its
properties are checked (keys hit, unit norm, C1 at the keys by finite differences, the slerp for two
keys, a constant-rate turn reproduced). Clip interpolation against :func:`jaxanim.resample_at`.

Compiled shapes are few: every curve has 7 keys (non-uniform knots, 3-D points) and is queried at
one ``[200]`` vector holding the knots, points just around the interior knots, points outside the
range and a dense grid; the clip tests share one ``[120]`` query on the shipped walk (120 x 21).
"""

from __future__ import annotations

import equinox as eqx
import jax
import numpy as np
import pytest
from scipy.integrate import quad
from scipy.interpolate import CubicHermiteSpline, CubicSpline
from scipy.spatial.transform import Rotation, Slerp

import jaxanim
from jaxanim import JaxanimError
from jaxanim import splines as sp

from .helpers import assert_close

_ATOL = 1e-12  # float64 curve values vs scipy / numpy (values of order 1)
_ATOL_D2 = 1e-10  # second derivatives (h^-2 amplifies round-off)
_RTOL_ARC = 1e-8  # arc length vs adaptive quadrature (Gauss-Legendre, 16 pieces per segment)
_ATOL_Q = 1e-12  # quaternions at keys and vs scipy's Slerp
_DELTA = 1e-6  # finite-difference step for the C1 checks
_ATOL_C1 = 1e-4  # a C1 curve's one-sided difference quotients agree to O(delta)
_N = 7  # keys per curve
_NQ = 200  # queries per curve


# ------------------------------------------------------------------------------------------------
# Shared data and references
# ------------------------------------------------------------------------------------------------


def _R(q_wxyz) -> Rotation:
    q = np.asarray(q_wxyz, np.float64)
    return Rotation.from_quat(q[..., [1, 2, 3, 0]])


def _wxyz(R: Rotation) -> np.ndarray:
    return R.as_quat()[..., [3, 0, 1, 2]]


def _same_rotation(name: str, q, q_ref, atol=_ATOL_Q) -> None:
    """Quaternions equal up to sign, sample by sample."""
    q, q_ref = np.asarray(q), np.asarray(q_ref)
    sign = np.where(np.sum(q * q_ref, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    assert_close(name, q * sign, q_ref, atol=atol)


class Data:
    """Knots, keys and the query vector shared by the module (see the module docstring)."""

    def __init__(self):
        rng = np.random.default_rng(15)
        self.knots = np.cumsum(rng.uniform(0.3, 1.5, _N)) - 0.5
        self.points = rng.normal(size=(_N, 3))
        self.tangents = rng.normal(size=(_N, 3))
        k = self.knots
        self.interior = k[1:-1]
        outside = np.array([k[0] - 1.0, k[0] - 1e-3, k[-1] + 1e-3, k[-1] + 2.0])
        fixed = np.concatenate([k, self.interior - _DELTA, self.interior + _DELTA, outside])
        grid = np.linspace(k[0], k[-1], _NQ - fixed.size)
        self.t = np.concatenate([fixed, grid])
        self.at_knots = slice(0, _N)
        self.left = slice(_N, 2 * _N - 2)
        self.right = slice(2 * _N - 2, 3 * _N - 4)
        self.outside = slice(3 * _N - 4, 3 * _N)
        self.inside = (self.t >= k[0]) & (self.t <= k[-1])
        rotvecs = rng.normal(size=(_N, 3)) * 0.9
        R = Rotation.from_rotvec(rotvecs[0])
        keys = [R]
        for v in rotvecs[1:]:
            keys.append(keys[-1] * Rotation.from_rotvec(v))
        self.quats = np.stack([_wxyz(r) for r in keys])


@pytest.fixture(scope="module")
def data() -> Data:
    return Data()


@pytest.fixture(scope="module")
def natural(data):
    """The natural spline of the shared keys, its scipy twin and its arc-length table."""
    curve = sp.natural_cubic_spline(data.knots, data.points)
    return curve, CubicSpline(data.knots, data.points, bc_type="natural"), sp.arc_length_table(curve)


@pytest.fixture(scope="module")
def clip():
    _, motion = jaxanim.read_bvh(jaxanim.default_clip_path())
    return motion


@pytest.fixture(scope="module")
def jit_resample_at():
    return eqx.filter_jit(jaxanim.resample_at)


def _fd_tangents(knots, points) -> np.ndarray:
    """Catmull-Rom tangents written out: central differences inside, one-sided at the ends."""
    m = np.empty_like(points)
    m[1:-1] = (points[2:] - points[:-2]) / (knots[2:] - knots[:-2])[:, None]
    m[0] = (points[1] - points[0]) / (knots[1] - knots[0])
    m[-1] = (points[-1] - points[-2]) / (knots[-1] - knots[-2])
    return m


def _bernstein_np(cp: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``sum_k C(p, k) s^k (1 - s)^(p - k) P_k`` with numpy (s inside [0, 1])."""
    from math import comb

    p = cp.shape[0] - 1
    basis = np.stack([comb(p, k) * s**k * (1 - s) ** (p - k) for k in range(p + 1)], axis=-1)
    return basis @ cp


# ------------------------------------------------------------------------------------------------
# Positional curves
# ------------------------------------------------------------------------------------------------


def test_linear_spline_matches_np_interp(data):
    curve = sp.linear_spline(data.knots, data.points)
    t = data.t[data.inside]
    ref = np.stack([np.interp(t, data.knots, data.points[:, c]) for c in range(3)], axis=-1)
    assert_close("linear value", np.asarray(sp.evaluate(curve, data.t))[data.inside], ref, atol=_ATOL)


def test_hermite_matches_scipy(data):
    curve = sp.hermite_spline(data.knots, data.points, data.tangents)
    ref = CubicHermiteSpline(data.knots, data.points, data.tangents)
    t, inside = data.t, data.inside
    assert_close("hermite value", np.asarray(sp.evaluate(curve, t))[inside], ref(t[inside]), atol=_ATOL)
    d1 = np.asarray(sp.evaluate(curve, t, derivative=1))
    assert_close("hermite derivative", d1[inside], ref(t[inside], 1), atol=_ATOL)
    assert_close("hermite keys", sp.evaluate(curve, t)[data.at_knots], data.points, atol=0.0)
    assert_close("hermite key tangents", d1[data.at_knots], data.tangents, atol=_ATOL)


def _first_segment(p0_p1, fill_to=_N) -> np.ndarray:
    """Keys of a worked example on [0, 1], padded to the module's 7 keys (the compiled shapes)."""
    out = np.zeros((fill_to, 3))
    out[: len(p0_p1), : np.shape(p0_p1)[1]] = p0_p1
    return out


def test_hermite_worked_example():
    """Course notes S3:379 (SEEDS 2.2 item 9): positions (1,4,5) -> (3,1,4), velocities (2,3,1),
    (1,1,1) on [0, 1] (the first segment of a 7-key curve)."""
    points = _first_segment([[1.0, 4, 5], [3, 1, 4]])
    tangents = _first_segment([[2.0, 3, 1], [1, 1, 1]])
    curve = sp.hermite_spline(np.arange(_N, dtype=float), points, tangents)
    t = np.full(_NQ, 0.5)
    assert_close("P(0.5)", sp.evaluate(curve, t)[0], [2.125, 2.75, 4.5], atol=_ATOL)
    assert_close("P'(0.5)", sp.evaluate(curve, t, derivative=1)[0], [2.25, -5.5, -2.0], atol=_ATOL)


def test_natural_spline_matches_scipy(natural, data):
    curve, ref, _ = natural
    t, inside = data.t, data.inside
    for k, atol in ((0, _ATOL), (1, _ATOL), (2, _ATOL_D2)):
        got = np.asarray(sp.evaluate(curve, t, derivative=k))[inside]
        assert_close(f"natural derivative {k}", got, ref(t[inside], k), atol=atol)
    ends = np.asarray(sp.evaluate(curve, t, derivative=2))[data.at_knots][[0, -1]]
    assert_close("natural end curvature", ends, np.zeros((2, 3)), atol=_ATOL_D2)


def test_catmull_rom_is_hermite_with_finite_difference_tangents(data):
    curve = sp.catmull_rom_spline(data.knots, data.points)
    ref = CubicHermiteSpline(data.knots, data.points, _fd_tangents(data.knots, data.points))
    t, inside = data.t, data.inside
    value = np.asarray(sp.evaluate(curve, t))
    assert_close("catmull-rom value", value[inside], ref(t[inside]), atol=_ATOL)
    assert_close("catmull-rom derivative", np.asarray(sp.evaluate(curve, t, derivative=1))[inside],
                 ref(t[inside], 1), atol=_ATOL)
    assert_close("catmull-rom keys", value[data.at_knots], data.points, atol=0.0)
    assert_close("catmull_rom_tangents", sp.catmull_rom_tangents(data.knots, data.points),
                 _fd_tangents(data.knots, data.points), atol=_ATOL)


def test_catmull_rom_reproduces_a_line_on_uneven_knots(data):
    """The correct tangent makes a sampled line come back exactly; the notes' extra factor 2 would
    halve every tangent and bend it."""
    a, b = np.array([0.5, -1.0, 2.0]), np.array([1.0, 0.3, -0.7])
    line = a + data.knots[:, None] * b
    curve = sp.catmull_rom_spline(data.knots, line)
    t = data.t[data.inside]
    assert_close("line value", np.asarray(sp.evaluate(curve, data.t))[data.inside], a + t[:, None] * b, atol=_ATOL)
    assert_close("line slope", np.asarray(sp.evaluate(curve, data.t, derivative=1))[data.inside],
                 np.broadcast_to(b, (t.size, 3)), atol=_ATOL)


def test_bezier_spline_matches_bernstein(data):
    rng = np.random.default_rng(3)
    cp = rng.normal(size=(3 * (_N - 1) + 1, 3))
    curve = sp.bezier_spline(data.knots, cp)
    t = data.t[data.inside]
    i = np.clip(np.searchsorted(data.knots, t, side="right") - 1, 0, _N - 2)
    u = (t - data.knots[i]) / np.diff(data.knots)[i]
    ref = np.stack([_bernstein_np(cp[3 * j : 3 * j + 4], uu) for j, uu in zip(i, u, strict=True)])
    assert_close("bezier spline", np.asarray(sp.evaluate(curve, data.t))[data.inside], ref, atol=_ATOL)
    assert_close("bezier spline joins", np.asarray(sp.evaluate(curve, data.t))[data.at_knots], cp[::3], atol=0.0)


def test_bezier_worked_example():
    """Course notes S3:425 (SEEDS 2.2 item 10): control points (30,0), (60,10), (80,30), (90,60) give
    (54.3, 11.7) at t = 0.3 and (67.5, 22.5) at t = 0.5 (the first segment of a 7-knot spline)."""
    cp = _first_segment([[30.0, 0], [60, 10], [80, 30], [90, 60]], fill_to=3 * (_N - 1) + 1)
    curve = sp.bezier_spline(np.arange(_N, dtype=float), cp)
    t = np.full(_NQ, 0.3)
    t[1] = 0.5
    got = np.asarray(sp.evaluate(curve, t))[:2, :2]
    assert_close("bezier worked example", got, [[54.3, 11.7], [67.5, 22.5]], atol=1e-12)


def test_bezier_curve_matches_bernstein():
    rng = np.random.default_rng(4)
    cp = rng.normal(size=(6, 3))  # degree 5
    s = np.linspace(0.0, 1.0, 41)
    assert_close("bezier degree 5", sp.bezier_curve(cp, s), _bernstein_np(cp, s), atol=_ATOL)
    d_ref = 5 * _bernstein_np(np.diff(cp, axis=0), s)
    assert_close("bezier degree 5 derivative", sp.bezier_curve(cp, s, derivative=1), d_ref, atol=_ATOL)


def test_extrapolation_holds_the_ends(natural, data):
    curve = natural[0]
    t_out = data.t[data.outside]
    ends = np.where((t_out < data.knots[0])[:, None], data.points[0], data.points[-1])
    assert_close("held value", np.asarray(sp.evaluate(curve, data.t))[data.outside], ends, atol=_ATOL)
    assert_close("zero derivative", np.asarray(sp.evaluate(curve, data.t, derivative=1))[data.outside],
                 np.zeros((4, 3)), atol=0.0)


# ------------------------------------------------------------------------------------------------
# Arc length
# ------------------------------------------------------------------------------------------------


def _quad_length(ref, a: float, b: float, knots) -> float:
    def speed(x):
        return float(np.linalg.norm(ref(x, 1)))

    inner = [k for k in knots if a < k < b]
    return quad(speed, a, b, points=inner or None, epsabs=1e-13, epsrel=1e-13, limit=200)[0]


def test_arc_length_matches_quadrature(natural, data):
    _, ref, table = natural
    k = data.knots
    total = _quad_length(ref, k[0], k[-1], k)
    assert_close("total length", table.total, total, rtol=_RTOL_ARC)
    t = data.t[-5:]  # grid points, in several segments
    s = np.asarray(sp.arc_length(table, data.t))[-5:]
    assert_close("s(t)", s, [_quad_length(ref, k[0], x, k) for x in t], rtol=_RTOL_ARC)


def test_reparameterized_samples_are_equally_spaced(natural, data):
    _, ref, table = natural
    num = 9
    params = np.asarray(sp.reparameterize_by_arc_length(table, num))
    assert params[0] == data.knots[0] and params[-1] == data.knots[-1]
    assert np.all(np.diff(params) > 0)
    gaps = [_quad_length(ref, params[j], params[j + 1], data.knots) for j in range(num - 1)]
    total = float(table.total)
    assert_close("arc-length gaps", gaps, np.full(num - 1, total / (num - 1)), rtol=_RTOL_ARC)


def test_arc_length_gradient_is_finite_for_a_standing_curve(data):
    """Zero speed everywhere (all keys equal): the speed's norm uses a safe branch."""
    fn = jax.jit(jax.grad(lambda y: sp.arc_length_table(sp.natural_cubic_spline(data.knots, y)).total))
    g = np.asarray(fn(np.zeros((_N, 3))))
    assert np.all(np.isfinite(g))


# ------------------------------------------------------------------------------------------------
# Rotation curves
# ------------------------------------------------------------------------------------------------


def test_slerp_chain_matches_scipy(data):
    q = np.asarray(sp.slerp_spline(data.knots, data.quats, data.t))
    ref = Slerp(data.knots, _R(data.quats))(data.t[data.inside])
    _same_rotation("slerp chain", q[data.inside], _wxyz(ref))
    _same_rotation("slerp keys", q[data.at_knots], data.quats)
    assert_close("unit norm", np.linalg.norm(q, axis=-1), np.ones(_NQ), atol=_ATOL_Q)


def _one_sided(q, data):
    """Forward and backward difference quotients at the interior keys."""
    at = q[data.at_knots][1:-1]
    return (q[data.right] - at) / _DELTA, (at - q[data.left]) / _DELTA


def test_squad_hits_keys_and_is_c1(data):
    q = np.asarray(sp.squad_spline(data.knots, data.quats, data.t))
    _same_rotation("squad keys", q[data.at_knots], data.quats)
    assert_close("unit norm", np.linalg.norm(q, axis=-1), np.ones(_NQ), atol=_ATOL_Q)
    fwd, bwd = _one_sided(q, data)
    assert_close("squad C1 at keys (non-uniform knots)", fwd, bwd, atol=_ATOL_C1)
    # the slerp chain, for contrast, has corners at the keys
    qs = np.asarray(sp.slerp_spline(data.knots, data.quats, data.t))
    fwd, bwd = _one_sided(qs, data)
    assert np.min(np.linalg.norm(fwd - bwd, axis=-1)) > 1e-2


def test_squad_ignores_key_signs(data):
    flips = np.array([1, -1, -1, 1, -1, 1, 1.0])[:, None]
    q = np.asarray(sp.squad_spline(data.knots, data.quats, data.t))
    q_flipped = np.asarray(sp.squad_spline(data.knots, data.quats * flips, data.t))
    assert_close("same curve", q_flipped, q, atol=_ATOL_Q)  # q_0 kept its sign: the same quaternions
    grid = q[3 * _N:]
    assert np.all(np.sum(grid[1:] * grid[:-1], axis=-1) > 0.9), "the output quaternion jumps hemisphere"


def test_squad_reduces_to_slerp(data):
    # two keys: the inner controls are the keys themselves
    k2, q2 = data.knots[[0, -1]], data.quats[[0, 2]]
    ref = Slerp(k2, _R(q2))(data.t[data.inside])
    _same_rotation("two keys", np.asarray(sp.squad_spline(k2, q2, data.t))[data.inside], _wxyz(ref))
    # a constant-rate turn on uniform knots is interpolated at that rate
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    knots = np.arange(_N) * 0.5
    rate = 1.3  # rad/s
    keys = _wxyz(Rotation.from_rotvec(np.outer(knots * rate, axis)))
    tq = np.linspace(knots[0], knots[-1], _NQ)
    got = sp.squad_spline(knots, keys, tq)
    _same_rotation("constant rate", got, _wxyz(Rotation.from_rotvec(np.outer(tq * rate, axis))), atol=1e-12)


def test_align_hemispheres(data):
    flips = np.array([1, -1, -1, 1, -1, 1, 1.0])[:, None]
    q = np.asarray(sp.align_hemispheres(-data.quats * flips))
    assert np.all(np.sum(q[1:] * q[:-1], axis=-1) >= 0)
    _same_rotation("same rotations", q, data.quats, atol=0.0)


# ------------------------------------------------------------------------------------------------
# Keyframe interpolation of a clip
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("position, rotation", [("linear", "slerp"), ("catmull_rom", "squad"), ("natural", "slerp")])
def test_clip_at_its_own_frames_is_the_clip(clip, position, rotation):
    times = np.arange(clip.num_frames) * clip.frame_time
    out = sp.interpolate_motion(clip, times, position=position, rotation=rotation)
    _same_rotation("rotations", out.rotations, clip.rotations)
    assert_close("translations", out.translations, clip.translations, atol=1e-12)
    assert out.frame_time == clip.frame_time


def test_clip_at_half_frames_matches_resample_at(clip, jit_resample_at):
    frames = np.arange(clip.num_frames) + 0.5  # the last one is past the end: both hold the last frame
    out = sp.interpolate_motion(clip, frames * clip.frame_time, position="linear", rotation="slerp")
    ref = jit_resample_at(clip, frames)
    _same_rotation("rotations", out.rotations, ref.rotations)
    assert_close("translations", out.translations, ref.translations, atol=1e-12)


def test_uneven_key_times(clip):
    """Frames as keys at uneven times: each key comes back at its own time (the parametrized test's
    compiled program: the key times are data)."""
    rng = np.random.default_rng(5)
    key_times = np.cumsum(rng.uniform(0.01, 0.06, clip.num_frames))
    out = sp.interpolate_motion(clip, key_times, key_times=key_times, position="catmull_rom", rotation="squad")
    _same_rotation("rotations", out.rotations, clip.rotations)
    assert_close("translations", out.translations, clip.translations, atol=1e-12)


# ------------------------------------------------------------------------------------------------
# vmap and bad input
# ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def batched_natural(data):
    return eqx.filter_jit(jax.vmap(lambda k, y: sp.evaluate(sp.natural_cubic_spline(k, y), data.t)))


def test_vmap_equals_loop(data, batched_natural):
    rng = np.random.default_rng(7)
    knots = np.stack([data.knots, data.knots * 1.5, data.knots + 0.25])
    points = rng.normal(size=(3, _N, 3))
    got = np.asarray(batched_natural(knots, points))
    for b in range(3):
        want = sp.evaluate(sp.natural_cubic_spline(knots[b], points[b]), data.t)
        assert_close(f"natural spline, batch element {b}", got[b], want, atol=_ATOL)


def test_traced_knots_are_checked_at_run_time(data, batched_natural):
    knots = np.stack([data.knots, data.knots[::-1], data.knots])
    with pytest.raises(eqx.EquinoxRuntimeError, match="knots: expected strictly increasing"):
        jax.block_until_ready(batched_natural(knots, np.zeros((3, _N, 3))))


def _bad_inputs(data, clip):
    k, y = data.knots, data.points
    short = jaxanim.Motion(clip.rotations[:1], clip.translations[:1], clip.frame_time)
    curve = sp.PiecewiseCubic(k[:2], np.zeros((1, 4, 3)))
    return [
        (lambda: sp.natural_cubic_spline(k[[0, 2, 1, 3]], y[:4]),
         r"knots: expected strictly increasing knots, got knots\[1\]"),
        (lambda: sp.hermite_spline(k[:1], y[:1], y[:1]),
         r"knots: expected shape \(n,\) with n >= 2 \(at least 2 points\), got \(1,\)"),
        (lambda: sp.catmull_rom_spline(k[None], y), r"knots: expected shape \(n,\) with n >= 2, got \(1, 7\)"),
        (lambda: sp.catmull_rom_spline(k, y[:-1]),
         r"points: expected shape \(n, \.\.\.\) = \(7, \.\.\.\), got \(6, 3\)"),
        (lambda: sp.hermite_spline(k, y, y[:, :2]),
         r"tangents: expected shape \(7, 3\) \(the shape of points\), got \(7, 2\)"),
        (lambda: sp.bezier_spline(k, y),
         r"control_points: expected shape \(3 \(n - 1\) \+ 1, \.\.\.\) = \(19, \.\.\.\), got \(7, 3\)"),
        (lambda: sp.bezier_curve(y[:1], 0.5), r"control_points: expected shape \(p \+ 1, \.\.\.\) with p \+ 1 >= 2"),
        (lambda: sp.evaluate(curve, 0.5, derivative=4), r"derivative: expected an int from 0 to 3, got 4"),
        (lambda: sp.evaluate(y, 0.5), r"curve: expected a jaxanim.splines.PiecewiseCubic, got ndarray"),
        (lambda: sp.arc_length_table(curve, subdivisions=0), r"subdivisions: expected a Python int >= 1"),
        (lambda: sp.reparameterize_by_arc_length(curve, 5), r"table: expected a jaxanim.splines.ArcLengthTable"),
        (lambda: sp.slerp_spline(k, data.quats[:, :3], 0.5), r"quats: expected shape \(n, 4\) = \(7, 4\)"),
        (lambda: sp.squad_spline(k, data.quats[:5], 0.5), r"quats: expected shape \(n, 4\) = \(7, 4\)"),
        (lambda: sp.interpolate_motion(clip, [0.1], position="cubic"),
         r"position: expected one of 'linear', 'catmull_rom', 'natural', got 'cubic'"),
        (lambda: sp.interpolate_motion(clip, [0.1], rotation="nlerp"), r"rotation: expected one of 'slerp', 'squad'"),
        (lambda: sp.interpolate_motion(clip, [[0.1]]), r"times: expected shape \(m,\), got \(1, 1\)"),
        (lambda: sp.interpolate_motion(clip, [0.1], key_times=k), r"key_times: expected shape \(frames,\) = \(120,\)"),
        (lambda: sp.interpolate_motion(short, [0.1]), r"motion: expected at least 2 frames to interpolate, got 1"),
    ]


def test_bad_input_names_the_argument(data, clip):
    for call, message in _bad_inputs(data, clip):
        with pytest.raises(JaxanimError, match=message):
            call()
