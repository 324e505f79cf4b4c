"""IK targets and the JSON target format of ``jaxanim ik`` (:func:`targets_from_json`)."""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._errors import JaxanimError, check_shape
from ..kinematics._jacobians import site_indices
from ..kinematics._limits import EulerLimit, SwingTwistLimit
from ..skeleton._skeleton import Skeleton


class Target(eqx.Module):
    """One IK target: a position and/or an orientation for a joint or End Site.

    Leading axes on ``position`` / ``orientation`` / ``weight`` are allowed for batches (per frame,
    per character), to be mapped over with ``jax.vmap``; :func:`solve_ik` takes one.

    Attributes:
        site: joint name or End Site name (``<joint>_End``). Static.
        position: ``[3]`` world position (file units), or ``None``.
        orientation: ``[4]`` wxyz world orientation of the site's frame, or ``None``.
        weight: scalar weight ``w`` of this target's squared error (array: sweepable by vmap).
    """

    site: str = eqx.field(static=True)
    position: Float[Array, "3"] | None
    orientation: Float[Array, "4"] | None
    weight: Float[Array, ""]

    def __init__(self, site: str, position=None, orientation=None, weight=1.0):
        if position is None and orientation is None:
            raise JaxanimError(f"targets: the target for {site!r} has neither a position nor an orientation")
        self.site = str(site)
        if position is not None:
            check_shape(f"targets[{site!r}].position", position, (3,), batch=True)
            position = jnp.asarray(position)
        if orientation is not None:
            check_shape(f"targets[{site!r}].orientation", orientation, (4,), batch=True)
            orientation = jnp.asarray(orientation)
        self.position = position
        self.orientation = orientation
        self.weight = jnp.asarray(weight)


def _check_targets(skeleton: Skeleton, targets, root_translation) -> tuple[tuple[Target, ...], tuple[int, ...]]:
    """Validate one problem's targets and ``root_translation``; the targets and their site indices."""
    if isinstance(targets, Target):
        targets = (targets,)
    if not isinstance(targets, Sequence) or not targets or not all(isinstance(t, Target) for t in targets):
        raise JaxanimError("targets: expected a non-empty sequence of jaxanim.ik.Target")
    if root_translation not in ("free", "fixed"):
        raise JaxanimError(f"root_translation: expected 'free' or 'fixed', got {root_translation!r}")
    site_idx = site_indices(skeleton, [t.site for t in targets])
    for t in targets:  # one problem: no leading axes (vmap over them instead)
        if t.position is not None:
            check_shape(f"targets[{t.site!r}].position", t.position, (3,))
        if t.orientation is not None:
            check_shape(f"targets[{t.site!r}].orientation", t.orientation, (4,))
        check_shape(f"targets[{t.site!r}].weight", t.weight, ())
    return tuple(targets), site_idx


def targets_from_json(skeleton: Skeleton, data, num_frames: int):
    """Parse the ``TARGETS.json`` of ``jaxanim ik`` into targets and :func:`solve_ik` options.

    Format::

        {"pin": NAME or null, "root_translation": "free" | "fixed", "frozen": [NAME, ...],
         "targets": [{"joint": NAME, "position": [x, y, z] or one [x, y, z] per frame,
                      "orientation": [w, x, y, z] or one per frame (optional), "weight": number}],
         "regularization": number, "position_tolerance": number, "orientation_tolerance": number,
         "limits": [{"joint": NAME, "lower": [3 degrees], "upper": [3 degrees], "order": "ZXY"}
                    or {"joint": NAME, "swing": degrees or [2 degrees], "twist": [lower, upper] degrees,
                        "axis": [x, y, z]}],
         "limit_mode": "hard" | "soft", "limit_weight": number}

    (every field but ``targets`` optional; an Euler limit's ``order`` defaults to the joint's
    channel order, so its bounds are the angles written in the BVH file; a swing-twist limit's
    ``axis`` defaults to the bone).

    NAME is a joint or an End Site (``<joint>_End``); positions are world coordinates in the file's
    units.

    Returns:
        ``(targets, kwargs)`` for :func:`solve_ik_clip`.

    Raises:
        JaxanimError: naming the offending field.
    """
    if not isinstance(data, dict):
        raise JaxanimError("TARGETS.json: expected a JSON object at the top level")
    unknown = set(data) - {
        "pin", "root_translation", "frozen", "targets", "regularization", "position_tolerance",
        "orientation_tolerance", "limits", "limit_mode", "limit_weight",
    }
    if unknown:
        raise JaxanimError(f"TARGETS.json: unknown fields {sorted(unknown)}")
    items = data.get("targets")
    if not isinstance(items, list) or not items:
        raise JaxanimError("TARGETS.json: 'targets' must be a non-empty list")
    targets = []
    for k, item in enumerate(items):
        where = f"TARGETS.json: targets[{k}]"
        if not isinstance(item, dict) or "joint" not in item:
            raise JaxanimError(f"{where}: expected an object with a 'joint' field")
        name = item["joint"]
        skeleton.site_index(name)  # raises, listing the valid names

        def field(key, n, name=name, where=where, item=item):
            if item.get(key) is None:
                return None
            try:
                x = np.asarray(item[key], dtype=np.float64)
            except (TypeError, ValueError):
                raise JaxanimError(f"{where}.{key}: expected numbers") from None
            if x.shape not in ((n,), (num_frames, n)):
                raise JaxanimError(
                    f"{where}.{key}: expected shape ({n},) or (frames, {n}) = ({num_frames}, {n}), got {x.shape}"
                )
            if not np.all(np.isfinite(x)):
                raise JaxanimError(f"{where}.{key}: expected finite numbers, got NaN or inf"
                                   + (f" at frame {int(np.argwhere(~np.isfinite(x))[0, 0])}" if x.ndim == 2 else ""))
            if key == "orientation" and np.any(np.linalg.norm(x, axis=-1) < 1e-6):
                raise JaxanimError(f"{where}.orientation: expected a rotation quaternion [w, x, y, z], got a zero "
                                   "one" + (f" at frame {int(np.argmin(np.linalg.norm(x, axis=-1)))}" if x.ndim == 2
                                            else ""))
            return x

        weight = item.get("weight", 1.0)
        if not isinstance(weight, (int, float)) or isinstance(weight, bool) or not np.isfinite(weight) or weight < 0:
            raise JaxanimError(f"{where}.weight: expected a non-negative number, got {weight!r}")
        targets.append(Target(name, field("position", 3), field("orientation", 4), float(weight)))
    kwargs = {}
    if data.get("pin") is not None:
        skeleton.site_index(data["pin"])
        kwargs["pin"] = data["pin"]
    if "root_translation" in data:
        kwargs["root_translation"] = data["root_translation"]
    frozen = data.get("frozen", [])
    if not isinstance(frozen, list):
        raise JaxanimError("TARGETS.json: 'frozen' must be a list of joint names")
    kwargs["frozen"] = tuple(frozen)
    for key in ("regularization", "position_tolerance", "orientation_tolerance", "limit_weight"):
        if key in data:
            if (not isinstance(data[key], (int, float)) or isinstance(data[key], bool) or not np.isfinite(data[key])
                    or data[key] < 0):
                raise JaxanimError(f"TARGETS.json: {key!r} must be a non-negative number, got {data[key]!r}")
            kwargs[key] = float(data[key])
    if "limit_mode" in data:
        kwargs["limit_mode"] = data["limit_mode"]
    if "limits" in data:
        kwargs["limits"] = _limits_from_json(skeleton, data["limits"])
    return tuple(targets), kwargs


def _limits_from_json(skeleton: Skeleton, items) -> tuple:
    if not isinstance(items, list):
        raise JaxanimError("TARGETS.json: 'limits' must be a list of objects")
    out = []
    for k, item in enumerate(items):
        where = f"TARGETS.json: limits[{k}]"
        if not isinstance(item, dict) or "joint" not in item:
            raise JaxanimError(f"{where}: expected an object with a 'joint' field")
        skeleton.index(item["joint"])  # raises, listing the valid names
        euler, swing = "lower" in item or "upper" in item, "swing" in item
        allowed = {"joint", "lower", "upper", "order"} if euler else {"joint", "swing", "twist", "axis"}
        if euler == swing or set(item) - allowed:
            raise JaxanimError(
                f"{where}: expected either 'lower', 'upper' (and 'order') of an Euler box or 'swing' (and "
                f"'twist', 'axis') of a swing-twist limit, got fields {sorted(item)}"
            )
        try:
            if euler:
                out.append(EulerLimit(item["joint"], item.get("lower"), item.get("upper"), item.get("order"), degrees=True))
            else:
                out.append(SwingTwistLimit(item["joint"], item["swing"], item.get("twist", (-180.0, 180.0)),
                                           item.get("axis"), degrees=True))
        except JaxanimError as e:
            raise JaxanimError(f"{where}: {e}") from None
        except (TypeError, ValueError):
            raise JaxanimError(f"{where}: expected numbers") from None
    return tuple(out)

