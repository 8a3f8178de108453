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
Hypothesis verification: choose among the estimator's best poses on the dense labeled scans.

SC2-PCR (Chen et al., CVPR 2022) keeps the hypothesis with the most inliers among the
sparse keypoint correspondences. On a street the mirror pose (a ~170 deg turn that
swaps the two sides) or a slide along a repetitive facade can win that count. The two
dense, labeled scans hold far more evidence; this stage (beyond the paper, the next
level of its "multi-level semantic consistency") weighs it:

1. candidates: the estimator's choice and its next best *distinct* hypotheses
   (:func:`~mlsemreg_ros.core.poses.distinct_hypotheses`: not within
   ``distinct_rotation`` / ``distinct_translation`` of a better one), each refined like
   the winner (SC2-PCR post-refinement) and de-duplicated again;
2. on a seeded sample of ``sample_points`` source scan points, transformed by every
   candidate at once, one nearest-neighbour query in the target scan's KD-tree (built
   once per target scan, :meth:`PreparedScan.points_tree`) gives, each sampled point
   weighted by its range ``** range_exponent`` (:func:`area_weights`: shares of the seen
   surface rather than of the points, so the dense ground around the sensor does not
   decide),

   - ``overlap``: the share of sampled points with a target point within
     ``overlap_distance``;
   - ``label_agreement``: among the overlapping points whose labels (source and nearest
     target point) are both counted (not in ``ignored_classes``), the share whose labels
     are equal or compatible (``compatible_classes``, e.g. ``vegetation~terrain``); 1
     when no such point exists (unlabeled scans: geometry alone decides);

3. ``score = overlap ** overlap_weight * label_agreement ** label_weight``. With both
   weights 1 it is the share of sampled points that overlap *with a compatible label*.
   The best score wins, but the estimator's choice is kept unless another hypothesis
   beats its score by more than ``min_gain`` (relative).

A mirror pose puts sidewalk on road and building on vegetation: its label agreement
drops even where its geometric overlap is as high as the true pose's.
"""

from __future__ import annotations

from dataclasses import dataclass
import threading
import time

from mlsemreg_ros.core.estimation import kernels
from mlsemreg_ros.core.estimation.config import (
    class_rule_names,
    EstimatorConfig,
    VerificationConfig,
)
from mlsemreg_ros.core.estimation.nearest_grid import nearest_within
from mlsemreg_ros.core.estimation.sc2pcr import count_inliers, post_refinement
from mlsemreg_ros.core.features.kernels import use_compiled
from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.poses import distinct_hypotheses, residuals, same_pose
from mlsemreg_ros.core.results import (
    EstimateResult,
    HypothesisScore,
    PreparedScan,
    VerificationResult,
)
import numpy as np
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

#: A hypothesis is refined on the correspondences with residual below this many times
#: ``estimator.refine_threshold`` under it (see :func:`candidate_hypotheses`).
_REFINE_SUPPORT = 2.0


@dataclass(frozen=True)
class LabelCompatibility:
    """Which learning-id pairs agree, and which ids count for the label agreement."""

    compatible: np.ndarray  # (C, C) bool, symmetric, true diagonal
    counted: np.ndarray  # (C,) bool, false for ignored classes


def label_compatibility(label_map: LabelMap, config: VerificationConfig) -> LabelCompatibility:
    """
    Resolve ``compatible_classes`` (``'a~b'`` or ``'a~b~c'``) and ``ignored_classes``.

    Every class of a rule agrees with every other class of it; each class agrees with
    itself. Unknown class names raise ConfigError (from the label map).
    """
    count = label_map.num_classes
    compatible = np.eye(count, dtype=bool)
    for rule in config.compatible_classes:
        ids = label_map.ids_of(class_rule_names(rule))
        compatible[np.ix_(ids, ids)] = True
    counted = np.ones(count, dtype=bool)
    counted[label_map.ids_of(config.ignored_classes)] = False
    return LabelCompatibility(compatible, counted)


def candidate_hypotheses(
    estimate: EstimateResult,
    src: np.ndarray,
    dst: np.ndarray,
    config: VerificationConfig,
    estimator: EstimatorConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """
    Return the estimator's choice and its best distinct other hypotheses, refined.

    ``estimate.transform`` comes first as it is. The next best distinct hypotheses of
    ``estimate.hypotheses`` (at most ``config.hypotheses`` in all; distinct from each
    other and from the refined choice) get SC2-PCR's post-refinement; one that comes
    within the distinct bounds of a better refined one is dropped (its refinement ends
    there, as most of them join the estimator's choice). The refinement runs
    on the finite correspondences within ``_REFINE_SUPPORT x refine_threshold`` of the
    starting pose (a fraction of them, so it is several times faster): a correspondence
    that far off would have to move by more than the refinement threshold to become an
    inlier.

    Returns ``(transforms (N, 4, 4), estimator_rank (N,))``, rank 0 = the estimator's choice.
    """
    transforms, ranks = [estimate.transform], [0]
    candidates = estimate.hypotheses
    if candidates is not None and len(candidates) > 1 and config.hypotheses > 1:
        # hypotheses[0] started the refined choice: compare the others with the refined pose
        pool = np.concatenate([estimate.transform[None], candidates.T_target_source[1:]])
        picked = distinct_hypotheses(
            pool, config.hypotheses, config.distinct_rotation, config.distinct_translation
        )
        finite = np.isfinite(src).all(axis=1) & np.isfinite(dst).all(axis=1)
        p, q = src[finite], dst[finite]
        support = _REFINE_SUPPORT * estimator.refine_threshold
        for rank in picked[1:]:  # at most config.hypotheses - 1 refinements
            start = pool[rank]
            near = residuals(start, p, q) < support
            known = np.stack(transforms)

            def joined(pose: np.ndarray, known: np.ndarray = known) -> bool:
                return same_pose(
                    pose, known, config.distinct_rotation, config.distinct_translation
                ).any()

            refined, _ = post_refinement(
                start,
                p[near],
                q[near],
                estimator.refine_threshold,
                estimator.refine_iterations,
                stop=joined,
            )
            if joined(refined):
                continue  # converged onto a better candidate: a duplicate
            transforms.append(refined)
            ranks.append(int(rank))
    return np.stack(transforms), np.asarray(ranks, dtype=np.int64)


def dense_scores(
    transforms: np.ndarray,
    source: PreparedScan,
    target_tree: cKDTree,
    target_labels: np.ndarray,
    labels: LabelCompatibility,
    config: VerificationConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """
    Overlap and label agreement of every hypothesis on the dense scans (module docstring).

    One query for all ``N`` hypotheses: the ``n`` sampled source points are transformed by
    each (``(N, n, 3)``) and their nearest target points within ``overlap_distance`` looked
    up (core/estimation/nearest_grid.py: compiled cells, or the target tree).

    Returns ``(overlap (N,), label_agreement (N,))``, both in ``[0, 1]``.
    """
    total = source.points.shape[0]
    count = transforms.shape[0]
    if total == 0 or target_tree.n == 0:
        return np.zeros(count), np.ones(count)
    rng = np.random.default_rng(config.seed)
    rows = (
        rng.choice(total, config.sample_points, replace=False)
        if total > config.sample_points
        else np.arange(total)
    )
    points, source_labels = source.points[rows], source.labels[rows]
    weight = area_weights(points, config.range_exponent)  # (n,), sums to 1
    moved = points @ transforms[:, :3, :3].transpose(0, 2, 1) + transforms[:, None, :3, 3]
    distance, nearest = nearest_within(target_tree, moved.reshape(-1, 3), config.overlap_distance)
    overlapping = np.isfinite(distance).reshape(count, -1)
    nearest = np.where(overlapping.ravel(), nearest, 0).reshape(count, -1)
    nearest_labels = target_labels[nearest]  # (N, n), meaningless where not overlapping
    counted = overlapping & labels.counted[source_labels][None, :]
    counted &= labels.counted[nearest_labels]
    # compatible: bool rules, or float weights of the adaptive label model (label_model.py)
    agreeing = counted * labels.compatible[source_labels[None, :], nearest_labels]
    counted_weight = counted @ weight
    agreement = np.where(
        counted_weight > 0, (agreeing @ weight) / np.maximum(counted_weight, 1e-300), 1.0
    )
    return np.clip(overlapping @ weight, 0.0, 1.0), np.clip(agreement, 0.0, 1.0)


def area_weights(points: np.ndarray, exponent: float) -> np.ndarray:
    """
    ``(n,)`` weights ``range ** exponent`` of sensor-frame points, normalised to sum 1.

    A LiDAR samples a surface at range ``r`` with a density ``~ 1 / r^2``, so with
    ``exponent = 2`` a weighted share is a share of the *seen surface*, not of the
    points, and the dense ground next to the sensor cannot outvote the rest of the scene
    (a pose that drops the source scan onto the target sensor overlaps many points).
    ``exponent = 0``: every point counts the same. All weights zero (all points at the
    origin) fall back to equal weights.
    """
    weight = np.linalg.norm(points, axis=1) ** exponent if exponent else np.ones(len(points))
    total = weight.sum()
    return weight / total if total > 0 else np.full(len(points), 1.0 / max(len(points), 1))


def combined_score(
    overlap: np.ndarray, agreement: np.ndarray, config: VerificationConfig
) -> np.ndarray:
    """``overlap ** overlap_weight * label_agreement ** label_weight`` (``0 ** 0 = 1``)."""
    return np.power(overlap, config.overlap_weight) * np.power(agreement, config.label_weight)


def choose(scores: np.ndarray, min_gain: float) -> int:
    """Index of the best score; 0 (the estimator's choice) unless beaten by ``min_gain``."""
    best = int(np.argmax(scores))
    return best if scores[best] > scores[0] * (1.0 + min_gain) else 0


def verify_hypotheses(
    estimate: EstimateResult,
    src: np.ndarray,
    dst: np.ndarray,
    source: PreparedScan,
    target: PreparedScan,
    config: VerificationConfig,
    estimator: EstimatorConfig,
    labels: LabelCompatibility,
) -> VerificationResult:
    """
    Score the estimator's best distinct hypotheses on the dense scans and choose one.

    - ``estimate``: the estimator's result (SC2-PCR: with all its hypotheses).
    - ``src``, ``dst``: ``(K, 3)`` correspondences the estimator saw.
    - ``source``, ``target``: the prepared scans (``points``, ``labels`` = learning ids).
    - ``config``: the ``verification`` section; ``estimator``: thresholds of the
      post-refinement and of the inlier count.
    - ``labels``: :func:`label_compatibility` of the label map.

    Returns every candidate's scores and the choice; ``diagnostics`` holds them as flat
    scalars (``verification_h{i}_score`` ...) for ``/diagnostics``.
    """
    start = time.perf_counter()
    transforms, ranks = candidate_hypotheses(estimate, src, dst, config, estimator)
    refined_ms = 1e3 * (time.perf_counter() - start)
    result = score_hypotheses(
        transforms, ranks, src, dst, source, target, config, estimator, labels
    )
    chosen = result.chosen
    result.diagnostics.update(
        {
            'verification_hypotheses': len(result.hypotheses),
            'verification_chosen_rank': int(ranks[chosen]),
            'verification_switched': chosen != 0,
            'verification_score': result.hypotheses[chosen].score,
            'verification_refine_ms': refined_ms,
        }
    )
    for i, h in enumerate(result.hypotheses):
        result.diagnostics.update(
            {
                f'verification_h{i}_rank': h.rank,
                f'verification_h{i}_inliers': h.num_inliers,
                f'verification_h{i}_overlap': h.overlap,
                f'verification_h{i}_label_agreement': h.label_agreement,
                f'verification_h{i}_score': h.score,
            }
        )
    return result


def refine_starts(
    starts: np.ndarray,
    src: np.ndarray,
    dst: np.ndarray,
    estimator: EstimatorConfig,
    compiled: bool | None = None,
) -> np.ndarray:
    """
    SC2-PCR post-refinement of every ``(N, 4, 4)`` start on the correspondences near it.

    Near: residual below ``_REFINE_SUPPORT x estimator.refine_threshold`` under the start
    (as in :func:`candidate_hypotheses`). A start with fewer than three near
    correspondences is returned as it is. ``compiled``: None uses the numba kernel when
    available (:func:`~mlsemreg_ros.core.estimation.kernels.refine_all`, all starts in one
    loop), False one NumPy post-refinement per start.
    """
    finite = np.isfinite(src).all(axis=1) & np.isfinite(dst).all(axis=1)
    p, q = src[finite], dst[finite]
    support = _REFINE_SUPPORT * estimator.refine_threshold
    if use_compiled(compiled) and len(starts):
        return kernels.refine_all(
            np.ascontiguousarray(starts, dtype=np.float64),
            np.ascontiguousarray(p, dtype=np.float64),
            np.ascontiguousarray(q, dtype=np.float64),
            float(support),
            float(estimator.refine_threshold),
            int(estimator.refine_iterations),
        )
    refined = starts.copy()
    for i, start in enumerate(starts):  # one small least-squares problem per start
        near = residuals(start, p, q) < support
        if np.count_nonzero(near) >= 3:
            refined[i], _ = post_refinement(
                start, p[near], q[near], estimator.refine_threshold, estimator.refine_iterations
            )
    return refined


def score_hypotheses(
    transforms: np.ndarray,
    ranks: np.ndarray,
    src: np.ndarray,
    dst: np.ndarray,
    source: PreparedScan,
    target: PreparedScan,
    config: VerificationConfig,
    estimator: EstimatorConfig,
    labels: LabelCompatibility,
    origin: str = 'estimator',
) -> VerificationResult:
    """
    Sparse inliers, dense overlap and label agreement of ``(N, 4, 4)`` poses; the choice.

    ``ranks``: each pose's position in the list it came from (``origin``); index 0 is
    kept unless another pose beats it by ``config.min_gain`` (:func:`choose`).
    ``diagnostics`` gets ``verification_tree_ms``.
    """
    finite = np.isfinite(src).all(axis=1) & np.isfinite(dst).all(axis=1)
    if finite.any():
        inliers = count_inliers(transforms, src[finite], dst[finite], estimator.inlier_threshold)
    else:
        inliers = np.zeros(len(transforms), dtype=np.int64)
    tick = time.perf_counter()
    tree = target.points_tree()
    tree_ms = 1e3 * (time.perf_counter() - tick)
    overlap, agreement = dense_scores(transforms, source, tree, target.labels, labels, config)
    scores = combined_score(overlap, agreement, config)
    hypotheses = [
        HypothesisScore(
            transforms[i],
            int(ranks[i]),
            int(inliers[i]),
            float(overlap[i]),
            float(agreement[i]),
            float(scores[i]),
            origin,
        )
        for i in range(len(transforms))
    ]
    return VerificationResult(
        hypotheses, choose(scores, config.min_gain), {'verification_tree_ms': tree_ms}
    )


#: Distinctive source points closer than this (m) belong to one object (a pole, a trunk).
DISTINCTIVE_OBJECT_RADIUS = 1.0
#: Objects of fewer points are left out of the object count (noise).
DISTINCTIVE_OBJECT_MIN_POINTS = 3
#: An object lines up when at least this share of its points lies on distinctive target points.
DISTINCTIVE_OBJECT_SHARE = 0.3
#: At most this many distinctive source points are scored (a seeded subset of them).
DISTINCTIVE_MAX_POINTS = 600
#: An object is in the target's view when one of its points has a target point this close (m):
#: a pole moved onto the sidewalk by a wrong pose has its foot on it.
DISTINCTIVE_VIEW_DISTANCE = 1.0


@dataclass(frozen=True)
class DistinctiveSide:
    """
    What :func:`distinctive_scores` needs of one scan, independent of the poses.

    ``points``: the scan's distinctive points (the source's: at most
    :data:`DISTINCTIVE_MAX_POINTS`, a seeded subset); ``tree``: their KD-tree;
    ``member``: ``(len(points),)`` the object of every point (connected within
    :data:`DISTINCTIVE_OBJECT_RADIUS`), ``size``: ``(objects,)`` points per object.
    """

    points: np.ndarray
    tree: cKDTree | None
    member: np.ndarray
    size: np.ndarray

    @classmethod
    def of(cls, scan: PreparedScan, distinctive: np.ndarray, source: bool) -> DistinctiveSide:
        """Return the side of ``scan`` (its objects too when it is the ``source``)."""
        labels = np.asarray(scan.labels, dtype=np.int64)
        known = (labels >= 0) & (labels < distinctive.size)
        points = scan.points[known & distinctive[np.where(known, labels, 0)]]
        none = np.zeros(0, dtype=np.int64)
        if not source:
            return cls(points, cKDTree(points) if len(points) else None, none, none)
        if len(points) > DISTINCTIVE_MAX_POINTS:  # seeded subset: the cost stays bounded
            rows = np.random.default_rng(0).choice(
                len(points), DISTINCTIVE_MAX_POINTS, replace=False
            )
            points = points[np.sort(rows)]
        if len(points) == 0:
            return cls(points, None, none, none)
        tree = cKDTree(points)
        graph = tree.sparse_distance_matrix(
            tree, DISTINCTIVE_OBJECT_RADIUS, output_type='coo_matrix'
        )
        num_objects, member = connected_components(graph, directed=False)
        return cls(points, tree, member, np.bincount(member, minlength=num_objects))


class _DistinctiveSides:
    """
    The :class:`DistinctiveSide` of the last few scans, made once per scan and role.

    A registration scores poses on the same two scans many times (the estimator's
    hypotheses, every search's candidates, the rivals of the confidence rule: about 14 calls
    per 60 m dev pair); the sides do not depend on the poses. An entry holds the scan's
    ``points`` and ``labels`` arrays and is used only for those very arrays (as the scan's
    KD-tree, :meth:`PreparedScan.points_tree`, the arrays are not changed in place).
    """

    def __init__(self, capacity: int = 8) -> None:
        """Keep the sides of the last ``capacity`` scan roles."""
        self.capacity = capacity
        self.entries: list[tuple[object, object, bytes, bool, DistinctiveSide]] = []
        self.lock = threading.Lock()

    def side(self, scan: PreparedScan, distinctive: np.ndarray, source: bool) -> DistinctiveSide:
        """Return the side of ``scan`` for ``distinctive`` (made now if not kept)."""
        points, labels, classes = scan.points, scan.labels, np.asarray(distinctive).tobytes()
        with self.lock:
            for entry in self.entries:
                if (
                    entry[0] is points
                    and entry[1] is labels
                    and entry[2] == classes
                    and entry[3] == source
                ):
                    return entry[4]
        found = DistinctiveSide.of(scan, np.asarray(distinctive), source)
        kept = self.capacity
        with self.lock:
            self.entries = [(points, labels, classes, source, found), *self.entries][:kept]
        return found


_DISTINCTIVE_SIDES = _DistinctiveSides()


def distinctive_scores(
    transforms: np.ndarray,
    source: PreparedScan,
    target: PreparedScan,
    distinctive: np.ndarray,
    distance: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    How much distinctive structure every ``(N, 4, 4)`` pose lines up (docs/hard_pairs.md).

    ``distinctive``: ``(C,)`` bool over learning ids (``confidence.distinctive_classes``:
    poles, signs, trunks). Every distinctive source point is moved by each pose and looked
    up among the distinctive target points (a small KD-tree). The source's
    distinctive points are grouped into objects (connected within
    :data:`DISTINCTIVE_OBJECT_RADIUS`, at least :data:`DISTINCTIVE_OBJECT_MIN_POINTS`
    points); an object lines up when :data:`DISTINCTIVE_OBJECT_SHARE` of its points do.
    The points, trees and objects of both scans are made once per scan
    (:class:`DistinctiveSide`).

    Returns ``(share (N,), objects (N,), in_view (N,))``: the share of distinctive source
    points with a distinctive target point within ``distance``, the number of objects
    lined up, and the number of objects in the target's view (one point within
    :data:`DISTINCTIVE_VIEW_DISTANCE` of any target point); zeros when either scan has
    none. A slide along a straight street lines up road and facades, not its poles: they
    land in view, beside the target's poles (on the dev pairs at most 1 of 5 in view line
    up at the zero motion, at least 3 of 5 at the truth).
    """
    count = transforms.shape[0]
    empty = np.zeros(count), np.zeros(count, dtype=np.int64), np.zeros(count, dtype=np.int64)
    mine = _DISTINCTIVE_SIDES.side(source, distinctive, source=True)
    theirs = _DISTINCTIVE_SIDES.side(target, distinctive, source=False)
    source_points = mine.points
    if count == 0 or len(source_points) == 0 or theirs.tree is None:
        return empty
    moved = source_points @ transforms[:, :3, :3].transpose(0, 2, 1) + transforms[:, None, :3, 3]
    found, _ = theirs.tree.query(moved.reshape(-1, 3), distance_upper_bound=distance)
    hit = np.isfinite(found).reshape(count, -1)
    seen, _ = target.points_tree().query(
        moved.reshape(-1, 3), distance_upper_bound=DISTINCTIVE_VIEW_DISTANCE
    )
    seen = np.isfinite(seen).reshape(count, -1)
    member, size = mine.member, mine.size
    num_objects = size.size
    lined = np.zeros((count, num_objects))
    np.add.at(lined, (slice(None), member), hit)  # (N, objects) points lined up
    viewed = np.zeros((count, num_objects))
    np.add.at(viewed, (slice(None), member), seen)
    counted = size >= DISTINCTIVE_OBJECT_MIN_POINTS
    objects = (lined >= DISTINCTIVE_OBJECT_SHARE * size) & counted
    in_view = ((viewed > 0) & counted) | objects
    return (
        hit.mean(axis=1),
        objects.sum(axis=1).astype(np.int64),
        in_view.sum(axis=1).astype(np.int64),
    )
