"""The ``oc`` benchmark: a reduced in-process run, and the Crocoddyl action models of its peer.

Only tiny sizes and a few implementations run here (each jaxanim row costs a compilation of a few
seconds); timings are not checked, the rows, accuracy columns and skipped peers are.
"""

from __future__ import annotations

import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks import REGISTRY
from benchmarks.oc import (SWING_MAX_STEPS, SWING_STOP, OCSizes, initial_states, make_dare_systems,
                           riccati_residual, run_oc, swing_problem)
from benchmarks.report import render_table

from .helpers import bench_rows, quick_bench_config

_TINY = OCSizes(
    unicycle_T=20, lqr_n=4, lqr_m=2, lqr_T=10, lqr_methods=(), dare_n=3, dare_m=2, dare_scipy_cap=4,
    swing_problems=("pendulum",), swing_methods=("ilqr",), swing_fixed=False, swing_T=40,
)
_UNICYCLE_T20_COST = 249.56089793082  # ../shared/data/ddp and solvers.problems.unicycle's docstring


def test_registered():
    assert REGISTRY["oc"].target == "benchmarks.oc:run_oc"
    assert REGISTRY["oc"].load() is run_oc


def test_reduced_run_without_crocoddyl(monkeypatch):
    """jaxanim and scipy rows run and are accurate; every Crocoddyl row is skipped with the reason."""
    monkeypatch.setitem(sys.modules, "crocoddyl", None)  # import crocoddyl -> ImportError
    config = quick_bench_config(only=("jaxanim ilqr", "jaxanim lqr", "jaxanim dare", "scipy*", "crocoddyl solverddp"))
    tables = run_oc(config, _TINY)
    assert [t.name for t in tables] == ["oc-unicycle", "oc-lqr", "oc-dare", "oc-pendulum", "oc-compile"]
    text = "\n".join(render_table(t) for t in tables)
    assert "failed:" not in text

    _, uni = bench_rows(tables, "oc-unicycle")
    row = uni[("jaxanim ilqr", 1)]
    assert row.success == 1.0 and row.compile_s > 0 and row.time_median_s > 0
    assert f"cost {_UNICYCLE_T20_COST:.9f}" in row.note, row.note
    skipped = uni[("Crocoddyl SolverDDP", None)]
    assert skipped.skipped.startswith("cannot import crocoddyl"), skipped.skipped

    _, lqr = bench_rows(tables, "oc-lqr")
    assert lqr[("jaxanim lqr", 1)].accuracy == "reference"
    assert lqr[("jaxanim lqr", 1)].success == 1.0

    _, dare = bench_rows(tables, "oc-dare")
    scipy_row = dare[("scipy solve_discrete_are (loop)", 2)]
    assert scipy_row.chars_per_call == 2 and scipy_row.success == 1.0
    dP, res = (float(x) for x in dare[("jaxanim dare", 2)].accuracy.split(" / "))
    assert dP < 1e-10 and res < 1e-10 and dare[("jaxanim dare", 2)].success == 1.0

    _, pend = bench_rows(tables, "oc-pendulum")
    row = pend[("jaxanim ilqr", 2)]
    assert row.success == 1.0 and row.accuracy == "n/a (no Crocoddyl)"
    assert pend[("Crocoddyl SolverDDP", None)].skipped.startswith("cannot import crocoddyl")

    comp, crows = bench_rows(tables, "oc-compile")
    assert len(crows) == 4 and all(r.compile_s > 0 for r in comp.rows)  # unicycle, lqr, dare, pendulum
    assert "- Target: iLQR / DDP compile ≤ 5 s: worst jaxanim" in render_table(comp)


def test_reduced_crocoddylbench_rows():
    """Crocoddyl rows alone: the unicycle optimum, the LQ cost convention, a C++ pendulum loop."""
    pytest.importorskip("crocoddyl")
    config = quick_bench_config(only=("crocoddyl*",))
    tables = run_oc(config, _TINY, tables=("unicycle", "lqr", "swing_up"))
    text = "\n".join(render_table(t) for t in tables)
    assert "failed:" not in text and "skipped" not in text

    _, uni = bench_rows(tables, "oc-unicycle")
    for name in ("SolverDDP", "SolverFDDP", "SolverDDP (Python model)"):
        row = uni[(f"Crocoddyl {name}", 1)]
        assert f"cost {_UNICYCLE_T20_COST:.9f}" in row.note, (name, row.note)
        assert row.accuracy < 1e-12
    assert uni[("Crocoddyl SolverBoxDDP", 1)].success == 1.0

    lqr, rows = bench_rows(tables, "oc-lqr")
    rel, du = (float(x) for x in rows[("Crocoddyl SolverDDP", 1)].accuracy.split(" / "))
    assert rel < 1e-9 and du < 1e-7
    assert any("the same problem" in n for n in lqr.notes), lqr.notes

    _, pend = bench_rows(tables, "oc-pendulum")
    row = pend[("Crocoddyl SolverDDP", 2)]
    assert row.chars_per_call >= 2 and row.accuracy == "reference" and row.success == 1.0
    assert "C++ models" in row.note, row.note
    agree, both = pend[("Crocoddyl SolverDDP (1 thread)", 2)].accuracy.split(" ")[0].split("/")  # same solves
    assert agree == both and int(both) >= 2


@pytest.mark.parametrize("name", ["unicycle"])
def test_python_action_models_match_solvers_problems(name):
    """calc / calcDiff of the Python action model equal solvers.problems' callbacks and their
    jax.jacfwd / jax.hessian, at random states and controls, running and terminal."""
    pytest.importorskip("crocoddyl")
    from benchmarks.peers import crocoddyl_oc as co
    from solvers import problems

    prob = getattr(problems, name)(dtype=jnp.float64)
    args = {k: np.asarray(v) for k, v in prob.args.items()}
    cls = co.python_model_class(name)
    running, terminal = cls(args), cls(args, terminal=True)
    rd, td = running.createData(), terminal.createData()
    jargs = {k: jnp.asarray(v) for k, v in args.items()}
    n, m = prob.x0.shape[0], prob.us_init.shape[1]
    rng = np.random.default_rng(3)
    t0 = jnp.asarray(0)

    @jax.jit
    def reference(x, u):
        f = lambda x, u: prob.dynamics(x, u, t0, jargs)  # noqa: E731
        l = lambda x, u: prob.cost(x, u, t0, jargs)  # noqa: E731
        lT = lambda x: prob.terminal_cost(x, jargs)  # noqa: E731
        return dict(
            xnext=f(x, u), cost=l(x, u), Fx=jax.jacfwd(f, 0)(x, u), Fu=jax.jacfwd(f, 1)(x, u),
            Lx=jax.grad(l, 0)(x, u), Lu=jax.grad(l, 1)(x, u), Lxx=jax.hessian(l, 0)(x, u),
            Luu=jax.hessian(l, 1)(x, u), Lxu=jax.jacfwd(jax.grad(l, 0), 1)(x, u),
            costT=lT(x), LxT=jax.grad(lT)(x), LxxT=jax.hessian(lT)(x),
        )

    for _ in range(5):
        x, u = rng.normal(size=n) * 2.0, rng.normal(size=m) * 3.0
        ref = {k: np.asarray(v) for k, v in reference(jnp.asarray(x), jnp.asarray(u)).items()}
        running.calc(rd, x, u)
        running.calcDiff(rd, x, u)
        terminal.calc(td, x)
        terminal.calcDiff(td, x)
        got = dict(xnext=rd.xnext, cost=rd.cost, Fx=rd.Fx, Fu=rd.Fu, Lx=rd.Lx, Lu=rd.Lu, Lxx=rd.Lxx, Luu=rd.Luu,
                   Lxu=rd.Lxu, costT=td.cost, LxT=td.Lx, LxxT=td.Lxx)
        for key, want in ref.items():
            # Crocoddyl returns n x 1 matrices as vectors: compare in the reference's shape
            np.testing.assert_allclose(np.reshape(got[key], want.shape), want, rtol=1e-12, atol=1e-13, err_msg=key)


@pytest.mark.parametrize("name", ["pendulum", "cart_pole"])
def test_cpp_swing_problems_match_jaxanim(name):
    """The C++ Crocoddyl swing-ups (Pinocchio + free forward dynamics + Euler + residual costs) are
    benchmarks.oc.swing_problem: the same states and cost for the same random controls, and, from the
    benchmark's first start, Crocoddyl's solver and jaxanim's ddp converge to the same cost."""
    croc = pytest.importorskip("crocoddyl")
    pytest.importorskip("pinocchio")
    from benchmarks.peers import crocoddyl_oc as co
    from solvers import problems

    T = 60
    prob = swing_problem(name, T)
    x0 = initial_states(name, 1)[0]
    pb = co.swing_problem(name, prob.args, x0, T)
    pb.nthreads = 1  # Crocoddyl's OpenMP threads crawl when the test workers hold the cores
    pinned = pb.runningModels[0].nu - 1  # the cart-pole's pole torque, held at 0 by u_lb = u_ub = 0
    us = np.random.default_rng(5).normal(size=prob.us_init.shape) * 3.0
    us_croc = [np.r_[u, np.zeros(pinned)] for u in us]
    xs_ref, cost_ref = (np.asarray(z) for z in prob.rollout(us, x0))
    xs = np.array(pb.rollout(us_croc))
    np.testing.assert_allclose(xs, xs_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(pb.calc(list(xs), us_croc), cost_ref, rtol=1e-13)

    solver = getattr(croc, "SolverBoxDDP" if pinned else "SolverDDP")(pb)
    solver.th_stop = SWING_STOP
    us0 = [np.zeros(pinned + 1)] * T
    assert solver.solve(pb.rollout(us0), us0, SWING_MAX_STEPS[name], True)
    out = prob.solve("ddp", x0=jnp.asarray(x0), max_steps=SWING_MAX_STEPS[name], atol=SWING_STOP, rtol=0.0)
    np.testing.assert_allclose(solver.cost, float(out.cost), rtol=1e-8)
    assert abs(np.array(solver.xs)[-1, 1 if pinned else 0] - np.pi) < 0.1  # a swing-up, not a stationary start
    np.testing.assert_array_equal(np.array(solver.us)[:, 1:], 0.0)
    if name == "pendulum":  # the problems' default damping has no C++ construction: refused, not dropped
        with pytest.raises(ValueError, match="damping"):
            co.pinocchio_model(name, problems.pendulum().args)


def test_problem_generators():
    x0 = initial_states("cart_pole", 5)
    assert x0.shape == (5, 4) and np.all(np.abs(x0[:, 1]) <= 0.3)
    np.testing.assert_array_equal(initial_states("pendulum", 3), initial_states("pendulum", 3))
    A, B, Q, R = make_dare_systems(3, n=3, m=2)
    np.testing.assert_allclose(np.abs(np.linalg.eigvals(A)).max(axis=-1), 1.1, rtol=1e-12)
    scipy_linalg = pytest.importorskip("scipy.linalg")
    P = np.stack([scipy_linalg.solve_discrete_are(A[i], B[i], Q[i], R[i]) for i in range(3)])
    assert riccati_residual(A, B, Q, R, P).max() < 1e-10
