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
Stage 6, the refused path: after a BEV search the pose is still refused.

Cheapest first (docs/hard_pairs.md), each only while the pose stays refused: guided
re-matching around the best searched peaks, SC2-PCR again on the full correspondence
graph, and the polishing of the pool's best candidates on the dense scans
(core/estimation/refused_path.py). Each returns verified candidates that join the pool.
"""

from __future__ import annotations

from mlsemreg_ros.core.results import VerificationResult
from mlsemreg_ros.core.stages.context import RegistrationContext


def _still_refused(context: RegistrationContext) -> bool:
    """Tell whether the BEV search found peaks and the confidence rule still refuses."""
    return context.searched is not None and bool(context.refusal)


class GuidedStage:
    """Guided re-matching around the best searched peaks (``guided_ms``)."""

    name = 'guided'

    def wanted(self, context: RegistrationContext) -> bool:
        """``bev_search.guided_peaks`` > 0 and still refused."""
        return _still_refused(context) and context.config.bev_search.guided_peaks > 0

    def run(self, context: RegistrationContext) -> VerificationResult | None:
        """Match again around the peaks, estimate and verify."""
        return context.scoring.refused_path().guided(
            context.source, context.target, context.searched, context.diagnostics
        )


class FullGraphStage:
    """SC2-PCR again on every correspondence, not a sample (``full_graph_ms``)."""

    name = 'full_graph'

    def wanted(self, context: RegistrationContext) -> bool:
        """``bev_search.full_graph``, SC2-PCR sampled its graph and did not retry it."""
        cfg, found = context.config, context.estimated.diagnostics
        count = len(context.source_points)
        return (
            _still_refused(context)
            and cfg.bev_search.full_graph
            and cfg.estimator.kind == 'sc2pcr'
            and found.get('graph_correspondences', count) < count
            and not found.get('graph_retried', False)
        )

    def run(self, context: RegistrationContext) -> VerificationResult | None:
        """Estimate on the full graph and verify."""
        return context.scoring.refused_path().full_graph(
            context.source,
            context.target,
            context.source_points,
            context.target_points,
            context.diagnostics,
        )


class PolishStage:
    """Polish the pool's best candidates on the dense scans (``polish_ms``)."""

    name = 'polish'

    def wanted(self, context: RegistrationContext) -> bool:
        """``bev_search.polish_candidates`` > 0 and still refused."""
        return _still_refused(context) and context.config.bev_search.polish_candidates > 0

    def run(self, context: RegistrationContext) -> VerificationResult | None:
        """Return the polished candidates, scored."""
        polished = context.scoring.refused_path().polished(
            context.source,
            context.target,
            context.source_points,
            context.target_points,
            context.pool,
            context.refine,
        )
        context.diagnostics['polished_candidates'] = len(polished.hypotheses)
        return polished
