"""Skeletons and clips: :class:`Skeleton`, :class:`Motion`, BVH read / write, AMASS (SMPL-family) clips,
the shipped clip and clip operations (resampling, retargeting) and motion processing (facing frames, alignment,
transitions, loops, inertialization, mirroring).
"""

from ._skeleton import (
    Motion as Motion,
    POSITION_CHANNELS as POSITION_CHANNELS,
    ROTATION_CHANNELS as ROTATION_CHANNELS,
    Skeleton as Skeleton,
    VALID_CHANNELS as VALID_CHANNELS,
    rest_motion as rest_motion,
)
from ._bvh import (
    channels_to_motion as channels_to_motion,
    format_bvh as format_bvh,
    motion_to_channels as motion_to_channels,
    parse_bvh as parse_bvh,
    read_bvh as read_bvh,
    write_bvh as write_bvh,
)
from ._amass import AMASSError as AMASSError, read_amass as read_amass, read_clip as read_clip
from ._clips import (
    resample as resample,
    resample_at as resample_at,
    rest_alignment as rest_alignment,
    retarget as retarget,
)
from ._default_clip import (
    default_clip_channels as default_clip_channels,
    default_clip_path as default_clip_path,
    default_skeleton as default_skeleton,
    make_default_clip as make_default_clip,
    write_default_clip as write_default_clip,
)
from ._processing import (
    align as align,
    concatenate as concatenate,
    decay_spring as decay_spring,
    facing_frame as facing_frame,
    inertialize as inertialize,
    make_loop as make_loop,
    split_facing as split_facing,
    transition as transition,
)
from ._mirror import mirror as mirror, mirror_pairs as mirror_pairs
