"""jaxanim: the numerical core of physics-based character animation, in JAX.

Every algorithm is a pure function that solves one instance; batch with ``jax.vmap``.
"""

from solvers import shard_batch as shard_batch

from . import balance as balance, bvh as bvh, character as character, contact as contact, control as control, joints as joints, physics as physics, rigid as rigid, rotations as rotations
from ._errors import BVHParseError as BVHParseError, JaxanimError as JaxanimError
from .bvh import read_bvh as read_bvh, write_bvh as write_bvh
from .default_clip import default_clip_path as default_clip_path, make_default_clip as make_default_clip
from .fk import (
    FKResult as FKResult,
    center_of_mass as center_of_mass,
    forward_kinematics as forward_kinematics,
    global_to_local as global_to_local,
    segment_com_offsets as segment_com_offsets,
)
from .jacobians import apply_increment as apply_increment, jacobian as jacobian
from .motion import resample as resample, resample_at as resample_at, rest_alignment as rest_alignment, retarget as retarget
from .skeleton import Motion as Motion, Skeleton as Skeleton, rest_motion as rest_motion

__version__ = "0.1.0"
