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
The fine alignment of a pose chosen where both scans see (stage 7, refused poses only).

Two scans 60 m apart share a thin lens of space; the pair's GICP (``fine.pair_method`` at
``fine.max_correspondence_distance``) then keeps under ``odometry.min_inlier_fraction`` of
the scan and is judged by its dense score, which at that range is a few per cent and as
noisy as the difference between a right and a wrong refinement. For a refused pose that the
covisible choice judged (core/stages/covisibility.py), the refinement is also run at
``covisibility.refine_distance``, from the coarse pose and from the usual result, and the
one with the best covisible overlap is kept if it holds the coarse pose's (within
``covisibility.min_gain``). On the 60 m GEDI dev pairs the usual refinement alone ended
within the success bounds for 6 of the 8 directions whose coarse pose was within 4 deg and
2 m; with this choice for 8 of 8 (docs/long_range.md).
"""

from __future__ import annotations

import dataclasses

from mlsemreg_ros.core.alignment.alignment import align_pair, Alignment
from mlsemreg_ros.core.alignment.fine_alignment import alignment_cloud
from mlsemreg_ros.core.estimation.covisibility import mutual_covisible_overlap
from mlsemreg_ros.core.stages.context import RegistrationContext
from mlsemreg_ros.core.stages.covisibility import covisible_sides
import numpy as np


def refine_where_both_see(
    context: RegistrationContext, coarse: np.ndarray, usual: Alignment
) -> Alignment | None:
    """
    Return the refinement to keep for a refused covisible pose (None: the usual path).

    ``usual`` is the pair's fine alignment from ``coarse``. None when the pose is accepted,
    when the covisible choice did not judge it, when ``covisibility.refine_distance`` is 0,
    or when no refinement holds the coarse pose's covisible overlap.
    """
    cfg = context.config
    covis, check = cfg.covisibility, cfg.verification
    if (
        not context.refusal
        or covis.refine_distance <= 0.0
        or 'covisible_overlap' not in context.diagnostics
    ):
        return None
    # the source cloud of the usual refinement of a refused pose (fine.refused_downsampled)
    source = alignment_cloud(context.source, cfg.fine, pair=not cfg.fine.refused_downsampled)
    target = alignment_cloud(context.target, cfg.fine, pair=True)
    near = dataclasses.replace(cfg.fine, max_correspondence_distance=covis.refine_distance)
    tries = [
        usual,
        align_pair(source, target, coarse, near, cfg.fine.pair_method),
        align_pair(source, target, usual.T_target_source, near, cfg.fine.pair_method),
    ]
    transforms = np.stack([coarse] + [found.T_target_source for found in tries])
    if not np.all(np.isfinite(transforms)):
        return None
    overlap, checked = mutual_covisible_overlap(
        transforms,
        *covisible_sides(context, check.sample_points),
        check.overlap_distance,
        covis.margin,
    )
    measured = np.where(checked >= covis.min_checked, overlap, -1.0)
    best = 1 + int(np.argmax(measured[1:]))  # the usual one first among equals
    context.diagnostics.update(
        covisible_refinement=best - 1, covisible_refined_overlap=float(overlap[best])
    )
    if measured[best] < 0.0 or measured[best] < measured[0] - covis.min_gain:
        return None
    return tries[best - 1]
