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
Whether the odometry trusts an alignment against its local map: the one place that decides.

Every candidate pose of the odometry (the refined prediction, the refined global estimate,
the start's and the sweep's realignments) is an initial guess refined against the local
map and judged here (:meth:`Trust.judge`):

    correction bounds   the refinement kept ``odometry.min_inlier_fraction`` of the scan and
                        moved its guess by at most ``odometry.max_correction_*``
                        (``refinement_refusal``, core/alignment/fine_alignment.py)
    relative inliers    at least ``odometry.min_relative_inlier_fraction`` of the median
                        fraction of the last accepted frames (:class:`InlierHistory`)
    tracking            the refined prediction may be accepted alone, without a global
                        registration (:meth:`Trust.tracking_refusal`)
    motion bound        the prediction's correction and tracking bounds widen with its own
                        recent errors (core/odometry/motion_bound.py)

The decision between trusted candidates is ``core/odometry/decision.py``.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass
from typing import TYPE_CHECKING

from mlsemreg_ros.core.alignment.alignment import Alignment
from mlsemreg_ros.core.alignment.fine_alignment import (
    move_refusal,
    refinement_refusal,
    RefinementBounds,
)
from mlsemreg_ros.core.odometry.motion_bound import MotionBound
from mlsemreg_ros.core.odometry.narrow_view import View
from mlsemreg_ros.core.poses import within_bounds
from mlsemreg_ros.core.rigid import rotation_angle_deg
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import OdometryConfig

#: Accepted frames whose median inlier fraction is the typical one.
FRACTION_HISTORY = 10
#: A longer gap in the stamps (in nominal frame intervals) needs the global registration.
MAX_TRACKING_GAP = 1.5


class InlierHistory:
    """Inlier fractions of the last :data:`FRACTION_HISTORY` accepted fine alignments."""

    def __init__(self) -> None:
        self._fractions: collections.deque[float] = collections.deque(maxlen=FRACTION_HISTORY)

    def __bool__(self) -> bool:
        return bool(self._fractions)

    def append(self, fraction: float) -> None:
        """Record the inlier fraction of an accepted frame."""
        self._fractions.append(fraction)

    def clear(self) -> None:
        """Forget the history (a new map)."""
        self._fractions.clear()

    def typical(self) -> float:
        """Return the median of the history (0 when empty)."""
        return float(np.median(self._fractions)) if self._fractions else 0.0


def relative_inlier_refusal(
    alignment: Alignment, share: float, history: InlierHistory, overlap: float = 1.0
) -> str:
    """
    Why an alignment keeps too little of the scan compared with the usual ('' if not).

    Refused below ``share`` (``odometry.min_relative_inlier_fraction``) times the median
    fraction of the last accepted frames, times ``overlap``: the share of a narrow view that
    the pose's turn since the last accepted scan leaves in view (1 on a full ring;
    core/odometry/narrow_view.py). No rule before the first or with ``share`` 0.
    """
    if share > 0 and history:
        typical = history.typical() * overlap
        if alignment.inlier_fraction < share * typical:
            turned = f' x {overlap:.2f} of the view after the turn' if overlap < 1.0 else ''
            return (
                f'fine alignment kept {alignment.inlier_fraction:.2f} of the scan '
                f'as inliers < odometry.min_relative_inlier_fraction={share:g} x '
                f'{typical:.2f} (median of the last accepted frames{turned})'
            )
    return ''


@dataclass
class Candidate:
    """One initial guess of the current pose and its refinement against the local map."""

    name: str  # 'global' (ML-SemReg estimate) or 'prediction' (the motion model)
    T_initial: np.ndarray  # (4, 4) T_odom_current guess
    alignment: Alignment
    refusal: str  # why it is not acceptable ('' if it is)
    still: bool = False  # a prediction from the last pose itself (odometry.still_start)

    @property
    def acceptable(self) -> bool:
        """Whether the refined pose may be published."""
        return not self.refusal


def tracking_refusal(
    predicted: Candidate | None,
    cfg: OdometryConfig,
    tracked_in_a_row: int,
    stamp_gap: float,
    history: InlierHistory,
) -> str:
    """
    Why the refined prediction may not be accepted alone ('' if it may).

    ``odometry.global_registration: on_demand`` only. The refinement is acceptable, fewer
    than ``odometry.global_interval`` scans were tracked in a row, the stamps show no gap
    (``stamp_gap``, in frame intervals, at most :data:`MAX_TRACKING_GAP`), the refinement
    moved the prediction by at most ``odometry.tracking_translation/rotation`` and kept at
    least ``odometry.tracking_min_inlier_fraction`` of the scan and
    ``odometry.tracking_inlier_share`` of the usual fraction.
    """
    if cfg.global_registration != 'on_demand':
        return 'global registration: always'
    if predicted is None:
        return 'no prediction yet'
    if not predicted.acceptable:
        return f'prediction refused ({predicted.refusal})'
    if tracked_in_a_row + 1 >= cfg.global_interval:
        return f'{tracked_in_a_row} scans tracked in a row (odometry.global_interval)'
    if stamp_gap > MAX_TRACKING_GAP:
        return f'a gap of {stamp_gap:.1f} frame intervals in the stamps'
    alignment = predicted.alignment
    if not within_bounds(
        alignment.T_initial,
        alignment.T_target_source,
        cfg.tracking_translation,
        cfg.tracking_rotation,
    ):
        moved = alignment.correction
        return (
            f'prediction corrected by {np.linalg.norm(moved[:3, 3]):.2f} m / '
            f'{rotation_angle_deg(moved):.2f} deg (odometry.tracking_*)'
        )
    if alignment.inlier_fraction < cfg.tracking_min_inlier_fraction:
        return (
            f'prediction kept {alignment.inlier_fraction:.2f} of the scan < '
            f'odometry.tracking_min_inlier_fraction={cfg.tracking_min_inlier_fraction:g}'
        )
    typical = history.typical()
    if alignment.inlier_fraction < cfg.tracking_inlier_share * typical:
        return (
            f'prediction kept {alignment.inlier_fraction:.2f} of the scan, usual '
            f'{typical:.2f} (odometry.tracking_inlier_share)'
        )
    return ''


class Trust:
    """The odometry's trust in its alignments: the rules and the state they need."""

    def __init__(self) -> None:
        self.history = InlierHistory()  # inlier fractions of the last accepted frames
        self.tracked_in_a_row = 0  # scans accepted by the refined prediction alone
        self.motion_bound = MotionBound()  # the prediction's bounds from its recent errors
        self.view = View()  # a narrow view's span, the last accepted pose (narrow_view.py)

    def restart(self) -> None:
        """Forget the history (a new map)."""
        self.history.clear()
        self.tracked_in_a_row = 0
        self.motion_bound.clear()

    def judge(
        self,
        name: str,
        T_initial: np.ndarray,
        alignment: Alignment,
        odometry: OdometryConfig,
        overlap: float = 1.0,
    ) -> Candidate:
        """
        Return the candidate ``name``: its alignment and why it is not trusted ('' if it is).

        ``overlap``: the share of a narrow view its turn leaves in view, which the
        relative-inlier rule expects less by (``core/odometry/turn_starts.py``; 1: the rule).
        """
        if name == 'prediction':
            odometry = self.motion_bound.widen(odometry)
        refusal = refinement_refusal(
            alignment, RefinementBounds.of(odometry)
        ) or relative_inlier_refusal(
            alignment,
            odometry.min_relative_inlier_fraction,
            self.history,
            overlap,
        )
        return Candidate(name, np.asarray(T_initial).copy(), alignment, refusal)

    def replacement_refusal(
        self, T_accepted: np.ndarray, T_new: np.ndarray, odometry: OdometryConfig
    ) -> str:
        """
        Why ``T_new`` may not replace the accepted pose ``T_accepted`` ('' if it may).

        A second alignment of an accepted scan (the sweep alignment) starts from its own
        estimate, so its correction bound says nothing about how far it took the pose from the
        one the rules accepted. The whole move must stay within the correction bounds, widened
        as the prediction's are (``core/odometry/motion_bound.py``): on a solid-state drive a
        sweep fit bent an accepted pose 2.6 m along a weakly held road (issue 35).
        """
        return move_refusal(
            T_accepted,
            T_new,
            RefinementBounds.of(self.motion_bound.widen(odometry)),
            'the accepted pose',
        )

    def tracking_refusal(
        self, predicted: Candidate | None, stamp_gap: float, odometry: OdometryConfig
    ) -> str:
        """Why the refined prediction may not be accepted alone ('' if it may)."""
        return tracking_refusal(
            predicted,
            self.motion_bound.widen(odometry),
            self.tracked_in_a_row,
            stamp_gap,
            self.history,
        )

    def accepted(self, inlier_fraction: float | None) -> None:
        """Record an accepted frame's inlier fraction (None: not aligned to the map)."""
        if inlier_fraction is not None:
            self.history.append(inlier_fraction)
