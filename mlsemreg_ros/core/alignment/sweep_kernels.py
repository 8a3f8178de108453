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

from typing import NamedTuple

from mlsemreg_ros.core.features.cell_grid import _nearest_squared, CellGrid
from mlsemreg_ros.core.features.kernels import _deskew_piecewise, jit, SegmentRows
import numpy as np


class SweepMap(NamedTuple):
    """The local map as the sweep kernels read it, one argument (numba passes it whole)."""

    grid: CellGrid  # the means sorted in cells of the pairing distance
    means: np.ndarray  # (V, 3)
    covariances: np.ndarray  # (V, 3, 3)
    max_squared: float  # the pairing distance, squared (m^2)
    regularization: float  # added to each covariance's diagonal

    @classmethod
    def of(
        cls,
        grid: CellGrid,
        means: np.ndarray,
        covariances: np.ndarray,
        max_distance: float,
        regularization: float,
    ) -> SweepMap:
        """Return the map's arrays as contiguous float64, the distance squared."""
        return cls(
            grid,
            np.ascontiguousarray(means, dtype=np.float64),
            np.ascontiguousarray(covariances, dtype=np.float64),
            float(max_distance) ** 2,
            float(regularization),
        )


class SweepSchedule(NamedTuple):
    """The Gauss-Newton loop's settings (``sweep_alignment``'s constants and config)."""

    iterations: int
    kernel_start: float  # the Geman-McClure scale of the first step, decaying to 1
    step_tolerance: float  # stop when no step component is larger
    small_angle: float  # the deskew's series bound (rad)


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
    a_jac = np.empty((3, 6))
    ge = np.empty(6)
    block = np.empty((6, 6))
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
        # G = [-[d]x, I]: A G and G^T A G term by term, the zero entries of G skipped (each
        # sum keeps the order of its nonzero terms: the same numbers as the dense products)
        x, y, z = deskewed[i, 0], deskewed[i, 1], deskewed[i, 2]
        for r in range(3):
            a_jac[r, 0] = weight * (info[r, 1] * -z + info[r, 2] * y)
            a_jac[r, 1] = weight * (info[r, 0] * z + info[r, 2] * -x)
            a_jac[r, 2] = weight * (info[r, 0] * -y + info[r, 1] * x)
            a_jac[r, 3] = weight * info[r, 0]
            a_jac[r, 4] = weight * info[r, 1]
            a_jac[r, 5] = weight * info[r, 2]
        for k in range(3):
            info_error[k] = weight * (
                info[k, 0] * error[0] + info[k, 1] * error[1] + info[k, 2] * error[2]
            )
        ge[0] = -z * info_error[1] + y * info_error[2]
        ge[1] = z * info_error[0] + -x * info_error[2]
        ge[2] = -y * info_error[0] + x * info_error[1]
        ge[3], ge[4], ge[5] = info_error[0], info_error[1], info_error[2]
        for c in range(6):
            block[0, c] = -z * a_jac[1, c] + y * a_jac[2, c]
            block[1, c] = z * a_jac[0, c] + -x * a_jac[2, c]
            block[2, c] = -y * a_jac[0, c] + x * a_jac[1, c]
            block[3, c], block[4, c], block[5, c] = a_jac[0, c], a_jac[1, c], a_jac[2, c]
        t = tau[i]
        t2 = t * t
        for r in range(6):
            gradient[r] += ge[r]
            gradient[6 + r] += t * ge[r]
            for c in range(6):
                b = block[r, c]
                hessian[r, c] += b
                hessian[r, 6 + c] += t * b
                hessian[6 + r, 6 + c] += t2 * b
    # the lower-left block gets the same terms as the upper-right one, in the same order
    for r in range(6):
        for c in range(6):
            hessian[6 + r, c] = hessian[r, 6 + c]
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


@jit
def _sweep_linearization(
    points: np.ndarray,
    times: np.ndarray,
    motion: SegmentRows,
    small_angle: float,
    rotation: np.ndarray,
    translation: np.ndarray,
    local_map: SweepMap,
    scale: float,
) -> tuple[np.ndarray, np.ndarray, int]:
    n = points.shape[0]
    deskewed = _deskew_piecewise(points, times, np.zeros(n, dtype=np.int64), motion, small_angle)
    return _deskewed_linearization(deskewed, times, rotation, translation, local_map, scale)


@jit
def _deskewed_linearization(
    deskewed: np.ndarray,
    times: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    local_map: SweepMap,
    scale: float,
) -> tuple[np.ndarray, np.ndarray, int]:
    """:func:`_sweep_linearization` of points already deskewed."""
    grid, means, covariances, max_squared, regularization = local_map
    n = deskewed.shape[0]
    world = np.empty((n, 3))
    for i in range(n):
        for r in range(3):
            world[i, r] = (
                rotation[r, 0] * deskewed[i, 0]
                + rotation[r, 1] * deskewed[i, 1]
                + rotation[r, 2] * deskewed[i, 2]
                + translation[r]
            )
    squared, index = _nearest_squared(world, np.sqrt(max_squared), grid, False)
    pairs = 0
    for i in range(n):
        if squared[i] < max_squared:
            pairs += 1
    kept = np.empty((pairs, 3))
    tau = np.empty(pairs)
    offset = np.empty((pairs, 3))
    kept_covariances = np.empty((pairs, 3, 3))
    k = 0
    for i in range(n):
        if squared[i] < max_squared:
            j = index[i]
            tau[k] = times[i]
            for r in range(3):
                kept[k, r] = deskewed[i, r]
                offset[k, r] = world[i, r] - means[j, r]
                for c in range(3):
                    kept_covariances[k, r, c] = covariances[j, r, c]
            k += 1
    hessian, gradient = _normal_equations(
        kept, tau, offset, kept_covariances, rotation, regularization, scale
    )
    return hessian, gradient, pairs


def sweep_linearization(
    points: np.ndarray,
    times: np.ndarray,
    twist_terms: tuple[np.ndarray, float, np.ndarray, np.ndarray, np.ndarray],
    small_angle: float,
    T: np.ndarray,
    local_map: SweepMap,
    scale: float,
) -> tuple[np.ndarray, np.ndarray, int]:
    """
    One Gauss-Newton linearization of the sweep alignment in one compiled pass.

    Deskews ``points`` (N, 3) taken at ``times`` by the twist (``twist_terms``: velocity,
    rate, axis, axis x velocity, axis x (axis x velocity), as ``deskew._twist_terms``),
    moves them by ``T`` (4, 4), pairs each with its nearest mean of ``local_map`` (sorted in
    its grid: ``core/features/cell_grid.py``) within its distance and returns ``H`` (12,
    12), ``g`` (12,) of the pairs (:func:`normal_equations`) and their count. The same
    steps as the NumPy loop of ``sweep_alignment.align_sweep``, without its temporaries.
    """
    f64 = np.float64
    T = np.asarray(T, dtype=f64)
    return _sweep_linearization(
        np.ascontiguousarray(points, dtype=f64),
        np.ascontiguousarray(times, dtype=f64),
        SegmentRows.constant(*twist_terms),
        float(small_angle),
        np.ascontiguousarray(T[:3, :3]),
        np.ascontiguousarray(T[:3, 3]),
        local_map,
        float(scale),
    )


@jit
def _twist_rows(xi: np.ndarray) -> SegmentRows:
    """``deskew._twist_terms`` of ``xi = (omega, v)`` as one segment's rows (identity start)."""
    velocity = xi[3:].copy().reshape(1, 3)
    rate = np.sqrt(xi[0] * xi[0] + xi[1] * xi[1] + xi[2] * xi[2])
    axis = np.zeros((1, 3))
    cross1 = np.zeros((1, 3))
    cross2 = np.zeros((1, 3))
    if rate > 0.0:
        a, v = xi[:3] / rate, xi[3:]
        axis[0, :] = a
        cross1[0, 0] = a[1] * v[2] - a[2] * v[1]
        cross1[0, 1] = a[2] * v[0] - a[0] * v[2]
        cross1[0, 2] = a[0] * v[1] - a[1] * v[0]
        c = cross1[0]
        cross2[0, 0] = a[1] * c[2] - a[2] * c[1]
        cross2[0, 1] = a[2] * c[0] - a[0] * c[2]
        cross2[0, 2] = a[0] * c[1] - a[1] * c[0]
    identity = np.eye(3).reshape(1, 3, 3)
    return SegmentRows(
        np.zeros(1), velocity, np.array([rate]), axis, cross1, cross2, identity, np.zeros((1, 3))
    )


@jit
def _solve(matrix: np.ndarray, vector: np.ndarray) -> tuple[np.ndarray, bool]:
    """``matrix^-1 vector`` by Gaussian elimination with partial pivoting (False: singular)."""
    n = vector.shape[0]
    a = matrix.copy()
    b = vector.copy()
    for k in range(n):
        pivot = k
        for r in range(k + 1, n):
            if abs(a[r, k]) > abs(a[pivot, k]):
                pivot = r
        if a[pivot, k] == 0.0 or not np.isfinite(a[pivot, k]):
            return b, False
        if pivot != k:
            for c in range(n):
                a[k, c], a[pivot, c] = a[pivot, c], a[k, c]
            b[k], b[pivot] = b[pivot], b[k]
        for r in range(k + 1, n):
            factor = a[r, k] / a[k, k]
            for c in range(k, n):
                a[r, c] -= factor * a[k, c]
            b[r] -= factor * b[k]
    for k in range(n - 1, -1, -1):
        s = b[k]
        for c in range(k + 1, n):
            s -= a[k, c] * b[c]
        b[k] = s / a[k, k]
    return b, True


@jit
def _se3_small(step: np.ndarray) -> np.ndarray:
    """``sweep_alignment._se3_small``: the (4, 4) pose of a small step (rotation exact)."""
    out = np.eye(4)
    angle = np.sqrt(step[0] * step[0] + step[1] * step[1] + step[2] * step[2])
    if angle > 0.0:
        k = step[:3] / angle
        skew = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        out[:3, :3] += np.sin(angle) * skew + (1.0 - np.cos(angle)) * (skew @ skew)
    out[:3, 3] = step[3:]
    return out


@jit
def _align_sweep(
    points: np.ndarray,
    times: np.ndarray,
    T_initial: np.ndarray,
    xi_initial: np.ndarray,
    prior: np.ndarray,
    schedule: SweepSchedule,
    local_map: SweepMap,
) -> tuple[np.ndarray, np.ndarray, int, int, float]:
    iterations, kernel_start, step_tolerance, small_angle = schedule
    T = T_initial.copy()
    xi = xi_initial.copy()
    pose_offset = np.zeros(6)
    pairs, iteration = 0, 0
    n = points.shape[0]
    segment = np.zeros(n, dtype=np.int64)
    # the points deskewed by the initial twist: the first step's, and the change's reference
    initial = _deskew_piecewise(points, times, segment, _twist_rows(xi_initial), small_angle)
    decay = kernel_start ** (-1.0 / max(iterations - 2, 1))
    for iteration in range(1, iterations + 1):
        scale = max(1.0, kernel_start * decay ** (iteration - 1))
        rotation = np.ascontiguousarray(T[:3, :3])
        translation = np.ascontiguousarray(T[:3, 3])
        if iteration == 1:  # xi is still xi_initial: its deskew is done
            hessian, gradient, pairs = _deskewed_linearization(
                initial, times, rotation, translation, local_map, scale
            )
        else:
            hessian, gradient, pairs = _sweep_linearization(
                points,
                times,
                _twist_rows(xi),
                small_angle,
                rotation,
                translation,
                local_map,
                scale,
            )
        if pairs < 12:
            break
        for k in range(12):
            state = pose_offset[k] if k < 6 else xi[k - 6] - xi_initial[k - 6]
            hessian[k, k] += prior[k]
            gradient[k] += prior[k] * state
        step, solved = _solve(hessian, gradient)
        if not solved:
            break
        step = -step
        T = T @ _se3_small(step[:6])
        pose_offset += step[:6]
        xi += step[6:]
        if np.max(np.abs(step)) < step_tolerance:
            break
    # the largest move of a point between the deskews by the result's and the initial twist
    change = 0.0
    final = _deskew_piecewise(points, times, segment, _twist_rows(xi), small_angle)
    for i in range(n):
        d = (
            (final[i, 0] - initial[i, 0]) ** 2
            + (final[i, 1] - initial[i, 1]) ** 2
            + (final[i, 2] - initial[i, 2]) ** 2
        )
        change = max(change, d)
    return T, xi, pairs, iteration, np.sqrt(change)


def align_sweep(
    points: np.ndarray,
    times: np.ndarray,
    T_initial: np.ndarray,
    xi_initial: np.ndarray,
    prior: np.ndarray,
    schedule: SweepSchedule,
    local_map: SweepMap,
) -> tuple[np.ndarray, np.ndarray, int, int, float]:
    """
    Run the whole Gauss-Newton loop of ``sweep_alignment.align_sweep`` in one compiled call.

    ``points`` (N, 3) raw, ``times`` (N,), ``T_initial`` (4, 4), ``xi_initial`` (6,) the
    deskew's twist ``(omega, v)``, ``prior`` (12,) the diagonal prior of ``(pose offset,
    twist - xi_initial)``; the map's means sorted in ``local_map``'s grid and their
    covariances. Each step is :func:`sweep_linearization`; the 12x12 system is solved by
    Gaussian elimination with partial pivoting (LAPACK's ``gesv`` without blocking: the
    same poses to rounding). Returns ``(T, xi, pairs, iterations, change_m)``,
    ``change_m`` the largest move of a point between the deskews by ``xi`` and
    ``xi_initial``.
    """
    f64 = np.float64
    return _align_sweep(
        np.ascontiguousarray(points, dtype=f64),
        np.ascontiguousarray(times, dtype=f64),
        np.ascontiguousarray(T_initial, dtype=f64),
        np.ascontiguousarray(xi_initial, dtype=f64),
        np.ascontiguousarray(prior, dtype=f64),
        SweepSchedule(
            int(schedule.iterations),
            float(schedule.kernel_start),
            float(schedule.step_tolerance),
            float(schedule.small_angle),
        ),
        local_map,
    )
