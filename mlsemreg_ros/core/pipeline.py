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

from collections.abc import Iterator
from contextlib import contextmanager
import dataclasses
from dataclasses import dataclass
import functools
import time
from typing import Any

from mlsemreg_ros.core import threads
from mlsemreg_ros.core.alignment.alignment import align_pair, Alignment
from mlsemreg_ros.core.alignment.fine_alignment import (
    alignment_cloud,
    correction_refusal,
    refinement_refusal,
    RefinementBounds,
)
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.estimation import bev_search, confidence, label_model
from mlsemreg_ros.core.estimation.estimation import estimate
from mlsemreg_ros.core.estimation.refused_path import RefusedPath
from mlsemreg_ros.core.estimation.verification import (
    combined_score,
    dense_scores,
    distinctive_scores,
    label_compatibility,
    LabelCompatibility,
    score_hypotheses,
    verify_hypotheses,
)
from mlsemreg_ros.core.features import features, fpfh
from mlsemreg_ros.core.features.scan_input import sanitize_scan_for
from mlsemreg_ros.core.labeling import quality as label_quality
from mlsemreg_ros.core.matching import landmarks, matching, signatures
from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.poses import same_pose
from mlsemreg_ros.core.results import (
    Correspondences,
    EstimateResult,
    HypothesisScore,
    Landmarks,
    PreparedScan,
    RegistrationResult,
    VerificationResult,
)
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


@contextmanager
def _timed(timings: dict[str, float], stage: str) -> Iterator[None]:
    start = time.perf_counter()
    yield
    timings[stage] = timings.get(stage, 0.0) + 1e3 * (time.perf_counter() - start)


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
        self._wildcard = np.ones(self.label_map.num_classes, dtype=bool)  # Local-SS of no labels
        self._wildcard[np.r_[resolved.ignored_ids, resolved.undefined_ids]] = False
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
        with _timed(timings, 'labels_ms'):
            # non-finite and out-of-range points out first (they would wreck the voxel grid)
            scan = sanitize_scan_for(points, labels, cfg.features)
            conversion = self.label_map.convert(scan.labels, cfg.semantic.label_scheme)
        points, labels = scan.points, conversion.ids
        input_stats = {
            'dropped_nonfinite': scan.dropped_nonfinite,
            'dropped_far': scan.dropped_far,
            'dropped_near': scan.dropped_near,
            'label_scheme': conversion.scheme,
            'labels_out_of_scheme': conversion.out_of_scheme,
        }
        if voxelize and cfg.features.voxel_size > 0:
            with _timed(timings, 'voxelize_ms'):
                points, labels = features.voxel_downsample(points, labels, cfg.features.voxel_size)
        tree = None
        with _timed(timings, 'keypoints_ms'):
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
            with _timed(timings, stage):
                found = (
                    _fpfh(points, scan.keypoint_indices, cfg)
                    if descriptors is None
                    else descriptors
                )
                return np.asarray(found, dtype=np.float32)

        def semantics_and_tree() -> tuple[np.ndarray, Landmarks, Any]:
            with _timed(timings, 'local_ss_ms'):
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
            with _timed(timings, 'landmarks_ms'):
                marks = landmarks.extract_landmarks(
                    points,
                    labels,
                    self._landmark_ids,
                    cfg.semantic.cluster_radius,
                    cfg.semantic.cluster_min_points,
                    cfg.semantic.landmark_min_share,
                    cfg.semantic.landmark_support_radius,
                )
            with _timed(timings, 'points_tree_ms'):  # for the dense scores, as a target
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
        Register ``source`` onto ``target`` (both from :meth:`prepare`).

        ``refine=False`` stops after the estimator (the odometry refines against its local
        map instead of the target scan). The fine alignment refines a refused pose too (it
        is the best one found; ``success`` stays false).

        Never worse than no labels (core/labeling/quality.py): a pair whose labels are no
        better than chance is registered as unlabeled; a pair with poorer labels that is
        refused is registered again as unlabeled, and that result is taken if accepted.
        """
        self.complete(source)
        self.complete(target)
        judged = label_quality.judge(source, target, self.config, self._label_compatibility)
        if judged.unlabeled:  # no better than chance: matched and judged as unlabeled
            return self._register(*self._unlabeled(source, target), refine, judged)
        result = self._register(source, target, refine, judged)
        if result.success or not judged.widen:
            return result
        plain = self._register(*self._unlabeled(source, target), refine, judged.as_unlabeled())
        return plain if plain.success else result

    def _unlabeled(
        self, source: PreparedScan, target: PreparedScan
    ) -> tuple[PreparedScan, PreparedScan]:
        """Both scans without labels (core/labeling/quality.py)."""
        return (
            label_quality.unlabeled_view(source, self._wildcard),
            label_quality.unlabeled_view(target, self._wildcard),
        )

    def _register(
        self,
        source: PreparedScan,
        target: PreparedScan,
        refine: bool,
        judged: label_quality.LabelQuality,
    ) -> RegistrationResult:
        """:meth:`register` of completed scans with their labels judged (``judged``)."""
        cfg, timings = judged.config(self.config), {}
        diagnostics: dict = {
            'source_keypoints': len(source.keypoints),
            'target_keypoints': len(target.keypoints),
            **judged.diagnostics,
        }
        # 1. correspondences: ML-SemReg (GM o MM) or the plain matcher
        with _timed(timings, 'gm_mm_ms'):
            if cfg.semantic.enabled:
                outcome = matching.ml_semreg(
                    source, target, cfg.semantic, cfg.matcher.kind, timings=timings
                )
                corr, mode, message = outcome.correspondences, outcome.mode, outcome.message
                diagnostics.update(outcome.diagnostics)
                if judged.widen:  # poorer labels: Group Matching widens (core/labeling/quality.py)
                    plain = matching.match_descriptors(
                        source.descriptors, target.descriptors, cfg.matcher.kind
                    )
                    corr = label_quality.widened(corr, plain)
            else:
                corr = matching.match_descriptors(
                    source.descriptors, target.descriptors, cfg.matcher.kind
                )
                mode, message = 'plain', ''
        corr = _best_ranked(corr, cfg.estimator.max_correspondences)
        src_pts, dst_pts = source.keypoints[corr.source], target.keypoints[corr.target]
        diagnostics['correspondences'] = len(corr)
        # 2. robust estimation (SC2-PCR by default)
        with _timed(timings, 'estimator_ms'):
            estimate_result = estimate(src_pts, dst_pts, cfg.estimator)
        transform = estimate_result.transform
        diagnostics.update(estimate_result.diagnostics)
        # 2b. hypothesis verification on the dense labeled scans (core/estimation/verification.py)
        verified = None
        if cfg.verification.enabled:
            with _timed(timings, 'verification_ms'):
                verified = self._verify(estimate_result, src_pts, dst_pts, source, target)
            transform = verified.T_target_source
            diagnostics.update(verified.diagnostics)
        # 2c. confidence: sparse and dense evidence must agree, no rival may come close
        # (core/estimation/confidence.py, docs/hard_pairs.md)
        with _timed(timings, 'confidence_ms'):
            measure = functools.partial(self._distinctive_of, source=source, target=target)
            ceilings = self._ceilings(source, target)
            trusted = confidence.objects_trusted(ceilings[1], cfg.confidence)
            pool = _Pool.of(verified, measure)
            chosen = pool.decide(pool.incumbent, cfg, trusted) if pool else None
            if chosen is not None:
                transform = pool.hypotheses[chosen].T_target_source
            inliers, evidence = self._evidence(
                transform, src_pts, dst_pts, pool, chosen, source, target, ceilings
            )
        refused = confidence.refusal(evidence, cfg.confidence, cfg.estimator.min_inliers)
        # 2d. refused or weak: search the scans themselves (core/estimation/bev_search.py); 2e.
        # still
        # refused: match again around the best peaks (core/estimation/guided.py). Every new
        # candidate
        # joins the pool, the choice and the rivals.
        weak = evidence.num_inliers < cfg.bev_search.weak_inliers
        if (refused or weak) and verified is not None and cfg.bev_search.enabled:
            first = f'refused: {refused}' if refused else f'{evidence.num_inliers} inliers'
            with _timed(timings, 'bev_search_ms'):
                searched = bev_search.search_scans(
                    source,
                    target,
                    src_pts,
                    dst_pts,
                    cfg,
                    self._label_compatibility,
                    self._bev_channels,
                )
            diagnostics['bev_search_used'] = False
            stages = []
            if searched is not None:
                diagnostics.update(searched.diagnostics)
                stages.append(searched)
            # still refused: the next stage, cheapest first (docs/hard_pairs.md)
            refused_path = self._refused_path()
            pending = refused_path.stages(estimate_result, len(src_pts))
            for found in stages:
                with _timed(timings, 'confidence_ms'):
                    pool = pool.extended(found, measure)
                    chosen = pool.decide(chosen, cfg, trusted)
                    transform = pool.hypotheses[chosen].T_target_source
                    inliers, evidence = self._evidence(
                        transform, src_pts, dst_pts, pool, chosen, source, target, ceilings
                    )
                refused = confidence.refusal(evidence, cfg.confidence, cfg.estimator.min_inliers)
                while refused and pending and found is stages[-1]:
                    stage = pending.pop(0)
                    with _timed(timings, f'{stage}_ms'):
                        extra = refused_path.run(
                            stage,
                            (source, target),
                            (src_pts, dst_pts),
                            pool,
                            searched,
                            refine,
                            diagnostics,
                        )
                    if extra is not None and extra.hypotheses:
                        stages.append(extra)
            origin = pool.origin(chosen)
            diagnostics['bev_search_used'] = origin == 'bev_search'
            diagnostics['chosen_origin'] = origin
            if origin != 'estimator':
                message = f"{origin} pose (the estimator's was {first})"
        diagnostics.update(evidence.as_diagnostics())
        success = not refused
        if refused:
            message = refused + (f'; {message}' if message else '')
        # 3. fine alignment of the scans (GICP/VGICP), from the (verified) estimate
        estimated, alignment = transform, None
        if refine and np.all(np.isfinite(transform)) and cfg.fine.pair_method != 'off':
            with _timed(timings, 'fine_ms'):
                alignment = align_pair(
                    alignment_cloud(source, cfg.fine, pair=True),
                    alignment_cloud(target, cfg.fine, pair=True),
                    transform,
                    cfg.fine,
                    cfg.fine.pair_method,
                )
            bounds = RefinementBounds.of(cfg.odometry)
            refused = refinement_refusal(alignment, bounds)
            diagnostics.update(
                fine_inlier_fraction=alignment.inlier_fraction,
                fine_iterations=alignment.iterations,
                fine_refused=refused or '',
            )
            doubtful = correction_refusal(alignment, bounds)
            if doubtful and success:  # the coarse pose was not right to the bounds
                success, message = False, doubtful + (f'; {message}' if message else '')
            if refused and self._refused_path().refinement_holds(
                alignment.T_target_source, transform, source, target
            ):
                # the refinement is the best pose found when it holds the dense score: at
                # 40-60 m the true overlap stays under odometry.min_inlier_fraction. (An
                # accepted pose it moved beyond the correction bounds is refused above.)
                # docs/hard_pairs.md
                diagnostics['fine_refused_kept'] = True
                refused = ''
            if not refused:
                transform = alignment.T_target_source
                alignment, degenerate = self._degeneracy(alignment, diagnostics)
                if degenerate and success:
                    success, message = False, degenerate + (f'; {message}' if message else '')
        return RegistrationResult(
            transform,
            corr,
            src_pts,
            dst_pts,
            inliers,
            success,
            mode,
            message,
            timings,
            diagnostics,
            estimated,
            alignment,
        )

    def _evidence(
        self,
        transform: np.ndarray,
        src_pts: np.ndarray,
        dst_pts: np.ndarray,
        pool: _Pool,
        chosen: int | None,
        source: PreparedScan,
        target: PreparedScan,
        ceilings: tuple[float, float] | None = None,
    ) -> tuple[np.ndarray, confidence.Evidence]:
        """
        Inlier mask and the evidence of ``transform`` (``pool.hypotheses[chosen]`` or new).

        Besides the sparse and dense scores: the distinctive structure it lines up and its
        best rival (other candidates of ``pool``, the zero motion, its slides;
        :mod:`mlsemreg_ros.core.estimation.confidence`).
        """
        cfg = self.config
        residual = np.linalg.norm(
            src_pts @ transform[:3, :3].T + transform[:3, 3] - dst_pts, axis=1
        )
        inliers = residual < cfg.estimator.inlier_threshold
        if not np.all(np.isfinite(transform)):
            return inliers, confidence.Evidence(
                int(inliers.sum()), len(src_pts), 0.0, 0.0, confidence.tilt_deg(transform)
            )
        # rivals: the pool's distinct candidates, then the zero motion and the slides
        conf = cfg.confidence
        extra = [np.eye(4)[None], confidence.slid_poses(transform, conf.slide_distance)]
        extra_names = ['zero motion'] + [f'slide {conf.slide_distance:g} m'] * 8
        if conf.slide_distance <= 0:
            extra, extra_names = extra[:1], extra_names[:1]
        fresh = (
            np.concatenate([transform[None], *extra]) if chosen is None else np.concatenate(extra)
        )
        overlap, agreement = self._dense(fresh, source, target)
        scores = combined_score(overlap, agreement, cfg.verification)
        shares, points, views = self._distinctive_of(fresh, source, target)
        if chosen is None:
            own = (
                float(overlap[0]),
                float(agreement[0]),
                float(scores[0]),
                float(shares[0]),
                int(points[0]),
                int(views[0]),
            )
            overlap, agreement, scores, shares, points = (
                a[1:] for a in (overlap, agreement, scores, shares, points)
            )
        else:
            h = pool.hypotheses[chosen]
            own = (
                h.overlap,
                h.label_agreement,
                h.score,
                float(pool.shares[chosen]),
                int(pool.points[chosen]),
                int(pool.views[chosen]),
            )
        rival_T = np.concatenate([pool.transforms(), np.concatenate(extra)])
        rival_scores = np.concatenate([pool.scores(), scores])
        rival_shares = np.concatenate([pool.shares, shares])
        rival_points = np.concatenate([pool.points, points])
        names = [pool.origin(i) for i in range(len(pool.hypotheses))] + extra_names
        distinct = ~same_pose(transform, rival_T, conf.rival_rotation, conf.rival_translation)
        rival_score, rival_share, rival, rival_objects = 0.0, 0.0, '', 0
        if distinct.any():
            best = int(np.argmax(np.where(distinct, rival_scores, -np.inf)))
            rival_score, rival = float(rival_scores[best]), names[best]
            close = distinct & (rival_scores >= (1.0 - conf.ambiguity_margin) * own[2])
            rival_share = float(rival_shares[close].max()) if close.any() else 0.0
            rival_objects = int(rival_points[close].max()) if close.any() else 0
        return inliers, confidence.Evidence(
            int(inliers.sum()),
            len(src_pts),
            float(own[0]),
            float(own[1]),
            confidence.tilt_deg(transform),
            float(own[2]),
            own[4],
            own[5],
            own[3],
            rival_score,
            rival_share,
            rival,
            rival_objects,
            *(self._ceilings(source, target) if ceilings is None else ceilings),
        )

    def _ceilings(self, source: PreparedScan, target: PreparedScan) -> tuple[float, float]:
        """Return the labels' ceiling and the distinctive classes' (estimation/label_model.py)."""
        cfg = self.config.verification
        return (
            label_model.label_ceiling(source, target, self._label_compatibility, cfg),
            label_model.distinctive_ceiling(
                source, target, self._distinctive, cfg.overlap_distance
            ),
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
        measure = functools.partial(self._distinctive_of, source=source, target=target)
        pool = _Pool.of(None, measure)
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
        _, evidence = self._evidence(
            np.asarray(transform, dtype=np.float64), src, dst, pool, None, source, target
        )
        return evidence, confidence.refusal(evidence, cfg.confidence, cfg.estimator.min_inliers)

    def _refused_path(self) -> RefusedPath:
        """Return the refused-path stages with this config (core/estimation/refused_path.py)."""
        return RefusedPath(self.config, self._label_compatibility, self._verify, self._dense)

    def _verify(
        self,
        estimated: EstimateResult,
        src_pts: np.ndarray,
        dst_pts: np.ndarray,
        source: PreparedScan,
        target: PreparedScan,
    ) -> VerificationResult:
        """:func:`verify_hypotheses` of ``estimated`` on these scans with this config."""
        cfg = self.config
        return verify_hypotheses(
            estimated,
            src_pts,
            dst_pts,
            source,
            target,
            cfg.verification,
            cfg.estimator,
            self._label_compatibility,
        )

    def _dense(
        self, transforms: np.ndarray, source: PreparedScan, target: PreparedScan
    ) -> tuple[np.ndarray, np.ndarray]:
        """:func:`dense_scores` of ``(N, 4, 4)`` poses: ``(overlap, label agreement)``."""
        return dense_scores(
            transforms,
            source,
            target.points_tree(),
            target.labels,
            self._label_compatibility,
            self.config.verification,
        )

    def _distinctive_of(
        self, transforms: np.ndarray, source: PreparedScan, target: PreparedScan
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:func:`distinctive_scores` (``core/estimation/verification.py``) of ``transforms``."""
        return distinctive_scores(
            transforms,
            source,
            target,
            self._distinctive,
            self.config.verification.overlap_distance,
        )

    def _degeneracy(
        self, alignment: Alignment, diagnostics: dict[str, Any]
    ) -> tuple[Alignment, str]:
        """
        Localizability of the fine alignment (``degeneracy_*`` diagnostics) and its verdict.

        ``confidence.degeneracy``: ``report`` leaves the alignment as it is, ``inflate``
        returns it with the Hessian's weak translation eigenvalue divided by
        ``confidence.degeneracy_inflation`` (so every covariance derived from it grows along
        the weak direction), ``refuse`` returns the reason to refuse.
        """
        conf = self.config.confidence
        found = confidence.localizability(alignment.hessian, alignment.T_target_source[:3, :3])
        if found is None:
            return alignment, ''
        weak = found.ratio < conf.min_localizability
        diagnostics.update(found.as_diagnostics())
        diagnostics['degeneracy_weak'] = weak
        diagnostics['degeneracy_action'] = conf.degeneracy if weak else ''
        if weak and conf.degeneracy == 'inflate':
            hessian = confidence.inflated_hessian(alignment.hessian, conf.degeneracy_inflation)
            return dataclasses.replace(alignment, hessian=hessian), ''
        return alignment, confidence.degeneracy_refusal(found, conf)

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


def _best_ranked(corr: Correspondences, cap: int) -> Correspondences:
    """Keep the ``cap`` correspondences with the smallest descriptor distance."""
    if len(corr) <= cap:
        return corr
    keep = np.sort(np.argpartition(corr.distance, cap - 1)[:cap])
    return Correspondences(corr.source[keep], corr.target[keep], corr.distance[keep])


@dataclasses.dataclass
class _Pool:
    """
    Every verified candidate pose of one registration, with its distinctive structure.

    The estimator's hypotheses (verification) and, once it ran, the BEV search's peaks.
    """

    hypotheses: list[HypothesisScore]
    shares: np.ndarray  # (N,) distinctive share (core/verification.distinctive_scores)
    points: np.ndarray  # (N,) distinctive objects lined up
    views: np.ndarray  # (N,) distinctive objects in the target's view
    incumbent: int = 0  # the verification's choice

    @classmethod
    def of(cls, verified: VerificationResult | None, measure: Any) -> _Pool:
        """Pool the verification's candidates (an empty pool without verification)."""
        if verified is None:
            return cls([], np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
        pool = cls(
            [],
            np.zeros(0),
            np.zeros(0, dtype=np.int64),
            np.zeros(0, dtype=np.int64),
            verified.chosen,
        )
        return pool.extended(verified, measure)

    def __bool__(self) -> bool:
        """Tell whether the pool holds a candidate."""
        return bool(self.hypotheses)

    def extended(self, result: VerificationResult, measure: Any) -> _Pool:
        """
        Return this pool with ``result``'s hypotheses added.

        ``measure(transforms)`` gives their distinctive ``(shares, objects, in_view)``.
        """
        added = np.stack([h.T_target_source for h in result.hypotheses])
        shares, points, views = measure(added)
        return _Pool(
            self.hypotheses + list(result.hypotheses),
            np.concatenate([self.shares, shares]),
            np.concatenate([self.points, points]),
            np.concatenate([self.views, views]),
            self.incumbent,
        )

    def transforms(self) -> np.ndarray:
        """``(N, 4, 4)`` candidate poses."""
        if not self.hypotheses:
            return np.zeros((0, 4, 4))
        return np.stack([h.T_target_source for h in self.hypotheses])

    def scores(self) -> np.ndarray:
        """``(N,)`` verification scores."""
        return np.array([h.score for h in self.hypotheses], dtype=np.float64)

    def origin(self, index: int) -> str:
        """Where candidate ``index`` came from ('estimator' or 'bev_search')."""
        return self.hypotheses[index].origin

    def decide(self, incumbent: int, config: RegistrationConfig, trusted: bool = True) -> int:
        """
        Return the candidate to keep: the best score, then the distinctive structure decides.

        ``incumbent`` is kept unless another scores more than ``verification.min_gain``
        higher. Then, among the candidates scoring at least ``1 - confidence.decide_margin``
        of the winner, those that are *decided* (at least ``confidence.min_distinctive_objects``
        distinctive objects lined up, and ``confidence.min_distinctive_fraction`` of those in
        the target view) replace an undecided winner, and one that lines up more objects
        replaces a decided winner (most objects first, then the best score): at 40 m the
        zero-motion slide overlaps more than the truth, but lines up none of its poles
        (docs/hard_pairs.md). Only while the objects are ``trusted``
        (:func:`~mlsemreg_ros.core.estimation.confidence.objects_trusted`): with flipped
        labels they line up by chance, and the best score decides.
        """
        conf, scores = config.confidence, self.scores()
        best = int(np.argmax(scores))
        winner = (
            best
            if scores[best] > scores[incumbent] * (1.0 + config.verification.min_gain)
            else incumbent
        )
        decided = (
            (self.points >= conf.min_distinctive_objects)
            & (self.points >= conf.min_distinctive_fraction * self.views)
            & trusted
        )
        eligible = decided & (scores >= (1.0 - conf.decide_margin) * scores[winner])
        if eligible.any() and not decided[winner]:
            # the most distinctive objects lined up, then the best score
            key = np.where(eligible, self.points + scores / (scores.max() + 1.0), -np.inf)
            winner = int(np.argmax(key))
        elif eligible.any():
            better = eligible & (self.points > self.points[winner])
            if better.any():
                key = np.where(better, self.points + scores / (scores.max() + 1.0), -np.inf)
                winner = int(np.argmax(key))
        return winner
