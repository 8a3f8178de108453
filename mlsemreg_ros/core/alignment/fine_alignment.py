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
Every rule about a fine alignment (GICP/VGICP, ``core/alignment/alignment.py``) in one place.

Used by the pair registration (``Registration.register``, scan to scan) and by the
odometry (``core/odometry/tracking.py``, scan to local map). It sits below both, so
neither imports the other:

    alignment_cloud(scan, fine, pair)           the scan's small_gicp cloud, cached on it
    refinement_refusal(alignment, bounds)       absolute bounds: inliers kept, guess moved
    relative_inlier_refusal(alignment, ...)     against the usual inlier fraction
    tracking_refusal(prediction, ...)           may the refined prediction be accepted alone
    InlierHistory                               inlier fractions of the last accepted frames
"""

from __future__ import annotations

import collections
from dataclasses import dataclass
from typing import TYPE_CHECKING

from mlsemreg_ros.core.alignment.alignment import Alignment, AlignmentCloud
from mlsemreg_ros.core.alignment.config import FineAlignmentConfig
from mlsemreg_ros.core.poses import within_bounds
from mlsemreg_ros.core.results import PreparedScan
from mlsemreg_ros.core.rigid import rotation_angle_deg
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import OdometryConfig

#: Accepted frames whose median inlier fraction is the typical one.
FRACTION_HISTORY = 10
#: A longer gap in the stamps (in nominal frame intervals) needs the global registration.
MAX_TRACKING_GAP = 1.5


def alignment_cloud(
    scan: PreparedScan, fine: FineAlignmentConfig, pair: bool = False
) -> AlignmentCloud:
    """
    Return the scan's fine-alignment cloud (built once, then cached on the scan).

    Odometry: downsampled to ``fine.downsampling_resolution``, ``fine.num_neighbors``,
    without the points of ``scan.map_excluded`` (moving objects,
    ``core/features/moving_objects.py``).
    Pairs (``pair=True``): the prepared scan as it is, ``fine.pair_num_neighbors``.
    """
    key = (
        (0.0, fine.pair_num_neighbors)
        if pair
        else (fine.downsampling_resolution, fine.num_neighbors)
    )
    if key not in scan.alignment_clouds:
        points = scan.points
        if not pair and scan.map_excluded is not None:
            points = points[~scan.map_excluded]
        scan.alignment_clouds[key] = AlignmentCloud.build(points, *key)
    return scan.alignment_clouds[key]


@dataclass(frozen=True)
class RefinementBounds:
    """What a fine alignment must satisfy to be trusted (``odometry.*`` by default)."""

    min_inlier_fraction: float
    max_correction_translation: float  # m
    max_correction_rotation: float  # deg

    @classmethod
    def of(cls, odometry: OdometryConfig) -> RefinementBounds:
        """Return the bounds of the ``odometry`` section."""
        return cls(
            odometry.min_inlier_fraction,
            odometry.max_correction_translation,
            odometry.max_correction_rotation,
        )


def refinement_refusal(alignment: Alignment, bounds: RefinementBounds) -> str:
    """
    Why a fine alignment's result is not trusted ('' if it is).

    It must keep ``odometry.min_inlier_fraction`` of the scan as inliers and move its
    initial guess by at most the ``odometry.max_correction_*`` bounds: a refinement
    that runs away or converges with little overlap is refused, not believed.
    """
    if not np.all(np.isfinite(alignment.T_target_source)):
        return 'non-finite fine alignment'
    if alignment.inlier_fraction < bounds.min_inlier_fraction:
        return (
            f'fine alignment kept {alignment.inlier_fraction:.2f} of the scan as '
            f'inliers < odometry.min_inlier_fraction={bounds.min_inlier_fraction:g}'
        )
    return correction_refusal(alignment, bounds)


def correction_refusal(alignment: Alignment, bounds: RefinementBounds) -> str:
    """
    Why the guess itself is doubtful: the refinement moved it beyond the bounds ('' if not).

    A coarse pose that the fine alignment pulls further than
    ``odometry.max_correction_translation/rotation`` was not right to that bound; a pair
    registration refuses such a pose instead of returning it unrefined (docs/confidence.md).
    """
    if not np.all(np.isfinite(alignment.T_target_source)):
        return 'non-finite fine alignment'
    moved = alignment.correction
    shift, turn = float(np.linalg.norm(moved[:3, 3])), rotation_angle_deg(moved)
    if shift > bounds.max_correction_translation or turn > bounds.max_correction_rotation:
        return (
            f'fine alignment moved its guess by {shift:.2f} m / {turn:.2f} deg, more '
            f'than odometry.max_correction_translation/rotation='
            f'{bounds.max_correction_translation:g} m / '
            f'{bounds.max_correction_rotation:g} deg'
        )
    return ''


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


def relative_inlier_refusal(alignment: Alignment, share: float, history: InlierHistory) -> str:
    """
    Why an alignment keeps too little of the scan compared with the usual ('' if not).

    Refused below ``share`` (``odometry.min_relative_inlier_fraction``) times the median
    fraction of the last accepted frames; no rule before the first or with ``share`` 0.
    """
    if share > 0 and history:
        typical = history.typical()
        if alignment.inlier_fraction < share * typical:
            return (
                f'fine alignment kept {alignment.inlier_fraction:.2f} of the scan '
                f'as inliers < odometry.min_relative_inlier_fraction={share:g} x '
                f'{typical:.2f} (median of the last accepted frames)'
            )
    return ''


@dataclass
class Candidate:
    """One initial guess of the current pose and its refinement against the local map."""

    name: str  # 'global' (ML-SemReg estimate) or 'prediction' (the motion model)
    T_initial: np.ndarray  # (4, 4) T_odom_current guess
    alignment: Alignment
    refusal: str  # why it is not acceptable ('' if it is)

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
