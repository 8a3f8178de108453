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
The registration pipeline: two labeled scans in, a rigid transform out.

Per pair the steps are (cf. Fig. 2 of the paper)::

    prepare(scan)      voxelize, keypoints, descriptors, Local-SS, landmarks (cached per scan)
    register(src, dst) ML-SemReg correspondences -> robust estimator -> verification on the
                       dense labeled scans -> fine alignment (GICP)

:meth:`Registration.prepare` is separate so a node can keep its keyframe's
prepared scan and pay only for the new scan on every frame.
"""

from __future__ import annotations

from dataclasses import dataclass
import functools
from typing import Any

from mlsemreg_ros.core import threads
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.deferred import Deferred
from mlsemreg_ros.core.estimation import bev_search, confidence, label_model
from mlsemreg_ros.core.estimation.candidates import CandidatePool
from mlsemreg_ros.core.estimation.verification import (
    label_compatibility,
    LabelCompatibility,
    score_hypotheses,
)
from mlsemreg_ros.core.features import features, fpfh
from mlsemreg_ros.core.features.scan_input import sanitize_scan_for
from mlsemreg_ros.core.matching import landmarks, signatures
from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.results import Landmarks, PreparedScan, RegistrationResult
from mlsemreg_ros.core.stages.bev_search import BevSearchStage
from mlsemreg_ros.core.stages.confidence import ConfidenceStage
from mlsemreg_ros.core.stages.context import RegistrationContext, Stage, timed
from mlsemreg_ros.core.stages.covisibility import CovisibilityStage
from mlsemreg_ros.core.stages.covisible_acceptance import CovisibleAcceptanceStage
from mlsemreg_ros.core.stages.early_acceptance import EarlyAcceptanceStage
from mlsemreg_ros.core.stages.early_refusal import EarlyRefusalStage
from mlsemreg_ros.core.stages.estimation import EstimationStage
from mlsemreg_ros.core.stages.far_search import FarSearchStage
from mlsemreg_ros.core.stages.fine_alignment import FineAlignmentStage
from mlsemreg_ros.core.stages.label_quality import (
    LabelQualityStage,
    UnlabeledFallbackStage,
    UnlabeledRerunStage,
)
from mlsemreg_ros.core.stages.levelling import LevelCheckStage
from mlsemreg_ros.core.stages.matching import MatchingStage
from mlsemreg_ros.core.stages.near_miss import NearMissStage
from mlsemreg_ros.core.stages.objects import ObjectStage
from mlsemreg_ros.core.stages.refused_path import FullGraphStage, GuidedStage, PolishStage
from mlsemreg_ros.core.stages.runner import run_stages
from mlsemreg_ros.core.stages.scoring import Scoring
from mlsemreg_ros.core.stages.swapped_search import SwappedSearchStage
from mlsemreg_ros.core.stages.verification import VerificationStage
from mlsemreg_ros.core.threads import LazyPool
import numpy as np


@dataclass(frozen=True)
class _ResolvedClasses:
    """A config's class names resolved to label ids once (unknown names raise ConfigError)."""

    landmark_ids: np.ndarray
    ignored_ids: np.ndarray
    undefined_ids: np.ndarray
    label_compatibility: LabelCompatibility
    bev_channels: np.ndarray
    distinctive: np.ndarray  # (num_classes,) bool: confidence.distinctive_classes

    @classmethod
    def of(cls, config: RegistrationConfig, label_map: LabelMap) -> _ResolvedClasses:
        sem, cfg = config.semantic, config.confidence
        return cls(
            label_map.ids_of(sem.landmark_classes),
            label_map.ids_of(sem.ignored_classes),
            label_map.ids_of(sem.undefined_classes),
            label_compatibility(label_map, config.verification),
            bev_search.channel_lookup(label_map, config.bev_search),
            np.isin(np.arange(label_map.num_classes), label_map.ids_of(cfg.distinctive_classes)),
        )


def default_stages() -> list[Stage]:
    """
    Return the stages of a registration, in order (core/stages/, docs/architecture.md).

    The label source is not a stage here: it runs per scan, before :meth:`Registration.prepare`
    (labels in, learning ids out). A stage that needs both prepared scans goes into this
    list at its place (docs/extending.md); one that returns candidates is a candidate
    source, like the BEV search: its candidates face the confidence rule.
    """
    later = [
        SwappedSearchStage(),  # 5b. still refused: the BEV search from the target's side
        FarSearchStage(),  # 5c. still refused: the BEV search on the far fields, polished
        GuidedStage(),  # 6. still refused: guided re-matching around the searched peaks,
        FullGraphStage(),  # 6. SC2-PCR on the full correspondence graph,
        PolishStage(),  # 6. the pool's best candidates polished on the dense scans
    ]
    end = [
        CovisibilityStage(),  # 6b. still refused: the best overlap where both scans see
        UnlabeledFallbackStage(),  # 6b. poorer labels, refused: the unlabeled attempt's pose
        LevelCheckStage(),  # 6c. a tilt the two ground fits do not allow is refused
        FineAlignmentStage(),  # 7. GICP of the pair from the chosen pose (refine=True)
        NearMissStage(),  # 8. accepted and refined: no second basin from perturbed starts
        CovisibleAcceptanceStage(),  # 9. refused, refined: accepted where both scans see
    ]
    # the gate (covisibility.early_accept_gap): the end stages tried on the pool so far
    skipped = [stage.name for stage in later]
    stages: list[Stage] = [
        LabelQualityStage(),  # 0. the labels' weight: never worse than no labels
        MatchingStage(),  # 1. correspondences: ML-SemReg (GM o MM) or the plain matcher
        EstimationStage(),  # 2. the robust estimator (SC2-PCR): hypotheses, best first
        VerificationStage(),  # 3. the hypotheses scored on the dense labeled scans
        ConfidenceStage(),  # 4. the choice and the confidence rule's verdict
        ObjectStage(),  # 5a. refused or weak: the object hypotheses, 4-DoF in levelled frames
        BevSearchStage(),  # 5. refused or weak: the semantic bird's-eye-view search
        EarlyAcceptanceStage(end, skipped),  # the gate, after the BEV search,
        later[0],
        EarlyAcceptanceStage(end, skipped),  # after the swapped search,
        later[1],
        EarlyAcceptanceStage(end, skipped),  # after the far search,
        later[2],
        EarlyAcceptanceStage(end, skipped),  # and after the guided re-matching
        # hopeless after the searches (covisibility.early_refuse_overlap): refused there
        EarlyRefusalStage([stage.name for stage in [*later[3:], *end]]),
        *later[3:],
        *end,
    ]
    # 10. poorer labels, still refused: what `none` accepts (stages 0 to 9 once more)
    return [*stages, UnlabeledRerunStage(stages)]


class Registration:
    """
    ML-SemReg + SC2-PCR registration of labeled scans, configured once.

    ``transform`` of every result is ``T_target_source``: ``p_target = T @ p_source``.
    """

    def __init__(
        self, config: RegistrationConfig | None = None, label_map: LabelMap | None = None
    ) -> None:
        self.label_map = label_map if label_map is not None else LabelMap.load()
        self.config = config if config is not None else RegistrationConfig()
        self.stages: list[Stage] = default_stages()

    @property
    def config(self) -> RegistrationConfig:
        """Return the active configuration."""
        return self._config

    @config.setter
    def config(self, config: RegistrationConfig) -> None:
        resolved = _ResolvedClasses.of(config, self.label_map)  # ConfigError if unknown
        threads.configure(config.threads)  # process-wide: only once the config is valid
        self._landmark_ids = resolved.landmark_ids
        self._ignored_ids = resolved.ignored_ids
        self._undefined_ids = resolved.undefined_ids
        # every class but the ignored and undefined ones: what a keypoint of an unlabeled
        # scan sees (core/labeling/quality.py)
        self._unlabeled_local_ss = np.ones(self.label_map.num_classes, dtype=bool)
        self._unlabeled_local_ss[np.r_[resolved.ignored_ids, resolved.undefined_ids]] = False
        self._label_compatibility = resolved.label_compatibility
        self._bev_channels = resolved.bev_channels
        self._distinctive = resolved.distinctive
        self._config = config
        self._configure_label_model(config)

    def _configure_label_model(self, config: RegistrationConfig) -> None:
        """``confidence.label_model: adaptive``: a :class:`LabelModel` (its counts kept)."""
        fixed = self._label_compatibility
        previous = getattr(self, 'label_model', None)
        if config.confidence.label_model != 'adaptive':
            self.label_model = None
            return
        model = label_model.LabelModel.from_config(fixed.compatible, config.confidence)
        if previous is not None and previous.counts.shape == model.counts.shape:
            model.counts, model.updates = previous.counts, previous.updates
        self.label_model = model
        self._label_compatibility = type(fixed)(model.compatibility(), fixed.counted)

    def learn_labels(
        self, T_target_source: np.ndarray, source: PreparedScan, target: PreparedScan
    ) -> None:
        """
        Feed an accepted pose's label co-occurrence to the adaptive label model.

        A no-op unless ``confidence.label_model`` is ``adaptive``; the odometry calls it for
        every accepted scan against its keyframe (core/estimation/label_model.py).
        """
        if self.label_model is None:
            return
        counts = label_model.cooccurrence(
            T_target_source, source, target, self.label_map.num_classes, self.config.verification
        )
        self.label_model.update(counts)
        fixed = self._label_compatibility
        self._label_compatibility = type(fixed)(self.label_model.compatibility(), fixed.counted)

    @staticmethod
    def check(config: RegistrationConfig, label_map: LabelMap) -> None:
        """Raise ConfigError if ``config`` names a class ``label_map`` lacks; no side effects."""
        _ResolvedClasses.of(config, label_map)

    # ------------------------------------------------------------------------------
    def prepare(
        self,
        points: np.ndarray,
        labels: np.ndarray,
        *,
        keypoints: np.ndarray | None = None,
        descriptors: np.ndarray | None = None,
        voxelize: bool = True,
        lazy: bool = False,
    ) -> PreparedScan:
        """
        Prepare one scan: sanitize, learning ids, voxels, keypoints, descriptors, signatures.

        Points with a non-finite coordinate or outside ``features.min_range ..
        features.max_range`` are dropped first, and labels outside the scheme become
        unlabeled; both are counted in ``input_stats``.

        ``keypoints`` (M, 3) and ``descriptors`` (M, D) may be given (e.g. GEDI from a
        pair file); keypoints without descriptors get FPFH at their nearest scan point.
        Keypoints whose descriptor is non-finite or all-zero are dropped.

        ``lazy=True`` stops after the keypoints: descriptors, Local-SS, landmarks and the
        KD-tree are computed by :meth:`complete` when a registration first needs them (the
        odometry tracks most scans without one). :meth:`register` completes its scans.
        """
        cfg, timings = self.config, {}
        if isinstance(labels, Deferred):  # labels computed when first read (core/deferred.py)
            return self._prepare_deferred(points, labels, voxelize, lazy, keypoints, descriptors)
        with timed(timings, 'labels_ms'):
            # non-finite and out-of-range points out first (they would wreck the voxel grid)
            scan = sanitize_scan_for(points, labels, cfg.features)
            conversion = self.label_map.convert(scan.labels, cfg.semantic.label_scheme)
        points, labels = scan.points, conversion.ids
        input_stats = {
            **scan.dropped_counts(),
            'label_scheme': conversion.scheme,
            'labels_out_of_scheme': conversion.out_of_scheme,
        }
        if voxelize and cfg.features.voxel_size > 0:
            with timed(timings, 'voxelize_ms'):
                points, labels = features.voxel_downsample(points, labels, cfg.features.voxel_size)
        return self._prepared(points, labels, keypoints, descriptors, timings, input_stats, lazy)

    def _prepare_deferred(
        self,
        points: np.ndarray,
        labels: Deferred[np.ndarray],
        voxelize: bool,
        lazy: bool,
        keypoints: np.ndarray | None,
        descriptors: np.ndarray | None,
    ) -> PreparedScan:
        """
        :meth:`prepare` with labels that arrive later: the points now, the labels when read.

        The same points, and on first read the same labels, as :meth:`prepare` with the
        computed labels: the voxels' majority of the kept points' converted labels.
        """
        cfg, timings = self.config, {}
        with timed(timings, 'labels_ms'):
            scan = sanitize_scan_for(points, None, cfg.features)
        points, keep, scheme = scan.points, scan.keep, cfg.semantic.label_scheme
        input_stats = scan.dropped_counts()
        voxelized = voxelize and cfg.features.voxel_size > 0
        inverse, count = None, 0
        if voxelized and points.shape[0]:
            with timed(timings, 'voxelize_ms'):
                points, inverse = features.voxel_centroids(points, cfg.features.voxel_size)
            count = points.shape[0]

        def prepared_labels(raw: np.ndarray) -> np.ndarray:
            conversion = self.label_map.convert(np.asarray(raw).reshape(-1)[keep], scheme)
            input_stats['label_scheme'] = conversion.scheme
            input_stats['labels_out_of_scheme'] = conversion.out_of_scheme
            if inverse is None:  # as voxel_downsample: int32 for an empty scan
                return conversion.ids.astype(np.int32) if voxelized else conversion.ids
            return features.voxel_majority(inverse, count, conversion.ids)

        labels = labels.then(prepared_labels)
        return self._prepared(points, labels, keypoints, descriptors, timings, input_stats, lazy)

    def _prepared(
        self,
        points: np.ndarray,
        labels: np.ndarray | Deferred[np.ndarray],
        keypoints: np.ndarray | None,
        descriptors: np.ndarray | None,
        timings: dict[str, float],
        input_stats: dict[str, Any],
        lazy: bool,
    ) -> PreparedScan:
        """Sample the keypoints and make the (lazy) prepared scan of :meth:`prepare`."""
        cfg = self.config
        tree = None
        with timed(timings, 'keypoints_ms'):
            if keypoints is None:
                kp = cfg.keypoints
                indices = features.sample_keypoints(
                    points, kp.count, kp.sampling, kp.voxel_size, kp.seed
                )
                keypoints = points[indices]
            else:
                keypoints = np.asarray(keypoints, dtype=np.float64).reshape(-1, 3)
                tree = signatures.search_tree(points)
                indices = tree.query(keypoints)[1].astype(np.int64)
        prepared = PreparedScan(
            points,
            labels,
            keypoints,
            indices,
            np.zeros((len(keypoints), 0), dtype=np.float32),
            np.zeros((len(keypoints), self.label_map.num_classes), dtype=bool),
            Landmarks.empty(),
            timings,
            {},
            input_stats,
        )
        # no reference to the scan itself: a lazy scan that is never completed is freed
        # by reference counting, not only by the cyclic garbage collector
        prepared.pending_features = functools.partial(self._describe, descriptors, tree)
        if not lazy:
            self.complete(prepared)
        return prepared

    def complete(self, scan: PreparedScan) -> PreparedScan:
        """Compute what a ``lazy`` :meth:`prepare` left out (once; a no-op afterwards)."""
        pending, scan.pending_features = scan.pending_features, None
        if pending is not None:
            pending(scan)
        return scan

    def _describe(
        self, descriptors: np.ndarray | None, keypoint_tree: Any, scan: PreparedScan
    ) -> None:
        """Descriptors | Local-SS, landmarks and the KD-tree of ``scan``, on two threads."""
        cfg, timings = self.config, scan.timings_ms
        points, labels, keypoints = scan.points, scan.labels, scan.keypoints
        stage = 'fpfh_ms' if descriptors is None else 'descriptors_ms'

        def describe() -> np.ndarray:
            with timed(timings, stage):
                found = (
                    _fpfh(points, scan.keypoint_indices, cfg)
                    if descriptors is None
                    else descriptors
                )
                return np.asarray(found, dtype=np.float32)

        def semantics_and_tree() -> tuple[np.ndarray, Landmarks, Any]:
            with timed(timings, 'local_ss_ms'):
                local_ss = signatures.local_semantic_signature(
                    points,
                    labels,
                    keypoints,
                    cfg.semantic.local_radius,
                    self.label_map.num_classes,
                    ignored=self._ignored_ids,
                    undefined=self._undefined_ids,
                    points_tree=keypoint_tree,
                )
            with timed(timings, 'landmarks_ms'):
                marks = landmarks.extract_landmarks(
                    points,
                    labels,
                    self._landmark_ids,
                    cfg.semantic.cluster_radius,
                    cfg.semantic.cluster_min_points,
                    cfg.semantic.landmark_min_share,
                    cfg.semantic.landmark_support_radius,
                )
            with timed(timings, 'points_tree_ms'):  # for the dense scores, as a target
                tree = scan.kdtree or PreparedScan.build_points_tree(points)
            return local_ss, marks, tree

        # Descriptors | semantic signatures and the KD-tree: two threads. (small_gicp holds
        # the GIL, so the fine-alignment clouds are built later, on all cores, alone.)
        described, (local_ss, marks, tree) = _SCAN_POOL.run(
            lambda task: task(), [describe, semantics_and_tree]
        )
        valid = features.valid_descriptor_mask(described)
        scan.keypoints, scan.keypoint_indices = keypoints[valid], scan.keypoint_indices[valid]
        scan.descriptors, scan.local_ss = described[valid], local_ss[valid]
        scan.landmarks, scan.kdtree = marks, tree

    # ------------------------------------------------------------------------------
    def register(
        self, source: PreparedScan, target: PreparedScan, *, refine: bool = True
    ) -> RegistrationResult:
        """
        Register ``source`` onto ``target`` (both from :meth:`prepare`): run :attr:`stages`.

        Each stage that is :meth:`~mlsemreg_ros.core.stages.context.Stage.wanted` runs in
        order and is timed as ``<name>_ms``; the candidates a stage returns join the pool and
        face the confidence rule again (``core/stages/confidence.py``). ``refine=False``
        stops before the pair's fine alignment (the odometry refines against its local map
        instead). The fine alignment refines a refused pose too (it is the best one found;
        ``success`` stays false).

        Never worse than no labels: stage 0 judges the pair's labels and decides the one
        path it takes (core/labeling/quality.py).
        """
        self.complete(source)
        self.complete(target)
        return self._run_stages(source, target, refine)

    def _run_stages(
        self, source: PreparedScan, target: PreparedScan, refine: bool
    ) -> RegistrationResult:
        """Run :attr:`stages` on completed scans."""
        context = RegistrationContext(source, target, refine, self.config, self.scoring())
        context.label_names = self.label_map.names
        context.diagnostics.update(
            source_keypoints=len(source.keypoints), target_keypoints=len(target.keypoints)
        )
        return run_stages(context, self.stages).result()

    def scoring(self) -> Scoring:
        """Return the scores with the current config and label rule (core/stages/scoring.py)."""
        return Scoring(
            self.config,
            self._label_compatibility,
            self._distinctive,
            self._bev_channels,
            self._unlabeled_local_ss,
        )

    def judge(
        self,
        source: PreparedScan,
        target: PreparedScan,
        transform: np.ndarray,
        rivals: np.ndarray | None = None,
        source_points: np.ndarray | None = None,
        target_points: np.ndarray | None = None,
    ) -> tuple[confidence.Evidence, str]:
        """
        Judge one given pose by the confidence rule: ``(evidence, refusal)`` ('' = accepted).

        ``transform`` faces the same rule as a registration's choice: its rivals are the
        zero motion, its slides and the given ``rivals`` ``(R, 4, 4)`` (scored like the
        estimator's hypotheses). ``source_points`` / ``target_points``: ``(K, 3)``
        correspondences for the sparse evidence (none: 0 inliers). Needs the scans'
        points and labels only (a ``lazy`` :meth:`prepare` is enough).
        """
        cfg, none = self.config, np.zeros((0, 3))
        src = none if source_points is None else np.asarray(source_points, dtype=np.float64)
        dst = none if target_points is None else np.asarray(target_points, dtype=np.float64)
        scoring = self.scoring()
        measure = functools.partial(scoring.distinctive_of, source=source, target=target)
        pool = CandidatePool.of(None, measure)
        if rivals is not None and len(rivals):
            rivals = np.asarray(rivals, dtype=np.float64).reshape(-1, 4, 4)
            scored = score_hypotheses(
                rivals,
                np.arange(len(rivals)),
                src,
                dst,
                source,
                target,
                cfg.verification,
                cfg.estimator,
                self._label_compatibility,
                origin='rival',
            )
            pool = pool.extended(scored, measure)
        _, evidence = scoring.evidence(
            np.asarray(transform, dtype=np.float64), src, dst, pool, None, source, target
        )
        return evidence, confidence.refusal(evidence, cfg.confidence, cfg.estimator.min_inliers)

    def prepare_scans(self, *scans: dict[str, Any]) -> list[PreparedScan]:
        """
        Prepare several scans at once, each given as the keyword arguments of :meth:`prepare`.

        The scans are prepared concurrently on two threads (NumPy, SciPy's KD-trees and
        sparse products release the GIL): the two clouds of a KITTI pair take about 60 %
        of their sequential wall time on two cores. Each scan's stage timings are its own
        wall times, so they overlap.
        """
        return _PREPARE_POOL.run(lambda kwargs: self.prepare(**kwargs), list(scans))

    def register_scans(
        self,
        source_points: np.ndarray,
        source_labels: np.ndarray,
        target_points: np.ndarray,
        target_labels: np.ndarray,
    ) -> RegistrationResult:
        """Prepare both scans (concurrently) and register them; timings include preparation."""
        source, target = self.prepare_scans(
            {'points': source_points, 'labels': source_labels},
            {'points': target_points, 'labels': target_labels},
        )
        result = self.register(source, target)
        for scan in (source, target):
            for stage, ms in scan.timings_ms.items():
                result.timings_ms[stage] = result.timings_ms.get(stage, 0.0) + ms
        return result


_PREPARE_POOL = LazyPool('mlsemreg-prepare')  # scans of prepare_scans
_SCAN_POOL = LazyPool('mlsemreg-scan')  # stages inside one prepare (never waits on a pool)


def _fpfh(points: np.ndarray, indices: np.ndarray, cfg: RegistrationConfig) -> np.ndarray:
    """FPFH of ``points[indices]`` with the configured implementation."""
    f = cfg.features
    if f.descriptor == 'fpfh_open3d':
        return features.fpfh_open3d_at(
            points, indices, f.normal_radius, f.normal_max_nn, f.feature_radius, f.feature_max_nn
        )
    return fpfh.fpfh_at_keypoints(
        points,
        indices,
        f.normal_radius,
        f.feature_radius,
        f.support_voxel_size,
        snap=f.snap_keypoints,
    )
