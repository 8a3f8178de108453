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
Stage 1, correspondences: ML-SemReg's Group and Mask Matching, or the plain matcher.

Group Matching on Local-SS and Mask Matching on BMR-SS inside each group (the paper's
eq. 1-9, core/matching/matching.py); with ``semantic.enabled: false`` the plain nearest
neighbours of the descriptors. At most ``estimator.max_correspondences`` are kept, the
smallest descriptor distances first.
"""

from __future__ import annotations

from mlsemreg_ros.core.labeling import quality
from mlsemreg_ros.core.matching import matching
from mlsemreg_ros.core.results import Correspondences
from mlsemreg_ros.core.stages.context import RegistrationContext
import numpy as np


class MatchingStage:
    """Stage 1: the correspondences between the two scans' keypoints (``gm_mm_ms``)."""

    name = 'gm_mm'

    def wanted(self, context: RegistrationContext) -> bool:
        """Say yes: every registration starts from correspondences."""
        return True

    def run(self, context: RegistrationContext) -> None:
        """Set the correspondences, their keypoints, the matching mode and its message."""
        cfg, source, target = context.config, context.source, context.target
        if cfg.semantic.enabled:
            outcome = matching.ml_semreg(
                source, target, cfg.semantic, cfg.matcher.kind, timings=context.timings_ms
            )
            corr, context.mode, context.message = (
                outcome.correspondences,
                outcome.mode,
                outcome.message,
            )
            context.diagnostics.update(outcome.diagnostics)
            if context.label_quality is not None and context.label_quality.widen:
                plain = matching.match_descriptors(  # poorer labels: Group Matching widens
                    source.descriptors, target.descriptors, cfg.matcher.kind
                )
                corr = quality.widened(corr, plain)
        else:
            corr = matching.match_descriptors(
                source.descriptors, target.descriptors, cfg.matcher.kind
            )
            context.mode, context.message = 'plain', ''
        corr = best_ranked(corr, cfg.estimator.max_correspondences)
        context.correspondences = corr
        context.source_points = source.keypoints[corr.source]
        context.target_points = target.keypoints[corr.target]
        context.diagnostics['correspondences'] = len(corr)


def best_ranked(corr: Correspondences, cap: int) -> Correspondences:
    """Keep the ``cap`` correspondences with the smallest descriptor distance."""
    if len(corr) <= cap:
        return corr
    keep = np.sort(np.argpartition(corr.distance, cap - 1)[:cap])
    return Correspondences(corr.source[keep], corr.target[keep], corr.distance[keep])
