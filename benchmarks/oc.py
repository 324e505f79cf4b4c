"""Optimal-control benchmark (``python -m benchmarks oc``): iLQR / DDP / LQR / DARE vs Crocoddyl and scipy, float64."""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import solvers
from solvers import problems
from solvers.problems import LQProblem

from .peers import crocoddyl_oc as co, require
from .report import Row, Table, Target, format_seconds, sel
from .timing import Runner, Timing, row_limits, status_counts, time_call

__all__ = ["ACCELERATOR_SIZES", "ACCELERATOR_TABLES", "OCSizes", "initial_states", "make_dare_systems", "make_lq",
           "riccati_residual", "run_oc", "swing_problem"]

SEED = 0
UNICYCLE_X0 = (-1.0, -1.0, 1.0)
UNICYCLE_BOUNDS = ((-2.0, -1.5), (2.0, 1.5))  # (u_min, u_max): speed, turn rate; the optimum leaves it
SWING_MAX_STEPS = {"pendulum": 100, "cart_pole": 600}  # both sides; first-order solvers take ~330-490 on the cart-pole
ANGLE_INDEX = {"pendulum": 0, "cart_pole": 1}
UPRIGHT_TOLERANCE = 0.1  # rad: success needs |theta_T - pi| below this
AGREE_RTOL = 1e-6  # swing-up final costs "agree" below this relative difference
SWING_STOP = 1e-9  # both sides stop once the full step's predicted cost decrease is below this (absolute)
_SWING_PEERS = {"pendulum": ("SolverDDP", "SolverFDDP"), "cart_pole": ("SolverBoxDDP", "SolverBoxFDDP")}
UNICYCLE_MAX_STEPS = 500  # both sides (box-DDP needs more than 100 here)
_CROC = "Crocoddyl"
_STARTS = {"pendulum": "angle uniform in ±π/4 of hanging, rate in ±0.5 rad/s",
           "cart_pole": "cart in ±0.2 m, pole angle in ±0.3 rad of hanging, rates in ±0.2"}
_SCIPY = "scipy solve_discrete_are (loop)"


@dataclasses.dataclass(frozen=True)
class OCSizes:
    """Problem sizes (tests shrink them); ``config.batches`` overrides the batches, ``swing_T=None`` keeps 100;
    ``swing_peer_s`` bounds each Crocoddyl swing-up loop's seconds (``None``: the row budget, ``max_row_s``)."""

    unicycle_T: int = 200
    lqr_n: int = 37
    lqr_m: int = 12
    lqr_T: int = 100
    lqr_methods: tuple[str, ...] = ("ilqr", "ddp")
    dare_n: int = 12
    dare_m: int = 4
    dare_batches: tuple[int, ...] = (1, 64, 1024, 10_000)
    dare_scipy_cap: int = 512
    swing_problems: tuple[str, ...] = ("pendulum", "cart_pole")
    swing_batches: tuple[int, ...] = (1, 64, 1024)
    swing_methods: tuple[str, ...] = ("ilqr", "ddp")
    swing_fixed: bool = True
    swing_T: int | None = None
    swing_peer_s: float | None = None


#: ``--gpu`` on a machine with an accelerator: DARE of 1,024 to 10^5 systems, swing-ups of 16,384 (adaptive solves
#: only: each batch and method compiles again; the Crocoddyl loops on the host for 3 s each), and only the batched
#: tables (:data:`ACCELERATOR_TABLES`): the unicycle and LQ tables time one solve.
ACCELERATOR_SIZES = OCSizes(dare_batches=(1024, 10_000, 100_000), swing_batches=(16384,), swing_fixed=False,
                            swing_peer_s=3.0)
ACCELERATOR_TABLES = ("dare", "swing_up", "compile")


def make_lq(n: int = 37, m: int = 12, T: int = 100, seed: int = SEED) -> dict[str, np.ndarray]:
    """A seeded LQ problem in Crocoddyl's ``ActionModelLQR`` terms, ``[[Q, N], [N', R]] = L L' + 0.1 I``."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n)) / np.sqrt(n)
    A *= 1.02 / np.abs(np.linalg.eigvals(A)).max()
    B = rng.normal(size=(n, m)) / np.sqrt(n)
    L = rng.normal(size=(n + m, n + m)) / np.sqrt(n + m)
    W = L @ L.T + 0.1 * np.eye(n + m)
    return dict(A=A, B=B, Q=W[:n, :n], N=W[:n, n:], R=W[n:, n:], f=0.1 * rng.normal(size=n),
                q=rng.normal(size=n), r=rng.normal(size=m), x0=rng.normal(size=n), T=T)


def make_dare_systems(count: int, n: int = 12, m: int = 4, seed: int = SEED) -> tuple[np.ndarray, ...]:
    """``count`` seeded stabilizable DARE problems ``(A, B, Q, R)`` (see the table's description)."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(count, n, n)) / np.sqrt(n)
    A *= (1.1 / np.abs(np.linalg.eigvals(A)).max(axis=-1))[:, None, None]
    B = rng.normal(size=(count, n, m))
    G = rng.normal(size=(count, n, n)) / np.sqrt(n)
    H = rng.normal(size=(count, m, m)) / np.sqrt(m)
    return A, B, G @ G.transpose(0, 2, 1) + 1e-3 * np.eye(n), H @ H.transpose(0, 2, 1) + np.eye(m)


def riccati_residual(A, B, Q, R, P) -> np.ndarray:
    """``max|A'PA - P - A'PB (R + B'PB)^{-1} B'PA + Q| / max|P|`` per system (float64 numpy, batched)."""
    A, B, Q, R, P = (np.asarray(z, np.float64) for z in (A, B, Q, R, P))
    BP = np.swapaxes(B, -1, -2) @ P
    N = BP @ A
    F = np.swapaxes(A, -1, -2) @ P @ A - P - np.swapaxes(N, -1, -2) @ np.linalg.solve(R + BP @ B, N) + Q
    return np.abs(F).max(axis=(-2, -1)) / np.abs(P).max(axis=(-2, -1))


def swing_problem(name: str, T: int | None = None) -> problems.ControlProblem:
    """``solvers.problems.<name>(T=T)`` as Crocoddyl's C++ models state it exactly (:func:`~benchmarks.peers.
    crocoddyl_oc.swing_problem`): semi-implicit Euler ``v+ = v + dt a``, ``q+ = q + dt v+`` (Crocoddyl's
    ``IntegratedActionModelEuler``; the problems use explicit Euler, ``q+ = q + dt v``) with the problems' own
    acceleration ``a``, and an undamped pendulum (Crocoddyl's free forward dynamics has no joint damping)."""
    kw = ({} if T is None else {"T": T}) | ({"damping": 0.0} if name == "pendulum" else {})
    prob = getattr(problems, name)(**kw)
    return dataclasses.replace(prob, dynamics=_semi_implicit(prob.dynamics))


@functools.cache  # one callback per problem: repeated solves reuse one compilation
def _semi_implicit(explicit: Callable) -> Callable:
    def dynamics(x, u, t, args):
        nq = x.shape[0] // 2
        v_next = explicit(x, u, t, args)[nq:]  # v + dt a(x, u)
        return jnp.concatenate([x[:nq] + args["dt"] * v_next, v_next])

    return dynamics


def initial_states(name: str, count: int, seed: int = SEED) -> np.ndarray:
    """``[count, n]`` seeded swing-up starts near hanging (:data:`_STARTS`)."""
    rng = np.random.default_rng(seed)
    if name == "pendulum":
        return np.stack([rng.uniform(-np.pi / 4, np.pi / 4, count), rng.uniform(-0.5, 0.5, count)], axis=-1)
    if name == "cart_pole":
        return rng.uniform(-1.0, 1.0, size=(count, 4)) * np.array([0.2, 0.3, 0.2, 0.2])
    raise ValueError(f"name: expected 'pendulum' or 'cart_pole', got {name!r}")


def _ok(result) -> np.ndarray:
    return np.asarray(result == solvers.RESULTS.successful)


def _rel(a: float, b: float) -> float:
    return abs(a - b) / max(abs(b), 1e-300)


def _croc_single(run: Runner, impl: str, problem, solver: str, maxiter: int, accuracy: Callable, what: str) -> Row:
    """One Crocoddyl ``solve`` from zero controls per sample, at least 15 samples within ``max_row_s``."""
    us0 = [np.zeros(problem.runningModels[0].nu)] * problem.T
    xs0 = problem.rollout(us0)
    s = getattr(co.load_crocoddyl(), solver)(problem)
    ok = s.solve(xs0, us0, maxiter, True, 1e-9)
    limit, fewest = row_limits(run.config)
    tm = time_call(s.solve, xs0, us0, maxiter, True, 1e-9, repeats=max(run.config.repeats, 15), warmup=0, number=1,
                   max_total_s=limit, min_samples=fewest)
    its, cost, slowest = int(s.iter), float(s.cost), max(tm.all)
    note = (f"{its} iteration{'s' if its != 1 else ''}, {format_seconds(tm.median / max(its, 1))} / iteration, cost "
            f"{cost:.12g}; {what}; {tm.samples} single-call samples: min {format_seconds(tm.min)}, median "
            f"{format_seconds(tm.median)}, max {format_seconds(slowest)}")
    return run.row(impl, "float64", 1, tm, accuracy=accuracy(cost, np.array(s.us)), success=float(ok), note=note,
                   extra=dict(cost=cost, its=its, fastest=tm.min, slowest=slowest))


def _solve(prob, method: str, **options) -> Callable:
    """``(x0, us, args) -> solvers.<method>`` on ``prob``'s dynamics and costs (a new function: a fresh jit)."""
    fn = getattr(solvers, method)
    return lambda x0, us, args: fn(prob.dynamics, prob.cost, x0, us, terminal_cost=prob.terminal_cost, args=args,
                                   **options)


def _jax_solve(run: Runner, impl: str, fn: Callable, args: tuple, b: int, accuracy: Callable, note: str,
               success: Callable = lambda out: _ok(out.result)) -> Row:
    out, tm, comp = run.jax(jax.jit(fn), *args)
    ok, cost = success(out), np.asarray(out.cost)
    its = np.asarray(out.stats["num_steps"]) if getattr(out, "stats", None) else None  # lqr has no iterations
    if b > 1:
        head = f"iterations {its.mean():.1f} / {int(its.max())}, mean cost {cost.mean():.6g}; "
    else:
        n = None if its is None else int(its.max())
        head = "" if n is None else f"{n} iterations, {format_seconds(tm.median / max(n, 1))} / iteration, "
        head += f"cost {float(cost.mean()):.12g}; "
    return run.row(impl, "float64", b, tm, compile_s=comp, accuracy=accuracy(out), success=float(ok.mean()),
                   status=status_counts(out.result), extra=dict(ok=ok, cost=cost), note=head + note)


def _unicycle_table(config, sz: OCSizes) -> Table:
    T = sz.unicycle_T
    lo, hi = (np.asarray(b, np.float64) for b in UNICYCLE_BOUNDS)
    own, croc = sel(("jaxanim ilqr", "jaxanim ddp"), exact=True), sel(f"{_CROC} SolverDDP", exact=True)
    table = Table(
        "oc-unicycle", f"Optimal control: unicycle, T = {T}, one solve (Crocoddyl's ActionModelUnicycle)",
        accuracy_label="rel. cost diff vs Crocoddyl (box rows: BoxDDP)", description=(
            f"`solvers.problems.unicycle(T={T})` (exactly Crocoddyl's `ActionModelUnicycle`: dt = 0.1, cost 0.5 (10² "
            f"|x|² + 1² |u|²) per knot, terminal 0.5 · 10² |x_T|²) from x0 = {UNICYCLE_X0}, zero controls; box rows: u "
            f"∈ [{lo[0]}, {hi[0]}] × [{lo[1]}, {hi[1]}] (which the unbounded optimum leaves), `bounds=` vs `u_lb/u_ub` "
            f"+ SolverBoxDDP. ≤ {UNICYCLE_MAX_STEPS} iterations; jaxanim default tolerances (`jax.jit`), Crocoddyl "
            "th_stop 1e-9 (`solver.solve`, one call per sample, spread in the notes). Crocoddyl uses first "
            "derivatives of the dynamics (as jaxanim ilqr); jaxanim ddp also second ones."),
        targets=[Target("one unicycle solve at most 1.5x Crocoddyl SolverDDP's time, fastest samples (speedup ≥ "
                        "0.667x)", own, 1 / 1.5, "min_us", versus=croc),
                 Target("the same, medians (speedup ≥ 0.667x)", own, 1 / 1.5, "us", versus=croc)])
    run = Runner(config, table)
    prob = problems.unicycle(T=T, dtype=jnp.float64)
    ref: dict[bool, float] = {}  # per boxed: the first row's cost (Crocoddyl SolverDDP if it ran)

    def rel(cost, boxed: bool) -> float:
        return _rel(float(cost), ref.setdefault(boxed, float(cost)))

    for solver, boxed, py in (("SolverDDP", False, False), ("SolverFDDP", False, False), ("SolverBoxDDP", True, False),
                              ("SolverDDP", False, True)):
        impl = f"{_CROC} {solver}" + (" (Python model)" if py else "")
        what = ("Python action model (same dynamics and cost)" if py else "C++ ActionModelUnicycle") + (
            ", bounds" if boxed else "")
        run.add(impl, "float64", 1, lambda: _croc_single(run, impl, co.python_problem(
            "unicycle", prob.args, UNICYCLE_X0, T) if py else co.unicycle_problem(
            T, UNICYCLE_X0, state_weight=10.0, control_weight=1.0, dt=0.1, bounds=(lo, hi) if boxed else None),
            solver, UNICYCLE_MAX_STEPS, lambda c, us: rel(c, boxed), what), peer=True)
    for boxed in (False, True):
        for method in ("ilqr", "ddp"):
            impl = f"jaxanim {method}" + (" box" if boxed else "")
            solve = _solve(prob, method, bounds=(jnp.asarray(lo), jnp.asarray(hi)) if boxed else None,
                           max_steps=UNICYCLE_MAX_STEPS)
            run.add(impl, "float64", 1, lambda: _jax_solve(
                run, impl, solve, (prob.x0, prob.us_init, prob.args), 1, lambda out: rel(out.cost, boxed),
                f"solvers.{method}" + (", bounds" if boxed else "") + ", while_loop"))
    rows = {r.implementation: r for r in table.rows if r.measured}
    c, py = rows.get(f"{_CROC} SolverDDP"), rows.get(f"{_CROC} SolverDDP (Python model)")
    if c and py:
        table.notes.append(f"Crocoddyl SolverDDP on the same unicycle written as a Python action model: "
                           f"{format_seconds(py.time_min_s)} vs {format_seconds(c.time_min_s)} with the C++ model "
                           f"({py.time_min_s / c.time_min_s:.2g}x, fastest samples); the swing-up peers below are "
                           "C++ models.")
    _note_wide_spread(table, "single-call samples", "with the same iterations and result: read its min column.")
    return table


def _note_wide_spread(table: Table, what: str, tail: str) -> None:
    """A note naming the rows whose ``extra`` ``slowest`` is over 10x their ``fastest`` (Crocoddyl's slow mode)."""
    wide = [f"{r.implementation} {format_seconds(r.extra['fastest'])} to {format_seconds(r.extra['slowest'])}"
            for r in table.rows if r.measured and r.extra.get("slowest", 0.0) > 10 * r.extra.get("fastest", np.inf)]
    if wide:
        table.notes.append(f"Crocoddyl's {what} spread over more than 10x in this run ({', '.join(wide)}), {tail}")


def _lqr_table(config, sz: OCSizes) -> Table:
    n, m, T = sz.lqr_n, sz.lqr_m, sz.lqr_T
    d = make_lq(n, m, T)
    tile = lambda z: jnp.asarray(np.broadcast_to(z, (T,) + z.shape), jnp.float64)  # noqa: E731
    lq = LQProblem(A=tile(d["A"]), B=tile(d["B"]), Q=tile(d["Q"]), R=tile(d["R"]), QT=jnp.asarray(d["Q"]),
                   x0=jnp.asarray(d["x0"]), S=tile(d["N"].T), q=tile(d["q"]), r=tile(d["r"]), qT=jnp.asarray(d["q"]),
                   c=tile(d["f"]), constant=jnp.zeros((), jnp.float64))
    table = Table(
        "oc-lqr", f"Optimal control: LQ problem, {n} states × {m} inputs, T = {T}",
        accuracy_label="rel. cost diff / max |Δu| vs solvers.lqr", description=(
            "A seeded time-invariant LQ problem (`benchmarks.oc.make_lq`: A with spectral radius 1.02, cost 0.5 x'Qx "
            "+ 0.5 u'Ru + x'N u + q'x + r'u with [[Q, N], [N', R]] positive definite, drift f, terminal 0.5 x'Qx + "
            "q'x), the same matrices in Crocoddyl's `ActionModelLQR`. `solvers.lqr` is the exact Riccati solution; "
            "iLQR / DDP take one iteration and confirm convergence with a second; Crocoddyl's solvers stop after one."))
    run = Runner(config, table)
    sol = lq.solve()
    ref_cost, ref_us = float(sol.cost), np.asarray(sol.us)
    def acc(cost, us) -> str:
        return f"{_rel(float(cost), ref_cost):.1e} / {np.abs(np.asarray(us) - ref_us).max():.1e}"

    run.add("jaxanim lqr", "float64", 1, lambda: _jax_solve(
        run, "jaxanim lqr", lambda p: p.solve(), (lq,), 1, lambda out: "reference",
        "solvers.lqr (backward Riccati scan + forward rollout)"))
    cp = lq.as_control_problem()
    for method in sz.lqr_methods:
        run.add(f"jaxanim {method}", "float64", 1, lambda: _jax_solve(
            run, f"jaxanim {method}", lambda p, method=method: p.solve(method, max_steps=10), (cp,), 1,
            lambda out: acc(out.cost, out.us),
            f"solvers.{method} on the problem as callbacks (LQProblem.as_control_problem)"))

    for solver in ("SolverDDP", "SolverFDDP", "SolverBoxDDP"):
        run.add(f"{_CROC} {solver}", "float64", 1, lambda: _croc_single(run, f"{_CROC} {solver}", co.lqr_problem(
            *(d[k] for k in ("A", "B", "Q", "R", "N", "f", "q", "r", "x0")), T), solver, 10, acc,
            "ActionModelLQR (C++)"), peer=True)
    c = next((r for r in table.rows if r.implementation == f"{_CROC} SolverDDP" and r.measured), None)
    if c is not None:
        same = _rel(c.extra["cost"], ref_cost) <= 1e-9
        table.notes.append(f"Cost conventions: Crocoddyl SolverDDP's final cost {c.extra['cost']:.15g} vs solvers.lqr "
                           f"{ref_cost:.15g}: " + ("the same problem." if same else
                                                   "MISMATCH (> 1e-9): the problems differ."))
    return table


def _dare_table(config, sz: OCSizes) -> Table:
    n, m = sz.dare_n, sz.dare_m
    batches = config.batches_for(sz.dare_batches)
    big = max(batches)
    A, B, Q, R = make_dare_systems(big, n, m)
    cap = min(sz.dare_scipy_cap, config.loop_cap, big)
    table = Table(
        "oc-dare", f"Discrete algebraic Riccati equation, {n} × {m}, batched",
        accuracy_label="max rel ΔP vs scipy / max rel Riccati residual", description=(
            f"{big} seeded random systems (`benchmarks.oc.make_dare_systems`: A Gaussian with spectral radius 1.1, B "
            "Gaussian, Q = GG' + 1e-3 I, R = HH' + I). jaxanim: `jax.jit(jax.vmap(solvers.dare))` "
            "(structure-preserving doubling, adaptive while_loop) on the first `batch` systems; scipy: "
            f"`scipy.linalg.solve_discrete_are` in a Python loop over the first {cap} (µs / char = per system). ΔP: "
            "max over the systems both solved of max|P − P_scipy| / max|P_scipy|; residual: max over the batch of "
            "max|F(P)| / max|P| (numpy float64)."),
        targets=[Target(f"batched DARE ≥ 50x the scipy loop at batch {big}", sel("jaxanim dare", batch=big), 50.0,
                        versus=sel(_SCIPY))])
    run = Runner(config, table)
    ref: dict[str, np.ndarray] = {}

    def scipy_row() -> Row:
        sl = require("scipy.linalg")
        args = (A[:cap], B[:cap], Q[:cap], R[:cap])
        P, tm = run.python(lambda: np.stack([sl.solve_discrete_are(*(z[i] for z in args)) for i in range(cap)]))
        ref["P"] = P
        return run.row(_SCIPY, "float64", big, tm, cap, accuracy=f"reference / {riccati_residual(*args, P).max():.1e}",
                       success=float(np.mean(np.isfinite(P).all(axis=(1, 2)))),
                       note=f"Python loop, timed on {cap} of {big} systems (QZ method)")

    run.add(_SCIPY, "float64", big, scipy_row, peer=True)

    def dare_row(b: int) -> Row:
        out, tm, comp = run.jax(jax.vmap(lambda A, B, Q, R: solvers.dare(A, B, Q, R)),
                                *(jnp.asarray(z[:b]) for z in (A, B, Q, R)))
        P, steps, dP = np.asarray(out.P), np.asarray(out.stats["num_steps"]), "n/a"
        if "P" in ref:  # the scipy row ran: compare on the systems both solved
            k = min(b, len(ref["P"]))
            dP = f"{(np.abs(P[:k] - ref['P'][:k]).max(axis=(1, 2)) / np.abs(ref['P'][:k]).max(axis=(1, 2))).max():.1e}"
        res = riccati_residual(A[:b], B[:b], Q[:b], R[:b], P).max()
        return run.row("jaxanim dare", "float64", b, tm, compile_s=comp, accuracy=f"{dP} / {res:.1e}",
                       success=float(_ok(out.result).mean()), status=status_counts(out.result),
                       note=f"doubling steps {steps.mean():.1f} / {steps.max()} (mean / max)")

    for b in batches:
        run.add("jaxanim dare", "float64", b, lambda: dare_row(b))
    return table


def _agreement(cost, ok, ref: Row | None) -> str:
    """``agree/both (median rel diff)`` against the Crocoddyl reference row ``ref`` on the problems both solved."""
    if ref is None:
        return "n/a (no Crocoddyl)"
    k = min(len(cost), ref.chars_per_call)
    both = np.asarray(ok[:k]) & ref.extra["conv"][:k]
    if not both.any():
        return f"0/0 of {k}"
    rel = (np.abs(np.asarray(cost[:k]) - ref.extra["cost"][:k]) / np.abs(ref.extra["cost"][:k]))[both]
    return f"{int(np.sum(rel <= AGREE_RTOL))}/{int(both.sum())} (median {np.median(rel):.0e})"


def _swing_table(config, sz: OCSizes, name: str) -> Table:
    prob = swing_problem(name, sz.swing_T)
    T, ai, max_steps = prob.horizon, ANGLE_INDEX[name], SWING_MAX_STEPS[name]
    batches = config.batches_for(sz.swing_batches)
    big = max(batches)
    x0s = initial_states(name, big)
    peers = _SWING_PEERS[name]
    reference = f"{_CROC} {peers[0]}"  # the accuracy column's; the targets take it or its (1 thread) twin, the faster
    croc, either = sel(reference, exact=True), sel(reference)
    pinned = ", the pole torque pinned to 0 by u_lb = u_ub = 0 (hence the box solvers)" if name == "cart_pole" else ""
    table = Table(
        f"oc-{name}", f"Optimal control: batched {name.replace('_', '-')} swing-ups, T = {T}",
        accuracy_label=f"final costs agreeing with Crocoddyl {peers[0]} (≤ {AGREE_RTOL:g} rel.)", description=(
            f"`benchmarks.oc.swing_problem('{name}')`: `solvers.problems.{name}()`"
            + (" with damping 0" if name == "pendulum" else "") + " stepped by semi-implicit Euler (v+ = v + dt a, "
            f"q+ = q + dt v+, dt = {float(prob.args['dt']):g}; the problems' own explicit Euler has no C++ Crocoddyl "
            f"counterpart, nor has a damped joint), quadratic cost to upright; from {big} seeded starts "
            f"({_STARTS[name]}), zero controls, ≤ {max_steps} iterations. jaxanim: `jax.jit(jax.vmap(solve))` over the "
            "first `batch` starts, " + (f"adaptive and `fixed_steps=True` (a scan of {max_steps}; finished problems "
                                        "frozen). " if sz.swing_fixed else "adaptive (`while_loop`). ") +
            "Crocoddyl: C++ models only (the Pinocchio "
            "model of `benchmarks.peers.crocoddyl_oc.pinocchio_model`, DifferentialActionModelFreeFwdDynamics + "
            f"IntegratedActionModelEuler, ResidualModelState / Control costs{pinned}), a Python loop of `solve` over "
            "the first starts within the row budget (its success counts those only), on Crocoddyl's default OpenMP "
            "threads over the knots (these tables run before the unicycle's, whose Python model would switch them off "
            "for the process) and, in the (1 thread) row, on one (OpenMP threads wait for each other at every loop "
            "over the knots, so a core held by another process slows the default rows). One stopping rule: stop once "
            "the full step's predicted cost decrease is below "
            f"{SWING_STOP:g} (jaxanim atol = {SWING_STOP:g}, rtol = 0; Crocoddyl th_stop = {SWING_STOP:g}, set on "
            "every solver: BoxDDP's default is 5e-5); iterations count backward passes on both sides (Crocoddyl: iter "
            "+ 1 when it converged; its last one still takes its step). The regularisation schedules are each solver's "
            "own. Crocoddyl uses first derivatives of the dynamics (like jaxanim ilqr; jaxanim ddp also second ones). "
            f"**Success**: converged and |θ_T − π| < {UPRIGHT_TOLERANCE} rad. Accuracy: how many final costs of the "
            f"problems both this row and Crocoddyl {peers[0]} solved agree to {AGREE_RTOL:g} relative (median "
            "relative difference; local optima may differ)."),
        targets=[Target(f"batched DDP on {big} swing-ups ≥ 10x the faster Crocoddyl {peers[0]} loop's throughput "
                        "(jaxanim ddp: second-order dynamics; Crocoddyl: first-order)", sel("jaxanim ddp", batch=big),
                        10.0, versus=either),
                 Target(f"like with like, jaxanim ilqr on {big} swing-ups ≥ 10x the faster Crocoddyl {peers[0]} loop "
                        "(both first-order dynamics)", sel("jaxanim ilqr", batch=big), 10.0, versus=either)])
    run = Runner(config, table)

    def croc_row(impl: str, solver: str, one_thread: bool) -> Row:
        pb = co.swing_problem(name, prob.args, x0s[0], T)
        if one_thread:
            pb.nthreads = 1
        s = getattr(co.load_crocoddyl(), solver)(pb)
        s.th_stop = SWING_STOP
        us0 = [np.zeros(pb.runningModels[0].nu)] * T
        limit, solved, t0 = min(big, config.loop_cap), [], time.perf_counter()
        row_s = min(row_limits(config)[0], sz.swing_peer_s or np.inf)
        for x0 in x0s[:limit]:  # (cost, converged, backward passes, final angle, seconds) per start
            t1, pb.x0 = time.perf_counter(), x0
            ok = s.solve(pb.rollout(us0), us0, max_steps, True)
            solved.append((float(s.cost), bool(ok), min(int(s.iter) + 1, max_steps), float(s.xs[-1][ai]),
                           time.perf_counter() - t1))
            if time.perf_counter() - t0 > row_s and len(solved) >= 2:
                break
        total = time.perf_counter() - t0
        cost, conv, its, angle, secs = (np.asarray(c) for c in zip(*solved))
        k, per_it = len(cost), secs / its
        success = conv & (np.abs(angle - np.pi) < UPRIGHT_TOLERANCE)
        spread = lambda z: " / ".join(format_seconds(v) for v in np.percentile(z, [0, 50, 100]))  # noqa: E731
        threads = f"{pb.nthreads} thread" + ("s" if pb.nthreads > 1 else "")
        ref = next((r for r in table.rows if croc(r) and r.measured), None)
        return run.row(impl, "float64", big, Timing(total, None, 1), k,
                       accuracy="reference" if impl == reference else _agreement(cost, conv, ref),
                       success=float(success.mean()),
                       extra=dict(cost=cost, conv=conv, fastest=per_it.min(), slowest=per_it.max()), note=(
                           f"iterations {its.mean():.1f} / {its.max()}, mean cost {cost.mean():.6g}; C++ models, "
                           f"Python loop over the first {k} of {big} starts (one timed pass"
                           f"{', time budget' if k < limit else ''}, {threads}); min / median / max over problems: "
                           f"per solve {spread(secs)}, per iteration {spread(per_it)}"))

    for solver, one_thread in ((peers[0], False), (peers[0], True), (peers[1], False)):
        impl = f"{_CROC} {solver}" + (" (1 thread)" if one_thread else "")
        run.add(impl, "float64", big, lambda: croc_row(impl, solver, one_thread), peer=True)
    ref = next((r for r in table.rows if croc(r) and r.measured), None)

    def upright(out) -> np.ndarray:
        return _ok(out.result) & (np.abs(np.asarray(out.xs)[:, -1, ai] - np.pi) < UPRIGHT_TOLERANCE)

    for b in batches:
        args = (jnp.asarray(x0s[:b]), jnp.broadcast_to(prob.us_init, (b,) + prob.us_init.shape), prob.args)
        for method in sz.swing_methods:
            for fixed in (False, True) if sz.swing_fixed else (False,):
                impl = f"jaxanim {method}" + (f" (fixed {max_steps})" if fixed else "")
                note = f"solvers.{method}, " + (f"fixed_steps (scan of {max_steps})" if fixed else "while_loop")
                one = jax.vmap(_solve(prob, method, max_steps=max_steps, fixed_steps=fixed, atol=SWING_STOP, rtol=0.0),
                               in_axes=(0, 0, None))
                run.add(impl, "float64", b, lambda: _jax_solve(run, impl, one, args, b, lambda out: _agreement(
                    np.asarray(out.cost), _ok(out.result), ref), note, upright))
    for r in table.rows if ref is not None else ():  # success on the starts Crocoddyl's reference ran (like with like)
        if "ok" in r.extra:
            k = min(r.batch, ref.chars_per_call)
            r.note += f"; success on Crocoddyl's first {k} starts {100 * r.extra['ok'][:k].mean():.1f} %"
    _note_wide_spread(table, "time per iteration over the problems", "as measured (a slow mode, in its row time).")
    return table


def _compile_table(tables: Sequence[Table]) -> Table:
    table = Table("oc-compile", "Optimal control: compile times (jaxanim)", accuracy_label="—", description=(
        "`jax.jit(f).lower(*args).compile()` of every jitted jaxanim row above on a fresh `jax.jit` object (tracing, "
        "lowering and XLA compilation: what the first call costs on top of running), never in the run times above."),
        targets=[Target("iLQR / DDP compile ≤ 5 s", sel(("jaxanim ilqr", "jaxanim ddp")), 5.0, "compile", worst=True)])
    for t in tables:
        table.rows += [Row(f"{r.implementation} [{t.name.removeprefix('oc-')}]", r.dtype, r.batch,
                           compile_s=r.compile_s) for r in t.rows if r.measured and r.compile_s is not None]
    return table

TABLES = ("unicycle", "lqr", "dare", "swing_up", "compile")


def run_oc(config, sizes: OCSizes | None = None, tables: Sequence[str] | None = None) -> list[Table]:
    """The ``oc`` benchmark (see the module docstring); ``sizes`` and ``tables`` (default :data:`TABLES`, or
    :data:`ACCELERATOR_TABLES` under ``--gpu``) shrink it for tests."""
    tables = config.pick(TABLES, accelerator=ACCELERATOR_TABLES) if tables is None else tables
    unknown = set(tables) - set(TABLES)
    if unknown:
        raise ValueError(f"tables: unknown {sorted(unknown)}; expected some of {TABLES}")
    sz = sizes or config.pick(OCSizes(), accelerator=ACCELERATOR_SIZES)
    config.float64_only("oc", "Crocoddyl and scipy are float64")
    # the DARE table (scipy only) and then the swing-ups run first: once a Python action model exists (the unicycle
    # table's), Crocoddyl runs every problem of the process on one thread; within a section time budget the
    # batched tables come first. The tables keep their order.
    dare = [_dare_table(config, sz)] if "dare" in tables else []
    swing = [_swing_table(config, sz, name) for name in sz.swing_problems] if "swing_up" in tables else []
    out = [make(config, sz) for key, make in (("unicycle", _unicycle_table), ("lqr", _lqr_table)) if key in tables]
    out += dare + swing
    if "compile" in tables and any(r.compile_s for t in out for r in t.rows):
        out.append(_compile_table(out))
    return out
