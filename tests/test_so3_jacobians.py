"""rotations.left_jacobian / right_jacobian / left_jacobian_inverse against finite differences of the
exponential (the IK's exact Jacobians of skeletons and robots are built from them)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxanim import rotations as rot


def _exp(v):
    return Rotation.from_rotvec(v).as_matrix()


def _log(R):
    return Rotation.from_matrix(R).as_rotvec()


@pytest.mark.parametrize("phi", [[0.3, -0.7, 1.1], [1e-5, 2e-5, -1e-5], [0.0, 0.0, 0.0], [2.0, 1.0, -1.5]])
def test_so3_jacobians_equal_finite_differences(phi):
    phi = np.asarray(phi)
    Jl, Jr, Jli = (np.asarray(f(phi)) for f in (rot.left_jacobian, rot.right_jacobian, rot.left_jacobian_inverse))
    h = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        # exp(phi + d) = exp(J_l d) exp(phi) = exp(phi) exp(J_r d)
        left = (_log(_exp(phi + d) @ _exp(phi).T) - _log(_exp(phi - d) @ _exp(phi).T)) / (2 * h)
        right = (_log(_exp(phi).T @ _exp(phi + d)) - _log(_exp(phi).T @ _exp(phi - d))) / (2 * h)
        # log(exp(d) exp(phi)) = phi + J_l^{-1} d
        inverse = (_log(_exp(d) @ _exp(phi)) - _log(_exp(-d) @ _exp(phi))) / (2 * h)
        np.testing.assert_allclose(Jl[:, k], left, atol=1e-8, err_msg="left")
        np.testing.assert_allclose(Jr[:, k], right, atol=1e-8, err_msg="right")
        np.testing.assert_allclose(Jli[:, k], inverse, atol=1e-8, err_msg="left inverse")
    np.testing.assert_allclose(Jl @ Jli, np.eye(3), atol=1e-12)
    batch = np.stack([phi, 2 * phi])
    np.testing.assert_allclose(np.asarray(rot.left_jacobian(batch))[0], Jl, atol=1e-15)
