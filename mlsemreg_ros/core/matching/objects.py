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
Objects of a scan for long-range matching: clusters of labeled points with their extents.

At 60 m two scans share few keypoint neighbourhoods, but the same poles, trunks, signs,
parked cars and building corners are seen from both ends (Segregator, Yin et al. 2023;
G3Reg, Qiao et al. 2024). An object is a connected cluster (xy distance below its group's
``cluster_radius``) of the points of one *group* of classes, with:

- its centroid ``(x, y, z)`` (in the levelled frame: :mod:`mlsemreg_ros.core.features.levelling`),
- its extent: the square roots of the two eigenvalues of its xy covariance (the semi-axes
  of G3Reg's ellipse), and its height span.

Groups (``objects.groups``): ``pole`` (pole, traffic-sign: a sign is on a pole), ``trunk``,
``vehicle`` (car, truck, other-vehicle) and ``building``. Clusters of a building are cut
along the facade at ``objects.building_segment`` metres, each piece an object. Clusters
larger than a group's ``max_extent`` (a row of parked cars merged, a hedge of trunks) are
left out: their centroid moves with the view.

:func:`object_correspondences` pairs every source object with every target object of its
group whose extents are compatible (the larger semi-axis within ``extent_ratio``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

#: Groups of classes clustered into objects: (name, classes, cluster radius m,
#: min points, max semi-axis m). Class names of the label map; missing ones are skipped.
OBJECT_GROUPS: tuple[tuple[str, tuple[str, ...], float, int, float], ...] = (
    ('pole', ('pole', 'traffic-sign'), 0.5, 3, 1.0),
    ('trunk', ('trunk',), 0.5, 3, 1.0),
    ('vehicle', ('car', 'truck', 'other-vehicle'), 0.8, 8, 3.0),
    ('building', ('building',), 1.0, 10, 6.0),
)


@dataclass(frozen=True)
class Objects:
    """The objects of one scan: centroids, groups and extents (rows match)."""

    centroids: np.ndarray  # (Z, 3) float64, levelled frame when levelled
    groups: np.ndarray  # (Z,) int64: index into OBJECT_GROUPS
    axes: np.ndarray  # (Z, 2) float64: semi-axes of the xy ellipse (major, minor), m
    heights: np.ndarray  # (Z,) float64: z span, m
    sizes: np.ndarray  # (Z,) int64: points

    @classmethod
    def empty(cls) -> Objects:
        """No object."""
        return cls(
            np.zeros((0, 3)),
            np.zeros(0, dtype=np.int64),
            np.zeros((0, 2)),
            np.zeros(0),
            np.zeros(0, dtype=np.int64),
        )

    def __len__(self) -> int:
        return int(self.groups.shape[0])


def group_ids(names: tuple[str, ...]) -> list[np.ndarray]:
    """Learning ids of each group of :data:`OBJECT_GROUPS` (``names``: the label map's)."""
    return [
        np.array([names.index(c) for c in classes if c in names], dtype=np.int64)
        for _, classes, _, _, _ in OBJECT_GROUPS
    ]


def extract_objects(
    points: np.ndarray,
    labels: np.ndarray,
    ids_per_group: list[np.ndarray],
    building_segment: float,
    max_range: float,
) -> Objects:
    """
    Cluster each group's points into objects (module docstring).

    ``points`` (N, 3) (levelled), ``labels`` (N,) learning ids, ``ids_per_group`` from
    :func:`group_ids`; points farther than ``max_range`` (xy) are left out.
    """
    points = np.asarray(points, dtype=np.float64)
    inside = np.einsum('ij,ij->i', points[:, :2], points[:, :2]) <= max_range**2
    parts = []
    for group, (ids, spec) in enumerate(zip(ids_per_group, OBJECT_GROUPS, strict=True)):
        _, _, radius, min_points, max_axis = spec
        pts = points[inside & np.isin(labels, ids)]
        if len(pts) < min_points:
            continue
        component = _clusters(pts[:, :2], radius)
        if spec[0] == 'building' and building_segment > 0:
            component = _cut_along(pts[:, :2], component, building_segment)
        parts.append(_describe(pts, component, group, min_points, max_axis))
    if not parts:
        return Objects.empty()
    return Objects(*(np.concatenate(arrays) for arrays in zip(*parts, strict=True)))


def _clusters(xy: np.ndarray, radius: float) -> np.ndarray:
    """Label the connected components of the xy points closer than ``radius``: (n,) labels."""
    edges = cKDTree(xy).query_pairs(radius, output_type='ndarray')
    graph = sp.coo_matrix(
        (np.ones(len(edges), dtype=np.int8), (edges[:, 0], edges[:, 1])),
        shape=(len(xy), len(xy)),
    )
    return connected_components(graph, directed=False)[1]


def _cut_along(xy: np.ndarray, component: np.ndarray, length: float) -> np.ndarray:
    """
    Cut each cluster into pieces ``length`` long along its major axis, from its ends.

    The pieces are counted from both ends inwards, so that an end (a corner) keeps its
    piece whatever is seen of the other end.
    """
    count = int(component.max()) + 1
    size = np.bincount(component, minlength=count).astype(np.float64)
    mean = np.stack([np.bincount(component, xy[:, k], count) for k in range(2)], 1) / size[:, None]
    centred = xy - mean[component]
    cov = np.zeros((count, 2, 2))
    for a in range(2):
        for b in range(2):
            cov[:, a, b] = np.bincount(component, centred[:, a] * centred[:, b], count) / size
    major = np.linalg.eigh(cov)[1][:, :, 1]  # (count, 2)
    along = np.einsum('ij,ij->i', centred, major[component])
    low = np.full(count, np.inf)
    high = np.full(count, -np.inf)
    np.minimum.at(low, component, along)
    np.maximum.at(high, component, along)
    from_low = along - low[component]
    from_high = high[component] - along
    # pieces from the nearer end: the first half of a cluster counts from its low end
    half = from_low <= from_high
    piece = np.where(half, np.floor(from_low / length), -1 - np.floor(from_high / length))
    _, relabelled = np.unique(np.column_stack([component, piece]), axis=0, return_inverse=True)
    return relabelled.ravel()


def _describe(
    pts: np.ndarray, component: np.ndarray, group: int, min_points: int, max_axis: float
) -> tuple[np.ndarray, ...]:
    """Centroid, semi-axes, height span and size of every kept cluster."""
    count = int(component.max()) + 1
    size = np.bincount(component, minlength=count)
    mean = np.stack([np.bincount(component, pts[:, k], count) for k in range(3)], 1)
    mean /= np.maximum(size, 1)[:, None]
    centred = pts[:, :2] - mean[component, :2]
    cov = np.zeros((count, 2, 2))
    for a in range(2):
        for b in range(2):
            cov[:, a, b] = np.bincount(component, centred[:, a] * centred[:, b], count)
    cov /= np.maximum(size, 1)[:, None, None]
    axes = np.sqrt(np.maximum(np.linalg.eigvalsh(cov)[:, ::-1], 0.0))
    top = np.full(count, -np.inf)
    bottom = np.full(count, np.inf)
    np.maximum.at(top, component, pts[:, 2])
    np.minimum.at(bottom, component, pts[:, 2])
    keep = (size >= min_points) & (axes[:, 0] <= max_axis)
    return (
        mean[keep],
        np.full(int(keep.sum()), group, dtype=np.int64),
        axes[keep],
        (top - bottom)[keep],
        size[keep].astype(np.int64),
    )


def object_correspondences(
    source: Objects, target: Objects, extent_ratio: float
) -> tuple[np.ndarray, np.ndarray]:
    """
    Every source-target object pair of one group with compatible extents.

    Compatible: the major semi-axes within a factor ``extent_ratio`` of each other
    (at least 0.3 m apart allowed: a pole's extent is mostly noise).
    Returns ``(source rows, target rows)``, (P,) int64 each.
    """
    same = source.groups[:, None] == target.groups[None, :]
    major_s, major_t = source.axes[:, 0][:, None], target.axes[:, 0][None, :]
    close = np.abs(major_s - major_t) <= np.maximum(
        0.3, (extent_ratio - 1.0) * np.minimum(major_s, major_t)
    )
    rows, cols = np.nonzero(same & close)
    return rows.astype(np.int64), cols.astype(np.int64)
