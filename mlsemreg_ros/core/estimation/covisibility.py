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
Overlap where both scans can see: the share of the *checkable* source surface on the target.

The dense overlap of the verification
(:func:`~mlsemreg_ros.core.estimation.verification.dense_scores`) divides by the whole
source scan. Two scans 60 m apart share a lens of space only, so the
right pose overlaps 4-30 % of the source and is refused by ``confidence.min_overlap``, while
a wrong pose that drops the source onto the target's near field overlaps as much.

Here a source point counts only where the target can say something about it (free-space
carving, as in MapClosures' and occupancy-based loop checks): the target's
*range image* (azimuth x elevation bins of ``covisibility.bin_deg``, each holding the
nearest target range) tells, for a source point moved into the target frame at range
``r`` in a bin of nearest range ``r_t``:

- **on the target**: a target point within ``verification.overlap_distance``;
- **seen through**: ``r < r_t - covisibility.margin``: the target's beam passed where the
  point is, so the pose contradicts the target;
- **hidden** (``r > r_t + margin``), in an empty bin or beyond the target's reach: the
  target cannot check it, and it is left out.

The covisible overlap is ``on / (on + seen through)`` (range-weighted, as the dense
overlap), with ``checked`` the weighted share of the source that was checkable. Both
directions are measured (the source's view of the moved target too), and the smaller
counts: a pose must survive both scans' free space.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core.estimation import kernels
from mlsemreg_ros.core.estimation.nearest_grid import nearest_within
from mlsemreg_ros.core.features import kernels as compiled
from mlsemreg_ros.core.settings import param
import numpy as np
from scipy.spatial import cKDTree


@dataclass
class CovisibilityConfig:
    """The ``covisibility`` section: the overlap where both scans can see."""

    enabled: bool = param(
        True,
        "Judge the overlap only where both scans can see (free space of each scan's range "
        'image): confidence.min_overlap applies to the covisible overlap of a pose that has '
        'covisibility.min_checked of its surface checkable (core/estimation/covisibility.py).',
    )
    swapped_search: bool = param(
        True,
        "When the BEV search left the pose refused, search again from the target's side "
        '(the scans swapped, the peaks inverted): a 60 m pair found in one direction is '
        'often missed in the other (core/stages/swapped_search.py).',
    )
    far_min_range: float = param(
        20.0,
        'When the BEV searches left the pose refused, search again on the far points only '
        '(farther than this from their sensor, both scans, both directions), polish the '
        'best peaks on the dense scans and add them to the candidates: two scans 60 m apart '
        'share only their far field, and their near fields make false peaks '
        '(core/stages/far_search.py); 0: off.',
        unit='m',
        low=0.0,
        high=200.0,
    )
    far_peaks: int = param(
        6,
        'Best peaks of each direction of the far search that are polished and verified.',
        low=1,
        high=1000,
    )
    bin_deg: float = param(
        2.0,
        'Azimuth and elevation size of a range-image bin.',
        unit='deg',
        low=0.1,
        high=30.0,
    )
    margin: float = param(
        1.0,
        'A moved point nearer than the target surface of its bin by more than this is seen '
        'through (the pose contradicts the free space); farther: hidden, not checked.',
        unit='m',
        low=0.05,
        high=20.0,
    )
    min_checked: float = param(
        0.03,
        'Smallest share of the source surface (range-weighted) the target can check for '
        'the covisible overlap to stand in for the overlap.',
        low=0.0,
        high=1.0,
    )
    min_overlap: float = param(
        0.5,
        'Smallest covisible overlap (on / (on + seen through)) of an accepted pose that '
        'is judged by it.',
        low=0.0,
        high=1.0,
    )
    refine_distance: float = param(
        0.5,
        'A refused pose chosen where both scans see (the covisible choice) is also refined '
        'with this GICP correspondence distance, from the coarse pose and from the usual '
        'fine alignment; the refinement with the best covisible overlap is kept. Two scans '
        '60 m apart share a thin lens of space, and one distance does not suit every pair '
        '(0: off).',
        unit='m',
        low=0.0,
        high=20.0,
    )
    accept_overlap: float = param(
        0.97,
        'A refused pose chosen where both scans see and refined is accepted on its covisible '
        'overlap (measured on covisibility.accept_points points) when it reaches this, with '
        'covisibility.accept_checked of its surface checked, its tilt within '
        'covisibility.accept_tilt and the level check, and every distinct candidate and '
        'slide covisibility.accept_gap below it (core/estimation/covisible_acceptance.py, '
        'docs/long_range.md); 0: off.',
        low=0.0,
        high=1.0,
    )
    accept_checked: float = param(
        0.03,
        'Smallest checkable share of the surface of a pose accepted on its covisible overlap.',
        low=0.0,
        high=1.0,
    )
    accept_rival_share: float = param(
        0.25,
        'A distinct candidate or slide counts as a rival of a pose judged on its covisible '
        'overlap only when at least this share of what the pose has checked is checkable '
        'under it: a rival that both scans barely see measures a high overlap on next to '
        'nothing (the first pair of the simulated field drive seed 1 at stride 20: the pose '
        '0.978 on 0.39 of the surface, a rival 0.961 on 0.036; docs/labels.md); 0: every '
        'rival with covisibility.min_checked.',
        low=0.0,
        high=1.0,
    )
    accept_gap: float = param(
        0.04,
        'A pose accepted on its covisible overlap must beat the best distinct candidate of '
        'the pool and the best of its slides (confidence.slide_distance, 8 directions) by '
        'this much.',
        low=0.0,
        high=1.0,
    )
    accept_near_slide: float = param(
        1.0,
        'A pose judged on its covisible overlap is also measured slid by this distance and by '
        '1.5 times it, along 8 horizontal directions; a slide that fits more than '
        'covisibility.accept_climb of the surface better refuses it: the pose is not where '
        'the scans fit best. A real KITTI 40 m FPFH pose 1.55 m off along the street '
        'measured 0.989 on 0.25 of the surface, slid 1-1.5 m 0.998, the truth 1.000 '
        '(docs/hard_pairs.md); 0: off.',
        unit='m',
        low=0.0,
        high=10.0,
    )
    accept_climb: float = param(
        0.0012,
        'How much more of the surface a slide of covisibility.accept_near_slide may fit than '
        'a pose accepted on its covisible overlap: (slide overlap - pose overlap) times the '
        'checked share. A gain in overlap on little checked surface is noise: right 60 m '
        'poses gained 0.011 on 0.05 (0.0006), the wrong 40 m pose 0.010 on 0.25 (0.0025).',
        low=0.0,
        high=1.0,
    )
    early_accept_gap: float = param(
        0.08,
        'The gate of the refused path: after the BEV, swapped and far searches and the guided '
        're-matching, while the pose is refused, the end stages (covisible choice, fine '
        'alignment, near-miss check, acceptance where both scans see) are tried on the '
        'candidates found so far; a pose accepted whose covisible overlap (measured as '
        'stage 9 does) beats the best distinct candidate and slide by this much ends the '
        'registration there (core/stages/early_acceptance.py, docs/hard_pairs.md); 0: off.',
        low=0.0,
        high=1.0,
    )
    early_refuse_overlap: float = param(
        0.70,
        'The early refusal of the refused path: after the guided re-matching, a pose still '
        "refused whose best covisible overlap in the gate's last trial "
        '(covisibility.early_accept_gap) is below this is refused there, without the full '
        'graph, the polishing and the end stages. There, accepted poses measured 0.878 and '
        'more, right refused ones 0.738 and more, and 16 of 78 wrong refused ones less '
        '(core/stages/early_refusal.py, docs/hard_pairs.md); 0: off.',
        low=0.0,
        high=1.0,
    )
    accept_tilt: float = param(
        10.0,
        "Largest tilt (angle between the scans' up axes) of a pose accepted on its "
        'covisible overlap.',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    accept_localizability: float = param(
        0.01,
        "Smallest ratio of the refined pose's translation Hessian eigenvalues (smallest to "
        'largest, degeneracy_ratio) for an acceptance on its covisible overlap: the overlap '
        'cannot see a slide of a metre along a weak direction (a simulated 80 m pose 0.90 m '
        'off along the street measured 1.000 at a ratio of 0.006; right KITTI 40-60 m poses '
        '0.023-0.17; docs/hard_pairs.md, margins); 0: not checked.',
        low=0.0,
        high=1.0,
    )
    accept_points: int = param(
        8000,
        'Points of each scan (seeded random subset) on which a pose judged for acceptance on '
        'its covisible overlap, its slides and its best distinct candidates are measured '
        'again (the covisible choice measures verification.sample_points).',
        low=100,
        high=1000000,
    )
    accept_rivals: int = param(
        8,
        'Distinct pool candidates with the best covisible overlap that are measured again '
        'against a pose judged for acceptance on its covisible overlap.',
        low=1,
        high=1000,
    )
    min_gain: float = param(
        0.03,
        'The covisible choice keeps the current pose unless another candidate beats its '
        'covisible overlap by more than this, and a candidate with no more sparse inliers, '
        'score and surface on the other scan, and no less seen through, than the current '
        'pose never replaces it (right 60 m poses measure 0.96-1.00, with a spread of '
        '0.01-0.02 between variants of the same pose).',
        low=0.0,
        high=1.0,
    )


@dataclass(frozen=True)
class RangeImage:
    """The nearest range of a scan per (azimuth, elevation) bin; ``inf`` where empty."""

    nearest: np.ndarray  # (A, E) float64
    bin_rad: float
    min_elevation: float  # rad, lower edge of bin 0

    @classmethod
    def of(cls, points: np.ndarray, bin_deg: float) -> RangeImage:
        """Build the range image of sensor-frame ``points`` ``(N, 3)``."""
        bin_rad = np.radians(bin_deg)
        ranges = np.linalg.norm(points, axis=1)
        elevation = np.arcsin(np.clip(points[:, 2] / np.maximum(ranges, 1e-9), -1.0, 1.0))
        low = float(elevation.min()) if len(points) else 0.0
        cols = int(np.ceil((float(elevation.max()) - low) / bin_rad)) + 1 if len(points) else 1
        rows = int(np.ceil(2.0 * np.pi / bin_rad))
        nearest = np.full((rows, cols), np.inf)
        a, e = cls._bins(points, ranges, elevation, bin_rad, low, rows, cols)
        np.minimum.at(nearest, (a, e), ranges)
        return cls(nearest, bin_rad, low)

    @staticmethod
    def _bins(
        points: np.ndarray,
        ranges: np.ndarray,
        elevation: np.ndarray,
        bin_rad: float,
        low: float,
        rows: int,
        cols: int,
    ) -> tuple[np.ndarray, np.ndarray]:
        azimuth = np.arctan2(points[:, 1], points[:, 0]) + np.pi
        a = np.minimum((azimuth / bin_rad).astype(np.int64), rows - 1)
        e = np.floor((elevation - low) / bin_rad).astype(np.int64)
        return a, e

    def seen_through(self, points: np.ndarray, on: np.ndarray, margin: float) -> np.ndarray:
        """
        ``(N,)`` whether each of ``points`` not ``on`` the scan is seen through (module docstring).

        Nearer than its bin's nearest range by more than ``margin``; compiled when the kernels
        are (the NumPy arrays of every point's range and bin otherwise).
        """
        points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        on = np.asarray(on, dtype=bool)
        if compiled.enabled():
            return kernels.seen_through(
                points, on, self.nearest, self.bin_rad, self.min_elevation, margin
            )
        surface = self.surface(points)
        ranges = np.linalg.norm(points, axis=1)
        return ~on & np.isfinite(surface) & (ranges < surface - margin)

    def surface(self, points: np.ndarray) -> np.ndarray:
        """``(N,)`` the nearest range of the bin of each point (inf: empty or out of view)."""
        rows, cols = self.nearest.shape
        ranges = np.linalg.norm(points, axis=1)
        elevation = np.arcsin(np.clip(points[:, 2] / np.maximum(ranges, 1e-9), -1.0, 1.0))
        a, e = self._bins(points, ranges, elevation, self.bin_rad, self.min_elevation, rows, cols)
        inside = (e >= 0) & (e < cols)
        out = np.full(len(points), np.inf)
        out[inside] = self.nearest[a[inside], e[inside]]
        return out


def covisible_overlap(
    transforms: np.ndarray,
    source_points: np.ndarray,
    target_tree: cKDTree,
    target_image: RangeImage,
    weight: np.ndarray,
    overlap_distance: float,
    margin: float,
) -> tuple[np.ndarray, np.ndarray]:
    """
    ``(overlap (N,), checked (N,))`` of ``(N, 4, 4)`` poses, one direction (module docstring).

    ``source_points`` ``(n, 3)`` sampled source points with their ``weight`` ``(n,)``
    (summing to 1); ``target_tree`` and ``target_image`` of the target scan.
    """
    count = len(transforms)
    moved = source_points @ transforms[:, :3, :3].transpose(0, 2, 1) + transforms[:, None, :3, 3]
    flat = moved.reshape(-1, 3)
    distance, _ = nearest_within(target_tree, flat, overlap_distance, first_only=True)
    on = np.isfinite(distance)
    through = target_image.seen_through(flat, on, margin).reshape(count, -1)
    on = on.reshape(count, -1)
    on_weight, through_weight = on @ weight, through @ weight
    checked = on_weight + through_weight
    overlap = np.where(checked > 0, on_weight / np.maximum(checked, 1e-12), 0.0)
    return overlap, checked


def mutual_covisible_overlap(
    transforms: np.ndarray,
    source: tuple[np.ndarray, np.ndarray, cKDTree, RangeImage],
    target: tuple[np.ndarray, np.ndarray, cKDTree, RangeImage],
    overlap_distance: float,
    margin: float,
) -> tuple[np.ndarray, np.ndarray]:
    """
    Both directions: the smaller overlap and the smaller checked share of each pose.

    ``source``/``target``: ``(sampled points, weights, KD-tree, range image)`` of a scan.
    """
    forward = covisible_overlap(
        transforms, source[0], target[2], target[3], source[1], overlap_distance, margin
    )
    inverse = np.linalg.inv(transforms)
    backward = covisible_overlap(
        inverse, target[0], source[2], source[3], target[1], overlap_distance, margin
    )
    return np.minimum(forward[0], backward[0]), np.minimum(forward[1], backward[1])


def covisible_choice(
    overlap: np.ndarray,
    checked: np.ndarray,
    inliers: np.ndarray,
    scores: np.ndarray,
    current: int | None,
    min_checked: float,
    min_gain: float,
) -> int:
    """
    Return the candidate the covisible overlap chooses, ``current`` if it holds, -1 for none.

    - ``overlap``, ``checked``: :func:`mutual_covisible_overlap` of every candidate;
      ``inliers``, ``scores``: their sparse inliers and verification scores.
    - Only candidates with ``checked >= min_checked`` are eligible (-1: none is).
    - The *contenders* reach the best eligible overlap within ``min_gain``. The current
      candidate stays if it is one; else the best overlap is chosen.
      On a mirrored street the right BEV pose (covisible overlap 1.00 of 0.86 of its surface
      checked) was once replaced by a pose 180 deg off with 1.00 of 0.11 checked, 0 inliers
      and an eighth of the score: a tie, which now keeps the current pose.
    - Never less evidence: a contender with no more sparse inliers, score and surface on
      the other scan (``overlap x checked``) than the current candidate, and no less surface
      seen through (``(1 - overlap) x checked``), does not replace it (-1 when the current
      one is not eligible itself).
    """
    eligible = checked >= min_checked
    if not eligible.any():
        return -1
    best = float(overlap[eligible].max())
    contenders = eligible & (overlap >= best - min_gain)
    if current is not None and current >= 0 and contenders[current]:
        return current
    pick = int(np.argmax(np.where(eligible, overlap, -np.inf)))
    if current is None or current < 0:
        return pick
    evidence = np.array(
        [inliers, scores, overlap * checked, -(1.0 - overlap) * checked], dtype=np.float64
    )
    if np.all(evidence[:, pick] <= evidence[:, current]):
        return current if eligible[current] else -1
    return pick
