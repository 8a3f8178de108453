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
Start-up of the compiled kernels: compiled (first run) or loaded from the cache.

Above :mod:`mlsemreg_ros.core.features.kernels` (which ``fpfh`` and ``features`` import), so that
module imports neither of them back.
"""

from __future__ import annotations

import time

from mlsemreg_ros.core.alignment import sweep_kernels
from mlsemreg_ros.core.features import fpfh, kernels
from mlsemreg_ros.core.features.cell_grid import CellGrid
from mlsemreg_ros.core.features.features import voxel_downsample
import numpy as np


def warm_up() -> dict[str, float]:
    """
    Compile or load from the cache every kernel, on a tiny cloud; return ms per step.

    Call it once at start-up (e.g. the node before its first scan) so the first frame
    does not pay the JIT. Without numba (or with ``MLSEMREG_KERNELS=numpy``) it
    returns ``{}``. Keys: ``voxel_ms``, ``fpfh_ms`` (both FPFH variants), ``deskew_ms``
    (constant and piecewise), ``sweep_ms`` (the sweep alignment's normal equations and
    its one-pass linearization), ``labels_ms`` (the geometric labeler's kernels, on a
    scene of ground, a pole and a box), ``total_ms``.
    """
    if not kernels.enabled():
        return {}
    rng = np.random.default_rng(0)
    points = np.c_[rng.uniform(-2.0, 2.0, (200, 2)), rng.normal(0.0, 0.05, 200)]
    labels = rng.integers(0, 3, 200)
    timings: dict[str, float] = {}
    start = time.perf_counter()
    voxel_downsample(points, labels, 0.3, compiled=True)
    timings['voxel_ms'] = 1e3 * (time.perf_counter() - start)
    middle = time.perf_counter()
    indices = np.arange(0, 200, 7)
    fpfh.fpfh_at_keypoints(points, indices, 0.9, 1.5, 0.5, snap=True, compiled=True)
    fpfh.fpfh_at_keypoints(points, indices, 0.9, 1.5, 0.5, snap=False, compiled=True)
    end = time.perf_counter()
    timings['fpfh_ms'] = 1e3 * (end - middle)
    axes = np.eye(3)
    times = np.linspace(0.0, 0.1, 200)
    segment = (times > 0.05).astype(np.int64)  # two segments of a piecewise (gyro) motion
    twists = (np.array([0.0, 0.05]), axes[:2], np.ones(2), axes[1:], axes[:2], axes[1:])
    two = kernels.SegmentRows.of(*twists, np.stack([axes, axes]), axes[:2])
    kernels.deskew_piecewise_points(points, times, segment, two, 1e-6)
    deskewed = time.perf_counter()
    timings['deskew_ms'] = 1e3 * (deskewed - end)
    covariances = np.broadcast_to(np.eye(3), (200, 3, 3))
    sweep_kernels.normal_equations(points, times, points, covariances, axes, 0.01, 1.0)
    map_covariances = np.tile(np.eye(4), (200, 1, 1))[:, :3, :3]  # as the local map gives
    terms = (axes[0], 1.0, axes[2], axes[1], axes[0])
    cells = CellGrid.build(points, 1.0)
    cells.nearest(points, 0.6)  # the dense scores' call
    local_map = sweep_kernels.SweepMap.of(cells, points, map_covariances, 1.0, 0.01)
    sweep_kernels.sweep_linearization(points, times, terms, 1e-6, np.eye(4), local_map, 1.0)
    swept = time.perf_counter()
    timings['sweep_ms'] = 1e3 * (swept - deskewed)
    _warm_labeler(rng)
    timings['labels_ms'] = 1e3 * (time.perf_counter() - swept)
    timings['total_ms'] = 1e3 * (time.perf_counter() - start)
    return timings


def _warm_labeler(rng: np.random.Generator) -> None:
    """Run the geometric labeler on ground, a pole and a box, and its support counts."""
    from mlsemreg_ros.core.labeling import geometric_kernels
    from mlsemreg_ros.core.labeling.geometric import GeometricLabeler

    ground = np.c_[rng.uniform(-10.0, 10.0, (2000, 2)), rng.normal(-1.8, 0.01, 2000)]
    pole = np.c_[np.full(40, 4.0), np.zeros(40), np.linspace(-1.7, 3.0, 40)]
    box = np.c_[
        rng.uniform(-6.0, -2.0, 300), rng.uniform(2.0, 3.8, 300), rng.uniform(-1.5, -0.3, 300)
    ]
    GeometricLabeler().label(np.concatenate([ground, pole, box]))
    cells = CellGrid.build(pole, 0.6)  # the support test runs only when objects are found
    rows = np.arange(pole.shape[0])
    labels = np.ones(pole.shape[0], dtype=np.uint32)
    geometric_kernels.support_counts(pole, rows, labels, labels > 0, 0.6, cells)
    keys = np.arange(5, dtype=np.int64)
    geometric_kernels.window_sum(keys, 3, np.ones(5), 1)
