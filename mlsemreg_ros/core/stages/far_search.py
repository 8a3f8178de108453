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
Stage 5c, the far search: the BEV search on the scans' far fields, both directions.

Two scans 60 m apart share only a lens of space far from both sensors; their near fields
(the road and facades around each sensor) make the BEV search's strongest false peaks.
On the 60 m dev pairs, a peak within 8 deg and 4 m of the truth ranked in the top three
for 7 of 16 pair directions with the points nearer than 20 m left out, and for 1 of 16
with them (``covisibility.far_min_range``). The best ``covisibility.far_peaks`` peaks of
each direction (the swapped one inverted; the two directions searched at once on two
threads when ``threads`` allows) are polished on the dense scans (the yaw-only
ICP of core/estimation/polish.py) and verified (origin ``far_search``); the covisible
overlap (core/stages/covisibility.py) then tells the right one from the rest.
"""

from __future__ import annotations

import dataclasses

from mlsemreg_ros.core.estimation.bev_search import bev_hypotheses
from mlsemreg_ros.core.estimation.polish import polish_poses, radius_schedule
from mlsemreg_ros.core.results import PreparedScan, VerificationResult
from mlsemreg_ros.core.stages.context import RegistrationContext
from mlsemreg_ros.core.threads import LazyPool
import numpy as np

#: the far search's two directions, one per worker (``threads``; one worker: in turn)
_DIRECTIONS = LazyPool('far_search')


class FarSearchStage:
    """The BEV search on the far fields, polished (``far_search_ms``)."""

    name = 'far_search'

    def wanted(self, context: RegistrationContext) -> bool:
        """``covisibility.far_min_range`` > 0, the BEV search ran and the pose is refused."""
        return (
            context.config.covisibility.far_min_range > 0
            and context.searched is not None
            and bool(context.refusal)
        )

    def run(self, context: RegistrationContext) -> VerificationResult | None:
        """Search the far fields both ways; polish, verify and return the best peaks."""
        cfg = context.config
        covis, search, check = cfg.covisibility, cfg.bev_search, cfg.verification
        source = _far(context.source, covis.far_min_range)
        target = _far(context.target, covis.far_min_range)
        lookup = context.scoring.bev_channels
        # only the best far_peaks are used: the suppression keeps the same first ones
        # (greedy, best first) and stops there
        wanted = dataclasses.replace(search, hypotheses=min(search.hypotheses, covis.far_peaks))
        # the two directions are independent: both cores (the kernels and FFTs free the GIL)
        (forward, _), (backward, _) = _DIRECTIONS.run(
            lambda scans: bev_hypotheses(*scans[0], *scans[1], lookup, wanted),
            [(source, target), (target, source)],
        )
        starts = [forward[: covis.far_peaks]]
        if len(backward):
            starts.append(np.linalg.inv(backward[: covis.far_peaks]))
        starts = np.concatenate(starts)
        if len(starts) == 0:
            return None
        rng = np.random.default_rng(check.seed)
        points = context.source.points
        rows = (
            rng.choice(len(points), search.polish_points, replace=False)
            if len(points) > search.polish_points
            else np.arange(len(points))
        )
        radii = radius_schedule(
            search.polish_radius, check.overlap_distance, search.polish_iterations
        )
        polished = polish_poses(
            starts, points[rows], context.target.points_tree(), context.target.points, radii
        )
        return context.verify_candidates(polished, 'far_search')


def _far(scan: PreparedScan, min_range: float) -> tuple[np.ndarray, np.ndarray]:
    """Return the points of ``scan`` at least ``min_range`` from the sensor (xy), labels."""
    far = np.einsum('ij,ij->i', scan.points[:, :2], scan.points[:, :2]) >= min_range**2
    return scan.points[far], scan.labels[far]
