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
Stage 2, the robust estimator: SC2-PCR (or RANSAC) on the correspondences.

Its hypotheses, best first, and its choice (core/estimation/estimation.py, sc2pcr.py).
"""

from __future__ import annotations

from mlsemreg_ros.core.estimation.estimation import estimate
from mlsemreg_ros.core.stages.context import RegistrationContext


class EstimationStage:
    """Stage 2: the estimator's transform and hypotheses (``estimator_ms``)."""

    name = 'estimator'

    def wanted(self, context: RegistrationContext) -> bool:
        """Say yes: every registration estimates."""
        return True

    def run(self, context: RegistrationContext) -> None:
        """Estimate ``T_target_source`` from the correspondences."""
        estimated = estimate(
            context.source_points, context.target_points, context.config.estimator
        )
        context.estimated, context.transform = estimated, estimated.transform
        context.diagnostics.update(estimated.diagnostics)
