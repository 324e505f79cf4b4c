"""Inverse kinematics on a :class:`~jaxanim.Skeleton` as a nonlinear least-squares problem.

:func:`solve_ik` minimizes the course notes' objective (``SEEDS.md`` §1.F; the variables, pins,
frozen joints and the residual are described in ``jaxanim/ik/_problem.py``) with
:func:`solvers.least_squares` (Gauss-Newton or Levenberg-Marquardt, own or backend solvers) and the
analytic Jacobian of :func:`jaxanim.jacobian`; :func:`solve_ik_clip` maps it over a clip's frames.

Options. The configuration is one :class:`IKOptions` Module, ``options=``; every option is also a
keyword of :func:`solve_ik` (the 0.1 calls), and a keyword given together with ``options=`` wins
over that field.

Compiling once. The public functions check their input in Python and call one
``eqx.filter_jit``-ed core per structure (skeleton tree, target sites, options): a second call
with new values (targets, start pose, weights) reuses the compiled solve.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import solvers

from .. import rotations as rot
from .._errors import JaxanimError, check_shape
from .._types import Array, Float
from ..kinematics._fk import site_transforms_sequential
from ..kinematics._limits import EulerLimit as EulerLimit, SwingTwistLimit as SwingTwistLimit
from ..kinematics._limits import bone_axis, limit_violation as limit_violation
from ._robot import solve_ik_robot, target_errors
from ..robots._robot import Robot
from ..skeleton._skeleton import Motion, Skeleton
from ._problem import _layout as _layout, _pose, _residual, _residual_and_jacobian as _residual_and_jacobian
from ._problem import _setup, _stop
from ._targets import Target as Target, targets_from_json as targets_from_json


class IKSolution(eqx.Module):
    """Result of :func:`solve_ik`.

    Attributes:
        rotations: ``[joints, 4]`` local wxyz quaternions of the solved pose.
        translations: ``[joints, 3]`` local translations (the root's may have moved).
        result: :class:`solvers.RESULTS`, per element under ``vmap``.
        stats: the solver's statistics (``num_steps``, ``cost``, ...).
        position_errors: ``[targets]`` distance to each position target (0 where none).
        orientation_errors: ``[targets]`` angle to each orientation target, radians (0 where none).
        success: scalar bool: the solver converged **and** every target is met within the
            tolerances of :func:`solve_ik`. An unreachable target gives ``False`` with ``result``
            successful: the pose is then the least-squares-closest one the solver found.
    """

    rotations: Float[Array, "joints 4"]
    translations: Float[Array, "joints 3"]
    result: solvers.RESULTS
    stats: dict
    position_errors: Float[Array, " targets"]
    orientation_errors: Float[Array, " targets"]
    success: Array


def _names(frozen) -> tuple[str, ...]:
    return (frozen,) if isinstance(frozen, str) else tuple(str(n) for n in frozen)


def _limit_tuple(limits) -> tuple:
    return (limits,) if isinstance(limits, (EulerLimit, SwingTwistLimit)) else tuple(limits)


def _optional_array(x):
    return None if x is None else jnp.asarray(x)


class IKOptions(eqx.Module):
    """The configuration of :func:`solve_ik` and :func:`solve_ik_clip` (each field is also a
    keyword of theirs; see :func:`solve_ik` for what each means).

    Structure (``pin``, ``frozen``, ``root_translation``, ``limit_mode``, ``stop_at_tolerance``,
    ``throw``) is static; the numbers are arrays (sweepable with ``vmap``), except
    ``regularization``, whose literal ``0`` removes the regularizer's rows (a Python float is
    static under jit: pass an array to sweep it without recompiling).
    """

    pin: str | None = eqx.field(static=True, default=None)
    frozen: tuple[str, ...] = eqx.field(static=True, default=(), converter=_names)
    root_translation: str = eqx.field(static=True, default="free")
    regularization: float | Float[Array, ""] = 0.0
    joint_weights: Float[Array, " joints"] | None = eqx.field(default=None, converter=_optional_array)
    limits: tuple = eqx.field(default=(), converter=_limit_tuple)
    limit_mode: str = eqx.field(static=True, default="hard")
    limit_weight: Float[Array, ""] = eqx.field(default=1.0, converter=jnp.asarray)
    position_tolerance: Float[Array, ""] | None = eqx.field(default=None, converter=_optional_array)
    orientation_tolerance: Float[Array, ""] = eqx.field(default=1e-4, converter=jnp.asarray)
    stop_at_tolerance: bool = eqx.field(static=True, default=True)
    solver: solvers.AbstractLeastSquaresSolver | None = None
    throw: bool = eqx.field(static=True, default=False)


_OPTION_NAMES = tuple(f for f in IKOptions.__dataclass_fields__)


class _Unset:
    """The default of :func:`solve_ik`'s option keywords: take the value from ``options``."""

    def __repr__(self) -> str:
        return "<from options>"


_UNSET = _Unset()


def _resolve_options(options: IKOptions | None, keywords: dict) -> IKOptions:
    """``options`` (default :class:`IKOptions`) with the keywords that were given in its place."""
    if options is None:
        options = IKOptions()
    elif not isinstance(options, IKOptions):
        raise JaxanimError(f"options: expected a jaxanim.ik.IKOptions, got {type(options).__name__}")
    unknown = sorted(set(keywords) - set(_OPTION_NAMES))
    if unknown:
        raise TypeError(f"unexpected keyword arguments {unknown}; the options are {list(_OPTION_NAMES)}")
    given = {k: v for k, v in keywords.items() if v is not _UNSET}
    if not given:
        return options
    fields = {k: getattr(options, k) for k in _OPTION_NAMES}
    fields.update(given)
    return IKOptions(**fields)


def _skeleton_defaults(skeleton: Skeleton, options: IKOptions) -> IKOptions:
    """Fill in the defaults that are computed from the skeleton's offsets, while they are concrete
    (before the jitted core, where the skeleton is traced): the position tolerance (``1e-5`` times
    the skeleton's size, the sum of |offsets|) and the twist axis of a swing-twist limit without one
    (the bone)."""
    offsets = skeleton.offsets
    traced = isinstance(offsets, jax.core.Tracer)
    if options.position_tolerance is None:
        if traced:  # the same sum, in the graph
            size = jnp.sum(jnp.abs(offsets))
        else:
            size = float(np.abs(np.asarray(offsets)).sum())
        options = eqx.tree_at(lambda o: o.position_tolerance, options, jnp.asarray(1e-5 * size),
                              is_leaf=lambda x: x is None)
    if not traced and any(isinstance(lim, SwingTwistLimit) and lim.axis is None for lim in options.limits):
        limits = tuple(
            eqx.tree_at(lambda x: x.axis, lim, jnp.asarray(bone_axis(skeleton, skeleton.index(lim.joint))),
                        is_leaf=lambda x: x is None)
            if isinstance(lim, SwingTwistLimit) and lim.axis is None else lim
            for lim in options.limits
        )
        options = eqx.tree_at(lambda o: o.limits, options, limits)
    return options


def _check_problem(skeleton, targets, rotations, translations, reference, options: IKOptions):
    """Python-side checks of one problem (before tracing); the layout and the pose arrays."""
    if not isinstance(skeleton, Skeleton):
        raise JaxanimError(f"skeleton: expected a jaxanim.Skeleton, got {type(skeleton).__name__}")
    J = skeleton.num_joints
    layout = _layout(skeleton, targets, options.pin, options.frozen, options.root_translation, options.limits,
                     options.limit_mode)
    check_shape("rotations", rotations, (J, 4), what=f"(joints, 4) = ({J}, 4)")
    q0 = jnp.asarray(rotations)
    if translations is not None:
        check_shape("translations", translations, (J, 3), what=f"(joints, 3) = ({J}, 3)")
    if reference is not None:
        check_shape("reference[0]", reference[0], (J, 4), what=f"(joints, 4) = ({J}, 4)")
        check_shape("reference[1]", reference[1], (J, 3), what=f"(joints, 3) = ({J}, 3)")
    if options.joint_weights is not None:
        check_shape("joint_weights", options.joint_weights, (J,), what=f"(joints,) = ({J},)")
        solver = options.solver
        if isinstance(solver, solvers.LevenbergMarquardt) and solver.weights is not None:
            raise JaxanimError("joint_weights: the solver already has weights; give one or the other")
    return layout, (targets,) if isinstance(targets, Target) else tuple(targets), q0


@eqx.filter_jit
def _solve(skeleton, layout, targets, q0, translations, reference, options: IKOptions) -> IKSolution:
    """The compiled core of :func:`solve_ik` (one trace per structure)."""
    J = skeleton.num_joints
    dtype = q0.dtype
    t0 = skeleton.offsets.astype(dtype) if translations is None else jnp.asarray(translations, dtype)
    if reference is None:
        q_ref, t_ref = q0, t0
    else:
        q_ref, t_ref = (jnp.asarray(x, dtype) for x in reference)
    w = jnp.ones(J, dtype) if options.joint_weights is None else jnp.asarray(options.joint_weights, dtype)
    # a literal 0 removes the regularizer's rows: the residual then has only the targets' rows
    # (fewer than the variables), and the solvers take the cheap m x m path
    regularization = options.regularization
    no_reg = isinstance(regularization, (int, float)) and regularization == 0
    reg_w = None if no_reg else jnp.asarray(regularization, dtype) * w
    data, y0, bounds = _setup(
        skeleton, layout, targets, q0, t0, q_ref, t_ref, reg_w, options.limits, options.limit_weight,
        options.position_tolerance, options.orientation_tolerance,
    )
    solver = solvers.LevenbergMarquardt() if options.solver is None else options.solver
    if options.joint_weights is not None and isinstance(solver, solvers.LevenbergMarquardt):
        # joint weights as the damping metric W of Levenberg-Marquardt (the notes' eq. 4.10)
        var_w = jnp.concatenate(([jnp.ones(3, dtype)] if layout.free_root else [])
                                + [jnp.repeat(w[jnp.asarray(layout.free_joints)], 3)])
        solver = eqx.tree_at(lambda s: s.weights, solver, var_w, is_leaf=lambda x: x is None)
    stop = _stop if options.stop_at_tolerance else None
    sol = solvers.least_squares(_residual, solver, y0, data, jac=True, bounds=bounds, stop=stop, throw=options.throw)
    def finish(value, data):  # the pose and its target errors, by an FK of the solution
        q, t = _pose(value, data)
        p_sites, R_sites = site_transforms_sequential(skeleton, q, t, layout.site_idx)
        return (q, t) + target_errors(data.targets, p_sites, R_sites, dtype)

    # at the compacted loop's shapes (lane-width chunks) when the solve ran one
    q, t, pe, oe = solvers.lane_map(finish, sol.value, data, chunks=not getattr(solver, "fixed_steps", False))
    success = ((sol.result == solvers.RESULTS.successful) & jnp.all(pe <= data.position_tolerance)
               & jnp.all(oe <= data.orientation_tolerance))
    return IKSolution(rot.quat_canonical(q), t, sol.result, sol.stats, pe, oe, success)


_SKELETON_ONLY = ("pin", "root_translation", "limits", "limit_mode", "limit_weight")
_ROBOT_KEYWORDS = ("reference", "frozen", "regularization", "joint_weights", "solver", "position_tolerance",
                   "orientation_tolerance", "stop_at_tolerance", "throw")


def solve_ik(
    skeleton: Skeleton,
    targets: Sequence[Target] | Target,
    rotations: Float[Array, "joints 4"],
    translations: Float[Array, "joints 3"] | None = None,
    *,
    reference: tuple[Float[Array, "joints 4"], Float[Array, "joints 3"]] | None = None,
    options: IKOptions | None = None,
    pin: str | None = _UNSET,
    frozen: Sequence[str] = _UNSET,
    root_translation: str = _UNSET,
    regularization: float | Float[Array, ""] = _UNSET,
    joint_weights: Float[Array, " joints"] | None = _UNSET,
    limits: Sequence[EulerLimit | SwingTwistLimit] = _UNSET,
    limit_mode: str = _UNSET,
    limit_weight: float | Float[Array, ""] = _UNSET,
    solver=_UNSET,
    position_tolerance: float | None = _UNSET,
    orientation_tolerance: float = _UNSET,
    stop_at_tolerance: bool = _UNSET,
    throw: bool = _UNSET,
) -> IKSolution:
    """Solve one IK problem; batch with ``jax.vmap`` over characters or frames.

    The solve is compiled once per structure (skeleton tree, target sites, options): calling again
    with new targets or a new start pose does not recompile.

    Robots. ``solve_ik(robot, targets, qpos, ...)`` with a :class:`jaxanim.robots.Robot` is
    :func:`jaxanim.ik.solve_ik_robot`: targets name robot bodies or sites, ``qpos [nq]`` is the
    start, limited hinges and slides are hard bounds, a free joint is a floating base, and the
    result is a :class:`jaxanim.ik.RobotIKSolution` (``qpos`` and the status fields of
    :class:`IKSolution`). It takes ``reference`` (a ``qpos``), ``frozen`` (joint names),
    ``regularization``, ``joint_weights`` (``[nv]``), ``solver``, the tolerances,
    ``stop_at_tolerance`` and ``throw``; ``translations``, ``options``, ``pin``,
    ``root_translation``, ``limits``, ``limit_mode`` and ``limit_weight`` are skeleton arguments and
    raise a :class:`JaxanimError` naming them.

    Args:
        skeleton: the tree (or a :class:`jaxanim.robots.Robot`: see Robots above).
        targets: :class:`Target` s (positions and/or orientations of joints / End Sites).
        rotations: ``[joints, 4]`` initial local wxyz quaternions (e.g. a clip frame); a robot's
            ``qpos [nq]``.
        translations: ``[joints, 3]`` initial local translations (``None``: the offsets).
        reference: ``(rotations, translations)`` of the pose the regularizer pulls towards and the
            pin and frozen joints refer to (default: the initial pose); a robot's ``qpos [nq]``.
        options: an :class:`IKOptions` holding the options below (default ``IKOptions()``). A
            keyword given beside it wins over that field.
        pin: a joint or End Site that stays exactly where the reference pose puts it.
        frozen: joint names that keep their reference rotations.
        root_translation: ``"free"`` or ``"fixed"`` (ignored when ``pin`` is given: it follows).
        regularization: ``lambda`` of the regularizer ``lambda/2 sum_j w_j |delta_j|^2`` towards the
            reference pose. The literal default ``0`` removes it: the solve is then the notes' damped
            least squares from the start pose (each Levenberg-Marquardt step is the smallest in the
            ``W`` metric), and with fewer target rows than variables the solver works with an
            ``m x m`` system (much faster). Any other value, or an array, keeps the term.
        joint_weights: ``[joints]`` per-joint stiffness ``w_j`` against moving (default ones): the
            damping metric ``W`` of ``LevenbergMarquardt`` (``(J^T J + lambda W) p = -J^T r``, the
            notes' eq. 4.10) and the regularizer's weights.
        limits: :class:`~jaxanim.limits.EulerLimit` / :class:`~jaxanim.limits.SwingTwistLimit` s
            on joints' local rotations (frozen joints ignore theirs).
        limit_mode: ``"hard"``: every iterate satisfies the limits exactly (the limited joints
            are written in coordinates where the limit is a box, and the solver is bounded; needs
            an own solver: ``LevenbergMarquardt``, ``GaussNewton`` or ``GradientDescent``); the
            start is projected into the limits. ``"soft"``: a penalty
            ``limit_weight/2 * (angle outside the limit)^2`` per limit, any solver.
        limit_weight: weight of the soft penalty (array: sweepable by vmap).
        solver: a :mod:`solvers` least-squares solver (default ``LevenbergMarquardt()``).
        position_tolerance: distance (file units) within which a position target counts as met
            for ``success``; default ``1e-5`` times the skeleton's size (sum of |offsets|).
        orientation_tolerance: angle (radians) within which an orientation target counts as met.
        stop_at_tolerance: stop as soon as every target is within its tolerance (the usual IK
            criterion, as in closed-loop IK; any solver, the optimistix and jaxopt adapters
            included: they check it on each accepted iterate). ``False``: solve the regularized
            least-squares problem to the solver's own tolerances (slow when the regularizer is weak
            and the task leaves many directions free: the minimum is then very flat). A solve that
            stopped at the tolerance before a minimizer has a NaN derivative (``jax.grad``): to
            differentiate, give a ``regularization``.
        throw: raise on failure instead of reporting it in ``result`` (use ``False`` under vmap).

    Returns:
        :class:`IKSolution` (a :class:`jaxanim.ik.RobotIKSolution` for a robot).

    Raises:
        JaxanimError: a wrong shape, an unknown joint / End Site, a bad option value, or nothing
            left to move; raised in Python before anything is computed.
    """
    keywords = dict(
        pin=pin, frozen=frozen, root_translation=root_translation, regularization=regularization,
        joint_weights=joint_weights, limits=limits, limit_mode=limit_mode, limit_weight=limit_weight, solver=solver,
        position_tolerance=position_tolerance, orientation_tolerance=orientation_tolerance,
        stop_at_tolerance=stop_at_tolerance, throw=throw,
    )
    if isinstance(skeleton, Robot):  # ik.solve_ik_robot, with the keywords that apply to a robot
        for name, value in (("translations", translations), ("options", options)) + tuple(
                (k, keywords[k]) for k in _SKELETON_ONLY):
            if value is not None and value is not _UNSET:
                raise JaxanimError(f"{name}: only for a skeleton; with a robot give qpos [nq] as the third "
                                   f"argument and the robot keywords ({', '.join(_ROBOT_KEYWORDS)})")
        given = {k: v for k, v in keywords.items() if v is not _UNSET}
        return solve_ik_robot(skeleton, targets, rotations, reference=reference, **given)
    options = _resolve_options(options, keywords)
    layout, targets, q0 = _check_problem(skeleton, targets, rotations, translations, reference, options)
    options = _skeleton_defaults(skeleton, options)
    return _solve(skeleton, layout, targets, q0, translations, reference, options)


@eqx.filter_jit
def _solve_clip(skeleton, motion, targets, reference, options):
    """The compiled core of :func:`solve_ik_clip`: :func:`solve_ik` mapped over the frames."""
    F = motion.num_frames

    def per_frame(x, n):
        if x is None:
            return None
        x = jnp.asarray(x)
        if x.ndim == 1:
            return jnp.broadcast_to(x, (F, n))
        check_shape("targets position/orientation", x, (F, n), what=f"({n},) or (frames, {n}) = ({F}, {n})")
        return x

    stacked = tuple(
        Target(tg.site, per_frame(tg.position, 3), per_frame(tg.orientation, 4), jnp.broadcast_to(tg.weight, (F,)))
        for tg in targets
    )

    def one(tg, q, t):
        return solve_ik(skeleton, tg, q, t, reference=reference, options=options)

    sol = jax.vmap(one)(stacked, motion.rotations, motion.translations)
    return Motion(sol.rotations, sol.translations, motion.frame_time), sol


def solve_ik_clip(
    skeleton: Skeleton,
    motion,
    targets: Sequence[Target] | Target,
    *,
    options: IKOptions | None = None,
    reference=None,
    **kwargs,
):
    """Solve IK on every frame of a clip at once (``vmap`` over frames), compiled once per
    structure (skeleton tree, number of frames, target sites, options).

    Each frame starts from, and is regularized towards, the clip's own pose of that frame; a
    ``pin`` stays where the clip puts it in every frame.

    Args:
        skeleton: the tree.
        motion: the clip (:class:`~jaxanim.Motion`).
        targets: :class:`Target` s whose ``position`` is ``[3]`` (the same every frame) or
            ``[frames, 3]``, and ``orientation`` ``[4]`` or ``[frames, 4]``.
        options: an :class:`IKOptions` (default ``IKOptions()``).
        reference: one ``(rotations, translations)`` for every frame instead of the frame's own
            pose (see :func:`solve_ik`).
        **kwargs: the options as keywords, as :func:`solve_ik` takes them (``pin``, ``frozen``,
            ``root_translation``, ``solver``, ...); a keyword wins over the field of ``options``.

    Returns:
        ``(edited Motion, IKSolution)`` where the solution's fields have a leading frames axis.
    """
    motion.check_skeleton(skeleton, "motion")
    targets = (targets,) if isinstance(targets, Target) else tuple(targets)
    options = _skeleton_defaults(skeleton, _resolve_options(options, kwargs))
    return _solve_clip(skeleton, motion, targets, reference, options)
