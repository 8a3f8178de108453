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

from mlsemreg_ros.core.features.kernels import _deskew_piecewise, jit
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


#: Each coordinate of a cell key is offset by this and packed into 21 bits.
_CELL_OFFSET = 1 << 20
_GOLDEN = -7046029254386353131  # 0x9E3779B97F4A7C15 as int64 (Fibonacci hashing)


@jit
def _cell_key(x: float, y: float, z: float, cell: float) -> int:
    """Packed key of the cell of ``(x, y, z)``; -1 outside the +-2**20 cells of the origin."""
    ix = np.int64(np.floor(x / cell)) + _CELL_OFFSET
    iy = np.int64(np.floor(y / cell)) + _CELL_OFFSET
    iz = np.int64(np.floor(z / cell)) + _CELL_OFFSET
    limit = 2 * _CELL_OFFSET
    if ix < 1 or iy < 1 or iz < 1 or ix >= limit - 1 or iy >= limit - 1 or iz >= limit - 1:
        return -1
    return (ix << 42) | (iy << 21) | iz


@jit
def _cell_table(
    means: np.ndarray, cell: float, bits: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Open-addressing table (``2**bits`` buckets) of the means by cell: key, index and mean.

    Every mean takes a bucket of its own (several means may share a cell); a mean whose
    cell is out of range is left out. The bucket holds a copy of its mean, so a probe
    reads neighbouring memory instead of the means array at random.
    """
    size = 1 << bits
    mask = size - 1
    table_key = np.full(size, -1, dtype=np.int64)
    table_index = np.full(size, -1, dtype=np.int64)
    table_mean = np.zeros((size, 3))
    for m in range(means.shape[0]):
        key = _cell_key(means[m, 0], means[m, 1], means[m, 2], cell)
        if key < 0:
            continue
        bucket = ((key * _GOLDEN) >> (64 - bits)) & mask
        while table_key[bucket] >= 0:
            bucket = (bucket + 1) & mask
        table_key[bucket] = key
        table_index[bucket] = m
        table_mean[bucket, 0] = means[m, 0]
        table_mean[bucket, 1] = means[m, 1]
        table_mean[bucket, 2] = means[m, 2]
    return table_key, table_index, table_mean


@jit
def _nearest_in_cells(
    points: np.ndarray,
    table_key: np.ndarray,
    table_index: np.ndarray,
    table_mean: np.ndarray,
    cell: float,
    bits: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest mean of each point among the 27 cells around it (-1 and inf: none)."""
    mask = (1 << bits) - 1
    n = points.shape[0]
    index = np.full(n, -1, dtype=np.int64)
    squared = np.full(n, np.inf)
    gap = np.empty((3, 3))  # squared distance to the neighbour cells along each axis
    limit = cell * cell
    for i in range(n):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        center = _cell_key(x, y, z, cell)
        if center < 0:
            continue
        for k in range(3):
            low = points[i, k] - np.floor(points[i, k] / cell) * cell
            gap[k, 0] = low * low
            gap[k, 1] = 0.0
            gap[k, 2] = (cell - low) * (cell - low)
        best, best_sq = -1, np.inf
        for step in range(27):  # the point's own cell first (step 13 is the centre)
            c = (step + 13) % 27
            dx, dy, dz = c // 9, (c // 3) % 3, c % 3
            bound = gap[0, dx] + gap[1, dy] + gap[2, dz]
            if bound >= best_sq or bound > limit:  # no mean there can be nearer
                continue
            key = center + ((dx - 1) << 42) + ((dy - 1) << 21) + (dz - 1)
            bucket = ((key * _GOLDEN) >> (64 - bits)) & mask
            while table_key[bucket] >= 0:
                if table_key[bucket] == key:
                    ex = table_mean[bucket, 0] - x
                    ey = table_mean[bucket, 1] - y
                    ez = table_mean[bucket, 2] - z
                    sq = ex * ex + ey * ey + ez * ez
                    if sq < best_sq:
                        best, best_sq = bucket, sq
                bucket = (bucket + 1) & mask
        if best >= 0:
            index[i] = table_index[best]
            squared[i] = best_sq
    return index, squared


class CellIndex:
    """
    The means hashed by cells of edge ``cell``: the nearest mean within ``cell`` of a point.

    Exact for every point whose nearest mean is at most ``cell`` away (it lies in one of the
    27 cells around the point's own); a point with none that near gets index -1 and an
    infinite squared distance. Built in one pass (no tree): the sweep alignment's map
    changes at every scan, and a KD-tree over it cost more than the whole search.
    """

    def __init__(self, means: np.ndarray, cell: float) -> None:
        """``means`` (V, 3); ``cell`` > 0, metres."""
        self.means = np.ascontiguousarray(means, dtype=np.float64)
        self.cell = float(cell)
        self.bits = max(4, int(np.ceil(np.log2(max(2 * len(self.means), 2)))))  # load <= 1/2
        self.table_key, self.table_index, self.table_mean = _cell_table(
            self.means, self.cell, self.bits
        )

    def nearest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Index (-1: none) and squared distance (inf: none) of each point's nearest mean."""
        return _nearest_in_cells(
            np.ascontiguousarray(points, dtype=np.float64),
            self.table_key,
            self.table_index,
            self.table_mean,
            self.cell,
            self.bits,
        )


@jit
def _sweep_linearization(
    points: np.ndarray,
    times: np.ndarray,
    velocity: np.ndarray,
    rate: np.ndarray,
    axis: np.ndarray,
    cross1: np.ndarray,
    cross2: np.ndarray,
    small_angle: float,
    rotation: np.ndarray,
    translation: np.ndarray,
    table_key: np.ndarray,
    table_index: np.ndarray,
    table_mean: np.ndarray,
    cell: float,
    bits: int,
    means: np.ndarray,
    covariances: np.ndarray,
    max_squared: float,
    regularization: float,
    scale: float,
) -> tuple[np.ndarray, np.ndarray, int]:
    n = points.shape[0]
    deskewed = _deskew_piecewise(
        points,
        times,
        np.zeros(n, dtype=np.int64),
        np.zeros(1),
        velocity,
        rate,
        axis,
        cross1,
        cross2,
        np.eye(3).reshape(1, 3, 3),
        np.zeros((1, 3)),
        small_angle,
    )
    world = np.empty((n, 3))
    for i in range(n):
        for r in range(3):
            world[i, r] = (
                rotation[r, 0] * deskewed[i, 0]
                + rotation[r, 1] * deskewed[i, 1]
                + rotation[r, 2] * deskewed[i, 2]
                + translation[r]
            )
    index, squared = _nearest_in_cells(world, table_key, table_index, table_mean, cell, bits)
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
    cells: CellIndex,
    covariances: np.ndarray,
    max_distance: float,
    regularization: float,
    scale: float,
) -> tuple[np.ndarray, np.ndarray, int]:
    """
    One Gauss-Newton linearization of the sweep alignment in one compiled pass.

    Deskews ``points`` (N, 3) taken at ``times`` by the twist (``twist_terms``: velocity,
    rate, axis, axis x velocity, axis x (axis x velocity), as ``deskew._twist_terms``),
    moves them by ``T`` (4, 4), pairs each with its nearest mean of ``cells`` within
    ``max_distance`` and returns ``H`` (12, 12), ``g`` (12,) of the pairs
    (:func:`normal_equations`) and their count. The same steps as the NumPy loop of
    ``sweep_alignment.align_sweep``, without its temporaries.
    """
    velocity, rate, axis, cross1, cross2 = twist_terms
    f64 = np.float64
    T = np.asarray(T, dtype=f64)
    return _sweep_linearization(
        np.ascontiguousarray(points, dtype=f64),
        np.ascontiguousarray(times, dtype=f64),
        np.asarray(velocity, dtype=f64).reshape(1, 3),
        np.array([float(rate)]),
        np.asarray(axis, dtype=f64).reshape(1, 3),
        np.asarray(cross1, dtype=f64).reshape(1, 3),
        np.asarray(cross2, dtype=f64).reshape(1, 3),
        float(small_angle),
        np.ascontiguousarray(T[:3, :3]),
        np.ascontiguousarray(T[:3, 3]),
        cells.table_key,
        cells.table_index,
        cells.table_mean,
        cells.cell,
        cells.bits,
        cells.means,
        covariances,
        float(max_distance) ** 2,
        float(regularization),
        float(scale),
    )
