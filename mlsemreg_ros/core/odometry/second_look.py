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
The odometry's second look at a decision (issue 29): near misses and a prediction over a gap.

Two cases, both judged by the basins of the map alignment (core/alignment/near_miss.py,
``near_miss.*``): the scan is aligned to the local map again from perturbed starts.

- **A pose from a sparse global registration** (source ``global``): refined on the map, it
  must sit alone in its basin. A start that converges elsewhere about as well disputes
  it: the scan is refused, or (``near_miss.action: inflate``) its covariance grows along
  the disputed direction until it covers the gap. With ``near_miss.recheck_swept`` a
  refused pose that nothing else rescues is judged again once its sweep is deskewed again
  (core/odometry/swept_dispute.py). A rival place with a lower cost is the
  same cost's deeper minimum, where the map alignment stopped short: the pose moves there
  if it is trusted and undisputed in turn.
- **A candidate refused by a rule its own evidence may overrule** (no candidate vetoes
  another): the refined estimate of a global registration that succeeded, refused only
  because it kept fewer map inliers than the last accepted frames did (a scan far from
  them overlaps the map less); the refined prediction, when the global registration
  failed, refused only by the correction bounds (a prediction extrapolated over a gap, a
  refused scan or a stride, is rougher than they assume). Each is judged on its own
  evidence: its alignment's weakest direction must be held by at least
  ``near_miss.min_weak_support`` inliers' worth of information
  (core/alignment/weak_direction.py: perturbed starts come back to a place a handful of
  inliers decide, wrong or right), and every perturbed start must come back to it, with no
  rival basin. Then it is accepted (the reason says so); otherwise the refusal stands.
  A candidate held by fewer is accepted only on the sweep alignment's confirmation
  (``near_miss.weak_confirmation``, ``Tracker.align_accepted``): the scan deskewed by the
  motion the candidate implies, aligned with its sweep twist free, must keep a pose close
  to it. A pose a few skewed points decide moves or is not kept.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

from mlsemreg_ros.core.alignment.alignment import Alignment
from mlsemreg_ros.core.alignment.fine_alignment import (
    correction_refusal,
    refinement_refusal,
    RefinementBounds,
)
from mlsemreg_ros.core.alignment.near_miss import (
    alignment_fit,
    better_place,
    disputed_hessian,
    judge_basins,
    NearMiss,
)
from mlsemreg_ros.core.alignment.weak_direction import weakest_direction
from mlsemreg_ros.core.odometry.global_registration import GlobalEstimate
from mlsemreg_ros.core.odometry.steps import Decision
from mlsemreg_ros.core.odometry.trust import Candidate, relative_inlier_refusal
from mlsemreg_ros.core.results import PreparedScan
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.odometry.tracking import Tracker

#: A successful global registration's refinement may keep this share of
#: ``odometry.min_inlier_fraction`` when every perturbed start comes back to it (a scan 20 m
#: from the map's scans overlaps it less; the dev chain's scan 7 kept 0.22).
GLOBAL_INLIER_FLOOR = 0.6


def basins(
    tracker: Tracker, candidate: Candidate, scan: PreparedScan, cfg: RegistrationConfig
) -> NearMiss:
    """Align ``scan`` to the map again from perturbed starts around ``candidate``'s pose."""
    return judge_basins(
        candidate.alignment,
        lambda start: tracker.map.align_scan(scan, start),
        alignment_fit,
        cfg.near_miss,
    )


def starts_back(alignment: Alignment, verdict: NearMiss, cfg: RegistrationConfig) -> int:
    """
    Return how many perturbed starts of ``verdict`` came back to ``alignment``'s pose.

    0 when none ran or any converged farther than ``near_miss.agreement_translation``: a
    pose accepted on its own evidence needs every start back home.
    """
    T = alignment.T_target_source
    shifts = [np.linalg.norm(np.linalg.solve(T, b.T_target_source)[:3, 3]) for b in verdict.others]
    if not shifts or max(shifts) > cfg.near_miss.agreement_translation:
        return 0
    return len(shifts)


def second_look(
    tracker: Tracker,
    chosen: Decision,
    estimate: GlobalEstimate,
    scan: PreparedScan,
    cfg: RegistrationConfig,
) -> Decision:
    """Return ``chosen``, refused or inflated when disputed, or a rescued candidate."""
    if not cfg.near_miss.enabled:
        return chosen
    if chosen.accepted:
        return _near_miss(tracker, chosen, scan, cfg)
    return _rescue(tracker, chosen, estimate, scan, cfg)


def _near_miss(
    tracker: Tracker, chosen: Decision, scan: PreparedScan, cfg: RegistrationConfig
) -> Decision:
    if chosen.source not in ('global', 'prediction'):
        return chosen  # prediction+global: two estimates agree
    candidate = next(c for c in chosen.candidates if c.name == chosen.source)
    verdict = basins(tracker, candidate, scan, cfg)
    if not verdict.refusal:
        return chosen
    better = better_place(verdict, cfg.near_miss) if cfg.near_miss.move_to_better_place else None
    if better is not None and better.alignment is not None:  # the refinement stopped short
        moved = tracker.trust.judge(
            candidate.name, candidate.T_initial, better.alignment, cfg.odometry
        )
        again = basins(tracker, moved, scan, cfg) if moved.acceptable else None
        if again is not None and not again.refusal:
            alignment = moved.alignment
            note = f'moved to a better place {verdict.refusal.partition(": ")[2]}'
            return dataclasses.replace(
                chosen,
                reason='; '.join(r for r in (chosen.reason, note) if r),
                pose=alignment.T_target_source,
                frame_covariance=alignment.covariance(
                    cfg.odometry.covariance_scale, axes='source'
                ),
                inlier_fraction=alignment.inlier_fraction,
                residual_variance=alignment.residual_variance,
                candidates=[*chosen.candidates, moved],
            )
    if cfg.near_miss.action == 'refuse' and cfg.near_miss.recheck_swept:  # swept_dispute.py
        dispute = f'{candidate.name}: {verdict.refusal}'
        tracker.disputed = dataclasses.replace(chosen, swept_dispute=dispute)
    if cfg.near_miss.action == 'refuse' or verdict.disputed is None:
        return Decision(
            source='',
            reason='; '.join(
                r for r in (chosen.reason, f'{candidate.name}: {verdict.refusal}') if r
            ),
            result=chosen.result,
            relative=chosen.result.transform if chosen.result is not None else None,
            candidates=chosen.candidates,
            timings_ms=chosen.timings_ms,
        )
    alignment = dataclasses.replace(
        candidate.alignment,
        hessian=disputed_hessian(candidate.alignment, verdict.disputed),
    )
    chosen.frame_covariance = alignment.covariance(cfg.odometry.covariance_scale, axes='source')
    chosen.reason = '; '.join(r for r in (chosen.reason, f'inflated: {verdict.refusal}') if r)
    return chosen


def _own_evidence(
    candidate: Candidate, estimate: GlobalEstimate, tracker: Tracker, cfg: RegistrationConfig
) -> bool:
    """
    Whether ``candidate`` was refused only by a rule its own evidence may overrule.

    The refined global estimate of a registration that succeeded, refused only by the
    inliers relative to the last accepted frames or by the absolute share down to
    :data:`GLOBAL_INLIER_FLOOR` of it (a scan far from the last ones overlaps the map less
    than they did); the refined prediction, when the global registration
    failed, refused only by the correction bounds (a prediction over a gap is rougher
    than they assume); never a still start (``odometry.still_start``), which predicts
    nothing.
    """
    alignment, odometry = candidate.alignment, cfg.odometry
    bounds = RefinementBounds.of(odometry)
    if candidate.acceptable or not np.all(np.isfinite(alignment.T_target_source)):
        return False
    if candidate.name == 'global':  # its own sparse evidence passed the confidence rule
        floor = dataclasses.replace(
            bounds, min_inlier_fraction=GLOBAL_INLIER_FLOOR * bounds.min_inlier_fraction
        )
        return estimate.usable and not refinement_refusal(alignment, floor)
    return (
        candidate.name == 'prediction'
        and not candidate.still  # a still start has no motion model's roughness to excuse
        and not estimate.usable
        and bool(correction_refusal(alignment, bounds))
        and alignment.inlier_fraction >= bounds.min_inlier_fraction
        and not relative_inlier_refusal(
            alignment, odometry.min_relative_inlier_fraction, tracker.history
        )
    )


def weak_refusal(alignment: Alignment, cfg: RegistrationConfig) -> str:
    """
    Why ``alignment``'s own evidence cannot pin its weakest direction ('' if it can).

    The support of the Hessian's weakest direction (core/alignment/weak_direction.py) must
    reach ``near_miss.min_weak_support`` inliers' worth: perturbed starts come back to a
    place that a handful of inliers decide, wrong or right.
    """
    near_miss = cfg.near_miss
    if near_miss.min_weak_support <= 0:
        return ''
    weak = weakest_direction(alignment)
    if weak.support >= near_miss.min_weak_support:
        return ''
    return (
        f"its weakest direction, {weak.describe()}, carries {weak.support:.1f} inliers' "
        f'worth of information < near_miss.min_weak_support={near_miss.min_weak_support:g}'
    )


def _rescue(
    tracker: Tracker,
    chosen: Decision,
    estimate: GlobalEstimate,
    scan: PreparedScan,
    cfg: RegistrationConfig,
) -> Decision:
    notes = []
    for candidate in sorted(chosen.candidates, key=lambda c: c.name != 'global'):
        if not _own_evidence(candidate, estimate, tracker, cfg):
            continue
        alignment = candidate.alignment
        weak = weak_refusal(alignment, cfg)
        if weak and cfg.near_miss.weak_confirmation <= 0:
            notes.append(f'{candidate.name} not accepted on its own evidence: {weak}')
            continue
        verdict = basins(tracker, candidate, scan, cfg)
        back = starts_back(alignment, verdict, cfg)
        if verdict.refusal or not back:
            continue
        note = (
            f'{candidate.name} accepted on its own evidence ({candidate.refusal}; '
            f'{back} perturbed starts came back to it)'
        )
        if weak:  # tracking.py's Tracker.align_accepted: the sweep alignment must confirm
            note = f'{note}, if the sweep alignment confirms it ({weak})'
        return Decision.of_alignment(
            candidate.name,
            '; '.join(r for r in (chosen.reason.split('; ')[0], note) if r),
            alignment,
            cfg.odometry.covariance_scale,
            result=chosen.result,
            candidates=chosen.candidates,
            timings_ms=chosen.timings_ms,
            confirm_weak=bool(weak),
        )
    if notes:
        return dataclasses.replace(
            chosen, reason='; '.join(r for r in (chosen.reason, *notes) if r)
        )
    return chosen
