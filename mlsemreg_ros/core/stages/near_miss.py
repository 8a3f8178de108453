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
Stage 8, the near-miss check: an accepted pair pose must sit alone in its basin.

After the fine alignment (stage 7), the pair is aligned again from perturbed starts
(core/alignment/near_miss.py). A start that converges to another place about as good as
the refined pose disputes it: ``near_miss.action`` refuses the pose, or inflates its
covariance along the disputed direction. Runs when ``near_miss.enabled``, the pose is
accepted so far and the fine alignment refined it.
"""

from __future__ import annotations

import dataclasses

from mlsemreg_ros.core.alignment.alignment import align_pair, Alignment
from mlsemreg_ros.core.alignment.fine_alignment import alignment_cloud
from mlsemreg_ros.core.alignment.near_miss import (
    disputed_hessian,
    home_first,
    judge_basins,
    PointToDistribution,
)
from mlsemreg_ros.core.stages.context import RegistrationContext
import numpy as np


class NearMissStage:
    """Stage 8: the refined pose aligned again from perturbed starts (``near_miss_ms``)."""

    name = 'near_miss'

    def wanted(self, context: RegistrationContext) -> bool:
        """``near_miss.enabled``, accepted so far on at most ``near_miss.max_inliers``, refined."""
        check = context.config.near_miss
        strong = 0 < check.max_inliers < np.count_nonzero(context.inliers)
        return (
            check.enabled
            and not strong
            and not context.refusal
            and not context.doubts
            and context.alignment is not None
            and bool(np.array_equal(context.transform, context.alignment.T_target_source))
        )

    def run(self, context: RegistrationContext) -> None:
        """Judge the basins; refuse a disputed pose or inflate its covariance."""
        cfg = context.config
        source = alignment_cloud(context.source, cfg.fine, pair=True)
        target = alignment_cloud(context.target, cfg.fine, pair=True)
        # the perturbed starts may run on the downsampled source; the fit is the full scan's
        starts = alignment_cloud(context.source, cfg.fine, pair=not cfg.near_miss.pair_downsampled)

        def align(start: np.ndarray, iterations: int) -> Alignment:
            fine = dataclasses.replace(cfg.fine, max_iterations=iterations)
            return align_pair(starts, target, start, fine, cfg.fine.pair_method)

        verdict = judge_basins(
            context.alignment,
            home_first(align, context.alignment, cfg.near_miss, cfg.fine.max_iterations),
            PointToDistribution(source, target, cfg.fine.max_correspondence_distance),
            cfg.near_miss,
        )
        context.diagnostics.update(verdict.as_diagnostics())
        if not verdict.refusal:
            return
        if cfg.near_miss.action == 'refuse' or verdict.disputed is None:
            context.doubt(verdict.refusal)
            return
        hessian = disputed_hessian(context.alignment, verdict.disputed)
        context.alignment = dataclasses.replace(context.alignment, hessian=hessian)
        context.diagnostics['near_miss_inflated'] = True
