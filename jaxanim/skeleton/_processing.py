"""Motion processing: facing frames, alignment, transitions, loops, inertialization (mirroring is
in :mod:`._mirror`).

Conventions (see :mod:`jaxanim.skeleton._skeleton`): joint 0 is the root; ``translations[:, 0]`` is
the root position in the world, ``rotations[:, 0]`` the root orientation ``R_world_root`` (wxyz).
The up axis ``up`` (default ``(0, 1, 0)``, BVH's Y up) is a static 3-tuple; the ground plane is
the plane through the origin normal to it.

**Facing frame** (course notes, S4:739-747). Decompose the root rotation ``R = R_y R_xz``: ``R'``
is the smallest rotation taking the root's local up axis ``R up`` back onto ``up``, ``R_y = R' R``
(a rotation about ``up`` only, since ``R_y up = R' (R up) = up``) and ``R_xz = R_y^T R``. This is
the swing-twist decomposition with the twist about ``up``. The facing frame's origin is the root
position projected on the ground, ``t = p - (p . up) up`` (for ``up = y``: ``(p_x, 0, p_z)``; the
notes' ``(t_x, 0, t_y)`` is a typo).

**Alignment** (eq. 5.5): with ``(R_A, t_A)`` the facing frame of clip A at ``frame_a`` and
``(R_B, t_B)`` that of clip B at ``frame_b``, B's root becomes ``R(i) = R_A R_B^T R_B(i)`` and
``t(i) = R_A R_B^T (t_B(i) - t_B) + t_A``. ``R_A R_B^T`` turns about ``up`` and ``t_A, t_B`` have no
up component, so the up component of ``t(i)`` is B's own root height: the formula moves B on the
ground and keeps its height.

Everything here solves one clip; batch with :func:`jax.vmap`. Frame indices, windows and joint
permutations are Python ints (static: they fix output shapes); halflives and times are arrays.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import rotations as rot
from .._errors import JaxanimError, check_positive, check_shape
from .._linalg import matmul
from .._types import Array, ArrayLike, Float
from ._skeleton import Motion

_FRAME_TIME_RTOL = 1e-6  # frame times of two clips that count as equal


# ------------------------------------------------------------------------------------------------
# Input checks
# ------------------------------------------------------------------------------------------------


def _up_tuple(up) -> tuple[float, float, float]:
    """The unit up axis as a static tuple; ``up`` must be a concrete nonzero 3-vector."""
    try:
        u = np.asarray(up, dtype=np.float64)
    except Exception as exc:  # a tracer, a string
        raise JaxanimError(f"up: expected a concrete 3-vector such as (0, 1, 0), got {up!r}") from exc
    if u.shape != (3,):
        raise JaxanimError(f"up: expected a 3-vector such as (0, 1, 0), got shape {u.shape}")
    n = float(np.linalg.norm(u))
    if not (math.isfinite(n) and n > 0):
        raise JaxanimError(f"up: expected a nonzero finite 3-vector, got {tuple(u.tolist())}")
    return tuple(float(x) for x in u / n)


def _check_motion(name: str, motion) -> None:
    if not isinstance(motion, Motion):
        raise JaxanimError(f"{name}: expected a jaxanim Motion, got {type(motion).__name__}")


def _is_int(x) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, bool)


def _static_int(name: str, x, lo: int, hi: int, what: str) -> int:
    """``x`` as a Python int in ``[lo, hi]``, or a :class:`JaxanimError` naming ``name``."""
    if not _is_int(x):
        raise JaxanimError(f"{name}: expected a Python int (it fixes the output's length), got {x!r}")
    x = int(x)
    if not lo <= x <= hi:
        raise JaxanimError(f"{name}: frame {x} is out of range: {what} (valid: {lo} to {hi})")
    return x


def _frame_index(name: str, x, n: int, label: str):
    """A frame index: a Python int checked against ``[0, n)``, or an integer scalar array (under
    ``vmap``) used as is (clamped by JAX's indexing)."""
    if _is_int(x):
        return _static_int(name, x, 0, n - 1, f"{label} has {n} frames")
    if isinstance(x, jax.core.Tracer) or isinstance(x, (jax.Array, np.ndarray)):
        if jnp.ndim(x) != 0 or not jnp.issubdtype(jnp.asarray(x).dtype, jnp.integer):
            raise JaxanimError(f"{name}: expected an integer frame index, got an array of shape "
                               f"{jnp.shape(x)} and dtype {jnp.asarray(x).dtype}")
        if not isinstance(x, jax.core.Tracer):
            return _static_int(name, int(x), 0, n - 1, f"{label} has {n} frames")
        return x
    raise JaxanimError(f"{name}: expected an integer frame index, got {x!r}")


def _check_frames(name: str, motion: Motion, at_least: int) -> None:
    if motion.num_frames < at_least:
        raise JaxanimError(f"{name}: expected at least {at_least} frame(s), got {motion.num_frames}")


def _check_same_joints(name_a: str, a: Motion, name_b: str, b: Motion) -> None:
    if a.num_joints != b.num_joints:
        raise JaxanimError(
            f"{name_b}: expected {a.num_joints} joints ({name_a}'s skeleton), got {b.num_joints}: "
            "the clips must be on the same skeleton"
        )


def _check_frame_times(name_a: str, a: Motion, name_b: str, b: Motion) -> None:
    if isinstance(a.frame_time, jax.core.Tracer) or isinstance(b.frame_time, jax.core.Tracer):
        return  # under jit / vmap: the caller's business
    fa, fb = float(a.frame_time), float(b.frame_time)
    if not abs(fa - fb) <= _FRAME_TIME_RTOL * max(abs(fa), abs(fb)):
        raise JaxanimError(
            f"{name_b}.frame_time: expected {fa:.9g} s ({name_a}'s), got {fb:.9g} s; resample one clip "
            "first (jaxanim.skeleton.resample)"
        )


def _check_window(window, remaining_a: int, remaining_b: int, frame_a: int, frame_b: int) -> int:
    if not _is_int(window):
        raise JaxanimError(f"window: expected a Python int (a number of frames), got {window!r}")
    window = int(window)
    if window < 0:
        raise JaxanimError(f"window: expected a number of frames >= 0, got {window}")
    if window > remaining_a:
        raise JaxanimError(
            f"window: {window} frames is longer than what remains of a from frame_a {frame_a} "
            f"({remaining_a} frames); shorten the window (or use concatenate, which extends a)"
        )
    if window > remaining_b:
        raise JaxanimError(
            f"window: {window} frames is longer than what remains of b from frame_b {frame_b} "
            f"({remaining_b} frames)"
        )
    return window


# ------------------------------------------------------------------------------------------------
# Facing frames and alignment
# ------------------------------------------------------------------------------------------------


def _facing(q: Array, p: Array, u: Array) -> tuple[Array, Array]:
    a = rot.quat_apply(q, u)
    R_prime = rot.rotation_between(a, jnp.broadcast_to(u, a.shape))
    R_y = rot.quat_canonical(rot.quat_normalize(rot.quat_multiply(R_prime, q)))
    u_b = jnp.broadcast_to(u, p.shape)
    origin = p - jnp.sum(p * u_b, axis=-1, keepdims=True) * u_b
    return R_y, origin


def facing_frame(
    rotation: Float[ArrayLike, "*batch 4"],
    position: Float[ArrayLike, "*batch 3"],
    *,
    up=(0.0, 1.0, 0.0),
) -> tuple[Float[Array, "*batch 4"], Float[Array, "*batch 3"]]:
    """The facing frame of a root pose: its heading about ``up`` and its ground-projected origin.

    ``R_y = R' R`` with ``R'`` the smallest rotation taking ``R up`` back to ``up`` (so ``R_y`` turns
    about ``up`` only); ``origin = p - (p . up) up``. Undefined (an arbitrary heading) when the root
    is upside down (``R up = -up``).

    Args:
        rotation: ``[..., 4]`` root orientations ``R_world_root``, wxyz.
        position: ``[..., 3]`` root positions (world, file units); batch axes as ``rotation``'s.
        up: the world up axis, a concrete 3-vector (normalized here); default Y.

    Returns:
        ``(facing [..., 4], origin [..., 3])``: ``R_y`` as a wxyz quaternion with ``w >= 0``, and the
        root position with its up component removed.

    Raises:
        JaxanimError: on wrong trailing dimensions, mismatched batch shapes or a bad ``up``.
    """
    q = jnp.asarray(rotation)
    p = jnp.asarray(position)
    check_shape("rotation", q, (4,), batch=True)
    check_shape("position", p, (3,), batch=True)
    if q.shape[:-1] != p.shape[:-1]:
        raise JaxanimError(f"position: expected batch shape {q.shape[:-1]} (rotation's), got {p.shape[:-1]}")
    dtype = jnp.result_type(q.dtype, p.dtype, float)
    return _facing_jit(q.astype(dtype), p.astype(dtype), _up_tuple(up))


def split_facing(
    rotation: Float[ArrayLike, "*batch 4"], *, up=(0.0, 1.0, 0.0)
) -> tuple[Float[Array, "*batch 4"], Float[Array, "*batch 4"]]:
    """Decompose ``R = R_y R_xz``: the heading ``R_y`` about ``up`` and the rest ``R_xz = R_y^T R``.

    Args:
        rotation: ``[..., 4]`` root orientations, wxyz.
        up: the world up axis (default Y).

    Returns:
        ``(R_y [..., 4], R_xz [..., 4])``, wxyz; ``quat_multiply(R_y, R_xz) == rotation`` (up to sign).

    Raises:
        JaxanimError: on a wrong trailing dimension or a bad ``up``.
    """
    q = jnp.asarray(rotation)
    check_shape("rotation", q, (4,), batch=True)
    return _split_jit(q.astype(jnp.result_type(q.dtype, float)), _up_tuple(up))


@eqx.filter_jit
def _facing_jit(q: Array, p: Array, up: tuple) -> tuple[Array, Array]:
    return _facing(q, p, jnp.asarray(up, q.dtype))


@eqx.filter_jit
def _split_jit(q: Array, up: tuple) -> tuple[Array, Array]:
    R_y, _ = _facing(q, jnp.zeros(q.shape[:-1] + (3,), q.dtype), jnp.asarray(up, q.dtype))
    return R_y, rot.quat_multiply(rot.quat_conjugate(R_y), q)


def _root_facing(motion: Motion, frame, u: Array) -> tuple[Array, Array]:
    return _facing(motion.rotations[frame, 0], motion.translations[frame, 0], u)


def _align_to(b: Motion, R_B: Array, t_B: Array, R_A: Array, t_A: Array) -> Motion:
    """Eq. 5.5 on B's root: ``R(i) = D R_B(i)``, ``t(i) = D (t_B(i) - t_B) + t_A``, ``D = R_A R_B^T``."""
    D = rot.quat_multiply(R_A, rot.quat_conjugate(R_B))
    q_root = rot.quat_multiply(D[None], b.rotations[:, 0])
    p_root = rot.quat_apply(D[None], b.translations[:, 0] - t_B[None]) + t_A[None]
    return Motion(b.rotations.at[:, 0].set(q_root), b.translations.at[:, 0].set(p_root), b.frame_time)


def align(motion_b: Motion, frame_b, motion_a: Motion, frame_a, *, up=(0.0, 1.0, 0.0)) -> Motion:
    """Move clip B on the ground so that its facing frame at ``frame_b`` is A's at ``frame_a`` (eq. 5.5).

    ``R(i) = R_A R_B^T R_B(i)`` and ``t(i) = R_A R_B^T (t_B(i) - t_B) + t_A`` on B's root, with
    ``(R_A, t_A)``, ``(R_B, t_B)`` the facing frames (:func:`facing_frame`) of A at ``frame_a`` and B
    at ``frame_b``. The up component of B's root position (its height) is unchanged; the other
    joints are B's own.

    Args:
        motion_b: the clip to move (B).
        frame_b: B's frame that lands on A's facing frame: a Python int in ``[0, frames_b)``, or an
            integer scalar array under ``vmap``.
        motion_a: the reference clip (A); it may be on another skeleton (only its root is read).
        frame_a: A's frame, as ``frame_b``.
        up: the world up axis (default Y).

    Returns:
        B with its root rotations and positions moved, in B's dtype and frame time.

    Raises:
        JaxanimError: a frame out of range, an argument that is not a Motion, or a bad ``up``.
    """
    _check_motion("motion_b", motion_b)
    _check_motion("motion_a", motion_a)
    _check_frames("motion_b", motion_b, 1)
    _check_frames("motion_a", motion_a, 1)
    frame_b = _frame_index("frame_b", frame_b, motion_b.num_frames, "motion_b")
    frame_a = _frame_index("frame_a", frame_a, motion_a.num_frames, "motion_a")
    # frames as arrays: one compiled program serves every frame
    return _align_jit(motion_b, jnp.asarray(frame_b), motion_a, jnp.asarray(frame_a), _up_tuple(up))


@eqx.filter_jit
def _align_jit(motion_b: Motion, frame_b, motion_a: Motion, frame_a, up: tuple) -> Motion:
    dtype = motion_b.rotations.dtype
    u = jnp.asarray(up, dtype)
    R_A, t_A = _root_facing(motion_a, frame_a, u)
    R_B, t_B = _root_facing(motion_b, frame_b, u)
    return _align_to(motion_b, R_B, t_B, R_A.astype(dtype), t_A.astype(dtype))


# ------------------------------------------------------------------------------------------------
# Transitions
# ------------------------------------------------------------------------------------------------


def _continuation(a: Motion, frame_a: int, n: int, u: Array) -> Motion:
    """A's frames ``frame_a .. frame_a + n - 1``; past A's end, its last frame held, with the root
    moved on along the ground by A's last step (its up component held)."""
    F = a.num_frames
    idx = np.arange(frame_a, frame_a + n)
    extra = np.maximum(idx - (F - 1), 0).astype(np.float64)
    q = a.rotations[np.minimum(idx, F - 1)]
    t = a.translations[np.minimum(idx, F - 1)]
    if extra.any() and F >= 2:
        step = a.translations[F - 1, 0] - a.translations[F - 2, 0]
        step = step - jnp.sum(step * u) * u
        t = t.at[:, 0].add(jnp.asarray(extra, t.dtype)[:, None] * step[None])
    return Motion(q, t, a.frame_time)


def _smoothstep(s: Array) -> Array:
    return s * s * (3.0 - 2.0 * s)


@eqx.filter_jit
def _transition(a: Motion, b: Motion, frame_a: int, frame_b: int, window: int, up: tuple) -> Motion:
    dtype = a.rotations.dtype
    u = jnp.asarray(up, dtype)
    b = Motion(b.rotations.astype(dtype), b.translations.astype(dtype), b.frame_time.astype(dtype))
    cont = _continuation(a, frame_a, max(window, 1), u)
    R_A, t_A = _root_facing(cont, 0, u)
    R_B, t_B = _root_facing(b, frame_b, u)
    b_al = _align_to(b, R_B, t_B, R_A, t_A)
    q_b, t_b = b_al.rotations[frame_b:], b_al.translations[frame_b:]
    if window > 0:
        w = _smoothstep(jnp.arange(window, dtype=dtype) / window)  # 0 at the switch, -> 1
        q_mix = rot.slerp(cont.rotations[:window], q_b[:window], jnp.broadcast_to(w[:, None], (window, a.num_joints)))
        t_mix = cont.translations[:window] + w[:, None, None] * (t_b[:window] - cont.translations[:window])
        q_b = jnp.concatenate([q_mix, q_b[window:]], axis=0)
        t_b = jnp.concatenate([t_mix, t_b[window:]], axis=0)
    q = jnp.concatenate([a.rotations[:frame_a], q_b], axis=0)
    t = jnp.concatenate([a.translations[:frame_a], t_b], axis=0)
    return Motion(q, t, a.frame_time)


def transition(a: Motion, b: Motion, frame_a: int, frame_b: int, window: int, *, up=(0.0, 1.0, 0.0)) -> Motion:
    """Switch from clip A to clip B: A before ``frame_a``, then B from ``frame_b`` on, aligned to A.

    B is aligned (:func:`align`) so that its facing frame at ``frame_b`` is A's at ``frame_a``. The
    first ``window`` frames after the switch blend A's continuation (its frames ``frame_a ..``) into
    aligned B with the weight ``w_k = smoothstep(k / window)``, ``k = 0 .. window - 1`` (0 at the
    switch, so frame ``frame_a`` is A's own and the root does not jump; ``w`` reaches 1 with zero
    slope): slerp per joint, lerp for the translations (the root position). From frame
    ``frame_a + window`` on the result is aligned B exactly, with B's own joint rotations.

    Args:
        a: the clip to leave (A).
        b: the clip to enter (B), on the same skeleton (joint count) and at the same frame time.
        frame_a: the switch in A, a Python int in ``[0, frames_a]`` (``frames_a``: switch at A's
            end, with ``window == 0``; :func:`concatenate` blends there by extending A).
        frame_b: B's first frame, a Python int in ``[0, frames_b)``.
        window: blend length in frames, ``0 <= window <= min(frames_a - frame_a, frames_b - frame_b)``.
        up: the world up axis (default Y).

    Returns:
        A :class:`Motion` of ``frame_a + frames_b - frame_b`` frames at A's frame time and dtype.

    Raises:
        JaxanimError: a frame out of range, a window longer than what remains of either clip or
            negative, clips with different joint counts or frame times.
    """
    _check_pair(a, b)
    frame_a = _static_int("frame_a", frame_a, 0, a.num_frames,
                          f"a has {a.num_frames} frames and the switch may be at its end")
    frame_b = _static_int("frame_b", frame_b, 0, b.num_frames - 1, f"b has {b.num_frames} frames")
    window = _check_window(window, a.num_frames - frame_a, b.num_frames - frame_b, frame_a, frame_b)
    return _transition(a, b, frame_a, frame_b, window, _up_tuple(up))


def _check_pair(a: Motion, b: Motion) -> None:
    """Two clips to join: Motions of at least one frame, the same joints and frame time."""
    _check_motion("a", a)
    _check_motion("b", b)
    _check_same_joints("a", a, "b", b)
    _check_frame_times("a", a, "b", b)
    _check_frames("a", a, 1)
    _check_frames("b", b, 1)


def concatenate(a: Motion, b: Motion, *, window: int = 0, up=(0.0, 1.0, 0.0)) -> Motion:
    """A then B: :func:`transition` at A's end and B's start (``frames_a + frames_b`` frames).

    B's first frame is aligned to the facing frame one step past A's last frame (A's last frame
    with its root moved on by its last step along the ground). With ``window > 0`` the first
    ``window`` frames of B are blended from that continuation of A: A's last frame held, its root
    carried on with its last ground velocity and its height held.

    Args:
        a, b: the clips, on the same skeleton and at the same frame time.
        window: blend length in frames, ``0 <= window <= frames_b``.
        up: the world up axis (default Y).

    Returns:
        A :class:`Motion` of ``frames_a + frames_b`` frames at A's frame time and dtype.

    Raises:
        JaxanimError: as :func:`transition`.
    """
    _check_pair(a, b)
    if not _is_int(window) or int(window) < 0:
        raise JaxanimError(f"window: expected a number of frames >= 0 (a Python int), got {window!r}")
    if int(window) > b.num_frames:
        raise JaxanimError(f"window: {int(window)} frames is longer than b ({b.num_frames} frames)")
    window = int(window)
    return _transition(a, b, a.num_frames, 0, window, _up_tuple(up))


# ------------------------------------------------------------------------------------------------
# Loops
# ------------------------------------------------------------------------------------------------


def _rel(q1: Array, q0: Array) -> Array:
    """``log(q1 q0^-1)``: the rotation vector taking ``q0`` to ``q1`` (left, parent frame)."""
    return rot.quat_to_rotvec(rot.quat_multiply(q1, rot.quat_conjugate(q0)))


def make_loop(motion: Motion, *, up=(0.0, 1.0, 0.0)) -> Motion:
    """Make a clip loop: its last frame followed by its first is as smooth as its own frames.

    Playing the clip again continues from its end the way :func:`concatenate` does: the first frame
    is aligned to the facing frame one ground step past the last frame. What that alignment cannot
    fix is the mismatch between the last frame and the first in everything but the facing frame:
    the root position relative to the facing frame (its height ``h``), the root's rotation relative
    to the facing frame (``R_xz``, :func:`split_facing`) and every joint's local rotation. For each of
    these ``x`` the residual is the wrap step minus the mean of the clip's first and last steps,
    ``r = (x_0 - x_{F-1}) - ((x_{F-1} - x_{F-2}) + (x_1 - x_0)) / 2`` (rotations: rotation vectors,
    composed on the left), and frame ``i`` gets ``i / (F - 1)`` of it, so frame 0 is unchanged and
    the wrap step becomes the mean of its neighbors. Root headings and ground positions are kept.

    Args:
        motion: the clip, at least 2 frames.
        up: the world up axis (default Y).

    Returns:
        The looping clip: same length, frame time and dtype.

    Raises:
        JaxanimError: fewer than 2 frames, or a bad ``up``.
    """
    _check_motion("motion", motion)
    _check_frames("motion", motion, 2)
    return _make_loop(motion, _up_tuple(up))


@eqx.filter_jit
def _make_loop(motion: Motion, up: tuple) -> Motion:
    q, t = motion.rotations, motion.translations
    F = motion.num_frames
    u = jnp.asarray(up, q.dtype)
    R_y, _ = _facing(q[:, 0], t[:, 0], u)
    R_xz = rot.quat_multiply(rot.quat_conjugate(R_y), q[:, 0])
    local = q.at[:, 0].set(R_xz)  # [F, J, 4]: root relative to its facing frame, joints to parents
    mean_step = 0.5 * (_rel(local[F - 1], local[F - 2]) + _rel(local[1], local[0]))  # [J, 3]
    # the last frame that makes the wrap step the mean step: exp(-mean) local_0
    target = rot.quat_multiply(rot.rotvec_to_quat(-mean_step), local[0])
    r_rot = _rel(target, local[F - 1])  # [J, 3]
    h = matmul(t[:, 0], u)  # [F]
    r_h = (h[0] - h[F - 1]) - 0.5 * ((h[F - 1] - h[F - 2]) + (h[1] - h[0]))
    alpha = jnp.arange(F, dtype=q.dtype) / (F - 1)
    fix = rot.rotvec_to_quat(alpha[:, None, None] * r_rot[None])
    local = rot.quat_multiply(fix, local)
    q_new = local.at[:, 0].set(rot.quat_multiply(R_y, local[:, 0]))
    t_new = t.at[:, 0].add((alpha * r_h)[:, None] * u[None])
    return Motion(q_new, t_new, motion.frame_time)


# ------------------------------------------------------------------------------------------------
# Inertialization
# ------------------------------------------------------------------------------------------------


def decay_spring(
    offset: Float[ArrayLike, "..."],
    velocity: Float[ArrayLike, "..."],
    halflife: Float[ArrayLike, "..."],
    t: Float[ArrayLike, "..."],
) -> tuple[Float[Array, "..."], Float[Array, "..."]]:
    """A critically damped spring decaying an offset to 0 (Holden's ``decay_spring_implicit``).

    With ``y = 2 ln 2 / halflife`` (half of Holden's damping ``4 ln 2 / halflife``) and
    ``j = v_0 + y x_0``: ``x(t) = e^{-y t} (x_0 + j t)``, ``v(t) = e^{-y t} (v_0 - j y t)``, the exact
    solution of ``x'' = -2 y x' - y^2 x`` (so ``x(0) = x_0``, ``x'(0) = v_0``).

    Args:
        offset: ``x_0``, any shape (file units, or radians for rotation vectors).
        velocity: ``v_0`` per second, ``offset``'s shape.
        halflife: seconds, > 0; broadcasts against ``offset``.
        t: seconds since the start; broadcasts against ``offset``.

    Returns:
        ``(offset_t, velocity_t)`` in the broadcast shape.

    Raises:
        JaxanimError: a concrete ``halflife`` that is not a positive finite number (checked when it
            is known: a traced one, under ``jit`` or ``vmap``, passes unchecked).
    """
    check_positive("halflife", halflife, units="seconds")
    x, v, hl, t = (jnp.asarray(z) for z in (offset, velocity, halflife, t))
    dtype = jnp.result_type(x.dtype, v.dtype, hl.dtype, t.dtype, float)
    x, v, hl, t = jnp.broadcast_arrays(*(z.astype(dtype) for z in (x, v, hl, t)))
    y = (2.0 * math.log(2.0)) / hl
    j = v + y * x
    e = jnp.exp(-y * t)
    return e * (x + j * t), e * (v - j * y * t)


def inertialize(source: Motion, target: Motion, switch: int, halflife) -> Motion:
    """Switch from ``source`` to ``target`` at frame ``switch`` without a jump (C1), by inertialization.

    Frames before ``switch`` are the source's; frame ``switch + k`` is the target's plus an offset
    decaying by :func:`decay_spring` over ``k * frame_time`` seconds. The offset starts at the
    source's extrapolation one frame past ``switch - 1`` minus the target at ``switch`` (root
    position; root and joint rotations as rotation vectors composed on the left, ``exp(x) q``), with
    velocity the source's last velocity (backward difference at ``switch - 1``) minus the target's
    at ``switch`` (forward difference; backward on its last frame). So position and velocity are
    continuous at the switch, and the offset is gone after a few halflives. Other joints'
    translations are the target's. Align the target first (:func:`align`) if it is elsewhere.

    Args:
        source: the clip playing before the switch, at least ``switch`` frames.
        target: the clip playing from the switch, time-aligned with ``source`` (its frame ``i``
            plays at frame ``i``), same joints and frame time.
        switch: the first target frame, a Python int in ``[1, frames_target)`` and ``<= frames_source``.
        halflife: seconds (> 0), a scalar (may be traced).

    Returns:
        A :class:`Motion` of ``frames_target`` frames at the target's frame time.

    Raises:
        JaxanimError: ``switch`` out of range, clips with different joints or frame times, a
            non-scalar or non-positive ``halflife``.
    """
    _check_motion("source", source)
    _check_motion("target", target)
    _check_same_joints("source", source, "target", target)
    _check_frame_times("source", source, "target", target)
    _check_frames("target", target, 2)
    Ft, Fs = target.num_frames, source.num_frames
    switch = _static_int("switch", switch, 1, min(Ft - 1, Fs),
                         f"target has {Ft} frames and source {Fs}: switch needs a source frame before it "
                         "and a target frame at it")
    hl = jnp.asarray(halflife)
    if hl.ndim != 0:
        raise JaxanimError(f"halflife: expected a scalar (seconds), got shape {hl.shape}")
    if not isinstance(hl, jax.core.Tracer) and not float(hl) > 0:
        raise JaxanimError(f"halflife: expected a positive number of seconds, got {float(hl)}")
    return _inertialize(source, target, switch, hl.astype(target.rotations.dtype))


@eqx.filter_jit
def _inertialize(source: Motion, target: Motion, s: int, hl: Array) -> Motion:
    dtype = target.rotations.dtype
    dt = target.frame_time.astype(dtype)
    Ft = target.num_frames
    qs, ps = source.rotations.astype(dtype), source.translations[:, 0].astype(dtype)
    qt, pt = target.rotations, target.translations[:, 0]
    # source: last shown frame s - 1 and its last step (zero when it has one frame before the switch)
    if s >= 2:
        w_src, v_src = _rel(qs[s - 1], qs[s - 2]), ps[s - 1] - ps[s - 2]
    else:
        w_src, v_src = jnp.zeros(qs.shape[1:-1] + (3,), dtype), jnp.zeros((3,), dtype)
    k0, k1 = (s, s + 1) if s + 1 < Ft else (s - 1, s)
    w_tgt, v_tgt = _rel(qt[k1], qt[k0]), pt[k1] - pt[k0]
    q_ext = rot.quat_multiply(rot.rotvec_to_quat(w_src), qs[s - 1])
    x_rot, v_rot = _rel(q_ext, qt[s]), (w_src - w_tgt) / dt  # [J, 3]
    x_pos, v_pos = ps[s - 1] + v_src - pt[s], (v_src - v_tgt) / dt  # [3]
    times = jnp.arange(Ft - s, dtype=dtype) * dt  # [K]
    off_rot, _ = decay_spring(x_rot[None], v_rot[None], hl, times[:, None, None])
    off_pos, _ = decay_spring(x_pos[None], v_pos[None], hl, times[:, None])
    q_after = rot.quat_multiply(rot.rotvec_to_quat(off_rot), qt[s:])
    t_after = target.translations[s:].at[:, 0].add(off_pos)
    q = jnp.concatenate([qs[:s], q_after], axis=0)
    t = jnp.concatenate([source.translations[:s].astype(dtype), t_after], axis=0)
    return Motion(q, t, target.frame_time)
