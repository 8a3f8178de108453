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
Stage 5b, the BEV search from the other side: the scans swapped, the peaks inverted.

The BEV search (core/estimation/bev_search.py) rasterises the source within
``bev_search.radius`` and correlates it with the target. Far apart, the two directions
find different peaks: on the 60 m dev pairs the right pose was in the pool for 4 of 8
pairs one way and 1 of 8 the other. When the search left the pose refused, the search
runs again with target and source swapped; its peaks, inverted, are refined on the
pair's correspondences and verified like the forward peaks (origin
``bev_search_swapped``).
"""

from __future__ import annotations

import dataclasses

from mlsemreg_ros.core.estimation.bev_search import bev_hypotheses
from mlsemreg_ros.core.estimation.verification import refine_starts, score_hypotheses
from mlsemreg_ros.core.results import VerificationResult
from mlsemreg_ros.core.stages.context import RegistrationContext
import numpy as np


class SwappedSearchStage:
    """The BEV search with the scans swapped (``bev_search_swapped_ms``)."""

    name = 'bev_search_swapped'

    def wanted(self, context: RegistrationContext) -> bool:
        """``covisibility.swapped_search``, the BEV search ran and the pose is still refused."""
        return (
            context.config.covisibility.swapped_search
            and context.searched is not None
            and bool(context.refusal)
        )

    def run(self, context: RegistrationContext) -> VerificationResult | None:
        """Search target onto source; the inverted peaks, refined and verified."""
        cfg, source, target = context.config, context.source, context.target
        peaks, _ = bev_hypotheses(
            target.points,
            target.labels,
            source.points,
            source.labels,
            context.scoring.bev_channels,
            cfg.bev_search,
        )
        if len(peaks) == 0:
            return None
        starts = np.linalg.inv(peaks)
        refined = refine_starts(
            starts, context.source_points, context.target_points, cfg.estimator
        )
        return score_hypotheses(
            refined,
            np.arange(len(refined)),
            context.source_points,
            context.target_points,
            source,
            target,
            dataclasses.replace(cfg.verification, min_gain=0.0),
            cfg.estimator,
            context.scoring.compatibility,
            origin='bev_search_swapped',
        )
