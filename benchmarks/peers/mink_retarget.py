"""mink (differential IK on MuJoCo, 1.3.0) as the per-frame retargeting peer, run the way GMR runs it.

GMR (github.com/YanjieZe/GMR, ``general_motion_retargeting/motion_retarget.py`` at commit ``4f9e8b7b8b47``,
2025-08-09, package version 0.1.0) retargets a clip one frame after another on one ``mink.Configuration``:

- one ``mink.FrameTask(frame_type="body", position_cost, orientation_cost, lm_damping=1)`` per mapped robot body
  whose two costs are not both zero, its target ``SE3(SO3(wxyz), position)`` in the world frame (Z up, metres);
- two task tables ("stages") solved one after the other on each frame: its G1 configs weight mostly orientations
  in the first (positions only on the pelvis and feet) and positions and orientations in the second;
- per stage: ``mink.solve_ik(configuration, tasks, dt, solver="daqp", damping=0.5)`` then
  ``configuration.integrate_inplace(v, dt)`` with ``dt = model.opt.timestep``, repeated while the norm of the
  stacked task errors (``task.compute_error``, unweighted 6-vectors) falls by more than ``1e-3`` and at most
  ``max_iter = 10`` more times (so 1 to 11 QP solves per stage and frame);
- joint limits: ``solve_ik``'s default ``limits=None`` is ``[mink.ConfigurationLimit(model)]`` (gain 0.95); it is
  passed explicitly here. No posture task, no velocity limits, no collision avoidance;
- warm start: the configuration is never reset, so each frame starts from the previous frame's solution.

GMR's offsets, scale tables and ground offset act on the human data before ``set_target``; here the caller gives
the robot-frame targets directly. Without velocity limits ``dt`` cancels out (the QP unknown is
``dq = v dt`` and :class:`mink.ConfigurationLimit` and the damping act on ``dq``), so the clip's frame rate does
not enter the solve. mink has no batching: :func:`mink_retarget_batch` runs clips one after another.

The robots here have a free joint (``floating_base_joint`` on ``unitree_g1/g1.xml`` and on jaxanim's
``data/humanoid.xml``, ``root`` on ``cmu_humanoid/humanoid_CMU.xml``); :func:`mink_retarget` requires one, since
retargeting moves the floating base.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from . import require

__all__ = ["GMR_DAMPING", "GMR_MAX_ITER", "GMR_TOL", "frame_poses", "frame_types", "load_mink", "load_model",
           "mink_retarget", "mink_retarget_batch"]

GMR_DAMPING = 0.5     # GeneralMotionRetargeting(damping=5e-1)
GMR_MAX_ITER = 10     # self.max_iter: extra solves per stage after the first
GMR_TOL = 1e-3        # continue while the stacked task error norm falls by more than this
GMR_LM_DAMPING = 1.0  # FrameTask(lm_damping=1)


def load_mink():
    """The ``mink`` module, or :class:`PeerUnavailable` (its import pulls in qpsolvers, whose jaxopt backend warns)."""
    require("qpsolvers", "pip install 'qpsolvers[daqp]'", quiet=True)
    return require("mink", "pip install mink==1.3.0", quiet=True)


def load_model(model_path_or_mjmodel) -> Any:
    """A ``mujoco.MjModel`` from an MJCF/URDF path, or the given model unchanged."""
    mujoco = require("mujoco", "pip install mujoco")
    if isinstance(model_path_or_mjmodel, mujoco.MjModel):
        return model_path_or_mjmodel
    return mujoco.MjModel.from_xml_path(str(model_path_or_mjmodel))


def frame_types(model, targets: Sequence[str]) -> tuple[str, ...]:
    """``"body"`` or ``"site"`` for each name in ``targets`` (a body first, as GMR maps bodies).

    Raises:
        ValueError: a name that is neither a body nor a site of ``model``; the message lists the valid ones.
    """
    mujoco = require("mujoco", "pip install mujoco")
    types = []
    for name in targets:
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name) >= 0:
            types.append("body")
        elif mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name) >= 0:
            types.append("site")
        else:
            bodies = [model.body(i).name for i in range(1, model.nbody)]
            sites = [model.site(i).name for i in range(model.nsite)]
            raise ValueError(f"targets: {name!r} is neither a body nor a site of the model; bodies: {bodies}, "
                             f"sites: {sites}")
    return tuple(types)


def frame_poses(model, qpos: np.ndarray, targets: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo's forward kinematics of ``qpos [T, nq]`` at the bodies or sites ``targets``.

    Returns:
        ``(positions [T, K, 3], orientations [T, K, 4])``: world frame, metres, wxyz quaternions.
    """
    mujoco = require("mujoco", "pip install mujoco")
    qpos = np.asarray(qpos, dtype=np.float64)
    if qpos.ndim != 2 or qpos.shape[1] != model.nq:
        raise ValueError(f"qpos: expected shape (T, nq) = (T, {model.nq}), got {qpos.shape}")
    kinds = frame_types(model, targets)
    obj = {"body": mujoco.mjtObj.mjOBJ_BODY, "site": mujoco.mjtObj.mjOBJ_SITE}
    ids = [mujoco.mj_name2id(model, obj[k], n) for n, k in zip(targets, kinds)]
    data = mujoco.MjData(model)
    pos = np.empty((qpos.shape[0], len(targets), 3))
    quat = np.empty((qpos.shape[0], len(targets), 4))
    for t, q in enumerate(qpos):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        for k, (i, kind) in enumerate(zip(ids, kinds)):
            if kind == "body":
                pos[t, k], quat[t, k] = data.xpos[i], data.xquat[i]
            else:
                pos[t, k] = data.site_xpos[i]
                mujoco.mju_mat2Quat(quat[t, k], data.site_xmat[i])
    return pos, quat


def _stage_weights(name: str, w, k: int) -> np.ndarray:
    """``w`` (a scalar, ``[K]`` or ``[S, K]``) as ``[S, K]`` float64, checked finite and non-negative."""
    a = np.asarray(w, dtype=np.float64)
    if a.ndim == 0:
        a = np.full((1, k), float(a))
    elif a.ndim == 1:
        a = a[None]
    if a.ndim != 2 or a.shape[1] != k:
        raise ValueError(f"{name}: expected a scalar, shape (K,) = ({k},) or (stages, K) = (S, {k}), got "
                         f"{np.shape(w)}")
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ValueError(f"{name}: weights must be finite and non-negative")
    return a


class _Retargeter:
    """The mink configuration, the frame tasks of each stage and the limits, built once (untimed) and reused."""

    def __init__(self, mink, model, targets, position_weights, orientation_weights, *, has_orientations, solver,
                 damping, posture_cost, max_iter, tol, dt):
        k = len(targets)
        if k == 0:
            raise ValueError("targets: expected at least one body or site name, got none")
        if len(set(targets)) != k:
            raise ValueError(f"targets: names must be unique, got {list(targets)}")
        kinds = frame_types(model, targets)
        pw = _stage_weights("position_weights", position_weights, k)
        ow = _stage_weights("orientation_weights", orientation_weights, k)
        if pw.shape[0] != ow.shape[0] and 1 not in (pw.shape[0], ow.shape[0]):
            raise ValueError(f"position_weights and orientation_weights: stage counts differ, {pw.shape[0]} and "
                             f"{ow.shape[0]}")
        pw, ow = np.broadcast_arrays(pw, ow)  # one stage's weights serve every stage of the other
        if not has_orientations and np.any(ow > 0):
            raise ValueError("orientation_weights: must be zero when orientations is None")
        free = [j for j in range(model.njnt) if model.jnt_type[j] == 0]  # mjJNT_FREE
        if not free:
            raise ValueError("model: no free joint; retargeting moves the floating base, so the root body needs "
                             "a <freejoint/>")
        self.mink, self.model, self.k = mink, model, k
        self.error_rows = slice(None) if has_orientations else slice(0, 3)  # the SE3 error is [lin; ang]
        self.solver, self.damping, self.max_iter, self.tol = solver, float(damping), int(max_iter), float(tol)
        self.dt = float(model.opt.timestep if dt is None else dt)
        self.configuration = mink.Configuration(model)
        self.limits = [mink.ConfigurationLimit(model)]
        self.frame_tasks: list[list[tuple[int, Any]]] = []  # per stage: (target index, FrameTask)
        for s in range(pw.shape[0]):
            stage = [(i, mink.FrameTask(frame_name=targets[i], frame_type=kinds[i], position_cost=pw[s, i],
                                        orientation_cost=ow[s, i], lm_damping=GMR_LM_DAMPING))
                     for i in range(k) if pw[s, i] != 0 or ow[s, i] != 0]
            if not stage:
                raise ValueError(f"position_weights, orientation_weights: stage {s} has no task with a non-zero "
                                 "weight")
            self.frame_tasks.append(stage)
        self.posture = mink.PostureTask(model, cost=float(posture_cost)) if posture_cost > 0 else None

    def _error(self, tasks) -> float:
        conf = self.configuration
        rows = self.error_rows  # GMR's error1/error2: the norm of the unweighted errors of the frame tasks
        return float(np.linalg.norm(np.concatenate([task.compute_error(conf)[rows] for task in tasks])))

    def _step(self, tasks) -> None:
        v = self.mink.solve_ik(self.configuration, tasks, self.dt, self.solver, self.damping, limits=self.limits)
        self.configuration.integrate_inplace(v, self.dt)

    def run(self, positions: np.ndarray, orientations: np.ndarray | None, qpos_init: np.ndarray) -> np.ndarray:
        mink, conf = self.mink, self.configuration
        identity = mink.SO3.identity()
        conf.update(q=qpos_init)
        out = np.empty((positions.shape[0], self.model.nq))
        for t in range(positions.shape[0]):
            for stage in self.frame_tasks:  # GMR's update_targets: every task's target set from this frame
                for i, task in stage:
                    rot = identity if orientations is None else mink.SO3(orientations[t, i])
                    task.set_target(mink.SE3.from_rotation_and_translation(rot, positions[t, i]))
            extra = []
            if self.posture is not None:
                self.posture.set_target(conf.q)  # stay near the previous frame (off in GMR)
                extra = [self.posture]
            for stage in self.frame_tasks:  # GMR's retarget(): each table until its error stops falling
                tasks = [task for _, task in stage]
                solve = tasks + extra
                err = self._error(tasks)
                self._step(solve)
                new = self._error(tasks)
                n = 0
                while err - new > self.tol and n < self.max_iter:
                    err = new
                    self._step(solve)
                    new = self._error(tasks)
                    n += 1
            out[t] = conf.q
        return out


def _check_clip(model, k: int, positions, orientations, qpos_init, name: str = ""):
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim != 3 or pos.shape[1:] != (k, 3):
        raise ValueError(f"positions{name}: expected shape (T, K, 3) = (T, {k}, 3), got {pos.shape}")
    quat = None
    if orientations is not None:
        quat = np.asarray(orientations, dtype=np.float64)
        if quat.shape != (pos.shape[0], k, 4):
            raise ValueError(f"orientations{name}: expected shape (T, K, 4) = ({pos.shape[0]}, {k}, 4), got "
                             f"{quat.shape}")
        norm = np.linalg.norm(quat, axis=-1, keepdims=True)
        if not np.all(norm > 0):
            raise ValueError(f"orientations{name}: a zero quaternion")
        quat = quat / norm
    if not np.all(np.isfinite(pos)) or (quat is not None and not np.all(np.isfinite(quat))):
        raise ValueError(f"positions/orientations{name}: non-finite values")
    q0 = np.array(model.qpos0 if qpos_init is None else qpos_init, dtype=np.float64)
    if q0.shape != (model.nq,):
        raise ValueError(f"qpos_init{name}: expected shape (nq,) = ({model.nq},), got {q0.shape}")
    return pos, quat, q0


def mink_retarget(model_path_or_mjmodel, targets: Sequence[str], positions, orientations, position_weights,
                  orientation_weights, *, qpos_init=None, solver: str = "daqp", damping: float = GMR_DAMPING,
                  posture_cost: float = 0.0, max_iter: int = GMR_MAX_ITER, tol: float = GMR_TOL,
                  dt: float | None = None) -> tuple[np.ndarray, float]:
    """Retarget one clip with mink, frame by frame, warm-started, as GMR does (see the module docstring).

    Args:
        model_path_or_mjmodel: an MJCF/URDF path or a ``mujoco.MjModel`` with a free joint.
        targets: ``K`` body names (``FrameTask`` of ``frame_type="body"``) or site names (``"site"``).
        positions: ``[T, K, 3]`` target positions, world frame (Z up), metres.
        orientations: ``[T, K, 4]`` target orientations, wxyz, world frame (normalised here); ``None`` for
            positions only (then ``orientation_weights`` must be zero).
        position_weights: ``FrameTask.position_cost`` per target: a scalar, ``[K]`` (one stage) or ``[S, K]``
            (``S`` stages solved in turn on each frame; GMR uses two). A target whose two weights are zero in a
            stage has no task in it.
        orientation_weights: ``FrameTask.orientation_cost``, shaped like ``position_weights``.
        qpos_init: ``[nq]`` start of the first frame (MuJoCo order; free joint ``[x, y, z, qw, qx, qy, qz]``);
            ``None`` for ``model.qpos0``.
        solver: the qpsolvers backend (GMR: ``"daqp"``).
        damping: ``solve_ik``'s Levenberg-Marquardt damping on all dofs (GMR: 0.5).
        posture_cost: a ``PostureTask`` toward the previous frame's ``qpos`` in every stage when positive (GMR: off).
        max_iter: solves per stage and frame after the first, at most (GMR: 10).
        tol: keep solving while the task error norm falls by more than this (GMR: 1e-3); ``-inf`` runs all.
        dt: the integration step, seconds; ``None`` for ``model.opt.timestep`` (GMR). It cancels out of the
            result (no velocity limits), so a clip's frame rate plays no part.

    Returns:
        ``(qpos [T, nq], seconds)``: the retargeted configurations, and the wall-clock time of the frame loop
        (targets set, QP solves, integration), excluding model loading and task construction.

    Raises:
        ValueError: bad shapes, names, weights, or a model without a free joint.
        mink.NoSolutionFound: the QP backend failed on some frame (GMR would stop there too).
        PeerUnavailable: mink, qpsolvers or mujoco cannot be imported.
    """
    mink = load_mink()
    model = load_model(model_path_or_mjmodel)
    pos, quat, q0 = _check_clip(model, len(targets), positions, orientations, qpos_init)
    solver_ = _Retargeter(mink, model, list(targets), position_weights, orientation_weights,
                          has_orientations=quat is not None, solver=solver, damping=damping,
                          posture_cost=posture_cost, max_iter=max_iter, tol=tol, dt=dt)
    start = time.perf_counter()
    qpos = solver_.run(pos, quat, q0)
    return qpos, time.perf_counter() - start


def mink_retarget_batch(model_path_or_mjmodel, targets: Sequence[str], positions: Sequence,
                        orientations: Sequence | None, position_weights, orientation_weights, *,
                        qpos_init=None, solver: str = "daqp", damping: float = GMR_DAMPING,
                        posture_cost: float = 0.0, max_iter: int = GMR_MAX_ITER, tol: float = GMR_TOL,
                        dt: float | None = None) -> tuple[list[np.ndarray], float]:
    """Retarget several clips one after another (mink has no batching), on one configuration and task set.

    Args:
        positions: a list of ``[T_b, K, 3]`` arrays (clips may differ in length).
        orientations: a list of ``[T_b, K, 4]`` wxyz arrays, or ``None`` for positions only.
        qpos_init: ``None`` (``model.qpos0`` for every clip), one ``[nq]`` for all, or ``[B, nq]`` / a list of
            ``[nq]``, one per clip. Each clip starts from its own ``qpos_init``, not from the previous clip.
        The other arguments are those of :func:`mink_retarget`.

    Returns:
        ``(qpos_list, seconds)``: a ``[T_b, nq]`` array per clip and the summed frame-loop time of all clips.
    """
    mink = load_mink()
    model = load_model(model_path_or_mjmodel)
    n = len(positions)
    if orientations is not None and len(orientations) != n:
        raise ValueError(f"orientations: expected {n} clips (one per positions clip), got {len(orientations)}")
    if qpos_init is None:
        inits = [None] * n
    else:
        q = np.asarray(qpos_init, dtype=np.float64)
        inits = [q] * n if q.ndim == 1 else list(q)
        if len(inits) != n:
            raise ValueError(f"qpos_init: expected shape (nq,) or (B, nq) = ({n}, {model.nq}), got {q.shape}")
    clips = [_check_clip(model, len(targets), positions[b], None if orientations is None else orientations[b],
                         inits[b], name=f"[{b}]") for b in range(n)]
    solver_ = _Retargeter(mink, model, list(targets), position_weights, orientation_weights,
                          has_orientations=orientations is not None, solver=solver, damping=damping,
                          posture_cost=posture_cost, max_iter=max_iter, tol=tol, dt=dt)
    out, total = [], 0.0
    for pos, quat, q0 in clips:
        start = time.perf_counter()
        out.append(solver_.run(pos, quat, q0))
        total += time.perf_counter() - start
    return out, total
