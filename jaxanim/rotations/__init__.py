"""Rotations on wxyz quaternions, rotation matrices, Euler angles of all 12 orders, rotation vectors
(SO(3) exp / log), the 6-D representation, slerp / nlerp. Every function broadcasts over leading axes.
"""

from ._quaternions import (
    quat_apply as quat_apply,
    quat_canonical as quat_canonical,
    quat_conjugate as quat_conjugate,
    quat_distance as quat_distance,
    quat_identity as quat_identity,
    quat_inverse as quat_inverse,
    quat_multiply as quat_multiply,
    quat_normalize as quat_normalize,
    rotation_angle as rotation_angle,
)
from ._matrices import (
    matrix_to_quat as matrix_to_quat,
    matrix_to_sixd as matrix_to_sixd,
    perpendicular_basis as perpendicular_basis,
    quat_to_matrix as quat_to_matrix,
    sixd_to_matrix as sixd_to_matrix,
    skew as skew,
)
from ._so3 import (
    axis_angle_to_quat as axis_angle_to_quat,
    left_jacobian as left_jacobian,
    left_jacobian_inverse as left_jacobian_inverse,
    matrix_to_rotvec as matrix_to_rotvec,
    nlerp as nlerp,
    quat_to_axis_angle as quat_to_axis_angle,
    quat_to_rotvec as quat_to_rotvec,
    right_jacobian as right_jacobian,
    rotation_between as rotation_between,
    rotvec_to_matrix as rotvec_to_matrix,
    rotvec_to_quat as rotvec_to_quat,
    slerp as slerp,
)
from ._euler import (
    euler_to_matrix as euler_to_matrix,
    euler_to_quat as euler_to_quat,
    matrix_to_euler as matrix_to_euler,
    quat_to_euler as quat_to_euler,
)
