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
The bounds of a fine alignment (GICP/VGICP, ``core/alignment/alignment.py``), and its cloud.

Used by the pair registration (``core/stages/fine_alignment.py``, scan to scan) and by
the odometry's trust rules (``core/odometry/trust.py``, scan to local map). It sits below
both, so neither imports the other:

    alignment_cloud(scan, fine, pair)           the scan's small_gicp cloud, cached on it
    refinement_refusal(alignment, bounds)       absolute bounds: inliers kept, guess moved
    correction_refusal(alignment, bounds)       the guess moved beyond the correction bounds
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from mlsemreg_ros.core.alignment.alignment import Alignment, AlignmentCloud
from mlsemreg_ros.core.alignment.config import FineAlignmentConfig
from mlsemreg_ros.core.results import PreparedScan
from mlsemreg_ros.core.rigid import rotation_angle_deg
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import OdometryConfig


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
    return _moved_refusal(alignment.correction, bounds, 'its guess')


def move_refusal(
    T_from: np.ndarray, T_to: np.ndarray, bounds: RefinementBounds, what: str = 'its guess'
) -> str:
    """
    Why ``T_to`` lies beyond the correction bounds of ``T_from`` ('' if it does not).

    ``inv(T_from) @ T_to`` must stay within ``odometry.max_correction_translation/rotation``:
    the bound of a fine alignment's correction (:func:`correction_refusal`), and of anything
    that replaces an accepted pose by a refined one (the sweep alignment,
    ``core/odometry/tracking.py``).
    """
    if not (np.all(np.isfinite(T_from)) and np.all(np.isfinite(T_to))):
        return 'non-finite fine alignment'
    return _moved_refusal(np.linalg.solve(T_from, T_to), bounds, what)


def _moved_refusal(moved: np.ndarray, bounds: RefinementBounds, what: str) -> str:
    """Why the move ``moved`` (4, 4) is beyond the correction bounds ('' if it is not)."""
    shift, turn = float(np.linalg.norm(moved[:3, 3])), rotation_angle_deg(moved)
    if shift > bounds.max_correction_translation or turn > bounds.max_correction_rotation:
        return (
            f'fine alignment moved {what} by {shift:.2f} m / {turn:.2f} deg, more '
            f'than odometry.max_correction_translation/rotation='
            f'{bounds.max_correction_translation:g} m / '
            f'{bounds.max_correction_rotation:g} deg'
        )
    return ''
