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
Stage 3, hypothesis verification on the dense labeled scans.

The best distinct hypotheses of the estimator are scored by overlap and label agreement;
a clearly better one replaces the estimator's choice (core/estimation/verification.py).
"""

from __future__ import annotations

from mlsemreg_ros.core.stages.context import RegistrationContext


class VerificationStage:
    """Stage 3: the verified hypotheses and their choice (``verification_ms``)."""

    name = 'verification'

    def wanted(self, context: RegistrationContext) -> bool:
        """``verification.enabled``."""
        return context.config.verification.enabled

    def run(self, context: RegistrationContext) -> None:
        """Verify the estimator's hypotheses; the chosen one becomes the transform."""
        verified = context.scoring.verify(
            context.estimated,
            context.source_points,
            context.target_points,
            context.source,
            context.target,
        )
        context.verified, context.transform = verified, verified.T_target_source
        context.diagnostics.update(verified.diagnostics)
