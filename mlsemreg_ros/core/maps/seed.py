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
A seeded relocalization: a given map pose with its uncertainty (``/initialpose``, docs/maps.md).

The seed narrows the relocalization (:mod:`mlsemreg_ros.core.maps.relocalization`) to the
keyframes that can overlap a scan taken within the seed's search radius, and its answer
must land inside the seed's window: within ``radius_m`` of the seeded position (in the
ground plane) and ``yaw_window_rad`` of its heading. The map's own verdict (the
registration's acceptance, the submap check) still decides first: a wrong seed finds
nothing it accepts, or an answer outside the window, and is refused, not adopted.

Radius and yaw window come from the seed's covariance (ROS order ``[x, y, z, roll, pitch,
yaw]``): :data:`SEED_SIGMAS` standard deviations, at least :data:`MIN_SEED_RADIUS_M` and
:data:`MIN_SEED_YAW_RAD` (RViz's "2D Pose Estimate" sends 0.5 m and 15 deg).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

#: Standard deviations of the seed's covariance that the search window spans.
SEED_SIGMAS = 3.0
#: Least search radius around a seeded position (m).
MIN_SEED_RADIUS_M = 2.0
#: Least yaw window around a seeded heading (rad; 10 deg).
MIN_SEED_YAW_RAD = float(np.radians(10.0))
#: Keyframes this much farther than the radius can still overlap the scan (m): the
#: distance over which two scans of a street still register (the dev pairs are ~20 m apart).
SEED_OVERLAP_M = 20.0


@dataclass(frozen=True)
class PoseSeed:
    """A map pose to relocalize around."""

    T_map_sensor: np.ndarray  # (4, 4)
    radius_m: float
    yaw_window_rad: float

    @classmethod
    def from_covariance(cls, T_map_sensor: np.ndarray, covariance: np.ndarray) -> PoseSeed:
        """Build the seed of a pose (4, 4) with its covariance (6, 6) (module docstring)."""
        cov = np.nan_to_num(np.asarray(covariance, dtype=np.float64).reshape(6, 6), nan=0.0)
        sigma_xy = float(np.sqrt(max(cov[0, 0], cov[1, 1], 0.0)))
        sigma_yaw = float(np.sqrt(max(cov[5, 5], 0.0)))
        return cls(
            np.asarray(T_map_sensor, dtype=np.float64).copy(),
            max(SEED_SIGMAS * sigma_xy, MIN_SEED_RADIUS_M),
            min(max(SEED_SIGMAS * sigma_yaw, MIN_SEED_YAW_RAD), np.pi),
        )

    def candidates(self, keyframes: Any) -> set[int]:
        """Return the ids of the keyframes (``keyframe_id``, ``position``) the scan can overlap."""
        reach = self.radius_m + SEED_OVERLAP_M
        here = self.T_map_sensor[:2, 3]
        return {k.keyframe_id for k in keyframes if np.linalg.norm(k.position[:2] - here) <= reach}

    def refusal(self, T_map_sensor: np.ndarray) -> str:
        """Why a found pose (4, 4) lies outside the seed's window ('' inside it)."""
        off = float(np.linalg.norm(T_map_sensor[:2, 3] - self.T_map_sensor[:2, 3]))
        turn = abs(_wrap(_yaw(T_map_sensor) - _yaw(self.T_map_sensor)))
        if off > self.radius_m:
            return f'found {off:.1f} m from the seed (radius {self.radius_m:.1f} m)'
        if turn > self.yaw_window_rad:
            return (
                f'found {np.degrees(turn):.0f} deg from the seeded heading (window '
                f'{np.degrees(self.yaw_window_rad):.0f} deg)'
            )
        return ''


def _yaw(T: np.ndarray) -> float:
    return float(np.arctan2(T[1, 0], T[0, 0]))


def _wrap(angle: float) -> float:
    return float((angle + np.pi) % (2.0 * np.pi) - np.pi)
