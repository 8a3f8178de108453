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
  stage widens Group Matching (``context.label_quality.widen``);
- never worse, pair by pair: an unlabeled attempt that was accepted (and not vetoed) but
  too weak to be taken first is kept; when the labelled path ends refused, the pose falls
  back to it (:class:`UnlabeledFallbackStage`, before the tilt check): what
  ``label_source: none`` accepts, the labelled path does not lose;
- never worse, last: a pair of poorer labels still refused after every stage is registered
  once more as ``label_source: none`` registers it, every stage on the unlabeled views
  (:class:`UnlabeledRerunStage`), and takes that pose when it is accepted and the labels
  do not veto it. ``none`` accepts some pairs only in its later stages (the covisible
  acceptance, stage 9), which the unlabeled attempt does not run.
"""

from __future__ import annotations

from dataclasses import fields, replace
from typing import Any

from mlsemreg_ros.core.estimation import label_model
from mlsemreg_ros.core.labeling import quality
from mlsemreg_ros.core.poses import same_pose
from mlsemreg_ros.core.stages.confidence import ConfidenceStage
from mlsemreg_ros.core.stages.context import RegistrationContext, Stage
from mlsemreg_ros.core.stages.estimation import EstimationStage
from mlsemreg_ros.core.stages.matching import MatchingStage
from mlsemreg_ros.core.stages.runner import run_stages
from mlsemreg_ros.core.stages.verification import VerificationStage
import numpy as np

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
    ran are then done. Otherwise the pair goes on with its labels, weighed, and the attempt
    is kept for :class:`UnlabeledFallbackStage`.
    """
    # no second SC2-PCR on the full graph: it runs when the sampled one found fewer inliers
    # than estimator.graph_retry_inliers, far below what the attempt needs to be taken first
    quick = replace(
        context.config, estimator=replace(context.config.estimator, graph_retry_inliers=0)
    )
    attempt = _attempt(context, quick)
    context.unlabeled_attempt = attempt  # the labelled path's fallback
    if not _allowed(context, attempt, judged):
        return False
    if attempt.evidence.num_inliers < FIRST_INLIER_FACTOR * quick.estimator.min_inliers:
        return False
    _adopt(context, attempt)
    context.diagnostics['labels_unlabeled_first'] = True
    context.done.update(stage.name for stage in UNLABELED_FIRST)
    return True


def _unlabeled(context: RegistrationContext, config: Any) -> RegistrationContext:
    """Return a fresh context of the pair's unlabeled views with ``config``."""
    wildcard = context.scoring.unlabeled_local_ss
    return RegistrationContext(
        quality.unlabeled_view(context.source, wildcard),
        quality.unlabeled_view(context.target, wildcard),
        context.refine,
        config,
        replace(context.scoring, config=config),
    )


def _attempt(context: RegistrationContext, config: Any) -> RegistrationContext:
    """Run :data:`UNLABELED_FIRST` on unlabeled views of the pair with ``config``."""
    attempt = _unlabeled(context, config)
    for stage in UNLABELED_FIRST:
        if stage.wanted(attempt):
            with attempt.timed(f'unlabeled_{stage.name}'):
                stage.run(attempt)
    for name, ms in attempt.timings_ms.items():
        context.timings_ms[name] = context.timings_ms.get(name, 0.0) + ms
    return attempt


def _allowed(
    context: RegistrationContext, attempt: RegistrationContext, judged: quality.LabelQuality
) -> bool:
    """Whether the attempt's pose is accepted and the labels do not veto it."""
    if attempt.refusal or attempt.evidence is None:
        return False
    counts = label_model.cooccurrence(
        attempt.transform,
        context.source,
        context.target,
        len(context.scoring.compatibility.counted),
        attempt.config.verification,
    )
    information = label_model.information(counts, context.scoring.compatibility)
    share = information / judged.information if judged.information > 0 else float('nan')
    context.diagnostics['labels_unlabeled_information'] = share
    # the labels veto (NaN too)
    return bool(share >= attempt.config.confidence.min_relative_information)


def _adopt(context: RegistrationContext, attempt: RegistrationContext) -> None:
    """Hand the unlabeled attempt's pose, verdict and views on to ``context``."""
    for name in _ADOPTED:
        setattr(context, name, getattr(attempt, name))
    context.source, context.target = attempt.source, attempt.target
    context.diagnostics.update(attempt.diagnostics)


class UnlabeledFallbackStage:
    """
    Never worse, pair by pair: a refused labelled path takes the unlabeled pose.

    Poorer labels run the unlabeled attempt first (:class:`LabelQualityStage`); one that is
    accepted but has fewer than ``FIRST_INLIER_FACTOR`` x ``estimator.min_inliers`` inliers
    is not taken first (at 40 m a wrong unlabeled pose had 84), and the labelled path runs.
    When that path ends refused (the confidence rule, or a later stage's doubt), the pair
    takes what ``label_source: none`` accepts up to its confidence rule: the attempt's pose,
    or, when the attempt was refused, the attempt again with SC2-PCR's retry on the full
    graph (``estimator.graph_retry_inliers``, which the quick attempt leaves out), if that
    is accepted, the labels do not veto it, **and it is the labelled path's own pose**
    (within ``verification.distinct_rotation`` / ``distinct_translation``): two matchings
    that found the same pose. Without that last test a quick attempt's pose 42 m off (dev
    pairs 40 m apart, GEDI, 000007_000008: 50 inliers, not vetoed) was accepted. Dev pair
    000006 reversed, FPFH, geometric labels: the labelled path's right pose was refused as
    ambiguous; ``none`` accepts it (after the retry), and now the labelled path does too.
    The tilt check, the fine alignment and the near-miss check then judge the pose as any
    other (``labels_unlabeled_fallback`` and ``labels_unlabeled_agrees`` in the
    diagnostics).
    """

    name = 'unlabeled_fallback'

    def wanted(self, context: RegistrationContext) -> bool:
        """Say yes when the labelled path of poorer labels ends refused at a finite pose."""
        return (
            context.unlabeled_attempt is not None
            and bool(context.refusal or context.doubts)
            and bool(np.isfinite(context.transform).all())
        )

    def run(self, context: RegistrationContext) -> None:
        """Adopt the unlabeled pose if allowed; the labelled path's search no longer holds."""
        attempt, judged = context.unlabeled_attempt, context.label_quality
        assert attempt is not None and judged is not None  # wanted() says so
        if not _allowed(context, attempt, judged):
            retry = context.config.estimator.graph_retry_inliers
            sampled = attempt.estimated.num_inliers if attempt.estimated is not None else 0
            if not attempt.refusal or sampled >= retry:
                return  # accepted but vetoed, or the retry would not run
            quick = attempt.config
            full = replace(quick, estimator=replace(quick.estimator, graph_retry_inliers=retry))
            attempt = _attempt(context, full)
            if not _allowed(context, attempt, judged):
                return
        ver = context.config.verification
        agree = same_pose(
            context.transform,
            attempt.transform[None],
            ver.distinct_rotation,
            ver.distinct_translation,
        )
        context.diagnostics['labels_unlabeled_agrees'] = bool(agree[0])
        if not agree[0]:  # the two paths disagree: the refusal stands
            return
        _adopt(context, attempt)
        context.searched, context.search_reason = None, ''
        context.doubts.clear()
        context.diagnostics['labels_unlabeled_fallback'] = True


#: What the rerun does not hand on: the judged labels and the pair's own timings.
_NOT_ADOPTED = frozenset({'timings_ms', 'diagnostics', 'label_quality', 'unlabeled_attempt'})


class UnlabeledRerunStage:
    """
    Never worse, last: a pair of poorer labels still refused is registered as ``none`` would.

    The unlabeled attempt (:class:`LabelQualityStage`) and its fallback
    (:class:`UnlabeledFallbackStage`) cover what ``label_source: none`` decides up to its
    confidence rule. ``none`` accepts some pairs later: dev pair 000008_000009 40 m apart,
    reversed, GEDI, is accepted by its covisible acceptance (stage 9), and with 30 % of its
    labels flipped the labelled path refused it (docs/labels.md). So when every stage has
    run and the pair is still refused, the whole registration runs once more on the
    unlabeled views with the unweighed config (``stages``: the pipeline's default stages
    before this one, given at construction by ``pipeline.default_stages``; the same
    ``refine``): exactly what ``label_source: none`` does. Its pose is taken when it is
    accepted and the labels do not veto it (their information at the pose, as for the
    unlabeled attempt); ``labels_unlabeled_rerun`` in the diagnostics, its stage times as
    ``unlabeled_rerun_*``. Costs one unlabeled registration, on refused pairs only.
    """

    name = 'unlabeled_rerun'

    def __init__(self, stages: list[Stage]) -> None:
        self.stages = list(stages)  # what ``none`` runs: every stage before this one

    def wanted(self, context: RegistrationContext) -> bool:
        """Say yes when a pair of poorer labels ends refused."""
        return context.unlabeled_attempt is not None and bool(context.refusal or context.doubts)

    def run(self, context: RegistrationContext) -> None:
        """Register the unlabeled views with every stage; adopt an accepted, unvetoed pose."""
        attempt, judged = context.unlabeled_attempt, context.label_quality
        assert attempt is not None and judged is not None  # wanted() says so
        # the config before the labels' weight: the attempt's, with the full-graph retry
        quick = attempt.config
        retry = context.config.estimator.graph_retry_inliers
        config = replace(quick, estimator=replace(quick.estimator, graph_retry_inliers=retry))
        rerun = _unlabeled(context, config)
        rerun.label_names = context.label_names
        run_stages(rerun, self.stages)
        for name, ms in rerun.timings_ms.items():
            key = f'unlabeled_rerun_{name}'
            context.timings_ms[key] = context.timings_ms.get(key, 0.0) + ms
        accepted = not (rerun.refusal or rerun.doubts)
        context.diagnostics['labels_unlabeled_rerun_accepted'] = accepted
        if not accepted or rerun.evidence is None or not _allowed(context, rerun, judged):
            return
        for item in fields(rerun):
            if item.name not in _NOT_ADOPTED:
                setattr(context, item.name, getattr(rerun, item.name))
        context.diagnostics.update(rerun.diagnostics)
        context.diagnostics['labels_unlabeled_rerun'] = True
