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
Stage 6b, the covisible overlap: a refused pose is chosen again where both scans can see.

After the refused path the pool holds every candidate found. Each is measured by its
overlap where both scans can see (core/estimation/covisibility.py): the right pose of a
60 m dev pair puts 0.97-1.00 of the checkable surface on the other scan, the best wrong
candidates 0.73-0.92 and the zero motion 0.45-0.60 (docs/hard_pairs.md). The candidate with
the highest covisible overlap (the current pose kept if it is within
``covisibility.min_gain`` of it, and never replaced by one with less evidence:
:func:`~mlsemreg_ros.core.estimation.covisibility.covisible_choice`), at least
``covisibility.min_overlap`` with ``covisibility.min_checked`` of its surface checkable,
becomes the pose; and for the confidence rule its overlap is then enough
(``confidence.min_overlap`` applies to the share of the whole scan, which a right pose 60 m
away cannot reach). Every other rule still applies.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from mlsemreg_ros.core.estimation import confidence
from mlsemreg_ros.core.estimation.covisibility import (
    covisible_choice,
    mutual_covisible_overlap,
    RangeImage,
)
from mlsemreg_ros.core.estimation.verification import area_weights
from mlsemreg_ros.core.results import PreparedScan, VerificationResult
from mlsemreg_ros.core.stages.confidence import score_current
from mlsemreg_ros.core.stages.context import RegistrationContext
import numpy as np


class CovisibilityStage:
    """Choose the refused pool's best covisible candidate and judge it (``covisibility_ms``)."""

    name = 'covisibility'

    def wanted(self, context: RegistrationContext) -> bool:
        """``covisibility.enabled``, the pose refused and a pool to choose from."""
        return (
            context.config.covisibility.enabled
            and bool(context.refusal)
            and context.pool is not None
            and bool(context.pool)
        )

    def run(self, context: RegistrationContext) -> VerificationResult | None:
        """Measure the pool, switch to its best covisible candidate, judge it again."""
        cfg = context.config
        covis = cfg.covisibility
        transforms = context.pool.transforms()
        overlap, checked = pool_covisible_overlap(context, transforms)
        pool = context.pool
        context.covisible_pool = (overlap, checked)
        best = covisible_choice(
            overlap,
            checked,
            np.array([h.num_inliers for h in pool.hypotheses]),
            pool.scores(),
            context.chosen,
            covis.min_checked,
            covis.min_gain,
        )
        context.diagnostics['covisible_switched'] = False
        if best < 0:
            return None
        context.diagnostics.update(
            covisible_overlap=float(overlap[best]), covisible_checked=float(checked[best])
        )
        if overlap[best] < covis.min_overlap:
            return None
        if best != context.chosen:
            context.diagnostics['covisible_switched'] = True
            context.chosen = best
            context.transform = transforms[best]
            context.message = (
                f'covisible pose ({context.pool.origin(best)}: overlap {overlap[best]:.2f} '
                f'where both scans see, {checked[best]:.2f} of the surface checked)'
                + (f'; {context.message}' if context.message else '')
            )
            score_current(context)
        # the overlap is judged where both scans see: a far right pose is not refused for it
        judged = dataclasses.replace(
            context.evidence, overlap=max(context.evidence.overlap, cfg.confidence.min_overlap)
        )
        context.refusal = confidence.refusal(judged, cfg.confidence, cfg.estimator.min_inliers)
        return None


def pool_covisible_overlap(
    context: RegistrationContext, transforms: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """
    Return the covisible ``(overlap, checked)`` of the pool's ``transforms`` ``(N, 4, 4)``.

    Measured on ``verification.sample_points``. The candidates an earlier call measured
    (the gate's trials, core/stages/early_acceptance.py) are not measured again when the
    pool grew from them (each pose's figures do not depend on the others); a pool that was
    replaced (the unlabeled fallback adopts its attempt's pool) is measured afresh.
    """
    cfg = context.config
    covis, verification = cfg.covisibility, cfg.verification
    done = context.covisible_measured
    known = 0 if done is None else len(done[0])
    if done is not None and (
        known > len(transforms) or not np.array_equal(done[2], transforms[:known])
    ):
        known, done = 0, None
    if done is None or known < len(transforms):
        overlap, checked = mutual_covisible_overlap(
            transforms[known:],
            *covisible_sides(context, verification.sample_points),
            verification.overlap_distance,
            covis.margin,
        )
        if done is not None:
            overlap = np.concatenate([done[0], overlap])
            checked = np.concatenate([done[1], checked])
        context.covisible_measured = (overlap, checked, transforms.copy())
    overlap, checked, _ = context.covisible_measured
    return overlap, checked


def covisible_sides(context: RegistrationContext, sample_points: int) -> tuple[Any, Any]:
    """:func:`covisible_side` of the source and the target on ``sample_points``, made once."""
    key = (sample_points, id(context.source.points), id(context.target.points))
    if key not in context.covisible_sides:
        cfg = context.config
        check = dataclasses.replace(cfg.verification, sample_points=sample_points)
        context.covisible_sides[key] = (
            covisible_side(context.source, cfg.covisibility.bin_deg, check),
            covisible_side(context.target, cfg.covisibility.bin_deg, check),
        )
    return context.covisible_sides[key]


def covisible_side(
    scan: PreparedScan, bin_deg: float, verification: object
) -> tuple[np.ndarray, np.ndarray, object, RangeImage]:
    """Return the sampled points, their weights, the KD-tree and the range image of ``scan``."""
    points = scan.points
    rng = np.random.default_rng(verification.seed)
    count = verification.sample_points
    rows = rng.choice(len(points), count, replace=False) if len(points) > count else None
    sample = points if rows is None else points[rows]
    return (
        sample,
        area_weights(sample, verification.range_exponent),
        scan.points_tree(),
        RangeImage.of(points, bin_deg),
    )
