"""Inverse-kinematics benchmark on the 31-joint CMU skeleton (``python -m benchmarks ik``): random reachable
targets (:func:`draw_problems`), success judged from the returned poses only (:func:`evaluate`)."""

from __future__ import annotations

import dataclasses
import functools
import pathlib
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from scipy.spatial.transform import Rotation

import solvers
from jaxanim import read_bvh
from jaxanim.ik import Target as IKTarget, solve_ik, solve_ik_ccd

from .fk import CLIP, _cast, euler_quats, pinocchio
from .peers import pinocchio_peer, require
from .peers import numpy_fk as numpy_peer
from .report import Row, Table, Target, sel
from .timing import Runner, status_counts

__all__ = ["EFFECTORS", "IKEvaluation", "ORIENTATION_TOLERANCE", "ProblemSet", "batched_solver", "draw_problems",
           "evaluate", "load_skeleton", "make_problems", "run_ik", "skeleton_height"]

IK_BATCHES = (1, 64, 1024, 4096)
IK_ACCELERATOR_BATCHES = (1024, 16384, 131072)  # --gpu on a machine with an accelerator
EFFECTORS = ("LeftHand", "RightHand", "LeftToeBase_End", "RightToeBase_End", "Head_End")
SEED = 0
MAX_ANGLE_DEG = 45.0
ROOT_TRANSLATION_STD = 5.0  # file units, per axis
POSITION_TOLERANCE_REL = 1e-3  # success: position error < this x skeleton height
ORIENTATION_TOLERANCE = 0.01  # success: orientation error < this (rad)
REGULARIZATION = 0.0  # solve_ik's lambda for every row
MAX_STEPS = 100  # adaptive solvers' iteration cap
FIXED_STEPS = 30  # the fixed-iteration LM row
JT_MAX_STEPS = 300  # Jacobian transpose
CCD_MAX_SWEEPS = 200
# The one stopping rule of the LM, CCD and Pinocchio CLIK rows: every effector within this fraction of the success
# thresholds (a margin, so that a float32 solve that stops also passes the independent float64 check)
STOP_FRACTION = 0.5
CLIK_MAX_ITERATIONS = 100
CLIK_DAMPING = 1e-4
_SLOW_MAX_BATCH = 1024  # peers and baselines are not run above this in full mode (time budget)


def _matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``[..., 3, 3]`` (float64) of wxyz quaternions ``[..., 4]``, normalized first."""
    q = np.asarray(q, np.float64)
    return Rotation.from_quat(q.reshape(-1, 4)[:, [1, 2, 3, 0]]).as_matrix().reshape(q.shape[:-1] + (3, 3))


def _fk_sites(skeleton, quats: np.ndarray, trans: np.ndarray, sites: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """Float64 numpy FK of ``[B, J, 4]`` wxyz / ``[B, J, 3]`` poses: site positions and rotations."""
    out = numpy_peer.forward_kinematics(skeleton.parents, skeleton.end_site_parents,
                                        np.asarray(skeleton.end_site_offsets, dtype=np.float64), _matrices(quats),
                                        np.asarray(trans, dtype=np.float64))
    J, idx = skeleton.num_joints, [skeleton.site_index(s) for s in sites]
    p_all = np.concatenate([out.positions, out.end_site_positions], axis=1)
    return p_all[:, idx], out.rotations[:, [i if i < J else skeleton.end_site_parents[i - J] for i in idx]]


def skeleton_height(skeleton) -> float:
    """The vertical (y) extent of the rest pose's joints and End Sites, file units."""
    y = _fk_sites(skeleton, np.asarray(skeleton.rest_rotations(jnp.float64))[None], np.asarray(skeleton.offsets)[None],
                  skeleton.names + skeleton.end_site_names)[0][0, :, 1]
    return float(y.max() - y.min())


@dataclasses.dataclass(frozen=True)
class ProblemSet:
    """A batch of IK problems (float64 numpy): the goal poses, their world targets ``positions [B, sites, 3]``,
    ``orientations [B, sites, 4]`` (wxyz) and ``rotation_matrices``, the rest pose every solve starts from."""

    skeleton: Any
    sites: tuple[str, ...]
    goal_rotations: np.ndarray
    goal_translations: np.ndarray
    positions: np.ndarray
    orientations: np.ndarray
    rotation_matrices: np.ndarray
    start_rotations: np.ndarray
    start_translations: np.ndarray
    height: float

    batch = property(lambda self: int(self.positions.shape[0]))
    position_tolerance = property(lambda self: POSITION_TOLERANCE_REL * self.height)

    def first(self, batch: int) -> ProblemSet:
        return dataclasses.replace(self, **{k: getattr(self, k)[:batch] for k in (
            "goal_rotations", "goal_translations", "positions", "orientations", "rotation_matrices")})

    def targets(self, dtype: Any) -> tuple:
        """The problems' :class:`jaxanim.ik.Target` s, with a leading batch axis."""
        return tuple(IKTarget(s, jnp.asarray(self.positions[:, k], dtype), jnp.asarray(self.orientations[:, k], dtype),
                              jnp.ones((self.batch,), dtype)) for k, s in enumerate(self.sites))

    def start(self, dtype: Any) -> tuple[jax.Array, jax.Array]:
        """``(rotations [B, J, 4], translations [B, J, 3])`` of the start pose."""
        return tuple(jnp.asarray(np.broadcast_to(a, (self.batch,) + a.shape), dtype)
                     for a in (self.start_rotations, self.start_translations))


def draw_problems(skeleton, batch: int, seed: int = SEED, sites: Sequence[str] = EFFECTORS) -> ProblemSet:
    """Draw ``batch`` reachable IK problems for ``skeleton`` (see the module docstring)."""
    J = skeleton.num_joints
    rng = np.random.default_rng(seed)
    ang = np.deg2rad(rng.uniform(-MAX_ANGLE_DEG, MAX_ANGLE_DEG, size=(batch, J, 3)))
    q = euler_quats(ang[..., ::-1], "ZYX")  # Rz Ry Rx of the angles (z, y, x) times the identity rest rotations
    root = rng.normal(size=(batch, 4))  # the root uniform on SO(3)
    q[:, 0] = root / np.linalg.norm(root, axis=-1, keepdims=True)
    offsets = np.asarray(skeleton.offsets, dtype=np.float64)
    t = np.broadcast_to(offsets, (batch, J, 3)).copy()
    t[:, 0] += ROOT_TRANSLATION_STD * rng.normal(size=(batch, 3))
    pos, mats = _fk_sites(skeleton, q, t, sites)
    quats = Rotation.from_matrix(mats.reshape(-1, 3, 3)).as_quat(canonical=True)[:, [3, 0, 1, 2]]  # w >= 0
    return ProblemSet(skeleton, tuple(sites), q, t, pos, quats.reshape(mats.shape[:-2] + (4,)), mats,
                      np.tile(np.array([1.0, 0.0, 0.0, 0.0]), (J, 1)), offsets.copy(), skeleton_height(skeleton))


def make_problems(skeleton, batch: int, seed: int = SEED, dtype: Any = jnp.float64):
    """``(targets, rotations, translations)``: ``batch`` problems' batched targets and rest-pose starts."""
    ps = draw_problems(skeleton, batch, seed)
    return (ps.targets(dtype), *ps.start(dtype))


class IKEvaluation(NamedTuple):
    """``position_errors [B, sites]`` (file units), ``orientation_errors [B, sites]`` (rad) from an independent
    float64 numpy FK, ``success [B]`` (every error under its tolerance) and its ``rate``."""

    position_errors: np.ndarray
    orientation_errors: np.ndarray
    success: np.ndarray
    rate: float

    def p98(self) -> str:  # over problems, of each problem's worst position / orientation error
        return " / ".join(f"{np.percentile(e.max(axis=1), 98):.1e}" for e in self[:2])


def evaluate(skeleton, targets, rotations, translations) -> IKEvaluation:
    """Errors and success of poses ``[B, J, 4]`` / ``[B, J, 3]`` against batched ``targets`` (a tuple of
    :class:`jaxanim.ik.Target` or a :class:`ProblemSet`); a non-finite pose fails (errors ``inf``)."""
    if isinstance(targets, ProblemSet):
        sites, goal_p, goal_R = targets.sites, targets.positions, targets.rotation_matrices
    else:
        sites = tuple(t.site for t in targets)
        goal_p = np.stack([np.asarray(t.position, np.float64) for t in targets], axis=1)
        goal_R = _matrices(np.stack([np.asarray(t.orientation, np.float64) for t in targets], axis=1))
    b = goal_p.shape[0]
    q, t = np.asarray(rotations, np.float64)[:b], np.asarray(translations, np.float64)[:b]
    finite = np.isfinite(q).all(axis=(1, 2)) & np.isfinite(t).all(axis=(1, 2))
    p, R = _fk_sites(skeleton, np.where(finite[:, None, None], q, np.array([1.0, 0, 0, 0])),
                     np.where(finite[:, None, None], t, 0.0), sites)
    pe = np.where(finite[:, None], np.linalg.norm(p - goal_p, axis=-1), np.inf)
    angle = Rotation.from_matrix(np.einsum("bsij,bskj->bsik", R, goal_R).reshape(-1, 3, 3)).magnitude()
    oe = np.where(finite[:, None], angle.reshape(pe.shape), np.inf)
    pt = POSITION_TOLERANCE_REL * skeleton_height(skeleton)
    ok = (pe < pt).all(axis=1) & (oe < ORIENTATION_TOLERANCE).all(axis=1)
    return IKEvaluation(pe, oe, ok, float(np.mean(ok)) if ok.size else float("nan"))


def batched_solver(skeleton, solve: Callable | None = None, **kwargs) -> Callable:
    """A fresh ``jax.jit(jax.vmap(...))`` of ``solve(skeleton, targets, q, t, **kwargs)`` (default ``solve_ik``)."""
    solve = solve_ik if solve is None else solve
    return jax.jit(jax.vmap(lambda targets, q, t: solve(skeleton, targets, q, t, **kwargs)))


def load_skeleton(config):
    """The CMU skeleton (float64), or the reason it cannot be loaded."""
    path = config.data_file(CLIP)
    return _cast(read_bvh(str(path))[0], jnp.float64) if isinstance(path, pathlib.Path) else path


def _tol(dtype) -> dict:
    """``rtol, atol`` of the adaptive solvers: the library defaults in float64, looser in float32."""
    return dict(rtol=1e-8, atol=1e-10) if jnp.dtype(dtype) == jnp.float64 else dict(rtol=1e-5, atol=1e-7)


def _ik(solver, problems: ProblemSet) -> dict:
    """``solve_ik`` keywords: the solver, and the one stopping rule of every row (:data:`STOP_FRACTION`)."""
    return dict(solve=solve_ik, solver=solver, regularization=REGULARIZATION, stop_at_tolerance=True,
                position_tolerance=STOP_FRACTION * problems.position_tolerance,
                orientation_tolerance=STOP_FRACTION * ORIENTATION_TOLERANCE)


def _jaxopt(dtype, problems: ProblemSet) -> dict:
    require("jaxopt", "pip install 'jaxanim[jaxopt]'", quiet=True)  # it announces on import that it is unmaintained
    atol = 1e-8 if jnp.dtype(dtype) == jnp.float64 else 1e-3  # |J^T r|_2
    return _ik(solvers.JaxoptSolver("LevenbergMarquardt", atol=atol, max_steps=MAX_STEPS), problems)


_LM_ADAPTIVE = "jaxanim LM (adaptive)"
_LM_FIXED = f"jaxanim LM (fixed {FIXED_STEPS})"
_CCD = "jaxanim CCD"
_JT = "jaxanim Jacobian transpose"
_PIN = "Pinocchio CLIK"
_TOL = "rtol/atol {rtol:g}/{atol:g} (f64), ".format(**_tol(jnp.float64)) + "{rtol:g}/{atol:g} (f32)".format(
    **_tol(jnp.float32))
# (name, make(dtype, problems) -> kwargs of batched_solver, note, is_peer, max_batch)
_METHODS = (
    (_LM_ADAPTIVE, lambda d, p: _ik(solvers.LevenbergMarquardt(**_tol(d), max_steps=MAX_STEPS, fixed_steps=False), p),
     f"solvers.LevenbergMarquardt, while_loop, ≤ {MAX_STEPS} iterations, {_TOL}", False, None),
    (_LM_FIXED, lambda d, p: _ik(solvers.LevenbergMarquardt(**_tol(d), max_steps=FIXED_STEPS, fixed_steps=True), p),
     f"solvers.LevenbergMarquardt(fixed_steps=True): lax.scan of {FIXED_STEPS} iterations (iterations = steps "
     "until converged; finished problems are frozen)", False, None),
    ("optimistix LM", lambda d, p: _ik(solvers.OptimistixSolver(optx.LevenbergMarquardt(**_tol(d)),
                                                                max_steps=MAX_STEPS), p),
     f"OptimistixSolver(optx.LevenbergMarquardt), ≤ {MAX_STEPS} steps, {_TOL}; its damped step is a dense QR "
     "(lineax's default) of the stacked (m + n) x n matrix [J; √λ I] each step, where own LM solves an m x m "
     "system (m = 30 < n = 96)", True, _SLOW_MAX_BATCH),
    ("optimistix GN", lambda d, p: _ik(solvers.OptimistixSolver(optx.GaussNewton(**_tol(d)), max_steps=MAX_STEPS), p),
     f"OptimistixSolver(optx.GaussNewton) (default linear solver), ≤ {MAX_STEPS} steps, {_TOL}", True,
     _SLOW_MAX_BATCH),
    ("jaxopt LM", lambda d, p: _jaxopt(d, p), "JaxoptSolver('LevenbergMarquardt'): Cholesky, |J^T r| ≤ 1e-8 (f64) / "
     f"1e-3 (f32), ≤ {MAX_STEPS} steps", True, _SLOW_MAX_BATCH),
    (_CCD, lambda d, p: dict(solve=solve_ik_ccd, max_sweeps=CCD_MAX_SWEEPS, fixed_sweeps=False,
                             position_tolerance=STOP_FRACTION * p.position_tolerance,
                             orientation_tolerance=STOP_FRACTION * ORIENTATION_TOLERANCE),
     f"jaxanim.ik.solve_ik_ccd, while_loop, ≤ {CCD_MAX_SWEEPS} sweeps, stops at half the success "
     "thresholds; iterations = sweeps", False, _SLOW_MAX_BATCH),
    (_JT, lambda d, p: _ik(solvers.GradientDescent(**_tol(d), max_steps=JT_MAX_STEPS, fixed_steps=False,
                                                   max_backtracks=8), p),
     f"solvers.GradientDescent (Buss step + Armijo backtracking), ≤ {JT_MAX_STEPS} iterations, {_TOL}", False,
     _SLOW_MAX_BATCH),
)


def _iterations(steps: np.ndarray) -> str:
    return f"iterations {steps.mean():.1f} / {int(steps.max())} (mean / max)"


def _jax_row(run: Runner, impl: str, make: Callable, note: str, problems: ProblemSet, dtype: str, b: int) -> Row:
    sub = problems.first(b)
    out, tm, comp = run.jax(batched_solver(_cast(problems.skeleton, dtype), **make(dtype, problems)),
                            sub.targets(dtype), *sub.start(dtype))
    if out.rotations.dtype != jnp.dtype(dtype):
        raise TypeError(f"the {dtype} solve returned {out.rotations.dtype} rotations")
    ev = evaluate(problems.skeleton, sub, out.rotations, out.translations)
    steps = np.asarray(out.stats["num_steps"])
    return run.row(impl, dtype, b, tm, compile_s=comp, accuracy=ev.p98(), success=ev.rate,
                   status=status_counts(out.result), note=f"{_iterations(steps)}; {note}", extra=dict(steps=steps))


def _pin_row(run: Runner, pin, problems: ProblemSet, b: int) -> Row:
    n = min(b, run.config.loop_cap)
    prev = [r.us_per_char for r in run.table.rows if r.implementation == _PIN and r.measured]
    if prev:  # keep one call within about half the row budget
        n = min(n, max(64, int(0.5 * run.config.max_row_s / (max(prev) * 1e-6))))
    sub = problems.first(n)
    q0s = list(pinocchio_peer.configurations(np.broadcast_to(sub.start_rotations, (n,) + sub.start_rotations.shape),
                                             np.broadcast_to(sub.start_translations[0], (n, 3))))
    loop = functools.partial(pinocchio_peer.clik_loop, damping=CLIK_DAMPING, max_iterations=CLIK_MAX_ITERATIONS,
                             position_tolerance=STOP_FRACTION * sub.position_tolerance,
                             orientation_tolerance=STOP_FRACTION * ORIENTATION_TOLERANCE)
    (qs, its), tm = run.python(loop, pin, q0s, [pin.frame_ids[s] for s in sub.sites], sub.positions,
                               sub.rotation_matrices)
    ev = evaluate(problems.skeleton, sub, *pinocchio_peer.to_poses(qs, np.asarray(problems.skeleton.offsets)))
    note = (f"{_iterations(its)}; Python loop, damped least squares lambda={CLIK_DAMPING:g}, ≤ {CLIK_MAX_ITERATIONS} "
            "iterations, stops at half the success thresholds" + (f"; timed on {n} of {b} problems" if n < b else ""))
    return run.row(_PIN, "float64", b, tm, n, accuracy=ev.p98(), success=ev.rate, note=note)


def _iteration_note(table: Table) -> list[str]:
    """How many iterations the adaptive LM needed at its largest batch (from the rows)."""
    parts = []
    for d in ("float64", "float32"):
        rows = [r for r in table.rows if r.measured and r.implementation == _LM_ADAPTIVE and r.dtype == d]
        if rows:
            r = max(rows, key=lambda r: r.batch)
            s = r.extra["steps"]
            parts.append(f"{d} (batch {r.batch}) " + " / ".join(f"{x:.0f}" for x in np.percentile(s, [50, 99, 99.5]))
                         + f" / {int(s.max())}")
    return ["Iterations the adaptive LM took to converge (median / 99th / 99.5th percentile / max): " + "; ".join(
        parts) + f". The fixed row runs {FIXED_STEPS}; its success column shows the outcome."] if parts else []


def _accelerator_targets(b: int) -> list[Target]:
    """Issue 29's targets on one H200 (``--gpu`` on an accelerator), at the largest batch ``b``."""
    return [Target(f"accelerator: own adaptive LM ≥ 10^5 problems/s in float32 at batch {b} (≤ 10 µs per problem)",
                   sel(_LM_ADAPTIVE, "float32", b, exact=True), 10.0),
            Target(f"accelerator: own adaptive LM ≥ 6·10^4 problems/s in float64 at batch {b} (≤ 16.7 µs per "
                   "problem)", sel(_LM_ADAPTIVE, "float64", b, exact=True), 1e6 / 6e4),
            Target(f"accelerator: ≥ 99.5 % success at batch {b} in float32 and float64 (own adaptive LM)",
                   sel(_LM_ADAPTIVE, batch=b, exact=True), 0.995, "success", worst=True)]


def run_ik(config) -> list[Table]:
    """The ``ik`` benchmark (see the module docstring)."""
    batches = config.batches_for(IK_BATCHES, IK_ACCELERATOR_BATCHES)
    b_t = 1024 if 1024 in batches else max(batches)
    lm = (_LM_ADAPTIVE, _LM_FIXED)
    own, own_b, own64 = sel(lm, exact=True), sel(lm, batch=b_t, exact=True), sel(lm, "float64", b_t, exact=True)
    table = Table("ik", "Inverse kinematics: 5 effectors, position + orientation (31-joint CMU skeleton)",
                  accuracy_label="p98 error: position / orientation", targets=[
                      Target(f"≥ 99.5 % success at batch {b_t} in float32 and float64 (own LM)", own_b, 0.995,
                             "success", worst=True),
                      Target(f"own LM ≥ 10x the throughput of the Pinocchio CLIK loop at batch {b_t}, float64, both "
                             "under the one stopping rule", own64, 10.0, versus=sel(_PIN, "float64", b_t)),
                      Target(f"optimistix LM within 3x of the own adaptive LM at batch {b_t}, float64 (speedup "
                             "≥ 0.33x)", sel("optimistix LM", "float64", b_t), 1 / 3,
                             versus=sel(_LM_ADAPTIVE, "float64", b_t)),
                      Target("IK compile ≤ 5 s (own LM rows)", own, 5.0, "compile", worst=True)]
                  + (_accelerator_targets(max(batches)) if config.accelerator else []))
    skel = load_skeleton(config)
    if isinstance(skel, str):
        table.skipped = skel
        return [table]
    problems = draw_problems(skel, max(batches), SEED)
    table.description = (
        f"Random reachable targets on the 31-joint CMU skeleton (`{CLIP}`, 96 degrees of freedom): world positions and "
        f"orientations of {len(EFFECTORS)} effectors ({', '.join(f'`{s}`' for s in EFFECTORS)}) after FK of a random "
        f"pose (joints within ±{MAX_ANGLE_DEG:g}° per axis of the rest pose, the root rotated uniformly and translated "
        f"by N(0, {ROOT_TRANSLATION_STD}²) per axis; seed {SEED}). Solves start from the rest pose; `solve_ik` rows "
        "use `regularization=0` and the tolerances in their notes. **One stopping rule**: every row (own LM, the "
        "optimistix and jaxopt adapters, CCD, Pinocchio CLIK) stops as soon as every effector is within "
        f"{STOP_FRACTION:g} × the success thresholds, or at its own tolerances if earlier (iterations are counted to "
        "that rule; optimistix counts its first step, an evaluation at the start). Rows are "
        "`jax.jit(jax.vmap(solve))`; Pinocchio "
        "CLIK is a Python loop (float64). µs / char = µs per problem. **Success**: every position error < "
        f"{POSITION_TOLERANCE_REL:g} × skeleton height ({problems.height:.2f} units, so "
        f"{problems.position_tolerance:.4f}) and orientation error < {ORIENTATION_TOLERANCE} rad, by an independent "
        "float64 numpy FK of the returned poses (not the solvers' flags). Error column: 98th percentile over problems "
        "of each problem's worst position (units) / orientation (rad) error.")
    run = Runner(config, table)
    pin = pinocchio(run, skel, _PIN)
    dtypes = sorted(config.dtypes, key=lambda d: d != "float64")
    # under --gpu the own LM rows climb the whole ladder first, then the others run (to batch 1024): within the
    # section's time budget every batch compiles again, and the sizes are the own solver's
    passes = ((_METHODS[:2], False), (_METHODS[2:], True)) if config.accelerator else ((_METHODS, True),)
    for methods, with_pin in passes:
        for dtype in dtypes:
            for b in batches:
                for impl, make, note, peer, max_batch in methods:
                    run.add(impl, dtype, b, lambda: _jax_row(run, impl, make, note, problems, dtype, b), peer=peer,
                            max_batch=max_batch)
                if with_pin and pin is not None and dtype == dtypes[0]:
                    run.add(_PIN, "float64", b, lambda: _pin_row(run, pin, problems, b), peer=True)
    table.notes += _iteration_note(table)
    return [table]
