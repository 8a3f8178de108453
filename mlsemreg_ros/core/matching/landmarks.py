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
"""Landmarks for BMR-SS: Euclidean clusters of landmark-class points (Sec. 3.3, eq. 4)."""

from __future__ import annotations

from mlsemreg_ros.core.results import Landmarks
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


def extract_landmarks(
    points: np.ndarray,
    labels: np.ndarray,
    landmark_ids: np.ndarray,
    cluster_radius: float,
    min_points: int,
    min_share: float = 0.0,
    support_radius: float = 0.6,
) -> Landmarks:
    """
    Cluster the points of every landmark class; each cluster's centroid is a landmark.

    Clustering is Euclidean in the xy-plane (as the reference implementation): points of one
    class closer than ``cluster_radius`` (m) are connected; connected components with at
    least ``min_points`` points are landmarks, smaller ones are noise. All classes are
    clustered in one pass: class ids are spread along a third axis far apart, so no edge
    joins two classes.

    ``min_share > 0`` (``semantic.landmark_min_share``, beyond the paper): only
    *confidently labeled* points are clustered, those with at least that share of the scan
    points within ``support_radius`` (3-D, m) in their own class
    (:func:`confident_points`). A randomly mislabeled point on a wall has no support;
    without the test such points chain along facades into false landmarks.

    points (N, 3), labels (N,) learning ids -> Landmarks(centroids (Z, 3), classes (Z,)).
    """
    landmark_ids = np.asarray(landmark_ids, dtype=np.int64)
    select = np.isin(labels, landmark_ids)
    if min_share > 0.0 and select.any():
        select[select] = confident_points(points, labels, select, min_share, support_radius)
    pts, cls = points[select], labels[select].astype(np.int64)
    if len(pts) == 0:
        return Landmarks.empty()
    separated = np.column_stack([pts[:, :2], cls * (10.0 * cluster_radius + 1e3)])
    edges = cKDTree(separated).query_pairs(cluster_radius, output_type='ndarray')
    graph = sp.coo_matrix(
        (np.ones(len(edges), dtype=np.int8), (edges[:, 0], edges[:, 1])),
        shape=(len(pts), len(pts)),
    )
    count, component = connected_components(graph, directed=False)
    size = np.bincount(component, minlength=count)
    centroids = (
        np.column_stack(
            [np.bincount(component, weights=pts[:, k], minlength=count) for k in range(3)]
        )
        / size[:, None]
    )
    first = np.full(count, len(pts))
    np.minimum.at(first, component, np.arange(len(pts)))
    keep = size >= min_points
    return Landmarks(centroids[keep], cls[first[keep]])


def confident_points(
    points: np.ndarray,
    labels: np.ndarray,
    select: np.ndarray,
    min_share: float,
    radius: float,
) -> np.ndarray:
    """
    Which selected points have at least ``min_share`` of their neighbours in their class.

    Neighbours: the scan points within ``radius`` (the point itself included). Returns a
    bool array over ``points[select]``. Two counts per selected point: all points, and
    the points of its own class (classes spread far apart along a fourth axis, one tree).
    """
    query = points[select]
    total = cKDTree(points).query_ball_point(query, radius, return_length=True)
    own = labels[select].astype(np.float64)[:, None] * (10.0 * radius + 1e3)
    tagged = np.column_stack([query, own])
    same = cKDTree(tagged).query_ball_point(tagged, radius, return_length=True)
    return same >= min_share * total
