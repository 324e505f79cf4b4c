"""Tracking a clip with the physics character on joint torques only (no root force): sampling-based
control (:func:`samcon`), its reference (:func:`tracking_reference`), time-varying LQR feedback around
the tracked trajectory (:func:`feedback`), and replays with pushes."""

from ._feedback import FeedbackOptions as FeedbackOptions, feedback as feedback, linearize as linearize
from ._samcon import (
    Feedback as Feedback,
    TrackingOptions as TrackingOptions,
    TrackingReference as TrackingReference,
    TrackingResult as TrackingResult,
    TrackingStatus as TrackingStatus,
    joint_sigma as joint_sigma,
    joint_torque_limits as joint_torque_limits,
    replay as replay,
    samcon as samcon,
    state_difference as state_difference,
    state_retract as state_retract,
    torso_body as torso_body,
    tracking_options as tracking_options,
    tracking_reference as tracking_reference,
    windows_of as windows_of,
)
