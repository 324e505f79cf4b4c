"""Robots as kinematic trees: MJCF / URDF loading (through MuJoCo), forward kinematics, geometric
Jacobians and the centre of mass, equal to MuJoCo's ``mj_kinematics`` / ``mj_jac`` to rounding, and
their dynamics in joint coordinates (the mass matrix, bias and passive forces, the accelerations), equal
to MuJoCo's ``mj_fullM``, ``qfrc_bias``, ``qfrc_passive`` and ``qacc_smooth``.

Inverse kinematics on robots is :func:`jaxanim.ik.solve_ik_robot`, and retargeting human motion onto
them is :mod:`jaxanim.retargeting`. Their old names here (``robots.retarget``,
``robots.solve_ik_robot``, ...) still work for one release and emit a ``DeprecationWarning`` that
names the new home.

Loading needs the optional extra: ``pip install 'jaxanim[robots]'``.
"""

import importlib as _importlib
import warnings as _warnings

from ._kinematics import (
    RobotFK as RobotFK,
    center_of_mass as center_of_mass,
    forward_kinematics as forward_kinematics,
    jacobian as jacobian,
)
from ._data import default_robot_path as default_robot_path
from ._dynamics import (
    actuator_forces as actuator_forces,
    bias_forces as bias_forces,
    forward_dynamics as forward_dynamics,
    mass_matrix as mass_matrix,
    passive_forces as passive_forces,
)
from ._load import (
    RobotLoadError as RobotLoadError,
    load_robot as load_robot,
    robot_from_mujoco as robot_from_mujoco,
)
from ._robot import Robot as Robot, with_floating_base as with_floating_base, with_surface_points as with_surface_points

#: The names that moved out of this package, and their new home (deprecated here for one release).
_MOVED = {
    **{name: "jaxanim.retargeting" for name in (
        "Calibration", "RetargetMap", "calibrate", "load_mapping", "default_mapping_path", "RetargetProblem",
        "prepare_retarget", "stack_problems", "RetargetOptions", "RetargetResult", "solve_retarget",
        "RetargetDiagnostics", "diagnostics", "summary", "retarget", "retarget_clips")},
    "RobotIKSolution": "jaxanim.ik",
    "solve_ik_robot": "jaxanim.ik",
}


def __getattr__(name: str):
    home = _MOVED.get(name)
    if home is None:
        raise AttributeError(f"module 'jaxanim.robots' has no attribute {name!r}")
    _warnings.warn(f"jaxanim.robots.{name} has moved to {home}.{name}; the old name goes in the next release",
                   DeprecationWarning, stacklevel=2)
    # by name, at the first use: the new homes sit above this package and import it
    return getattr(_importlib.import_module(home), name)


def __dir__():
    return sorted(set(globals()) | set(_MOVED))
