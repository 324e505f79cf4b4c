"""Bind poses: the rest pose's world transforms, and the one place that interprets a ``bind=``
argument (``None``, ``[joints, 4, 4]`` matrices or an ``(R, p)`` pair), shared by the mesh, weight
and skinning modules."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._errors import JaxanimError, check_shape
from .._types import Array, Float
from ..kinematics._fk import forward_kinematics
from ..skeleton._skeleton import Skeleton


@jax.jit
def _rest_fk(skeleton: Skeleton):
    fk = forward_kinematics(skeleton, skeleton.rest_rotations(), skeleton.offsets)
    return fk.rotations, fk.positions


def _bind_rt(skeleton: Skeleton, bind, dtype=None) -> tuple[Array, Array]:
    """``(R [J, 3, 3], p [J, 3])`` of a bind pose given as ``None`` (the rest pose), ``[J, 4, 4]``
    matrices or an ``(R, p)`` tuple; checked against the skeleton."""
    J = skeleton.num_joints
    dtype = skeleton.offsets.dtype if dtype is None else dtype
    if bind is None:
        R, p = _rest_fk(skeleton)
    elif isinstance(bind, tuple):
        if len(bind) != 2:
            raise JaxanimError(f"bind: expected [joints, 4, 4] matrices or a tuple (R [joints, 3, 3], p [joints, 3]), "
                               f"got a tuple of {len(bind)}")
        R, p = bind
        check_shape("bind rotations", R, (J, 3, 3), what=f"(joints, 3, 3) = ({J}, 3, 3)")
        check_shape("bind positions", p, (J, 3), what=f"(joints, 3) = ({J}, 3)")
    else:
        check_shape("bind", bind, (J, 4, 4), what=f"(joints, 4, 4) = ({J}, 4, 4)")
        bind = jnp.asarray(bind)
        R, p = bind[:, :3, :3], bind[:, :3, 3]
    return jnp.asarray(R).astype(dtype), jnp.asarray(p).astype(dtype)


def bind_transforms(
    skeleton: Skeleton,
    rotations: Float[Array, "joints 4"] | Float[Array, "joints 3 3"] | None = None,
    translations: Float[Array, "joints 3"] | None = None,
) -> Float[Array, "joints 4 4"]:
    """Global bind transforms ``Ts_world_joint`` of a bind pose, as 4x4 matrices.

    The default is the rest pose: every local rotation the identity and every local translation its
    OFFSET (the root at its OFFSET). Pass the result (or an ``(R, p)`` pair) as ``bind=`` to
    :func:`skin`, :func:`heuristic_weights` and :func:`capsule_mesh` when the mesh was modelled in
    another pose.

    Args:
        skeleton: the tree.
        rotations: local rotations of the bind pose, ``[joints, 4]`` wxyz or ``[joints, 3, 3]``
            (default: identities).
        translations: ``[joints, 3]`` local translations (default: the OFFSETs).

    Returns:
        ``[joints, 4, 4]`` homogeneous matrices ``[[R, p], [0, 1]]`` (world from joint).
    """
    if not isinstance(skeleton, Skeleton):
        raise JaxanimError(f"skeleton: expected a jaxanim.Skeleton, got {type(skeleton).__name__}")
    if rotations is None and translations is None:
        R, p = _rest_fk(skeleton)
    else:
        if rotations is None:
            rotations = skeleton.rest_rotations()
        fk = forward_kinematics(skeleton, rotations, translations)
        R, p = fk.rotations, fk.positions
    J = skeleton.num_joints
    top = jnp.concatenate([R, p[:, :, None]], axis=2)
    bottom = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 0.0, 1.0], R.dtype), (J, 1, 4))
    return jnp.concatenate([top, bottom], axis=1)
