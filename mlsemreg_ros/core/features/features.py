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
Preprocessing and local geometric descriptors.

Voxel downsampling with majority labels, keypoint sampling (random as in the
paper, or spatially uniform voxel sampling), FPFH (Rusu et al., ICRA 2009)
computed at the keypoints only, and the validity mask that drops keypoints
whose descriptor is NaN (GEDI) or all zero (FPFH of an isolated point).
All functions are vectorized; none loops over points in Python. The voxel
functions take ``compiled``: None uses the numba kernels of
:mod:`mlsemreg_ros.core.features.kernels` when available, False the NumPy code (the
reference); both give the same voxels, order, centroids and labels.
"""

from __future__ import annotations

from mlsemreg_ros.core.features import kernels
import numpy as np

#: Voxel keys at or beyond this magnitude are grouped by their float values (no int64 keys).
_MAX_EXACT_KEY = 2.0**40


def voxel_groups(
    points: np.ndarray, voxel_size: float, compiled: bool | None = None
) -> tuple[np.ndarray, int]:
    """
    Voxel id of every point: ``(inverse (N,) int64, number of occupied voxels)``.

    Voxels are numbered in lexicographic order of their integer (x, y, z) keys. Points
    must be finite (ValueError otherwise;
    :func:`~mlsemreg_ros.core.features.scan_input.sanitize_scan`
    drops the others); keys beyond the exact integer range of float64 (a point at 1e30)
    are grouped exactly by their float keys, so one absurd point cannot merge the others.
    """
    if points.shape[0] == 0:
        return np.zeros(0, dtype=np.int64), 0
    reach = float(np.abs(points).max()) / voxel_size  # NaN/inf propagate
    if not np.isfinite(reach):
        raise ValueError('voxel_groups needs finite points (sanitize_scan drops the others)')
    if reach >= _MAX_EXACT_KEY:  # int64 keys and their extents could overflow: exact path
        _, inverse = np.unique(np.floor(points / voxel_size), axis=0, return_inverse=True)
        inverse = inverse.reshape(-1).astype(np.int64)
        return inverse, int(inverse.max()) + 1
    if kernels.use_compiled(compiled):
        grid = kernels.voxel_grid(points, voxel_size)
        if grid is not None:
            return grid[0], grid[2].shape[0]
    keys = np.floor(points / voxel_size).astype(np.int64)
    keys -= keys.min(axis=0)
    extent = keys.max(axis=0) + 1
    if float(np.prod(extent.astype(np.float64))) < 2.0**62:
        linear = (keys[:, 0] * extent[1] + keys[:, 1]) * extent[2] + keys[:, 2]
        order = np.argsort(linear)
        ordered = linear[order]
        starts = np.empty(ordered.shape[0], dtype=np.int64)
        starts[0] = 0
        np.cumsum(ordered[1:] != ordered[:-1], out=starts[1:])
        inverse = np.empty_like(starts)
        inverse[order] = starts  # = np.unique(linear, return_inverse=True)[1], cheaper
        return inverse, int(starts[-1]) + 1
    else:  # absurd extents: fall back to row-wise unique (slower, no overflow)
        _, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1).astype(np.int64)
    return inverse, int(inverse.max()) + 1


def voxel_centroids(
    points: np.ndarray, voxel_size: float, compiled: bool | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """
    Centroids of the occupied voxels: ``(centroids (V, 3) float64, voxel of each point (N,))``.

    Voxels in the order of :func:`voxel_groups`.
    """
    if points.shape[0] and kernels.use_compiled(compiled):
        grid = kernels.voxel_grid(points, voxel_size)
        if grid is not None:
            inverse, sums, sizes = grid
            return sums / sizes.astype(np.float64)[:, None], inverse
    inverse, count = voxel_groups(points, voxel_size, compiled=False)
    sizes = np.bincount(inverse, minlength=count).astype(np.float64)
    centroids = (
        np.stack(
            [np.bincount(inverse, weights=points[:, k], minlength=count) for k in range(3)], axis=1
        )
        / sizes[:, None]
    )
    return centroids, inverse


def voxel_downsample(
    points: np.ndarray, labels: np.ndarray, voxel_size: float, compiled: bool | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """
    One point per occupied voxel: the voxel centroid with the voxel's majority label.

    - ``points``: (N, 3) float64 scan, metres.
    - ``labels``: (N,) integer labels (learning ids).
    - ``voxel_size``: voxel edge length in metres; ``<= 0`` returns the input unchanged.

    Returns ``(points (V, 3) float64, labels (V,) int32)``, voxels in lexicographic order of
    their integer keys. Label ties go to the smallest label id. ``compiled``: see the
    module docstring (the compiled path also counts the majority in one loop).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    labels = np.asarray(labels).reshape(-1)
    if labels.shape[0] != points.shape[0]:
        raise ValueError(f'{points.shape[0]} points but {labels.shape[0]} labels')
    if voxel_size <= 0 or points.shape[0] == 0:
        return points, labels.astype(np.int32)
    compiled = kernels.use_compiled(compiled)
    centroids, inverse = voxel_centroids(points, voxel_size, compiled=compiled)
    return centroids, voxel_majority(inverse, centroids.shape[0], labels, compiled)


def voxel_majority(
    inverse: np.ndarray, count: int, labels: np.ndarray, compiled: bool | None = None
) -> np.ndarray:
    """
    Return the majority label of each of ``count`` voxels: (count,) int32, smallest id on ties.

    ``inverse`` (N,) is each point's voxel (:func:`voxel_centroids`), ``labels`` (N,) its
    label. :func:`voxel_downsample`'s labels; the odometry calls it alone when a scan's
    labels arrive after its points were voxelized (core/deferred.py).
    """
    labels = np.asarray(labels).reshape(-1)
    compiled = kernels.use_compiled(compiled)
    # A dense (voxel, label) count table when the ids are small, as learning ids are;
    # else count the distinct pairs.
    label_ids, label_inverse = _small_unique(labels)
    if count * len(label_ids) <= 64 * labels.shape[0]:
        if compiled:
            winner = kernels.majority(inverse, label_inverse, count, len(label_ids))
            return label_ids[winner].astype(np.int32)
        table = np.bincount(
            inverse * len(label_ids) + label_inverse, minlength=count * len(label_ids)
        ).reshape(count, len(label_ids))
        return label_ids[table.argmax(axis=1)].astype(np.int32)
    pair = inverse * len(label_ids) + label_inverse
    pairs, pair_counts = np.unique(pair, return_counts=True)
    pair_voxel, pair_label = np.divmod(pairs, len(label_ids))
    # Sort by voxel, then count descending, then label ascending; first row per voxel wins.
    order = np.lexsort((pair_label, -pair_counts, pair_voxel))
    first = np.ones(order.shape[0], dtype=bool)
    first[1:] = pair_voxel[order][1:] != pair_voxel[order][:-1]
    winners = order[first]
    return label_ids[pair_label[winners]].astype(np.int32)


def _small_unique(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(values, return_inverse=True)``, by a lookup table for small non-negative ids."""
    if values.size and values.dtype.kind in 'iu' and 0 <= values.min() and values.max() < 65536:
        present = np.bincount(values) > 0
        ids = np.flatnonzero(present)
        lookup = np.cumsum(present) - 1
        return ids.astype(values.dtype), lookup[values]
    ids, inverse = np.unique(values, return_inverse=True)
    return ids, inverse.reshape(-1)


def sample_keypoints(
    points: np.ndarray, count: int, sampling: str, voxel_size: float, seed: int
) -> np.ndarray:
    """
    Pick at most ``count`` keypoints among ``points``; return their row indices.

    ``random``: a seeded uniform draw without replacement (as in the paper); all points
    when there are no more than ``count``. ``voxel``: the point nearest to the centroid
    of every occupied keypoint voxel (edge ``voxel_size`` m), which spreads keypoints
    evenly in space; if there are more than ``count`` voxels, a seeded random subset.

    - ``points``: (N, 3) float64, metres.
    - ``count``: maximum number of keypoints.
    - ``sampling``: ``'random'`` or ``'voxel'``.
    - ``voxel_size``: keypoint voxel edge in metres (``voxel`` sampling only).
    - ``seed``: seed of ``numpy.random.default_rng``.

    Returns (M,) int64 sorted row indices into ``points``, ``M <= count``.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = points.shape[0]
    rng = np.random.default_rng(seed)
    if sampling == 'random':
        candidates = np.arange(n, dtype=np.int64)
    elif sampling == 'voxel':
        if n == 0:
            return np.zeros(0, dtype=np.int64)
        if voxel_size <= 0:
            raise ValueError(f'voxel keypoint sampling needs voxel_size > 0, got {voxel_size}')
        centroids, inverse = voxel_centroids(points, voxel_size)
        dist = np.linalg.norm(points - centroids[inverse], axis=1)
        order = np.lexsort((np.arange(n), dist, inverse))
        first = np.ones(n, dtype=bool)
        first[1:] = inverse[order][1:] != inverse[order][:-1]
        candidates = np.sort(order[first]).astype(np.int64)
    else:
        raise ValueError(f"unknown keypoint sampling {sampling!r}; use 'random' or 'voxel'")
    if candidates.shape[0] <= count:
        return candidates
    chosen = rng.choice(candidates.shape[0], size=count, replace=False)
    return candidates[np.sort(chosen)]


def fpfh_open3d_at(
    points: np.ndarray,
    indices: np.ndarray,
    normal_radius: float,
    normal_max_nn: int,
    feature_radius: float,
    feature_max_nn: int,
) -> np.ndarray:
    """
    FPFH descriptors (Rusu et al. 2009) of the scan points ``points[indices]``.

    Normals are estimated on the whole scan (hybrid radius/kNN search), and the
    histograms are computed only at the requested points with Open3D's
    ``compute_fpfh_feature(..., indices=...)``; the neighbourhoods still use every
    scan point, so each row equals the corresponding row of the full computation.
    Open3D returns the rows of the distinct indices in ascending order; this function
    maps them back, so row ``m`` always belongs to ``points[indices[m]]`` (unsorted and
    repeated indices are fine).

    - ``points``: (N, 3) float64 scan, metres.
    - ``indices``: (M,) int rows of ``points``.
    - ``normal_radius``: normal estimation radius, metres.
    - ``normal_max_nn``: maximum neighbours for normal estimation.
    - ``feature_radius``: FPFH neighbourhood radius, metres.
    - ``feature_max_nn``: maximum neighbours for FPFH.

    Returns (M, 33) float32; rows of isolated points are all zero
    (see :func:`valid_descriptor_mask`).
    """
    import open3d as o3d

    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    indices = np.asarray(indices, dtype=np.int64).reshape(-1)
    if indices.shape[0] == 0 or points.shape[0] == 0:
        return np.zeros((indices.shape[0], 33), dtype=np.float32)
    if indices.min() < 0 or indices.max() >= points.shape[0]:
        raise IndexError(f'keypoint indices must lie in [0, {points.shape[0] - 1}]')
    # Open3D 0.20 returns one column per *distinct* index in ascending order, whatever
    # the order of ``indices``: compute at the sorted unique rows, then scatter back.
    unique, inverse = np.unique(indices, return_inverse=True)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(
        o3d.geometry.KDTreeSearchParamHybrid(radius=normal_radius, max_nn=normal_max_nn)
    )
    feature = o3d.pipelines.registration.compute_fpfh_feature(
        cloud,
        o3d.geometry.KDTreeSearchParamHybrid(radius=feature_radius, max_nn=feature_max_nn),
        indices=o3d.utility.IntVector(unique.tolist()),
    )
    data = np.asarray(feature.data, dtype=np.float32).T
    if data.shape != (unique.shape[0], 33):
        raise RuntimeError(
            f'Open3D returned FPFH of shape {data.shape} for {unique.shape[0]} distinct keypoints'
        )
    return np.ascontiguousarray(data[inverse.reshape(-1)])


def valid_descriptor_mask(descriptors: np.ndarray) -> np.ndarray:
    """
    Rows that are usable descriptors: all finite and not all zero.

    GEDI arrays can hold NaN rows and FPFH gives all-zero rows for isolated points;
    either would attract matches (docs/definitions.md, pitfalls), so such keypoints are dropped.

    - ``descriptors``: (M, D) float.

    Returns (M,) bool.
    """
    d = np.asarray(descriptors)
    if d.ndim != 2:
        raise ValueError(f'descriptors must be (M, D), got shape {d.shape}')
    return np.all(np.isfinite(d), axis=1) & np.any(d != 0, axis=1)
