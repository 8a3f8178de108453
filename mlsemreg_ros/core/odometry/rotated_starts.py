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
Yaw-rotated starts of the map alignment before the global registration (issue 35).

0.3 s ahead of a hand that turns +-17 deg at 0.5 Hz, a constant-velocity guess is about
10 deg off, outside the map alignment's basin: the refined prediction is refused and the
scan goes to the global registration (50-120 ms). The prediction's own uncertainty says how
far off it may be (:class:`~mlsemreg_ros.core.odometry.motion_bound.MotionBound`: the
widened ``odometry.max_correction_rotation``). Within that bound, the map alignment is also
started from the prediction turned about the sensor's vertical axis by
:data:`YAW_OFFSETS`, each a few milliseconds. A rotated start is taken only when

- its offset lies within the prediction's widened rotation bound (a car's stays at the
  configured 5 deg: no rotated start is ever tried on a car);
- its refinement passes every tracking rule of a refined prediction
  (:meth:`~mlsemreg_ros.core.odometry.trust.Trust.tracking_refusal`: correction bounds
  from the start, inlier fractions, ``odometry.global_interval``, stamp gaps);
- its refined pose is within the widened rotation bound of the prediction itself;
- and, of the rotated starts that pass, it kept the largest share of the scan, with no
  other passing start converged more than :data:`AGREEMENT` away (two basins: neither).

Otherwise the scan goes to the global registration as before.
"""

from __future__ import annotations

from collections.abc import Callable
import dataclasses
from typing import Any, TYPE_CHECKING

from mlsemreg_ros.core.features.deskew import SweepMotion
from mlsemreg_ros.core.odometry.motion_bound import prediction_error
from mlsemreg_ros.core.odometry.prior_guard import prior_used
from mlsemreg_ros.core.odometry.sweep_starts import implied_twist
from mlsemreg_ros.core.odometry.trust import Candidate, MAX_TRACKING_GAP
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import OdometryConfig
    from mlsemreg_ros.core.odometry.preprocess import PreprocessedScan
    from mlsemreg_ros.core.results import PreparedScan

#: Yaw offsets (deg) of the rotated starts, nearest first.
YAW_OFFSETS = (10.0, -10.0, 20.0, -20.0)
#: Two passing starts further apart than this (m, deg) found two basins: take neither.
AGREEMENT = (0.3, 2.0)


def rotated(candidate: Candidate) -> Candidate:
    """
    Return the candidate named ``'rotated'`` (judged as a prediction, from a rotated start).

    The decision lists it first and the refined prediction after it: the covariance's
    correction (``core/odometry/advance.py``) is then the pose against the prediction.
    """
    return dataclasses.replace(candidate, name='rotated')


def yaw_rotated(T: np.ndarray, yaw_deg: float) -> np.ndarray:
    """Return ``T`` turned by ``yaw_deg`` about its own z axis (the sensor's vertical)."""
    angle = np.radians(yaw_deg)
    turn = np.eye(4)
    turn[:2, :2] = [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
    return np.asarray(T, dtype=np.float64) @ turn


def offsets_within(rotation_bound_deg: float) -> list[float]:
    """Return the offsets of :data:`YAW_OFFSETS` strictly within the rotation bound (deg)."""
    return [o for o in YAW_OFFSETS if abs(o) < rotation_bound_deg]


def best_rotated_start(
    T_predicted: np.ndarray,
    rotation_bound_deg: float,
    refine: Callable[[np.ndarray], Candidate],
    refusal: Callable[[Candidate], str],
    redeskewed: Callable[[np.ndarray], Candidate | None] | None = None,
) -> Candidate | None:
    """
    Return the rotated start's refined candidate to track, or None (go global).

    ``rotation_bound_deg``: the prediction's widened ``odometry.max_correction_rotation``.
    ``refine(T_start)``: the start refined against the map and judged as a prediction;
    ``refusal(candidate)``: why it may not be tracked ('' if it may).
    ``redeskewed(T_start)``: the scan deskewed by the twist ``T_start`` implies, refined from
    ``T_start`` and judged as a prediction (None: not possible). The scan was deskewed by the
    prediction's twist, as wrong as the prediction: a rotated start in the right basin keeps
    0.5-0.7 of it as inliers, under ``odometry.tracking_min_inlier_fraction``. When no start
    passes, the one that kept the most (and is acceptable as a refinement) is deskewed again
    by its own twist and refined once more; it must then pass every rule above, its move
    measured from the prediction (:func:`from_prediction`).
    """
    passing: list[Candidate] = []
    tried: list[Candidate] = []
    for offset in offsets_within(rotation_bound_deg):
        candidate = refine(yaw_rotated(T_predicted, offset))
        tried.append(candidate)
        if within(T_predicted, candidate, rotation_bound_deg) and not refusal(candidate):
            passing.append(candidate)
    if not passing and redeskewed is not None:
        acceptable = [
            c for c in tried if c.acceptable and within(T_predicted, c, rotation_bound_deg)
        ]
        if acceptable:
            best = max(acceptable, key=lambda c: c.alignment.inlier_fraction)
            again = redeskewed(best.alignment.T_target_source)
            if (
                again is not None
                and within(T_predicted, again, rotation_bound_deg)
                and not refusal(from_prediction(again, T_predicted))
            ):
                passing.append(again)
    if not passing:
        return None
    best = max(passing, key=lambda c: c.alignment.inlier_fraction)
    for other in passing:
        shift, turn = prediction_error(
            best.alignment.T_target_source, other.alignment.T_target_source
        )
        if shift > AGREEMENT[0] or turn > AGREEMENT[1]:
            return None
    return best


def from_prediction(candidate: Candidate, T_predicted: np.ndarray) -> Candidate:
    """
    Return ``candidate`` as if refined from the prediction (its move judged from it).

    A start deskewed again by its own twist is a new scan: its points moved by up to metres
    at range, so its refinement moves the pose from the start's refined pose by 0.5-0.85 m on
    the handheld VLP-16 walk at stride 3 while the prediction was within 0.1-0.3 m of the
    truth (docs/sensors.md, session 18). The start's pose was never a guess of this scan; the
    prediction is the motion model's, and ``odometry.tracking_translation`` bounds the move
    from it, as for a refined prediction.
    """
    alignment = dataclasses.replace(
        candidate.alignment, T_initial=np.asarray(T_predicted, dtype=np.float64)
    )
    return dataclasses.replace(candidate, alignment=alignment)


def within(T_predicted: np.ndarray, candidate: Candidate, rotation_bound_deg: float) -> bool:
    """Whether the candidate's refined pose is within the rotation bound of the prediction."""
    _, turn = prediction_error(T_predicted, candidate.alignment.T_target_source)
    return turn <= rotation_bound_deg


def worth_rotating(tracked_in_a_row: int, stamp_gap: float, odometry: OdometryConfig) -> bool:
    """
    Whether a tracked rotated start could be taken at all.

    Not when the global registration is due anyway (``odometry.global_registration:
    always``, ``odometry.global_interval`` scans tracked in a row, a gap in the stamps):
    every rotated start would be refused by the same tracking rules.
    """
    return (
        odometry.global_registration == 'on_demand'
        and tracked_in_a_row + 1 < odometry.global_interval
        and stamp_gap <= MAX_TRACKING_GAP
    )


class Redeskew:
    """
    The scan deskewed again by the twist a pose implies, for a rotated start.

    Called with a pose ``T_odom_current``: the twist from the motion model's last accepted
    pose to it (``sweep_starts.implied_twist``), the scan preprocessed again with it; the
    odometry takes :attr:`redone` when the decision's candidate is ``'rotated'``. Only a scan
    deskewed by a twist from the poses (no gyro or wheel prior) is deskewed again.
    """

    def __init__(self, odometry: Any, given: tuple[Any, Any, Any, int], raw: Any) -> None:
        self.odometry, self.given, self.raw = odometry, given, raw
        self.redone: PreprocessedScan | None = None

    def __call__(self, T: np.ndarray) -> PreparedScan | None:
        """Return the scan deskewed by the twist ``T`` implies (None: not possible)."""
        odometry, raw = self.odometry, self.raw
        points, labels, point_times, stamp_ns = self.given
        if (
            point_times is None
            or raw.input_points is None
            or not isinstance(raw.motion, SweepMotion)
            or prior_used(odometry.sweep_state()[2], raw.motion)
        ):
            return None
        implied = implied_twist(odometry.motion_model, T, stamp_ns)
        if implied is None:
            return None
        again = odometry.preprocessor.scan(points, labels, point_times, implied)
        if not again.deskewed:
            return None
        self.redone = again
        return again.scan

    def scan_of(self, decision: Any, raw: PreprocessedScan) -> PreprocessedScan:
        """
        Return the scan the decision was made on: :attr:`redone` for a ``'rotated'`` one.

        The scan is deskewed again only when no rotated start passed on ``raw``
        (:func:`best_rotated_start`), so a rotated decision after it is the redone scan's.
        """
        used = decision.accepted and decision.candidates and decision.candidates[0].name
        return self.redone if used == 'rotated' and self.redone is not None else raw
