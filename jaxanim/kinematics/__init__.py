"""Forward kinematics, its inverse (global to local), center of mass, geometric Jacobians and the
retraction that matches them, joint limits, and the foot contacts of a clip.
"""

from ._contacts import (
    detect_foot_contacts as detect_foot_contacts,
    foot_joints as foot_joints,
)
from ._fk import (
    FKResult as FKResult,
    center_of_mass as center_of_mass,
    forward_kinematics as forward_kinematics,
    global_to_local as global_to_local,
    segment_com_offsets as segment_com_offsets,
)
from ._jacobians import (
    apply_increment as apply_increment,
    jacobian as jacobian,
)
from ._limits import (
    EulerLimit as EulerLimit,
    SwingTwistLimit as SwingTwistLimit,
    limit_violation as limit_violation,
)
