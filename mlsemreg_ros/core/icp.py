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


"""Optional final refinement: point-to-plane ICP on the scans (Open3D)."""

from __future__ import annotations

from mlsemreg_ros.core.config import RefineConfig
import numpy as np

#: Neighbours used for the target normals.
NORMAL_MAX_NN = 30


def refine_icp(source_points: np.ndarray, target_points: np.ndarray, init: np.ndarray,
               config: RefineConfig, normal_radius: float) -> np.ndarray:
    """
    Refine ``T_target_source`` by point-to-plane ICP.

    Normals are estimated on the target (hybrid search, radius ``normal_radius``,
    at most 30 neighbours); correspondences farther than ``config.max_distance``
    are ignored; at most ``config.iterations`` iterations.

    - ``source_points``: ``(N, 3)`` source scan, metres.
    - ``target_points``: ``(M, 3)`` target scan, metres.
    - ``init``: ``(4, 4)`` initial ``T_target_source`` (e.g. from SC2-PCR).
    - ``config``: ICP settings.
    - ``normal_radius``: normal estimation radius in metres.

    Returns the refined ``(4, 4)`` transform, or ``init`` unchanged when ICP finds no
    correspondence (fitness 0), fails or returns a non-finite matrix.
    """
    import open3d as o3d  # heavy import, only when ICP is enabled

    init = np.asarray(init, dtype=np.float64)
    source_points = np.asarray(source_points, dtype=np.float64).reshape(-1, 3)
    target_points = np.asarray(target_points, dtype=np.float64).reshape(-1, 3)
    source_points = source_points[np.isfinite(source_points).all(axis=1)]
    target_points = target_points[np.isfinite(target_points).all(axis=1)]
    if source_points.shape[0] < 3 or target_points.shape[0] < 3:
        return init.copy()
    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source_points))
    target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(target_points))
    target.estimate_normals(
        o3d.geometry.KDTreeSearchParamHybrid(radius=normal_radius, max_nn=NORMAL_MAX_NN))
    registration = o3d.pipelines.registration
    try:
        result = registration.registration_icp(
            source, target, config.max_distance, init,
            registration.TransformationEstimationPointToPlane(),
            registration.ICPConvergenceCriteria(max_iteration=config.iterations))
    except RuntimeError:
        return init.copy()
    transform = np.array(result.transformation, dtype=np.float64)
    if result.fitness <= 0.0 or not np.isfinite(transform).all():
        return init.copy()
    return transform
