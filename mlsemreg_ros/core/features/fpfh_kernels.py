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
Compiled FPFH passes (numba): one loop over the point pairs per step.

Each kernel is the twin of a NumPy step of :mod:`mlsemreg_ros.core.features.fpfh`
(FPFH: Rusu et al., "Fast Point Feature Histograms (FPFH) for 3D Registration",
ICRA 2009) and performs the same floating-point operations in the same order:
float32 pair geometry, float64 sums accumulated in pair order as ``np.bincount``
does, neighbour sums in ascending neighbour order as SciPy's CSR product does.
The transcendental functions (``arctan2`` of the pair angle alpha, the
eigen-solver's ``arccos``/``cos``) stay in NumPy between the kernels: NumPy's
SIMD versions differ from libm in the last bit, and a last-bit change can move a
pair into the next histogram bin. So the compiled FPFH equals the NumPy FPFH bit
for bit on the same machine (tested).
"""

from __future__ import annotations

from mlsemreg_ros.core.features.kernels import jit
import numpy as np

_F0 = np.float32(0.0)
_F1 = np.float32(1.0)
_TINY = np.float32(1e-6)  # sine below this: the all-zero pair feature
_LOW_ALPHA = np.float32(-np.pi)
_SCALE_ALPHA = np.float32(11 / (2 * np.pi))
_LOW_UNIT = np.float32(-1.0)
_SCALE_UNIT = np.float32(11 / 2.0)


@jit
def pair_offsets(
    coords: np.ndarray, first: np.ndarray, second: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(3, P) float32 ``p_second - p_first`` of float32 ``coords`` (3, S) and (P,) ``|.|^2``."""
    size = first.shape[0]
    delta = np.empty((3, size), dtype=np.float32)
    dist2 = np.empty(size, dtype=np.float32)
    for e in range(size):
        a, b = first[e], second[e]
        dx = coords[0, b] - coords[0, a]
        dy = coords[1, b] - coords[1, a]
        dz = coords[2, b] - coords[2, a]
        delta[0, e], delta[1, e], delta[2, e] = dx, dy, dz
        dist2[e] = dx * dx + dy * dy + dz * dz
    return delta, dist2


@jit
def keypoint_offsets(
    keypoints: np.ndarray, support: np.ndarray, owner: np.ndarray, other: np.ndarray
) -> np.ndarray:
    """(3, E) float32 of the float64 differences ``support[other] - keypoints[owner]``."""
    offset = np.empty((3, owner.shape[0]), dtype=np.float32)
    for e in range(owner.shape[0]):
        for k in range(3):
            offset[k, e] = np.float32(support[other[e], k] - keypoints[owner[e], k])
    return offset


@jit
def covariances(
    n: int, first: np.ndarray, second: np.ndarray, offset: np.ndarray, use: np.ndarray
) -> np.ndarray:
    """
    (n, 6) neighbourhood covariances ``[c00, c01, c02, c11, c12, c22]`` (float64).

    Twin of the accumulation in :func:`mlsemreg_ros.core.features.fpfh.estimate_normals` over the
    offsets ``use`` of ``offset`` (3, E): ``second`` empty means one owner per offset,
    else unordered pairs (the offset leads from ``first`` to ``second``).
    """
    pairs = second.shape[0] > 0
    sums = np.zeros((2, n, 3))  # per owner role, as one np.bincount per role
    products = np.zeros((2, n, 6))
    count = np.zeros(n)
    for u in range(use.shape[0]):
        e = use[u]
        dx, dy, dz = offset[0, e], offset[1, e], offset[2, e]
        p00, p01, p02 = np.float64(dx * dx), np.float64(dx * dy), np.float64(dx * dz)
        p11, p12, p22 = np.float64(dy * dy), np.float64(dy * dz), np.float64(dz * dz)
        owners = 2 if pairs else 1
        for role in range(owners):
            i = first[e] if role == 0 else second[e]
            count[i] += 1.0
            sums[role, i, 0] += np.float64(dx)
            sums[role, i, 1] += np.float64(dy)
            sums[role, i, 2] += np.float64(dz)
            products[role, i, 0] += p00
            products[role, i, 1] += p01
            products[role, i, 2] += p02
            products[role, i, 3] += p11
            products[role, i, 4] += p12
            products[role, i, 5] += p22
    out = np.empty((n, 6))
    for i in range(n):
        total = count[i] + 1.0  # the point itself, offset 0
        mean = np.empty(3)
        for a in range(3):
            mean[a] = (sums[0, i, a] - sums[1, i, a]) / total
        slot = 0
        for a in range(3):
            for b in range(a, 3):
                summed = (0.0 + products[0, i, slot]) + products[1, i, slot]
                out[i, slot] = summed / total - mean[a] * mean[b]
                slot += 1
    return out


@jit
def pair_angles(
    delta: np.ndarray,
    normals_a: np.ndarray,
    index_a: np.ndarray,
    normals_b: np.ndarray,
    index_b: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """
    Twin of :func:`mlsemreg_ros.core.features.fpfh.pair_feature_bins` up to its ``arctan2``.

    Pair ``e`` joins ``normals_a[:, index_a[e]]`` (at the start of ``delta[:, e]``) and
    ``normals_b[:, index_b[e]]``. Returns the arguments ``(y, x)`` (float32) of alpha's
    ``arctan2``, the (3, P) int8 bins with phi and theta filled (row 0 is left for
    alpha) and the (P,) bool mask of regular pairs (the others have the zero feature).
    """
    size = delta.shape[1]
    y = np.empty(size, dtype=np.float32)
    x = np.empty(size, dtype=np.float32)
    bins = np.empty((3, size), dtype=np.int8)
    regular = np.empty(size, dtype=np.bool_)
    for e in range(size):
        dx, dy, dz = delta[0, e], delta[1, e], delta[2, e]
        a, b = index_a[e], index_b[e]
        n1x, n1y, n1z = normals_a[0, a], normals_a[1, a], normals_a[2, a]
        n2x, n2y, n2z = normals_b[0, b], normals_b[1, b], normals_b[2, b]
        inv_length = _F1 / np.sqrt(dx * dx + dy * dy + dz * dz)
        along_first = (n1x * dx + n1y * dy + n1z * dz) * inv_length
        along_second = (n2x * dx + n2y * dy + n2z * dz) * inv_length
        cos_normals = n1x * n2x + n1y * n2y + n1z * n2z
        triple = (
            dx * (n1y * n2z - n1z * n2y)
            + dy * (n1z * n2x - n1x * n2z)
            + dz * (n1x * n2y - n1y * n2x)
        ) * inv_length
        if abs(along_first) < abs(along_second):
            theta, along_target = -along_second, -along_first
        else:
            theta, along_target = along_first, along_second
        sine = np.sqrt(max(_F1 - theta * theta, _F0))
        if sine > _TINY:
            regular[e] = True
            phi = triple / sine
            y[e] = along_target - theta * cos_normals
            x[e] = cos_normals * sine
        else:
            regular[e] = False
            phi, theta = _F0, _F0
            y[e], x[e] = _F0, _F1
        bins[1, e] = _bin(phi, _LOW_UNIT, _SCALE_UNIT)
        bins[2, e] = _bin(theta, _LOW_UNIT, _SCALE_UNIT)
    return y, x, bins, regular


@jit
def _bin(value: np.float32, low: np.float32, scale: np.float32) -> int:
    scaled = np.floor((value - low) * scale)
    return int(min(max(scaled, _F0), np.float32(10.0)))


@jit
def histograms(
    n: int,
    first: np.ndarray,
    second: np.ndarray,
    bins: np.ndarray,
    regular: np.ndarray,
    alpha: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """
    SPFH of :func:`mlsemreg_ros.core.features.fpfh.simplified_histograms` as ``(counts, scale)``.

    ``SPFH[i, k] = counts[i, k] * scale[i]`` (float64, ``scale = 100 / max(degree, 1)``):
    (n, 33) int32 counts are a quarter of the memory the neighbour sums read. Fills
    alpha's bins (row 0 of ``bins``) from ``alpha`` first; ``second`` empty means one
    owner per pair feature.
    """
    counts = np.zeros((n, 33), dtype=np.int32)
    degree = np.zeros(n, dtype=np.int64)
    zero_alpha = _bin(_F0, _LOW_ALPHA, _SCALE_ALPHA)
    owners = 2 if second.shape[0] > 0 else 1
    for e in range(first.shape[0]):
        bins[0, e] = _bin(alpha[e], _LOW_ALPHA, _SCALE_ALPHA) if regular[e] else zero_alpha
        for role in range(owners):
            i = first[e] if role == 0 else second[e]
            degree[i] += 1
            counts[i, bins[0, e]] += 1
            counts[i, 11 + bins[1, e]] += 1
            counts[i, 22 + bins[2, e]] += 1
    scale = np.empty(n)
    for i in range(n):
        scale[i] = 100.0 / max(degree[i], 1)
    return counts, scale


@jit
def spfh_rows(counts: np.ndarray, scale: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """(len(rows), 33) float64 SPFH of the given rows."""
    out = np.empty((rows.shape[0], 33))
    for r in range(rows.shape[0]):
        for k in range(33):
            out[r, k] = counts[rows[r], k] * scale[rows[r]]
    return out


@jit
def _row_sums(
    m: int,
    rows: np.ndarray,
    cols: np.ndarray,
    weights: np.ndarray,
    counts: np.ndarray,
    scale: np.ndarray,
) -> np.ndarray:
    """``sum_k w_k SPFH[col_k]`` per row, each row's terms in ascending column order."""
    start = np.zeros(m + 1, dtype=np.int64)
    for e in range(rows.shape[0]):
        start[rows[e] + 1] += 1
    for r in range(m):
        start[r + 1] += start[r]
    fill = start[:-1].copy()
    col = np.empty(rows.shape[0], dtype=np.int64)
    weight = np.empty(rows.shape[0])
    for e in range(rows.shape[0]):
        at = fill[rows[e]]
        col[at], weight[at] = cols[e], weights[e]
        fill[rows[e]] += 1
    out = np.zeros((m, 33))
    for r in range(m):
        for at in range(start[r] + 1, start[r + 1]):  # insertion sort by column
            c, w, j = col[at], weight[at], at - 1
            while j >= start[r] and col[j] > c:
                col[j + 1], weight[j + 1] = col[j], weight[j]
                j -= 1
            col[j + 1], weight[j + 1] = c, w
        for at in range(start[r], start[r + 1]):
            j, w = col[at], weight[at]
            for k in range(33):  # w * SPFH[j, k], the same product as the NumPy CSR sum
                out[r, k] += w * (counts[j, k] * scale[j])
    return out


@jit
def support_neighbour_sums(
    rows: np.ndarray,
    n: int,
    first: np.ndarray,
    second: np.ndarray,
    dist2: np.ndarray,
    counts: np.ndarray,
    scale: np.ndarray,
) -> np.ndarray:
    """
    Sum ``SPFH[k] / d_k^2`` over the support pairs of each support point of ``rows``.

    The product of :func:`mlsemreg_ros.core.features.fpfh._pair_weights` with the SPFH; returns
    (len(rows), 33) float64.
    """
    position = np.full(n, -1, dtype=np.int64)
    for r in range(rows.shape[0]):
        position[rows[r]] = r
    size = 0
    for e in range(first.shape[0]):
        size += (position[first[e]] >= 0) + (position[second[e]] >= 0)
    target = np.empty(size, dtype=np.int64)
    neighbour = np.empty(size, dtype=np.int64)
    weights = np.empty(size)
    at = 0
    for role in range(2):  # the order of _pair_weights: pairs from their first point, then
        for e in range(first.shape[0]):
            here, there = (first[e], second[e]) if role == 0 else (second[e], first[e])
            if position[here] >= 0:
                target[at], neighbour[at] = position[here], there
                weights[at] = np.float64(_F1 / dist2[e])  # float32, as 1.0 / d2 in NumPy
                at += 1
    return _row_sums(rows.shape[0], target, neighbour, weights, counts, scale)


@jit
def keypoint_neighbour_sums(
    m: int,
    owner: np.ndarray,
    other: np.ndarray,
    dist: np.ndarray,
    counts: np.ndarray,
    scale: np.ndarray,
) -> np.ndarray:
    """(m, 33) ``sum_k SPFH[other_k] / dist_k^2`` of every keypoint's support neighbours."""
    weights = np.empty(owner.shape[0])
    for e in range(owner.shape[0]):
        weights[e] = 1.0 / (dist[e] * dist[e])
    return _row_sums(m, owner, other, weights, counts, scale)


@jit
def eigen_setup(covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    First half of :func:`mlsemreg_ros.core.features.fpfh.smallest_eigenvectors`, per (N, 6) row.

    Returns ``q`` (the mean eigenvalue), ``p`` and the numerator of the scaled determinant
    ``det = numerator / max(p, 0 -> 1) ** 3``; NumPy then takes the power, ``arccos`` and
    ``cos``, as the NumPy solver does.
    """
    n = covariance.shape[0]
    q = np.empty(n)
    p = np.empty(n)
    numerator = np.empty(n)
    for i in range(n):
        a00, a01, a02, a11, a12, a22 = covariance[i]
        mean = (a00 + a11 + a22) / 3.0
        b00, b11, b22 = a00 - mean, a11 - mean, a22 - mean
        off = a01 * a01 + a02 * a02 + a12 * a12
        q[i] = mean
        p[i] = np.sqrt(max((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * off) / 6.0, 0.0))
        numerator[i] = (
            b00 * (b11 * b22 - a12 * a12)
            - a01 * (a01 * b22 - a12 * a02)
            + a02 * (a01 * a12 - b11 * a02)
        )
    return q, p, numerator


@jit
def eigen_vectors(
    covariance: np.ndarray, q: np.ndarray, p: np.ndarray, cosine: np.ndarray, points: np.ndarray
) -> np.ndarray:
    """
    Finish the solver and orient as :func:`mlsemreg_ros.core.features.fpfh.orient_normals` does.

    ``cosine`` = ``cos(phi + 2 pi / 3)`` from NumPy. Returns (3, N) float32 unit normals
    facing the origin.
    """
    n = covariance.shape[0]
    normals = np.empty((3, n), dtype=np.float32)
    crosses = np.empty((3, 3))
    for i in range(n):
        a00, a01, a02, a11, a12, a22 = covariance[i]
        smallest = q[i] + 2.0 * p[i] * cosine[i]
        d00, d11, d22 = a00 - smallest, a11 - smallest, a22 - smallest
        crosses[0, 0] = a01 * a12 - a02 * d11  # r0 x r1
        crosses[0, 1] = a02 * a01 - d00 * a12
        crosses[0, 2] = d00 * d11 - a01 * a01
        crosses[1, 0] = a01 * d22 - a02 * a12  # r0 x r2
        crosses[1, 1] = a02 * a02 - d00 * d22
        crosses[1, 2] = d00 * a12 - a01 * a02
        crosses[2, 0] = d11 * d22 - a12 * a12  # r1 x r2
        crosses[2, 1] = a12 * a02 - a01 * d22
        crosses[2, 2] = a01 * a12 - d11 * a02
        l0 = (
            crosses[0, 0] * crosses[0, 0]
            + crosses[0, 1] * crosses[0, 1]
            + crosses[0, 2] * crosses[0, 2]
        )
        l1 = (
            crosses[1, 0] * crosses[1, 0]
            + crosses[1, 1] * crosses[1, 1]
            + crosses[1, 2] * crosses[1, 2]
        )
        l2 = (
            crosses[2, 0] * crosses[2, 0]
            + crosses[2, 1] * crosses[2, 1]
            + crosses[2, 2] * crosses[2, 2]
        )
        best = 1 if l1 > l0 else 0
        if l2 > max(l0, l1):
            best = 2
        chosen = (l0, l1, l2)[best]
        length = np.sqrt(chosen)
        scale = 0.0
        for k in range(6):
            scale = max(scale, abs(covariance[i, k]))
        scale = max(scale, 1e-300)
        vx, vy, vz = crosses[best, 0], crosses[best, 1], crosses[best, 2]
        if length <= 1e-12 * scale * scale:
            vx, vy, vz, length = 0.0, 0.0, 1.0, 1.0
        vx, vy, vz = vx / length, vy / length, vz / length
        if vx * points[i, 0] + vy * points[i, 1] + vz * points[i, 2] > 0:  # faces away
            vx, vy, vz = -vx, -vy, -vz
        normals[0, i], normals[1, i], normals[2, i] = vx, vy, vz
    return normals
