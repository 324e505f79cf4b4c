"""Retargeting benchmark (``python -m benchmarks retarget``): the shipped walk at several speeds onto the Unitree G1
(``../shared/data/robots``), jaxanim's whole-clip solve (``retargeting.solve_retarget`` under ``vmap``) against mink
driven frame by frame as GMR drives it, on the same robot, pairs, targets and clips; both clips judged by the same
measures (``retargeting.diagnostics``)."""

from __future__ import annotations

import dataclasses
import functools
import time

import jax
import jax.numpy as jnp
import numpy as np
from jaxanim import default_clip_path, read_bvh, retargeting, robots
from jaxanim.app._simulate import _looped_motion
from jaxanim.retargeting._solve import _initial
from jaxanim.skeleton import Motion, resample_at

from .peers import mink_retarget as mr
from .report import Row, Table, Target, sel
from .retarget_dataset import DatasetSizes, dataset_table
from .timing import Runner, status_counts

__all__ = ["ACCELERATOR_SIZES", "RetargetSizes", "clip_problems", "run_retarget"]

_JAX = "jaxanim retargeting.solve_retarget (vmap)"
_MINK = "mink 1.3.0 solve_ik per frame (GMR's loop, daqp)"
#: mink's task costs: ``MINK_COST * sqrt(weight)`` of each pair (a cost scales the residual, not its square), so the
#: map's ratios at GMR's magnitude (its G1 tables use position costs of 100 on the pelvis and feet).
MINK_COST = 100.0


@dataclasses.dataclass(frozen=True)
class RetargetSizes:
    """Sizes (``--quick`` and tests shrink them): the range of the clips' speed factors (as many clips as the
    largest batch, ``frames`` frames of the walk each, looped and resampled) and the batches timed (the first
    clips of the list)."""

    speed_range: tuple[float, float] = (0.7, 1.3)
    frames: int = 120
    batches: tuple[int, ...] = (1, 32)


#: ``--gpu`` on a machine with an accelerator: the same clips (mink runs on the host either way).
ACCELERATOR_SIZES = RetargetSizes()


@functools.lru_cache(maxsize=4)
def _clips(speeds: tuple[float, ...], frames: int) -> tuple:
    """The shipped walk looped and resampled to each speed factor (``frames`` frames at its 30 fps)."""
    skel, walk = read_bvh(default_clip_path())[:2]
    out = []
    for s in speeds:
        long = _looped_motion(walk, int(np.ceil(frames * s)) + 2)
        m = resample_at(long, jnp.asarray(np.arange(frames) * s, dtype=long.rotations.dtype))
        out.append(Motion(m.rotations, m.translations, walk.frame_time))
    return skel, tuple(out)


def clip_problems(robot: robots.Robot, speeds: tuple[float, ...], frames: int) -> list[retargeting.RetargetProblem]:
    """One prepared problem per clip (the shipped map; calibrated on the robot's zero pose)."""
    skel, clips = _clips(speeds, frames)
    mapping = retargeting.load_mapping(retargeting.default_mapping_path())
    return [retargeting.prepare_retarget(skel, m, robot, mapping) for m in clips]


def _measures(robot, problems, qpos) -> dict[str, np.ndarray]:
    """Per clip: :func:`retargeting.summary` of :func:`retargeting.diagnostics` (float64 kinematics)."""
    out: dict[str, list[float]] = {}
    for p, q in zip(problems, qpos):
        s = retargeting.summary(retargeting.diagnostics(robot, p, jnp.asarray(q, jnp.float64)), p.position_weight)
        for k, v in s.items():
            out.setdefault(k, []).append(v)
    return {k: np.asarray(v, np.float64) for k, v in out.items()}


def _note(m: dict[str, np.ndarray]) -> str:
    return (f"stance slide median {1e3 * np.max(m['foot_slide']):.2f} mm/s (worst clip); lowest foot point "
            f"{1e3 * np.min(m['lowest_foot']):.2f} mm; jitter {np.mean(m['jitter']):.3g} rad/s²; range violation "
            f"{np.max(m['range_violation']):.1e}; orientation error {np.mean(m['orientation_error']):.3f} rad")


def _success(m: dict[str, np.ndarray]) -> float:
    """The fraction of clips meeting issue 30's foot and range targets."""
    ok = (m["foot_slide"] <= 1e-3) & (m["penetration"] <= 1e-3) & (m["range_violation"] <= 1e-6)
    return float(np.mean(ok))


def _table(config, sz: RetargetSizes) -> Table:
    path = config.data_file("robots/unitree_g1/g1.xml")
    if isinstance(path, str):
        return Table("retarget", "Retargeting onto the Unitree G1", skipped=path)
    robot = robots.load_robot(path)
    batches = config.batches_for(sz.batches)
    speeds = tuple(np.round(np.linspace(*sz.speed_range, max(batches)), 4))
    problems = clip_problems(robot, speeds, sz.frames)
    names = problems[0].names
    opts = retargeting.RetargetOptions()
    table = Table(
        "retarget", f"Retargeting: the shipped walk onto the Unitree G1, {sz.frames}-frame clips",
        accuracy_label="matching error (m)", description=(
            f"Clips: the shipped walk looped and resampled to {len(speeds)} speed factors "
            f"({min(speeds):g}-{max(speeds):g}), {sz.frames} frames each at 30 fps; a batch of `b` clips is "
            f"the first `b`. The robot: `robots/unitree_g1/g1.xml` of the shared data ({robot.nv} dofs). The map: "
            f"the shipped `walk_humanoid.json` ({len(names)} targets with the root, calibrated on the robot's zero "
            "pose); both solvers get the same robot-frame targets (`RetargetProblem.target_positions`, "
            "`orientations`) and start from the same first frame. jaxanim: `jax.vmap(retargeting.solve_retarget)` over "
            "the clips (default `RetargetOptions`: one least-squares problem per clip with planted feet, ground, "
            "hard joint ranges and smoothness; compile apart). mink: GMR's loop "
            "(`benchmarks/peers/mink_retarget.py`), one stage, one `FrameTask` per pair with costs "
            f"{MINK_COST:g}·sqrt(weight) (the map's ratios at GMR's magnitude), daqp, clips one after another "
            "(mink has no batching). **µs / char is per frame.** Every clip of both is judged by "
            "`retargeting.diagnostics`: accuracy is the mean distance to the weighted position targets (the planted "
            "feet's included), averaged over the clips; success is the fraction of clips whose median stance-foot "
            "slide, penetration and range violation meet issue 30's targets; the note gives the worst clip's "
            "slide, the lowest foot point, the mean joint jitter and the largest range violation."),
        targets=[Target("≥ 5× mink's frames per second on a batch of 32 clips (float64)",
                        sel(_JAX, "float64", 32), 5.0, versus=sel(_MINK, batch=32)),
                 Target("every clip's stance slide ≤ 1 mm/s, penetration ≤ 1 mm, no range violation above 1e-6 "
                        "(float64)", sel(_JAX, "float64"), 1.0, "success", worst=True)])
    run = Runner(config, table)
    measured: dict[tuple[str, str, int], dict[str, np.ndarray]] = {}

    def mink_row(b: int) -> Row:
        mink = mr.load_mink()  # noqa: F841 (a missing peer is one skipped row)
        model = mr.load_model(path)
        ps = problems[:b]
        pos = [np.asarray(p.target_positions(), np.float64) for p in ps]
        quat = [np.asarray(p.orientations, np.float64) for p in ps]
        pw = MINK_COST * np.sqrt(np.asarray(ps[0].position_weight, np.float64))
        ow = MINK_COST * np.sqrt(np.asarray(ps[0].orientation_weight, np.float64))
        init = np.stack([np.asarray(_initial(robot, p, jnp.float64)[0]) for p in ps])

        def call(pos, quat):
            return mr.mink_retarget_batch(model, names, pos, quat, pw, ow, qpos_init=init)[0]

        qpos, tm = run.python(call, pos, quat)
        m = _measures(robot, ps, qpos)
        measured[(_MINK, "float64", b)] = m
        return run.row(_MINK, "float64", b, tm, b * sz.frames, None, float(np.mean(m["matching_error"])),
                       success=_success(m), note=_note(m))

    def jax_row(b: int, dtype: str) -> Row:
        batch = retargeting.stack_problems(problems[:b])
        batch = jax.tree.map(lambda x: x.astype(dtype) if jnp.issubdtype(x.dtype, jnp.floating) else x, batch)
        fn = jax.jit(jax.vmap(lambda p: retargeting.solve_retarget(robot, p, opts)))
        res, tm, comp = run.jax(fn, batch)
        m = _measures(robot, problems[:b], np.asarray(res.qpos, np.float64))
        measured[(_JAX, dtype, b)] = m
        steps = np.asarray(res.num_steps)
        return run.row(_JAX, dtype, b, tm, b * sz.frames, comp, float(np.mean(m["matching_error"])),
                       success=_success(m), status=status_counts(res.result), note=_note(m) + f"; {int(steps.max())} iterations")

    for b in batches:
        run.add(_MINK, "float64", b, lambda: mink_row(b), peer=True)
        for dt in config.dtypes:
            run.add(_JAX, dt, b, lambda: jax_row(b, dt))
    table.notes += _versus_mink(measured)
    if config.selects(_JAX) and "float64" in config.dtypes:
        table.notes.append(_profile(robot, problems[:max(batches)], opts))
    return table


def _profile(robot, problems, opts) -> str:
    """Where an iteration's time goes (float64, the largest batch): the linearization of every frame (kinematics,
    Jacobians, ``J'J``) and the banded solve, each jitted alone and timed after a warm-up call."""
    from jaxanim.retargeting import _solve as rs
    from jaxanim.robots._tangent import TangentLayout

    import solvers

    lay, dtype = TangentLayout(robot), jnp.float64
    batch = retargeting.stack_problems(problems)

    def linearize(p):
        return rs._linearize(robot, p, lay, rs._initial(robot, p, dtype), rs._frames(p, opts, dtype), opts)

    def solve(lin):
        _, JtJ, Jtr, (c, o, a, acc), _ = lin
        g = rs._gradient(Jtr, c, o, a, acc)
        H, e1, e2, g, _ = rs._normal_equations(JtJ, g, c, a, jnp.ones_like(g), jnp.asarray(1e-2, dtype))
        return solvers.block_pentadiagonal_solve(H, e1, e2, -g)[0]

    f_lin, f_solve = jax.jit(jax.vmap(linearize)), jax.jit(jax.vmap(solve))
    lin = jax.block_until_ready(f_lin(batch))
    jax.block_until_ready(f_solve(lin))
    times = []
    for f, x in ((f_lin, batch), (f_solve, lin)):
        best = np.inf
        for _ in range(3):
            t0 = time.perf_counter()
            jax.block_until_ready(f(x))
            best = min(best, time.perf_counter() - t0)
        times.append(best)
    T, n = problems[0].num_frames, robot.nv
    return (f"Where an iteration's time goes (float64, {len(problems)} clips of {T} frames, each phase jitted alone, "
            f"best of 3): linearizing every frame (kinematics, Jacobians, J'J) {1e3 * times[0]:.0f} ms, the banded "
            f"solve ({(T + 1) // 2} sequential steps per clip, each the inverse of a {2 * n} x {2 * n} block from its "
            f"halves) {1e3 * times[1]:.0f} ms; a solve takes the iterations the rows' notes give.")


def _versus_mink(measured) -> list[str]:
    """Issue 30's jitter and matching targets, against mink's clips of the same batch (float64)."""
    lines = []
    for (impl, dtype, b), m in sorted(measured.items(), key=lambda kv: (kv[0][2], kv[0][1])):
        peer = measured.get((_MINK, "float64", b))
        if impl != _JAX or dtype != "float64" or peer is None:
            continue
        for label, key, limit in (("jitter ≤ 0.5× mink's", "jitter", 0.5),
                                  ("matching error within 1.2× mink's", "matching_error", 1.2)):
            x, y = float(np.mean(m[key])), float(np.mean(peer[key]))
            lines.append(f"Target: {label} (float64, batch {b}): jaxanim {x:.3g} vs mink {y:.3g} = {x / y:.3g}×: "
                         f"{'met' if x <= limit * y else 'missed'}.")
    return lines


def run_retarget(config, sizes: RetargetSizes | None = None, dataset: DatasetSizes | None = None) -> list[Table]:
    """The ``retarget`` benchmark (see the module docstring) and its end-to-end dataset table
    (:mod:`benchmarks.retarget_dataset`); ``sizes`` and ``dataset`` shrink them for tests."""
    sz = sizes or config.pick(RetargetSizes(), accelerator=ACCELERATOR_SIZES,
                              quick=RetargetSizes(frames=30, batches=(1, 2)))
    ds = dataset or config.pick(DatasetSizes(), quick=DatasetSizes(clips=4, min_frames=30, max_frames=60))
    tables = [_table(config, sz)]
    path = config.data_file("robots/unitree_g1/g1.xml")
    if isinstance(path, str):
        return tables + [Table("retarget_dataset", "Retargeting a dataset end to end", skipped=path)]
    return tables + [dataset_table(config, path, ds)]
