"""Writing a retargeted robot clip ``qpos [T, nq]`` in the motion formats that humanoid policy trainers
read (issue 59, item 2): :func:`write_motion`, with :func:`qvel_from_qpos` (MuJoCo's velocities) and
:func:`resample_qpos` (a new frame rate, rotations slerped).

Formats (:data:`FORMATS`; file suffix: :func:`format_suffix`):

* ``"npz"``: jaxanim's own file. The command line writes it (``jaxanim retarget``), not
  :func:`write_motion`, which refuses it with a :class:`~jaxanim.JaxanimError` that says so.
* ``"csv"``: the LAFAN1 retargeting CSV that mjlab's and BeyondMimic's ``csv_to_npz.py`` read with
  ``np.loadtxt(path, delimiter=",")``. One row per frame: root position (m), root quaternion **x, y, z,
  w**, then the hinge and slide values in the robot's joint order. Written with 17 significant digits
  (the float64 round trip), and no header row unless asked for.
* ``"beyondmimic"``: the ``.npz`` that mjlab's and whole_body_tracking's ``MotionLoader`` read:
  ``fps`` ``[1]`` (a one-element array, as both ``csv_to_npz.py`` write it: ``"fps": [output_fps]``),
  ``joint_pos`` / ``joint_vel`` ``[T, nj]`` (hinges and slides, robot joint order),
  ``body_pos_w`` / ``body_quat_w`` ``[T, nb, 3]`` / ``[T, nb, 4]`` (world frame; wxyz, sign ``w >= 0``),
  ``body_lin_vel_w`` / ``body_ang_vel_w`` ``[T, nb, 3]`` (world frame; the body frame's origin), and
  ``body_names`` ``[nb]`` (a unicode array: ``np.load`` needs no pickle). Bodies are in MuJoCo's order
  without the world, which is mjlab's ``Entity`` order (``spec.bodies[1:]``); Isaac Lab
  (whole_body_tracking) orders its bodies differently, so map them by ``body_names``.
* ``"gmr"``: the pickle of GMR's ``scripts/*_to_robot_dataset.py``: a dict with ``fps``, ``root_pos``
  ``[T, 3]``, ``root_rot`` ``[T, 4]`` (**x, y, z, w**), ``dof_pos`` ``[T, nj]`` (``qpos[:, 7:]``: the
  hinges and slides), ``local_body_pos`` ``[T, nb, 3]`` (every body but the world, in the root body's
  frame: GMR's FK with the root at the origin and unrotated) and ``link_body_list`` (a list of the body
  names). GMR's single-clip scripts write ``None`` for the last two. ``fps`` is a Python ``int`` when the
  rate is whole (GMR writes ``30``), a ``float`` otherwise.

Checked against the peers' code: GMR at commit ``4f9e8b7b8b471c9d8b4cb0119f6dca886868b3dd``
(``scripts/bvh_to_robot_dataset.py``, ``scripts/smplx_to_robot_dataset.py``, ``scripts/bvh_to_robot.py``
and its reader ``general_motion_retargeting/data_loader.py``; ``local_body_pos`` from
``general_motion_retargeting/kinematics_model.py``), mjlab at ``0eda4e736f09626d29674f0221d37afd9fd5132e``
(``src/mjlab/scripts/csv_to_npz.py``, ``src/mjlab/tasks/tracking/mdp/commands.py``) and
whole_body_tracking at ``cd65172032893724b445448818c34165846d847d`` (``scripts/csv_to_npz.py``,
``source/whole_body_tracking/whole_body_tracking/tasks/tracking/mdp/commands.py``).

Every array is written as float64. The peers' own writers produce float32 arrays (from torch) for
``joint_*``, ``body_*`` and GMR's ``local_body_pos``, but their readers convert what they load
(``torch.tensor(..., dtype=torch.float32)``; GMR's loader takes the arrays as they are), so none needs
float32. The bodies' frames are computed on the host in float64 (:mod:`jaxanim.robots._host`), the
velocities in JAX's precision: float64 with ``jax_enable_x64``, as the command line sets it.

Finite differences, one scheme everywhere: with ``dt = 1 / fps``, frame ``t`` of ``T`` has
``v[t] = (x[t+1] ⊖ x[t-1]) / (2 dt)`` for ``0 < t < T-1``, the one-sided ``(x[1] ⊖ x[0]) / dt`` and
``(x[T-1] ⊖ x[T-2]) / dt`` at the ends, and zeros for a single frame. ``⊖`` is MuJoCo's
``mj_differentiatePos`` for ``qvel`` (a rotation's difference in its body's local frame) and, for the
bodies' world velocities, ``p_b - p_a`` and ``log(q_b q_a^-1)`` (the rotation difference expressed in
the world frame).
"""

from __future__ import annotations

import os
import pickle

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import JaxanimError, check_float, check_shape
from .._types import Array, Float
from ..robots._host import body_frames_host
from ..robots._robot import Robot
from ..robots._tangent import TangentLayout, tangent_difference
from ..rotations._numpy import matrix_to_quat, quat_conj, quat_exp, quat_log, quat_mul, quat_to_matrix

__all__ = ["FORMATS", "format_suffix", "qvel_from_qpos", "resample_qpos", "write_motion"]

#: The motion formats of ``jaxanim retarget --format`` (``"npz"`` is written by the command line).
FORMATS = ("npz", "csv", "beyondmimic", "gmr")
_SUFFIX = {"npz": ".npz", "csv": ".csv", "beyondmimic": ".npz", "gmr": ".pkl"}
_ROOT_COLUMNS = ("root_x", "root_y", "root_z", "root_qx", "root_qy", "root_qz", "root_qw")
_XYZW = [4, 5, 6, 3]  # a free joint's qpos slots of its quaternion's x, y, z, w

#: ``qb ⊖ qa`` as one program per layout and shape
_tangent_difference = jax.jit(tangent_difference, static_argnums=0)


def format_suffix(format: str) -> str:
    """The file suffix of a motion format: ``".npz"``, ``".csv"``, ``".npz"`` or ``".pkl"`` for
    ``"npz"``, ``"csv"``, ``"beyondmimic"`` and ``"gmr"``.

    Raises:
        JaxanimError: if ``format`` is not one of :data:`FORMATS`.
    """
    return _SUFFIX[_check_format(format)]


def _check_format(format) -> str:
    if not isinstance(format, str) or format not in FORMATS:
        raise JaxanimError(f"format: unknown motion format {format!r}; valid formats: {list(FORMATS)}")
    return format


def _check_fps(name: str, fps) -> float:
    v = np.asarray(fps) if not isinstance(fps, bool) else np.asarray(None)
    number = np.issubdtype(v.dtype, np.floating) or np.issubdtype(v.dtype, np.integer)
    if v.shape != () or not number or not np.isfinite(v) or not v > 0:
        raise JaxanimError(f"{name}: expected a finite number > 0 (frames per second), got {fps!r}")
    return float(v)


def _check_qpos(robot, qpos) -> tuple[np.ndarray, TangentLayout]:
    """A float64 copy of ``qpos [T, nq]`` with its quaternions normalised, and the robot's layout."""
    if not isinstance(robot, Robot):
        raise JaxanimError(f"robot: expected a jaxanim.robots.Robot, got {type(robot).__name__}")
    if isinstance(qpos, jax.core.Tracer):
        raise JaxanimError("qpos: expected a concrete array (the export runs outside jit / vmap), got a tracer")
    check_shape("qpos", qpos, (None, robot.nq), what=f"(T, nq) = (T, {robot.nq})")
    check_float("qpos", qpos)
    q = np.array(qpos, dtype=np.float64)
    if q.shape[0] == 0:
        raise JaxanimError("qpos: expected at least one frame, got shape (0, nq)")
    bad = ~np.isfinite(q)
    if bad.any():
        t, i = (int(k) for k in np.argwhere(bad)[0])
        raise JaxanimError(f"qpos: expected finite values, got {float(q[t, i])} at frame {t}, coordinate {i}")
    lay = TangentLayout(robot)
    if lay.rot_q.size:
        qi = lay.rot_q[:, None] + np.arange(4)
        norm = np.linalg.norm(q[:, qi], axis=-1, keepdims=True)
        if (norm <= np.finfo(np.float64).tiny).any():
            t, k = (int(x) for x in np.argwhere(norm[..., 0] <= np.finfo(np.float64).tiny)[0])
            raise JaxanimError(f"qpos: the quaternion at coordinates {int(lay.rot_q[k])}..{int(lay.rot_q[k]) + 3} "
                               f"of frame {t} is zero")
        q[:, qi] = q[:, qi] / norm
    return q, lay


def _difference_pairs(T: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The scheme's frame pairs ``(a, b)`` ``[T]`` and weights ``1 / (b - a)`` (0 for a single frame):
    ``v[t] = (x[b] ⊖ x[a]) * fps * w[t]``."""
    t = np.arange(T)
    a, b = np.maximum(t - 1, 0), np.minimum(t + 1, T - 1)
    return a, b, np.where(b > a, 1.0 / np.maximum(b - a, 1), 0.0)


#: Frames are padded to a multiple of this for the compiled differences (a dataset of clips of many lengths
#: compiles a program per multiple, not per length).
_PAD = 64


def _padded(q: np.ndarray) -> np.ndarray:
    """``q`` with its last frame repeated up to a multiple of :data:`_PAD` frames."""
    return np.concatenate([q, np.repeat(q[-1:], -len(q) % _PAD, axis=0)])


def _qvel(lay: TangentLayout, q: np.ndarray, fps: float) -> np.ndarray:
    a, b, w = _difference_pairs(len(q))
    d = _tangent_difference(lay, jnp.asarray(_padded(q[a])), jnp.asarray(_padded(q[b])))
    return np.asarray(d, np.float64)[: len(q)] * (fps * w)[:, None]


def qvel_from_qpos(robot: Robot, qpos: Float[Array, "T nq"], fps: float) -> np.ndarray:
    """MuJoCo's generalised velocities ``qvel [T, nv]`` of a clip, by finite differences.

    The layout is ``qvel``'s (``robot.jnt_dofadr``): a hinge or slide gives ``d qpos / dt``; a free joint
    the world-frame linear velocity of its translation, then the angular velocity in the body's local
    frame; a ball joint the local angular velocity. ``⊖`` is MuJoCo's ``mj_differentiatePos``
    (:func:`~jaxanim.robots._tangent.tangent_difference`), in the scheme
    ``qvel[t] = (q[t+1] ⊖ q[t-1]) / (2 dt)`` inside, ``(q[1] ⊖ q[0]) / dt`` and ``(q[T-1] ⊖ q[T-2]) / dt``
    at the first and last frame, zeros for a single frame (``dt = 1 / fps``). Quaternions are normalised
    first; a rotation of more than pi between the two frames of a difference is taken the short way.

    Args:
        robot: the robot.
        qpos: ``[T, nq]`` the clip (MuJoCo's ``qpos`` per frame; hinges rad, slides m, wxyz quaternions).
        fps: frames per second, > 0.

    Returns:
        ``[T, nv]`` float64 velocities (rad/s, m/s).

    Raises:
        JaxanimError: if ``qpos`` is not ``[T, nq]`` or not finite, or ``fps`` is not a number > 0.
    """
    q, lay = _check_qpos(robot, qpos)
    return _qvel(lay, q, _check_fps("fps", fps))


def _sign_continuous(quats: np.ndarray) -> np.ndarray:
    """``quats [T, ..., 4]`` with each negated where needed so that consecutive ones have ``dot >= 0``
    (the first frame keeps its sign)."""
    if len(quats) < 2:
        return quats
    flip = np.sum(quats[1:] * quats[:-1], axis=-1) < 0
    sign = np.concatenate([np.ones_like(flip[:1], float), np.cumprod(np.where(flip, -1.0, 1.0), axis=0)])
    return quats * sign[..., None]


def resample_qpos(robot: Robot, qpos: Float[Array, "T nq"], fps: float, new_fps: float) -> np.ndarray:
    """The clip at another frame rate, over the same duration.

    The output has ``T' = floor((T - 1) new_fps / fps) + 1`` frames at the times ``k / new_fps``.
    Additive coordinates (hinges, slides, a free joint's translation) are interpolated linearly between
    the two nearest frames, every quaternion (free and ball joints) by slerp along the shorter arc. The
    quaternion tracks are made sign-continuous first (each frame's quaternion negated where its dot
    product with the previous frame's is negative; the first frame keeps its sign) and normalised, so
    the output's tracks are continuous and unit; the same rate returns the clip itself, up to those signs.

    Args:
        robot: the robot.
        qpos: ``[T, nq]`` the clip.
        fps: the clip's frames per second, > 0.
        new_fps: the output's frames per second, > 0.

    Returns:
        ``[T', nq]`` float64 configurations.

    Raises:
        JaxanimError: if ``qpos`` is not ``[T, nq]`` or not finite, or a rate is not a number > 0.
    """
    q, lay = _check_qpos(robot, qpos)
    fps, new_fps = _check_fps("fps", fps), _check_fps("new_fps", new_fps)
    T = len(q)
    n = int(np.floor((T - 1) * new_fps / fps + 1e-9)) + 1
    s = np.arange(n) * (fps / new_fps)  # the output frames' times, in input frames
    i0 = np.minimum(np.floor(s + 1e-9).astype(int), T - 1)
    i1 = np.minimum(i0 + 1, T - 1)
    u = np.clip(s - i0, 0.0, 1.0)[:, None]
    out = q[i0] * (1.0 - u) + q[i1] * u
    if lay.rot_q.size:
        qi = lay.rot_q[:, None] + np.arange(4)
        quats = _sign_continuous(q[:, qi])  # [T, blocks, 4]
        a, b = quats[i0], quats[i1]
        slerped = quat_mul(a, quat_exp(quat_log(quat_mul(quat_conj(a), b)) * u[:, :, None]))
        out[:, qi] = slerped / np.linalg.norm(slerped, axis=-1, keepdims=True)
    return out


def _trainer_joints(robot: Robot, format: str) -> list[str]:
    """The hinge and slide names; checks the structure the format can hold."""
    for j, ty in enumerate(robot.jnt_types):
        if ty == "ball" or (ty == "free" and j > 0):
            raise JaxanimError(f"robot: the {format!r} format holds a free root joint and hinges and slides; joint "
                               f"{j} ({robot.jnt_names[j]!r}) is a {ty} joint")
    if format in ("csv", "gmr") and (not robot.jnt_types or robot.jnt_types[0] != "free"):
        raise JaxanimError(f"robot: the {format!r} format needs a robot whose first joint is a free joint (its root); "
                           f"the first joint of {robot.name!r} is "
                           f"{robot.jnt_types[0] if robot.jnt_types else 'absent'}")
    return [robot.jnt_names[j] for j, ty in enumerate(robot.jnt_types) if ty in ("hinge", "slide")]


def _check_finite(arrays: dict) -> None:
    for key, value in arrays.items():
        if isinstance(value, np.ndarray) and value.dtype.kind == "f" and not np.isfinite(value).all():
            raise JaxanimError(f"qpos: the {key!r} computed from it is not finite (nothing was written)")


def _write_atomic(path, write) -> None:
    """``write(file)`` into a temporary file beside ``path``, then renamed onto it: a run that stops
    midway leaves no partial file under the final name."""
    path = os.fspath(path)
    tmp = f"{path}.{os.getpid()}.tmp"
    try:
        with open(tmp, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def _body_arrays(robot: Robot, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World positions ``[T, bodies, 3]`` and wxyz quaternions ``[T, bodies, 4]`` (``w >= 0``) of every body, on
    the host (a compiled program per clip length cost seconds of compiling)."""
    xpos, xmat = body_frames_host(robot, q)
    return xpos, matrix_to_quat(xmat)


def _beyondmimic(robot: Robot, lay: TangentLayout, q: np.ndarray, fps: float) -> dict:
    xpos, xquat = _body_arrays(robot, q)
    xpos, xquat = xpos[:, 1:], xquat[:, 1:]  # without the world
    a, b, w = _difference_pairs(len(q))
    k = (fps * w)[:, None, None]
    return {
        "fps": np.asarray([fps], np.float64),
        "joint_pos": q[:, lay.joint_q],
        "joint_vel": _qvel(lay, q, fps)[:, lay.joint_dofs],
        "body_pos_w": xpos,
        "body_quat_w": xquat,
        "body_lin_vel_w": (xpos[b] - xpos[a]) * k,
        "body_ang_vel_w": quat_log(quat_mul(xquat[b], quat_conj(xquat[a]))) * k,
        "body_names": np.asarray(robot.body_names[1:], dtype=str),
    }


def _gmr(robot: Robot, lay: TangentLayout, q: np.ndarray, fps: float) -> dict:
    xpos, xquat = _body_arrays(robot, q)
    root = robot.jnt_bodies[0]  # the free joint's body
    R_world_root = quat_to_matrix(xquat[:, root])  # [T, 3, 3]
    p_root = xpos[:, 1:] - xpos[:, root, None]  # [T, bodies - 1, 3], world axes
    local = np.einsum("tij,tbi->tbj", R_world_root, p_root)  # R_world_root^T p
    return {
        "fps": int(fps) if float(fps).is_integer() else fps,
        "root_pos": q[:, 0:3],
        "root_rot": q[:, _XYZW],
        "dof_pos": q[:, lay.joint_q],
        "local_body_pos": local,
        "link_body_list": list(robot.body_names[1:]),
    }


def write_motion(path, robot: Robot, qpos: Float[Array, "T nq"], fps: float, format: str, *,
                 csv_header: bool = False) -> None:
    """Write a robot clip in a policy trainer's motion format (see the module docstring for each).

    Args:
        path: the file to write (replaced if it exists; written to a temporary file and renamed).
        robot: the robot. ``"csv"`` and ``"gmr"`` need its first joint to be a free joint (the root);
            every format needs its other joints to be hinges or slides.
        qpos: ``[T, nq]`` the clip, MuJoCo's ``qpos`` per frame (quaternions are normalised on writing).
        fps: frames per second, > 0.
        format: ``"csv"``, ``"beyondmimic"`` or ``"gmr"``. ``"npz"`` (jaxanim's own file, written by the
            command line) is refused.
        csv_header: ``"csv"`` only: write a first row of column names (``root_x, root_y, root_z, root_qx,
            root_qy, root_qz, root_qw``, then the joint names).

    Raises:
        JaxanimError: an unknown ``format`` (naming the valid ones) or ``"npz"``; ``qpos`` not ``[T, nq]``
            or not finite; ``fps`` not a number > 0; a ``robot`` the format cannot hold. Nothing is
            written then, nor when a computed value is not finite.
    """
    format = _check_format(format)
    if format == "npz":
        raise JaxanimError("format: 'npz' (jaxanim's own file) is written by the command line, not by "
                           "write_motion; its formats are ['csv', 'beyondmimic', 'gmr']")
    q, lay = _check_qpos(robot, qpos)
    fps = _check_fps("fps", fps)
    names = _trainer_joints(robot, format)
    if format == "csv":
        rows = np.concatenate([q[:, 0:3], q[:, _XYZW], q[:, lay.joint_q]], axis=1)
        _check_finite({"csv": rows})
        header = ",".join(_ROOT_COLUMNS + tuple(names)) if csv_header else ""
        _write_atomic(path, lambda f: np.savetxt(f, rows, fmt="%.17g", delimiter=",", header=header, comments=""))
    elif format == "beyondmimic":
        arrays = _beyondmimic(robot, lay, q, fps)
        _check_finite(arrays)
        _write_atomic(path, lambda f: np.savez(f, **arrays))
    else:
        data = _gmr(robot, lay, q, fps)
        _check_finite(data)
        _write_atomic(path, lambda f: pickle.dump(data, f))
