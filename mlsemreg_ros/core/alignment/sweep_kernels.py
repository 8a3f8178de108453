# Copyright 2026 The mlsemreg_ros Authors
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""
The sweep alignment's normal equations in one compiled pass (numba, ``core/features/kernels.py``).

:func:`normal_equations` accumulates the Gauss-Newton ``H`` (12, 12) and ``g`` (12,) of
``core/alignment/sweep_alignment.py`` point by point: the 3x3 inverse of each voxel's
regularised covariance, its rotation into the stamp frame, the Geman-McClure weight and
the 6x6 block ``G^T A G`` with its ``tau`` and ``tau^2`` copies. The NumPy code
(``sweep_alignment._normal_equations_numpy``) is the reference and the fallback; a test
checks that both agree.
"""

from __future__ import annotations

from mlsemreg_ros.core.features.kernels import jit
import numpy as np


@jit
def _normal_equations(
    deskewed: np.ndarray,
    tau: np.ndarray,
    offset: np.ndarray,
    covariances: np.ndarray,
    rotation: np.ndarray,
    regularization: float,
    scale: float,
) -> tuple[np.ndarray, np.ndarray]:
    hessian = np.zeros((12, 12))
    gradient = np.zeros(12)
    world_info = np.empty((3, 3))
    info = np.empty((3, 3))
    tmp = np.empty((3, 3))
    error = np.empty(3)
    info_error = np.empty(3)
    jac = np.zeros((3, 6))
    a_jac = np.empty((3, 6))
    for i in range(deskewed.shape[0]):
        # (C + eps I)^-1 by the adjugate (symmetric)
        c00 = covariances[i, 0, 0] + regularization
        c11 = covariances[i, 1, 1] + regularization
        c22 = covariances[i, 2, 2] + regularization
        c01, c02, c12 = covariances[i, 0, 1], covariances[i, 0, 2], covariances[i, 1, 2]
        m00 = c11 * c22 - c12 * c12
        m01 = c02 * c12 - c01 * c22
        m02 = c01 * c12 - c02 * c11
        det = c00 * m00 + c01 * m01 + c02 * m02
        if not det > 0.0:
            continue
        world_info[0, 0] = m00 / det
        world_info[0, 1] = world_info[1, 0] = m01 / det
        world_info[0, 2] = world_info[2, 0] = m02 / det
        world_info[1, 1] = (c00 * c22 - c02 * c02) / det
        world_info[1, 2] = world_info[2, 1] = (c01 * c02 - c00 * c12) / det
        world_info[2, 2] = (c00 * c11 - c01 * c01) / det
        # A = R^T W R, e = R^T offset
        for r in range(3):
            for c in range(3):
                s = 0.0
                for k in range(3):
                    s += world_info[r, k] * rotation[k, c]
                tmp[r, c] = s
        for r in range(3):
            for c in range(3):
                s = 0.0
                for k in range(3):
                    s += rotation[k, r] * tmp[k, c]
                info[r, c] = s
            error[r] = (
                rotation[0, r] * offset[i, 0]
                + rotation[1, r] * offset[i, 1]
                + rotation[2, r] * offset[i, 2]
            )
        mahalanobis = 0.0
        for r in range(3):
            for c in range(3):
                mahalanobis += error[r] * info[r, c] * error[c]
        weight = scale / (scale + mahalanobis)
        weight *= weight
        # G = [-[d]x, I]
        x, y, z = deskewed[i, 0], deskewed[i, 1], deskewed[i, 2]
        jac[0, 1], jac[0, 2] = z, -y
        jac[1, 0], jac[1, 2] = -z, x
        jac[2, 0], jac[2, 1] = y, -x
        jac[0, 3] = jac[1, 4] = jac[2, 5] = 1.0
        for r in range(3):
            for c in range(6):
                s = 0.0
                for k in range(3):
                    s += info[r, k] * jac[k, c]
                a_jac[r, c] = weight * s
        for k in range(3):
            info_error[k] = weight * (
                info[k, 0] * error[0] + info[k, 1] * error[1] + info[k, 2] * error[2]
            )
        t = tau[i]
        t2 = t * t
        for r in range(6):
            ge = jac[0, r] * info_error[0] + jac[1, r] * info_error[1] + jac[2, r] * info_error[2]
            gradient[r] += ge
            gradient[6 + r] += t * ge
            for c in range(6):
                b = 0.0
                for k in range(3):
                    b += jac[k, r] * a_jac[k, c]
                hessian[r, c] += b
                hessian[r, 6 + c] += t * b
                hessian[6 + r, c] += t * b
                hessian[6 + r, 6 + c] += t2 * b
    return hessian, gradient


def normal_equations(
    deskewed: np.ndarray,
    tau: np.ndarray,
    offset: np.ndarray,
    covariances: np.ndarray,
    rotation: np.ndarray,
    regularization: float,
    scale: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """
    Return ``H`` (12, 12) and ``g`` (12,) of the paired points (one compiled pass).

    ``deskewed`` (n, 3) stamp-frame points, ``tau`` (n,) their times, ``offset`` (n, 3)
    world-frame offsets from their voxel means, ``covariances`` (n, 3, 3) the voxels',
    ``rotation`` (3, 3) the pose's, ``scale`` the Geman-McClure scale (squared Mahalanobis).
    """
    return _normal_equations(
        np.ascontiguousarray(deskewed, dtype=np.float64),
        np.ascontiguousarray(tau, dtype=np.float64),
        np.ascontiguousarray(offset, dtype=np.float64),
        np.ascontiguousarray(covariances, dtype=np.float64),
        np.ascontiguousarray(rotation, dtype=np.float64),
        float(regularization),
        float(scale),
    )
