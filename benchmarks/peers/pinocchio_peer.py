"""Pinocchio adapter: a :class:`jaxanim.Skeleton` as a ``pinocchio.Model``, and timed loops.

Model: the root is a ``JointModelFreeFlyer`` placed at the world origin (the free flyer carries the
root translation), every other joint a ``JointModelSpherical`` placed at its translation in its
parent's frame (its OFFSET) with an identity rotation, so Pinocchio's joint frames coincide with
jaxanim's. Each joint also gets a ``JOINT`` frame of the same name, and each End Site an
``OP_FRAME`` frame named ``<joint>_End`` placed at its OFFSET, so sites can be looked up by the
names jaxanim uses. The tree has nq = 7 + 4 (J-1) and nv = 6 + 3 (J-1).

Joints other than the root that have BVH position channels cannot be represented by a spherical
joint: they are treated as **fixed offsets equal to their current values** (pass the frame's local
``translations`` to :func:`build_model`; the model is then only valid for that frame). The CMU
skeleton has none.

Conventions differ from jaxanim's, and are converted explicitly here:

* **Quaternions.** jaxanim is wxyz; Pinocchio's ``q`` stores quaternions as **xyzw**. The free
  flyer's block of ``q`` is ``[x, y, z, qx, qy, qz, qw]`` and a spherical joint's ``[qx, qy, qz,
  qw]``; :func:`configurations` reorders and normalises.
* **Velocities.** Pinocchio's free-flyer velocity is the root's twist in its *local* frame and a
  spherical joint's angular velocity is in the joint's *local* frame (``R <- R exp(w)``), while
  jaxanim's Jacobian columns are the root translation in the world and rotation-vector increments
  in the *parent* frame (``R <- exp(d) R``). Since ``exp(d) R = R exp(R^T d)``, each 3-column block
  of Pinocchio's Jacobian times ``R_local^T`` gives jaxanim's (:func:`to_parent_frame_columns`).

Timing rule (PEERS.md): the timed loops call Pinocchio only and never copy results out to numpy
(copying 31 positions costs ~55 µs, far more than the FK itself); reading results is done in separate,
untimed functions.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from . import require

__all__ = [
    "PinocchioSkeleton",
    "build_model",
    "configurations",
    "fk_loop",
    "frame_jacobians",
    "jacobian_loop",
    "load_pinocchio",
    "positions",
    "to_parent_frame_columns",
]


def load_pinocchio() -> Any:
    """Import ``pinocchio`` or raise :class:`~benchmarks.peers.PeerUnavailable`."""
    return require("pinocchio", "pip install pin==4.0.0")


@dataclasses.dataclass(frozen=True)
class PinocchioSkeleton:
    """A Pinocchio model of a skeleton plus the index maps back to jaxanim's names.

    Attributes:
        pin: the ``pinocchio`` module.
        model: the ``pinocchio.Model``.
        data: a ``pinocchio.Data`` for it (reused by every call; not thread safe).
        joint_ids: Pinocchio joint id of each jaxanim joint (``j + 1``; 0 is the universe).
        end_site_frame_ids: Pinocchio frame id of each End Site.
        frame_ids: frame id by jaxanim site name (joint names and ``<joint>_End`` names).
    """

    pin: Any
    model: Any
    data: Any
    joint_ids: tuple[int, ...]
    end_site_frame_ids: tuple[int, ...]
    frame_ids: dict[str, int]


def build_model(skeleton, translations: np.ndarray | None = None) -> PinocchioSkeleton:
    """Build the Pinocchio model of ``skeleton``.

    Args:
        skeleton: a :class:`jaxanim.Skeleton`.
        translations: optional ``[joints, 3]`` local translations of one frame (file units). Non-root
            joints are placed there instead of at their OFFSET: use it for skeletons whose non-root
            joints have position channels (they become fixed offsets at these values). The root's
            entry is ignored (the free flyer carries it).

    Returns:
        The :class:`PinocchioSkeleton`.

    Raises:
        PeerUnavailable: Pinocchio is not installed.
    """
    pin = load_pinocchio()
    offsets = np.asarray(skeleton.offsets, dtype=np.float64)
    if translations is not None:
        offsets = np.asarray(translations, dtype=np.float64).reshape(offsets.shape)
    model = pin.Model()
    model.name = "jaxanim_skeleton"
    joint_ids: list[int] = []
    joint_frames: list[int] = []
    frame_ids: dict[str, int] = {}
    for j, (name, parent) in enumerate(zip(skeleton.names, skeleton.parents)):
        if parent < 0:
            jid = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), name)
            fid = model.addJointFrame(jid, 0)
        else:
            placement = pin.SE3(np.eye(3), offsets[j].copy())
            jid = model.addJoint(joint_ids[parent], pin.JointModelSpherical(), placement, name)
            fid = model.addJointFrame(jid, joint_frames[parent])
        joint_ids.append(jid)
        joint_frames.append(fid)
        frame_ids[name] = fid
    end_ids: list[int] = []
    end_offsets = np.asarray(skeleton.end_site_offsets, dtype=np.float64)
    for name, parent, off in zip(skeleton.end_site_names, skeleton.end_site_parents, end_offsets):
        placement = pin.SE3(np.eye(3), off.copy())
        frame = pin.Frame(name, joint_ids[parent], joint_frames[parent], placement, pin.FrameType.OP_FRAME)
        fid = model.addFrame(frame)
        end_ids.append(fid)
        frame_ids[name] = fid
    return PinocchioSkeleton(pin, model, model.createData(), tuple(joint_ids), tuple(end_ids), frame_ids)


def configurations(rotations: np.ndarray, root_translations: np.ndarray) -> np.ndarray:
    """Pinocchio configurations ``q`` from jaxanim poses.

    Args:
        rotations: ``[B, joints, 4]`` local rotations, **wxyz** (jaxanim's convention); normalised here.
        root_translations: ``[B, 3]`` root translations in the world (file units).

    Returns:
        ``[B, nq]`` float64 C-contiguous ``q``: ``[x, y, z, qx, qy, qz, qw]`` for the free flyer, then
        ``[qx, qy, qz, qw]`` (**xyzw**, Pinocchio's order) for each spherical joint.
    """
    rot = np.asarray(rotations, dtype=np.float64)
    rot = rot / np.linalg.norm(rot, axis=-1, keepdims=True)
    xyzw = rot[..., [1, 2, 3, 0]]  # wxyz -> xyzw
    b = rot.shape[0]
    root = np.asarray(root_translations, dtype=np.float64).reshape(b, 3)
    return np.ascontiguousarray(np.concatenate([root, xyzw.reshape(b, -1)], axis=-1))


def fk_loop(ps: PinocchioSkeleton, qs: Sequence[np.ndarray]) -> None:
    """``pinocchio.forwardKinematics`` for each configuration (the timed call; copies nothing out)."""
    fk, model, data = ps.pin.forwardKinematics, ps.model, ps.data
    for q in qs:
        fk(model, data, q)


def jacobian_loop(ps: PinocchioSkeleton, qs: Sequence[np.ndarray], frame_ids: Sequence[int]) -> None:
    """``computeJointJacobians`` then ``getFrameJacobian(LOCAL_WORLD_ALIGNED)`` per site, per configuration.

    This is the timed call. ``getFrameJacobian`` necessarily returns a new ``6 x nv`` numpy array per
    site; nothing else is copied.
    """
    pin, model, data = ps.pin, ps.model, ps.data
    cjj, gfj, lwa = pin.computeJointJacobians, pin.getFrameJacobian, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    for q in qs:
        cjj(model, data, q)
        for fid in frame_ids:
            gfj(model, data, fid, lwa)


def positions(ps: PinocchioSkeleton, qs: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Global joint and End Site positions (untimed; for the accuracy check).

    Returns:
        ``([B, joints, 3], [B, end_sites, 3])`` float64: ``data.oMi[j].translation`` and
        ``data.oMf[frame].translation`` after ``forwardKinematics`` + ``updateFramePlacements``.
    """
    pin, model, data = ps.pin, ps.model, ps.data
    pj = np.empty((len(qs), len(ps.joint_ids), 3))
    pe = np.empty((len(qs), len(ps.end_site_frame_ids), 3))
    for b, q in enumerate(qs):
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        for k, jid in enumerate(ps.joint_ids):
            pj[b, k] = data.oMi[jid].translation
        for k, fid in enumerate(ps.end_site_frame_ids):
            pe[b, k] = data.oMf[fid].translation
    return pj, pe


def frame_jacobians(ps: PinocchioSkeleton, qs: Sequence[np.ndarray], frame_ids: Sequence[int]) -> np.ndarray:
    """Pinocchio's frame Jacobians, ``LOCAL_WORLD_ALIGNED`` (untimed; for the accuracy check).

    Returns:
        ``[B, sites, 6, nv]`` float64, rows ``[linear; angular]`` in world axes, columns Pinocchio's
        (see :func:`to_parent_frame_columns` to compare with jaxanim).
    """
    pin, model, data = ps.pin, ps.model, ps.data
    out = np.empty((len(qs), len(frame_ids), 6, model.nv))
    for b, q in enumerate(qs):
        pin.computeJointJacobians(model, data, q)
        for k, fid in enumerate(frame_ids):
            out[b, k] = pin.getFrameJacobian(model, data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    return out


def to_parent_frame_columns(jac: np.ndarray, local_rotations: np.ndarray) -> np.ndarray:
    """Re-express Pinocchio Jacobian columns in jaxanim's parametrisation.

    jaxanim's columns are ``[root translation (world) | d_0 | d_1 | ...]`` with ``R_j <- exp(d_j)
    R_j`` (increment in the parent frame). Pinocchio's are ``[v_root (root local) | w_0 (root local)
    | w_1 (joint 1 local) | ...]``. With ``R_j`` the local rotation matrices, ``v = R_0^T dt`` and
    ``w_j = R_j^T d_j``, so each 3-column block is multiplied on the right by ``R^T`` of its joint
    (the root's for both the translation and the root-rotation blocks).

    Args:
        jac: ``[B, sites, 6, 6 + 3 (J-1)]`` Pinocchio Jacobians.
        local_rotations: ``[B, J, 3, 3]`` local rotation matrices ``R_parent_joint``.

    Returns:
        ``[B, sites, 6, 3 + 3 J]`` in jaxanim's column convention.
    """
    b, s, _, nv = jac.shape
    nj = local_rotations.shape[1]
    blocks = jac.reshape(b, s, 6, nv // 3, 3)
    rots = np.concatenate([local_rotations[:, :1], local_rotations], axis=1)  # root R twice: v and w_0
    assert rots.shape[1] == nv // 3 == nj + 1
    out = np.einsum("bsrkc,bkdc->bsrkd", blocks, rots)  # block @ R^T
    return out.reshape(b, s, 6, nv)
