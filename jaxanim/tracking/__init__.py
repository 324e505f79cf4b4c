"""Tracking a clip with the physics character on joint torques only (no root force): sampling-based
control (:func:`samcon`), its reference (:func:`tracking_reference`) and replays with pushes."""

from ._samcon import (
    TrackingOptions as TrackingOptions,
    TrackingReference as TrackingReference,
    TrackingResult as TrackingResult,
    TrackingStatus as TrackingStatus,
    joint_sigma as joint_sigma,
    replay as replay,
    samcon as samcon,
    tracking_reference as tracking_reference,
    windows_of as windows_of,
)
