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
The verification's scores with one configuration, as every stage and ``judge`` use them.

:class:`Scoring` holds the config and the label rule resolved for it (the label
compatibility, adaptive or fixed; the distinctive classes), so that every stage scores a
pose the same way: the verification of the estimator's hypotheses, the dense scores, the
distinctive structure, and the confidence rule's evidence with its rivals
(core/estimation/verification.py, core/estimation/confidence.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from mlsemreg_ros.core.estimation import confidence, label_model
from mlsemreg_ros.core.estimation.refused_path import RefusedPath
from mlsemreg_ros.core.estimation.verification import (
    combined_score,
    dense_scores,
    distinctive_scores,
    LabelCompatibility,
    verify_hypotheses,
)
from mlsemreg_ros.core.poses import same_pose
from mlsemreg_ros.core.results import EstimateResult, PreparedScan, VerificationResult
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.estimation.candidates import CandidatePool


@dataclass(frozen=True)
class Scoring:
    """The scores of poses on two prepared scans under one configuration."""

    config: RegistrationConfig
    compatibility: LabelCompatibility  # the verification's label rule
    distinctive: np.ndarray  # (num_classes,) bool: confidence.distinctive_classes
    bev_channels: np.ndarray  # bev_search.channel_lookup of the config
    unlabeled_local_ss: np.ndarray  # (num_classes,) bool: the Local-SS of a scan of zeros

    def refused_path(self) -> RefusedPath:
        """Return the refused-path steps with this config (core/estimation/refused_path.py)."""
        return RefusedPath(self.config, self.compatibility, self.verify, self.dense)

    def verify(
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
            self.compatibility,
        )

    def dense(
        self, transforms: np.ndarray, source: PreparedScan, target: PreparedScan
    ) -> tuple[np.ndarray, np.ndarray]:
        """:func:`dense_scores` of ``(N, 4, 4)`` poses: ``(overlap, label agreement)``."""
        return dense_scores(
            transforms,
            source,
            target.points_tree(),
            target.labels,
            self.compatibility,
            self.config.verification,
        )

    def distinctive_of(
        self, transforms: np.ndarray, source: PreparedScan, target: PreparedScan
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:func:`distinctive_scores` (``core/estimation/verification.py``) of ``transforms``."""
        return distinctive_scores(
            transforms,
            source,
            target,
            self.distinctive,
            self.config.verification.overlap_distance,
        )

    def ceilings(self, source: PreparedScan, target: PreparedScan) -> tuple[float, float, float]:
        """
        Return the labels' ceiling, the distinctive classes' and the information ceiling.

        (core/estimation/label_model.py.) The information ceiling is measured only under the
        ``information`` label rule (poorer labels, core/labeling/quality.py), else NaN.
        """
        cfg = self.config.verification
        information = float('nan')
        if self.config.confidence.label_rule == 'information':
            information = label_model.information_ceiling(source, target, self.compatibility, cfg)
        return (
            label_model.label_ceiling(source, target, self.compatibility, cfg),
            label_model.distinctive_ceiling(
                source, target, self.distinctive, cfg.overlap_distance
            ),
            information,
        )

    def information(
        self, transform: np.ndarray, source: PreparedScan, target: PreparedScan
    ) -> float:
        """Label agreement beyond chance at ``transform`` (NaN unless the information rule)."""
        if self.config.confidence.label_rule != 'information':
            return float('nan')
        counts = label_model.cooccurrence(
            transform, source, target, len(self.compatibility.counted), self.config.verification
        )
        return label_model.information(counts, self.compatibility)

    def evidence(
        self,
        transform: np.ndarray,
        src_pts: np.ndarray,
        dst_pts: np.ndarray,
        pool: CandidatePool,
        chosen: int | None,
        source: PreparedScan,
        target: PreparedScan,
        ceilings: tuple[float, float, float] | None = None,
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
        overlap, agreement = self.dense(fresh, source, target)
        scores = combined_score(overlap, agreement, cfg.verification)
        shares, points, views = self.distinctive_of(fresh, source, target)
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
        if ceilings is None:
            ceilings = self.ceilings(source, target)
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
            *ceilings[:2],
            label_information=self.information(transform, source, target),
            information_ceiling=ceilings[2],
        )
