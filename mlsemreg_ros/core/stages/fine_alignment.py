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
Stage 7, the fine alignment of the pair: GICP of the source scan onto the target scan.

From the chosen pose, with ``fine.pair_method`` (core/alignment/alignment.py). A refused
pose is refined too (it is the best one found; the result stays refused), with the source
downsampled as in the polishing if ``fine.refused_downsampled``. The alignment
must stay within the correction bounds (core/alignment/fine_alignment.py), or the coarse
pose was not right to those bounds and the pose is refused; a refinement refused only by
its bounds is kept when it holds the dense score (at 40-60 m the true overlap stays under
``odometry.min_inlier_fraction``; docs/hard_pairs.md); a refused pose chosen where both
scans see is refined at two distances and judged by that overlap instead
(core/stages/covisible_refinement.py). An accepted pose whose refinement is refused and not
kept stays unrefined only if the refinement stayed in the same place
(``near_miss.agreement_*``, :func:`unrefined_refusal`); otherwise it is refused. Last, the
localizability of the alignment (``confidence.degeneracy``).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from mlsemreg_ros.core.alignment.alignment import align_pair, Alignment
from mlsemreg_ros.core.alignment.config import NearMissConfig
from mlsemreg_ros.core.alignment.fine_alignment import (
    alignment_cloud,
    correction_refusal,
    refinement_refusal,
    RefinementBounds,
)
from mlsemreg_ros.core.estimation import confidence
from mlsemreg_ros.core.estimation.config import ConfidenceConfig
from mlsemreg_ros.core.rigid import rotation_angle_deg
from mlsemreg_ros.core.stages.context import RegistrationContext
from mlsemreg_ros.core.stages.covisible_refinement import refine_where_both_see
import numpy as np


class FineAlignmentStage:
    """Stage 7: GICP/VGICP of the pair from the chosen pose (``fine_ms``)."""

    name = 'fine'

    def wanted(self, context: RegistrationContext) -> bool:
        """``refine``, a finite pose and ``fine.pair_method`` not ``off``."""
        return (
            context.refine
            and bool(np.all(np.isfinite(context.transform)))
            and context.config.fine.pair_method != 'off'
        )

    def run(self, context: RegistrationContext) -> None:
        """Refine the transform; doubt it when the refinement moved it beyond the bounds."""
        cfg, source, target, coarse = (
            context.config,
            context.source,
            context.target,
            context.transform,
        )
        # a refused pose stays refused: its source cloud may be the downsampled one
        downsampled = bool(context.refusal) and cfg.fine.refused_downsampled
        alignment = align_pair(
            alignment_cloud(source, cfg.fine, pair=not downsampled),
            alignment_cloud(target, cfg.fine, pair=True),
            coarse,
            cfg.fine,
            cfg.fine.pair_method,
        )
        covisible = refine_where_both_see(context, coarse, alignment)  # refused 60 m poses
        alignment = covisible or alignment
        bounds = RefinementBounds.of(cfg.odometry)
        refused = refinement_refusal(alignment, bounds)
        context.diagnostics.update(
            fine_inlier_fraction=alignment.inlier_fraction,
            fine_iterations=alignment.iterations,
            fine_refused=refused or '',
        )
        # an accepted pose the refinement moved beyond the correction bounds is refused
        moved = correction_refusal(alignment, bounds)
        context.doubt(moved)
        if refused and (
            covisible
            or context.scoring.refused_path().refinement_holds(
                alignment.T_target_source, coarse, source, target
            )
        ):
            context.diagnostics['fine_refused_kept'] = True
            refused = ''
        if refused and not moved:  # the coarse pose stays: only if the refinement agrees
            context.doubt(unrefined_refusal(alignment, cfg.near_miss))
        if not refused:
            context.transform = alignment.T_target_source
            alignment, degenerate = degeneracy(alignment, cfg.confidence, context.diagnostics)
            context.doubt(degenerate)
        context.coarse, context.alignment = coarse, alignment


def degeneracy(
    alignment: Alignment, conf: ConfidenceConfig, diagnostics: dict[str, Any]
) -> tuple[Alignment, str]:
    """
    Localizability of the fine alignment (``degeneracy_*`` diagnostics) and its verdict.

    ``confidence.degeneracy``: ``report`` leaves the alignment as it is, ``inflate``
    returns it with the Hessian's weak translation eigenvalue divided by
    ``confidence.degeneracy_inflation`` (so every covariance derived from it grows along
    the weak direction), ``refuse`` returns the reason to refuse.
    """
    found = confidence.localizability(alignment.hessian, alignment.T_target_source[:3, :3])
    if found is None:
        return alignment, ''
    weak = found.ratio < conf.min_localizability
    diagnostics.update(found.as_diagnostics())
    diagnostics['degeneracy_weak'] = weak
    diagnostics['degeneracy_action'] = conf.degeneracy if weak else ''
    if weak and conf.degeneracy == 'inflate':
        hessian = confidence.inflated_hessian(alignment.hessian, conf.degeneracy_inflation)
        return dataclasses.replace(alignment, hessian=hessian), ''
    return alignment, confidence.degeneracy_refusal(found, conf)


def unrefined_refusal(alignment: Alignment, near_miss: NearMissConfig) -> str:
    """
    Why an accepted pose cannot stay unrefined after its refinement was refused ('' if it can).

    A refinement refused for its small overlap leaves the coarse pose in place. That pose is
    only as good as the refinement says when the refinement stayed in the same place
    (``near_miss.agreement_translation`` / ``agreement_rotation``): on a simulated 60 m pair
    with a 33 deg turn the sparse pose accepted on 50 inliers was 0.78 m off, and its refused
    refinement 0.11 m off, 0.7 m away (docs/hard_pairs.md, margins).
    """
    moved = alignment.correction
    shift, turn = float(np.linalg.norm(moved[:3, 3])), rotation_angle_deg(moved)
    if shift <= near_miss.agreement_translation and turn <= near_miss.agreement_rotation:
        return ''
    return (
        f'the refused fine alignment moved the unrefined pose by {shift:.2f} m / {turn:.2f} '
        f'deg, more than near_miss.agreement_translation/rotation='
        f'{near_miss.agreement_translation:g} m / {near_miss.agreement_rotation:g} deg'
    )
