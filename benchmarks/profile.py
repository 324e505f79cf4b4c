"""Where the time goes in the kernels behind the speed targets (``python -m benchmarks profile``).

Every kernel is compiled once (``jax.jit(f).lower(*args).compile()``), timed like the other benchmarks, then
called under ``jax.profiler.trace``. The trace's XLA:CPU events are the compiled program's instructions (a
fusion, a LAPACK custom call, a copy, a while loop). Each event is matched by name to the instruction in
``compiled.as_text()``, which gives its kind, and the time is summed per kind. While loops and conditionals are
left out of the sums, because their bodies' instructions are counted themselves. The report gives:

- the instructions run per call, and their mean time: a count in the thousands at a few hundred nanoseconds each
  means the call is dominated by the cost of launching XLA:CPU kernels, not by arithmetic;
- the share of each kind;
- the five most expensive instructions, with the JAX operation they came from;
- the kernels in the compiled program: the compiler builds every one separately (LLVM), so their number drives
  compile time; and the library functions they come from (:func:`kernel_sources`: the innermost frame of the
  project's code on each kernel's stack, which XLA keeps in the compiled text), the most first.

A row's *cause* is written from these measurements, and the kernel's own benchmark section states the ratio
to the peer. The profiler slows every call, so compare the shares, not the times, with the other sections.
"""

from __future__ import annotations

import collections
import dataclasses
import pathlib
import re
import tempfile
from collections.abc import Callable, Collection
from typing import Any

import jax
import jax.numpy as jnp

from .report import Row, Table, format_seconds
from .timing import budget_spent, compile_time, sample_call

__all__ = ["KERNELS", "Instruction", "hlo_instructions", "kernel_sources", "kind_of", "profile_events",
           "run_profile"]

PROFILED_CALLS = 2
CART_POLE_PROFILED_STEPS = 60  # of its 600: the trace of every event of a whole solve would not fit in memory
_CONTAINERS = ("while", "conditional", "call")  # their bodies' instructions are events of their own


@dataclasses.dataclass(frozen=True)
class Instruction:
    """One instruction of a compiled HLO module: ``opcode``, fusion kind or custom-call target (``detail``) and the
    JAX ``op_name`` it was lowered from."""

    opcode: str
    detail: str
    op_name: str


_INSTR = re.compile(r"^\s*(?:ROOT )?%?([\w.\-]+) = .*? ([a-z][\w\-]*)\((.*)$")


def hlo_instructions(text: str) -> dict[str, Instruction]:
    """Every instruction of ``compiled.as_text()`` by name (inner computations of fusions included: harmless)."""
    out = {}
    for line in text.splitlines():
        m = _INSTR.match(line)
        if not m:
            continue
        name, opcode, rest = m.groups()
        detail = ""
        if opcode == "fusion":
            k = re.search(r"kind=(k\w+)", rest)
            detail = k.group(1) if k else ""
        elif opcode == "custom-call":
            k = re.search(r'custom_call_target="([^"]+)"', rest)
            detail = k.group(1) if k else ""
        op = re.search(r'op_name="([^"]+)"', rest)
        out[name] = Instruction(opcode, detail, op.group(1) if op else "")
    return out


def kind_of(ins: Instruction | None) -> str:
    """The reported kind of an instruction: elementwise fusion, reduction, data movement, library call, ..."""
    if ins is None:
        return "other"
    if ins.opcode == "fusion":
        if ins.detail == "kCustom":  # XLA:CPU hands dots to YNNPACK as custom fusions
            return "dot fusions"
        if ins.detail == "kInput":
            return "reduction fusions"
        if ins.detail == "kOutput":
            return "dot fusions"
        n = ins.op_name.rsplit("/", 1)[-1]
        if any(w in n for w in ("concatenate", "split", "slice", "transpose", "gather", "scatter", "dynamic",
                                "broadcast_in_dim", "pad", "stack", "_take", "copy")):
            return "data-movement fusions"
        return "elementwise fusions"
    if ins.opcode == "custom-call":
        name = ins.detail.removeprefix("lapack_").removesuffix("_ffi")
        return f"library calls ({name})" if name else "library calls"
    if ins.opcode in ("copy", "transpose", "gather", "scatter", "dynamic-update-slice", "dynamic-slice",
                      "concatenate", "slice", "pad"):
        return "data movement (" + ins.opcode + ")"
    if ins.opcode in ("dot", "convolution"):
        return "dots"
    if ins.opcode in ("sort",):
        return "sorts"
    return ins.opcode


def profile_events(compiled: Callable, args: tuple, calls: int = PROFILED_CALLS,
                   names: Collection[str] | None = None) -> dict[str, tuple[float, int]]:
    """``{instruction name: (seconds, count)}`` per call of ``compiled(*args)`` from a ``jax.profiler`` trace of
    XLA:CPU's threads (runtime bookkeeping events excluded). With ``names`` (the program's instructions,
    :func:`hlo_instructions`) only their events are kept: XLA:CPU's classic emitters
    (``--xla_cpu_use_fusion_emitters=false``) also trace library work nested inside an instruction's
    own event (Eigen's ``Transpose``), which would count that time twice."""
    from jax._src.lib import _profile_data  # noqa: PLC0415 - the reader of the profiler's own trace files

    jax.block_until_ready(compiled(*args))
    with tempfile.TemporaryDirectory() as logdir:
        with jax.profiler.trace(logdir):
            for _ in range(calls):
                jax.block_until_ready(compiled(*args))
        path = next(pathlib.Path(logdir).rglob("*.xplane.pb"))
        data = _profile_data.ProfileData.from_file(str(path))
    total, count = collections.Counter(), collections.Counter()
    for plane in data.planes:
        if not plane.name.startswith("/host:CPU"):
            continue
        for line in plane.lines:
            if not line.name.startswith("tf_XLA"):
                continue
            for ev in line.events:
                if "::" in ev.name or " " in ev.name:  # ThunkExecutor::Execute and other bookkeeping
                    continue
                if names is not None and ev.name not in names:
                    continue
                total[ev.name] += ev.duration_ns * 1e-9
                count[ev.name] += 1
    return {k: (total[k] / calls, count[k] // calls) for k in total}


_KERNEL = re.compile(r"= \S+ (?:fusion|custom-call|copy|dot|gather|scatter|transpose|sort)\(")


def _kernel_lines(text: str) -> list[str]:
    """The instructions of ``compiled.as_text()`` that are kernels of their own: fusions, library calls, copies,
    dots, gathers, scatters, transposes and sorts outside the fused computations (whose instructions are inlined
    into their fusion's kernel)."""
    out, fused = [], False
    for line in text.splitlines():
        if line and not line[0].isspace() and line.rstrip().endswith("{"):
            fused = line.removeprefix("ENTRY ").lstrip("%").startswith("fused")
        elif not fused and _KERNEL.search(line):
            out.append(line)
    return out


_TABLES = ("FileNames", "FunctionNames", "FileLocations", "StackFrames")
_PROJECT = ("jaxanim/", "solvers/", "benchmarks/")
#: thin wrappers that only state a product's precision: a kernel they emit is counted at their caller
_WRAPPERS = {"matmul", "dot", "einsum"}


def _stack_tables(text: str) -> dict[str, dict[int, str]]:
    """The compiled text's stack-frame tables (``FileNames`` ... ``StackFrames``), each ``{id: line}``."""
    tables: dict[str, dict[int, str]] = {}
    section = None
    for line in text.splitlines():
        if line in _TABLES:
            section = tables.setdefault(line, {})
        elif section is not None:
            m = re.match(r"(\d+) (.*)$", line)
            if not m:
                section = None
                continue
            section[int(m.group(1))] = m.group(2)
    return tables


def kernel_sources(text: str) -> list[tuple[str, int]]:
    """``[(source, kernels)]``, the most first: the kernels of ``compiled.as_text()`` (:func:`_kernel_lines`) by
    the innermost function of this project (``jaxanim``, ``solvers``, ``benchmarks``) on the stack that XLA recorded
    for each (``stack_frame_id``; the precision-stating product wrappers count at their caller), as
    ``"file.py:function"`` (``"physics/_bodies.py:_spd_inverse"``: paths in ``jaxanim`` from there, the others'
    from the repository's root); ``"other"`` for kernels without one. Empty where the text has no stack tables.

    A custom JVP rule's operations carry the stack of its primal's call, so a differentiated solve's kernels count
    at the function that called it (the tracking gains' at ``solve_rows``). In the printed tables a frame's
    ``parent_frame_id`` is the parent's number plus one (0 for none)."""
    tables = _stack_tables(text)
    if any(t not in tables for t in _TABLES):
        return []
    files = {k: v.strip('"') for k, v in tables["FileNames"].items()}
    funcs = {k: v.strip('"') for k, v in tables["FunctionNames"].items()}
    locations, frames = {}, {}
    for k, v in tables["FileLocations"].items():
        m = re.search(r"file_name_id=(\d+) function_name_id=(\d+)", v)
        if m:
            locations[k] = (int(m.group(1)), int(m.group(2)))
    for k, v in tables["StackFrames"].items():
        m = re.search(r"file_location_id=(\d+) parent_frame_id=(\d+)", v)
        if m:
            frames[k] = (int(m.group(1)), int(m.group(2)) - 1)

    def source(frame: int) -> str:
        seen = set()
        while frame in frames and frame not in seen:
            seen.add(frame)
            location, frame = frames[frame]
            file_id, func_id = locations.get(location, (0, 0))
            path, func = files.get(file_id, ""), funcs.get(func_id, "")
            rel = next((path[path.rindex(p):] for p in _PROJECT if p in path), None)
            if rel is not None and not (func in _WRAPPERS and rel.endswith("_linalg.py")):
                name = rel.removeprefix("jaxanim/") if rel.count("/") > 1 else rel
                return f"{name}:{func.replace('.<locals>.', '.')}"
        return "other"

    counts: collections.Counter = collections.Counter()
    for line in _kernel_lines(text):
        m = re.search(r"stack_frame_id=(\d+)", line)
        counts[source(int(m.group(1))) if m else "other"] += 1
    return counts.most_common()


@dataclasses.dataclass(frozen=True)
class KernelProfile:
    """The summary of one profiled kernel (see the module docstring)."""

    instructions_run: int
    busy_s: float  # summed over the instructions (several threads may overlap)
    by_kind: list[tuple[str, float]]  # (kind, share of busy time), largest first
    top: list[tuple[str, str, float, int]]  # (instruction, op_name tail, share, runs per call)
    kernels_compiled: int
    kernel_sources: list[tuple[str, int]] = dataclasses.field(default_factory=list)  # (function, kernels)


def summarize(events: dict[str, tuple[float, int]], instructions: dict[str, Instruction], text: str) -> KernelProfile:
    leaf = {k: v for k, v in events.items()
            if (ins := instructions.get(k)) is None or ins.opcode not in _CONTAINERS}
    busy = sum(t for t, _ in leaf.values()) or 1e-30
    by_kind = collections.Counter()
    for k, (t, _) in leaf.items():
        by_kind[kind_of(instructions.get(k))] += t
    top = sorted(leaf.items(), key=lambda kv: -kv[1][0])[:5]
    tail = lambda k: "/".join(instructions[k].op_name.split("/")[-2:]) if k in instructions else "?"  # noqa: E731
    kernels = len(_kernel_lines(text))
    return KernelProfile(
        instructions_run=sum(c for _, c in leaf.values()), busy_s=busy,
        by_kind=[(k, t / busy) for k, t in by_kind.most_common()],
        top=[(k, tail(k), t / busy, c) for k, (t, c) in top], kernels_compiled=kernels,
        kernel_sources=kernel_sources(text))


def _describe(p: KernelProfile, seconds: float) -> str:
    kinds = ", ".join(f"{k} {s:.0%}" for k, s in p.by_kind[:5] if s >= 0.01)
    top = "; ".join(f"`{k}` ({op}) {s:.0%}, {c}×" for k, op, s, c in p.top)
    per = seconds / max(p.instructions_run, 1)
    named = [(f, n) for f, n in p.kernel_sources if f != "other"][:5]
    sources = (f" (the most from {', '.join(f'`{f}` {n}' for f, n in named)})" if named else "")
    return (f"{p.instructions_run} XLA instructions run per call ({format_seconds(per)} of wall time each); "
            f"{p.kernels_compiled} kernels compiled{sources}; time by kind: {kinds}; most expensive: {top}")


# --- the kernels ---------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Kernel:
    """A profiled kernel: ``build(config) -> (fn, args, chars_per_call)`` (``fn`` is jitted here), the target it
    misses (section and line) and the cause read from its profile."""

    name: str
    dtype: str
    batch: int
    target: str
    build: Callable[[Any, int], tuple[Callable, tuple, int]]
    cause: str


def _fk(config, batch, dtype="float64"):
    from jaxanim import forward_kinematics

    from .fk import CLIP, Problem, _cast

    problem = Problem(config.data_file(CLIP), batch)
    skel = _cast(problem.skeleton, dtype)
    return jax.vmap(lambda q, t: forward_kinematics(skel, q, t)), problem.jax_inputs(dtype, batch), batch


def _fk32(config, batch):
    return _fk(config, batch, "float32")


def _jacobian(config, batch):
    from jaxanim import jacobian

    from .fk import CLIP, JACOBIAN_SITES, Problem

    problem = Problem(config.data_file(CLIP), batch)
    skel = problem.skeleton
    return (jax.vmap(lambda q, t: jacobian(skel, q, t, JACOBIAN_SITES)), problem.jax_inputs("float64", batch),
            batch)


def _retarget(config, batch):
    from jaxanim import retargeting, robots

    from .retarget import RetargetSizes, clip_problems

    path = config.data_file("robots/unitree_g1/g1.xml")
    if isinstance(path, str):
        raise FileNotFoundError(path)
    robot, sz = robots.load_robot(path), RetargetSizes()
    speeds = tuple(float(x) for x in jnp.linspace(*sz.speed_range, batch))
    problems = retargeting.stack_problems(clip_problems(robot, speeds, sz.frames))
    return jax.vmap(lambda p: retargeting.solve_retarget(robot, p).qpos), (problems,), batch * sz.frames


def _ik(config, batch):
    import solvers

    from . import ik

    skel = ik.load_skeleton(config)
    ps = ik.draw_problems(skel, batch)
    solver = solvers.LevenbergMarquardt(**ik._tol(jnp.float64), max_steps=ik.MAX_STEPS, fixed_steps=False)
    kw = ik._ik(solver, ps)
    solve = kw.pop("solve")
    return (jax.vmap(lambda tg, q, t: solve(skel, tg, q, t, **kw)), (ps.targets(jnp.float64), *ps.start(jnp.float64)),
            batch)


def _optimistix_ik(config, batch):
    import optimistix as optx

    import solvers

    from . import ik

    skel = ik.load_skeleton(config)
    ps = ik.draw_problems(skel, batch)
    kw = ik._ik(solvers.OptimistixSolver(optx.LevenbergMarquardt(**ik._tol(jnp.float64)), max_steps=ik.MAX_STEPS), ps)
    solve = kw.pop("solve")
    return (jax.vmap(lambda tg, q, t: solve(skel, tg, q, t, **kw)), (ps.targets(jnp.float64), *ps.start(jnp.float64)),
            batch)


def _unicycle(config, batch):
    import solvers
    from solvers import problems

    from .oc import UNICYCLE_MAX_STEPS, UNICYCLE_X0

    prob = problems.unicycle(T=200, dtype=jnp.float64)
    fn = lambda x0, us, args: solvers.ilqr(prob.dynamics, prob.cost, x0, us, terminal_cost=prob.terminal_cost,  # noqa
                                           args=args, max_steps=UNICYCLE_MAX_STEPS)
    return fn, (jnp.asarray(UNICYCLE_X0, jnp.float64), prob.us_init, prob.args), 1


def _swing(name, max_steps=None):
    def build(config, batch):
        from . import oc

        prob = oc.swing_problem(name)
        steps = oc.SWING_MAX_STEPS[name] if max_steps is None else max_steps
        solve = oc._solve(prob, "ilqr", max_steps=steps, atol=oc.SWING_STOP, rtol=0.0)
        us = jnp.broadcast_to(prob.us_init, (batch,) + prob.us_init.shape)
        return (jax.vmap(solve, in_axes=(0, 0, None)), (jnp.asarray(oc.initial_states(name, batch)), us, prob.args),
                batch)

    return build


def _dare(config, batch):
    import solvers

    from .oc import make_dare_systems

    return jax.vmap(solvers.dare), tuple(jnp.asarray(z) for z in make_dare_systems(batch)), batch


def _physics(model):
    def build(config, batch):
        from jaxanim import physics

        from .physics import DT, PhysicsSizes, standing_character

        ch = standing_character(config.data_dir, model)
        n = PhysicsSizes.steps_per_call

        def one(s, args):
            r = physics.rollout(ch.char.model, s, DT, n, record_every=n, controller=ch.controller,
                                controller_args=args)
            return r.final.position, r.result

        return jax.vmap(one, in_axes=(0, None)), (ch.batch_states(batch), ch.gains), batch * n

    return build


#: Windows of the profiled SAMCON call, at the 4 s walk's 256 samples (the tracking table's rows run 10 windows of
#: 256 and 1,024: the trace of every event of 2 windows at 1,024 did not fit in 23 GB of memory) and frames of the
#: profiled linearization (the walk table's runs 120).
SEARCH_PROFILED_WINDOWS = 1
GAINS_PROFILED_FRAMES = 9  # three windows of three frames


def _samcon_search(config, batch):
    from .tracking import _options, _search, steps_per_sample, walk_problem

    W = SEARCH_PROFILED_WINDOWS
    char, ref = walk_problem(W * 3 + 1)
    opts = _options(char, ref, batch)

    def search(key):
        res = _search(char, ref, key, opts, W)
        return res.corrections, res.joint_error

    return search, (jax.random.PRNGKey(0),), W * batch * steps_per_sample(opts)


def _linearize(config, batch):
    from jaxanim import tracking
    from jaxanim.tracking import _feedback

    from .tracking import TrackingSizes, _options, walk_problem

    char, ref = walk_problem(GAINS_PROFILED_FRAMES + 1)
    opts = _options(char, ref, TrackingSizes().walk_samples)  # the walk table's options
    windows = tracking.windows_of(ref, opts)
    corrections = jnp.zeros((windows, char.model.joints.num_joints, 3), jnp.float64)
    return (lambda c, states: _feedback._linearize(char, ref, opts, c, states)), (corrections, ref.states), \
        GAINS_PROFILED_FRAMES


KERNELS: tuple[Kernel, ...] = (
    Kernel("FK (quaternions)", "float64", 4096, "fk: FK ≥ 1.8x the Pinocchio loop (float64)", _fk,
           "Per-level products of [B, n, 3, 3] blocks whose minor dimension is 3: XLA:CPU runs each fusion as a "
           "scalar loop over the batch with strided 3-element rows (no vector lanes), and most of the time is "
           "data movement (the split / concatenate of every level's parents and the reorder in and out of level "
           "order: the data-movement share above). The memory floor row of the fk section shows that reading and "
           "writing the data once costs a small fraction of FK. A batch-minor formulation measured slower on this "
           "CPU, most of its time in the transposes in and out."),
    Kernel("FK (quaternions)", "float32", 4096, "fk: FK ≥ 2.5x the Pinocchio loop (float32)", _fk32,
           "The same program in float32: the kernels are the same scalar loops, so halving the bytes saves only "
           "the data-movement share."),
    Kernel("Jacobian of 5 sites", "float64", 1024, "jacobian: ≥ 3x Pinocchio", _jacobian,
           "FK plus the [5, 6, 96] columns (cross products of every joint axis with every site offset, "
           "[B, 5, 31, 3] elementwise fusions); most of the time is data movement: the concatenate that assembles "
           "the output columns, and FK's own split / concatenate before it (the top instructions above)."),
    Kernel("IK LM (adaptive)", "float64", 1024, "ik: own LM ≥ 10x Pinocchio CLIK; IK compile ≤ 5 s", _ik,
           "One LM iteration is FK + Jacobian + a 30x30 Cholesky per problem: hundreds of XLA instructions per "
           "iteration on 128-problem lanes, each a small kernel; the Cholesky and triangular solves are LAPACK "
           "calls per problem. Compile time is the LLVM build of every kernel: the program has the residual and "
           "Jacobian once (the loop's first iteration is the initial linearization), the final check once, and "
           "the lanes' bookkeeping."),
    Kernel("IK optimistix LM", "float64", 1024, "ik: the optimistix backend within 3x of own LM", _optimistix_ik,
           "optimistix's LevenbergMarquardt computes each damped step as the least-squares solution of the stacked "
           "[J; sqrt(lambda) I] (126 x 96) by lineax's dense QR (the geqrf / ormqr library calls above), where own "
           "LM solves the 30 x 30 system J D^-1 J' + lambda I by Cholesky (fewer residuals than variables). "
           "Isolated, per problem, that QR costs several times a normal-equation Cholesky of the 96 unknowns, which "
           "costs several times the 30 x 30 Cholesky. It also takes more iterations (its first step only evaluates "
           "the start; its trust region rejects more steps). `linear_solver=lineax.Normal(lineax.Cholesky())`, "
           "which a user may pass, measured only a little faster (it forms the damping block as a dense 96 x 96 "
           "product)."),
    Kernel("retarget onto the G1 (per frame)", "float64", 32, "retarget: ≥ 5x mink's frames per second on 32 clips",
           _retarget,
           "Each Levenberg-Marquardt iteration linearizes every frame (the robot's kinematics, the Jacobians of the "
           "targets and foot points, a dense J'J per frame: the `mi,mj->ij` product, over the rows that can carry "
           "weight: a foot's matching and planting rows are one set, and a target without an orientation weight has "
           "no orientation rows) and then runs the banded solve, a scan over pairs of frames, sequential in time, "
           "whose every step inverts a block of twice the robot's dofs for each clip by halves, and those halves by "
           "halves again (Cholesky factorizations and triangular inverses only at the smallest blocks, looped over "
           "the batch, and small products), at a fraction of the CPU's peak because the blocks are small; the solve "
           "costs somewhat more than the linearization. Under `vmap` the clips run in chunks of `RETARGET_LANES` "
           "(`jaxanim/retargeting/_solve.py`), each chunk until all of its clips have converged; the iterations "
           "are few and alike across clips since the normal equations carry the positive second-order diagonal (no "
           "rejected steps on these clips). The last iterations of a clip converge linearly along its arms' wrist "
           "pitch and elbow, which its matched points barely determine; exact Newton steps there were tried and were "
           "indefinite at their first use, and steps that ignore the coupling between frames, or reuse an earlier "
           "factorization, took more iterations than they saved. mink does per frame a few QPs of the dofs' size in "
           "C; the whole-clip solve does more arithmetic per frame for what the per-frame solve cannot give (planted "
           "feet, smoothness over the clip), so on two cores it trails the issue's target."),
    Kernel("iLQR unicycle, T = 200", "float64", 1, "oc: one unicycle solve ≤ 1.5x Crocoddyl", _unicycle,
           "Per iteration three scans over 200 knots (backward pass, adjoint gradient, line-search rollout), each "
           "knot tens of XLA instructions on 2- and 3-vectors: a call runs tens of thousands of instructions of "
           "tens of nanoseconds each (the counts above), where Crocoddyl runs straight C++; the time is the "
           "per-instruction cost of the XLA:CPU runtime, not arithmetic (unrolling the scans did not help: the "
           "same run time for a longer compile)."),
    Kernel("iLQR pendulum swing-up", "float64", 1024, "oc: batched DDP ≥ 10x Crocoddyl (pendulum)",
           _swing("pendulum"),
           "The backward and forward scans over the horizon on [lanes, 2] states: each knot is a handful of "
           "kernels over 128 lanes of 2-vectors, so launch overhead, not arithmetic, sets the time."),
    Kernel("iLQR cart-pole swing-up", "float64", 1024, "oc: batched DDP ≥ 10x Crocoddyl (cart-pole)",
           _swing("cart_pole", CART_POLE_PROFILED_STEPS),
           f"As the pendulum's, with 4-vector states, and hundreds of iterations per problem (the profile runs the first "
           f"{CART_POLE_PROFILED_STEPS}: a trace of all of them does not fit in memory)."),
    Kernel("DARE 12x4", "float64", 1024, "oc-dare: ≥ 50x the scipy loop", _dare,
           "Each doubling step is one 12x12 solve with 24 right-hand sides and seven batched 12x12 products on "
           "the lanes' systems. The solve is Gauss-Jordan with partial pivoting (`solvers._linalg.solve`; "
           "LAPACK's getrf / trsm per system took three times as long): per pivot a row exchange (the gathers "
           "above) and one elimination (the selects), a kernel pair run once per pivot on all lanes. The products "
           "are XLA:CPU's batched dots. No kernel dominates; what is left is the runtime's cost per small kernel "
           "and the gathers' per-element indexing, which an element-by-element form with the batch last made "
           "worse (the fused selects ran several times slower than these gathers; see `solvers/_linalg.py`)."),
    Kernel("rollout (penalty)", "float64", 1024, "physics: penalty ≤ 0.5x MuJoCo C", _physics("penalty"),
           "Every step eliminates the joint-constrained system level by level of the body tree (6x6 articulated "
           "inertias folded into the parents, then back-substitution), then the contact forces of every contact "
           "point: hundreds of small fusions per step on [bodies, 6, 6] blocks, none dominant (see the top "
           "shares), so the step is bound by the number of kernels and their strided 6-wide rows. A batch of "
           "1024 runs in chunks of 64 characters (`physics._rollout.ROLLOUT_LANES`: the whole batch's blocks "
           "streamed from memory), so every kernel runs 16 times per step on 64 characters each."),
    Kernel("rollout (complementarity:8)", "float64", 1024, "physics: complementarity:8 ≤ 1x MuJoCo C",
           _physics("complementarity:8"),
           "On top of the tree solve (the penalty row's cause), the contact rows are solved by projected "
           "Gauss-Seidel, a fixed number of sweeps every step, point after point (sequential by nature): each "
           "point's update is a handful of kernels (its rows' product, divides, the write into the impulses), each "
           "on one chunk's 64 characters: the most frequent instructions above. They are not most of the time, "
           "though: measured with a single sweep the step is still well over the penalty step's time, and nearly "
           "as much with two points as with eight, so most of the gap is a fixed cost of the contact path. "
           "Its 24 rows' Delassus matrix is formed along the rows' chains of ancestors "
           "(`jaxanim/physics/_rows_solve.py`: the per-body blocks gathered for each point's chain, a product "
           "per depth, then the rows' products at the shared bodies), their right-hand side is summed along the "
           "same chains after one leaves-to-roots pass, and the velocities take one roots-to-leaves pass with the "
           "impulses carried up the chains; carrying the rows as 24 more columns through every level of the tree "
           "solve cost more (measured, in the bound's comment there). Each of these is a few small kernels on "
           "one chunk. Wider chunks spread "
           "every kernel over more characters but stream the tree solve's blocks from memory (measured slower: "
           "the chunk constant's comment in `jaxanim/physics/_rollout.py`)."),
    Kernel(f"SAMCON search, {SEARCH_PROFILED_WINDOWS} window", "float64", 256,
           "tracking: SAMCON search per character-step ≤ 1.5x the plain step (issue 32)", _samcon_search,
           "Each sample's physics step solves the joint tree and the contact rows once, on the whole batch, and "
           "again in the torque-limit passes only where a joint exceeds its bound (`solvers.repeat_while`: those "
           "samples alone, on narrow lanes). The time is spread thin: no instruction takes more than a few percent, "
           "the largest being the elites' `top_k` sort, the slices and scatters of the Gauss-Seidel sweeps (one per "
           "contact point and sweep) and the copies between small kernels (the data-movement fusions). Each of the "
           "instructions counted above costs microseconds: the per-instruction cost of the XLA:CPU runtime on "
           "small arrays, not arithmetic, sets the time. Wider lanes spread it over more samples but leave more "
           "lanes idle (measured, in the lanes constant's comment in `jaxanim/physics/_step.py`)"),
    Kernel(f"feedback gains: linearize, {GAINS_PROFILED_FRAMES} frames", "float64", 1,
           "tracking-walk: feedback gains ≤ 50 ms per frame; compiling the search and the gains ≤ 15 s (issue 32)",
           _linearize, "`jax.jacfwd` carries every body-state and control tangent through each frame's physics steps "
           "(`python -m benchmarks tracking` gives their number). Each step's solve of the contact and joint-limit "
           "rows has a custom JVP (`jaxanim/physics/_rows_solve.py`): the tangent of their Delassus matrix is a "
           "few products of the rows' tree-solve columns with every tangent (the `jku,jkv->uv` and `biu,bij,bjv->uv` "
           "dots and the transposes that feed them), the Gauss-Seidel sweeps are differentiated forward point by "
           "point (the `in,n->i` dot, the update of every tangent's impulses and the slice of the matrix's tangent "
           "at each point: one small instruction each, per point and sweep), and the velocities' tangent is one "
           "substitution through the joint factors; the torque-limit passes (the `branch_1_fun` instructions: the "
           "pass branch, taken where a joint exceeds its bound) do it again. The gains need this derivative of the "
           "plant's own fixed sweeps: an implicit derivative at the converged contact solution and one that holds "
           "the Delassus matrix fixed were cheaper but gave gains that did not hold the acceptance push (issue 32's "
           "notes). Compile time is the LLVM build of the kernels counted above, for the search's program and this "
           "one apart"),
)


def run_profile(config) -> list[Table]:
    """The ``profile`` benchmark (see the module docstring)."""
    table = Table("profile", "Profiles of the kernels behind the speed targets",
                  accuracy_label="XLA instructions run / call", description=(
                      "Each kernel is compiled once, timed like the other sections, then run "
                      f"{PROFILED_CALLS} times under `jax.profiler.trace`. The trace's XLA:CPU events are matched "
                      "to the compiled HLO by instruction name, and their time is summed per kind (while loops "
                      "excluded: their bodies count themselves). The notes give the instructions run per call, "
                      "the kernels compiled, the time by kind and the five most expensive instructions, then the "
                      "cause read from them. The profiler slows every call: compare shares, not times, with "
                      "the other sections."))
    for k in KERNELS:
        batch = 8 if config.quick and k.batch > 1 else k.batch
        if not config.selects(k.name):
            continue
        if spent := budget_spent(config):
            table.rows.append(Row(k.name, k.dtype, batch, skipped=spent))
            continue
        config.log(f"profile: {k.name} ({k.dtype}, batch {batch})")
        try:
            fn, args, chars = k.build(config, batch)
            cs = compile_time(jax.jit(fn), *args)
            jax.block_until_ready(cs.compiled(*args))
            tm = sample_call(config, cs.compiled, args, 0.0)
            instructions = hlo_instructions(cs.compiled.as_text())
            p = summarize(profile_events(cs.compiled, args, names=instructions), instructions, cs.compiled.as_text())
        except Exception as exc:  # noqa: BLE001 - one kernel's failure is a row, not the end of the report
            table.rows.append(Row(k.name, k.dtype, batch, skipped=f"failed: {type(exc).__name__}: "
                                  f"{(str(exc).splitlines() or [''])[0][:200]}"))
            continue
        table.rows.append(Row(k.name, k.dtype, batch, tm.median, tm.min, chars, cs.total,
                              accuracy=str(p.instructions_run), samples=tm.samples,
                              note=f"target: {k.target}. Profile: {_describe(p, tm.median)}. **Cause**: {k.cause}",
                              extra=dict(profile=p)))
    return [table]

