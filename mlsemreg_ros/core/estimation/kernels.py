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
Compiled kernels of the global path's refused stages (numba, ``core/features/kernels.py``).

- :func:`refine_all`: SC2-PCR's post-refinement (reweighted least squares, Chen et al.
  CVPR 2022, Sec. 3.5) of many starting poses in one compiled loop, each on the
  correspondences near it (the BEV search's peaks, ``core/estimation/bev_search.py``);
- :func:`compatibility_upper`: SC2-PCR's length consistency (eq. 2) of every pair of
  correspondences in the strict upper triangle, the compatible ones kept row by row
  (``core/estimation/sc2pcr.py:compatibility_matrix``), computed from the coordinate
  differences in one fused pass instead of blocked matrix products;
- :func:`nearest_in_descriptor_space`: the guided re-matching's search
  (``core/estimation/guided.py``): for every moved source keypoint, the target keypoint
  nearest in descriptor space among those within a radius and of a compatible label,
  through a hash of ``radius``-sized cells instead of a pair list of every close pair;
- :func:`seen_through`: the covisible overlap's free-space test
  (``core/estimation/covisibility.py``) of the moved points not on the target, in one
  pass (range, bin, the bin's nearest range) instead of arrays of every point's.

Each is the NumPy code's arithmetic in another order: the same poses and matches up to
rounding (``test/test_estimation_kernels.py`` compares both). Without numba the same
Python functions run uncompiled (slow, only for a fresh clone without numba).
"""

from __future__ import annotations

from mlsemreg_ros.core.features.kernels import jit
import numpy as np

#: A batch whose weights sum to at most this is solved with uniform weights
#: (as ``core/rigid.py``).
_MIN_WEIGHT_SUM = 1e-12


@jit
def _apply(pose: np.ndarray, point: np.ndarray, out: np.ndarray) -> None:
    """``out = R point + t`` of one ``(4, 4)`` pose."""
    for a in range(3):
        out[a] = pose[a, 0] * point[0] + pose[a, 1] * point[1] + pose[a, 2] * point[2] + pose[a, 3]


@jit
def _weighted_kabsch(src: np.ndarray, dst: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted Kabsch of ``(n, 3)`` pairs (``core/rigid.py:weighted_rigid_transform``)."""
    count = src.shape[0]
    total = 0.0
    for k in range(count):
        total += max(weights[k], 0.0)
    w = np.empty(count)
    for k in range(count):
        w[k] = 1.0 / count if total <= _MIN_WEIGHT_SUM else max(weights[k], 0.0) / total
    centre_src = np.zeros(3)
    centre_dst = np.zeros(3)
    for k in range(count):
        for a in range(3):
            centre_src[a] += w[k] * src[k, a]
            centre_dst[a] += w[k] * dst[k, a]
    cov = np.zeros((3, 3))
    for k in range(count):
        for a in range(3):
            for b in range(3):
                cov[a, b] += w[k] * (src[k, a] - centre_src[a]) * (dst[k, b] - centre_dst[b])
    u, _, vt = np.linalg.svd(cov)
    v = vt.T.copy()
    ut = u.T.copy()
    v_ut = v @ ut
    if np.linalg.det(v_ut) < 0.0:
        v[:, 2] = -v[:, 2]
    rotation = v @ ut
    pose = np.eye(4)
    pose[:3, :3] = rotation
    for a in range(3):
        pose[a, 3] = centre_dst[a] - (
            rotation[a, 0] * centre_src[0]
            + rotation[a, 1] * centre_src[1]
            + rotation[a, 2] * centre_src[2]
        )
    return pose


@jit
def refine_all(
    starts: np.ndarray,
    src: np.ndarray,
    dst: np.ndarray,
    support: float,
    threshold: float,
    iterations: int,
) -> np.ndarray:
    """
    Post-refine every ``(S, 4, 4)`` start on the correspondences within ``support`` of it.

    Per start: the finite ``(K, 3)`` pairs with residual ``< support`` under it; with at
    least three, up to ``iterations`` reweighted steps (inliers ``r < threshold``, weights
    ``1 / (1 + (r / threshold)^2)``, stop when the inlier count repeats or drops below
    three), as ``core/estimation/sc2pcr.py:post_refinement``. Fewer than three near pairs:
    the start is kept. Returns ``(S, 4, 4)``.
    """
    count = src.shape[0]
    refined = starts.copy()
    moved = np.empty(3)
    near_src = np.empty((count, 3))
    near_dst = np.empty((count, 3))
    residual = np.empty(count)
    for s in range(starts.shape[0]):
        pose = starts[s].copy()
        near = 0
        for k in range(count):
            _apply(pose, src[k], moved)
            r = np.sqrt(
                (moved[0] - dst[k, 0]) ** 2
                + (moved[1] - dst[k, 1]) ** 2
                + (moved[2] - dst[k, 2]) ** 2
            )
            if r < support:
                near_src[near] = src[k]
                near_dst[near] = dst[k]
                near += 1
        if near < 3:
            continue
        previous = -1
        for _ in range(iterations):
            inliers = 0
            for k in range(near):
                _apply(pose, near_src[k], moved)
                residual[k] = np.sqrt(
                    (moved[0] - near_dst[k, 0]) ** 2
                    + (moved[1] - near_dst[k, 1]) ** 2
                    + (moved[2] - near_dst[k, 2]) ** 2
                )
                if residual[k] < threshold:
                    inliers += 1
            if inliers == previous or inliers < 3:
                break
            previous = inliers
            p = np.empty((inliers, 3))
            q = np.empty((inliers, 3))
            w = np.empty(inliers)
            at = 0
            for k in range(near):
                if residual[k] < threshold:
                    p[at] = near_src[k]
                    q[at] = near_dst[k]
                    w[at] = 1.0 / (1.0 + (residual[k] / threshold) ** 2)
                    at += 1
            pose = _weighted_kabsch(p, q, w)
        refined[s] = pose
    return refined


@jit
def nearest_in_descriptor_space(
    moved: np.ndarray,
    target: np.ndarray,
    radius: float,
    source_descriptors: np.ndarray,
    target_descriptors: np.ndarray,
    source_labels: np.ndarray,
    target_labels: np.ndarray,
    compatible: np.ndarray,
    use_labels: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Per moved source keypoint, the descriptor-nearest target keypoint within ``radius``.

    - ``moved``: ``(n, 3)`` source keypoints under the pose; ``target``: ``(m, 3)``.
    - ``*_descriptors``: ``(n, D)``, ``(m, D)`` float32.
    - ``*_labels``: learning ids of the keypoints; with ``use_labels`` a pair counts only
      when both ids lie inside ``compatible`` ``(C, C)`` (bool) and are compatible.

    Distances ``<= radius`` (Euclidean); ties in descriptor distance keep the lower target
    row. Returns ``(source rows ascending, target rows, float32 descriptor distances)``.
    """
    n, m = moved.shape[0], target.shape[0]
    size = compatible.shape[0]
    low = np.empty(3, dtype=np.int64)
    for a in range(3):
        low[a] = np.int64(np.floor(target[:, a].min() / radius)) - 1
    cells = np.empty((m, 3), dtype=np.int64)
    extent = np.zeros(3, dtype=np.int64)
    for j in range(m):
        for a in range(3):
            cells[j, a] = np.int64(np.floor(target[j, a] / radius)) - low[a]
            extent[a] = max(extent[a], cells[j, a] + 2)
    keys = (cells[:, 0] * extent[1] + cells[:, 1]) * extent[2] + cells[:, 2]
    order = np.argsort(keys, kind='mergesort')
    sorted_keys = keys[order]
    limit = radius * radius
    out_i = np.empty(n, dtype=np.int64)
    out_j = np.empty(n, dtype=np.int64)
    out_d = np.empty(n, dtype=np.float32)
    found = 0
    dims = source_descriptors.shape[1]
    cell = np.empty(3, dtype=np.int64)
    for i in range(n):
        outside = False
        for a in range(3):
            cell[a] = np.int64(np.floor(moved[i, a] / radius)) - low[a]
            if cell[a] < 0 or cell[a] > extent[a] - 1:
                outside = True
        if outside:
            continue
        a_label = source_labels[i]
        if use_labels and (a_label < 0 or a_label >= size):
            continue
        best, best_j = np.inf, -1
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                for dz in range(-1, 2):
                    cx, cy, cz = cell[0] + dx, cell[1] + dy, cell[2] + dz
                    if cx < 0 or cy < 0 or cz < 0 or cx >= extent[0] or cy >= extent[1]:
                        continue
                    if cz >= extent[2]:
                        continue
                    key = (cx * extent[1] + cy) * extent[2] + cz
                    first = np.searchsorted(sorted_keys, key, side='left')
                    last = np.searchsorted(sorted_keys, key, side='right')
                    for at in range(first, last):
                        j = order[at]
                        d2 = (
                            (moved[i, 0] - target[j, 0]) ** 2
                            + (moved[i, 1] - target[j, 1]) ** 2
                            + (moved[i, 2] - target[j, 2]) ** 2
                        )
                        if d2 > limit:
                            continue
                        if use_labels:
                            b_label = target_labels[j]
                            if b_label < 0 or b_label >= size or not compatible[a_label, b_label]:
                                continue
                        total = 0.0
                        for k in range(dims):
                            diff = np.float64(source_descriptors[i, k]) - np.float64(
                                target_descriptors[j, k]
                            )
                            total += diff * diff
                        distance = np.sqrt(total)
                        if distance < best or (distance == best and j < best_j):
                            best, best_j = distance, j
        if best_j >= 0:
            out_i[found], out_j[found], out_d[found] = i, best_j, np.float32(best)
            found += 1
    return out_i[:found], out_j[:found], out_d[:found]


@jit
def bev_local_peaks(
    correlation: np.ndarray, to_grid_order: np.ndarray, to_shift_order: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """
    Return the best ``k`` local maxima of every yaw's correlation (``Correlator.peaks``).

    ``correlation`` ``(Y, w, w)`` float32 over the reachable shifts in grid order;
    ``to_shift_order`` lists the grid rows in ascending shift, ``to_grid_order`` is its
    inverse. A cell is a local maximum when no neighbour of its 3x3 block in shift order
    (nothing beyond the block) is larger, as ``ndimage.maximum_filter(..., cval=-inf)``.
    Per yaw, the largest values first; equal values by ascending grid cell ``u * w + v``.
    Returns ``(yaw row, u, v, value)`` of every kept peak, yaw by yaw.
    """
    count, width = correlation.shape[0], correlation.shape[1]
    out_y = np.empty(count * k, dtype=np.int64)
    out_u = np.empty(count * k, dtype=np.int64)
    out_v = np.empty(count * k, dtype=np.int64)
    out_value = np.empty(count * k, dtype=np.float32)
    top_value = np.empty(k, dtype=np.float32)
    top_cell = np.empty(k, dtype=np.int64)
    found = 0
    for y in range(count):
        kept = 0
        for u in range(width):
            a = to_grid_order[u]
            for v in range(width):
                b = to_grid_order[v]
                value = correlation[y, u, v]
                if kept == k and not value > top_value[k - 1]:
                    continue  # not among the best k: whether it is a peak cannot matter
                peak = True
                for da in range(-1, 2):
                    na = a + da
                    if na < 0 or na >= width:
                        continue
                    row = to_shift_order[na]
                    for db in range(-1, 2):
                        nb = b + db
                        if nb < 0 or nb >= width or (da == 0 and db == 0):
                            continue
                        if correlation[y, row, to_shift_order[nb]] > value:
                            peak = False
                            break
                    if not peak:
                        break
                if not peak:
                    continue
                at = min(kept, k - 1)  # the slot after every kept value >= this one
                while at > 0 and top_value[at - 1] < value:
                    if at < k:
                        top_value[at], top_cell[at] = top_value[at - 1], top_cell[at - 1]
                    at -= 1
                top_value[at], top_cell[at] = value, u * width + v
                kept = min(kept + 1, k)
        for r in range(kept):
            out_y[found], out_value[found] = y, top_value[r]
            out_u[found], out_v[found] = top_cell[r] // width, top_cell[r] % width
            found += 1
    return out_y[:found], out_u[:found], out_v[:found], out_value[:found]


@jit
def compatibility_upper(
    p: np.ndarray, q: np.ndarray, threshold: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    SC2-PCR's first-order compatibility (eq. 2) of the strict upper triangle, row by row.

    ``p``, ``q``: ``(3, K)`` centred source and target coordinates (float32 or float64),
    one row per axis. For ``i < j``, ``c_ij = | ||p_i - p_j|| - ||q_i - q_j|| |`` from the
    differences (exact to the dtype's rounding of the difference, whatever the extent);
    the entries with ``c_ij < threshold`` are kept as ``max(1 - c_ij^2 / d^2, 1e-12)``.
    Returns ``(entries per row (K,), columns, values float32)`` in row-major order.
    """
    count = p.shape[1]
    px, py, pz, qx, qy, qz = p[0], p[1], p[2], q[0], q[1], q[2]
    limit = threshold
    scale = np.float32(1.0 / threshold)
    lengths = np.empty(count, dtype=p.dtype)
    per_row = np.zeros(count, dtype=np.int64)
    capacity = max(count * 16, 1024)
    columns = np.empty(capacity, dtype=np.int32)
    values = np.empty(capacity, dtype=np.float32)
    size = 0
    for i in range(count):
        ax, ay, az, bx, by, bz = px[i], py[i], pz[i], qx[i], qy[i], qz[i]
        width = count - i - 1
        for k in range(width):  # vectorised by the compiler: no branch, no reduction
            j = i + 1 + k
            dx, dy, dz = px[j] - ax, py[j] - ay, pz[j] - az
            ex, ey, ez = qx[j] - bx, qy[j] - by, qz[j] - bz
            lengths[k] = abs(
                np.sqrt(dx * dx + dy * dy + dz * dz) - np.sqrt(ex * ex + ey * ey + ez * ez)
            )
        found = 0
        for k in range(width):
            if lengths[k] < limit:
                found += 1
        if size + found > capacity:
            while size + found > capacity:
                capacity *= 2
            grown_columns = np.empty(capacity, dtype=np.int32)
            grown_columns[:size] = columns[:size]
            columns = grown_columns
            grown_values = np.empty(capacity, dtype=np.float32)
            grown_values[:size] = values[:size]
            values = grown_values
        for k in range(width):
            if lengths[k] < limit:
                ratio = np.float32(lengths[k]) * scale
                columns[size] = i + 1 + k
                values[size] = max(np.float32(1.0) - ratio * ratio, np.float32(1e-12))
                size += 1
        per_row[i] = found
    return per_row, columns[:size], values[:size]


@jit
def seen_through(
    points: np.ndarray,
    on: np.ndarray,
    nearest: np.ndarray,
    bin_rad: float,
    min_elevation: float,
    margin: float,
) -> np.ndarray:
    """
    ``(M,)`` whether each of ``points`` ``(M, 3)`` not ``on`` lies seen through a range image.

    ``nearest`` ``(A, E)``: the image's nearest range per (azimuth, elevation) bin of
    ``bin_rad``, elevation bins from ``min_elevation``
    (``core/estimation/covisibility.py:RangeImage``). Seen through: in a bin inside the
    image with a finite nearest range, nearer than it by more than ``margin``.
    """
    count = points.shape[0]
    rows, cols = nearest.shape
    out = np.zeros(count, dtype=np.bool_)
    for i in range(count):
        if on[i]:
            continue
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        distance = np.sqrt(x * x + y * y + z * z)
        elevation = np.arcsin(min(max(z / max(distance, 1e-9), -1.0), 1.0))
        e = np.int64(np.floor((elevation - min_elevation) / bin_rad))
        if e < 0 or e >= cols:
            continue
        a = min(np.int64((np.arctan2(y, x) + np.pi) / bin_rad), rows - 1)
        surface = nearest[a, e]
        out[i] = np.isfinite(surface) and distance < surface - margin
    return out


@jit
def bev_channel_sums(spectrum: np.ndarray, targets: np.ndarray, slot: np.ndarray) -> np.ndarray:
    """
    ``sum_c conj(S_bc) T_qc`` of ``B`` source spectra against ``Q`` target spectra, fused.

    ``spectrum`` ``(B, C, s, 2 h)`` and ``targets`` ``(Q, C, s, 2 h)``: complex64 spectra
    seen as float32 (real, imaginary); ``slot`` ``(B, Q)``: where each wanted sum goes
    (-1: not wanted; the slots ``0 .. n - 1`` each once). Returns ``(n, s, 2 h)`` float32
    (a complex64 view). Row by row, each row of a source spectrum is read once for every
    target; the products in the same channel order as ``Correlator._turned_sums``'s NumPy
    reference (the same sums up to rounding), in a loop over real numbers that the
    compiler vectorises.
    """
    count, channels, size, width = spectrum.shape
    quarters = targets.shape[0]
    out = np.empty((slot.max() + 1, size, width), dtype=np.float32)
    cells = width // 2
    for b in range(count):
        for row in range(size):
            for q in range(quarters):
                if slot[b, q] < 0:
                    continue
                total = out[slot[b, q], row]
                for c in range(channels):
                    source, target = spectrum[b, c, row], targets[q, c, row]
                    if c == 0:
                        for cell in range(cells):  # unit stride: vectorised
                            re, im = source[2 * cell], source[2 * cell + 1]
                            t_re, t_im = target[2 * cell], target[2 * cell + 1]
                            total[2 * cell] = re * t_re + im * t_im
                            total[2 * cell + 1] = re * t_im - im * t_re
                    else:
                        for cell in range(cells):
                            re, im = source[2 * cell], source[2 * cell + 1]
                            t_re, t_im = target[2 * cell], target[2 * cell + 1]
                            total[2 * cell] += re * t_re + im * t_im
                            total[2 * cell + 1] += re * t_im - im * t_re
    return out
