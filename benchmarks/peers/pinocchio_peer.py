"""Pinocchio adapter: a :class:`jaxanim.Skeleton` as a ``pinocchio.Model`` (free flyer root, spherical joints, a
``JOINT`` frame per joint, an ``OP_FRAME`` per End Site), timed loops and CLIK; ``q`` stores quaternions xyzw."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from . import require

__all__ = ["PinocchioSkeleton", "build_model", "clik_loop", "clik_solve", "configurations", "fk_loop",
           "frame_jacobians", "jacobian_loop", "positions", "to_parent_frame_columns", "to_poses"]


@dataclasses.dataclass(frozen=True)
class PinocchioSkeleton:
    """The model, one reused ``data``, the joint ids (``j + 1``), End Site frame ids and frame ids by site name."""

    pin: Any
    model: Any
    data: Any
    joint_ids: tuple[int, ...]
    end_site_frame_ids: tuple[int, ...]
    frame_ids: dict[str, int]


def build_model(skeleton) -> PinocchioSkeleton:
    """The Pinocchio model of ``skeleton`` (non-root joints at their OFFSETs); ``PeerUnavailable`` without Pinocchio."""
    pin = require("pinocchio", "pip install pin==4.0.0")
    offsets = np.asarray(skeleton.offsets, dtype=np.float64)
    model = pin.Model()
    model.name = "jaxanim_skeleton"
    joint_ids, joint_frames, end_ids, frame_ids = [], [], [], {}
    for j, (name, parent) in enumerate(zip(skeleton.names, skeleton.parents)):
        root = parent < 0
        jid = model.addJoint(0 if root else joint_ids[parent], pin.JointModelFreeFlyer() if root else
                             pin.JointModelSpherical(), pin.SE3.Identity() if root else
                             pin.SE3(np.eye(3), offsets[j].copy()), name)
        joint_ids.append(jid)
        joint_frames.append(frame_ids.setdefault(name, model.addJointFrame(jid, 0 if root else joint_frames[parent])))
    for name, parent, off in zip(skeleton.end_site_names, skeleton.end_site_parents,
                                 np.asarray(skeleton.end_site_offsets, dtype=np.float64)):
        end_ids.append(frame_ids.setdefault(name, model.addFrame(pin.Frame(
            name, joint_ids[parent], joint_frames[parent], pin.SE3(np.eye(3), off.copy()), pin.FrameType.OP_FRAME))))
    return PinocchioSkeleton(pin, model, model.createData(), tuple(joint_ids), tuple(end_ids), frame_ids)


def configurations(rotations: np.ndarray, root_translations: np.ndarray) -> np.ndarray:
    """``[B, nq]`` Pinocchio ``q`` of ``[B, J, 4]`` wxyz rotations and ``[B, 3]`` root translations:
    ``[x, y, z, qx, qy, qz, qw]`` for the free flyer, then ``[qx, qy, qz, qw]`` per spherical joint."""
    rot = np.asarray(rotations, dtype=np.float64)
    rot = rot / np.linalg.norm(rot, axis=-1, keepdims=True)
    b = rot.shape[0]
    root = np.asarray(root_translations, dtype=np.float64).reshape(b, 3)
    return np.ascontiguousarray(np.concatenate([root, rot[..., [1, 2, 3, 0]].reshape(b, -1)], axis=-1))


def fk_loop(ps: PinocchioSkeleton, qs: Sequence[np.ndarray]) -> None:
    """``pinocchio.forwardKinematics`` for each configuration (the timed call)."""
    fk, model, data = ps.pin.forwardKinematics, ps.model, ps.data
    for q in qs:
        fk(model, data, q)


def jacobian_loop(ps: PinocchioSkeleton, qs: Sequence[np.ndarray], frame_ids: Sequence[int]) -> None:
    """``computeJointJacobians`` then ``getFrameJacobian(LOCAL_WORLD_ALIGNED)`` per site (the timed call)."""
    pin, model, data = ps.pin, ps.model, ps.data
    cjj, gfj, lwa = pin.computeJointJacobians, pin.getFrameJacobian, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    for q in qs:
        cjj(model, data, q)
        for fid in frame_ids:
            gfj(model, data, fid, lwa)


def positions(ps: PinocchioSkeleton, qs: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``([B, joints, 3], [B, end_sites, 3])``: ``oMi`` and End Site ``oMf`` translations (untimed)."""
    pin, model, data = ps.pin, ps.model, ps.data
    pj = np.empty((len(qs), len(ps.joint_ids), 3))
    pe = np.empty((len(qs), len(ps.end_site_frame_ids), 3))
    for b, q in enumerate(qs):
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        pj[b] = [data.oMi[j].translation for j in ps.joint_ids]  # copies: oMi / oMf are views into data
        pe[b] = [data.oMf[f].translation for f in ps.end_site_frame_ids]
    return pj, pe


def frame_jacobians(ps: PinocchioSkeleton, qs: Sequence[np.ndarray], frame_ids: Sequence[int]) -> np.ndarray:
    """``[B, sites, 6, nv]`` ``LOCAL_WORLD_ALIGNED`` frame Jacobians in Pinocchio's columns (untimed)."""
    pin, model, data = ps.pin, ps.model, ps.data
    out = np.empty((len(qs), len(frame_ids), 6, model.nv))
    for b, q in enumerate(qs):
        pin.computeJointJacobians(model, data, q)
        out[b] = [pin.getFrameJacobian(model, data, f, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED) for f in frame_ids]
    return out


def to_parent_frame_columns(jac: np.ndarray, local_rotations: np.ndarray) -> np.ndarray:
    """Pinocchio's ``[B, sites, 6, nv]`` columns ``[v_root | w_0 | w_1 ...]`` (local frames) as jaxanim's
    ``[dt | d_0 | d_1 ...]``: each 3-column block times ``R^T`` of its joint (the root's for both root blocks)."""
    b, s, _, nv = jac.shape
    rots = np.concatenate([local_rotations[:, :1], local_rotations], axis=1)
    assert rots.shape[1] == nv // 3
    return np.einsum("bsrkc,bkdc->bsrkd", jac.reshape(b, s, 6, nv // 3, 3), rots).reshape(b, s, 6, nv)


def clik_solve(ps: PinocchioSkeleton, q0: np.ndarray, frame_ids: Sequence[int], positions: np.ndarray,
               rotations: np.ndarray, *, damping: float, max_iterations: int, position_tolerance: float,
               orientation_tolerance: float) -> tuple[np.ndarray, int, bool]:
    """``(q, iterations, converged)`` of damped least-squares IK (CLIK) from ``q0 [nq]`` to world targets
    ``positions [frames, 3]`` / ``rotations [frames, 3, 3]``: ``q = integrate(q, J^T (J J^T + lambda I)^{-1} e)``,
    ``e = [p_k - p(q); log3(R_k R(q)^T)]`` in world axes, ``J`` ``LOCAL_WORLD_ALIGNED``, until all errors pass."""
    pin, model, data = ps.pin, ps.model, ps.data
    lwa = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    n = len(frame_ids)
    e, jac, damp = np.empty(6 * n), np.empty((6 * n, model.nv)), damping * np.eye(6 * n)
    q = np.array(q0, dtype=np.float64)
    for it in range(max_iterations + 1):
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        done = True
        for k, fid in enumerate(frame_ids):
            oMf = data.oMf[fid]
            dp, w = positions[k] - oMf.translation, pin.log3(rotations[k] @ oMf.rotation.T)
            e[6 * k:6 * k + 3], e[6 * k + 3:6 * k + 6] = dp, w
            done = done and dp @ dp < position_tolerance**2 and w @ w < orientation_tolerance**2
        if done:
            return q, it, True
        if it == max_iterations:
            break
        for k, fid in enumerate(frame_ids):
            jac[6 * k:6 * k + 6] = pin.getFrameJacobian(model, data, fid, lwa)
        q = pin.integrate(model, q, jac.T @ np.linalg.solve(jac @ jac.T + damp, e))
    return q, max_iterations, False


def clik_loop(ps: PinocchioSkeleton, q0s: Sequence[np.ndarray], frame_ids: Sequence[int], positions: np.ndarray,
              rotations: np.ndarray, **kwargs: Any) -> tuple[list[np.ndarray], np.ndarray]:
    """:func:`clik_solve` for each problem (the timed call): ``(final configurations, iterations [B])``."""
    out = [clik_solve(ps, q0, frame_ids, positions[b], rotations[b], **kwargs) for b, q0 in enumerate(q0s)]
    return [q for q, _, _ in out], np.array([it for _, it, _ in out], dtype=np.int64)


def to_poses(qs: Sequence[np.ndarray], offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(rotations [B, J, 4] wxyz, translations [B, J, 3])`` of configurations (non-root translations = OFFSETs)."""
    q = np.stack([np.asarray(x, dtype=np.float64) for x in qs])
    b, J = q.shape[0], offsets.shape[0]
    t = np.broadcast_to(np.asarray(offsets, dtype=np.float64), (b, J, 3)).copy()
    t[:, 0] = q[:, :3]
    return q[:, 3:].reshape(b, J, 4)[..., [3, 0, 1, 2]], t
