"""Shared test helpers: small skeletons, random poses, cached jitted functions."""

from __future__ import annotations

import contextlib
import functools
import logging

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial.transform import Rotation

import jaxanim
from benchmarks.peers import numpy_fk as _numpy_fk
from jaxanim import ik
from jaxanim import rotations as rot
from jaxanim.bvh import read_bvh

from .conftest import SHARED_DATA


def assert_close(name: str, actual, expected, *, atol: float = 0.0, rtol: float = 0.0) -> None:
    """``np.testing.assert_allclose`` with the field name in the message."""
    np.testing.assert_allclose(np.asarray(actual), np.asarray(expected), atol=atol, rtol=rtol, err_msg=f"field: {name}")


def small_skeleton(dtype=jnp.float64) -> jaxanim.Skeleton:
    """A 6-joint tree with a branch, mixed channel layouts and two End Sites."""
    names = ("root", "spine", "head", "arm", "forearm", "leg")
    parents = (-1, 0, 1, 1, 3, 0)
    offsets = np.array(
        [[0.0, 1.0, 0.0], [0.0, 0.3, 0.1], [0.0, 0.4, 0.0], [0.2, 0.3, 0.0], [0.3, 0.0, 0.05], [0.1, -0.5, 0.0]]
    )
    channels = (
        ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"),
        ("Xrotation", "Yrotation", "Zrotation"),
        ("Yrotation", "Xrotation", "Zrotation"),
        ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation"),
        ("Zrotation", "Yrotation", "Xrotation"),
        ("Xrotation", "Zrotation", "Yrotation"),
    )
    return jaxanim.Skeleton(
        names, parents, jnp.asarray(offsets, dtype), channels,
        end_site_parents=(2, 4), end_site_offsets=jnp.asarray([[0.0, 0.1, 0.0], [0.25, 0.0, 0.0]], dtype),
    )


#: ``rotvec_to_quat`` as one program per shape (eager, it compiled 10-15 primitives one by one for every new
#: shape of ``random_pose``, which 45 call sites draw)
_rotvec_to_quat = jax.jit(rot.rotvec_to_quat)


def random_pose(skeleton: jaxanim.Skeleton, seed: int, n: int | None = None, scale: float = 0.8):
    """Random unit quaternions and translations (offsets plus noise), optionally batched by ``n``."""
    rng = np.random.default_rng(seed)
    shape = (skeleton.num_joints,) if n is None else (n, skeleton.num_joints)
    dtype = skeleton.offsets.dtype
    q = _rotvec_to_quat(jnp.asarray(rng.normal(size=shape + (3,)) * scale, dtype))
    t = jnp.asarray(np.asarray(skeleton.offsets) + 0.1 * rng.normal(size=shape + (3,)), dtype)
    return q, t


def scipy_rotation(q) -> Rotation:
    """numpy/scipy: the ``Rotation`` of wxyz quaternions ``[..., 4]`` (scipy stores xyzw)."""
    return Rotation.from_quat(np.asarray(q)[..., [1, 2, 3, 0]])


def wxyz(R) -> np.ndarray:
    """numpy/scipy: wxyz quaternions of rotation matrices ``[..., 3, 3]`` (scipy's sign)."""
    xyzw = Rotation.from_matrix(np.asarray(R)).as_quat()
    return np.concatenate([xyzw[..., 3:], xyzw[..., :3]], axis=-1)


def numpy_fk(skel: jaxanim.Skeleton, q, t) -> _numpy_fk.FKArrays:
    """numpy forward kinematics (the benchmarks' float64 reference, ``benchmarks.peers.numpy_fk``) of wxyz
    ``q [..., joints, 4]`` and ``t [..., joints, 3]``: world ``rotations``, ``positions`` and ``end_site_positions``
    with ``q``'s leading dimensions. An FK independent of the library's that compiles nothing (a jitted FK
    compiles ~1 s per skeleton and shape)."""
    q, t = np.asarray(q, np.float64), np.asarray(t, np.float64)
    lead, J = q.shape[:-2], skel.num_joints
    out = _numpy_fk.forward_kinematics(skel.parents, skel.end_site_parents, np.asarray(skel.end_site_offsets),
                                       scipy_rotation(q.reshape(-1, 4)).as_matrix().reshape(-1, J, 3, 3),
                                       t.reshape(-1, J, 3))
    return _numpy_fk.FKArrays(*(x.reshape(lead + x.shape[1:]) for x in out))


def random_site_targets(skel: jaxanim.Skeleton, seed: int, effectors) -> tuple[ik.Target, ...]:
    """Position and orientation targets for ``effectors`` (joints or End Sites) from FK (:func:`numpy_fk`) of a
    random pose within +-45 deg of the rest pose (``rot.euler_to_quat(eul, "ZYX")``), root rotated freely and
    moved: reachable."""
    rng = np.random.default_rng(seed)
    eul = rng.uniform(-np.pi / 4, np.pi / 4, size=(skel.num_joints, 3))
    q = wxyz(Rotation.from_euler("ZYX", eul).as_matrix())
    q[0] = wxyz(Rotation.from_rotvec(rng.normal(size=3)).as_matrix())
    t = np.asarray(skel.offsets).copy()
    t[0] = rng.normal(size=3) * 5
    out = numpy_fk(skel, q, t)
    pos = np.concatenate([out.positions, out.end_site_positions])
    quats = wxyz(out.rotations)
    tg = []
    for name in effectors:
        i = skel.site_index(name)
        owner = i if i < skel.num_joints else skel.end_site_parents[i - skel.num_joints]
        tg.append(ik.Target(name, pos[i], quats[owner]))
    return tuple(tg)


@functools.lru_cache(maxsize=None)
def shared_clip(stem: str):
    """``(skeleton, motion, reference npz)`` for a shared BVH clip (cached: parsed once per run)."""
    skel, motion = read_bvh(SHARED_DATA / "bvh" / f"{stem}.bvh")
    ref = dict(np.load(SHARED_DATA / "fk" / f"{stem}.fk.npz"))
    return skel, motion, ref


@functools.lru_cache(maxsize=None)
def batched_fk():
    """``jit(vmap(forward_kinematics))`` over frames, shared by every test (compiled per structure)."""
    return jax.jit(jax.vmap(jaxanim.forward_kinematics, in_axes=(None, 0, 0)))


#: ``forward_kinematics`` as one compiled program per signature (eager FK dispatches op by op,
#: compiling each primitive separately: seconds on the CMU skeleton).
jitted_fk = eqx.filter_jit(jaxanim.forward_kinematics)


def jitted_limit_violation(skel, batched=False):
    """``(limits, rotations) -> ik.limit_violation(skel, limits, rotations)``, jitted (eager, it
    dispatches op by op, and an eager ``vmap`` too: each op compiled separately), over a batch of
    poses if ``batched``. ``skel`` is a constant (a swing-twist limit without an axis takes it from
    the concrete offsets); limits with other bounds reuse the compile."""
    fn = functools.partial(ik.limit_violation, skel)
    return eqx.filter_jit(jax.vmap(fn, in_axes=(None, 0)) if batched else fn)


def quick_bench_config(**kw):
    """A benchmark config for smoke tests: batch 2, one sample, half a second per row."""
    from benchmarks import BenchConfig

    return BenchConfig.make_quick(verbose=False, batches=(2,), repeats=1, warmup=0, max_row_s=0.5, loop_cap=2, **kw)


def bench_rows(tables, name: str):
    """The table called ``name`` and its rows by ``(implementation, batch)``."""
    (table,) = [t for t in tables if t.name == name]
    return table, {(r.implementation, r.batch): r for r in table.rows}


_TRACE_EVENT = "/jax/core/compile/jaxpr_trace_duration"


@contextlib.contextmanager
def count_traces():
    """Count the jaxprs that JAX traces inside the block (a retrace of a jitted function is one).

    ``with count_traces() as traces: f(x)``, then ``traces[0]`` is the count (through
    ``jax.monitoring``'s trace-duration event, so it sees every jit, including nested ones).
    """
    traces = [0]

    def listener(event, duration, **kwargs):
        if event == _TRACE_EVENT:
            traces[0] += 1

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        yield traces
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)


@contextlib.contextmanager
def xla_compiles():
    """The names of the functions XLA compiles inside the ``with`` block (from ``jax.log_compiles``),
    e.g. ``["jit(_rollout)"]``: a call that does not retrace compiles nothing."""
    names: list[str] = []

    class _Handler(logging.Handler):
        def emit(self, record):
            msg = record.getMessage()
            if msg.startswith("Compiling "):
                names.append(msg.split()[1])

    handler = _Handler()
    logger = logging.getLogger("jax")
    logger.addHandler(handler)
    try:
        with jax.log_compiles():
            yield names
    finally:
        logger.removeHandler(handler)


@functools.cache
def phys_cmu_character():
    """``(skeleton, motion, q0, t0, character, state)``: the CMU clip 01_01 and the physics character
    built in its first frame on complementarity ground (``contact.make_ground()``'s default), built
    once per process for the files that all use it (test_balance, test_character, the simulate CLI's
    warm-up): building it dispatches a few hundred small programs op by op (each worker builds its own:
    they compile in under the run's compilation-cache floor of 2 s, so none is shared)."""
    from jaxanim import character, contact

    skel, motion = read_bvh(SHARED_DATA / "bvh" / "cmu_01_01_trim300.bvh")[:2]
    q0, t0 = motion.rotations[0], motion.translations[0]
    char, state = character.build_character(skel, q0, t0, ground=contact.make_ground("complementarity"))
    return skel, motion, q0, t0, char, state


#: The hand-written retargeting maps of the CMU clip (../shared/data/bvh) onto the G1 and onto dm_control's CMU
#: humanoid (tests/test_robots_retarget.py retargets with them; tests/test_retargeting_auto_map.py finds them).
CMU_TO_G1 = {
    "root": {"source": "Hips", "target": "pelvis"},
    "pairs": [
        {"source": "LeftFoot", "target": "left_ankle_roll_link", "foot": True, "orientation_weight": 0.5},
        {"source": "RightFoot", "target": "right_ankle_roll_link", "foot": True, "orientation_weight": 0.5},
        {"source": "LeftLeg", "target": "left_knee_link", "orientation_weight": 0.0},
        {"source": "RightLeg", "target": "right_knee_link", "orientation_weight": 0.0},
        {"source": "Spine1", "target": "torso_link", "orientation_weight": 0.5},
        {"source": "LeftForeArm", "target": "left_elbow_link", "position_weight": 0.5, "orientation_weight": 0.01},
        {"source": "RightForeArm", "target": "right_elbow_link", "position_weight": 0.5, "orientation_weight": 0.01},
        {"source": "LeftHand", "target": "left_wrist_yaw_link", "position_weight": 0.5, "orientation_weight": 0.1},
        {"source": "RightHand", "target": "right_wrist_yaw_link", "position_weight": 0.5, "orientation_weight": 0.1},
    ],
}

CMU_TO_CMU = {
    "root": {"source": "Hips", "target": "body:root"},
    "pairs": [
        {"source": "LeftFoot", "target": "lfoot", "foot": True, "orientation_weight": 0.5},
        {"source": "RightFoot", "target": "rfoot", "foot": True, "orientation_weight": 0.5},
        {"source": "LeftLeg", "target": "ltibia", "orientation_weight": 0.0},
        {"source": "RightLeg", "target": "rtibia", "orientation_weight": 0.0},
        {"source": "Spine1", "target": "thorax", "orientation_weight": 0.5},
        {"source": "LeftForeArm", "target": "lradius", "position_weight": 0.5, "orientation_weight": 0.01},
        {"source": "RightForeArm", "target": "rradius", "position_weight": 0.5, "orientation_weight": 0.01},
        {"source": "LeftHand", "target": "lwrist", "position_weight": 0.5, "orientation_weight": 0.1},
        {"source": "RightHand", "target": "rwrist", "position_weight": 0.5, "orientation_weight": 0.1},
    ],
}


#: A two-legged robot of 4 hinges (MJCF) whose retargeting solves compile in seconds, and its map from the
#: shipped walk (tests/test_robots_retarget.py, tests/test_retarget_dataset.py).
TINY = """<mujoco model="tiny"><worldbody><body name="pelvis" pos="0 0 0.5"><freejoint/>
  <geom type="sphere" size="0.05"/>
  <body name="lthigh" pos="0 0.1 0"><joint name="lhip" axis="0 1 0" range="-1.5 1.5"/>
    <geom type="capsule" fromto="0 0 0 0 0 -0.45" size="0.03"/>
    <body name="lfoot" pos="0 0 -0.45"><joint name="lknee" axis="0 1 0" range="0 2"/>
      <geom type="box" pos="0.03 0 -0.02" size="0.06 0.03 0.02"/></body></body>
  <body name="rthigh" pos="0 -0.1 0"><joint name="rhip" axis="0 1 0" range="-1.5 1.5"/>
    <geom type="capsule" fromto="0 0 0 0 0 -0.45" size="0.03"/>
    <body name="rfoot" pos="0 0 -0.45"><joint name="rknee" axis="0 1 0" range="0 2"/>
      <geom type="box" pos="0.03 0 -0.02" size="0.06 0.03 0.02"/></body></body>
</body></worldbody></mujoco>"""
TINY_MAP = {"root": {"source": "Hips", "target": "pelvis"},
            "pairs": [{"source": "LeftFoot", "target": "lfoot", "foot": True},
                      {"source": "RightFoot", "target": "rfoot", "foot": True},
                      {"source": "LeftUpLeg", "target": "lthigh", "orientation_weight": 0.0},
                      {"source": "RightUpLeg", "target": "rthigh", "orientation_weight": 0.0}]}
