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
Compiled (numba) kernels of the geometric labeler (core/labeling/geometric.py).

One loop over the points or the bins each: the concentric-zone bins, the region-wise
ground planes (Patchwork++), the height above the ground, the eigenvalue features of the
voxel cells and the column statistics. 3x3 symmetric eigen-problems are solved in closed
form (the trigonometric method), which is about a hundred times cheaper than a LAPACK call
per cell.
"""

from __future__ import annotations

import math

from mlsemreg_ros.core.features.cell_grid import CellGrid, column_run
from mlsemreg_ros.core.features.kernels import jit
import numpy as np


@jit
def eigen3(
    c00: float, c01: float, c02: float, c11: float, c12: float, c22: float
) -> tuple[float, float, float]:
    """Eigenvalues ``l1 >= l2 >= l3`` of a symmetric 3x3 matrix (closed form)."""
    p1 = c01 * c01 + c02 * c02 + c12 * c12
    q = (c00 + c11 + c22) / 3.0
    p2 = (c00 - q) ** 2 + (c11 - q) ** 2 + (c22 - q) ** 2 + 2.0 * p1
    if p2 <= 1e-30:
        return q, q, q
    p = math.sqrt(p2 / 6.0)
    b00, b11, b22 = (c00 - q) / p, (c11 - q) / p, (c22 - q) / p
    b01, b02, b12 = c01 / p, c02 / p, c12 / p
    det = (
        b00 * (b11 * b22 - b12 * b12)
        - b01 * (b01 * b22 - b12 * b02)
        + b02 * (b01 * b12 - b11 * b02)
    )
    r = min(max(det / 2.0, -1.0), 1.0)
    phi = math.acos(r) / 3.0
    l1 = q + 2.0 * p * math.cos(phi)
    l3 = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    return l1, 3.0 * q - l1 - l3, l3


@jit
def eigenvector3(
    c00: float, c01: float, c02: float, c11: float, c12: float, c22: float, value: float
) -> tuple[float, float, float]:
    """Return the unit eigenvector of ``value``: a cross product of rows of ``C - value I``."""
    r0 = (c00 - value, c01, c02)
    r1 = (c01, c11 - value, c12)
    r2 = (c02, c12, c22 - value)
    best, bx, by, bz = -1.0, 0.0, 0.0, 1.0
    for a, b in ((r0, r1), (r0, r2), (r1, r2)):
        x = a[1] * b[2] - a[2] * b[1]
        y = a[2] * b[0] - a[0] * b[2]
        z = a[0] * b[1] - a[1] * b[0]
        norm = x * x + y * y + z * z
        if norm > best:
            best, bx, by, bz = norm, x, y, z
    if best <= 1e-30:
        return 0.0, 0.0, 1.0
    scale = 1.0 / math.sqrt(best)
    return bx * scale, by * scale, bz * scale


@jit
def bin_points(
    points: np.ndarray,
    zone_min: np.ndarray,
    ring_width: np.ndarray,
    zone_rings: np.ndarray,
    zone_sectors: np.ndarray,
    zone_offset: np.ndarray,
    max_range: float,
    num_bins: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Concentric-zone bin of every point and the points grouped by bin (a counting sort).

    Returns ``(bin (N,) int64, -1 outside the zones; order (M,) point indices by bin;
    starts (num_bins + 1,) int64)``.
    """
    n = points.shape[0]
    zones = zone_min.shape[0]
    bins = np.full(n, -1, dtype=np.int64)
    counts = np.zeros(num_bins + 1, dtype=np.int64)
    for i in range(n):
        x, y = points[i, 0], points[i, 1]
        r = math.sqrt(x * x + y * y)
        if r < zone_min[0] or r >= max_range:
            continue
        zone = zones - 1
        while r < zone_min[zone]:
            zone -= 1
        ring = min(int((r - zone_min[zone]) / ring_width[zone]), zone_rings[zone] - 1)
        angle = math.atan2(y, x) + math.pi
        sector = min(int(angle / (2.0 * math.pi) * zone_sectors[zone]), zone_sectors[zone] - 1)
        b = zone_offset[zone] + ring * zone_sectors[zone] + sector
        bins[i] = b
        counts[b + 1] += 1
    starts = np.cumsum(counts)
    fill = starts[:-1].copy()
    order = np.empty(starts[-1], dtype=np.int64)
    for i in range(n):
        b = bins[i]
        if b >= 0:
            order[fill[b]] = i
            fill[b] += 1
    return bins, order, starts


@jit
def _plane_of(points: np.ndarray, rows: np.ndarray, use: np.ndarray) -> tuple:
    """Plane ``(nx, ny, nz, d, flatness, count)`` of the used rows (normal up; PCA)."""
    count = 0
    sx = sy = sz = 0.0
    for k in range(rows.shape[0]):
        if use[k]:
            i = rows[k]
            sx += points[i, 0]
            sy += points[i, 1]
            sz += points[i, 2]
            count += 1
    if count < 3:
        return 0.0, 0.0, 1.0, 0.0, 0.0, count
    mx, my, mz = sx / count, sy / count, sz / count
    c00 = c01 = c02 = c11 = c12 = c22 = 0.0
    for k in range(rows.shape[0]):
        if use[k]:
            i = rows[k]
            dx, dy, dz = points[i, 0] - mx, points[i, 1] - my, points[i, 2] - mz
            c00 += dx * dx
            c01 += dx * dy
            c02 += dx * dz
            c11 += dy * dy
            c12 += dy * dz
            c22 += dz * dz
    c00, c01, c02, c11, c12, c22 = (
        c00 / count,
        c01 / count,
        c02 / count,
        c11 / count,
        c12 / count,
        c22 / count,
    )
    _, _, l3 = eigen3(c00, c01, c02, c11, c12, c22)
    nx, ny, nz = eigenvector3(c00, c01, c02, c11, c12, c22, l3)
    if nz < 0.0:
        nx, ny, nz = -nx, -ny, -nz
    return nx, ny, nz, -(nx * mx + ny * my + nz * mz), max(l3, 0.0), count


@jit
def fit_bins(
    points: np.ndarray,
    order: np.ndarray,
    starts: np.ndarray,
    lowest: int,
    distance: float,
    iterations: int,
    min_points: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Region-wise ground planes: each bin's plane fitted to its lowest points, then refitted.

    The seeds are the points within ``distance`` above the mean of the bin's ``lowest``
    points; each iteration refits the plane to the points within ``distance`` of it.
    Returns ``(planes (B, 4) [nx, ny, nz, d] with nz >= 0, stats (B, 3) [flatness (the
    smallest eigenvalue, m^2), ground points, mean height of the ground points],
    on_plane (N,) bool: within ``distance`` of its bin's last plane)``. Bins with fewer
    than ``min_points`` points get the plane ``(0, 0, 0, 0)``.
    """
    num_bins = starts.shape[0] - 1
    planes = np.zeros((num_bins, 4))
    stats = np.zeros((num_bins, 3))
    on_plane = np.zeros(points.shape[0], dtype=np.bool_)
    for b in range(num_bins):
        first, last = starts[b], starts[b + 1]
        rows = order[first:last]
        n = rows.shape[0]
        if n < min_points:
            continue
        heights = np.empty(n)
        for k in range(n):
            heights[k] = points[rows[k], 2]
        ranked = np.argsort(heights)
        take = min(lowest, n)
        representative = 0.0
        for k in range(take):
            representative += heights[ranked[k]]
        representative /= take
        use = heights < representative + distance
        nx, ny, nz, d, flat, count = _plane_of(points, rows, use)
        for _ in range(iterations):
            if count < 3:
                break
            for k in range(n):
                i = rows[k]
                use[k] = abs(nx * points[i, 0] + ny * points[i, 1] + nz * points[i, 2] + d) < (
                    distance
                )
            nx, ny, nz, d, flat, count = _plane_of(points, rows, use)
        if count < 3:
            continue
        mean_z = 0.0
        for k in range(n):
            if use[k]:
                on_plane[rows[k]] = True
                mean_z += heights[k]
        planes[b, 0], planes[b, 1], planes[b, 2], planes[b, 3] = nx, ny, nz, d
        stats[b, 0], stats[b, 1], stats[b, 2] = flat, count, mean_z / count
    return planes, stats, on_plane


@jit
def height_above_ground(
    points: np.ndarray,
    bins: np.ndarray,
    planes: np.ndarray,
    accepted: np.ndarray,
    fallback_z: np.ndarray,
    ground_z: float,
) -> np.ndarray:
    """
    Height of every point above its bin's ground (N,) metres.

    An accepted bin's plane at the point; a rejected bin's ``fallback_z`` (the ground height
    carried outwards from its inner neighbours); outside the zones ``ground_z`` (minus the
    estimated sensor height).
    """
    n = points.shape[0]
    height = np.empty(n)
    for i in range(n):
        b = bins[i]
        z = points[i, 2]
        if b < 0:
            height[i] = z - ground_z
        elif accepted[b]:
            nx, ny, nz, d = planes[b, 0], planes[b, 1], planes[b, 2], planes[b, 3]
            height[i] = z + (nx * points[i, 0] + ny * points[i, 1] + d) / nz
        else:
            height[i] = z - fallback_z[b]
    return height


@jit
def carry_ground(
    upright: np.ndarray,
    bin_ground_z: np.ndarray,
    zone_rings: np.ndarray,
    zone_sectors: np.ndarray,
    zone_offset: np.ndarray,
    ground_z: float,
    rise: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """
    Which bins are ground, and the ground height of every bin (B,).

    Bins are walked outwards ring by ring. An upright bin is accepted when its ground
    height rises at most ``rise[zone]`` above its inner neighbour's (a roof or the top of
    a parked car is not ground); a rejected bin inherits its inner neighbour's height, so
    a run of them (a wall) carries the last ground seen on the way out. The innermost
    ring starts from ``ground_z``. Returns ``(carried (B,), accepted (B,) bool)``.
    """
    carried = np.full(upright.shape[0], ground_z)
    accepted = np.zeros(upright.shape[0], dtype=np.bool_)
    for zone in range(zone_rings.shape[0]):
        for ring in range(zone_rings[zone]):
            for sector in range(zone_sectors[zone]):
                b = zone_offset[zone] + ring * zone_sectors[zone] + sector
                inner_z = ground_z
                if ring > 0:
                    inner_z = carried[b - zone_sectors[zone]]
                elif zone > 0:
                    inner = zone - 1
                    inner_sector = (sector * zone_sectors[inner]) // zone_sectors[zone]
                    inner_z = carried[
                        zone_offset[inner]
                        + (zone_rings[inner] - 1) * zone_sectors[inner]
                        + inner_sector
                    ]
                if upright[b] and bin_ground_z[b] - inner_z <= rise[zone]:
                    accepted[b] = True
                    carried[b] = bin_ground_z[b]
                else:
                    carried[b] = inner_z
    return carried, accepted


@jit
def cell_features(
    points: np.ndarray, inverse: np.ndarray, cells: int
) -> tuple[np.ndarray, np.ndarray]:
    """
    Eigenvalue features of every voxel cell.

    Returns ``(features (C, 5) [linearity, planarity, scatter, |normal z|, |principal z|],
    counts (C,) int64)``; linearity ``(l1 - l2) / l1``, planarity ``(l2 - l3) / l1``,
    scatter ``l3 / l1`` of the cell's covariance (zeros for cells of fewer than 3 points).
    """
    sums = np.zeros((cells, 9))
    counts = np.zeros(cells, dtype=np.int64)
    for i in range(points.shape[0]):
        c = inverse[i]
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        counts[c] += 1
        sums[c, 0] += x
        sums[c, 1] += y
        sums[c, 2] += z
        sums[c, 3] += x * x
        sums[c, 4] += x * y
        sums[c, 5] += x * z
        sums[c, 6] += y * y
        sums[c, 7] += y * z
        sums[c, 8] += z * z
    features = np.zeros((cells, 5))
    for c in range(cells):
        n = counts[c]
        if n < 3:
            continue
        mx, my, mz = sums[c, 0] / n, sums[c, 1] / n, sums[c, 2] / n
        c00 = sums[c, 3] / n - mx * mx
        c01 = sums[c, 4] / n - mx * my
        c02 = sums[c, 5] / n - mx * mz
        c11 = sums[c, 6] / n - my * my
        c12 = sums[c, 7] / n - my * mz
        c22 = sums[c, 8] / n - mz * mz
        l1, l2, l3 = eigen3(c00, c01, c02, c11, c12, c22)
        if l1 <= 1e-12:
            continue
        l2, l3 = max(l2, 0.0), max(l3, 0.0)
        features[c, 0] = (l1 - l2) / l1
        features[c, 1] = (l2 - l3) / l1
        features[c, 2] = l3 / l1
        features[c, 3] = abs(eigenvector3(c00, c01, c02, c11, c12, c22, l3)[2])
        features[c, 4] = abs(eigenvector3(c00, c01, c02, c11, c12, c22, l1)[2])
    return features, counts


@jit
def column_extent(
    column: np.ndarray, height: np.ndarray, mask: np.ndarray, columns: int
) -> tuple[np.ndarray, np.ndarray]:
    """Highest and lowest height above the ground of the masked points of each column."""
    top = np.full(columns, -np.inf)
    base = np.full(columns, np.inf)
    for i in range(column.shape[0]):
        c = column[i]
        if c >= 0 and mask[i]:
            top[c] = max(top[c], height[i])
            base[c] = min(base[c], height[i])
    return top, base


@jit
def support_counts(
    points: np.ndarray,
    rows: np.ndarray,
    labels: np.ndarray,
    select: np.ndarray,
    radius: float,
    grid: CellGrid,
) -> tuple[np.ndarray, np.ndarray]:
    """
    Neighbour counts of the ``rows`` of ``points`` (N, 3) within ``radius`` (each counts itself).

    ``grid``: the same ``points`` in cells of edge ``radius`` (``CellGrid.build``);
    ``labels`` (N,) and ``select`` (N,) bool. Returns, per row, the count of
    all points within ``radius`` and the count of the selected points of its own label
    (the two ``cKDTree.query_ball_point`` counts of ``landmarks.confident_points``).
    """
    cell, low, extent, sorted_points, order = grid[0], grid[1], grid[2], grid[6], grid[7]
    count = rows.shape[0]
    total = np.zeros(count, dtype=np.int64)
    same = np.zeros(count, dtype=np.int64)
    reach = np.int64(np.ceil(radius / cell))
    limit = radius * radius
    for i in range(count):
        own = labels[rows[i]]
        x, y, z = points[rows[i], 0], points[rows[i], 1], points[rows[i], 2]
        cx = np.int64(np.floor(x / cell)) - low[0]
        cy = np.int64(np.floor(y / cell)) - low[1]
        cz = np.int64(np.floor(z / cell)) - low[2]
        for ix in range(max(cx - reach, 0), min(cx + reach + 1, extent[0])):
            for iy in range(max(cy - reach, 0), min(cy + reach + 1, extent[1])):
                first, last = column_run(grid, ix * extent[1] + iy, cz, reach)
                for k in range(first, last):
                    d2 = (
                        (x - sorted_points[k, 0]) ** 2
                        + (y - sorted_points[k, 1]) ** 2
                        + (z - sorted_points[k, 2]) ** 2
                    )
                    if d2 <= limit:
                        total[i] += 1
                        j = order[k]
                        if select[j] and labels[j] == own:
                            same[i] += 1
    return total, same


@jit
def window_sum(keys: np.ndarray, span: int, values: np.ndarray, radius: int) -> np.ndarray:
    """
    Sum of ``values`` (M,) over each occupied column's (2 radius + 1)^2 window.

    ``keys`` (M,) the columns' sorted linear keys ``ix * span + iy`` (``geometric.Columns``).
    The keys moved by one offset are sorted too, so each offset's neighbours are found by
    one merge walk over the keys; an unoccupied neighbour adds nothing. The terms are added
    in the order of the NumPy loop (dx, then dy), so the sums are the same.
    """
    count = keys.shape[0]
    total = np.zeros(count)
    for dx in range(-radius, radius + 1):
        for dy in range(-radius, radius + 1):
            offset = dx * span + dy
            j = 0
            for m in range(count):
                wanted = keys[m] + offset
                while j < count and keys[j] < wanted:
                    j += 1
                if j < count and keys[j] == wanted:
                    total[m] += values[j]
    return total
