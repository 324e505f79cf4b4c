"""Retargeting human motion onto a robot: :func:`retarget` (one clip) and :func:`retarget_clips`
(a batch, padded to one length and solved by one ``vmap``)."""

from __future__ import annotations

from collections.abc import Sequence

import jax
import numpy as np

from .._errors import JaxanimError
from ..skeleton._skeleton import Motion, Skeleton
from ._mapping import Calibration, RetargetMap, load_mapping
from ._problem import prepare_retarget, stack_problems
from ._solve import RetargetOptions, RetargetResult, solve_retarget
from ..robots._robot import Robot

__all__ = ["retarget", "retarget_clips"]


def _check_options(options) -> RetargetOptions:
    options = RetargetOptions() if options is None else options
    if not isinstance(options, RetargetOptions):
        raise JaxanimError(f"options: expected a RetargetOptions, got {type(options).__name__}")
    if isinstance(options.iterations, bool) or not isinstance(options.iterations, int) or options.iterations < 1:
        raise JaxanimError(f"options.iterations: expected a positive int, got {options.iterations!r}")
    for name in ("velocity_weight", "acceleration_weight", "plant_weight", "ground_weight", "posture_weight",
                 "velocity_limit_weight", "rtol", "xtol"):
        value = np.asarray(getattr(options, name))
        if value.shape != () or not np.isfinite(value) or value < 0:
            raise JaxanimError(f"options.{name}: expected a finite number >= 0, got {value!r}")
    vmax = np.asarray(options.max_joint_velocity)
    if vmax.shape != () or not vmax > 0:
        raise JaxanimError(f"options.max_joint_velocity: expected a number > 0 (inf: no limit), got {vmax!r}")
    return options


def _check_robot(robot) -> None:
    if not isinstance(robot, Robot):
        raise JaxanimError(f"robot: expected a Robot (robots.load_robot), got {type(robot).__name__}")


def retarget(
    skeleton: Skeleton,
    motion: Motion,
    robot: Robot,
    mapping: RetargetMap | str | dict,
    *,
    options: RetargetOptions | None = None,
    calibration: Calibration | None = None,
    contacts=None,
    fixed_base: bool = False,
) -> RetargetResult:
    """Retarget one clip onto a robot: one least-squares problem over the whole clip.

    Every frame matches the map's pairs (positions and orientations, scaled and turned into the
    robot's frame), the feet stay planted, flat and on the ground in each stance phase the source
    shows, nothing goes below the ground, the joints stay in their ranges (hard bounds) and under
    ``options.max_joint_velocity``, and velocities and accelerations are penalized; the normal
    equations are block banded in time and solved in O(T) (see ``_retarget_solve``).

    Args:
        skeleton, motion: the source clip (any BVH dialect); not modified.
        robot: the robot (:func:`load_robot`), with a floating base.
        mapping: a :class:`RetargetMap`, or a JSON path or dict (:func:`load_mapping`).
        options: :class:`RetargetOptions`.
        calibration: axes, scale and offsets (default :func:`calibrate`: from the source's rest pose
            and the robot's zero pose).
        contacts: ``[frames, feet]`` stance frames instead of the detection.
        fixed_base: refuse a robot whose root is not moved by a free joint instead of adding one
            (see :func:`prepare_retarget`).

    A robot without a free joint on its root (a URDF) gets one, ``"root_joint"``, first in ``qpos``
    (:func:`~jaxanim.robots.with_floating_base`); a foot without collision geometry stands on its
    target's frame (:func:`with_soles`).

    Returns:
        :class:`RetargetResult`: ``qpos [T, nq]`` (of :func:`prepared_robot`), ``fps``, ``result``, ``success``, ``cost`` and the
        per-frame ``diagnostics`` (:func:`summary` condenses them).
    """
    _check_robot(robot)
    options = _check_options(options)
    problem = prepare_retarget(skeleton, motion, robot, mapping, calibration=calibration, contacts=contacts,
                               fixed_base=fixed_base)
    return solve_retarget(robot, problem, options)


def retarget_clips(
    skeleton: Skeleton | Sequence[Skeleton],
    motions: Sequence[Motion],
    robot: Robot,
    mapping: RetargetMap | str | dict,
    *,
    options: RetargetOptions | None = None,
    fixed_base: bool = False,
) -> list[RetargetResult]:
    """Retarget a batch of clips in one ``vmap``: each is padded to the longest with a mask.

    Args:
        skeleton: the clips' skeleton, or one per clip (each with the map's joint names).
        motions: the clips.
        robot, mapping, options, fixed_base: as :func:`retarget`.

    Returns:
        One :class:`RetargetResult` per clip, cut to its own length.
    """
    _check_robot(robot)
    options = _check_options(options)
    if isinstance(motions, Motion) or not isinstance(motions, Sequence) or not motions:
        raise JaxanimError("motions: expected a non-empty list of Motion (one per clip)")
    skeletons = list(skeleton) if isinstance(skeleton, Sequence) else [skeleton] * len(motions)
    if len(skeletons) != len(motions):
        raise JaxanimError(f"skeleton: {len(skeletons)} skeletons for {len(motions)} clips")
    mapping = mapping if isinstance(mapping, RetargetMap) else load_mapping(mapping)
    length = max(m.num_frames for m in motions)
    problems = []
    for i, (s, m) in enumerate(zip(skeletons, motions)):
        try:
            problems.append(prepare_retarget(s, m, robot, mapping, length=length, fixed_base=fixed_base))
        except JaxanimError as exc:
            raise JaxanimError(f"motions[{i}]: {exc}") from None
    batch = jax.vmap(solve_retarget, in_axes=(None, 0, None))(robot, stack_problems(problems), options)
    out = []
    for i, m in enumerate(motions):
        one = jax.tree.map(lambda x: x[i], batch)
        n = m.num_frames  # every array of a result that is not a scalar is per frame
        out.append(jax.tree.map(lambda x: x[:n] if getattr(x, "ndim", 0) else x, one))
    return out
