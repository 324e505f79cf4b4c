"""jaxanim: the numerical core of physics-based character animation, in JAX.

Every algorithm is a pure function that solves one instance; batch with ``jax.vmap``.

The subpackages, from the bottom up (each imports only those above it in this list):
``rotations`` -> ``skeleton`` -> ``kinematics`` -> ``robots`` (MJCF / URDF robots) -> ``ik`` and
``retargeting`` (human motion onto robots); ``rotations`` -> ``physics`` ->
``character`` (which also uses ``skeleton`` and ``kinematics``); ``skeleton`` and ``kinematics`` ->
``matching`` (motion matching: features, database, search, controller); ``rotations``, ``skeleton``
and ``kinematics`` -> ``skinning`` (LBS / DQS, skin weights, capsule mesh, OBJ); ``rotations`` and
``skeleton`` -> ``splines`` (curves, arc length, slerp / squad, keyframes); ``app`` (CLI, plots,
render, viewer) on top.
"""

from ._version import __version__ as __version__

from solvers import shard_batch as shard_batch

from . import (
    app as app,
    character as character,
    ik as ik,
    kinematics as kinematics,
    matching as matching,
    physics as physics,
    retargeting as retargeting,
    robots as robots,
    rotations as rotations,
    skeleton as skeleton,
    skinning as skinning,
    splines as splines,
)
from ._errors import BVHParseError as BVHParseError, JaxanimError as JaxanimError
from .kinematics import (
    FKResult as FKResult,
    apply_increment as apply_increment,
    center_of_mass as center_of_mass,
    forward_kinematics as forward_kinematics,
    global_to_local as global_to_local,
    jacobian as jacobian,
    segment_com_offsets as segment_com_offsets,
)
from .skeleton import (
    Motion as Motion,
    Skeleton as Skeleton,
    default_clip_path as default_clip_path,
    make_default_clip as make_default_clip,
    read_bvh as read_bvh,
    resample as resample,
    resample_at as resample_at,
    rest_alignment as rest_alignment,
    rest_motion as rest_motion,
    retarget as retarget,
    write_bvh as write_bvh,
)
import sys as _sys

from . import _legacy

_legacy.register(_sys.modules[__name__])
del _legacy, _sys
