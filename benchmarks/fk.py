"""Forward-kinematics and Jacobian benchmarks (``fk``, ``jacobian``); float64 runs first, its reference rows reused.
The poses are built on the device in one jitted call (:class:`Problem`)."""

from __future__ import annotations

import functools
import pathlib
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.spatial.transform import Rotation as JaxRotation
from jaxanim import forward_kinematics, jacobian, read_bvh

from .peers import PeerUnavailable
from .peers import numpy_fk as numpy_peer, pinocchio_peer
from .report import Row, Table, Target, sel
from .timing import Runner

__all__ = ["CLIP", "Problem", "autodiff_jacobian", "euler_quats", "naive_fk", "perturbed_sites", "run_fk",
           "run_jacobian"]

CLIP = "bvh/cmu_01_01_trim300.bvh"
REFERENCE = "fk/cmu_01_01_trim300.fk.npz"
FK_BATCHES = (1, 64, 1024, 4096, 16384)
FK_ACCELERATOR_BATCHES = (1024, 131072, 1_048_576)  # --gpu on a machine with an accelerator
_HOST_MAX_BATCH = 131072  # under --gpu the NumPy peer (on the host; its µs per pose is flat) stops here
JACOBIAN_BATCHES = (1, 64, 1024, 4096)
JACOBIAN_ACCELERATOR_BATCHES = (1024, 16384, 131072)
JACOBIAN_SITES = ("LeftHand", "RightHand", "LeftToeBase_End", "RightToeBase_End", "Head_End")
SEED = 0
MAX_ANGLE_DEG = 45.0
_ACCURACY_SAMPLES = 64  # configurations on which Python-loop peers are checked (untimed)


def _cast(tree, dtype):
    """A copy of ``tree`` whose floating arrays are ``dtype`` (structure untouched)."""
    floating = lambda x: isinstance(x, (jax.Array, np.ndarray)) and jnp.issubdtype(x.dtype, jnp.floating)  # noqa: E731
    return jax.tree.map(lambda x: jnp.asarray(x, dtype=dtype) if floating(x) else x, tree)


def _times_axis(q: tuple, axis: str, c, s) -> tuple:
    """The components of ``q (c + s e_axis)`` (``q`` as ``(w, x, y, z)``; ``c, s``: cosine and sine of half the
    angle): ``c q + s (q e_axis)``, where ``q e_axis`` is a signed permutation of ``q``."""
    w, x, y, z = q
    e = {"X": (-x, w, z, -y), "Y": (-y, -z, w, x), "Z": (-z, y, -x, w)}[axis]
    return tuple(c * a + s * b for a, b in zip(q, e))


def euler_quats(angles, axes: str, q=None):
    """``q R_a0(angles[..., 0]) R_a1(angles[..., 1]) R_a2(angles[..., 2])`` as wxyz quaternions ``[..., 4]``:
    intrinsic rotations about ``axes`` (e.g. ``"XYZ"``; scipy's ``Rotation.from_euler`` with upper-case axes: the
    same products of elementary quaternions) after ``q`` (default the identity), component by component (no
    gathers: elementwise, fused by XLA). NumPy in, NumPy out (float64); a JAX array in, JAX out (traceable)."""
    xp = jnp if isinstance(angles, jax.Array) else np
    parts = None if q is None else tuple(q[..., i] for i in range(4))
    for k, axis in enumerate(axes):
        half = 0.5 * angles[..., k]
        c, s = xp.cos(half), xp.sin(half)
        if parts is None:
            parts = (c,) + tuple(s if i == "XYZ".index(axis) else xp.zeros_like(s) for i in range(3))
        else:
            parts = _times_axis(parts, axis, c, s)
    return xp.stack(parts, axis=-1)


@jax.jit
def _poses(clip_q: jax.Array, frames: jax.Array, angles_deg: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(quats [B, J, 4], matrices [B, J, 3, 3])``: the clip's (normalised) frames ``frames`` times
    ``Rx Ry Rz(angles_deg)`` joint by joint."""
    clip_q = clip_q / jnp.linalg.norm(clip_q, axis=-1, keepdims=True)
    q = euler_quats(jnp.deg2rad(angles_deg), "XYZ", clip_q[frames])
    w, x, y, z = (q[..., i] for i in range(4))
    m = jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                   2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                   2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1)
    return q, m.reshape(q.shape[:-1] + (3, 3))


class Problem:
    """The CMU skeleton (float64) and ``max_batch`` poses: ``quats [B, J, 4]`` wxyz, ``mats [B, J, 3, 3]``,
    ``trans [B, J, 3]`` (float64; NumPy copies of the device arrays, made when first asked for), and the clip as
    read (``motion``). Pose ``b`` is the clip's frame ``b mod frames`` with every local rotation times ``Rx(a) Ry(b)
    Rz(c)`` of seeded angles, so the first poses of a larger problem are the same. The angles are drawn by NumPy
    (the same on every machine) and the poses built on the default device in one jitted elementwise call
    (:func:`euler_quats`), not on the host: 10^6 poses are 31 M quaternions and matrices."""

    def __init__(self, path: pathlib.Path, max_batch: int, seed: int = SEED):
        skeleton, self.motion = read_bvh(str(path))
        self.skeleton = _cast(skeleton, jnp.float64)
        clip_q = np.asarray(self.motion.rotations, dtype=np.float64)
        frames = np.arange(max_batch) % clip_q.shape[0]
        rng = np.random.default_rng(seed)
        ang = rng.uniform(-MAX_ANGLE_DEG, MAX_ANGLE_DEG, size=(max_batch, clip_q.shape[1], 3))
        self.device_quats, self.device_mats = _poses(clip_q, frames, ang)
        self.device_trans = jnp.asarray(self.motion.translations, dtype=jnp.float64)[frames]

    quats = functools.cached_property(lambda self: np.asarray(self.device_quats))
    mats = functools.cached_property(lambda self: np.asarray(self.device_mats))
    trans = functools.cached_property(lambda self: np.asarray(self.device_trans))

    def jax_inputs(self, dtype: Any, batch: int, matrices: bool = False) -> tuple[jax.Array, jax.Array]:
        """``(rotations, translations)`` of the first ``batch`` poses: quaternions, or matrices."""
        rot = self.device_mats if matrices else self.device_quats
        return rot[:batch].astype(dtype), self.device_trans[:batch].astype(dtype)


def naive_fk(skeleton, rotations: jax.Array, translations: jax.Array) -> numpy_peer.FKArrays:
    """Textbook FK for one pose: a Python loop over joints (``skeleton.parents``, static), one 3x3 matmul each;
    ``rotations [joints, 3, 3]`` local, ``translations [joints, 3]``."""
    R_world: list[jax.Array] = []
    p_world: list[jax.Array] = []
    for j, p in enumerate(skeleton.parents):
        R_world.append(rotations[j] if p < 0 else R_world[p] @ rotations[j])
        p_world.append(translations[j] if p < 0 else p_world[p] + R_world[p] @ translations[j])
    off = skeleton.end_site_offsets.astype(rotations.dtype)
    ends = [p_world[p] + R_world[p] @ off[e] for e, p in enumerate(skeleton.end_site_parents)]
    ends_arr = jnp.stack(ends) if ends else jnp.zeros((0, 3), rotations.dtype)
    return numpy_peer.FKArrays(jnp.stack(R_world), jnp.stack(p_world), ends_arr)


def _so3_exp(v: jax.Array) -> jax.Array:
    """Rodrigues' formula ``[..., 3] -> [..., 3, 3]``, with a Taylor branch (exact gradient at 0)."""
    th2 = jnp.sum(v * v, axis=-1)
    small = th2 < jnp.finfo(v.dtype).eps ** 0.5
    th2_safe = jnp.where(small, jnp.ones_like(th2), th2)
    th = jnp.sqrt(th2_safe)
    a = jnp.where(small, 1 - th2 / 6, jnp.sin(th) / th)
    b = jnp.where(small, 0.5 - th2 / 24, (1 - jnp.cos(th)) / th2_safe)
    zero = jnp.zeros_like(v[..., 0])
    K = jnp.stack([zero, -v[..., 2], v[..., 1], v[..., 2], zero, -v[..., 0], -v[..., 1], v[..., 0], zero],
                  axis=-1).reshape(v.shape[:-1] + (3, 3))
    return jnp.broadcast_to(jnp.eye(3, dtype=v.dtype), K.shape) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def perturbed_sites(skeleton, rotations: jax.Array, translations: jax.Array, sites: tuple[str, ...],
                    delta: jax.Array, fk: Callable | None = None) -> tuple[jax.Array, jax.Array]:
    """World site positions ``[sites, 3]`` and rotations ``[sites, 3, 3]`` (an End Site has its joint's) of one pose
    perturbed by ``delta = [dt (3), d_0 (3), ..., d_{J-1} (3)]``: root translation ``t_0 + dt``, local rotations
    ``exp(d_j) R_j``; ``fk(skeleton, R_local, t_local)`` defaults to jaxanim's ``forward_kinematics``."""
    J = skeleton.num_joints
    R_local = _so3_exp(delta[3:].reshape(J, 3)) @ JaxRotation.from_quat(rotations[:, [1, 2, 3, 0]]).as_matrix()
    res = (fk or forward_kinematics)(skeleton, R_local, translations.at[0].add(delta[:3]))
    idx = [skeleton.site_index(s) for s in sites]
    joint = [i if i < J else skeleton.end_site_parents[i - J] for i in idx]
    p_all = jnp.concatenate([res.positions, res.end_site_positions], axis=0)
    # static row picks (slices), not gathers: a gather's transpose is a scatter, slow on CPU
    return jnp.stack([p_all[i] for i in idx]), jnp.stack([res.rotations[j] for j in joint])


def autodiff_jacobian(skeleton, rotations: jax.Array, translations: jax.Array, sites: tuple[str, ...],
                      jac: Callable = jax.jacfwd, fk: Callable | None = None) -> jax.Array:
    """Geometric Jacobian ``[sites, 6, 3 + 3 joints]`` (rows ``[linear; angular]``) by ``jac`` of
    :func:`perturbed_sites`; angular rows are the derivative of ``vee(skew(R(d) R(0)^T))`` at 0."""
    zero = jnp.zeros((3 + 3 * skeleton.num_joints,), dtype=rotations.dtype)
    f = functools.partial(perturbed_sites, skeleton, rotations, translations, sites, fk=fk)
    R0 = jax.lax.stop_gradient(f(zero)[1])

    def coordinates(d):
        p, R = f(d)
        W = jnp.einsum("sab,scb->sac", R, R0)
        w = 0.5 * jnp.stack([W[:, 2, 1] - W[:, 1, 2], W[:, 0, 2] - W[:, 2, 0], W[:, 1, 0] - W[:, 0, 1]], axis=1)
        return jnp.concatenate([p, w], axis=1)

    return jac(coordinates)(zero)


def _max_err(pairs: Sequence[tuple[Any, np.ndarray]]) -> float:
    return max(float(np.max(np.abs(np.asarray(a, dtype=np.float64) - b), initial=0.0)) for a, b in pairs)


class _Reference:  # float64 reference outputs per batch: recorded by the reference row, else computed once
    def __init__(self, compute: Callable[[], tuple]):
        self._by_batch = {}
        self._full = functools.cache(lambda: tuple(np.asarray(a, dtype=np.float64) for a in compute()))

    def record(self, batch: int, *arrays: Any) -> str:
        self._by_batch[batch] = tuple(np.asarray(a, dtype=np.float64) for a in arrays)
        return "reference"

    def get(self, batch: int) -> tuple[np.ndarray, ...]:
        return self._by_batch.get(batch) or tuple(a[:batch] for a in self._full())


def _row(run: Runner, impl: str, fn: Callable, args: tuple, dtype: str, b: int, accuracy: Callable, note: str,
         n: int | None = None) -> Row:
    """A row of ``jax.jit(fn)`` (fresh per row: no trace cache hides compile work), or with ``n`` of a Python
    call on ``n`` of the ``b`` configurations; ``accuracy(output)`` fills its accuracy cell."""
    if n is None:
        out, tm, comp = run.jax(jax.jit(fn), *args)
    else:
        (out, tm), comp = run.python(fn, *args), None
        note += f"; timed on {n} of {b} configurations" if n < b else ""
    return run.row(impl, dtype, b, tm, n, compile_s=comp, accuracy=accuracy(out), note=note)


def pinocchio(run: Runner, skeleton, impl: str):
    """The Pinocchio model of ``skeleton``, or ``None`` (``impl`` not selected, or a skipped row added)."""
    if not run.config.selects(impl):
        return None
    try:
        return pinocchio_peer.build_model(skeleton)
    except PeerUnavailable as exc:
        run.table.rows.append(Row(impl, skipped=str(exc), is_peer=True))
        return None


def _pin_inputs(run: Runner, problem: Problem, b: int) -> tuple[int, list, int]:
    """``(n, configurations, k)``: the ``n`` timed configurations of batch ``b``, the first ``k`` checked."""
    n = min(b, run.config.loop_cap)
    return n, list(pinocchio_peer.configurations(problem.quats[:n], problem.trans[:n, 0])), min(n, _ACCURACY_SAMPLES)


def _problem(config, table: Table, batch: int) -> Problem | None:
    """The benchmark problem with ``batch`` poses, or ``None`` with ``table`` skipped (the BVH file is missing)."""
    path = config.data_file(CLIP)
    if isinstance(path, str):
        table.skipped = path
        return None
    return Problem(path, batch)

_FK_REF = "jaxanim (quaternions)"
_PIN_FK = "Pinocchio forwardKinematics"


def run_fk(config) -> list[Table]:
    """The ``fk`` benchmark (see the module docstring)."""
    batches = config.batches_for(FK_BATCHES, FK_ACCELERATOR_BATCHES)
    description = (
        f"Global rotations, joint and End Site positions of a batch of poses of the 31-joint CMU skeleton (`{CLIP}`, "
        f"7 End Sites): clip frame `b mod 300`, every local rotation right-multiplied by a random rotation of up to "
        f"±{MAX_ANGLE_DEG:g}° about each axis (seed {SEED}), clip translations. µs / char = time per call / batch (per "
        "configuration for capped Python loops). Accuracy: max abs error of joint + End Site positions (file units, "
        "|p| ≤ ~30) against jaxanim float64 with quaternion input (\"reference\").")
    pin64 = sel(_PIN_FK, "float64", 4096)
    targets = [Target("FK ≥ 1.8x the Pinocchio loop per configuration at batch 4096 in float64",
                      sel(_FK_REF, "float64", 4096), 1.8, versus=pin64),
               Target("FK ≥ 2.5x the Pinocchio loop (float64) per configuration at batch 4096 in float32",
                      sel(_FK_REF, "float32", 4096), 2.5, versus=pin64),
               Target("FK compile ≤ 2 s (jaxanim rows)", sel("jaxanim"), 2.0, "compile", worst=True)]
    table = Table("fk", "Forward kinematics (31-joint CMU skeleton)", description, "max abs err vs jaxanim f64",
                  targets=targets)
    if (problem := _problem(config, table, max(batches))) is None:
        return [table]
    run, dtypes = Runner(config, table), sorted(config.dtypes, key=lambda d: d != "float64")
    skel64 = problem.skeleton
    ref = _Reference(lambda: _outputs(jax.jit(jax.vmap(functools.partial(forward_kinematics, skel64)))(
        *problem.jax_inputs(jnp.float64, max(batches)))))
    table.notes.extend(_fk_validation_notes(config, problem))
    pin = pinocchio(run, skel64, _PIN_FK)
    for dtype in dtypes:
        skel = _cast(skel64, dtype)
        naive = jax.vmap(functools.partial(naive_fk, skel))
        for b in batches:
            q_in, m_in = problem.jax_inputs(dtype, b), problem.jax_inputs(dtype, b, matrices=True)
            e = lambda out, b=b: _max_err(zip(_outputs(out), ref.get(b)))  # noqa: E731
            ours = lambda: jax.vmap(functools.partial(forward_kinematics, skel))  # noqa: E731
            np_args = lambda b=b, dtype=dtype: (  # noqa: E731 -- built when the row runs (host copies)
                skel64.parents, skel64.end_site_parents, np.asarray(skel64.end_site_offsets, dtype),
                problem.mats[:b].astype(dtype), problem.trans[:b].astype(dtype))
            for impl, fn, args, acc, n, note in (
                    (_FK_REF, ours(), q_in, (lambda out, b=b: ref.record(b, *_outputs(out)))
                     if dtype == "float64" else e, None, "jit(vmap(forward_kinematics)), wxyz [B,31,4]"),
                    ("jaxanim (matrices)", ours(), m_in, e, None, "jit(vmap(forward_kinematics)), [B,31,3,3]"),
                    ("naive JAX", naive, m_in, e, None,
                     "jit(vmap(naive_fk)): Python loop, one matmul per joint, [B,31,3,3]"),
                    ("numpy", numpy_peer.forward_kinematics, np_args, e, b,
                     "vectorized over the batch, loop over joints, [B,31,3,3]"),
                    (_FLOOR, _memory_floor, q_in, lambda _: "—", None,
                     "jit of reading the inputs and writing fresh outputs of FK's shapes: no FK can beat it")):
                run.add(impl, dtype, b, lambda: _row(run, impl, fn, args() if callable(args) else args, dtype, b, acc,
                                                     note, n), peer=not impl.startswith("jaxanim") and impl != _FLOOR,
                        max_batch=_HOST_MAX_BATCH if config.accelerator and impl == "numpy" else None)
            if pin is not None and dtype == dtypes[0]:
                n, qs, k = _pin_inputs(run, problem, b)
                acc = lambda _, b=b: _max_err(zip(pinocchio_peer.positions(pin, qs[:k]),  # noqa: E731
                                                  (a[:k] for a in ref.get(b))))
                run.add(_PIN_FK, "float64", b, lambda: _row(
                    run, _PIN_FK, pinocchio_peer.fk_loop, (pin, qs), "float64", b, acc,
                    "Python loop over configurations; joints only (oMi), no End Sites", n), peer=True)
    return [table]


_FLOOR = "memory floor"


def _memory_floor(quats: jax.Array, trans: jax.Array) -> tuple[jax.Array, ...]:
    """Outputs of FK's shapes and dtype (``[B,31,3,3]``, ``[B,31,3]``, ``[B,7,3]``) from one elementwise pass over
    the inputs: the time of the memory traffic alone (fresh output buffers, as every jitted call returns)."""
    R = jnp.broadcast_to(quats[..., 1:, None], quats.shape[:-1] + (3, 3)) * quats[..., :1, None]
    return R, trans * 1.0, trans[:, :7] * 1.0


def _outputs(out) -> tuple:  # what FK's accuracy is judged on
    return out.positions, out.end_site_positions


def _fk_validation_notes(config, problem: Problem) -> list[str]:
    """jaxanim float64 and the Pinocchio model against the shared FK reference on the clip's frames."""
    path = config.data_file(REFERENCE)
    if isinstance(path, str):
        return [f"shared FK reference `{REFERENCE}` not found: the reference check was not run."]
    ref = np.load(path)
    want = (ref["positions"], ref["end_site_positions"])
    rot, tr = (jnp.asarray(a, dtype=jnp.float64) for a in (problem.motion.rotations, problem.motion.translations))
    out = jax.jit(jax.vmap(functools.partial(forward_kinematics, problem.skeleton)))(rot, tr)
    notes = [f"jaxanim float64 vs the shared reference `{REFERENCE}` ({rot.shape[0]} clip frames): max abs "
             f"position error {_max_err(zip(_outputs(out), want)):.2e}."]
    try:
        ps = pinocchio_peer.build_model(problem.skeleton)
    except PeerUnavailable:
        return notes
    pos = pinocchio_peer.positions(ps, list(pinocchio_peer.configurations(np.asarray(rot), np.asarray(tr[:, 0]))))
    return notes + [f"Pinocchio model (`data.oMi`, End Site frames) vs the same reference: max abs error "
                    f"{_max_err(zip(pos, want)):.2e}."]

_JAC_REF = "jacfwd of jaxanim FK"
_PIN_JAC = "Pinocchio"


def run_jacobian(config) -> list[Table]:
    """The ``jacobian`` benchmark (see the module docstring)."""
    batches = config.batches_for(JACOBIAN_BATCHES, JACOBIAN_ACCELERATOR_BATCHES)
    sites = JACOBIAN_SITES
    description = (
        f"Geometric Jacobian `[5, 6, 96]` of {', '.join(f'`{s}`' for s in sites)} on the CMU skeleton (poses of `fk`): "
        "rows `[linear; angular]` in world axes, columns the root translation then a rotation-vector increment of "
        "every local rotation in its parent frame (`R_j <- exp(d_j) R_j`). Autodiff rows differentiate FK (jaxanim's "
        "or the naive loop) after that perturbation (angular rows `vee(dR R^T)`). Accuracy: max abs difference from "
        "`jax.jacfwd` of jaxanim's FK in float64 (\"reference\"); Pinocchio's `LOCAL_WORLD_ALIGNED` columns (root "
        "twist in the root frame, joint angular velocities in the joint frames) are converted for the check only.")
    targets = [Target("Jacobian of 5 end effectors ≥ 3x Pinocchio per configuration at batch 1024 in float64",
                      sel("jaxanim", "float64", 1024, exact=True), 3.0, versus=sel(_PIN_JAC, "float64", 1024))]
    impls = [("jaxanim", None, None, False, "jit(vmap(jacobian)), analytic"),
             (_JAC_REF, jax.jacfwd, None, True, "jit(vmap(jacfwd(perturbed jaxanim FK)))"),
             ("jacrev of jaxanim FK", jax.jacrev, None, True, "jit(vmap(jacrev(perturbed jaxanim FK)))"),
             ("jacfwd of naive FK", jax.jacfwd, naive_fk, True, "jit(vmap(jacfwd(perturbed naive_fk)))"),
             ("jacrev of naive FK", jax.jacrev, naive_fk, True, "jit(vmap(jacrev(perturbed naive_fk)))")]
    table = Table("jacobian", "Jacobian of 5 end effectors (31-joint CMU skeleton)", description,
                  "max abs err vs jacfwd f64", targets=targets)
    if (problem := _problem(config, table, max(batches))) is None:
        return [table]
    run, dtypes = Runner(config, table), sorted(config.dtypes, key=lambda d: d != "float64")
    skel64 = problem.skeleton
    ref = _Reference(lambda: (jax.jit(jax.vmap(lambda q, t: autodiff_jacobian(skel64, q, t, sites)))(
        *problem.jax_inputs(jnp.float64, max(batches))),))
    pin = pinocchio(run, skel64, _PIN_JAC)
    for dtype in dtypes:
        skel = _cast(skel64, dtype)
        for b in batches:
            args = problem.jax_inputs(dtype, b)
            for impl, jac, fk, peer, note in impls:
                fn = (jax.vmap(lambda q, t: jacobian(skel, q, t, sites)) if jac is None else
                      jax.vmap(functools.partial(autodiff_jacobian, skel, sites=sites, jac=jac, fk=fk)))
                acc = ((lambda out, b=b: ref.record(b, out)) if impl == _JAC_REF and dtype == "float64" else
                       (lambda out, b=b: _max_err([(out, ref.get(b)[0])])))
                run.add(impl, dtype, b, lambda: _row(run, impl, fn, args, dtype, b, acc, note), peer=peer)
            if pin is not None and dtype == dtypes[0]:
                n, qs, k = _pin_inputs(run, problem, b)
                fids = [pin.frame_ids[s] for s in sites]
                acc = lambda _, b=b: _max_err([(pinocchio_peer.to_parent_frame_columns(  # noqa: E731
                    pinocchio_peer.frame_jacobians(pin, qs[:k], fids), problem.mats[:k]), ref.get(b)[0][:k])])
                run.add(_PIN_JAC, "float64", b, lambda: _row(
                    run, _PIN_JAC, pinocchio_peer.jacobian_loop, (pin, qs, fids), "float64", b, acc, "Python "
                    "loop: computeJointJacobians + 5 × getFrameJacobian; columns converted for the check", n),
                    peer=True)
    return [table]
