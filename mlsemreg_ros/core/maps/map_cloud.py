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

"""The map as one point cloud in the map frame: every keyframe moved by its pose, voxelised."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from mlsemreg_ros.core.features.features import voxel_downsample
import numpy as np


def map_cloud(keyframes: Iterable[Any], voxel_size: float) -> tuple[np.ndarray, np.ndarray]:
    """
    Return the map's points (V, 3) float64 in the map frame and their labels (V,) int32.

    ``keyframes``: objects with ``points`` (N, 3, sensor frame), ``labels`` (N,) and
    ``T_map_keyframe`` (4, 4), e.g. a :class:`~mlsemreg_ros.core.maps.keyframe_store.
    KeyframeStore`. One point per ``voxel_size`` voxel (the centroid, the majority label);
    ``voxel_size <= 0`` keeps every point.
    """
    clouds, labels = [], []
    for keyframe in keyframes:
        T = np.asarray(keyframe.T_map_keyframe, dtype=np.float64)
        clouds.append(np.asarray(keyframe.points, dtype=np.float64) @ T[:3, :3].T + T[:3, 3])
        labels.append(np.asarray(keyframe.labels).reshape(-1))
    if not clouds:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int32)
    return voxel_downsample(np.concatenate(clouds), np.concatenate(labels), voxel_size)
