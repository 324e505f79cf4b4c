"""Foot contacts of a clip: detection, and a cleanup that plants the feet by inverse kinematics.

Motion capture and procedural or retargeted clips often let a foot slide while it should stand on
the ground ("foot skate"). :func:`clean_foot_contacts` finds the frames where each foot is on the
ground (:func:`detect_foot_contacts`: low and slow), pins the foot where it lands for each run of
such frames, blends the pinned path in and out of each run over a few frames, and moves the legs
to follow it with :func:`~jaxanim.ik.solve_ik_clip` (one compiled solve for all frames; the rest
of the body and the root keep their motion).

The detection and the targets are computed on the host (NumPy) from one batched forward
kinematics of the clip: the runs of contact frames are data-dependent, and a clip is prepared
once. The IK solve is the batched, compiled one.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._errors import JaxanimError
from .._types import Array, Bool, Float
from ..kinematics._contacts import clip_positions, contacts_from_positions, resolve_feet, true_runs, detect_foot_contacts, foot_joints
from ..skeleton._skeleton import Motion, Skeleton
from ._solve import IKOptions, solve_ik_clip
from ._targets import Target

__all__ = ["FootCleanup", "clean_foot_contacts", "detect_foot_contacts", "foot_joints"]


class FootCleanup(eqx.Module):
    """Result of :func:`clean_foot_contacts`.

    Attributes:
        motion: the cleaned clip (same skeleton, frame time and frame count).
        feet: the names of the foot joints (static).
        contacts: ``[frames, feet]`` whether each foot is on the ground.
        targets: ``[frames, feet, 3]`` the foot positions asked of the IK (the pinned path).
        errors: ``[frames, feet]`` distance from each foot to its target after the IK (file units).
        success: ``[frames]`` the IK met every target of the frame within its tolerance.
    """

    motion: Motion
    feet: tuple[str, ...] = eqx.field(static=True)
    contacts: Bool[Array, "frames feet"]
    targets: Float[Array, "frames feet 3"]
    errors: Float[Array, "frames feet"]
    success: Bool[Array, " frames"]


def _pinned_path(P: np.ndarray, contacts: np.ndarray, blend: int) -> np.ndarray:
    """The foot targets ``[F, feet, 3]``: in each run of contact frames the foot's position at the
    run's first frame; outside, the clip's path plus the offsets of the neighbouring runs, each
    fading out with a smoothstep over ``blend`` frames."""
    F = P.shape[0]
    frames = np.arange(F)
    out = P.copy()
    for k in range(P.shape[1]):
        offset = np.zeros((F, 3))
        inside = np.zeros(F, bool)
        for a, b in true_runs(contacts[:, k]):
            anchor = P[a, k]
            offset[a:b] = anchor - P[a:b, k]
            inside[a:b] = True
        fade = np.zeros((F, 3))
        for a, b in true_runs(contacts[:, k]):
            for edge, dist in ((a, a - frames), (b - 1, frames - (b - 1))):
                u = np.clip(dist / (blend + 1.0), 0.0, 1.0)
                w = np.where((dist > 0) & ~inside, 1.0 - u * u * (3.0 - 2.0 * u), 0.0)
                fade += w[:, None] * offset[edge]
        out[:, k] = P[:, k] + np.where(inside[:, None], offset, fade)
    return out


def _leg_joints(skeleton: Skeleton, feet: Sequence[int]) -> set[int]:
    """The joints between each foot and the nearest joint shared by all the feet' chains (the
    hips on a humanoid; the root for a single foot): thigh, shin, ankle, and the foot itself."""
    chains = []
    for j in feet:
        chain = []
        while j >= 0:
            chain.append(j)
            j = skeleton.parents[j]
        chains.append(chain)
    shared = set(chains[0]).intersection(*chains[1:]) if len(chains) > 1 else {chains[0][-1]}
    return {j for chain in chains for j in chain if j not in shared}


def clean_foot_contacts(
    skeleton: Skeleton,
    motion: Motion,
    feet: Sequence[str] | str | None = None,
    *,
    contacts=None,
    up: int = 1,
    ground: float | None = None,
    height: float | None = None,
    speed: float | None = None,
    blend: int | None = None,
    options: IKOptions | None = None,
) -> FootCleanup:
    """Plant the feet of a clip: pin each foot where it lands while it is on the ground.

    Each run of contact frames of a foot (``contacts``, or :func:`detect_foot_contacts` with
    ``up``, ``ground``, ``height`` and ``speed``) keeps the foot at its position in the run's first
    frame; over ``blend`` frames before and after a run the correction fades in and out with a
    smoothstep, so the foot's path stays continuous. The legs follow by
    :func:`~jaxanim.ik.solve_ik_clip`: every frame gets a position target on every foot, and only
    the leg joints (from each foot up to the joint shared by the feet' chains, the hips on a
    humanoid) move; the root and the rest of the body keep their motion. A pin out of the leg's
    reach leaves the foot as close as it gets (``errors``, ``success``).

    Args:
        skeleton, motion: the clip; it is not modified.
        feet: foot joint names (default :func:`foot_joints`).
        contacts: ``[frames, feet]`` bools to use instead of the detection.
        up, ground, height, speed: the detection's settings (:func:`detect_foot_contacts`).
        blend: frames over which a pin fades in and out (default: 0.1 s of frames, at least 1).
        options: :class:`~jaxanim.ik.IKOptions` for the solve (default: the non-leg joints frozen,
            the root translation fixed, regularization ``1e-6`` towards each frame's own pose).

    Returns:
        :class:`FootCleanup`.

    Raises:
        JaxanimError: unknown foot names, ``contacts`` of the wrong shape, a negative ``blend``, a clip
            without frames, with NaN or inf values (naming the frames) or a frame time that is not
            positive.
    """
    motion.check_skeleton(skeleton, "motion")
    motion.check_finite("motion")
    if motion.num_frames == 0:
        raise JaxanimError("motion: the clip has no frames; there are no feet to plant")
    feet, idx = resolve_feet(skeleton, feet, up)
    F = motion.num_frames
    dt = float(motion.frame_time)
    P = np.asarray(clip_positions(skeleton, motion), dtype=np.float64)[:, idx]
    if contacts is None:
        contacts = contacts_from_positions(skeleton, idx, P, dt, up, ground, height, speed)
    else:
        contacts = np.asarray(contacts)
        if contacts.shape != (F, len(feet)):
            raise JaxanimError(
                f"contacts: expected shape (frames, feet) = ({F}, {len(feet)}), got {tuple(contacts.shape)}"
            )
        contacts = contacts.astype(bool)
    if blend is None:
        blend = max(1, int(round(0.1 / dt)))
    if isinstance(blend, bool) or not isinstance(blend, (int, np.integer)) or blend < 0:
        raise JaxanimError(f"blend: expected a number of frames >= 0, got {blend!r}")
    path = _pinned_path(P, contacts, int(blend))
    if options is None:
        moving = _leg_joints(skeleton, idx)
        frozen = tuple(n for j, n in enumerate(skeleton.names) if j not in moving)
        options = IKOptions(frozen=frozen, root_translation="fixed", regularization=jnp.asarray(1e-6))
    dtype = motion.rotations.dtype
    targets = [Target(f, position=jnp.asarray(path[:, k], dtype)) for k, f in enumerate(feet)]
    cleaned, sol = solve_ik_clip(skeleton, motion, targets, options=options)
    return FootCleanup(
        motion=cleaned,
        feet=feet,
        contacts=jnp.asarray(contacts),
        targets=jnp.asarray(path, dtype),
        errors=sol.position_errors,
        success=sol.success,
    )
