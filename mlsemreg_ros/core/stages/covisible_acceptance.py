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
Stage 9, acceptance where both scans see: a refused far pose accepted on its covisible overlap.

Runs when ``covisibility.accept_overlap`` > 0, last, for a pose that is still refused, that
the covisible choice judged (core/stages/covisibility.py) and that the fine alignment
refined. Its tilt first (``covisibility.accept_tilt``, the level check on the refined
pose) and the refined pose's localizability (``covisibility.accept_localizability``, the
fine alignment's ``degeneracy_ratio``); then the pose, its slides and the pool's best
distinct candidates are measured where both scans see on ``covisibility.accept_points``
points (``covisible_accept_*`` diagnostics), and a pose that passes the rule
(core/estimation/covisible_acceptance.py) and that no later stage doubted (but for the
refinement's move from the coarse pose: the refined pose is the one judged) is accepted.

It runs after the near-miss check, which therefore does not judge a pose accepted here: its
rivals are the pool's distinct candidates and the 5 m slides, measured where both scans see.
On the 60 m dev pairs the near-miss check disputed right poses for a second basin
0.11-0.15 m and 1.1-2.7 deg away, within the success bounds (docs/long_range.md).
"""

from __future__ import annotations

from mlsemreg_ros.core.alignment.fine_alignment import correction_refusal, RefinementBounds
from mlsemreg_ros.core.estimation.confidence import slid_poses, tilt_deg
from mlsemreg_ros.core.estimation.covisibility import mutual_covisible_overlap
from mlsemreg_ros.core.estimation.covisible_acceptance import (
    acceptance_refusal,
    best_eligible,
    best_rivals,
    CovisibleEvidence,
    localizability_refusal,
    tilt_refusal,
)
from mlsemreg_ros.core.features.levelling import tilt_refusal as level_refusal
from mlsemreg_ros.core.results import VerificationResult
from mlsemreg_ros.core.stages.context import RegistrationContext
from mlsemreg_ros.core.stages.covisibility import covisible_sides, pool_covisible_overlap
from mlsemreg_ros.core.stages.levelling import ground_fits
import numpy as np

SLIDES = 8  # directions of the slides (confidence.slid_poses)


class CovisibleAcceptanceStage:
    """Judge a refined refused pose by its covisible overlap (``covisible_accept_ms``)."""

    name = 'covisible_accept'

    def wanted(self, context: RegistrationContext) -> bool:
        """On; refused, judged by the covisible choice and refined (the alignment's pose)."""
        return (
            context.config.covisibility.accept_overlap > 0.0
            and bool(context.refusal)
            and context.covisible_pool is not None
            and context.alignment is not None
            and bool(np.array_equal(context.transform, context.alignment.T_target_source))
        )

    def run(self, context: RegistrationContext) -> VerificationResult | None:
        """Check the tilt, measure the pose, its slides and rivals; accept a pose that passes."""
        pose = context.transform
        tilt = tilt_deg(pose)
        context.diagnostics['covisible_accept_tilt_deg'] = tilt
        reason = pose_refusal(context, tilt)
        if not reason:
            evidence = self._measure(context, tilt)
            context.diagnostics.update(evidence.as_diagnostics())
            reason = acceptance_refusal(evidence, context.config.covisibility)
        context.diagnostics['covisible_accept_refusal'] = reason
        doubts = self._doubts(context)
        if reason or doubts:
            return None
        context.doubts = doubts  # the refinement's move from the coarse pose no longer counts
        context.diagnostics['covisible_accepted'] = True
        context.message = (
            f'accepted where both scans see (covisible overlap {evidence.overlap:.3f} of '
            f'{evidence.checked:.2f} checked; best distinct candidate {evidence.rival_overlap:.3f}'
            f', best slide {evidence.slide_overlap:.3f}) over: {context.refusal}'
            + (f'; {context.message}' if context.message else '')
        )
        context.refusal = ''
        return None

    @staticmethod
    def _measure(context: RegistrationContext, tilt: float) -> CovisibleEvidence:
        """Measure the pose, its slides and the pool's best distinct candidates on more points."""
        cfg = context.config
        covis, conf, check = cfg.covisibility, cfg.confidence, cfg.verification
        pose = context.transform
        candidates = context.pool.transforms()
        rivals = best_rivals(
            pose,
            candidates,
            *pool_covisible_overlap(context, candidates),  # the pool now, not a replaced one
            covis.min_checked,
            conf.rival_rotation,
            conf.rival_translation,
            covis.accept_rivals,
        )
        slides = slid_poses(pose, conf.slide_distance, SLIDES)[
            : SLIDES * (conf.slide_distance > 0)
        ]
        near = np.concatenate(
            [slid_poses(pose, scale * covis.accept_near_slide, SLIDES) for scale in (1.0, 1.5)]
        )[: 2 * SLIDES * (covis.accept_near_slide > 0)]
        transforms = np.concatenate([pose[None], slides, near, candidates[rivals]])
        overlap, checked = mutual_covisible_overlap(
            transforms,
            *covisible_sides(context, covis.accept_points),
            check.overlap_distance,
            covis.margin,
        )
        end = 1 + len(slides)
        near_end = end + len(near)
        # a rival counts only where both scans see enough of it (covisibility.accept_rival_share)
        floor = max(covis.min_checked, covis.accept_rival_share * float(checked[0]))
        return CovisibleEvidence(
            float(overlap[0]),
            float(checked[0]),
            *best_eligible(overlap[near_end:], checked[near_end:], floor),
            *best_eligible(overlap[1:end], checked[1:end], floor),
            tilt,
            best_eligible(overlap[end:near_end], checked[end:near_end], floor)[0],
        )

    @staticmethod
    def _doubts(context: RegistrationContext) -> list[str]:
        """Return the later stages' doubts, but the refinement's move from the coarse pose."""
        bounds = RefinementBounds.of(context.config.odometry)
        moved = correction_refusal(context.alignment, bounds)  # the refined pose is judged
        doubts = [doubt for doubt in context.doubts if doubt != moved]
        context.diagnostics['covisible_accept_doubts'] = '; '.join(doubts)
        return doubts

    @staticmethod
    def _level_refusal(context: RegistrationContext) -> str:
        """Run the level check on the refined pose ('' when levelling is off or it passes)."""
        if not context.config.levelling.enabled:
            return ''
        source, target = ground_fits(context)
        if source is None or target is None:
            return ''
        return level_refusal(context.transform, source, target, context.config.levelling)


def pose_refusal(context: RegistrationContext, tilt: float) -> str:
    """Stage 9's checks of the refined pose before its measure: tilt, level, localizability."""
    covis = context.config.covisibility
    return (
        tilt_refusal(tilt, covis)
        or CovisibleAcceptanceStage._level_refusal(context)
        or localizability_refusal(context.diagnostics.get('degeneracy_ratio'), covis)
    )


def covisible_evidence(context: RegistrationContext) -> tuple[CovisibleEvidence | None, str]:
    """
    Judge the context's pose as stage 9 does: ``(evidence, refusal)`` ('' = it passes).

    The refined pose's tilt, level and localizability first (no evidence measured when one
    refuses: ``(None, reason)``), then its covisible overlap against its slides and the
    pool's best distinct candidates.
    """
    tilt = tilt_deg(context.transform)
    reason = pose_refusal(context, tilt)
    if reason:
        return None, reason
    evidence = CovisibleAcceptanceStage._measure(context, tilt)
    return evidence, acceptance_refusal(evidence, context.config.covisibility)
