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


"""Correspondence RANSAC baseline (Open3D), an alternative to SC2-PCR."""

from __future__ import annotations

import time

from mlsemreg_ros.core.estimation.config import EstimatorConfig
from mlsemreg_ros.core.results import EstimateResult
from mlsemreg_ros.core.rigid import apply_transform
import numpy as np

#: Open3D's pruning of 3-samples: edge-length ratio and point distance checks.
EDGE_LENGTH_SIMILARITY = 0.9


def ransac(src: np.ndarray, dst: np.ndarray, config: EstimatorConfig) -> EstimateResult:
    """
    Estimate ``T_dst_src`` with Open3D's ``registration_ransac_based_on_correspondence``.

    Point-to-point estimation from 3-samples, inlier distance
    ``config.inlier_threshold``, at most ``config.ransac_iterations`` iterations
    with confidence ``config.ransac_confidence``; samples are pruned by the
    edge-length checker (0.9) and the distance checker (``inlier_threshold``).
    Open3D draws samples from its own global RNG (``open3d.utility.random.seed``).

    - ``src``: ``(K, 3)`` source points of the correspondences, metres.
    - ``dst``: ``(K, 3)`` target points, row ``i`` matched to ``src[i]``.
    - ``config``: estimator settings.

    Returns the transform, ``inlier_mask = residual < inlier_threshold`` and diagnostics
    (``ransac_fitness``, ``ransac_inlier_rmse``, ``ransac_ms``).
    """
    import open3d as o3d  # heavy import, only for this baseline

    start = time.perf_counter()
    src = np.asarray(src, dtype=np.float64).reshape(-1, 3)
    dst = np.asarray(dst, dtype=np.float64).reshape(-1, 3)
    if src.shape != dst.shape:
        raise ValueError(f'src and dst must have the same shape, got {src.shape}, {dst.shape}')
    total = src.shape[0]
    rows = np.flatnonzero(np.isfinite(src).all(axis=1) & np.isfinite(dst).all(axis=1))
    diagnostics: dict = {'n_correspondences': total}
    if rows.size < 3:
        diagnostics['message'] = f'ransac needs at least 3 finite correspondences, got {rows.size}'
        return EstimateResult(np.eye(4), np.zeros(total, dtype=bool), diagnostics)
    registration = o3d.pipelines.registration
    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(src[rows]))
    target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(dst[rows]))
    pairs = np.repeat(np.arange(rows.size, dtype=np.int32)[:, None], 2, axis=1)
    result = registration.registration_ransac_based_on_correspondence(
        source,
        target,
        o3d.utility.Vector2iVector(pairs),
        config.inlier_threshold,
        registration.TransformationEstimationPointToPoint(False),
        3,
        [
            registration.CorrespondenceCheckerBasedOnEdgeLength(EDGE_LENGTH_SIMILARITY),
            registration.CorrespondenceCheckerBasedOnDistance(config.inlier_threshold),
        ],
        registration.RANSACConvergenceCriteria(config.ransac_iterations, config.ransac_confidence),
    )
    transform = np.array(result.transformation, dtype=np.float64)
    if not np.isfinite(transform).all():
        transform = np.eye(4)
    residual = np.linalg.norm(apply_transform(transform, src[rows]) - dst[rows], axis=1)
    inlier_mask = np.zeros(total, dtype=bool)
    inlier_mask[rows] = residual < config.inlier_threshold
    diagnostics.update(
        ransac_fitness=float(result.fitness),
        ransac_inlier_rmse=float(result.inlier_rmse),
        ransac_ms=1e3 * (time.perf_counter() - start),
    )
    return EstimateResult(transform, inlier_mask, diagnostics)
