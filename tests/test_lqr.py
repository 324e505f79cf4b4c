"""solvers.lqr: finite-horizon LQR, DARE and CARE.

References: ``../shared/data/lqr/lqr_refs.json`` (scipy, cross-checked against SLICOT), a dense KKT
solve in numpy of the same finite-horizon problem (cross and affine terms included),
``scipy.linalg.solve_discrete_are`` / ``solve_continuous_are`` on random stabilizable systems,
and central finite differences for the implicit derivatives.
"""

import functools
import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

import solvers
from solvers import RESULTS, care, dare, lqr

from .conftest import shared_data_dir
from .helpers import assert_close, count_traces

_TOL_REF = 1e-9  # against the scipy/SLICOT reference values (relative and absolute)
_TOL_KKT = 1e-9  # finite-horizon LQR against the dense KKT solve
_TOL_RESIDUAL = 1e-10  # max |Riccati residual|
_TOL_SCIPY = 1e-9  # DARE/CARE against scipy (relative to max |P|)
_TOL_GRAD = 1e-6  # implicit derivative against central finite differences (relative)


@functools.lru_cache(maxsize=None)
def _refs() -> dict:
    return json.loads((shared_data_dir() / "lqr" / "lqr_refs.json").read_text())


def _ref_cases(kind: str) -> list[str]:
    # The names are fixed by make_refs.py; listing them here keeps the parametrisation independent of
    # whether the data is present (the tests skip with the reason when it is not).
    names = {
        "continuous": ["double_integrator_continuous", "scalar_continuous", "cartpole_linearised_continuous"],
        "discrete": [
            "scalar_discrete",
            "double_integrator_discrete_dt0.1",
            "cartpole_linearised_discrete_euler_dt0.02",
            "random_5x2_discrete_seed7",
        ],
    }
    return names[kind]


def _ref_case(name: str) -> dict:
    cases = {c["name"]: c for c in _refs()["infinite_horizon"]}
    return cases[name]


def random_system(seed: int, n: int, m: int, *, cross: bool = False, radius: float = 1.1, continuous=False):
    """A random stabilizable (generic B) system with some unstable modes and a PD joint cost.

    ``[[Q, S'], [S, R]]`` is positive definite, so ``Q - S' R^-1 S`` is too (detectability).
    """
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    if continuous:
        A = A / np.sqrt(n) + 0.2 * np.eye(n)  # some eigenvalues with positive real part
    else:
        A = A * (radius / np.max(np.abs(np.linalg.eigvals(A))))
    B = rng.normal(size=(n, m))
    Z = rng.normal(size=(n + m, n + m))
    W = Z @ Z.T / (n + m) + 0.1 * np.eye(n + m)
    Q, R = W[:n, :n], W[n:, n:]
    S = W[n:, :n] if cross else None
    return A, B, Q, R, S


# ---------------------------------------------------------------------------------------------
# Reference data (scipy / SLICOT).
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", _ref_cases("discrete"))
def test_dare_matches_reference(name):
    case = _ref_case(name)
    sol = dare(*(np.array(case[k]) for k in "ABQR"), throw=True)
    assert sol.result == RESULTS.successful
    assert_close(f"{name}.P", sol.P, case["P"], rtol=_TOL_REF, atol=_TOL_REF)
    assert_close(f"{name}.K", sol.K, case["K"], rtol=_TOL_REF, atol=_TOL_REF)


@pytest.mark.parametrize("name", _ref_cases("continuous"))
def test_care_matches_reference(name):
    case = _ref_case(name)
    sol = care(*(np.array(case[k]) for k in "ABQR"), throw=True)
    assert sol.result == RESULTS.successful
    assert_close(f"{name}.P", sol.P, case["P"], rtol=_TOL_REF, atol=_TOL_REF)
    assert_close(f"{name}.K", sol.K, case["K"], rtol=_TOL_REF, atol=_TOL_REF)


def test_finite_horizon_matches_reference():
    ref = _refs()["finite_horizon"]
    N = ref["N"]
    stack = lambda M: np.broadcast_to(np.array(M), (N,) + np.shape(M))  # noqa: E731
    sol = lqr(stack(ref["A"]), stack(ref["B"]), stack(ref["Q"]), stack(ref["R"]), np.array(ref["Qf"]),
              np.array(ref["x0"]), throw=True)
    assert sol.result == RESULTS.successful
    sol = jax.device_get(sol)
    # The reference applies u = -K x; lqr applies u = K x + k.
    assert_close("Ks", -sol.Ks, ref["K_t"], rtol=_TOL_REF, atol=_TOL_REF)
    assert_close("ks", sol.ks, np.zeros((N, 1)), atol=_TOL_REF)
    assert_close("Ps[0]", sol.Ps[0], ref["P0"], rtol=_TOL_REF, atol=_TOL_REF)
    assert_close("cost", sol.cost, ref["optimal_cost"], rtol=_TOL_REF)
    assert_close("value(x0)", 0.5 * sol.xs[0] @ sol.Ps[0] @ sol.xs[0], ref["optimal_cost_from_P0"], rtol=_TOL_REF)


# ---------------------------------------------------------------------------------------------
# Finite horizon against a dense KKT solve.
# ---------------------------------------------------------------------------------------------


def random_lq_problem(seed: int, T: int = 6, n: int = 3, m: int = 2) -> dict:
    rng = np.random.default_rng(seed)
    A = np.eye(n) + 0.3 * rng.normal(size=(T, n, n))
    B = rng.normal(size=(T, n, m))
    Z = rng.normal(size=(T, n + m, n + m))
    W = Z @ np.swapaxes(Z, 1, 2) / (n + m) + 0.1 * np.eye(n + m)
    ZT = rng.normal(size=(n, n))
    return dict(
        A=A, B=B, Q=W[:, :n, :n], R=W[:, n:, n:], QT=ZT @ ZT.T / n + 0.1 * np.eye(n), x0=rng.normal(size=n),
        S=W[:, n:, :n], q=rng.normal(size=(T, n)), r=rng.normal(size=(T, m)), qT=rng.normal(size=n),
        c=rng.normal(size=(T, n)),
    )


def kkt_solve(p: dict, x0: np.ndarray):
    """Dense KKT solve of the LQ problem: ``(xs, us, cost, z, H, h)``, z = [x_0..x_T, u_0..u_{T-1}]."""
    A, B = p["A"], p["B"]
    T, n, m = B.shape
    nx = (T + 1) * n
    N = nx + T * m
    xi = lambda t: slice(t * n, (t + 1) * n)  # noqa: E731
    ui = lambda t: slice(nx + t * m, nx + (t + 1) * m)  # noqa: E731
    H = np.zeros((N, N))
    h = np.zeros(N)
    C = np.zeros(((T + 1) * n, N))
    d = np.zeros((T + 1) * n)
    C[:n, xi(0)] = np.eye(n)
    d[:n] = x0
    for t in range(T):
        H[xi(t), xi(t)] = p["Q"][t]
        H[ui(t), ui(t)] = p["R"][t]
        H[ui(t), xi(t)] = p["S"][t]
        H[xi(t), ui(t)] = p["S"][t].T
        h[xi(t)] = p["q"][t]
        h[ui(t)] = p["r"][t]
        rows = slice((t + 1) * n, (t + 2) * n)
        C[rows, xi(t + 1)] = np.eye(n)
        C[rows, xi(t)] = -A[t]
        C[rows, ui(t)] = -B[t]
        d[rows] = p["c"][t]
    H[xi(T), xi(T)] = p["QT"]
    h[xi(T)] = p["qT"]
    kkt = np.block([[H, C.T], [C, np.zeros((C.shape[0], C.shape[0]))]])
    z = np.linalg.solve(kkt, np.concatenate([-h, d]))[:N]
    cost = 0.5 * z @ H @ z + h @ z
    return z[:nx].reshape(T + 1, n), z[nx:].reshape(T, m), cost, z, H, h


@pytest.mark.parametrize("seed", [0, 1])
def test_lqr_matches_dense_kkt(seed):
    p = random_lq_problem(seed)
    kw = {k: p[k] for k in ("S", "q", "r", "qT", "c")}
    sol = lqr(p["A"], p["B"], p["Q"], p["R"], p["QT"], p["x0"], **kw)
    assert sol.result == RESULTS.successful
    sol = jax.device_get(sol)  # the arithmetic below in numpy (eager jax ops compile one program each)
    xs, us, cost, z, H, h = kkt_solve(p, p["x0"])
    assert_close("xs", sol.xs, xs, atol=_TOL_KKT, rtol=_TOL_KKT)
    assert_close("us", sol.us, us, atol=_TOL_KKT, rtol=_TOL_KKT)
    assert_close("cost", sol.cost, cost, atol=_TOL_KKT, rtol=_TOL_KKT)
    value = 0.5 * p["x0"] @ sol.Ps[0] @ p["x0"] + sol.ps[0] @ p["x0"] + sol.vs[0]
    assert_close("value(x0)", value, cost, atol=_TOL_KKT, rtol=_TOL_KKT)
    # The KKT solution is affine in x0, z(x0) = z(0) + Z x0; the value is quadratic with Hessian
    # Z'HZ = P_0 and gradient at 0 Z'(H z(0) + h) = p_0, and u_0(x0) = K_0 x0 + k_0.
    n, T, m = p["x0"].shape[0], *p["r"].shape
    z0 = kkt_solve(p, np.zeros(n))[3]
    Z = np.stack([kkt_solve(p, e)[3] - z0 for e in np.eye(n)], axis=1)
    assert_close("Ps[0]", sol.Ps[0], Z.T @ H @ Z, atol=_TOL_KKT, rtol=_TOL_KKT)
    assert_close("ps[0]", sol.ps[0], Z.T @ (H @ z0 + h), atol=_TOL_KKT, rtol=_TOL_KKT)
    u0 = slice((T + 1) * n, (T + 1) * n + m)
    assert_close("Ks[0]", sol.Ks[0], Z[u0], atol=_TOL_KKT, rtol=_TOL_KKT)
    assert_close("ks[0]", sol.ks[0], z0[u0], atol=_TOL_KKT, rtol=_TOL_KKT)
    # the policy reproduces the trajectory, and the last step's value data are the terminal cost
    assert_close("us = Ks xs + ks", np.einsum("tij,tj->ti", sol.Ks, sol.xs[:-1]) + sol.ks, us, atol=_TOL_KKT)
    assert_close("Ps[T]", sol.Ps[-1], p["QT"], atol=0)


def test_lqr_vmap_equals_loop_and_bad_hessian():
    p = random_lq_problem(3)  # the shapes of test_lqr_matches_dense_kkt: its compiled solve is reused
    kw = {k: p[k] for k in ("S", "q", "r", "qT", "c")}
    x0s = np.random.default_rng(0).normal(size=(3, p["x0"].shape[0]))
    R = np.stack([p["R"], p["R"], -1e3 * np.broadcast_to(np.eye(2), p["R"].shape)])  # the third is concave in u
    f = lambda x0, R: lqr(p["A"], p["B"], p["Q"], R, p["QT"], x0, **kw)  # noqa: E731
    batch = jax.vmap(f)(x0s, R)
    assert list(np.asarray(batch.result == RESULTS.successful)) == [True, True, False]
    assert np.asarray(batch.result == RESULTS.not_positive_definite)[2], "result[2]"
    for i in range(2):
        one = f(x0s[i], R[i])
        for field in ("xs", "us", "Ks", "ks", "Ps", "ps", "vs", "cost"):
            assert_close(f"{field}[{i}]", getattr(batch, field)[i], getattr(one, field), atol=1e-10, rtol=1e-10)
    with pytest.raises(eqx.EquinoxRuntimeError, match="not positive definite"):
        lqr(p["A"], p["B"], p["Q"], R[2], p["QT"], x0s[2], **kw, throw=True)


# ---------------------------------------------------------------------------------------------
# DARE / CARE against scipy.
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed,cross", [(0, False), (1, True), (2, True)])
def test_dare_matches_scipy(seed, cross):
    A, B, Q, R, S = random_system(seed, 12, 4, cross=cross)
    sol = dare(A, B, Q, R, S=S)
    assert sol.result == RESULTS.successful
    P = scipy.linalg.solve_discrete_are(A, B, Q, R, s=None if S is None else S.T)
    Sm = np.zeros((4, 12)) if S is None else S
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A + Sm)
    scale = np.max(np.abs(P))
    assert_close("P", sol.P, P, atol=_TOL_SCIPY * scale)
    assert_close("K", sol.K, K, atol=_TOL_SCIPY * np.max(np.abs(K)))
    assert float(sol.stats["residual"]) < _TOL_RESIDUAL, "residual"
    Pj = np.asarray(sol.P)
    F = A.T @ Pj @ A - Pj - (A.T @ Pj @ B + Sm.T) @ np.linalg.solve(R + B.T @ Pj @ B, B.T @ Pj @ A + Sm) + Q
    assert np.max(np.abs(F)) < _TOL_RESIDUAL, "residual (numpy)"
    assert np.max(np.abs(np.linalg.eigvals(A - B @ np.asarray(sol.K)))) < 1, "closed loop stable"
    assert 0 < int(sol.stats["num_steps"]) <= 20, "num_steps"


@pytest.mark.parametrize("seed,cross", [(0, False), (1, True)])
def test_care_matches_scipy(seed, cross):
    A, B, Q, R, S = random_system(seed, 6, 2, cross=cross, continuous=True)
    sol = care(A, B, Q, R, S=S)
    assert sol.result == RESULTS.successful
    P = scipy.linalg.solve_continuous_are(A, B, Q, R, s=None if S is None else S.T)
    Sm = np.zeros((2, 6)) if S is None else S
    K = np.linalg.solve(R, B.T @ P + Sm)
    assert_close("P", sol.P, P, atol=_TOL_SCIPY * np.max(np.abs(P)))
    assert_close("K", sol.K, K, atol=_TOL_SCIPY * np.max(np.abs(K)))
    assert float(sol.stats["residual"]) < _TOL_RESIDUAL, "residual"
    assert np.max(np.real(np.linalg.eigvals(A - B @ np.asarray(sol.K)))) < 0, "closed loop stable"


def test_dare_fixed_steps_vmap_equals_loop():
    systems = [random_system(s, 4, 2, cross=True) for s in range(3)]  # the gradient test's shapes
    A, B, Q, R, S = (np.stack(x) for x in zip(*systems))
    for fixed in (False, True):
        batch = jax.vmap(functools.partial(dare, max_steps=30, fixed_steps=fixed))(A, B, Q, R, S=S)
        for i in range(3):
            one = dare(A[i], B[i], Q[i], R[i], S=S[i])
            assert one.result == RESULTS.successful
            assert np.asarray(batch.result == RESULTS.successful)[i], f"result[{i}]"
            assert_close(f"P[{i}] fixed={fixed}", batch.P[i], one.P, atol=1e-10, rtol=1e-10)
            assert_close(f"K[{i}] fixed={fixed}", batch.K[i], one.K, atol=1e-10, rtol=1e-10)
            assert int(batch.stats["num_steps"][i]) == int(one.stats["num_steps"]), "num_steps"


def test_care_vmap_equals_loop():
    systems = [random_system(s, 4, 2, continuous=True) for s in range(3)]
    A, B, Q, R, _ = (np.stack(x) if x[0] is not None else None for x in zip(*systems))
    batch = jax.vmap(care)(A, B, Q, R)
    for i in range(3):
        one = care(A[i], B[i], Q[i], R[i])
        assert np.asarray(batch.result == RESULTS.successful)[i], f"result[{i}]"
        assert_close(f"P[{i}]", batch.P[i], one.P, atol=1e-10, rtol=1e-10)


# ---------------------------------------------------------------------------------------------
# Failures: per element under vmap, no exception.
# ---------------------------------------------------------------------------------------------


def _unstabilizable_batch(continuous: bool):
    """Three 3-state, 1-input systems; the middle one has an unstable mode that B cannot reach."""
    lam = 0.6 if continuous else 1.5
    A_bad = np.diag([lam, -1.0 if continuous else 0.5, -2.0 if continuous else 0.3])
    B_bad = np.array([[0.0], [1.0], [1.0]])
    rng = np.random.default_rng(5)
    A_ok = np.diag([lam, -1.0 if continuous else 0.5, -2.0 if continuous else 0.3]) + 0.1 * rng.normal(size=(3, 3))
    B_ok = np.array([[1.0], [1.0], [0.5]])
    A = np.stack([A_ok, A_bad, A_ok])
    B = np.stack([B_ok, B_bad, B_ok])
    Q = np.stack([np.eye(3), np.eye(3), np.eye(3)])
    R = np.ones((3, 1, 1))
    return A, B, Q, R


@pytest.mark.parametrize("continuous", [False, True])
def test_unstabilizable_gives_status_under_vmap(continuous):
    A, B, Q, R = _unstabilizable_batch(continuous)
    solve = care if continuous else dare
    batch = jax.vmap(solve)(A, B, Q, R)
    assert list(np.asarray(batch.result == RESULTS.successful)) == [True, False, True]
    assert np.asarray(batch.result == RESULTS.no_stabilising_solution)[1], "result[1]"
    assert np.all(np.isfinite(np.asarray(batch.P[0]))) and np.all(np.isfinite(np.asarray(batch.P[2])))
    # an unstable mode that neither B reaches nor Q weights: P = 0 there solves the equation but
    # does not stabilize; still a failure
    Q0 = np.diag([0.0, 1.0, 1.0])
    assert solve(A[1], B[1], Q0, R[1]).result != RESULTS.successful
    if not continuous:  # (one throw test is enough: it compiles another function)
        with pytest.raises(eqx.EquinoxRuntimeError, match="stabilizing"):
            solve(A[1], B[1], Q[1], R[1], throw=True)


def test_dare_failure_statuses():
    A, B, Q, R, _ = random_system(0, 3, 1)
    bad_A = A.copy()
    bad_A[0, 0] = np.nan
    assert dare(bad_A, B, Q, R).result == RESULTS.no_stabilising_solution, "NaN in A"
    assert dare(A, B, Q, -R).result == RESULTS.no_stabilising_solution, "R negative definite"
    short = dare(A, B, Q, R, max_steps=1)
    assert short.result == RESULTS.max_steps_reached, "max_steps=1"
    assert int(short.stats["num_steps"]) == 1, "num_steps"


# ---------------------------------------------------------------------------------------------
# Implicit derivatives against central finite differences.
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("continuous", [False, True])
def test_riccati_gradients_match_finite_differences(continuous):
    A, B, Q, R, S = random_system(11, 4, 2, cross=True, continuous=continuous)
    solve = care if continuous else dare
    rng = np.random.default_rng(1)
    Wp = rng.normal(size=(4, 4))
    Wk = rng.normal(size=(2, 4))
    args = dict(A=A, B=B, Q=Q, R=R, S=S)

    def f(A, B, Q, R, S):
        sol = solve(A, B, Q, R, S=S)
        return jnp.sum(Wp * sol.P) + jnp.sum(Wk * sol.K)

    # each derivative jitted whole: one program apiece (eager, the AD of the jitted solve compiles its
    # linearized and transposed parts separately, and the sums around it op by op); the differences
    # use the values of the gradient's program (a forward program of its own: ~0.5 s more to compile)
    value_and_grads = jax.jit(jax.value_and_grad(f, argnums=tuple(range(5))))
    _, grads = value_and_grads(*args.values())
    h = 1e-6
    tangents = {k: rng.normal(size=np.shape(v)) for k, v in args.items()}

    def f_at(name, x):
        return value_and_grads(*(x if k == name else v for k, v in args.items()))[0]

    for (name, x), g in zip(args.items(), grads):
        D = tangents[name]
        fd = (f_at(name, x + h * D) - f_at(name, x - h * D)) / (2 * h)
        assert_close(f"grad {name}", np.vdot(g, D), fd, rtol=_TOL_GRAD, atol=_TOL_GRAD)
    if continuous:
        return
    # forward mode agrees with reverse mode
    _, jvp = jax.jit(lambda xs, ts: jax.jvp(f, xs, ts))(tuple(args.values()), tuple(tangents.values()))
    total = sum(np.vdot(g, tangents[k]) for k, g in zip(args, grads))
    assert_close("jvp", jvp, total, rtol=1e-10, atol=1e-10)
    # second order: a Hessian-vector product in A against finite differences of the gradient
    rest = tuple(args.values())[1:]
    grad_A = lambda A: value_and_grads(A, *rest)[1][0]  # noqa: E731
    _, hvp = jax.jit(lambda A, dA: jax.jvp(lambda A: jax.grad(f)(A, *rest), (A,), (dA,)))(A, tangents["A"])
    h2 = 1e-5
    fd2 = (grad_A(A + h2 * tangents["A"]) - grad_A(A - h2 * tangents["A"])) / (2 * h2)
    assert_close("hvp A", hvp, fd2, rtol=1e-6, atol=1e-6 * np.max(np.abs(fd2)))


# ---------------------------------------------------------------------------------------------
# float32, bad input.
# ---------------------------------------------------------------------------------------------


def test_float32():
    A, B, Q, R, S = random_system(4, 5, 2, cross=True)
    f32 = lambda x: np.asarray(x, np.float32)  # noqa: E731
    sol = dare(f32(A), f32(B), f32(Q), f32(R), S=f32(S))
    assert sol.P.dtype == jnp.float32 and sol.result == RESULTS.successful
    P = scipy.linalg.solve_discrete_are(A, B, Q, R, s=S.T)
    assert_close("P float32", sol.P, P, atol=1e-4 * np.max(np.abs(P)))
    p = random_lq_problem(0)
    kw = {k: f32(p[k]) for k in ("S", "q", "r", "qT", "c")}
    fin = lqr(*(f32(p[k]) for k in ("A", "B", "Q", "R", "QT", "x0")), **kw)
    assert fin.xs.dtype == jnp.float32 and fin.result == RESULTS.successful
    assert_close("xs float32", fin.xs, kkt_solve(p, p["x0"])[0], atol=1e-4, rtol=1e-4)


def test_bad_shapes_raise():
    p = random_lq_problem(0, T=4)
    args = [p[k] for k in ("A", "B", "Q", "R", "QT", "x0")]

    def call(i, value, **kw):
        a = list(args)
        if i is not None:
            a[i] = value
        return lqr(*a, **kw)

    with pytest.raises(ValueError, match=r"x0: expected shape \(n,\)"):
        call(5, np.zeros((3, 1)))
    with pytest.raises(ValueError, match=r"A: expected shape \(T, n, n\)"):
        call(0, p["A"][0])
    with pytest.raises(ValueError, match=r"B: expected shape \(T, n, m\) = \(4, 3, 2\), got \(4, 2, 2\)"):
        call(1, p["B"][:, :2])
    with pytest.raises(ValueError, match=r"Q: expected shape \(T, n, n\) = \(4, 3, 3\), got \(3, 3, 3\)"):
        call(2, p["Q"][:3])
    with pytest.raises(ValueError, match=r"R: expected shape \(T, m, m\)"):
        call(3, p["R"][0])
    with pytest.raises(ValueError, match=r"QT: expected shape \(n, n\) = \(3, 3\)"):
        call(4, np.eye(2))
    with pytest.raises(ValueError, match=r"S: expected shape \(T, m, n\) = \(4, 2, 3\), got \(4, 3, 2\)"):
        call(None, None, S=np.swapaxes(p["S"], 1, 2))
    with pytest.raises(ValueError, match=r"c: expected shape \(T, n\)"):
        call(None, None, c=p["c"][:, :2])
    with pytest.raises(ValueError, match=r"qT: expected shape \(n,\) = \(3,\)"):
        call(None, None, qT=np.zeros(2))
    A, B, Q, R, _ = random_system(0, 3, 1)
    with pytest.raises(ValueError, match=r"A: expected a square matrix"):
        dare(A[:2], B, Q, R)
    with pytest.raises(ValueError, match=r"R: expected shape \(m, m\) = \(1, 1\), got \(2, 2\)"):
        dare(A, B, Q, np.eye(2))
    with pytest.raises(ValueError, match=r"S: expected shape \(m, n\) = \(1, 3\), got \(3, 1\)"):
        care(A, B, Q, R, S=np.zeros((3, 1)))
    with pytest.raises(ValueError, match="max_steps: expected an int >= 1"):
        dare(A, B, Q, R, max_steps=0)
    with pytest.raises(ValueError, match="gamma: expected a positive scalar"):
        care(A, B, Q, R, gamma=-1.0)


def test_exports():
    assert solvers.lqr is lqr and solvers.dare is dare and solvers.care is care
    assert solvers.LQRSolution.__name__ == "LQRSolution" and solvers.RiccatiSolution.__name__ == "RiccatiSolution"


def test_second_eager_call_does_not_retrace():
    # Same shapes and static options, new values: lqr and dare reuse their compilations (the shapes
    # of test_lqr_matches_dense_kkt and test_dare_matches_scipy, so nothing new is compiled either).
    first, second = random_lq_problem(0), random_lq_problem(1)
    kw = ("S", "q", "r", "qT", "c")
    lqr(*(first[k] for k in ("A", "B", "Q", "R", "QT", "x0")), **{k: first[k] for k in kw})
    A1, B1, Q1, R1, S1 = random_system(0, 12, 4, cross=True)
    dare(A1, B1, Q1, R1, S=S1)
    A2, B2, Q2, R2, S2 = random_system(1, 12, 4, cross=True)
    with count_traces() as traces:
        sol = lqr(*(second[k] for k in ("A", "B", "Q", "R", "QT", "x0")), **{k: second[k] for k in kw})
        ric = dare(A2, B2, Q2, R2, S=S2)
    assert traces[0] == 0, f"{traces[0]} traces on the second calls"
    assert sol.result == RESULTS.successful and ric.result == RESULTS.successful
