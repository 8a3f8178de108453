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
Stage 0, the labels' weight: never worse than no labels (core/labeling/quality.py).

Before the pair is matched its labels are judged (their ceiling and their source):

- labels no better than chance: both scans are replaced by views without labels, and the
  pair is matched and judged exactly as with ``label_source: none``;
- poorer labels: the verification's scores and the confidence rule give way to the
  geometric evidence (``context.config`` and ``context.scoring``), the labels keep a veto
  by their information, and the matching stage widens Group Matching
  (``context.label_quality.widen``).
"""

from __future__ import annotations

from dataclasses import replace

from mlsemreg_ros.core.labeling import quality
from mlsemreg_ros.core.stages.context import RegistrationContext


class LabelQualityStage:
    """Stage 0: weigh the pair's labels (``label_quality_ms``)."""

    name = 'label_quality'

    def wanted(self, context: RegistrationContext) -> bool:
        """Say yes: every pair's labels are judged before they are used."""
        return True

    def run(self, context: RegistrationContext) -> None:
        """Set ``context.label_quality``; unlabeled views and the weighed config if it says so."""
        judged = quality.judge(
            context.source, context.target, context.config, context.scoring.compatibility
        )
        if judged.unlabeled:  # no better than chance: matched and judged as unlabeled
            wildcard = context.scoring.unlabeled_local_ss
            context.source = quality.unlabeled_view(context.source, wildcard)
            context.target = quality.unlabeled_view(context.target, wildcard)
        context.config = judged.config(context.config)
        context.scoring = replace(context.scoring, config=context.config)  # scores weighed too
        context.label_quality = judged
        context.diagnostics.update(judged.diagnostics)
