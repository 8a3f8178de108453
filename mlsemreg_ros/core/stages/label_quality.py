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
- poorer labels: first the unlabeled attempt (plain matching up to the confidence rule's
  verdict, what ``label_source: none`` gives); its pose is taken when accepted with strong
  geometric evidence and not vetoed by the labels' information, and the stages it ran are
  done. Otherwise the pair goes on with its labels: the verification's scores and the
  confidence rule give way to the geometric evidence (``context.config`` and
  ``context.scoring``), the labels keep a veto by their information, and the matching
  stage widens Group Matching (``context.label_quality.widen``).
"""

from __future__ import annotations

from dataclasses import replace

from mlsemreg_ros.core.estimation import label_model
from mlsemreg_ros.core.labeling import quality
from mlsemreg_ros.core.stages.confidence import ConfidenceStage
from mlsemreg_ros.core.stages.context import RegistrationContext
from mlsemreg_ros.core.stages.estimation import EstimationStage
from mlsemreg_ros.core.stages.matching import MatchingStage
from mlsemreg_ros.core.stages.verification import VerificationStage

#: The unlabeled attempt of poorer labels: the stages up to the confidence rule's verdict.
UNLABELED_FIRST = (MatchingStage(), EstimationStage(), VerificationStage(), ConfidenceStage())
#: What the unlabeled attempt hands on when its pose is taken.
_ADOPTED = (
    'correspondences',
    'source_points',
    'target_points',
    'mode',
    'message',
    'estimated',
    'transform',
    'verified',
    'pool',
    'chosen',
    'trusted',
    'ceilings',
    'inliers',
    'evidence',
    'refusal',
)
#: The unlabeled attempt's pose is taken only with this many times estimator.min_inliers
#: (docs/labels.md: at 40 m, ``--labels none`` accepts a pose 42 m off with 84 inliers;
#: the right unlabeled GEDI poses at 20 m have 155-371).
FIRST_INLIER_FACTOR = 3


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
        context.label_quality = judged
        context.diagnostics.update(judged.diagnostics)
        wildcard = context.scoring.unlabeled_local_ss
        if judged.unlabeled:  # no better than chance: matched and judged as unlabeled
            context.source = quality.unlabeled_view(context.source, wildcard)
            context.target = quality.unlabeled_view(context.target, wildcard)
            return
        if judged.widen and _unlabeled_first(context, judged):
            return
        context.config = judged.config(context.config)
        context.scoring = replace(context.scoring, config=context.config)  # scores weighed too


def _unlabeled_first(context: RegistrationContext, judged: quality.LabelQuality) -> bool:
    """
    Poorer labels: register as unlabeled first, and keep that pose if the labels allow it.

    The unlabeled attempt is what ``label_source: none`` gives up to the confidence rule's
    verdict (plain matching: one group of every keypoint, core/matching/matching.py). Its
    pose is taken when it is accepted, has ``FIRST_INLIER_FACTOR`` x
    ``estimator.min_inliers`` inliers and the labels do not veto it (their information at
    the pose reaches ``confidence.min_relative_information`` of their own); the stages it
    ran are then done. Otherwise the pair goes on with its labels, weighed.
    """
    wildcard = context.scoring.unlabeled_local_ss
    # no second SC2-PCR on the full graph: it runs when the sampled one found fewer inliers
    # than estimator.graph_retry_inliers, far below what the attempt needs to be kept
    quick = replace(
        context.config, estimator=replace(context.config.estimator, graph_retry_inliers=0)
    )
    attempt = RegistrationContext(
        quality.unlabeled_view(context.source, wildcard),
        quality.unlabeled_view(context.target, wildcard),
        context.refine,
        quick,
        replace(context.scoring, config=quick),
    )
    for stage in UNLABELED_FIRST:
        if stage.wanted(attempt):
            with attempt.timed(f'unlabeled_{stage.name}'):
                stage.run(attempt)
    context.timings_ms.update(attempt.timings_ms)
    evidence, cfg = attempt.evidence, context.config
    if attempt.refusal or evidence is None:
        return False
    if evidence.num_inliers < FIRST_INLIER_FACTOR * cfg.estimator.min_inliers:
        return False
    counts = label_model.cooccurrence(
        attempt.transform,
        context.source,
        context.target,
        len(context.scoring.compatibility.counted),
        cfg.verification,
    )
    information = label_model.information(counts, context.scoring.compatibility)
    share = information / judged.information if judged.information > 0 else float('nan')
    context.diagnostics['labels_unlabeled_information'] = share
    if not share >= cfg.confidence.min_relative_information:  # the labels veto (NaN too)
        return False
    for name in _ADOPTED:
        setattr(context, name, getattr(attempt, name))
    context.source, context.target = attempt.source, attempt.target
    context.diagnostics.update(attempt.diagnostics)
    context.diagnostics['labels_unlabeled_first'] = True
    context.done.update(stage.name for stage in UNLABELED_FIRST)
    return True
