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
Guided re-matching: correspondences searched only near a pose hypothesis (docs/hard_pairs.md).

Scans 40-60 m apart share a small part of their keypoints; among thousands of global
nearest-neighbour matches, the few true ones do not form the densest compatible clique,
and SC2-PCR seeds elsewhere (on dev pair 000007 it never seeds where the true inliers are).
A pose hypothesis that does not come from the correspondences (the BEV search's peaks,
core/estimation/bev_search.py) says where each source keypoint should land: matching it only among
the target keypoints within ``radius`` of that place (and of a compatible label) keeps
the true matches and drops most false ones. SC2-PCR then runs again on them.
"""

from __future__ import annotations

from mlsemreg_ros.core.estimation import kernels
from mlsemreg_ros.core.estimation.verification import LabelCompatibility
from mlsemreg_ros.core.features.kernels import use_compiled
from mlsemreg_ros.core.results import Correspondences, PreparedScan
import numpy as np
from scipy.spatial import cKDTree


def guided_correspondences(
    source: PreparedScan,
    target: PreparedScan,
    T_target_source: np.ndarray,
    radius: float,
    labels: LabelCompatibility | None = None,
    compiled: bool | None = None,
) -> Correspondences:
    """
    Match every source keypoint only near where ``T_target_source`` puts it.

    Its correspondence is the nearest target keypoint in descriptor space among those
    within ``radius`` (m) of that place.

    ``labels``: when given, only keypoints whose labels (of their scan points) are equal or
    compatible are matched. Source keypoints without a candidate get no correspondence.
    """
    empty = Correspondences(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if len(source.keypoints) == 0 or len(target.keypoints) == 0:
        return empty
    T = np.asarray(T_target_source, dtype=np.float64)
    moved = source.keypoints @ T[:3, :3].T + T[:3, 3]
    if use_compiled(compiled):
        return _compiled(moved, source, target, radius, labels)
    near = cKDTree(moved).sparse_distance_matrix(
        cKDTree(target.keypoints), radius, output_type='ndarray'
    )
    i, j = near['i'].astype(np.int64), near['j'].astype(np.int64)
    if labels is not None and i.size:
        a = np.asarray(source.labels, dtype=np.int64)[source.keypoint_indices[i]]
        b = np.asarray(target.labels, dtype=np.int64)[target.keypoint_indices[j]]
        size = labels.compatible.shape[0]
        inside = (a >= 0) & (a < size) & (b >= 0) & (b < size)
        keep = inside & labels.compatible[np.where(inside, a, 0), np.where(inside, b, 0)]
        i, j = i[keep], j[keep]
    if i.size == 0:
        return empty
    distance = np.linalg.norm(
        source.descriptors[i].astype(np.float32) - target.descriptors[j].astype(np.float32),
        axis=1,
    )
    order = np.lexsort((distance, i))  # by source keypoint, best descriptor first
    first = order[np.unique(i[order], return_index=True)[1]]
    return Correspondences(i[first], j[first], distance[first].astype(np.float64))


def _compiled(
    moved: np.ndarray,
    source: PreparedScan,
    target: PreparedScan,
    radius: float,
    labels: LabelCompatibility | None,
) -> Correspondences:
    """:func:`guided_correspondences` by the compiled kernel."""
    if labels is not None:
        source_labels = np.asarray(source.labels, dtype=np.int64)[source.keypoint_indices]
        target_labels = np.asarray(target.labels, dtype=np.int64)[target.keypoint_indices]
        compatible = np.asarray(labels.compatible) > 0
    else:
        source_labels = np.zeros(len(moved), dtype=np.int64)
        target_labels = np.zeros(len(target.keypoints), dtype=np.int64)
        compatible = np.ones((1, 1), dtype=bool)
    i, j, distance = kernels.nearest_in_descriptor_space(
        np.ascontiguousarray(moved, dtype=np.float64),
        np.ascontiguousarray(target.keypoints, dtype=np.float64),
        float(radius),
        np.ascontiguousarray(source.descriptors, dtype=np.float32),
        np.ascontiguousarray(target.descriptors, dtype=np.float32),
        np.ascontiguousarray(source_labels),
        np.ascontiguousarray(target_labels),
        np.ascontiguousarray(compatible),
        labels is not None,
    )
    return Correspondences(i, j, distance.astype(np.float64))
