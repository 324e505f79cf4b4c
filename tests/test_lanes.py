"""solvers._lanes: a batched while loop compacted onto lanes equals the plain vmapped
``lax.while_loop`` element by element (and the one-instance loop), in input order, with
per-element trip counts, batched and shared closed-over data (also integers), a batch that is not
a multiple of the lanes, nested vmap and forward mode; and the solvers that run on it (the
iteration driver, DARE, iLQR) give each problem the result it gets alone. ``repeat_while`` (passes that most problems
skip) equals the passes one problem at a time."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import solvers
from solvers import problems
from solvers._iterate import iterate
from solvers._lanes import hoist_closure, while_loop
from solvers._riccati import _DOUBLING_LANES

_LANES = 8
_B = 3 * _LANES + 5  # more problems than lanes, not a multiple of them
_A = jnp.asarray(np.random.default_rng(0).uniform(0.01, 1e6, _B))


def _newton_sqrt(a, scale, loop=while_loop):
    """``scale * sqrt(a)`` by Newton's iteration: a trip count that depends on ``a``."""

    def body(c):
        y, k = c
        return 0.5 * (y + a / y), k + 1

    kw = dict(lanes=_LANES) if loop is while_loop else {}
    y, k = loop(lambda c: (jnp.abs(c[0] ** 2 - a) > 1e-13 * a) & (c[1] < 60), body, (jnp.ones_like(a), 0), **kw)
    return y * scale, k


def test_compacted_equals_plain_vmap_and_one_instance_loops():
    got_y, got_k = jax.jit(jax.vmap(_newton_sqrt, in_axes=(0, None)))(_A, 3.0)
    ref_y, ref_k = jax.jit(jax.vmap(lambda a, s: _newton_sqrt(a, s, jax.lax.while_loop), in_axes=(0, None)))(_A, 3.0)
    np.testing.assert_array_equal(np.asarray(got_k), np.asarray(ref_k))
    assert len(set(np.asarray(got_k).tolist())) > 3  # the trip counts differ: lanes were really reused
    np.testing.assert_allclose(np.asarray(got_y), np.asarray(ref_y), rtol=1e-15, atol=0)
    np.testing.assert_allclose(np.asarray(got_y), 3.0 * np.sqrt(np.asarray(_A)), rtol=1e-12)
    one = jax.jit(_newton_sqrt)  # unbatched: the plain while loop
    for i in (0, _LANES, _B - 1):
        y, k = one(_A[i], 3.0)
        assert int(k) == int(got_k[i]) and abs(float(y) - float(got_y[i])) <= 1e-15 * float(y)


def test_batched_closure_of_integers_and_small_batches():
    def run(a, n):  # the loop closes over a batched int ``n``: its own trip count
        return while_loop(lambda c: c[1] < n, lambda c: (c[0] + a, c[1] + 1), (jnp.zeros_like(a), 0), lanes=_LANES)

    n = jnp.arange(_B) % 7
    total, k = jax.jit(jax.vmap(run))(_A, n)
    np.testing.assert_array_equal(np.asarray(k), np.asarray(n))
    np.testing.assert_allclose(np.asarray(total), np.asarray(_A) * np.asarray(n), rtol=1e-15)
    small, _ = jax.vmap(run)(_A[:3], n[:3])  # fewer problems than lanes: one plain vmapped loop
    np.testing.assert_allclose(np.asarray(small), np.asarray(_A[:3] * n[:3]), rtol=1e-15)
    conv, consts = hoist_closure(lambda x: x * 2.0, _A[0])  # nothing to hoist outside a trace
    assert consts == [] and float(conv(_A[0])) == 2.0 * float(_A[0])


def test_nested_vmap_and_forward_mode():
    grid = jnp.concatenate([_A, _A[:13]]).reshape(2, 21)  # characters x frames
    y, _ = jax.jit(jax.vmap(jax.vmap(_newton_sqrt, in_axes=(0, None)), in_axes=(0, None)))(grid, 1.0)
    np.testing.assert_allclose(np.asarray(y), np.sqrt(np.asarray(grid)), rtol=1e-12)
    tangent = jax.jit(jax.vmap(lambda a: jax.jvp(lambda x: _newton_sqrt(x, 1.0)[0], (a,), (1.0,))[1]))
    np.testing.assert_allclose(np.asarray(tangent(_A)), 0.5 / np.sqrt(np.asarray(_A)), rtol=1e-9)


def test_iterate_adaptive_under_vmap_equals_per_element_runs():
    def run(a):
        it = iterate(lambda y: 0.5 * (y + a / y), jnp.ones_like(a), done=lambda y: jnp.abs(y * y - a) <= 1e-12 * a,
                     max_steps=60, record=lambda y: y, lanes=_LANES)
        return it.state, it.num_steps, it.history

    y, k, hist = jax.jit(jax.vmap(run))(_A)
    one = jax.jit(run)
    for i in (1, _LANES + 3, _B - 1):
        yi, ki, hi = one(_A[i])
        assert int(ki) == int(k[i]) and float(yi) == float(y[i])
        np.testing.assert_array_equal(np.asarray(hist[i]), np.asarray(hi))


def test_batched_dare_equals_one_system_solves():
    rng = np.random.default_rng(3)
    n, m, count = 4, 2, _DOUBLING_LANES + 12  # past the doubling's lanes
    A = rng.standard_normal((count, n, n)) * 0.6
    B = rng.standard_normal((count, n, m))
    Q, R = np.eye(n), np.eye(m)
    sol = jax.jit(jax.vmap(lambda A, B: solvers.dare(A, B, Q, R)))(A, B)
    one = jax.jit(lambda A, B: solvers.dare(A, B, Q, R))
    for i in (0, _DOUBLING_LANES, count - 1):
        s = one(A[i], B[i])
        np.testing.assert_allclose(np.asarray(sol.P[i]), np.asarray(s.P), rtol=1e-12, atol=1e-12)
        assert int(sol.stats["num_steps"][i]) == int(s.stats["num_steps"])


def test_batched_ilqr_equals_one_problem_solves():
    prob = problems.pendulum(T=20)
    count = 140
    rng = np.random.default_rng(5)
    x0s = jnp.asarray(np.stack([rng.uniform(-0.8, 0.8, count), rng.uniform(-0.5, 0.5, count)], -1))

    def solve(x0):
        return solvers.ilqr(prob.dynamics, prob.cost, x0, prob.us_init, terminal_cost=prob.terminal_cost,
                            args=prob.args, max_steps=40)

    out = jax.jit(jax.vmap(solve))(x0s)
    steps = np.asarray(out.stats["num_steps"])
    assert steps.min() < steps.max()
    one = jax.jit(solve)
    for i in (0, 128, count - 1):
        s = one(x0s[i])
        assert int(s.stats["num_steps"]) == int(steps[i])
        np.testing.assert_allclose(np.asarray(out.us[i]), np.asarray(s.us), rtol=1e-9, atol=1e-11)
        np.testing.assert_allclose(float(out.cost[i]), float(s.cost), rtol=1e-12)


def test_lane_map_equals_vmap_in_chunks():
    """``lane_map`` under vmap (more problems than lanes, not a multiple of them; a pytree argument with a shared
    leaf; a closed-over batched value) equals ``jax.vmap`` of the function; one instance is the function itself."""
    from solvers._lanes import lane_map

    def fun(a, tree, s):
        return lane_map(lambda x, t: (jnp.sin(x) * t["w"] + t["c"] * s, x**2), a, tree, lanes=_LANES)

    tree = {"w": _A * 0.5, "c": jnp.asarray(2.0)}  # "c" shared by every element
    s = jnp.arange(_B, dtype=_A.dtype)
    got = jax.jit(jax.vmap(fun, in_axes=(0, {"w": 0, "c": None}, 0)))(_A, tree, s)
    ref = (jnp.sin(_A) * tree["w"] + 2.0 * s, _A**2)
    for g, r in zip(got, ref):
        assert g.shape == r.shape
        np.testing.assert_allclose(np.asarray(g), np.asarray(r), rtol=1e-15)
    one = fun(_A[3], {"w": tree["w"][3], "c": tree["c"]}, s[3])
    np.testing.assert_allclose(np.asarray(one[0]), np.asarray(ref[0][3]), rtol=1e-15)


def test_lane_map_reverse_chunks_a_reverse_mode_only_loop_and_keeps_its_gradient():
    """``lane_map(reverse=True)`` around a checkpointed while loop (no forward mode): batched values in chunks
    equal ``jax.vmap`` of the loop, and ``jax.grad`` through the chunked call (a custom VJP: the loop's own
    reverse pass) equals the plain gradient, with an integer output in the result."""
    import equinox.internal as eqxi

    from solvers._lanes import lane_map

    def newton(a, s):  # sqrt(a) * s by Newton's iteration, adaptive: each element its own trip count
        def body(c):
            x, k = c
            return 0.5 * (x + a / x), k + 1

        x, k = eqxi.while_loop(lambda c: jnp.abs(c[0] * c[0] - a) > 1e-12 * a, body, (a + 1.0, jnp.asarray(0)),
                               max_steps=200, kind="checkpointed")
        return x * s, k

    def chunked(a, s):
        return lane_map(newton, a, s, lanes=_LANES, reverse=True)

    s = jnp.linspace(0.5, 1.5, _B)
    got, ref = jax.jit(jax.vmap(chunked))(_A, s), jax.jit(jax.vmap(newton))(_A, s)
    np.testing.assert_allclose(np.asarray(got[0]), np.asarray(ref[0]), rtol=1e-15)
    np.testing.assert_array_equal(np.asarray(got[1]), np.asarray(ref[1]))
    assert len(set(np.asarray(ref[1]).tolist())) > 3  # trip counts differ
    loss = lambda f: lambda a, s: jnp.sum(jax.vmap(f)(a, s)[0] ** 2)  # noqa: E731
    ga, gs = jax.jit(jax.grad(loss(chunked), argnums=(0, 1)))(_A, s)
    ra, rs = jax.jit(jax.grad(loss(newton), argnums=(0, 1)))(_A, s)
    np.testing.assert_allclose(np.asarray(ga), np.asarray(ra), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(gs), np.asarray(rs), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(gs), 2 * s * _A, rtol=1e-9)  # d/ds (sqrt(a) s)^2


def test_repeat_while_equals_the_passes_one_by_one():
    """``repeat_while`` under vmap (more problems than lanes, the first pass in chunks narrower than the batch; no
    problem, one, more than the lanes and all of them needing the later passes; a batched and a shared closed-over
    value) equals each problem's one-instance call, which equals the passes written out; forward and reverse mode are
    those of the passes run."""
    from solvers._lanes import repeat_while

    x = jnp.asarray(np.random.default_rng(1).normal(size=(_B, 3)))
    w = jnp.asarray(np.random.default_rng(2).uniform(0.5, 2.0, size=_B))
    c = jnp.asarray(0.5)

    def fun(xi, wi, cut):  # pass i adds (i + c) * w to the first entry while it is below cut
        return repeat_while(lambda i, a: a.at[0].add((i + c) * wi), lambda a: a[0] < cut, xi, times=4, lanes=_LANES,
                            width=_LANES + 3)

    def written_out(xi, wi, cut):
        a = xi.at[0].add(c * wi)
        for i in (1, 2, 3):
            if float(a[0]) >= cut:
                break
            a = a.at[0].add((i + c) * wi)
        return a

    for keyword, value in (("width", 0), ("lanes", 2.0), ("times", 0)):  # named, not a division by zero inside
        counts = {"times": 4, "lanes": _LANES, "width": _LANES, keyword: value}
        with pytest.raises(ValueError, match=f"{keyword}: expected an int >= 1, got {value!r}"):
            jax.vmap(lambda xi: repeat_while(lambda i, a: a, lambda a: a[0] < 0, xi, **counts))(x)

    batched = jax.jit(jax.vmap(fun, in_axes=(0, 0, None)))
    for cut in (-10.0, -1.5, 1.0, 10.0):  # none, one, more than the lanes (20) and all of them run a later pass
        got = batched(x, w, cut)
        for i in range(_B):
            want = written_out(x[i], w[i], cut)
            np.testing.assert_allclose(np.asarray(got[i]), np.asarray(want), rtol=1e-15, atol=1e-15)
            if i % 7 == 0:
                np.testing.assert_allclose(np.asarray(fun(x[i], w[i], cut)), np.asarray(want), rtol=1e-15, atol=1e-15)
    # the derivative with respect to w: the passes run contribute (i + c) each
    i = int(np.argmax(np.asarray(x[:, 0]) < -1.0))
    grad = jax.grad(lambda wi: fun(x[i], wi, 0.0)[0])(w[i])
    tangent = jax.jvp(lambda wi: fun(x[i], wi, 0.0)[0], (w[i],), (jnp.ones(()),))[1]
    passes = np.cumsum([0.5, 1.5, 2.5, 3.5]) * float(w[i]) + float(x[i, 0])
    taken = 1 + int(np.sum(passes[:3] < 0.0))
    expected = float(np.sum(np.arange(taken) + 0.5))
    assert float(grad) == pytest.approx(expected, rel=1e-15) and float(tangent) == pytest.approx(expected, rel=1e-15)
