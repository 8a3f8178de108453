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
Stage 5, the BEV search: when the pose is refused or weak, search the scans themselves.

The two scans' semantic bird's-eye views are correlated over yaw and translation and the
peaks verified like the estimator's hypotheses (core/estimation/bev_search.py); they join
the pool and face the confidence rule (docs/hard_pairs.md).
"""

from __future__ import annotations

from mlsemreg_ros.core.estimation import bev_search
from mlsemreg_ros.core.results import VerificationResult
from mlsemreg_ros.core.stages.context import RegistrationContext


class BevSearchStage:
    """Stage 5: the BEV search's verified peaks (``bev_search_ms``)."""

    name = 'bev_search'

    def wanted(self, context: RegistrationContext) -> bool:
        """``bev_search.enabled``, after a verification, for a refused or weak pose."""
        return context.refused_or_weak() and context.config.bev_search.enabled

    def run(self, context: RegistrationContext) -> VerificationResult | None:
        """Search; the verified peaks, or None without a peak."""
        context.search_reason = (
            f'refused: {context.refusal}'
            if context.refusal
            else f'{context.evidence.num_inliers} inliers'
        )
        searched = bev_search.search_scans(
            context.source,
            context.target,
            context.source_points,
            context.target_points,
            context.config,
            context.scoring.compatibility,
            context.scoring.bev_channels,
        )
        context.diagnostics['bev_search_used'] = False
        if searched is not None:
            context.diagnostics.update(searched.diagnostics)
        context.searched = searched
        return searched
