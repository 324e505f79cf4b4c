"""Robots as kinematic trees: MJCF / URDF loading (through MuJoCo), forward kinematics, geometric
Jacobians and the centre of mass, equal to MuJoCo's ``mj_kinematics`` / ``mj_jac`` to rounding, and
inverse kinematics (:func:`solve_ik_robot`, also reached through ``jaxanim.ik.solve_ik(robot, ...)``),
and retargeting of human motion onto robots (:func:`retarget`: one problem per clip, planted feet).

Loading needs the optional extra: ``pip install 'jaxanim[robots]'``.
"""

from ._kinematics import (
    RobotFK as RobotFK,
    center_of_mass as center_of_mass,
    forward_kinematics as forward_kinematics,
    jacobian as jacobian,
)
from ._data import default_mapping_path as default_mapping_path, default_robot_path as default_robot_path
from ._ik import (
    RobotIKSolution as RobotIKSolution,
    solve_ik_robot as solve_ik_robot,
)
from ._load import (
    RobotLoadError as RobotLoadError,
    load_robot as load_robot,
    robot_from_mujoco as robot_from_mujoco,
)
from ._mapping import (
    Calibration as Calibration,
    RetargetMap as RetargetMap,
    calibrate as calibrate,
    load_mapping as load_mapping,
)
from ._retarget import retarget as retarget, retarget_clips as retarget_clips
from ._retarget_diagnostics import RetargetDiagnostics as RetargetDiagnostics, diagnostics as diagnostics, summary as summary
from ._retarget_problem import (
    RetargetProblem as RetargetProblem,
    prepare_retarget as prepare_retarget,
    stack_problems as stack_problems,
)
from ._retarget_solve import RetargetOptions as RetargetOptions, RetargetResult as RetargetResult, solve_retarget as solve_retarget
from ._robot import Robot as Robot
