"""Inverse kinematics: targets, Gauss-Newton / Levenberg-Marquardt solves with joint limits
(:func:`solve_ik`, :func:`solve_ik_clip`) on skeletons and on robots (:func:`solve_ik_robot`, also
reached through ``solve_ik(robot, ...)``), the CCD baseline, the JSON target format, and the
foot-contact cleanup built on them (:func:`clean_foot_contacts`).
"""

from ..kinematics import EulerLimit as EulerLimit, SwingTwistLimit as SwingTwistLimit, limit_violation as limit_violation
from ._solve import (
    IKOptions as IKOptions,
    IKSolution as IKSolution,
    Target as Target,
    solve_ik as solve_ik,
    solve_ik_clip as solve_ik_clip,
    targets_from_json as targets_from_json,
)
from ._robot import RobotIKSolution as RobotIKSolution, solve_ik_robot as solve_ik_robot
from ._ccd import (
    solve_ik_ccd as solve_ik_ccd,
)
from ._contacts import (
    FootCleanup as FootCleanup,
    clean_foot_contacts as clean_foot_contacts,
    detect_foot_contacts as detect_foot_contacts,
    foot_joints as foot_joints,
)
