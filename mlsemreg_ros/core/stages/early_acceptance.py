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
The gate of the refused path: the end stages tried early, on the pool found so far.

A pair that the first round refuses runs every search (the BEV search, the swapped and far
searches, the guided re-matching, the full graph, the polishing) before the end stages
judge its pose: the covisible choice, the fine alignment and the acceptance where both
scans see (stage 9). On the dev pairs 40 and 60 m apart, 28 of 68 accepted poses are
accepted by stage 9, and their pose often comes from the first searches
(docs/hard_pairs.md, "The refused path, fourth round").

After a search (the BEV, swapped and far searches and the guided re-matching; not after
the full graph and the polishing, which the end stages follow anyway), while the pose is
still refused, this stage runs the end stages on a copy
of the registration. Their verdict is taken, and the remaining searches and end stages are
skipped, only when the pose is accepted beyond doubt: by stage 9, or by the confidence rule
on its covisible overlap and then the near-miss check, and in both cases on stage 9's own
measure (8000 points) its covisible overlap beats the best distinct candidate of the pool
so far and the best slide by at least ``covisibility.early_accept_gap`` (stage 9 itself
asks ``covisibility.accept_gap``), since the searches not run would have added rivals.
Otherwise the copy is dropped and the search goes on; the trial's time is the price
(``early_accept_ms``). A trial whose covisible choice falls short of
``covisibility.accept_overlap``, or has a distinct candidate within the gap on the choice's
own measure (2000 points), stops before the fine alignment.
``covisibility.early_accept_gap`` 0: off. Only for the pair's own fine alignment
(``refine``): the odometry's global registration refines on its map and never runs stage 9.
"""

from __future__ import annotations

from collections.abc import Sequence
import dataclasses

from mlsemreg_ros.core.poses import same_pose
from mlsemreg_ros.core.results import VerificationResult
from mlsemreg_ros.core.stages.confidence import consider
from mlsemreg_ros.core.stages.context import RegistrationContext, Stage
from mlsemreg_ros.core.stages.covisibility import CovisibilityStage
from mlsemreg_ros.core.stages.covisible_acceptance import covisible_evidence
import numpy as np


class EarlyAcceptanceStage:
    """Try the end stages on the pool so far; adopt a pose stage 9 accepts beyond doubt."""

    name = 'early_accept'

    def __init__(self, end: Sequence[Stage], skipped: Sequence[str]) -> None:
        """``end``: the end stages, in order; ``skipped``: the stages an adoption makes done."""
        self.end = tuple(end)
        self.skipped = frozenset(skipped) | {self.name} | {stage.name for stage in self.end}

    def wanted(self, context: RegistrationContext) -> bool:
        """``covisibility.early_accept_gap`` > 0, ``refine``, searched and still refused."""
        covis = context.config.covisibility
        return (
            covis.early_accept_gap > 0.0
            and covis.enabled
            and covis.accept_overlap > 0.0
            and context.refine
            and context.searched is not None
            and bool(context.refusal)
            and context.pool is not None
            and bool(context.pool)
        )

    def run(self, context: RegistrationContext) -> VerificationResult | None:
        """Run the end stages on a copy; adopt its verdict if stage 9 accepts beyond doubt."""
        covis = context.config.covisibility
        trial = dataclasses.replace(
            context,
            timings_ms={},
            diagnostics=dict(context.diagnostics),
            doubts=list(context.doubts),
            done=set(context.done),
        )
        tries = int(context.diagnostics.get('covisible_early_tries', 0)) + 1
        context.diagnostics['covisible_early_tries'] = tries
        for stage in self.end:
            if stage.name in trial.done or not stage.wanted(trial):
                continue
            found = stage.run(trial)
            if found is not None and found.hypotheses:
                consider(trial, found)
            if stage.name == CovisibilityStage.name:
                context.covisible_measured = trial.covisible_measured  # the pool is the same
                context.diagnostics.setdefault('covisible_early_overlaps', []).append(
                    float(trial.diagnostics.get('covisible_overlap', float('nan')))
                )
                if not _worth_refining(context, trial):
                    return None  # no fine alignment for nothing
        if trial.refusal or trial.doubts:
            return None
        gap = _gap(trial)
        context.diagnostics['covisible_early_gap'] = gap
        if not gap >= covis.early_accept_gap:  # NaN: not beyond doubt
            return None
        for field in dataclasses.fields(context):
            if field.name not in ('timings_ms', 'diagnostics', 'done'):
                setattr(context, field.name, getattr(trial, field.name))
        context.diagnostics.update(trial.diagnostics, covisible_early_accepted=True)
        context.done.update(trial.done | self.skipped)
        return None


def _worth_refining(context: RegistrationContext, trial: RegistrationContext) -> bool:
    """
    Tell whether the trial's covisible choice may pass beyond doubt, and is new.

    Not when its covisible overlap falls short of ``covisibility.accept_overlap``, when an
    earlier trial judged the same pose (the rivals can only have grown), or when a distinct
    candidate of the pool comes within ``covisibility.early_accept_gap`` of it on the
    choice's own measure.
    """
    covis, conf = trial.config.covisibility, trial.config.confidence
    if trial.diagnostics.get('covisible_overlap', 0.0) < covis.accept_overlap:
        return False
    pose = trial.transform
    if any(np.array_equal(pose, tried) for tried in context.early_tried):
        return False
    # beyond doubt on the choice's own figures first: a distinct candidate within the gap
    overlap, checked = trial.covisible_pool
    candidates = trial.pool.transforms()
    distinct = ~same_pose(pose, candidates, conf.rival_rotation, conf.rival_translation)
    rivals = overlap[distinct & (checked >= covis.min_checked)]
    best = trial.diagnostics['covisible_overlap']
    if len(rivals) and float(rivals.max()) > best - covis.early_accept_gap:
        return False
    context.early_tried.append(pose.copy())
    return True


def _gap(trial: RegistrationContext) -> float:
    """
    Stage 9's margin: the pose's covisible overlap over its best rival or slide (NaN: none).

    A pose stage 9 accepted has it in its diagnostics. A pose the confidence rule accepted
    on its covisible overlap (the covisible choice, then the fine alignment and the
    near-miss check) is measured as stage 9 would measure it, and must pass stage 9's rule
    too (NaN when it does not).
    """
    found = trial.diagnostics
    if not found.get('covisible_accepted'):
        if trial.alignment is None or not np.array_equal(
            trial.transform, trial.alignment.T_target_source
        ):
            return float('nan')
        evidence, refusal = covisible_evidence(trial)
        if refusal:
            return float('nan')
        found = evidence.as_diagnostics()
    rival = max(found['covisible_accept_rival_overlap'], found['covisible_accept_slide_overlap'])
    return float(found['covisible_accept_overlap'] - rival)
