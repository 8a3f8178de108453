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
Stage 4, the choice and the confidence rule.

The verified candidates are pooled (core/estimation/candidates.py) and the best is chosen,
the distinctive structure deciding between close scores; then the sparse evidence
(inliers, inlier ratio) and the dense evidence (overlap, label agreement, tilt, the best
rival) must all agree, or the pose is refused (core/estimation/confidence.py,
docs/confidence.md). :func:`consider` does the same for the candidates a later stage
adds (the BEV search, the refused path): the loop of ``Registration.register`` calls it.
"""

from __future__ import annotations

import dataclasses
import functools

from mlsemreg_ros.core.estimation import chance, confidence
from mlsemreg_ros.core.estimation.candidates import CandidatePool
from mlsemreg_ros.core.results import VerificationResult
from mlsemreg_ros.core.stages.context import RegistrationContext


class ConfidenceStage:
    """Stage 4: choose among the verified candidates and judge the choice (``confidence_ms``)."""

    name = 'confidence'

    def wanted(self, context: RegistrationContext) -> bool:
        """Say yes: no pose leaves without the confidence rule's verdict."""
        return True

    def run(self, context: RegistrationContext) -> None:
        """Pool the verification's candidates, choose one, and judge it."""
        cfg, scoring = context.config, context.scoring
        context.ceilings = scoring.ceilings(context.source, context.target)
        context.trusted = confidence.objects_trusted(context.ceilings[1], cfg.confidence)
        pool = CandidatePool.of(context.verified, _measure(context))
        context.pool = pool
        context.chosen = pool.decide(pool.incumbent, cfg, context.trusted) if pool else None
        if context.chosen is not None:
            context.transform = pool.hypotheses[context.chosen].T_target_source
        _judge(context)


def consider(context: RegistrationContext, found: VerificationResult) -> None:
    """Add a stage's verified candidates to the pool, choose again, and judge the choice."""
    pool = context.pool.extended(found, _measure(context))
    incumbent = pool.incumbent if context.chosen is None else context.chosen
    context.pool = pool
    context.chosen = pool.decide(incumbent, context.config, context.trusted)
    context.transform = pool.hypotheses[context.chosen].T_target_source
    _judge(context)


def _measure(context: RegistrationContext) -> functools.partial:
    """Return the distinctive structure ``(shares, objects, in_view)`` of poses on the scans."""
    return functools.partial(
        context.scoring.distinctive_of, source=context.source, target=context.target
    )


def _judge(context: RegistrationContext) -> None:
    """Set the evidence of the current transform and the confidence rule's refusal."""
    cfg = context.config
    score_current(context)
    if chance.wanted(context.evidence.num_inliers, cfg.confidence):  # core/estimation/chance.py
        context.evidence = dataclasses.replace(context.evidence, chance_inliers=_chance(context))
    context.refusal = confidence.refusal(
        context.evidence, cfg.confidence, cfg.estimator.min_inliers
    )


def _chance(context: RegistrationContext) -> float:
    """Return the pair's largest chance consensus, measured once per registration."""
    key = 'confidence_chance_draws'
    if key not in context.diagnostics:
        draws = chance.chance_consensus(
            context.source_points,
            context.target_points,
            context.config.estimator,
            context.config.confidence.chance_shuffles,
        )
        context.diagnostics[key] = ' '.join(str(int(d)) for d in draws)
    draws = context.diagnostics[key].split()
    return float(max(int(d) for d in draws)) if draws else float('nan')


def score_current(context: RegistrationContext) -> None:
    """Set the inliers and the evidence of the context's current transform."""
    context.inliers, context.evidence = context.scoring.evidence(
        context.transform,
        context.source_points,
        context.target_points,
        context.pool,
        context.chosen,
        context.source,
        context.target,
        context.ceilings,
    )
