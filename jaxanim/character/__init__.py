"""Physics characters built from skeletons: PD / stable PD, clip tracking and static balance.
"""

from ._build import (
    Character as Character,
    TrackingController as TrackingController,
    build_character as build_character,
    character_pose as character_pose,
    character_state as character_state,
    export_mjcf as export_mjcf,
    root_body as root_body,
    spd_targets as spd_targets,
    tracking_controller as tracking_controller,
)
from ._pd import (
    pd_force as pd_force,
    pd_joint_torques as pd_joint_torques,
    stable_pd_force as stable_pd_force,
)
from ._balance import (
    BalanceController as BalanceController,
    balance_controller as balance_controller,
    joint_anchors as joint_anchors,
    stance_leg_joints as stance_leg_joints,
    standing_pose as standing_pose,
    stood as stood,
    support_center as support_center,
)
