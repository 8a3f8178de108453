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
Object hypotheses: a 4-DoF pose from matched object centroids, by a consistency graph.

The scans are levelled first (:mod:`mlsemreg_ros.core.features.levelling`), so what is
left is ``(x, y, yaw)`` (the height is the ground's, 0 in both levelled frames). The
putative matches are every same-group object pair with compatible extents
(:func:`mlsemreg_ros.core.matching.objects.object_correspondences`).

**Consistency graph** (SC2-PCR eq. 2 with G3Reg's object bounds): two matches ``i, j``
are compatible when their centroid distances agree within a bound that grows with the
objects' extents, ``c_ij = | ||s_i - s_j|| - ||t_i - t_j|| | < b_ij``,
``b_ij = objects.distance_bound + a_i + a_j`` with ``a`` the major semi-axes of the two
objects of a match (a centroid of a partly seen object moves by up to its extent: G3Reg's
ellipsoid bound, Qiao et al. 2024, Sec. IV-B). The weight is SC2-PCR's
``1 - c^2 / b^2`` (graded like Segregator's graduated rule: a close agreement counts more).
Matches sharing an object are incompatible (one-to-one).

**Cliques**: the second-order scores ``SC2 = C o (C C)`` (SC2-PCR eq. 4) rank the matches;
from each of the best ``objects.seeds`` seeds a clique grows greedily among its
neighbours (highest SC2 with the seed first, kept when compatible with every member).
Each clique of at least ``objects.min_objects`` matches gives a weighted 2-D Procrustes
fit (weights ``1 / b_i^2``), refit once on every match within its bound; the poses are
ranked by their matches and the distinct best are returned.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core.matching.objects import Objects
from mlsemreg_ros.core.poses import distinct_hypotheses
from mlsemreg_ros.core.settings import param
import numpy as np


@dataclass
class ObjectsConfig:
    """The ``objects`` section: object hypotheses for pairs the points cannot register."""

    enabled: bool = param(
        False,
        "When the pose is refused or weak, match the scans' objects (poles, signs, trunks, "
        'vehicles, building segments) with a consistency graph and add their 4-DoF poses '
        'to the candidates the verification scores (core/estimation/object_registration.py).',
    )
    max_range: float = param(
        80.0,
        'Objects farther than this from the sensor (xy) are left out.',
        unit='m',
        low=5.0,
        high=500.0,
    )
    building_segment: float = param(
        4.0,
        'Building clusters are cut into pieces this long along the facade, counted from '
        'both ends (a corner keeps its piece); 0: whole clusters.',
        unit='m',
        low=0.0,
        high=100.0,
    )
    extent_ratio: float = param(
        2.0,
        'Two objects may match when their larger semi-axes are within this factor '
        '(or 0.3 m) of each other.',
        low=1.0,
        high=100.0,
    )
    distance_bound: float = param(
        0.6,
        "Base bound on the difference of two matches' centroid distances; the objects' "
        "semi-axes are added to it (G3Reg's ellipsoid bound).",
        unit='m',
        low=0.01,
        high=10.0,
    )
    extent_weight: float = param(
        0.5,
        "Share of the objects' semi-axes added to objects.distance_bound.",
        low=0.0,
        high=5.0,
    )
    max_matches: int = param(
        1500,
        'Most putative object matches in the graph (the closest extents first).',
        low=10,
        high=20000,
    )
    seeds: int = param(48, 'Cliques grown, from the best second-order scores.', low=1, high=10000)
    min_objects: int = param(
        4,
        'Fewest consistent object matches a pose needs to become a candidate.',
        low=2,
        high=1000,
    )
    hypotheses: int = param(
        8, 'Most distinct object poses handed to the verification.', low=1, high=1000
    )


@dataclass(frozen=True)
class ObjectPoses:
    """Object poses between the levelled frames, best first."""

    transforms: np.ndarray  # (H, 4, 4) T_levelledtarget_levelledsource
    matches: np.ndarray  # (H,) int64: consistent object matches of each
    diagnostics: dict[str, float]


def register_objects(
    source: Objects,
    target: Objects,
    rows: np.ndarray,
    cols: np.ndarray,
    config: ObjectsConfig,
) -> ObjectPoses:
    """Poses from the matches ``source[rows[k]] <-> target[cols[k]]`` (module docstring)."""
    diagnostics: dict[str, float] = {
        'objects_source': len(source),
        'objects_target': len(target),
        'objects_matches': len(rows),
    }
    none = ObjectPoses(np.zeros((0, 4, 4)), np.zeros(0, dtype=np.int64), diagnostics)
    if len(rows) < config.min_objects:
        return none
    if len(rows) > config.max_matches:
        gap = np.abs(source.axes[rows, 0] - target.axes[cols, 0])
        keep = np.sort(np.argsort(gap, kind='stable')[: config.max_matches])
        rows, cols = rows[keep], cols[keep]
    p = source.centroids[rows, :2]
    q = target.centroids[cols, :2]
    radius = config.extent_weight * (source.axes[rows, 0] + target.axes[cols, 0])
    bound = config.distance_bound + radius[:, None] + radius[None, :]
    gap = np.abs(_distances(p) - _distances(q))
    weight = np.maximum(1.0 - (gap / bound) ** 2, 0.0).astype(np.float32)
    weight[rows[:, None] == rows[None, :]] = 0.0  # one-to-one
    weight[cols[:, None] == cols[None, :]] = 0.0
    compatible = weight > 0
    hard = compatible.astype(np.float32)
    sc2 = weight * (hard @ hard)  # SC2-PCR eq. 4 on the graded graph
    ranked = np.argsort(-sc2.sum(axis=1), kind='stable')[: config.seeds]
    single = config.distance_bound + radius  # a match's own bound
    poses, counts = [], []
    for seed in ranked:
        clique = _grow_clique(int(seed), compatible, sc2[seed])
        if len(clique) < config.min_objects:
            continue
        pose = _procrustes_2d(p[clique], q[clique], 1.0 / single[clique] ** 2)
        residual = np.linalg.norm(p @ pose[:2, :2].T + pose[:2, 2] - q, axis=1)
        members = _one_to_one(np.flatnonzero(residual < single), residual, rows, cols)
        if len(members) >= config.min_objects:
            pose = _procrustes_2d(p[members], q[members], 1.0 / single[members] ** 2)
        poses.append(_lift(pose))
        counts.append(max(len(members), len(clique)))
    diagnostics['objects_cliques'] = len(poses)
    if not poses:
        return none
    order = np.argsort(-np.asarray(counts), kind='stable')
    transforms = np.stack(poses)[order]
    keep = distinct_hypotheses(transforms, config.hypotheses, 5.0, 1.0)
    matches = np.asarray(counts, dtype=np.int64)[order][keep]
    diagnostics['objects_best_matches'] = int(matches[0])
    return ObjectPoses(transforms[keep], matches, diagnostics)


def _distances(xy: np.ndarray) -> np.ndarray:
    """``(K, K)`` pairwise distances of ``(K, 2)`` points."""
    return np.sqrt(((xy[:, None, :] - xy[None, :, :]) ** 2).sum(axis=-1))


def _grow_clique(seed: int, compatible: np.ndarray, score: np.ndarray) -> np.ndarray:
    """Grow a clique from ``seed``: its neighbours by descending ``score``, if compatible."""
    neighbours = np.flatnonzero(compatible[seed])
    neighbours = neighbours[neighbours != seed]
    neighbours = neighbours[np.argsort(-score[neighbours], kind='stable')]
    alive = np.ones(len(neighbours), dtype=bool)
    clique = [seed]
    links = compatible[np.ix_(neighbours, neighbours)]
    for k in range(len(neighbours)):  # over the seed's neighbours only (tens)
        if alive[k]:
            clique.append(int(neighbours[k]))
            alive &= links[k]
    return np.asarray(clique, dtype=np.int64)


def _one_to_one(
    members: np.ndarray, residual: np.ndarray, rows: np.ndarray, cols: np.ndarray
) -> np.ndarray:
    """Keep, per source and per target object, only the member with the least residual."""
    members = members[np.argsort(residual[members], kind='stable')]
    _, first_row = np.unique(rows[members], return_index=True)
    members = members[np.sort(first_row)]
    _, first_col = np.unique(cols[members], return_index=True)
    return members[np.sort(first_col)]


def _procrustes_2d(p: np.ndarray, q: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """``(3, 3)`` rigid 2-D transform minimising ``sum w ||R p + t - q||^2`` (Umeyama)."""
    w = weight / weight.sum()
    mean_p, mean_q = w @ p, w @ q
    cov = ((q - mean_q) * w[:, None]).T @ (p - mean_p)
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    rotation = u @ np.diag([1.0, d]) @ vt
    pose = np.eye(3)
    pose[:2, :2] = rotation
    pose[:2, 2] = mean_q - rotation @ mean_p
    return pose


def _lift(pose: np.ndarray) -> np.ndarray:
    """Return a 2-D pose as a ``(4, 4)`` yaw and xy translation (levelled frames)."""
    T = np.eye(4)
    T[:2, :2] = pose[:2, :2]
    T[:2, 3] = pose[:2, 2]
    return T
