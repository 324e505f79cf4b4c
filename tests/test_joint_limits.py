"""Joint limits (jaxanim.joints.limit_rows, solved in jaxanim.physics.step): a hinge pendulum falls
onto its range's bound and rests there, and moves exactly as the unlimited one while away from it;
a ball-jointed pendulum swings out to its cone and stays on it; a twisted body stops at its twist
bound; MuJoCo's hinge with the same range rests at the same angle; bad limits are errors."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanim import JaxanimError, joints, physics, rigid
from jaxanim import rotations as rot

_R, _L = 0.05, 0.4
_HALF = _L / 2 + _R
_DT = 1 / 240


def _horizontal_capsule():
    """A capsule along +x with one end at the origin (the pivot)."""
    bodies = rigid.make_bodies([("capsule", (_R, _L))], names=("link",))
    q = rot.rotation_between(jnp.array([0.0, 0.0, 1.0]), jnp.array([1.0, 0.0, 0.0]))
    state = rigid.make_state(bodies, position=np.array([[_HALF, 0.0, 0.0]]), orientation=q[None])
    return bodies, state


@functools.lru_cache(maxsize=None)
def _hinge(limit):
    bodies, state = _horizontal_capsule()
    spec = dict(name="pin", type="hinge", parent=None, child="link", anchor=(0.0, 0.0, 0.0), axis=(0.0, 0.0, 1.0))
    if limit is not None:
        spec["limit"] = limit
    return physics.make_model(bodies, joints.make_joints(bodies, state, [spec])), state


def _hinge_angle(traj):
    """The link's angle about +z from +x (the hinge angle, zero at assembly)."""
    tip = traj.position[:, 0]
    return np.arctan2(np.asarray(tip[:, 1]), np.asarray(tip[:, 0]))


@functools.lru_cache(maxsize=None)
def _hinge_runs():
    lower = -0.5
    free_model, state = _hinge(None)
    lim_model, _ = _hinge((lower, 0.5))
    steps = int(2.0 / _DT)
    free = physics.rollout(free_model, state, _DT, steps)
    lim = physics.rollout(lim_model, state, _DT, steps)
    return lower, free, lim


def test_hinge_rests_on_its_lower_bound():
    lower, _, lim = _hinge_runs()
    theta = _hinge_angle(lim.trajectory)
    assert lim.result == physics.SimResult.successful
    assert theta.min() > lower - 0.01, f"overshoot past the bound: {theta.min() - lower:.4f} rad"
    assert abs(theta[-1] - lower) < 2e-3, f"final angle {theta[-1]:.5f} vs bound {lower}"
    assert np.max(np.abs(np.asarray(lim.trajectory.angular_velocity[-60:]))) < 0.05, "not at rest on the bound"


def test_hinge_moves_freely_away_from_its_bound():
    lower, free, lim = _hinge_runs()
    theta_free = _hinge_angle(free.trajectory)
    before = theta_free > lower + 0.1  # the step that could reach the bound is excluded
    first_far = np.argmin(before)  # the first step near the bound
    assert first_far > 10
    np.testing.assert_allclose(np.asarray(lim.trajectory.position[:first_far]),
                               np.asarray(free.trajectory.position[:first_far]), atol=1e-12)


def test_hinge_limit_matches_mujoco_rest_angle():
    mujoco = pytest.importorskip("mujoco")
    lower, _, lim = _hinge_runs()
    model, state = _hinge((lower, 0.5))
    m = mujoco.MjModel.from_xml_string(physics.to_mjcf(model, state, dt=_DT))
    assert m.jnt_limited[0] and np.allclose(m.jnt_range[0], [lower, 0.5])
    d = mujoco.MjData(m)
    for _ in range(int(2.0 / _DT)):
        mujoco.mj_step(m, d)
    # MuJoCo's limits are soft (a small violation under load); ours are held by ERP.
    assert abs(d.qpos[0] - lower) < 0.02
    assert abs(_hinge_angle(lim.trajectory)[-1] - d.qpos[0]) < 0.02


def test_ball_swing_cone_holds_the_pendulum_on_the_cone():
    bodies, state = _horizontal_capsule()
    cone = 0.3
    J = joints.make_joints(bodies, state, [dict(type="ball", parent=None, child="link", anchor=(0.0, 0.0, 0.0),
                                                axis=(1.0, 0.0, 0.0), swing=cone)])
    model = physics.make_model(bodies, J)
    run = physics.rollout(model, state, _DT, int(2.0 / _DT))
    axis = np.asarray(run.trajectory.position[:, 0]) / _HALF  # the link's direction (through the pivot)
    swing = np.arccos(np.clip(axis[:, 0], -1, 1))
    assert swing.max() < cone + 0.01, f"left the cone by {swing.max() - cone:.4f} rad"
    assert abs(swing[-1] - cone) < 2e-3
    # At rest on the cone's lowest line: straight down-tilted in the x-y plane.
    assert abs(axis[-1, 2]) < 1e-3 and axis[-1, 1] < 0


def test_ball_twist_stops_at_its_bound():
    bodies, state = _horizontal_capsule()
    bodies = rigid.make_bodies([("capsule", (_R, _L))], names=("link",), gravity=(0.0, 0.0, 0.0))
    J = joints.make_joints(bodies, state, [dict(type="ball", parent=None, child="link", anchor=(0.0, 0.0, 0.0),
                                                axis=(1.0, 0.0, 0.0), twist=(-0.2, 0.4), swing=1.0)])
    model = physics.make_model(bodies, J)
    torque = jnp.array([[0.05, 0.0, 0.0]])  # about the bone axis
    s = state
    step = jax.jit(lambda s: physics.step(model, s, _DT, physics.Control(torque=torque)))
    orientations = []
    for _ in range(int(1.5 / _DT)):
        s = step(s)
        orientations.append(s.orientation)
    # the twists of all the steps at once (per step, the eager ops and reads took ~2 s of the 3 s test)
    q = np.stack([np.asarray(o)[0] for o in orientations])  # (np: a jnp.stack of 360 arrays compiles a program)
    q_dev = np.asarray(rot.quat_multiply(jnp.asarray(q), rot.quat_conjugate(state.orientation[0])))
    twists = 2 * np.arctan2(q_dev[:, 1], q_dev[:, 0])
    assert twists.max() < 0.4 + 0.01
    assert abs(twists[-1] - 0.4) < 2e-3
    np.testing.assert_allclose(np.asarray(s.position[0]), [_HALF, 0.0, 0.0], atol=1e-3)  # no swing


@pytest.mark.parametrize(
    "spec, match",
    [
        (dict(type="ball", limit=(-1.0, 1.0), axis=(1.0, 0.0, 0.0)), "hinge"),
        (dict(type="hinge", swing=0.5, axis=(0.0, 0.0, 1.0)), "ball"),
        (dict(type="ball", swing=0.5), "axis"),
        (dict(type="ball", swing=-0.5, axis=(1.0, 0.0, 0.0)), "swing"),
        (dict(type="hinge", limit=(0.5, -0.5), axis=(0.0, 0.0, 1.0)), "lower < upper"),
        (dict(type="hinge", limit=(4.0, 5.0), axis=(0.0, 0.0, 1.0)), "excludes"),
    ],
)
def test_bad_limits_are_errors(spec, match):
    bodies, state = _horizontal_capsule()
    with pytest.raises(JaxanimError, match=match):
        joints.make_joints(bodies, state, [dict(parent=None, child="link", anchor=(0.0, 0.0, 0.0), **spec)])


def test_a_cycle_of_joints_is_an_error():
    bodies = rigid.make_bodies([("sphere", (0.1,)), ("sphere", (0.1,))], names=("a", "b"))
    state = rigid.make_state(bodies, position=np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))
    J = joints.make_joints(bodies, state, [
        dict(type="ball", parent="a", child="b", anchor=(0.5, 0.0, 0.0)),
        dict(type="ball", parent="b", child="a", anchor=(0.5, 0.0, 0.0)),
    ])
    with pytest.raises(JaxanimError, match="cycle"):
        physics.make_model(bodies, J)


def test_scan_levels_gives_the_same_steps():
    """A branching tree (free root, two children, a grandchild on a limited hinge) stepped with the
    depth levels written out and in a lax.scan: the same states to round-off (the two programs' small
    matrix-vector products may round differently: 3e-13 after the 60 steps)."""
    bodies = rigid.make_bodies([("capsule", (0.05, 0.3))] * 4, names=("root", "a", "b", "c"))
    pos = np.array([[0.0, 1.0, 0.0], [0.4, 1.0, 0.0], [-0.4, 1.0, 0.0], [0.8, 1.0, 0.0]])
    q = rot.rotation_between(jnp.array([0.0, 0.0, 1.0]), jnp.array([1.0, 0.0, 0.0]))
    state = rigid.make_state(bodies, position=pos, orientation=jnp.broadcast_to(q, (4, 4)),
                             angular_velocity=np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0],
                                                        [0.0, 0.0, -3.0]]))
    J = joints.make_joints(bodies, state, [
        dict(type="ball", parent="root", child="a", anchor=(0.2, 1.0, 0.0)),
        dict(type="ball", parent="root", child="b", anchor=(-0.2, 1.0, 0.0), axis=(-1.0, 0.0, 0.0), swing=0.3),
        dict(type="hinge", parent="a", child="c", anchor=(0.6, 1.0, 0.0), axis=(0.0, 0.0, 1.0), limit=(-0.2, 0.2)),
    ])
    runs = [physics.rollout(physics.make_model(bodies, J, scan_levels=flag), state, _DT, 60) for flag in (False, True)]
    for field in ("position", "orientation", "linear_velocity", "angular_velocity"):
        np.testing.assert_allclose(getattr(runs[0].trajectory, field), getattr(runs[1].trajectory, field),
                                   rtol=0, atol=1e-12)


def test_spd_inverse_equals_numpy_for_every_size():
    """The tree solve's inverses (closed forms up to 3 x 3, Schur-complement blocks above) against numpy's LU
    inverse, batched, on symmetric positive definite matrices of condition numbers up to a few hundred (errors
    about 1e-14 of the largest entry)."""
    from jaxanim.physics._bodies import _spd_inverse

    rng = np.random.default_rng(3)
    for k in range(1, 8):
        X = rng.normal(size=(5, 4, k, k))
        A = X @ np.swapaxes(X, -1, -2) + 1e-2 * k * np.eye(k)
        got = np.asarray(jax.jit(_spd_inverse)(jnp.asarray(A)))
        want = np.linalg.inv(A)
        scale = np.abs(want).max(axis=(-2, -1), keepdims=True)
        assert np.max(np.abs(got - want) / scale) < 1e-12, k
        np.testing.assert_allclose(got, np.swapaxes(got, -1, -2), rtol=0, atol=1e-12 * scale.max())


@pytest.mark.parametrize("scan_levels", [False, True], ids=["levels-written-out", "levels-scanned"])
def test_tree_solve_satisfies_its_system_and_its_jvp_is_the_implicit_one(scan_levels):
    """The tree solve on a random forest (a joint to the world, branching, a free body, 2
    right-hand sides): its velocities and multipliers satisfy ``M V = p + J' lambda`` and
    ``J V + C lambda = b`` (numpy); its custom JVP (one substitution with the linearized system's
    right-hand sides) equals forward-mode autodiff through every elimination step, along a
    symmetric inertia tangent."""
    from jaxanim.physics import _tree_solve as T

    rng = np.random.default_rng(3)
    # body 0 on a joint to the world, bodies 1 and 2 branching from it, body 3 free (depth 2: a
    # deeper chain repeats the same level code and cost 1.5 s more to compile per variant)
    parent, child, B, k, m = (-1, 0, 0), (0, 1, 2), 4, 3, 2
    plan = T._plan(parent, child, B)

    def spd(scale):
        a = rng.normal(size=(B, 6, 6))
        return scale * (a @ np.swapaxes(a, -1, -2) + 6 * np.eye(6))

    nj = len(parent)
    args = [spd(1.0), rng.normal(size=(B, 6, m)), rng.normal(size=(nj, k, 6)), rng.normal(size=(nj, k, 6)),
            rng.normal(size=(nj, k, m)), 1e-3 * np.abs(rng.normal(size=(nj, k)))]
    tangents = [spd(0.1), rng.normal(size=(B, 6, m)), rng.normal(size=(nj, k, 6)), rng.normal(size=(nj, k, 6)),
                rng.normal(size=(nj, k, m)), 1e-4 * rng.normal(size=(nj, k))]
    M, p, Jp, Jc, b, C = args

    @jax.jit  # one program (eager would run the unrolled solve op by op)
    def run(x, t):
        V, lam = T._tree_solve_multipliers(plan, *x, scan_levels)
        _, implicit = jax.jvp(lambda *a: T._tree_solve(plan, *a, scan_levels), x, t)
        _, autodiff = jax.jvp(lambda *a: T._tree_solve_multipliers(plan, *a, scan_levels)[0], x, t)
        return V, lam, T._tree_solve(plan, *x, scan_levels), implicit, autodiff

    V, lam, v1, t1, t2 = (np.asarray(a) for a in run(tuple(map(jnp.asarray, args)), tuple(map(jnp.asarray, tangents))))
    force = np.einsum("bij,bjm->bim", M, V) - p
    for j, (pa, c) in enumerate(zip(parent, child)):
        force[c] -= Jc[j].T @ lam[j]
        row = Jc[j] @ V[c] + C[j][:, None] * lam[j] - b[j]
        if pa >= 0:
            force[pa] -= Jp[j].T @ lam[j]
            row += Jp[j] @ V[pa]
        np.testing.assert_allclose(row, 0.0, atol=1e-10)
    np.testing.assert_allclose(force, 0.0, atol=1e-10)
    np.testing.assert_array_equal(v1, V)
    np.testing.assert_allclose(t1, t2, rtol=1e-10, atol=1e-12)


def test_rows_solve_jvp_equals_autodiff_through_every_step():
    """The joint and one-sided rows solved together (contacts with friction and two limit rows, one of them on a
    parent too, both pushing; a point sticking, one sliding, one apart): the custom JVP (adjoint products for the
    Delassus matrix's tangent, one substitution for the velocities') equals forward-mode autodiff through the tree
    solve's elimination, the columns and the Gauss-Seidel sweeps, along random tangents of every input (the
    inertias' symmetric, as the rule takes them); and along the same tangents with the linear inertias and the drive
    rows held constant (symbolic zero tangents, whose products the rule skips), where those parts matter. (Under
    ``jax.jacfwd``, the basis tangents of every other input, this test's program took 11.5 s to compile.)"""
    from jaxanim.physics import _rows_solve as R
    from jaxanim.physics import _tree_solve as T
    from jaxanim.physics._contact import projected_gauss_seidel

    rng = np.random.default_rng(5)
    parent, child, B = (-1, 0, 0), (0, 1, 2), 4
    plan = T._plan(parent, child, B)
    nj, K, L = len(parent), 3, 2
    U = 3 * K + L

    def spd(scale):
        a = rng.normal(size=(B, 3, 3))
        return scale * (a @ np.swapaxes(a, -1, -2) + 3 * np.eye(3))

    owner_a = np.array([0, 0, 0, 1, 1, 1, 3, 3, 3, 2, 1])
    owner_b = np.array([0, 0])
    shapes = [(nj, 2, 6), (nj, 1, 6), (nj, 2, 6), (nj, 1, 6), (nj, 3), (nj, 3), (U, 6), (U,), (L, 6)]
    x = [spd(1.0), spd(1.0), rng.normal(size=(B, 6)), *(rng.normal(size=s) for s in shapes), np.array(0.6),
         np.array(1e-6)]
    x[8] = 1e-3 * np.abs(x[8])  # C
    x[10] = x[10] + np.r_[np.ones(9), 10, 10]  # target
    t = [spd(0.1), spd(0.1), *(rng.normal(size=np.shape(a)) for a in x[2:])]
    x, t = tuple(map(jnp.asarray, x)), tuple(map(jnp.asarray, t))

    def rule(Mt, Mr, p, Jpg, Jpd, Jcg, Jcd, b, C, rows_a, target, rows_b, mu, cfm):
        return R._solve(plan, False, 10, L, (Mt, Mr), p, (Jpg, Jpd), (Jcg, Jcd), b, C, owner_a, rows_a, target,
                        owner_b, rows_b, mu, cfm)

    def impulses(Mt, Mr, p, Jpg, Jpd, Jcg, Jcd, b, C, rows_a, target, rows_b, mu, cfm):
        _, V0, _, Y, _, A, rhs = R._columns(plan, False, L, (Mt, Mr), p, (Jpg, Jpd), (Jcg, Jcd), b, C, owner_a,
                                            rows_a, target, owner_b, rows_b, cfm)
        return V0, Y, projected_gauss_seidel(A, rhs, mu, 10, num_single=L)

    def autodiff(*a):
        V0, Y, lam = impulses(*a)
        return V0 + jnp.einsum("bjv,v->bj", Y, lam)

    held = (0, 4, 6)  # M_lin and the drive rows: constants of the function differentiated

    args = tuple(i for i in range(len(x)) if i not in held)

    def part(f):  # the held inputs closed over: constants, whose tangents are symbolic zeros
        return lambda *a: f(*(x[i] if i in held else a[args.index(i)] for i in range(len(x))))

    @jax.jit
    def run(x, t):  # the impulses too: a jit of their own would be another program (1.3 s)
        out = [jax.jvp(f, x, t) for f in (rule, autodiff)]
        free = tuple(x[i] for i in args), tuple(t[i] for i in args)
        return out, [jax.jvp(part(f), *free)[1] for f in (rule, autodiff)], impulses(*x)[2]

    ((v1, d1), (v2, d2)), (e1, e2), lam = run(x, t)
    lam = np.asarray(lam)
    # the premise: point 0 pressed and sticking (inside the friction disc), point 1 pressed and sliding (on its
    # edge), point 2 apart, both limit rows pushing
    assert lam[0] > 1 and lam[3] > 1 and np.all(lam[6:9] == 0) and np.all(lam[-2:] > 1)
    assert np.hypot(lam[1], lam[2]) < 0.5 * lam[0]
    np.testing.assert_allclose(np.hypot(lam[4], lam[5]), 0.6 * lam[3], rtol=1e-12)
    np.testing.assert_array_equal(v1, v2)
    assert np.abs(np.asarray(d2)).max() > 1e-2
    np.testing.assert_allclose(d1, d2, rtol=1e-9, atol=1e-9 * float(np.abs(d2).max()))
    # the held parts' tangents matter: the JVP along the others alone differs
    assert np.abs(np.asarray(d1) - np.asarray(e1)).max() > 1e-3
    np.testing.assert_allclose(e1, e2, rtol=1e-9, atol=1e-9 * float(np.abs(e2).max()))


@pytest.mark.parametrize("scan_levels", [False, True], ids=["levels-written-out", "levels-scanned"])
def test_delassus_along_the_chains_equals_the_columns_through_the_tree_solve(scan_levels):
    """The one-sided rows' Delassus matrix carried up the rows' chains of ancestors (the rows solve's path for few
    rows) equals ``J_u Y`` of the columns ``Y = H^{-1} J_u'`` through the tree solve, and so do the velocities of
    both paths, to round-off: contact points on a body jointed to the world, on its child and on a free body, a
    limit row on the child and one on the grandchild (its momentum on the parent too)."""
    from jaxanim.physics import _rows_solve as R
    from jaxanim.physics import _tree_solve as T
    from jaxanim.physics._contact import projected_gauss_seidel

    rng = np.random.default_rng(7)
    parent, child, B = (-1, 0, 1), (0, 1, 2), 4
    plan = T._plan(parent, child, B)
    nj, K, L = len(parent), 3, 2
    U = 3 * K + L

    def spd():
        a = rng.normal(size=(B, 3, 3))
        return jnp.asarray(a @ np.swapaxes(a, -1, -2) + 3 * np.eye(3))

    M = (spd(), spd())
    p = jnp.asarray(rng.normal(size=(B, 6)))
    Jp = (jnp.asarray(rng.normal(size=(nj, 3, 6))), jnp.zeros((nj, 0, 6)))
    Jc = (jnp.asarray(rng.normal(size=(nj, 3, 6))), jnp.zeros((nj, 0, 6)))
    b, C = jnp.asarray(rng.normal(size=(nj, 3))), jnp.asarray(1e-3 * np.abs(rng.normal(size=(nj, 3))))
    owner_a, owner_b = np.array([0, 0, 0, 1, 1, 1, 3, 3, 3, 1, 2]), np.array([0, 1])
    rows_a, rows_b = jnp.asarray(rng.normal(size=(U, 6))), jnp.asarray(rng.normal(size=(L, 6)))
    target = jnp.asarray(rng.normal(size=U) + 5.0)
    mu, cfm = jnp.asarray(0.6), jnp.asarray(1e-6)

    @jax.jit
    def run():
        (factors, _, _), V0, _, Y, _, A, rhs = R._columns(plan, scan_levels, L, M, p, Jp, Jc, b, C, owner_a, rows_a,
                                                          target, owner_b, rows_b, cfm)
        blocks = T._body_blocks(plan, factors, B, scan_levels)
        chains = R._delassus(plan, (blocks[0], blocks[1], blocks[3]), B, L, owner_a, rows_a, owner_b, rows_b)[0]
        lam = projected_gauss_seidel(A, rhs, mu, 10, num_single=L)
        columns = V0 + jnp.einsum("bjv,v->bj", Y, lam)
        chained = R._solve(plan, scan_levels, 10, L, M, p, Jp, Jc, b, C, owner_a, rows_a, target, owner_b, rows_b,
                           mu, cfm)
        return A, R._contact_problem(chains, rhs, cfm)[0], lam, columns, chained

    A, A2, lam, V, V2 = (np.asarray(a) for a in run())
    assert U <= R._CHAIN_ROWS and np.count_nonzero(lam) >= 3  # the path under test, and impulses that act
    np.testing.assert_allclose(A2, A, rtol=0, atol=1e-13 * np.abs(A).max())
    np.testing.assert_allclose(V2, V, rtol=0, atol=1e-12 * np.abs(V).max())
