"""Forward-kinematics and Jacobian benchmarks on the 31-joint CMU skeleton.

Problem: ``bvh/cmu_01_01_trim300.bvh`` from the shared data (31 joints, 7 End Sites, free root + 30
ball joints). Poses: character ``b`` of a batch takes clip frame ``b mod 300``, right-multiplies
every local rotation by a random rotation ``Rx(a) Ry(b) Rz(c)`` with ``a, b, c`` uniform in ±45°
(fixed seed), and keeps the clip's local translations (root translation, OFFSETs). A batch of size
``B`` is the first ``B`` characters of the largest batch, so every batch size sees the same poses.

``fk`` (:func:`run_fk`): global rotations, joint positions and End Site positions of every character.

* jaxanim ``jit(vmap(forward_kinematics))`` with wxyz quaternion input and with matrix input;
* naive JAX: ``jit(vmap(naive_fk))``, one Python iteration (one matmul) per joint, matrix input;
* numpy: :mod:`benchmarks.peers.numpy_fk`, vectorised over the batch, a loop over joints;
* Pinocchio ``forwardKinematics`` in a Python loop (float64 only; capped, time per configuration).

Accuracy: max abs error of joint and End Site positions (file units) against jaxanim float64 with
quaternion input; the table notes also check jaxanim float64 and the Pinocchio model against the
shared reference ``fk/cmu_01_01_trim300.fk.npz`` on the clip's own frames.

``jacobian`` (:func:`run_jacobian`): the ``[5, 6, 96]`` geometric Jacobian (rows ``[linear;
angular]`` in world axes) of the hands, toe End Sites and head End Site, with respect to the root
translation and a rotation-vector increment of every local rotation in its parent frame
(``R_j <- exp(d_j) R_j``).

* jaxanim ``jit(vmap(jacobian))``;
* ``jax.jacfwd`` and ``jax.jacrev`` of :func:`perturbed_sites` (FK after the perturbation), once
  through jaxanim's FK and once through :func:`naive_fk`;
* Pinocchio ``computeJointJacobians`` + ``getFrameJacobian(LOCAL_WORLD_ALIGNED)`` per site, in a
  Python loop (float64 only; capped). Its columns are converted to jaxanim's parametrisation
  (:func:`benchmarks.peers.pinocchio_peer.to_parent_frame_columns`) for the accuracy check only.

Accuracy: max abs difference from ``jax.jacfwd`` of jaxanim's FK in float64.

float64 runs first: its reference row (jaxanim quaternions / jacfwd of jaxanim FK) is reused as the
reference of every other row, so the reference costs no extra compilation.
"""

from __future__ import annotations

import functools
import pathlib
import time
import traceback
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import BenchConfig
from .peers import PeerUnavailable
from .peers import numpy_fk as numpy_peer
from .report import Row, Table
from .timing import compile_time, time_call

__all__ = [
    "CLIP",
    "FK_BATCHES",
    "JACOBIAN_BATCHES",
    "JACOBIAN_SITES",
    "NaiveFK",
    "Problem",
    "autodiff_jacobian",
    "load_problem",
    "naive_fk",
    "perturbed_sites",
    "run_fk",
    "run_jacobian",
]

CLIP = "bvh/cmu_01_01_trim300.bvh"
REFERENCE = "fk/cmu_01_01_trim300.fk.npz"
FK_BATCHES = (1, 64, 1024, 4096, 16384)
JACOBIAN_BATCHES = (1, 64, 1024, 4096)
JACOBIAN_SITES = ("LeftHand", "RightHand", "LeftToeBase_End", "RightToeBase_End", "Head_End")
SEED = 0
MAX_ANGLE_DEG = 45.0
_ACCURACY_SAMPLES = 64  # configurations on which Python-loop peers are checked (untimed)


def _api() -> tuple[Callable, Callable]:
    """``(forward_kinematics, jacobian)`` from jaxanim's public namespace (imported lazily)."""
    from jaxanim import forward_kinematics, jacobian

    return forward_kinematics, jacobian


# --- problem ----------------------------------------------------------------------------------------
def _quat_mul_np(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def _axis_quat_np(angle: np.ndarray, axis: int) -> np.ndarray:
    q = np.zeros(angle.shape + (4,))
    q[..., 0] = np.cos(angle / 2)
    q[..., 1 + axis] = np.sin(angle / 2)
    return q


def _cast(skeleton, dtype):
    """A copy of ``skeleton`` whose floating arrays are ``dtype`` (structure untouched)."""

    def f(x):
        if isinstance(x, (jax.Array, np.ndarray)) and jnp.issubdtype(x.dtype, jnp.floating):
            return jnp.asarray(x, dtype=dtype)
        return x

    return jax.tree.map(f, skeleton)


class Problem:
    """The CMU skeleton and a fixed set of random poses, as float64 numpy arrays.

    Attributes:
        path: the BVH file.
        skeleton: the :class:`jaxanim.Skeleton` (float64).
        motion: the clip as read.
        quats: ``[B_max, joints, 4]`` local rotations, wxyz, unit.
        mats: ``[B_max, joints, 3, 3]`` the same as matrices.
        trans: ``[B_max, joints, 3]`` local translations (file units).
    """

    def __init__(self, path: pathlib.Path, max_batch: int, seed: int = SEED):
        """Read the clip and draw ``max_batch`` poses (see the module docstring)."""
        from jaxanim import read_bvh

        self.path = path
        skeleton, motion = read_bvh(str(path))
        self.skeleton = _cast(skeleton, jnp.float64)
        self.motion = motion
        clip_q = np.asarray(motion.rotations, dtype=np.float64)
        clip_t = np.asarray(motion.translations, dtype=np.float64)
        frames = np.arange(max_batch) % clip_q.shape[0]
        rng = np.random.default_rng(seed)
        ang = np.deg2rad(rng.uniform(-MAX_ANGLE_DEG, MAX_ANGLE_DEG, size=(max_batch, clip_q.shape[1], 3)))
        noise = _quat_mul_np(
            _quat_mul_np(_axis_quat_np(ang[..., 0], 0), _axis_quat_np(ang[..., 1], 1)), _axis_quat_np(ang[..., 2], 2)
        )
        q = _quat_mul_np(clip_q[frames], noise)
        self.quats = q / np.linalg.norm(q, axis=-1, keepdims=True)
        self.mats = numpy_peer.quat_to_matrix(self.quats)
        self.trans = np.ascontiguousarray(clip_t[frames])

    def skeleton_as(self, dtype: Any):
        """The skeleton with its arrays in ``dtype``."""
        return _cast(self.skeleton, dtype)

    def jax_inputs(self, dtype: Any, batch: int, matrices: bool = False) -> tuple[jax.Array, jax.Array]:
        """``(rotations, translations)`` of the first ``batch`` poses as jax arrays of ``dtype``.

        Rotations are ``[batch, joints, 4]`` wxyz quaternions, or ``[batch, joints, 3, 3]`` matrices
        with ``matrices=True``.
        """
        rot = self.mats if matrices else self.quats
        return jnp.asarray(rot[:batch], dtype=dtype), jnp.asarray(self.trans[:batch], dtype=dtype)


def load_problem(config: BenchConfig, max_batch: int) -> Problem | str:
    """The benchmark problem, or the reason it cannot be built (the BVH file is missing)."""
    path = pathlib.Path(config.data_dir) / CLIP
    if not path.is_file():
        return f"{path} not found (the shared data sits beside the clone; set JAXANIM_SHARED_DATA or --data-dir)"
    return Problem(path, max_batch)


# --- baselines written here -------------------------------------------------------------------------
class NaiveFK(NamedTuple):
    """Output of :func:`naive_fk` (the fields of :class:`jaxanim.fk.FKResult`)."""

    rotations: jax.Array
    positions: jax.Array
    end_site_positions: jax.Array


def naive_fk(
    parents: Sequence[int],
    end_site_parents: Sequence[int],
    end_site_offsets: jax.Array,
    rotations: jax.Array,
    translations: jax.Array,
) -> NaiveFK:
    """Textbook FK for one pose: a Python loop over joints, one 3x3 matmul each.

    Args:
        parents: parent per joint, ``-1`` for the root, topologically sorted (static).
        end_site_parents: joint of each End Site (static).
        end_site_offsets: ``[end_sites, 3]``.
        rotations: ``[joints, 3, 3]`` local rotation matrices.
        translations: ``[joints, 3]`` local translations.

    Returns:
        :class:`NaiveFK` with ``rotations [joints, 3, 3]``, ``positions [joints, 3]`` and
        ``end_site_positions [end_sites, 3]``.
    """
    Rs: list[jax.Array] = []
    ps: list[jax.Array] = []
    for j, p in enumerate(parents):
        if p < 0:
            Rs.append(rotations[j])
            ps.append(translations[j])
        else:
            Rs.append(Rs[p] @ rotations[j])
            ps.append(ps[p] + Rs[p] @ translations[j])
    off = end_site_offsets.astype(rotations.dtype)
    ends = [ps[p] + Rs[p] @ off[e] for e, p in enumerate(end_site_parents)]
    ends_arr = jnp.stack(ends) if ends else jnp.zeros((0, 3), rotations.dtype)
    return NaiveFK(jnp.stack(Rs), jnp.stack(ps), ends_arr)


def _naive_fk_skeleton(skeleton, rotations: jax.Array, translations: jax.Array) -> NaiveFK:
    """:func:`naive_fk` with jaxanim's ``forward_kinematics(skeleton, R, t)`` signature."""
    return naive_fk(skeleton.parents, skeleton.end_site_parents, skeleton.end_site_offsets, rotations, translations)


def _quat_to_matrix(q: jax.Array) -> jax.Array:
    """wxyz unit quaternions ``[..., 4]`` to matrices ``[..., 3, 3]`` (independent of jaxanim)."""
    w, x, y, z = (q[..., i] for i in range(4))
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]
    return jnp.stack(rows, axis=-1).reshape(q.shape[:-1] + (3, 3))


def _so3_exp(v: jax.Array) -> jax.Array:
    """Rodrigues' formula ``[..., 3] -> [..., 3, 3]``, with a Taylor branch (exact gradient at 0)."""
    th2 = jnp.sum(v * v, axis=-1)
    small = th2 < jnp.finfo(v.dtype).eps ** 0.5
    th2_safe = jnp.where(small, jnp.ones_like(th2), th2)
    th = jnp.sqrt(th2_safe)
    a = jnp.where(small, 1 - th2 / 6, jnp.sin(th) / th)
    b = jnp.where(small, 0.5 - th2 / 24, (1 - jnp.cos(th)) / th2_safe)
    zero = jnp.zeros_like(v[..., 0])
    K = jnp.stack(
        [zero, -v[..., 2], v[..., 1], v[..., 2], zero, -v[..., 0], -v[..., 1], v[..., 0], zero], axis=-1
    ).reshape(v.shape[:-1] + (3, 3))
    eye = jnp.broadcast_to(jnp.eye(3, dtype=v.dtype), K.shape)
    return eye + a[..., None, None] * K + b[..., None, None] * (K @ K)


def perturbed_sites(
    skeleton,
    rotations: jax.Array,
    translations: jax.Array,
    sites: tuple[str, ...],
    delta: jax.Array,
    fk: Callable | None = None,
) -> tuple[jax.Array, jax.Array]:
    """Site positions and rotations after perturbing one pose by ``delta``.

    ``delta = [dt (3), d_0 (3), ..., d_{J-1} (3)]``: the root translation becomes ``t_0 + dt`` and
    every local rotation ``R_j`` becomes ``exp(d_j) R_j`` (increment in the parent frame), then FK
    runs on the perturbed matrices.

    Args:
        skeleton: the tree.
        rotations: ``[joints, 4]`` wxyz local rotations.
        translations: ``[joints, 3]`` local translations.
        sites: joint or ``<joint>_End`` names (static).
        delta: ``[3 + 3 joints]``.
        fk: ``fk(skeleton, R_local [J,3,3], t_local [J,3])`` returning ``rotations``, ``positions``
            and ``end_site_positions``; default jaxanim's ``forward_kinematics``.

    Returns:
        ``(positions [sites, 3], rotations [sites, 3, 3])`` in world axes; an End Site has its joint's
        rotation.
    """
    fk = fk or _api()[0]
    J = skeleton.num_joints
    R_local = _so3_exp(delta[3:].reshape(J, 3)) @ _quat_to_matrix(rotations)
    t_local = translations.at[0].add(delta[:3])
    res = fk(skeleton, R_local, t_local)
    idx = [skeleton.site_index(s) for s in sites]
    joint = [i if i < J else skeleton.end_site_parents[i - J] for i in idx]
    p_all = jnp.concatenate([res.positions, res.end_site_positions], axis=0)
    # static row picks (slices), not gathers: a gather's transpose is a scatter, slow on CPU
    return jnp.stack([p_all[i] for i in idx]), jnp.stack([res.rotations[j] for j in joint])


def autodiff_jacobian(
    skeleton,
    rotations: jax.Array,
    translations: jax.Array,
    sites: tuple[str, ...],
    jac: Callable = jax.jacfwd,
    fk: Callable | None = None,
) -> jax.Array:
    """Geometric Jacobian of ``sites`` by automatic differentiation of :func:`perturbed_sites`.

    Linear rows are ``d p / d delta``. Angular rows are ``vee(dR/d delta_k R^T)``, the world-frame
    angular velocity each column produces; they are obtained as the derivative at ``delta = 0`` of
    ``vee(skew(R(delta) R(0)^T))`` (``dR R^T`` is skew, so taking the skew part changes nothing at
    first order), which differentiates 3 numbers per site instead of 9 and so halves ``jacrev``'s
    number of backward passes (30 instead of 60).

    Args:
        skeleton, rotations, translations, sites, fk: as for :func:`perturbed_sites`.
        jac: ``jax.jacfwd`` or ``jax.jacrev``.

    Returns:
        ``[sites, 6, 3 + 3 joints]``, rows ``[linear; angular]``.
    """
    zero = jnp.zeros((3 + 3 * skeleton.num_joints,), dtype=rotations.dtype)
    f = functools.partial(perturbed_sites, skeleton, rotations, translations, sites, fk=fk)
    R0 = jax.lax.stop_gradient(f(zero)[1])

    def coordinates(d):
        p, R = f(d)
        W = jnp.einsum("sab,scb->sac", R, R0)  # R(d) R(0)^T
        w = 0.5 * jnp.stack([W[:, 2, 1] - W[:, 1, 2], W[:, 0, 2] - W[:, 2, 0], W[:, 1, 0] - W[:, 0, 1]], axis=1)
        return jnp.concatenate([p, w], axis=1)  # [sites, 6]

    return jac(coordinates)(zero)


# --- row runners -------------------------------------------------------------------------------------
class _Reference:
    """Reference outputs per batch size.

    The reference row (float64, run first) records its own output with :meth:`record`; when it did
    not run (float32 only, filtered out, failed) :meth:`get` computes the reference once at the
    largest batch with ``compute`` and slices it.
    """

    def __init__(self, compute: Callable[[], tuple[np.ndarray, ...]]):
        self._compute = compute
        self._by_batch: dict[int, tuple[np.ndarray, ...]] = {}
        self._full: tuple[np.ndarray, ...] | None = None

    def record(self, batch: int, *arrays: Any) -> None:
        self._by_batch[batch] = tuple(np.asarray(a, dtype=np.float64) for a in arrays)

    def get(self, batch: int) -> tuple[np.ndarray, ...]:
        if batch in self._by_batch:
            return self._by_batch[batch]
        if self._full is None:
            self._full = tuple(np.asarray(a, dtype=np.float64) for a in self._compute())
        return tuple(a[:batch] for a in self._full)


def _max_err(pairs: Sequence[tuple[Any, np.ndarray]]) -> float:
    return max(float(np.max(np.abs(np.asarray(a, dtype=np.float64) - b), initial=0.0)) for a, b in pairs)


def _log_row(config: BenchConfig, bench: str, row: Row) -> None:
    if row.skipped is not None:
        config.log(f"{bench} {row.dtype} B={row.batch}: {row.implementation}: {row.skipped}")
        return
    acc = row.accuracy if isinstance(row.accuracy, str) else f"{row.accuracy:.2e}"
    comp = "" if row.compile_s is None else f", compile {row.compile_s:.2f} s"
    config.log(
        f"{bench} {row.dtype} B={row.batch}: {row.implementation}: {row.us_per_char:.3g} µs/char{comp}, err {acc}"
    )


def _run_row(
    config: BenchConfig, rows: list[Row], bench: str, impl: str, dtype: str, batch: int, make_row: Callable[[], Row]
) -> None:
    """Append ``make_row()`` to ``rows`` unless filtered out by ``config.only``.

    An unexpected exception becomes a ``failed: ...`` row (with the traceback on stderr) so that one
    broken implementation does not abort the whole report.
    """
    if not config.selects(impl):
        return
    try:
        row = make_row()
    except Exception as exc:
        traceback.print_exc()
        msg = str(exc).splitlines()[0][:200] if str(exc) else ""
        row = Row(impl, dtype, batch, skipped=f"failed: {type(exc).__name__}: {msg}")
    _log_row(config, bench, row)
    rows.append(row)


def _jax_row(
    config: BenchConfig,
    impl: str,
    fn: Callable,
    args: tuple,
    dtype: str,
    batch: int,
    accuracy: Callable[[Any], float | str],
    *,
    is_peer: bool,
    note: str = "",
) -> Row:
    """Compile ``jax.jit(fn)`` ahead of time (timed), then time the compiled executable."""
    cs = compile_time(jax.jit(fn), *args)
    t0 = time.perf_counter()
    out = jax.block_until_ready(cs.compiled(*args))  # for the accuracy; also the first warm-up call
    first = time.perf_counter() - t0
    acc = accuracy(out)
    del out
    long_call = first > 1.0  # seconds per call: no more warm-up, no calibration loop
    stats = time_call(
        cs.compiled, *args, repeats=config.repeats, warmup=0 if long_call else max(config.warmup - 1, 0),
        max_total_s=config.max_row_s, number=1 if long_call else None,
    )
    return Row(impl, dtype, batch, stats.median, stats.min, batch, cs.total, acc, is_peer=is_peer, note=note)


def _loop_row(
    config: BenchConfig, impl: str, fn: Callable, args: tuple, batch: int, n: int, accuracy: float | str, note: str
) -> Row:
    """Time a Python-loop peer over ``n <= batch`` configurations (float64, nothing compiled)."""
    stats = time_call(fn, *args, repeats=config.repeats, warmup=config.warmup, max_total_s=config.max_row_s)
    if n < batch:
        note = f"{note}; timed on {n} of {batch} configurations"
    return Row(impl, "float64", batch, stats.median, stats.min, n, None, accuracy, is_peer=True, note=note)


def _dtype_order(dtypes: Sequence[str]) -> list[str]:
    """float64 first, so that its reference rows are recorded before float32 rows need them."""
    return sorted(dtypes, key=lambda d: d != "float64")


def _load_pinocchio(config: BenchConfig, bench: str, skeleton, impl: str):
    """``(pinocchio_peer module, PinocchioSkeleton)``, or ``(None, skipped Row)``."""
    try:
        from .peers import pinocchio_peer

        return pinocchio_peer, pinocchio_peer.build_model(skeleton)
    except PeerUnavailable as exc:
        config.log(f"{bench}: {impl}: skipped: {exc}")
        return None, Row(impl, skipped=str(exc), is_peer=True)


# --- fk ----------------------------------------------------------------------------------------------
_FK_DESCRIPTION = """\
Global rotations, joint positions and End Site positions of a batch of poses of the 31-joint CMU
skeleton (`{clip}`, 7 End Sites), one call per batch. Poses: clip frame `b mod 300` with every
local rotation right-multiplied by a random rotation of up to ±45° about each axis (seed {seed}),
clip translations. µs / char = time per call / batch (per configuration for capped Python loops).
Accuracy: max abs error of joint + End Site positions (file units, |p| ≤ ~30) against jaxanim
float64 with quaternion input ("reference")."""

_FK_REF_IMPL = "jaxanim (quaternions)"
_PIN_FK_IMPL = "Pinocchio forwardKinematics"


def run_fk(config: BenchConfig) -> list[Table]:
    """The ``fk`` benchmark (see the module docstring)."""
    batches = config.batches_for(FK_BATCHES)
    table = Table(
        "fk", "Forward kinematics (31-joint CMU skeleton)",
        _FK_DESCRIPTION.format(clip=CLIP, seed=SEED), "max abs err vs jaxanim f64",
    )
    problem = load_problem(config, max(batches))
    if isinstance(problem, str):
        config.log(f"fk: skipped: {problem}")
        table.skipped = problem
        return [table]
    forward_kinematics, _ = _api()
    skel64 = problem.skeleton
    parents, esp = skel64.parents, skel64.end_site_parents
    eso64 = np.asarray(skel64.end_site_offsets)

    def compute_reference():
        config.log("fk: computing the float64 reference separately ...")
        fn = jax.jit(jax.vmap(functools.partial(forward_kinematics, skel64)))
        out = fn(*problem.jax_inputs(jnp.float64, max(batches)))
        return out.positions, out.end_site_positions

    ref = _Reference(compute_reference)

    def err(out, b: int) -> float:
        pos, end = ref.get(b)
        return _max_err([(out.positions, pos), (out.end_site_positions, end)])

    table.notes += _fk_validation_notes(config, problem, forward_kinematics)
    pin_mod, pin = (None, None)
    if config.selects(_PIN_FK_IMPL):
        pin_mod, pin = _load_pinocchio(config, "fk", skel64, _PIN_FK_IMPL)
    pin_dtype = "float64" if "float64" in config.dtypes else config.dtypes[0]

    for dtype_name in _dtype_order(config.dtypes):
        dtype = jnp.dtype(dtype_name)
        skel = problem.skeleton_as(dtype)
        eso = jnp.asarray(eso64, dtype=dtype)
        for b in batches:
            q_in = problem.jax_inputs(dtype, b)
            m_in = problem.jax_inputs(dtype, b, matrices=True)
            is_ref = dtype_name == "float64"

            def ref_accuracy(out, b=b):
                ref.record(b, out.positions, out.end_site_positions)
                return "reference"

            def jaxanim_row(impl, inputs, note, accuracy):
                # a fresh function per row, so that no trace cache hides compile work
                fn = jax.vmap(lambda r, t: forward_kinematics(skel, r, t))
                return _jax_row(config, impl, fn, inputs, dtype_name, b, accuracy, is_peer=False, note=note)

            _run_row(config, table.rows, "fk", _FK_REF_IMPL, dtype_name, b, lambda: jaxanim_row(
                _FK_REF_IMPL, q_in, "jit(vmap(forward_kinematics)), wxyz [B,31,4]",
                ref_accuracy if is_ref else functools.partial(err, b=b),
            ))
            _run_row(config, table.rows, "fk", "jaxanim (matrices)", dtype_name, b, lambda: jaxanim_row(
                "jaxanim (matrices)", m_in, "jit(vmap(forward_kinematics)), [B,31,3,3]", functools.partial(err, b=b),
            ))
            naive = jax.vmap(functools.partial(naive_fk, parents, esp, eso))
            _run_row(config, table.rows, "fk", "naive JAX", dtype_name, b, lambda: _jax_row(
                config, "naive JAX", naive, m_in, dtype_name, b, functools.partial(err, b=b), is_peer=True,
                note="jit(vmap(naive_fk)): Python loop, one matmul per joint, [B,31,3,3]",
            ))

            def numpy_row():
                args = (
                    parents, esp, eso64.astype(dtype), problem.mats[:b].astype(dtype), problem.trans[:b].astype(dtype)
                )
                stats = time_call(
                    numpy_peer.forward_kinematics, *args, repeats=config.repeats, warmup=config.warmup,
                    max_total_s=config.max_row_s,
                )
                return Row(
                    "numpy", dtype_name, b, stats.median, stats.min, b, None,
                    err(numpy_peer.forward_kinematics(*args), b), is_peer=True,
                    note="vectorised over the batch, loop over joints, [B,31,3,3]",
                )

            _run_row(config, table.rows, "fk", "numpy", dtype_name, b, numpy_row)
            if pin_mod is not None and dtype_name == pin_dtype:
                n = min(b, config.loop_cap)
                qs = list(pin_mod.configurations(problem.quats[:n], problem.trans[:n, 0]))

                def pin_row():
                    k = min(n, _ACCURACY_SAMPLES)
                    pj, pe = pin_mod.positions(pin, qs[:k])
                    pos, end = ref.get(b)
                    return _loop_row(
                        config, _PIN_FK_IMPL, pin_mod.fk_loop, (pin, qs), b, n,
                        _max_err([(pj, pos[:k]), (pe, end[:k])]),
                        note="Python loop over configurations; joints only (oMi), no End Sites",
                    )

                _run_row(config, table.rows, "fk", _PIN_FK_IMPL, "float64", b, pin_row)
    if isinstance(pin, Row):
        table.rows.append(pin)
    table.notes += _target_notes(table, "FK", _FK_REF_IMPL, 4096, _FK_TARGET_US, _FK_COMPILE_TARGET_S)
    if "float64" in config.dtypes:
        table.notes += _fk_profile_notes(config, problem, forward_kinematics, 4096 if 4096 in batches else max(batches))
    return [table]


# Targets of the core issue, float64 on the 2-core CPU (checked by the benchmark, not by tests).
_FK_TARGET_US = 0.5  # per character at batch 4096
_FK_COMPILE_TARGET_S = 2.0
_JAC_TARGET_US = 2.0  # per character at batch 1024


def _target_notes(table: Table, what: str, impl: str, batch: int, target_us: float, compile_target_s=None) -> list[str]:
    """One line comparing the float64 row of ``impl`` at ``batch`` with the target."""
    rows = [r for r in table.rows if r.implementation == impl and r.dtype == "float64" and r.batch == batch]
    if not rows or rows[0].time_median_s is None:
        return []
    r = rows[0]
    us = r.time_median_s / r.chars_per_call * 1e6
    verdict = "met" if us <= target_us else f"missed by {us / target_us:.1f}x"
    line = f"Target: {what} <= {target_us:g} µs per character at batch {batch} in float64: {us:.2f} µs, {verdict}."
    compiles = [x.compile_s for x in table.rows if x.implementation == impl and x.compile_s is not None]
    if compile_target_s is not None and compiles:
        worst = max(compiles)
        line += (f" Compile <= {compile_target_s:g} s: worst {worst:.2f} s, "
                 f"{'met' if worst <= compile_target_s else 'missed'}.")
    return [line]


def _hlo_counts(compiled) -> str:
    """Count the ops XLA:CPU runs: fusions, dots, copies, and all top-level instructions."""
    import re

    text = compiled.as_text()
    entry = text[text.rfind("ENTRY"):]
    body = [ln for ln in entry.splitlines()[1:] if "=" in ln]
    kinds: dict[str, int] = {}
    for ln in body:
        m = re.search(r"=\s*\S+\s+([a-z\-]+)\(", ln)
        if m:
            kinds[m.group(1)] = kinds.get(m.group(1), 0) + 1
    top = ", ".join(f"{k} {v}" for k, v in sorted(kinds.items(), key=lambda kv: -kv[1])[:5])
    return f"{len(body)} top-level ops ({top})"


def _fk_profile_notes(config: BenchConfig, problem: Problem, forward_kinematics: Callable, b: int) -> list[str]:
    """What bounds FK on this machine: the cost of only writing outputs of FK's size, and op counts."""
    from jaxanim.rotations import quat_to_matrix

    skel = problem.skeleton_as(jnp.float64)
    q, t = problem.jax_inputs(jnp.float64, b)
    floor = jax.jit(jax.vmap(lambda r, x: (quat_to_matrix(r), x * 2.0)))
    ours = jax.jit(jax.vmap(lambda r, x: forward_kinematics(skel, r, x)))
    naive = jax.jit(jax.vmap(functools.partial(
        naive_fk, skel.parents, skel.end_site_parents, jnp.asarray(skel.end_site_offsets))))
    m = problem.jax_inputs(jnp.float64, b, matrices=True)
    st = time_call(floor, q, t, repeats=config.repeats, warmup=config.warmup, max_total_s=config.max_row_s)
    return [
        f"Profile at batch {b}, float64: converting the quaternions to matrices and writing outputs of "
        f"FK's size, with no tree traversal at all, takes {st.median / b * 1e6:.2f} µs per character "
        "here: the memory floor of this output layout on this machine.",
        f"Compiled jaxanim FK: {_hlo_counts(ours.lower(q, t).compile())}; naive FK: "
        f"{_hlo_counts(naive.lower(*m).compile())}. XLA:CPU runs each op as a loop over "
        "[B, n, 3, 3] arrays whose minor dimension is 3, which it cannot vectorise; a batch-minor "
        "program (all arrays [.., B], elementwise) measured ~1.0-1.2 µs per character before the "
        "final transpose to [B, J, 3, 3], and ~1 µs more with it.",
    ]


def _fk_validation_notes(config: BenchConfig, problem: Problem, forward_kinematics: Callable) -> list[str]:
    """Check jaxanim float64 and the Pinocchio model against the shared FK reference (clip frames)."""
    path = pathlib.Path(config.data_dir) / REFERENCE
    if not path.is_file():
        return [f"shared FK reference `{REFERENCE}` not found: the reference check was not run."]
    ref = np.load(path)
    rot = jnp.asarray(problem.motion.rotations, dtype=jnp.float64)
    tr = jnp.asarray(problem.motion.translations, dtype=jnp.float64)
    out = jax.jit(jax.vmap(functools.partial(forward_kinematics, problem.skeleton)))(rot, tr)
    e = _max_err([(out.positions, ref["positions"]), (out.end_site_positions, ref["end_site_positions"])])
    notes = [
        f"jaxanim float64 vs the shared reference `{REFERENCE}` ({rot.shape[0]} clip frames): "
        f"max abs position error {e:.2e}."
    ]
    try:
        from .peers import pinocchio_peer

        ps = pinocchio_peer.build_model(problem.skeleton)
    except PeerUnavailable:
        return notes
    qs = list(pinocchio_peer.configurations(np.asarray(rot), np.asarray(tr[:, 0])))
    pj, pe = pinocchio_peer.positions(ps, qs)
    e = _max_err([(pj, ref["positions"]), (pe, ref["end_site_positions"])])
    notes.append(f"Pinocchio model (`data.oMi`, End Site frames) vs the same reference: max abs error {e:.2e}.")
    return notes


# --- jacobian ----------------------------------------------------------------------------------------
_JAC_DESCRIPTION = """\
Geometric Jacobian `[5, 6, 96]` of {sites} on the CMU skeleton: rows `[linear; angular]` in
world axes, columns the root translation then a rotation-vector increment of every local rotation
in its parent frame (`R_j <- exp(d_j) R_j`). Same poses as `fk`. The autodiff rows differentiate
FK after that perturbation (angular rows `vee(dR R^T)`), through jaxanim's `forward_kinematics` or
through the naive loop FK. Accuracy: max abs difference from `jax.jacfwd` of jaxanim's FK in
float64 ("reference"). Pinocchio's columns (root twist in the root frame, joint angular velocities
in the joint frames) are converted to these for the check only; its timed loop is
`computeJointJacobians` + 5 × `getFrameJacobian(LOCAL_WORLD_ALIGNED)`."""

_JAC_REF_IMPL = "jacfwd of jaxanim FK"
_PIN_JAC_IMPL = "Pinocchio"


def run_jacobian(config: BenchConfig) -> list[Table]:
    """The ``jacobian`` benchmark (see the module docstring)."""
    batches = config.batches_for(JACOBIAN_BATCHES)
    sites = JACOBIAN_SITES
    table = Table(
        "jacobian", "Jacobian of 5 end effectors (31-joint CMU skeleton)",
        _JAC_DESCRIPTION.format(sites=", ".join(f"`{s}`" for s in sites)), "max abs err vs jacfwd f64",
    )
    problem = load_problem(config, max(batches))
    if isinstance(problem, str):
        config.log(f"jacobian: skipped: {problem}")
        table.skipped = problem
        return [table]
    _, jacobian = _api()
    skel64 = problem.skeleton

    def compute_reference():
        config.log("jacobian: computing the float64 reference separately ...")
        fn = jax.jit(jax.vmap(lambda q, t: autodiff_jacobian(skel64, q, t, sites, jax.jacfwd)))
        return (fn(*problem.jax_inputs(jnp.float64, max(batches))),)

    ref = _Reference(compute_reference)

    def err(out, b: int) -> float:
        return _max_err([(out, ref.get(b)[0])])

    pin_mod, pin = (None, None)
    if config.selects(_PIN_JAC_IMPL):
        pin_mod, pin = _load_pinocchio(config, "jacobian", skel64, _PIN_JAC_IMPL)
    pin_dtype = "float64" if "float64" in config.dtypes else config.dtypes[0]

    for dtype_name in _dtype_order(config.dtypes):
        dtype = jnp.dtype(dtype_name)
        skel = problem.skeleton_as(dtype)
        for b in batches:
            args = problem.jax_inputs(dtype, b)

            def ref_accuracy(out, b=b):
                ref.record(b, out)
                return "reference"

            impls = [
                ("jaxanim", None, None, False, "jit(vmap(jacobian)), analytic"),
                (_JAC_REF_IMPL, jax.jacfwd, None, True, "jit(vmap(jacfwd(perturbed jaxanim FK)))"),
                ("jacrev of jaxanim FK", jax.jacrev, None, True, "jit(vmap(jacrev(perturbed jaxanim FK)))"),
                ("jacfwd of naive FK", jax.jacfwd, _naive_fk_skeleton, True, "jit(vmap(jacfwd(perturbed naive_fk)))"),
                ("jacrev of naive FK", jax.jacrev, _naive_fk_skeleton, True, "jit(vmap(jacrev(perturbed naive_fk)))"),
            ]
            for impl, jac, fk, peer, note in impls:
                if jac is None:
                    fn = jax.vmap(lambda q, t: jacobian(skel, q, t, sites))
                else:
                    fn = jax.vmap(functools.partial(autodiff_jacobian, skel, sites=sites, jac=jac, fk=fk))
                is_ref = impl == _JAC_REF_IMPL and dtype_name == "float64"
                acc = ref_accuracy if is_ref else functools.partial(err, b=b)
                _run_row(config, table.rows, "jacobian", impl, dtype_name, b, lambda: _jax_row(
                    config, impl, fn, args, dtype_name, b, acc, is_peer=peer, note=note,
                ))
            if pin_mod is not None and dtype_name == pin_dtype:
                n = min(b, config.loop_cap)
                qs = list(pin_mod.configurations(problem.quats[:n], problem.trans[:n, 0]))
                frame_ids = [pin.frame_ids[s] for s in sites]

                def pin_row():
                    k = min(n, _ACCURACY_SAMPLES)
                    jac_pin = pin_mod.frame_jacobians(pin, qs[:k], frame_ids)
                    conv = pin_mod.to_parent_frame_columns(jac_pin, problem.mats[:k])
                    return _loop_row(
                        config, _PIN_JAC_IMPL, pin_mod.jacobian_loop, (pin, qs, frame_ids), b, n,
                        _max_err([(conv, ref.get(b)[0][:k])]),
                        note="Python loop: computeJointJacobians + 5 × getFrameJacobian; "
                        "columns converted for the check",
                    )

                _run_row(config, table.rows, "jacobian", _PIN_JAC_IMPL, "float64", b, pin_row)
    if isinstance(pin, Row):
        table.rows.append(pin)
    table.notes += _target_notes(table, "Jacobian of 5 end effectors", "jaxanim", 1024, _JAC_TARGET_US)
    table.notes.append(
        "The dense float64 output is 5 x 6 x 96 x 8 B = 23 kB per character; at the write rate the FK "
        "profile above measures, writing it alone costs about as much as the FK outputs, so the "
        "analytic Jacobian is bounded below by roughly 2x the FK floor plus one FK."
    )
    return [table]
