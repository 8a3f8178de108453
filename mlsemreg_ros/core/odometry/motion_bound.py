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
How far the fine alignment may move the motion model's prediction: from its own uncertainty.

A constant-velocity prediction is off by the change of velocity over one interval: the
recent accelerations times ``dt^2``. A car's is off by a few centimetres and a tenth of a
degree, a hand's by 6 to 15 degrees in a fast turn (issue 35). Fixed bounds
(``odometry.max_correction_*``, ``odometry.tracking_*``) tuned for a car send every such
turn to the global registration; bounds wide enough for a hand would let a car's
diverged alignment through.

:class:`MotionBound` keeps the prediction's error on every accepted scan (the accepted pose
against the prediction: the acceleration the model did not know) over the last
:data:`ERROR_WINDOW` scans. The allowed correction of the next prediction is

    bound = clip(max(configured, GAIN x largest recent error, SIGMAS x prior sigma), cap)

for the rotation bounds (the translation bounds stay as configured, :meth:`MotionBound.widen`):
the configured bound is the floor (a car never leaves it),
a sensor that has turned fast recently gets a bound its motion needs, and a prediction
from an IMU or wheel prior with a stated covariance (``Prediction.sigmas``) gets at least
:data:`SIGMAS` standard deviations. It widens only the prediction's bounds; a global
estimate is judged by the configured ones. Before any error is known the floor holds.
"""

from __future__ import annotations

import collections
import dataclasses
from typing import TYPE_CHECKING

from mlsemreg_ros.core.rigid import rotation_angle_deg
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import OdometryConfig

#: Accepted scans whose prediction errors bound the next prediction (5 s at 10 Hz).
ERROR_WINDOW = 50
#: The bound is this many times the largest recent prediction error.
GAIN = 1.5
#: ... and at least this many standard deviations of a prior's stated covariance.
SIGMAS = 3.0
#: The widest bounds, whatever the errors: translation (m) and rotation (deg).
CAP_TRANSLATION = 3.0
CAP_ROTATION = 30.0
#: A prediction further from the accepted pose than this is not a prediction error but a
#: jump (a relocalization, a re-initialisation): not recorded (m, deg).
RECORD_LIMIT = (10.0, 90.0)


def prediction_error(T_predicted: np.ndarray, T_accepted: np.ndarray) -> tuple[float, float]:
    """Return how far the accepted pose is from the prediction: metres and degrees."""
    moved = np.linalg.solve(np.asarray(T_predicted, float), np.asarray(T_accepted, float))
    return float(np.linalg.norm(moved[:3, 3])), rotation_angle_deg(moved)


class MotionBound:
    """The prediction's recent errors, and the correction bounds they allow."""

    def __init__(self, window: int = ERROR_WINDOW) -> None:
        self._errors: collections.deque[tuple[float, float]] = collections.deque(maxlen=window)
        self._predicted: np.ndarray | None = None  # the pending prediction (4, 4)
        self._sigmas: tuple[float, float] | None = None  # its prior's (m, deg), if stated

    def clear(self) -> None:
        """Forget the errors (a new map, a reset)."""
        self._errors.clear()
        self._predicted, self._sigmas = None, None

    def predicted(self, T_predicted: np.ndarray | None, sigmas: tuple | None = None) -> None:
        """Take the current scan's prediction (None: none) and its prior's sigmas (m, deg)."""
        self._predicted = None if T_predicted is None else np.asarray(T_predicted, float).copy()
        self._sigmas = sigmas

    def accepted(self, T_accepted: np.ndarray) -> None:
        """Record the error of the pending prediction against the accepted pose."""
        if self._predicted is None:
            return
        shift, turn = prediction_error(self._predicted, T_accepted)
        self._predicted = None
        if shift <= RECORD_LIMIT[0] and turn <= RECORD_LIMIT[1]:
            self._errors.append((shift, turn))

    def spread(self) -> tuple[float, float]:
        """Return the largest recent prediction error: metres and degrees (0 without)."""
        if not self._errors:
            return 0.0, 0.0
        errors = np.asarray(self._errors)
        return float(errors[:, 0].max()), float(errors[:, 1].max())

    def bounds(self, translation: float, rotation: float) -> tuple[float, float]:
        """Return the prediction's correction bounds over the configured ``(m, deg)`` floor."""
        shift, turn = self.spread()
        wide_t, wide_r = GAIN * shift, GAIN * turn
        if self._sigmas is not None:
            sigma_t, sigma_r = self._sigmas
            wide_t = max(wide_t, SIGMAS * float(sigma_t))
            wide_r = max(wide_r, SIGMAS * float(sigma_r))
        return (
            max(translation, min(wide_t, CAP_TRANSLATION)),
            max(rotation, min(wide_r, CAP_ROTATION)),
        )

    def widen(self, odometry: OdometryConfig) -> OdometryConfig:
        """
        Return ``odometry`` with the prediction's rotation bounds widened.

        Only the rotation bounds (``odometry.max_correction_rotation``,
        ``odometry.tracking_rotation``): a hand's prediction errors are turns, and a widened
        translation bound let a pose 0.69 m off be tracked on the handheld OS1-128 drive at
        stride 3 (the recorded translation errors include the poses' own errors there).
        """
        _, max_r = self.bounds(
            odometry.max_correction_translation, odometry.max_correction_rotation
        )
        _, track_r = self.bounds(odometry.tracking_translation, odometry.tracking_rotation)
        if (max_r, track_r) == (odometry.max_correction_rotation, odometry.tracking_rotation):
            return odometry
        return dataclasses.replace(
            odometry, max_correction_rotation=max_r, tracking_rotation=track_r
        )
