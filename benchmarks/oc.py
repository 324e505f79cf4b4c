"""Optimal-control benchmark (``python -m benchmarks oc``): iLQR / DDP / LQR / DARE vs Crocoddyl and scipy.

Five tables, all float64 (Crocoddyl and scipy are float64 only):

1. **Unicycle, T = 200, one solve** (:func:`solvers.problems.unicycle`, exactly Crocoddyl's
   ``ActionModelUnicycle``; ``x0 = (-1, -1, 1)``, weights 10 / 1, ``dt = 0.1``): ``solvers.ilqr`` and
   ``solvers.ddp`` (unbounded, and box-DDP with :data:`UNICYCLE_BOUNDS`, which are active) against
   Crocoddyl's ``SolverDDP``, ``SolverFDDP`` (unbounded) and ``SolverBoxDDP`` (same bounds), plus
   ``SolverDDP`` on the same model written as a Python action model, to show what Python callbacks
   cost Crocoddyl (the swing-up peers are Python models). Accuracy: relative difference of the final
   cost to Crocoddyl ``SolverDDP``'s (box rows: ``SolverBoxDDP``'s).
2. **LQ problem, 37 states x 12 inputs, T = 100** (:func:`make_lq`, seeded, time-invariant, with
   cross term, affine cost and drift): ``solvers.lqr`` (exact), ``solvers.ilqr`` / ``solvers.ddp``
   (one iteration plus the confirming one) against Crocoddyl ``ActionModelLQR`` with the same
   matrices. Accuracy: relative cost difference and max ``|u - u_lqr|`` against ``solvers.lqr``.
3. **DARE, 12 x 4** (:func:`make_dare_systems`, 10^4 seeded stabilisable systems):
   ``scipy.linalg.solve_discrete_are`` in a Python loop over a capped subset against
   ``jax.jit(jax.vmap(solvers.dare))`` at batches 1, 64, 1024, 10^4. Accuracy: max relative
   difference of ``P`` to scipy's on the systems both solved, and max relative Riccati residual
   ``max|F(P)| / max|P|`` (numpy, float64) over the batch.
4. **Swing-ups** (pendulum, T = 100; cart-pole, T = 100; :func:`initial_states`, seeded random
   starts near hanging): ``jax.jit(jax.vmap(ilqr / ddp))``, adaptive (``lax.while_loop``) and
   ``fixed_steps=True``, at batches 1, 64, 1024, against a Python loop of Crocoddyl ``SolverDDP`` /
   ``SolverFDDP`` on Python action models with the same dynamics and cost
   (:mod:`benchmarks.peers.crocoddyl_oc`), timed on the first problems within the row budget.
   Success: solver status successful (Crocoddyl: ``solve`` returned ``True``) **and** the final
   angle within :data:`UPRIGHT_TOLERANCE` of upright. Accuracy: of the problems both jaxanim and
   Crocoddyl ``SolverDDP`` solved, the fraction whose final costs agree to 1e-6 relative (the same
   local optimum is not guaranteed).
5. **Compile times** of every jitted jaxanim function above (``lower`` + ``compile``), apart from
   the run times (which never include them).

Targets (benchmark targets, not tests; the notes say met / missed with the numbers): batched DDP on
1024 swing-ups >= 20x the throughput of the Crocoddyl loop; one unicycle solve within 2x of
Crocoddyl; batched DARE >= 20x the scipy loop; iLQR / DDP compile <= 5 s.

Time budget (full mode): a jaxanim row is not run at a batch where its per-problem time at the
previous batch predicts a call longer than ``4 x max_row_s``; calls longer than a second are timed
on as many calls as fit in ``max_row_s`` (at least the first call after compilation); Python loops
(Crocoddyl, scipy) stop after ``max_row_s`` seconds or ``loop_cap`` problems. Crocoddyl single
solves are timed one call per sample (at least 15) and the notes give the spread: on this machine
its times were bimodal (~1 ms or ~150 ms for the same unicycle solve; see
:mod:`benchmarks.peers.crocoddyl_oc`), so targets are judged on its fast mode (the fastest sample;
for the swing-up loops, the fastest decile of time per iteration times the mean iterations).
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from . import BenchConfig
from .peers import PeerUnavailable
from .report import Row, Table, format_seconds, measure_row
from .timing import CompileStats, compile_time, load_note
from .timing import sample_call as _sample

__all__ = [
    "DARE_BATCHES",
    "OCSizes",
    "SWING_BATCHES",
    "UNICYCLE_BOUNDS",
    "UPRIGHT_TOLERANCE",
    "initial_states",
    "make_dare_systems",
    "make_lq",
    "riccati_residual",
    "run_oc",
]

SEED = 0
UNICYCLE_X0 = (-1.0, -1.0, 1.0)
UNICYCLE_BOUNDS = ((-2.0, -1.5), (2.0, 1.5))  # (u_min, u_max): speed, turn rate; the optimum leaves it
SWING_BATCHES = (1, 64, 1024)
DARE_BATCHES = (1, 64, 1024, 10_000)
SWING_MAX_STEPS = {"pendulum": 100, "cart_pole": 300}
ANGLE_INDEX = {"pendulum": 0, "cart_pole": 1}
UPRIGHT_TOLERANCE = 0.1  # rad: success needs |theta_T - pi| below this
AGREE_RTOL = 1e-6  # swing-up final costs "agree" below this relative difference
UNICYCLE_MAX_STEPS = 500  # both sides (box-DDP needs more than 100 here)
CROCODDYL_TH_STOP = 1e-9  # Crocoddyl's default stopping threshold, stated for the notes
_CALL_BUDGET_FACTOR = 4.0
_CROC = "Crocoddyl"
_SCIPY = "scipy solve_discrete_are (loop)"


@dataclasses.dataclass(frozen=True)
class OCSizes:
    """Problem sizes; the defaults are the issue's (tests shrink them).

    Attributes:
        unicycle_T: unicycle horizon.
        lqr_n, lqr_m, lqr_T: LQ problem state / input dimensions and horizon.
        lqr_methods: the iterative solvers also run on the LQ problem (``"ilqr"``, ``"ddp"``).
        dare_n, dare_m: DARE system dimensions.
        dare_batches: jaxanim DARE batch sizes (``config.batches`` overrides them).
        dare_scipy_cap: the most systems the scipy loop solves per timed pass.
        swing_problems: which swing-ups to run (``"pendulum"``, ``"cart_pole"``).
        swing_batches: jaxanim swing-up batch sizes (``config.batches`` overrides them).
        swing_methods: ``"ilqr"`` and / or ``"ddp"``.
        swing_fixed: also run the ``fixed_steps=True`` rows.
        swing_T: swing-up horizon (``None``: the problems' defaults, 100).
    """

    unicycle_T: int = 200
    lqr_n: int = 37
    lqr_m: int = 12
    lqr_T: int = 100
    lqr_methods: tuple[str, ...] = ("ilqr", "ddp")
    dare_n: int = 12
    dare_m: int = 4
    dare_batches: tuple[int, ...] = DARE_BATCHES
    dare_scipy_cap: int = 512
    swing_problems: tuple[str, ...] = ("pendulum", "cart_pole")
    swing_batches: tuple[int, ...] = SWING_BATCHES
    swing_methods: tuple[str, ...] = ("ilqr", "ddp")
    swing_fixed: bool = True
    swing_T: int | None = None


# --- problems -----------------------------------------------------------------------------------------
def make_lq(n: int = 37, m: int = 12, T: int = 100, seed: int = SEED) -> dict[str, np.ndarray]:
    """A seeded time-invariant LQ problem, float64 numpy, in Crocoddyl's ``ActionModelLQR`` terms.

    ``A`` is Gaussian scaled to spectral radius 1.02 (mildly unstable), ``B`` Gaussian / sqrt(n); the
    joint cost matrix ``[[Q, N], [N', R]] = L L' + 0.1 I`` (positive definite, as Crocoddyl requires),
    ``q, r`` standard normal, drift ``f`` N(0, 0.1^2), ``x0`` standard normal. Cost per knot
    ``0.5 x'Qx + 0.5 u'Ru + x'N u + q'x + r'u``, terminal ``0.5 x'Qx + q'x``, dynamics
    ``x+ = A x + B u + f``; for :func:`solvers.lqr`: ``S = N'``, ``QT = Q``, ``qT = q``, ``c = f``.
    """
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n)) / np.sqrt(n)
    A *= 1.02 / np.abs(np.linalg.eigvals(A)).max()
    B = rng.normal(size=(n, m)) / np.sqrt(n)
    L = rng.normal(size=(n + m, n + m)) / np.sqrt(n + m)
    W = L @ L.T + 0.1 * np.eye(n + m)
    return dict(A=A, B=B, Q=W[:n, :n], N=W[:n, n:], R=W[n:, n:], f=0.1 * rng.normal(size=n),
                q=rng.normal(size=n), r=rng.normal(size=m), x0=rng.normal(size=n), T=T)


def _lq_problem(d: dict[str, np.ndarray]):
    from solvers.problems import LQProblem

    T = d["T"]
    tile = lambda z: jnp.asarray(np.broadcast_to(z, (T,) + z.shape), jnp.float64)  # noqa: E731
    return LQProblem(
        A=tile(d["A"]), B=tile(d["B"]), Q=tile(d["Q"]), R=tile(d["R"]), QT=jnp.asarray(d["Q"]),
        x0=jnp.asarray(d["x0"]), S=tile(d["N"].T), q=tile(d["q"]), r=tile(d["r"]), qT=jnp.asarray(d["q"]),
        c=tile(d["f"]), constant=jnp.zeros((), jnp.float64),
    )


def make_dare_systems(count: int, n: int = 12, m: int = 4, seed: int = SEED) -> tuple[np.ndarray, ...]:
    """``count`` seeded stabilisable DARE problems ``(A, B, Q, R)``, float64 numpy, leading batch axis.

    ``A`` Gaussian scaled to spectral radius 1.1 (unstable), ``B`` Gaussian (``(A, B)`` is then
    controllable with probability 1), ``Q = G G' + 1e-3 I``, ``R = H H' + I`` with Gaussian ``G, H``
    scaled by 1/sqrt(dim).
    """
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(count, n, n)) / np.sqrt(n)
    A *= (1.1 / np.abs(np.linalg.eigvals(A)).max(axis=-1))[:, None, None]
    B = rng.normal(size=(count, n, m))
    G = rng.normal(size=(count, n, n)) / np.sqrt(n)
    H = rng.normal(size=(count, m, m)) / np.sqrt(m)
    Q = G @ G.transpose(0, 2, 1) + 1e-3 * np.eye(n)
    R = H @ H.transpose(0, 2, 1) + np.eye(m)
    return A, B, Q, R


def riccati_residual(A, B, Q, R, P) -> np.ndarray:
    """``max|A'PA - P - A'PB (R + B'PB)^{-1} B'PA + Q| / max|P|`` per system (float64 numpy, batched)."""
    A, B, Q, R, P = (np.asarray(z, np.float64) for z in (A, B, Q, R, P))
    At = np.swapaxes(A, -1, -2)
    BP = np.swapaxes(B, -1, -2) @ P
    N = BP @ A
    F = At @ P @ A - P - np.swapaxes(N, -1, -2) @ np.linalg.solve(R + BP @ B, N) + Q
    return np.abs(F).max(axis=(-2, -1)) / np.abs(P).max(axis=(-2, -1))


def initial_states(name: str, count: int, seed: int = SEED) -> np.ndarray:
    """``[count, n]`` seeded random swing-up starts near hanging (float64 numpy).

    Pendulum: angle uniform in ±pi/4 of hanging (0), rate uniform in ±0.5 rad/s. Cart-pole: cart
    position uniform in ±0.2 m, pole angle in ±0.3 rad of hanging, both rates in ±0.2.
    """
    rng = np.random.default_rng(seed)
    if name == "pendulum":
        return np.stack([rng.uniform(-np.pi / 4, np.pi / 4, count), rng.uniform(-0.5, 0.5, count)], axis=-1)
    if name == "cart_pole":
        lim = np.array([0.2, 0.3, 0.2, 0.2])
        return rng.uniform(-1.0, 1.0, size=(count, 4)) * lim
    raise ValueError(f"name: expected 'pendulum' or 'cart_pole', got {name!r}")


def _swing_problem(name: str, T: int | None):
    from solvers import problems

    make = getattr(problems, name)
    return make() if T is None else make(T=T)


# --- shared row machinery -----------------------------------------------------------------------------
@dataclasses.dataclass
class _Context:
    config: BenchConfig
    sizes: OCSizes
    compiles: list[tuple[str, str, int, CompileStats]] = dataclasses.field(default_factory=list)
    records: dict = dataclasses.field(default_factory=dict)  # (table, impl, batch) -> dict of figures


def _success_mask(result) -> np.ndarray:
    import solvers

    return np.asarray(result._value == solvers.RESULTS.successful._value)


def _status_counts(result) -> str:
    import solvers

    v = np.asarray(result._value)
    parts = [f"{name} {int(np.sum(v == item._value))}" for name, item in solvers.RESULTS._name_to_item.items()
             if name != "successful" and np.any(v == item._value)]
    return ", ".join(parts)


def _jax_call(ctx: _Context, table: str, impl: str, batch: int, jitted: Callable, args: tuple):
    """Compile ``jitted`` ahead of time (recorded for the compile table), call it once, time it.

    Returns ``(first output, timing, compile stats)``.
    """
    cs = compile_time(jitted, *args)
    ctx.compiles.append((table, impl, batch, cs))
    t0 = time.perf_counter()
    out = jax.block_until_ready(cs.compiled(*args))
    first = time.perf_counter() - t0
    tm = _sample(ctx.config, cs.compiled, args, first)
    return out, tm, cs


def _time_python(config: BenchConfig, fn: Callable[[], Any]):
    """Call ``fn()`` once (its value is returned) and time it like a jitted call."""
    t0 = time.perf_counter()
    out = fn()
    first = time.perf_counter() - t0
    return out, _sample(config, fn, (), first)


def _log_row(config: BenchConfig, table: str, row: Row) -> None:
    if row.skipped is not None:
        config.log(f"oc {table} B={row.batch}: {row.implementation}: {row.skipped}")
        return
    comp = "" if row.compile_s is None else f", compile {row.compile_s:.2f} s"
    succ = "" if row.success is None else f", success {100 * row.success:.1f} %"
    config.log(f"oc {table} B={row.batch}: {row.implementation}: {row.us_per_char:.4g} µs/problem{comp}{succ}, "
               f"accuracy {row.accuracy}; {row.note.split(';')[0]}")


def _add_row(config: BenchConfig, table: Table, impl: str, batch: int | None, make_row: Callable[[], Row],
             is_peer: bool, failures: dict) -> Row | None:
    return measure_row(config, table, impl, batch, make_row, is_peer, failures,
                       lambda row: _log_row(config, table.name, row))


def _timing_note(tm) -> str:
    return f"; {tm.samples} timed call{'s' if tm.samples != 1 else ''}" if tm.samples < 3 else ""


def _time_single(config: BenchConfig, fn: Callable[[], Any]):
    """Time a Crocoddyl single solve one call per sample (at least 15 samples within ``max_row_s``),
    so that the spread of the samples shows (see ``crocoddyl_oc``'s docstring). Returns
    ``(first output, _SpreadTiming)``."""
    out = fn()  # warm-up, and the value
    samples: list[float] = []
    for _ in range(max(config.repeats, 15)):
        t0 = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t0)
        if sum(samples) > config.max_row_s and len(samples) >= 3:
            break
    return out, _SpreadTiming(float(np.median(samples)), min(samples), max(samples), len(samples))


@dataclasses.dataclass(frozen=True)
class _SpreadTiming:
    median: float
    min: float
    max: float
    samples: int


def _spread_note(tm: _SpreadTiming) -> str:
    return (f"{tm.samples} single-call samples: min {format_seconds(tm.min)}, median {format_seconds(tm.median)}, "
            f"max {format_seconds(tm.max)}")


def _rel(a: float, b: float) -> float:
    return abs(a - b) / max(abs(b), 1e-300)


# --- 1. unicycle --------------------------------------------------------------------------------------
def _unicycle_table(ctx: _Context) -> Table:
    import solvers
    from solvers import problems

    config, T = ctx.config, ctx.sizes.unicycle_T
    table = Table(
        "oc-unicycle", f"Optimal control: unicycle, T = {T}, one solve (Crocoddyl's ActionModelUnicycle)",
        accuracy_label="rel. cost diff vs Crocoddyl (box rows: BoxDDP)",
        description=(
            f"`solvers.problems.unicycle(T={T})` (exactly Crocoddyl's `ActionModelUnicycle`: Euler step "
            f"dt = 0.1, cost 0.5 (10² |x|² + 1² |u|²) per knot, terminal 0.5 · 10² |x_T|²) from "
            f"x0 = {UNICYCLE_X0}, zero initial controls. Box rows: u ∈ [{UNICYCLE_BOUNDS[0][0]}, "
            f"{UNICYCLE_BOUNDS[1][0]}] × [{UNICYCLE_BOUNDS[0][1]}, {UNICYCLE_BOUNDS[1][1]}] (speed, turn rate; "
            "the unbounded optimum leaves this box), jaxanim `bounds=` vs Crocoddyl `u_lb/u_ub` + "
            f"SolverBoxDDP. One problem per call (batch 1), float64; ≤ {UNICYCLE_MAX_STEPS} iterations on both "
            "sides; jaxanim default tolerances (rtol 1e-13 on the expected decrease, atol 1e-12), Crocoddyl "
            f"default th_stop {CROCODDYL_TH_STOP:g}. jaxanim rows are `jax.jit` of one solve, compiled ahead of "
            "time; Crocoddyl rows time `solver.solve(xs0, us0, maxiter, True, 1e-9)` on a built solver, one "
            "call per sample, and give the spread of the samples in the notes (Crocoddyl's times on this machine "
            "were bimodal while this benchmark was written: ~1-2 ms or ~150 ms for the same solve, see "
            "`benchmarks/peers/crocoddyl_oc.py`). Notes: iterations, time per iteration, final cost."
        ),
    )
    lo, hi = (np.asarray(b, np.float64) for b in UNICYCLE_BOUNDS)
    prob = problems.unicycle(T=T, dtype=jnp.float64)
    failures: dict = {}
    ref: dict[bool, float] = {}

    def croc_row(solver: str, boxed: bool, python_model: bool = False) -> Row:
        from .peers import crocoddyl_oc as co

        pb = co.unicycle_problem(T, UNICYCLE_X0, state_weight=10.0, control_weight=1.0, dt=0.1,
                                 bounds=(lo, hi) if boxed else None, python_model=python_model)
        us0 = [np.zeros(2)] * T
        xs0 = pb.rollout(us0)
        s = co.make_solver(pb, solver)
        ok, tm = _time_single(config, lambda: s.solve(xs0, us0, UNICYCLE_MAX_STEPS, True, 1e-9))
        cost, its = float(s.cost), int(s.iter)
        ctx.records[("unicycle-spread", solver + ("-py" if python_model else ""))] = tm
        if not python_model and solver in ("SolverDDP", "SolverBoxDDP"):
            ref.setdefault(boxed, cost)
        acc: float | str = _rel(cost, ref[boxed]) if boxed in ref else "n/a"
        what = "Python action model (same dynamics and cost)" if python_model else "C++ ActionModelUnicycle"
        note = (f"{its} iterations, {format_seconds(tm.median / max(its, 1))} / iteration, cost {cost:.12g}; "
                f"{what}{', bounds' if boxed else ''}; {_spread_note(tm)}")
        ctx.records[("unicycle", f"{solver}{'-py' if python_model else ''}", boxed)] = dict(t=tm.median, tmin=tm.min,
                                                                                          its=its,
                                                                                          cost=cost)
        return Row(f"{_CROC} {solver}" + (" (Python model)" if python_model else ""), "float64", 1, tm.median,
                   tm.min, 1, None, acc, success=float(ok), is_peer=True, note=note)

    for solver, boxed in (("SolverDDP", False), ("SolverFDDP", False), ("SolverBoxDDP", True)):
        _add_row(config, table, f"{_CROC} {solver}", 1, lambda s=solver, b=boxed: croc_row(s, b), True, failures)
    _add_row(config, table, f"{_CROC} SolverDDP (Python model)", 1, lambda: croc_row("SolverDDP", False, True), True,
             failures)

    def jax_row(method: str, boxed: bool) -> Row:
        fn = getattr(solvers, method)
        bounds = (jnp.asarray(lo), jnp.asarray(hi)) if boxed else None

        def solve(x0, us, args):
            return fn(prob.dynamics, prob.cost, x0, us, terminal_cost=prob.terminal_cost, args=args, bounds=bounds,
                      max_steps=UNICYCLE_MAX_STEPS)

        impl = f"jaxanim {method}" + (" box" if boxed else "")
        out, tm, cs = _jax_call(ctx, "unicycle", impl, 1, jax.jit(solve), (prob.x0, prob.us_init, prob.args))
        cost, its = float(out.cost), int(out.stats["num_steps"])
        if boxed not in ref:  # no Crocoddyl: the first jaxanim row of the kind is the reference
            ref[boxed] = cost
        status = _status_counts(out.result)
        ctx.records[("unicycle", impl, boxed)] = dict(t=tm.median, tmin=tm.min, its=its, cost=cost, compile=cs.total)
        note = (f"{its} iterations, {format_seconds(tm.median / max(its, 1))} / iteration, cost {cost:.12g}; "
                f"solvers.{method}{', bounds' if boxed else ''}, while_loop" + (f"; status {status}" if status else "")
                + _timing_note(tm))
        return Row(impl, "float64", 1, tm.median, tm.min, 1, cs.total, _rel(cost, ref[boxed]),
                   success=float(_success_mask(out.result)), note=note)

    for boxed in (False, True):
        for method in ("ilqr", "ddp"):
            impl = f"jaxanim {method}" + (" box" if boxed else "")
            _add_row(config, table, impl, 1, lambda m=method, b=boxed: jax_row(m, b), False, failures)

    # notes
    r = ctx.records
    croc_ddp = r.get(("unicycle", "SolverDDP", False))
    croc_box = r.get(("unicycle", "SolverBoxDDP", True))
    own = [(k[1], v) for k, v in r.items() if k[0] == "unicycle" and k[1].startswith("jaxanim") and not k[2]]
    own_box = [(k[1], v) for k, v in r.items() if k[0] == "unicycle" and k[1].startswith("jaxanim") and k[2]]
    if croc_ddp and own:
        name, best = min(own, key=lambda kv: kv[1]["tmin"])
        ratio = best["tmin"] / croc_ddp["tmin"]
        line = (f"Target: one unicycle solve within 2x of Crocoddyl (fastest samples, as Crocoddyl's median can sit in "
                f"its slow mode): best jaxanim row ({name}) {format_seconds(best['tmin'])} vs Crocoddyl SolverDDP "
                f"{format_seconds(croc_ddp['tmin'])} = {ratio:.2g}x: {'met' if ratio <= 2 else 'missed'} (medians: "
                f"{format_seconds(best['t'])} vs {format_seconds(croc_ddp['t'])} = {best['t'] / croc_ddp['t']:.2g}x).")
        if croc_box and own_box:
            nb, bb = min(own_box, key=lambda kv: kv[1]["tmin"])
            line += (f" Box: {nb} {format_seconds(bb['tmin'])} vs SolverBoxDDP {format_seconds(croc_box['tmin'])} = "
                     f"{bb['tmin'] / croc_box['tmin']:.2g}x, fastest samples ({bb['its']} vs {croc_box['its']} "
                     "iterations).")
        table.notes.append(line)
    spread = {k[1]: v for k, v in r.items() if k[0] == "unicycle-spread"}
    bimodal = [f"{k} {format_seconds(v.min)}–{format_seconds(v.max)}" for k, v in spread.items() if v.max > 10 * v.min]
    if bimodal:
        table.notes.append(
            "Crocoddyl's single-call samples spread over more than 10x in this run (" + ", ".join(bimodal) + "): its "
            "~100x slow mode on this machine (same iterations and result, CPU-bound, cause unknown; "
            "`benchmarks/peers/crocoddyl_oc.py`). Read its min column, and PEERS.md's figures, as its normal speed."
        )
    py = r.get(("unicycle", "SolverDDP-py", False))
    if croc_ddp and py:
        table.notes.append(
            f"Crocoddyl with the same unicycle as a Python action model takes {format_seconds(py['tmin'])} vs "
            f"{format_seconds(croc_ddp['tmin'])} with the C++ model ({py['tmin'] / croc_ddp['tmin']:.2g}x, fastest "
            "samples): the Python "
            "callbacks (calc / calcDiff per knot, per iteration and line-search trial) dominate; the swing-up "
            "peers below use Python models, so their times carry this overhead."
        )
    return table


# --- 2. LQ problem ------------------------------------------------------------------------------------
def _lqr_table(ctx: _Context) -> Table:
    config, sz = ctx.config, ctx.sizes
    n, m, T = sz.lqr_n, sz.lqr_m, sz.lqr_T
    d = make_lq(n, m, T)
    lq = _lq_problem(d)
    table = Table(
        "oc-lqr", f"Optimal control: LQ problem, {n} states × {m} inputs, T = {T}",
        accuracy_label="rel. cost diff / max |Δu| vs solvers.lqr",
        description=(
            "A seeded time-invariant LQ problem (`benchmarks.oc.make_lq`: A with spectral radius 1.02, cost "
            "0.5 x'Qx + 0.5 u'Ru + x'N u + q'x + r'u with [[Q, N], [N', R]] positive definite, drift f, "
            "terminal 0.5 x'Qx + q'x), the same matrices in Crocoddyl's `ActionModelLQR` (its cost and "
            "dynamics x+ = A x + B u + f were checked term by term). `solvers.lqr` is the exact Riccati "
            "solution; iLQR / DDP take one iteration and confirm convergence with a second; Crocoddyl's "
            "solvers stop after one. float64, one problem per call."
        ),
    )
    failures: dict = {}
    ref: dict[str, Any] = {}

    def lqr_row() -> Row:
        out, tm, cs = _jax_call(ctx, "lqr", "jaxanim lqr", 1, jax.jit(lambda p: p.solve()), (lq,))
        ref["cost"], ref["us"] = float(out.cost), np.asarray(out.us)
        ctx.records[("lqr", "jaxanim lqr")] = dict(t=tm.median)
        return Row("jaxanim lqr", "float64", 1, tm.median, tm.min, 1, cs.total, "reference",
                   success=float(_success_mask(out.result)),
                   note=f"cost {ref['cost']:.12g}; solvers.lqr (backward Riccati scan + forward rollout)"
                   + _timing_note(tm))

    _add_row(config, table, "jaxanim lqr", 1, lqr_row, False, failures)
    if not ref:  # filtered out or failed: the reference is still needed
        sol = lq.solve()
        ref["cost"], ref["us"] = float(sol.cost), np.asarray(sol.us)

    def acc(cost: float, us) -> str:
        return f"{_rel(cost, ref['cost']):.1e} / {np.abs(np.asarray(us) - ref['us']).max():.1e}"

    cp = lq.as_control_problem()
    for method in sz.lqr_methods:
        def jrow(method=method) -> Row:
            out, tm, cs = _jax_call(ctx, "lqr", f"jaxanim {method}", 1,
                                    jax.jit(lambda p: p.solve(method, max_steps=10)), (cp,))
            its = int(out.stats["num_steps"])
            return Row(f"jaxanim {method}", "float64", 1, tm.median, tm.min, 1, cs.total, acc(float(out.cost), out.us),
                       success=float(_success_mask(out.result)),
                       note=f"{its} iterations, {format_seconds(tm.median / max(its, 1))} / iteration; "
                       f"solvers.{method} on the problem as callbacks (LQProblem.as_control_problem)"
                       + _timing_note(tm))

        _add_row(config, table, f"jaxanim {method}", 1, jrow, False, failures)

    for solver in ("SolverDDP", "SolverFDDP", "SolverBoxDDP"):
        def crow(solver=solver) -> Row:
            from .peers import crocoddyl_oc as co

            pb = co.lqr_problem(d["A"], d["B"], d["Q"], d["R"], d["N"], d["f"], d["q"], d["r"], d["x0"], T)
            us0 = [np.zeros(m)] * T
            xs0 = pb.rollout(us0)
            s = co.make_solver(pb, solver)
            ok, tm = _time_single(config, lambda: s.solve(xs0, us0, 10, True, 1e-9))
            its = int(s.iter)
            ctx.records[("lqr", solver)] = dict(t=tm.median, cost=float(s.cost))
            return Row(f"{_CROC} {solver}", "float64", 1, tm.median, tm.min, 1, None,
                       acc(float(s.cost), np.array(s.us)),
                       success=float(ok), is_peer=True,
                       note=f"{its} iteration{'s' if its != 1 else ''}; ActionModelLQR (C++); {_spread_note(tm)}")

        _add_row(config, table, f"{_CROC} {solver}", 1, crow, True, failures)
    croc = ctx.records.get(("lqr", "SolverDDP"))
    if croc is not None:
        ok = _rel(croc["cost"], ref["cost"]) <= 1e-9
        table.notes.append(
            f"Cost conventions: Crocoddyl SolverDDP's final cost {croc['cost']:.15g} vs solvers.lqr "
            f"{ref['cost']:.15g} (relative difference {_rel(croc['cost'], ref['cost']):.1e}): "
            f"{'the same problem' if ok else 'MISMATCH (> 1e-9): the problems differ'}."
        )
    return table


# --- 3. DARE ------------------------------------------------------------------------------------------
def _dare_table(ctx: _Context) -> Table:
    import solvers

    config, sz = ctx.config, ctx.sizes
    n, m = sz.dare_n, sz.dare_m
    batches = config.batches_for(sz.dare_batches)
    big = max(batches)
    A, B, Q, R = make_dare_systems(big, n, m)
    cap = min(sz.dare_scipy_cap, config.loop_cap, big)
    table = Table(
        "oc-dare", f"Discrete algebraic Riccati equation, {n} × {m}, batched",
        accuracy_label="max rel ΔP vs scipy / max rel Riccati residual",
        description=(
            f"{big} seeded random systems (`benchmarks.oc.make_dare_systems`: A Gaussian with spectral radius "
            "1.1, B Gaussian, Q = GG' + 1e-3 I, R = HH' + I), float64. jaxanim: `jax.jit(jax.vmap(solvers.dare))` "
            "(structure-preserving doubling, adaptive while_loop) on the first `batch` systems; scipy: "
            "`scipy.linalg.solve_discrete_are` in a Python loop over the first "
            f"{cap} systems (µs / char = per system). ΔP: max over systems of max|P − P_scipy| / max|P_scipy| "
            "on the systems both timed; residual: max over the batch of max|F(P)| / max|P| (numpy float64)."
        ),
    )
    failures: dict = {}
    ref: dict[str, np.ndarray] = {}

    def scipy_row() -> Row:
        try:
            import scipy.linalg as sl
        except ImportError as exc:
            raise PeerUnavailable(f"cannot import scipy: {exc}") from exc
        k = cap
        args = (A[:k], B[:k], Q[:k], R[:k])

        def loop(A, B, Q, R):
            return np.stack([sl.solve_discrete_are(A[i], B[i], Q[i], R[i]) for i in range(A.shape[0])])

        P, tm = _time_python(config, lambda: loop(*args))
        ref["P"] = P
        res = riccati_residual(*args, P)
        ctx.records[("dare", _SCIPY)] = dict(t=tm.median / k)
        return Row(_SCIPY, "float64", big, tm.median, tm.min, k, None, f"reference / {res.max():.1e}",
                   success=float(np.mean(np.isfinite(P).all(axis=(1, 2)))), is_peer=True,
                   note=f"Python loop, timed on {k} of {big} systems (QZ method)" + _timing_note(tm))

    _add_row(config, table, _SCIPY, big, scipy_row, True, failures)

    def jrow(b: int) -> Row:
        args = tuple(jnp.asarray(z[:b]) for z in (A, B, Q, R))
        out, tm, cs = _jax_call(ctx, "dare", "jaxanim dare", b,
                                jax.jit(jax.vmap(lambda A, B, Q, R: solvers.dare(A, B, Q, R))), args)
        P = np.asarray(out.P)
        res = riccati_residual(A[:b], B[:b], Q[:b], R[:b], P)
        if "P" in ref:
            k = min(b, ref["P"].shape[0])
            dP = np.abs(P[:k] - ref["P"][:k]).max(axis=(1, 2)) / np.abs(ref["P"][:k]).max(axis=(1, 2))
            acc = f"{dP.max():.1e} / {res.max():.1e}"
        else:
            acc = f"n/a / {res.max():.1e}"
        steps = np.asarray(out.stats["num_steps"])
        ctx.records[("dare", "jaxanim dare", b)] = dict(t=tm.median / b)
        return Row("jaxanim dare", "float64", b, tm.median, tm.min, b, cs.total, acc,
                   success=float(_success_mask(out.result).mean()),
                   note=f"doubling steps {steps.mean():.1f} / {steps.max()} (mean / max)" + _timing_note(tm))

    for b in batches:
        _add_row(config, table, "jaxanim dare", b, lambda b=b: jrow(b), False, failures)
    sp = ctx.records.get(("dare", _SCIPY))
    own = ctx.records.get(("dare", "jaxanim dare", big))
    if sp and own:
        ratio = sp["t"] / own["t"]
        table.notes.append(
            f"Target: batched DARE ≥ 20x the scipy loop at batch {big}: {own['t'] * 1e6:.3g} vs "
            f"{sp['t'] * 1e6:.3g} µs per system = {ratio:.3g}x: {'met' if ratio >= 20 else 'missed'}."
        )
    return table


# --- 4. swing-ups -------------------------------------------------------------------------------------
def _swing_table(ctx: _Context, name: str) -> Table:
    import solvers

    config, sz = ctx.config, ctx.sizes
    prob = _swing_problem(name, sz.swing_T)
    T = prob.horizon
    batches = config.batches_for(sz.swing_batches)
    big = max(batches)
    x0s = initial_states(name, big)
    ai = ANGLE_INDEX[name]
    max_steps = SWING_MAX_STEPS[name]
    pretty = {"pendulum": "pendulum", "cart_pole": "cart-pole"}[name]
    start = {"pendulum": "angle uniform in ±π/4 of hanging, rate in ±0.5 rad/s",
             "cart_pole": "cart in ±0.2 m, pole angle in ±0.3 rad of hanging, rates in ±0.2"}[name]
    table = Table(
        f"oc-{name}", f"Optimal control: batched {pretty} swing-ups, T = {T}",
        accuracy_label=f"final costs agreeing with Crocoddyl DDP (≤ {AGREE_RTOL:g} rel.)",
        description=(
            f"`solvers.problems.{name}()` (explicit Euler, dt = {float(prob.args['dt']):g}, quadratic cost to "
            f"the upright goal) from {big} seeded random starts ({start}), zero initial controls, ≤ {max_steps} "
            "iterations, jaxanim default tolerances. jaxanim: `jax.jit(jax.vmap(solve))` over the first `batch` "
            "starts, adaptive (while_loop) and `fixed_steps=True` (a scan of "
            f"{max_steps} iterations; finished problems frozen). Crocoddyl: a Python loop of `solve` on Python "
            "action models with the same dynamics, cost and analytic first derivatives "
            "(`benchmarks/peers/crocoddyl_oc.py`), one ShootingProblem whose x0 is reset per problem, timed on "
            "the first starts within the row budget (µs / char = per problem). **Success**: solver status "
            f"successful (Crocoddyl: `solve` returned True) and |θ_T − π| < {UPRIGHT_TOLERANCE} rad. Accuracy: "
            "of the problems both this row and Crocoddyl SolverDDP solved (status), how many final costs agree "
            f"to {AGREE_RTOL:g} relative, and the median relative difference (different local optima are "
            "possible). Notes: iterations mean / max, mean final cost."
        ),
    )
    failures: dict = {}
    croc: dict[str, dict] = {}

    def croc_row(solver: str) -> Row:
        from .peers import crocoddyl_oc as co

        pb = co.swing_up_problem(name, prob.args, x0s[0], T)
        s = co.make_solver(pb, solver)
        us0 = [np.zeros(prob.us_init.shape[1])] * T
        limit = min(big, config.loop_cap)
        costs, conv, its, angle, secs = [], [], [], [], []
        t0 = time.perf_counter()
        for i in range(limit):
            t1 = time.perf_counter()
            pb.x0 = x0s[i]
            xs0 = pb.rollout(us0)
            ok = s.solve(xs0, us0, max_steps, True, 1e-9)
            secs.append(time.perf_counter() - t1)
            costs.append(float(s.cost))
            conv.append(bool(ok))
            its.append(int(s.iter))
            angle.append(float(s.xs[-1][ai]))
            if time.perf_counter() - t0 > config.max_row_s and i >= 1:
                break
        total = time.perf_counter() - t0
        k = len(costs)
        costs, conv, its, angle, secs = map(np.asarray, (costs, conv, its, angle, secs))
        success = conv & (np.abs(angle - np.pi) < UPRIGHT_TOLERANCE)
        per_it = secs / np.maximum(its, 1)
        p10, p50, pmax = np.percentile(per_it, [10, 50, 100])
        fast = p10 * its.mean()  # per problem, were every solve in the fast mode (see crocoddyl_oc's docstring)
        croc[solver] = dict(cost=costs, conv=conv, t=total / k, k=k)
        ctx.records[(name, f"{_CROC} {solver}", big)] = dict(t=total / k, fast=fast, success=success.mean())
        acc = "reference" if solver == "SolverDDP" else _agreement(costs, conv, croc.get("SolverDDP"))
        note = (f"iterations {its.mean():.1f} / {its.max()}, mean cost {costs.mean():.6g}; Python loop over the first "
                f"{k} of {big} starts (one timed pass{', time budget' if k < limit else ''}); Python action models; "
                f"time per iteration p10 / median / max over problems {format_seconds(p10)} / {format_seconds(p50)} / "
                f"{format_seconds(pmax)}")
        return Row(f"{_CROC} {solver}", "float64", big, total, None, k, None, acc, success=float(success.mean()),
                   is_peer=True, note=note)

    for solver in ("SolverDDP", "SolverFDDP"):
        _add_row(config, table, f"{_CROC} {solver}", big, lambda s=solver: croc_row(s), True, failures)

    def jax_row(method: str, fixed: bool, b: int, impl: str) -> Row:
        fn = getattr(solvers, method)

        def one(x0, us, args):
            return fn(prob.dynamics, prob.cost, x0, us, terminal_cost=prob.terminal_cost, args=args,
                      max_steps=max_steps, fixed_steps=fixed)

        args = (jnp.asarray(x0s[:b]), jnp.broadcast_to(prob.us_init, (b,) + prob.us_init.shape), prob.args)
        out, tm, cs = _jax_call(ctx, name, impl, b, jax.jit(jax.vmap(one, in_axes=(0, 0, None))), args)
        ok = _success_mask(out.result)
        angle = np.asarray(out.xs)[:, -1, ai]
        success = ok & (np.abs(angle - np.pi) < UPRIGHT_TOLERANCE)
        steps = np.asarray(out.stats["num_steps"])
        cost = np.asarray(out.cost)
        status = _status_counts(out.result)
        ctx.records[(name, impl, b)] = dict(t=tm.median / b, success=success.mean(), cost=cost, ok=ok)
        ref = croc.get("SolverDDP")
        acc = _agreement(cost, ok, ref) if ref is not None else "n/a (no Crocoddyl)"
        note = (f"iterations {steps.mean():.1f} / {steps.max()}, mean cost {np.mean(cost):.6g}; solvers.{method}, "
                + (f"fixed_steps (scan of {max_steps})" if fixed else "while_loop")
                + (f"; status (of {b}): {status}" if status else "") + _timing_note(tm))
        return Row(impl, "float64", b, tm.median, tm.min, b, cs.total, acc, success=float(success.mean()), note=note)

    for b in batches:
        for method in sz.swing_methods:
            for fixed in (False, True) if sz.swing_fixed else (False,):
                impl = f"jaxanim {method}" + (f" (fixed {max_steps})" if fixed else "")
                why = _budget_skip(config, ctx.records, name, impl, b)
                if why is not None and config.selects(impl):
                    row = Row(impl, "float64", b, skipped=why)
                    _log_row(config, table.name, row)
                    table.rows.append(row)
                    continue
                _add_row(config, table, impl, b, lambda m=method, f=fixed, b=b, i=impl: jax_row(m, f, b, i), False,
                         failures)
    table.notes += _swing_notes(ctx, name, batches, croc)
    return table


def _agreement(cost, ok, ref: dict | None) -> str:
    """``agree/both (median rel diff)`` against the Crocoddyl reference on the common problems."""
    if ref is None:
        return "n/a (no Crocoddyl)"
    k = min(len(cost), ref["k"])
    both = np.asarray(ok[:k]) & ref["conv"][:k]
    if not both.any():
        return f"0/0 of {k}"
    rel = np.abs(np.asarray(cost[:k]) - ref["cost"][:k]) / np.abs(ref["cost"][:k])
    rel = rel[both]
    return f"{int(np.sum(rel <= AGREE_RTOL))}/{int(both.sum())} (median {np.median(rel):.0e})"


def _budget_skip(config: BenchConfig, records: dict, table: str, impl: str, b: int) -> str | None:
    prev = sorted((bb, r) for (t, i, bb), r in ((k, v) for k, v in records.items() if len(k) == 3)
                  if t == table and i == impl and bb < b)
    if not prev:
        return None
    bb, rec = prev[-1]
    est = rec["t"] * b
    budget = _CALL_BUDGET_FACTOR * config.max_row_s
    if est > budget:
        return (f"not run (time budget): ~{est:.0f} s per call expected from {rec['t'] * 1e3:.3g} ms per problem "
                f"at batch {bb}, over {budget:.0f} s")
    return None


def _swing_notes(ctx: _Context, name: str, batches: Sequence[int], croc: dict) -> list[str]:
    notes = []
    r = ctx.records
    cref = r.get((name, f"{_CROC} SolverDDP", max(batches)))
    if cref is not None:
        for method in ctx.sizes.swing_methods:
            runs = sorted((k[2], k[1], v) for k, v in r.items()
                          if len(k) == 3 and k[0] == name and k[1].startswith(f"jaxanim {method}"))
            if not runs:
                continue
            bmax = max(b for b, _, _ in runs)
            impl, best = min(((i, v) for b, i, v in runs if b == bmax), key=lambda iv: iv[1]["t"])
            ratio = cref["t"] / best["t"]
            ratio_fast = cref["fast"] / best["t"]
            label = "Target: batched DDP on 1024 swing-ups ≥ 20x the Crocoddyl loop's throughput" if method == "ddp" \
                else "Throughput vs the Crocoddyl loop (iLQR, for comparison)"
            at = f"at batch {bmax}" + ("" if bmax == max(ctx.sizes.swing_batches) or ctx.config.batches else
                                       " (the largest batch run; see the skipped rows)")
            line = (f"{label}: {impl} {at} {best['t'] * 1e3:.3g} ms per problem vs Crocoddyl SolverDDP "
                    f"{cref['t'] * 1e3:.3g} ms measured = {ratio:.3g}x, or {cref['fast'] * 1e3:.3g} ms = "
                    f"{ratio_fast:.3g}x against Crocoddyl's fastest-decile time per iteration times its mean "
                    "iterations (Crocoddyl's slow mode, see the unicycle table, excluded)")
            line += f": {'met' if ratio_fast >= 20 else 'missed'} (judged on the second)." if method == "ddp" else "."
            notes.append(line)
        notes.append(
            "The Crocoddyl peers here are Python action models (Crocoddyl has no built-in pendulum or cart-pole "
            "action model); see the unicycle table for what Python callbacks cost Crocoddyl against a C++ model."
        )
    return notes


# --- 5. compile times ---------------------------------------------------------------------------------
def _compile_table(ctx: _Context) -> Table:
    table = Table(
        "oc-compile", "Optimal control: compile times (jaxanim)",
        accuracy_label="—",
        description=(
            "`jax.jit(f).lower(*args).compile()` of every jitted jaxanim function of the tables above, on a fresh "
            "`jax.jit` object (tracing + lowering + XLA compilation: what the first call costs on top of running). "
            "The run times above never include it. Notes: the lowering / compilation split."
        ),
    )
    for tname, impl, b, cs in ctx.compiles:
        table.rows.append(Row(f"{impl} [{tname}]", "float64", b, compile_s=cs.total,
                              note=f"lower {cs.lower:.2f} s + compile {cs.compile:.2f} s"))
    oc = [(cs.total, f"{impl} [{t}] batch {b}") for t, impl, b, cs in ctx.compiles
          if "ilqr" in impl or "ddp" in impl]
    if oc:
        worst, what = max(oc)
        best = min(c for c, _ in oc)
        table.notes.append(f"Target: iLQR / DDP compile ≤ 5 s: {best:.1f}–{worst:.1f} s over {len(oc)} "
                           f"compilations (worst: {what}): {'met' if worst <= 5 else 'missed'}.")
    return table


# --- entry point --------------------------------------------------------------------------------------
TABLES = ("unicycle", "lqr", "dare", "swing_up", "compile")


def run_oc(config: BenchConfig, sizes: OCSizes | None = None, tables: Sequence[str] = TABLES) -> list[Table]:
    """The ``oc`` benchmark (see the module docstring); ``sizes`` and ``tables`` shrink it for tests."""
    unknown = set(tables) - set(TABLES)
    if unknown:
        raise ValueError(f"tables: unknown {sorted(unknown)}; expected some of {TABLES}")
    ctx = _Context(config, sizes or OCSizes())
    load0 = os.getloadavg() if hasattr(os, "getloadavg") else None
    start = time.perf_counter()
    if "float64" not in config.dtypes:
        config.log("oc: runs in float64 only (Crocoddyl and scipy are float64); --dtype is ignored")
    out: list[Table] = []
    for key, make in (("unicycle", _unicycle_table), ("lqr", _lqr_table), ("dare", _dare_table)):
        if key in tables:
            out.append(make(ctx))
    if "swing_up" in tables:
        for name in ctx.sizes.swing_problems:
            out.append(_swing_table(ctx, name))
    if "compile" in tables and ctx.compiles:
        out.append(_compile_table(ctx))
    note = load_note("oc", start, load0)
    if out and note:
        out[-1].notes.append(note)
    return out
