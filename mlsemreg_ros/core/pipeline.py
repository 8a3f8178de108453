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

    prepare(scan)      voxelize, keypoints, descriptors, Local-SS, landmarks  (cached per scan)
    register(src, dst) ML-SemReg correspondences -> robust estimator -> verification
                       on the dense scans -> optional ICP

:meth:`Registration.prepare` is separate so a node can keep its keyframe's
prepared scan and pay only for the new scan on every frame.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
import time
from typing import Any

from mlsemreg_ros.core import features, fpfh, landmarks, matching, signatures
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.estimation import estimate, refine_icp
from mlsemreg_ros.core.labels import LabelMap
from mlsemreg_ros.core.results import (
    Correspondences,
    Landmarks,
    PreparedScan,
    RegistrationResult,
)
from mlsemreg_ros.core.threads import LazyPool
from mlsemreg_ros.core.verification import label_compatibility, verify_hypotheses
import numpy as np


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

    def __init__(self, config: RegistrationConfig | None = None,
                 label_map: LabelMap | None = None) -> None:
        self.label_map = label_map if label_map is not None else LabelMap.load()
        self.config = config if config is not None else RegistrationConfig()

    @property
    def config(self) -> RegistrationConfig:
        """Return the active configuration."""
        return self._config

    @config.setter
    def config(self, config: RegistrationConfig) -> None:
        sem = config.semantic
        # Resolve class names once; unknown names raise ConfigError here.
        self._landmark_ids = self.label_map.ids_of(sem.landmark_classes)
        self._ignored_ids = self.label_map.ids_of(sem.ignored_classes)
        self._undefined_ids = self.label_map.ids_of(sem.undefined_classes)
        self._label_compatibility = label_compatibility(self.label_map, config.verification)
        self._config = config

    # ------------------------------------------------------------------------------
    def prepare(self, points: np.ndarray, labels: np.ndarray, *,
                keypoints: np.ndarray | None = None,
                descriptors: np.ndarray | None = None,
                voxelize: bool = True) -> PreparedScan:
        """
        Prepare one scan: learning ids, voxels, keypoints, descriptors, signatures, landmarks.

        ``keypoints`` (M, 3) and ``descriptors`` (M, D) may be given (e.g. GEDI from a
        pair file); keypoints without descriptors get FPFH at their nearest scan point.
        Keypoints whose descriptor is non-finite or all-zero are dropped.
        """
        cfg, timings = self.config, {}
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        with _timed(timings, 'labels_ms'):
            labels = self.label_map.to_learning(labels, cfg.semantic.label_scheme)
        if voxelize and cfg.features.voxel_size > 0:
            with _timed(timings, 'voxelize_ms'):
                points, labels = features.voxel_downsample(points, labels, cfg.features.voxel_size)
        tree = None
        with _timed(timings, 'keypoints_ms'):
            if keypoints is None:
                kp = cfg.keypoints
                indices = features.sample_keypoints(points, kp.count, kp.sampling,
                                                    kp.voxel_size, kp.seed)
                keypoints = points[indices]
            else:
                keypoints = np.asarray(keypoints, dtype=np.float64).reshape(-1, 3)
                tree = signatures.search_tree(points)
                indices = tree.query(keypoints)[1].astype(np.int64)
        stage = 'fpfh_ms' if descriptors is None else 'descriptors_ms'

        def describe() -> np.ndarray:
            with _timed(timings, stage):
                found = _fpfh(points, indices, cfg) if descriptors is None else descriptors
                return np.asarray(found, dtype=np.float32)

        def semantics() -> tuple[np.ndarray, Landmarks]:
            with _timed(timings, 'local_ss_ms'):
                local_ss = signatures.local_semantic_signature(
                    points, labels, keypoints, cfg.semantic.local_radius,
                    self.label_map.num_classes, ignored=self._ignored_ids,
                    undefined=self._undefined_ids, points_tree=tree)
            with _timed(timings, 'landmarks_ms'):
                marks = landmarks.extract_landmarks(points, labels, self._landmark_ids,
                                                    cfg.semantic.cluster_radius,
                                                    cfg.semantic.cluster_min_points)
            return local_ss, marks

        # Descriptors and the semantic signatures are independent: two threads.
        described, (local_ss, marks) = _SCAN_POOL.run(lambda task: task(), [describe, semantics])
        valid = features.valid_descriptor_mask(described)
        keypoints, indices = keypoints[valid], indices[valid]
        descriptors, local_ss = described[valid], local_ss[valid]
        return PreparedScan(points, labels, keypoints, indices, descriptors, local_ss, marks,
                            timings)

    # ------------------------------------------------------------------------------
    def register(self, source: PreparedScan, target: PreparedScan) -> RegistrationResult:
        """Register ``source`` onto ``target`` (both from :meth:`prepare`)."""
        cfg, timings = self.config, {}
        diagnostics: dict = {'source_keypoints': len(source.keypoints),
                             'target_keypoints': len(target.keypoints)}
        # 1. correspondences: ML-SemReg (GM o MM) or the plain matcher
        with _timed(timings, 'gm_mm_ms'):
            if cfg.semantic.enabled:
                outcome = matching.ml_semreg(source, target, cfg.semantic, cfg.matcher.kind,
                                             timings=timings)
                corr, mode, message = outcome.correspondences, outcome.mode, outcome.message
                diagnostics.update(outcome.diagnostics)
            else:
                corr = matching.match_descriptors(source.descriptors, target.descriptors,
                                                  cfg.matcher.kind)
                mode, message = 'plain', ''
        corr = _best_ranked(corr, cfg.estimator.max_correspondences)
        src_pts, dst_pts = source.keypoints[corr.source], target.keypoints[corr.target]
        diagnostics['correspondences'] = len(corr)
        # 2. robust estimation (SC2-PCR by default)
        with _timed(timings, 'estimator_ms'):
            estimate_result = estimate(src_pts, dst_pts, cfg.estimator)
        transform = estimate_result.transform
        diagnostics.update(estimate_result.diagnostics)
        # 2b. hypothesis verification on the dense labeled scans (core/verification.py)
        if cfg.verification.enabled:
            with _timed(timings, 'verification_ms'):
                verified = verify_hypotheses(estimate_result, src_pts, dst_pts, source, target,
                                             cfg.verification, cfg.estimator,
                                             self._label_compatibility)
            transform = verified.T_target_source
            diagnostics.update(verified.diagnostics)
        # 3. optional point-to-plane ICP on the scans
        if cfg.refine.icp and len(corr) > 0:
            with _timed(timings, 'icp_ms'):
                transform = refine_icp(source.points, target.points, transform, cfg.refine,
                                       cfg.features.normal_radius)
        residual = np.linalg.norm(src_pts @ transform[:3, :3].T + transform[:3, 3] - dst_pts,
                                  axis=1)
        inliers = residual < cfg.estimator.inlier_threshold
        success = int(inliers.sum()) >= cfg.estimator.min_inliers
        if not success:
            message = (f'{int(inliers.sum())} inliers < estimator.min_inliers='
                       f'{cfg.estimator.min_inliers}' + (f'; {message}' if message else ''))
        return RegistrationResult(transform, corr, src_pts, dst_pts, inliers, success, mode,
                                  message, timings, diagnostics)

    def prepare_scans(self, *scans: dict[str, Any]) -> list[PreparedScan]:
        """
        Prepare several scans at once, each given as the keyword arguments of :meth:`prepare`.

        The scans are prepared concurrently on two threads (NumPy, SciPy's KD-trees and
        sparse products release the GIL): the two clouds of a KITTI pair take about 60 %
        of their sequential wall time on two cores. Each scan's stage timings are its own
        wall times, so they overlap.
        """
        return _PREPARE_POOL.run(lambda kwargs: self.prepare(**kwargs), list(scans))

    def register_scans(self, source_points: np.ndarray, source_labels: np.ndarray,
                       target_points: np.ndarray, target_labels: np.ndarray
                       ) -> RegistrationResult:
        """Prepare both scans (concurrently) and register them; timings include preparation."""
        source, target = self.prepare_scans(
            {'points': source_points, 'labels': source_labels},
            {'points': target_points, 'labels': target_labels})
        result = self.register(source, target)
        for scan in (source, target):
            for stage, ms in scan.timings_ms.items():
                result.timings_ms[stage] = result.timings_ms.get(stage, 0.0) + ms
        return result


_PREPARE_POOL = LazyPool('mlsemreg-prepare', 2)  # scans of prepare_scans
_SCAN_POOL = LazyPool('mlsemreg-scan', 2)  # stages inside one prepare (never waits on a pool)


def _fpfh(points: np.ndarray, indices: np.ndarray, cfg: RegistrationConfig) -> np.ndarray:
    """FPFH of ``points[indices]`` with the configured implementation."""
    f = cfg.features
    if f.descriptor == 'fpfh_open3d':
        return features.fpfh_open3d_at(points, indices, f.normal_radius, f.normal_max_nn,
                                       f.feature_radius, f.feature_max_nn)
    return fpfh.fpfh_at_keypoints(points, indices, f.normal_radius, f.feature_radius,
                                  f.support_voxel_size, snap=f.snap_keypoints)


def _best_ranked(corr: Correspondences, cap: int) -> Correspondences:
    """Keep the ``cap`` correspondences with the smallest descriptor distance."""
    if len(corr) <= cap:
        return corr
    keep = np.sort(np.argpartition(corr.distance, cap - 1)[:cap])
    return Correspondences(corr.source[keep], corr.target[keep], corr.distance[keep])
