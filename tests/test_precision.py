"""Every matrix product of the library states its precision (issue 29).

On an NVIDIA GPU a float32 ``dot`` without a stated precision runs in TF32 (about 10 bits of
mantissa): float32 LBS of the walk was 0.27 m off there, and the matching search 74 % exact. No CPU
run shows that, so the check is on the program: each public kernel is lowered
(``jax.jit(f).lower(...)``, tracing only, nothing compiled) and every ``dot_general`` in its
StableHLO must carry ``precision = [HIGHEST, HIGHEST]``, or the precision a kernel's documented
``precision`` option asked for. A source check beside it finds a ``jnp`` product written without
``precision=`` in code that no kernel below reaches.
"""

from __future__ import annotations

import ast
import functools
import pathlib
import re

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxanim
import solvers
from jaxanim import character, ik, matching, physics, skinning, splines, tracking
from jaxanim import rotations as rot
from jaxanim.app._simulate import _looped_motion

from .helpers import small_skeleton

REPO = pathlib.Path(__file__).resolve().parents[1]
_DOT = re.compile(r"stablehlo\.(dot_general|dot)\b")
_PRECISION = re.compile(r"precision = \[(\w+), (\w+)\]")


def _precisions(lowered) -> list[str]:
    """The precision of each dot in a lowered program's StableHLO (``"none"`` where unstated)."""
    out = []
    for line in lowered.as_text().splitlines():
        if _DOT.search(line):
            m = _PRECISION.search(line)
            out.append("none" if m is None else m.group(1) if m.group(1) == m.group(2) else f"{m.group(1)}/{m.group(2)}")
    return out


def _assert_highest(name: str, lowered, *, at_least: int = 1) -> None:
    got = _precisions(lowered)
    assert len(got) >= at_least, f"{name}: expected at least {at_least} dots in the program, found {len(got)}"
    bad = [p for p in got if p != "HIGHEST"]
    assert not bad, f"{name}: {len(bad)} of {len(got)} dots without precision HIGHEST: {sorted(set(bad))}"


def _lower(fn, *args):
    return jax.jit(fn).lower(*args)


def _cast(tree, dtype):
    return jax.tree.map(lambda x: x.astype(dtype) if eqx.is_inexact_array(x) else x, tree)


# --- fixtures: the shipped walk (kinematics, IK, skinning, matching) and a small character ----------


@functools.cache
def _walk(dtype):
    skel, clip = jaxanim.read_bvh(jaxanim.default_clip_path())
    return _cast(skel, dtype), _cast(clip, dtype)


@functools.cache
def _small_character():
    skel = small_skeleton()
    ground = physics.make_ground("complementarity", max_points=8, iterations=10, dtype=jnp.float64)
    char, state = character.build_character(skel, ground=ground)
    return skel, char, state


#: The kernels are lowered in float32 only: TF32 is a float32 matter (a float64 ``dot`` runs in float64 on every
#: backend), and no product of the library chooses its precision by dtype (each states HIGHEST or the caller's
#: ``precision``; the source check below). The float64 lowerings cost 22 s of the suite's time.
DTYPES = [jnp.float32]


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32"])
def test_kinematics_state_highest(dtype):
    skel, clip = _walk(dtype)
    q, t = clip.rotations[0], clip.translations[0]
    sites = ("LeftHand_End", "RightHand_End", "Head")
    n = 3 + 3 * skel.num_joints
    _assert_highest("forward_kinematics", _lower(lambda q, t: jaxanim.forward_kinematics(skel, q, t), q, t))
    _assert_highest("jacobian", _lower(lambda q, t: jaxanim.jacobian(skel, q, t, sites), q, t))
    _assert_highest("apply_increment", _lower(lambda q, t, d: jaxanim.apply_increment(skel, q, t, d), q, t,
                                              jnp.zeros(n, dtype)), at_least=0)
    fk = jax.eval_shape(lambda q, t: jaxanim.forward_kinematics(skel, q, t), q, t)  # shapes (op by op: 58 programs)
    _assert_highest("global_to_local", _lower(lambda R, p: jaxanim.global_to_local(skel, R, p), fk.rotations,
                                              fk.positions))
    _assert_highest("center_of_mass", _lower(lambda q, t: jaxanim.center_of_mass(skel, q, t,
                                                                                 jnp.ones(skel.num_joints, dtype)), q, t))


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32"])
def test_ik_states_highest(dtype):
    """The IK normal equations (own LM and Gauss-Newton with hard limits), CCD, and the implicit
    derivative of a solve (with the solve itself, which the gradient's program holds whole: the value and
    the gradient, one program; the solve lowered apart cost about 1 s more on the loaded 2-core machine)."""
    skel, clip = _walk(dtype)
    q, t = clip.rotations[0], clip.translations[0]
    j_foot = skel.index("RightFoot")
    goals = jax.ShapeDtypeStruct((2, 3), dtype)  # the hand's and the foot's positions: lowering needs shapes only
    limits = (ik.SwingTwistLimit("LeftArm", swing=[80, 60], twist=[-45, 45], degrees=True),)

    def targets(g):
        return (ik.Target("LeftHand", position=g[0]), ik.Target("RightFoot", position=g[1], orientation=q[j_foot]))

    def lm(g):
        return ik.solve_ik(skel, targets(g), q, t).rotations

    def gn_limits(g):
        return ik.solve_ik(skel, targets(g), q, t, limits=limits, limit_mode="hard",
                           solver=solvers.GaussNewton(max_steps=5)).rotations

    def ccd(g):
        return ik.solve_ik_ccd(skel, targets(g), q, t, max_sweeps=3).rotations

    _assert_highest("solve_ik (LM) and its grad", _lower(jax.value_and_grad(lambda g: jnp.sum(lm(g) ** 2)), goals))
    _assert_highest("solve_ik (GN, hard limits)", _lower(gn_limits, goals))
    _assert_highest("solve_ik_ccd", _lower(ccd, goals))


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32"])
@pytest.mark.parametrize("method", skinning.METHODS)
def test_skinning_states_highest_and_takes_the_fast_path_on_request(dtype, method, monkeypatch):
    """LBS / DQS by default; ``precision="default"`` reaches the blend's products over the vertices
    (both forms: the one-product form and the per-vertex fallback for very large meshes), while
    the joints' transforms stay HIGHEST."""
    skel, clip = _walk(dtype)
    mesh = skinning.capsule_mesh(skel, sides=4, rings=2, cap_rings=1)
    w = skinning.heuristic_weights(skel, mesh.vertices, k=2)
    clip3 = jaxanim.Motion(clip.rotations[:3], clip.translations[:3], clip.frame_time)
    _assert_highest(f"skin {method}", _lower(lambda q, t: skinning.skin(skel, q, t, mesh, w, method),
                                             clip.rotations[0], clip.translations[0]))
    _assert_highest(f"skin_motion {method}", _lower(lambda c: skinning.skin_motion(skel, c, mesh, w, method), clip3))
    for dense in (True, False):
        if not dense:  # the per-vertex form of meshes beyond the dense limit
            from jaxanim.skinning import _skin

            monkeypatch.setattr(_skin, "_DENSE_MAX", 0)
        fast = _precisions(_lower(lambda q, t: skinning.skin(skel, q, t, mesh, w, method, precision="default"),
                                  clip.rotations[0], clip.translations[0]))
        assert "DEFAULT" in fast and set(fast) <= {"DEFAULT", "HIGHEST"}, (method, dense, fast)
    with pytest.raises(jaxanim.JaxanimError, match="precision: expected a jax.lax.Precision or one of"):
        skinning.skin(skel, clip.rotations[0], clip.translations[0], mesh, w, method, precision="tf32")


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32"])
def test_matching_states_highest_and_takes_the_fast_path_on_request(dtype):
    """The search (one chunk, and the scan over chunks), a crowd of the controller, and the fast
    path of both on request."""
    skel, clip = _walk(jnp.float64)
    db = matching.build_database([clip], skel, dtype=dtype)
    query = db.features[5]
    for chunk in (512, 16):  # one chunk for the walk's rows, and the scan over chunks
        search = functools.partial(matching.search, db, chunk=chunk)
        _assert_highest(f"search (chunk {chunk})", _lower(lambda x: search(x).index, query))
        fast = _precisions(_lower(lambda x: matching.search(db, x, chunk=chunk, precision="default").index, query))
        assert "DEFAULT" in fast, fast
    inputs = jax.tree.map(lambda x: jnp.stack([x, x]), matching.control_input([0.0, 1.0], [[0.0, 1.0], [0.0, 1.2]],
                                                                              dtype=dtype))
    crowd = jax.vmap(lambda i: matching.motion_matching(db, i, 10).motion.rotations)
    _assert_highest("motion_matching (crowd of 2)", _lower(crowd, inputs))
    fast = jax.vmap(lambda i: matching.motion_matching(
        db, i, 10, options=matching.ControllerOptions(precision="default")).motion.rotations)
    assert "DEFAULT" in _precisions(_lower(fast, inputs))
    with pytest.raises(jaxanim.JaxanimError, match="precision: expected a jax.lax.Precision"):
        matching.search(db, query, precision=3)


def test_physics_character_and_tracking_state_highest():
    """A physics step of each contact model (and its JVP), the balance controller's rollout, and the
    tracking kernels (the SAMCON search, the replay, the linearization for the feedback gains)."""
    skel, char, state = _small_character()
    model = char.model
    penalty = eqx.tree_at(lambda m: m.ground, model, physics.make_ground("penalty", dtype=jnp.float64))
    tau = jnp.zeros((model.joints.num_joints, 3))
    for name, m in (("complementarity", model), ("penalty", penalty)):
        step = lambda s, tau, m=m: physics.step(m, s, 1 / 120, joint_torque=tau)  # noqa: E731
        # the step and its JVP's tangent, one program: under the JVP the constraint solves' primal comes from their
        # derivative rules, so the plain step stays beside it (lowered apart, the two took about 10 % longer)
        _assert_highest(f"physics.step and its jvp ({name})",
                        _lower(lambda s, tau: (step(s, tau), jax.jvp(lambda x: step(s, x), (tau,), (tau,))[1]),
                               state, tau))
    ctrl, args = character.balance_controller(char, skel.rest_rotations(), None, 1 / 120, support="initial",
                                              foot_names=("forearm",), leg_joints=(("forearm", "arm"),))
    _assert_highest("rollout with the balance controller", _lower(
        lambda s: physics.rollout(model, s, 1 / 120, 4, controller=ctrl, controller_args=args).final.position, state))
    motion = _looped_motion(jaxanim.rest_motion(skel, 2), 7)
    # the reference as shapes only, an argument of the programs (built, it compiled two programs: 1.4 s more)
    ref = jax.eval_shape(lambda: tracking.tracking_reference(char, motion))
    opts = tracking.tracking_options(char, 1 / 30, 4)
    key = jax.random.PRNGKey(0)
    _assert_highest("tracking.samcon", _lower(lambda ref, k: tracking.samcon(char, ref, k, opts).corrections, ref, key))
    # the search's result as shapes only (running the search would compile it: 10 s more)
    result = jax.eval_shape(lambda ref, k: tracking.samcon(char, ref, k, opts), ref, key)
    # replay reads the frame time in Python: that leaf concrete (as tracking_reference makes it), the rest shapes
    timed = eqx.tree_at(lambda r: r.frame_time, ref, jnp.asarray(float(motion.frame_time), ref.frame_time.dtype))
    shapes, concrete = eqx.partition(timed, lambda x: isinstance(x, jax.ShapeDtypeStruct))
    _assert_highest("tracking.replay", _lower(
        lambda shapes, r: tracking.replay(char, eqx.combine(shapes, concrete), r).window_cost, shapes, result))
    from jaxanim.tracking._feedback import _linearize

    _assert_highest("tracking.linearize", _lower(
        lambda ref, r: _linearize(char, ref, r.options, r.corrections, r.trajectory), ref, result))


def test_robots_state_highest():
    """FK, Jacobians, the centre of mass and IK of an MJCF robot (the G1 of the shared data)."""
    from jaxanim import retargeting, robots

    from .conftest import shared_data_dir

    pytest.importorskip("mujoco")
    g1 = robots.load_robot(shared_data_dir() / "robots" / "unitree_g1" / "g1.xml")
    q = g1.qpos0
    # the 3 x 3 products of the robot kinematics are elementwise (no dot at all), so none may be left
    _assert_highest("robots.forward_kinematics", _lower(lambda q: robots.forward_kinematics(g1, q).xpos, q), at_least=0)
    _assert_highest("robots.jacobian", _lower(lambda q: robots.jacobian(g1, q, ["left_foot", "pelvis"]), q), at_least=0)
    _assert_highest("robots.center_of_mass", _lower(lambda q: robots.center_of_mass(g1, q), q))
    feet = (ik.Target("left_foot", [0.0, 0.1, 0.0], [1.0, 0.0, 0.0, 0.0]), ik.Target("pelvis", [0.0, 0.0, 0.8]))
    _assert_highest("ik.solve_ik (robot)", _lower(lambda q: ik.solve_ik(g1, feet, q, regularization=1e-3).qpos, q))
    skel, motion = jaxanim.read_bvh(jaxanim.default_clip_path())
    clip = jaxanim.Motion(motion.rotations[:4], motion.translations[:4], motion.frame_time)
    mapping = retargeting.load_mapping(retargeting.default_mapping_path())
    # the stance frames given (every frame): their detection compiled programs of its own, and lowering needs shapes
    contacts = np.ones((clip.num_frames, sum(bool(f) for f in mapping.feet)), bool)
    problem = retargeting.prepare_retarget(skel, clip, g1, mapping, contacts=contacts)
    _assert_highest("retargeting.solve_retarget", jax.jit(lambda p: retargeting.solve_retarget(
        g1, p, retargeting.RetargetOptions(iterations=1)).qpos).lower(problem))


def test_splines_state_highest():
    knots = jnp.linspace(0.0, 1.0, 5)
    points = jnp.asarray(np.random.default_rng(0).normal(size=(5, 3)))
    quats = rot.rotvec_to_quat(0.3 * points)
    t = jnp.linspace(0.0, 1.0, 7)
    for name, make in (("natural_cubic_spline", splines.natural_cubic_spline),
                       ("catmull_rom_spline", splines.catmull_rom_spline)):
        _assert_highest(name, _lower(lambda p, make=make: splines.evaluate(make(knots, p), t), points), at_least=0)
    _assert_highest("squad_spline", _lower(lambda q: splines.squad_spline(knots, q, t), quats), at_least=0)


def _lq(n=18, m=4, T=5, dtype=jnp.float64):  # n^3 > 4096: the products are dots (mm)
    rng = np.random.default_rng(0)
    A = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    B = rng.normal(size=(n, m))
    return (jnp.asarray(A, dtype), jnp.asarray(B, dtype), jnp.eye(n, dtype=dtype), jnp.eye(m, dtype=dtype), T)


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32"])
def test_solvers_state_highest(dtype):
    """Least squares (own LM, GN, gradient descent, the optimistix and jaxopt adapters; their implicit
    derivative), LQR and its derivative, DARE, CARE, iLQR, DDP, box-DDP and MPC on the problem library. A
    kernel and its derivative are one program, ``value_and_grad`` (the value is the kernel's own output)."""
    A, B, Q, R, T = _lq(dtype=dtype)
    n, m = B.shape

    def residual(y, a):
        return jnp.stack([y[0] ** 2 - a, y[1] - 2 * y[0], 0.1 * y[0] * y[1]])

    y0 = jnp.asarray([2.0, 1.0], dtype)
    import optimistix as optx

    own = (solvers.LevenbergMarquardt(), solvers.GaussNewton(), solvers.GradientDescent(max_steps=5))
    # the adapters: lineax states HIGHEST itself; jaxopt's LM states nothing, and the adapter traces it at HIGHEST
    adapters = (solvers.OptimistixSolver(optx.LevenbergMarquardt(rtol=1e-5, atol=1e-7)),
                solvers.JaxoptSolver("LevenbergMarquardt"))
    for solver in own + adapters:
        ls = lambda a, solver=solver: solvers.least_squares(residual, solver, y0, jnp.asarray(a, dtype)).value  # noqa: E731
        _assert_highest(f"least_squares {type(solver).__name__} and its grad",
                        _lower(jax.value_and_grad(lambda a, ls=ls: jnp.sum(ls(a))), jnp.asarray(1.0, dtype)),
                        at_least=0)
    As, Bs = jnp.broadcast_to(A, (T, n, n)), jnp.broadcast_to(B, (T, n, m))
    Qs, Rs = jnp.broadcast_to(Q, (T, n, n)), jnp.broadcast_to(R, (T, m, m))
    x0 = jnp.ones(n, dtype)
    _assert_highest("lqr and its grad",
                    _lower(jax.value_and_grad(lambda A: jnp.sum(solvers.lqr(A, Bs, Qs, Rs, Q, x0).us)), As))
    _assert_highest("dare and its grad", _lower(jax.value_and_grad(lambda A: jnp.sum(solvers.dare(A, B, Q, R).P)), A))
    _assert_highest("care", _lower(lambda A: solvers.care(A - 2 * jnp.eye(n, dtype=dtype), B, Q, R).P, A))
    for name in ("cart_pole", "acrobot", "unicycle", "pendulum", "double_integrator"):
        p = getattr(solvers.problems, name)(T=5, dtype=dtype)
        for method in ("ilqr", "ddp"):
            solve = lambda x0, p=p, method=method: p.solve(method, x0=x0, max_steps=3).us  # noqa: E731
            _assert_highest(f"{method} on {name}", _lower(solve, p.x0), at_least=0)
    box = solvers.problems.pendulum(T=5, u_max=2.0, dtype=dtype)
    _assert_highest("box-DDP on pendulum", _lower(lambda x0: box.solve("ddp", x0=x0, max_steps=3).us, box.x0),
                    at_least=0)
    p = solvers.problems.pendulum(T=5, dtype=dtype)
    _assert_highest("mpc on pendulum", _lower(lambda x0: solvers.mpc(
        p.dynamics, p.cost, x0, p.us_init, terminal_cost=p.terminal_cost, args=p.args, steps=2, max_steps=2).us,
        p.x0), at_least=0)
    lq = solvers.problems.pd_servo_tracking(T=5, dtype=dtype)
    _assert_highest("ilqr on the LQ servo problem", _lower(
        lambda x0: lq.as_control_problem().solve("ilqr", x0=x0, max_steps=2).us, lq.x0))


# --- the source check --------------------------------------------------------------------------

_PRODUCTS = {"einsum", "dot", "matmul", "tensordot", "vdot", "inner", "dot_general", "multi_dot", "vecdot",
             "matvec", "vecmat"}
_JAX_MODULES = {"jnp", "lax", "jax.numpy", "jax.lax", "jnp.linalg", "jsl"}


def _unstated(path: pathlib.Path) -> list[str]:
    """``jnp``/``lax`` products in ``path`` called without ``precision=``."""
    src = path.read_text(encoding="utf-8")
    out = []
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in _PRODUCTS:
            owner = ast.get_source_segment(src, node.func.value)
            if owner in _JAX_MODULES and not any(k.arg == "precision" for k in node.keywords):
                out.append(f"{path.relative_to(REPO)}:{node.lineno}: {owner}.{node.func.attr}")
    return out


def test_library_products_state_their_precision_in_the_source():
    """No ``jnp.einsum`` / ``jnp.dot`` / ``jnp.matmul`` / ``lax.dot_general`` ... without ``precision=``
    in jaxanim or solvers (the helpers of ``solvers._linalg`` state HIGHEST)."""
    files = sorted((REPO / "jaxanim").rglob("*.py")) + sorted((REPO / "solvers").rglob("*.py"))
    bad = [hit for f in files for hit in _unstated(f)]
    assert not bad, "products without precision=:\n" + "\n".join(bad)
