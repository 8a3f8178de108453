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
Preprocessing: a raw scan in, the lazily prepared scan out (``docs/extending.md``).

    deskew(points, point_times, motion)  points mapped to the stamp (core/features/deskew.py), when
                                         preprocess.deskew allows it and the scan has times
                                         and the motion within the sweep is known
    registration.prepare(lazy=True)      sanitize, labels, voxelize, keypoints; descriptors
                                         and signatures only if a global registration needs
                                         them
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mlsemreg_ros.core.features import deskew
from mlsemreg_ros.core.results import PreparedScan
import numpy as np


@dataclass
class PreprocessedScan:
    """A scan as the odometry uses it: the raw arrays (to re-prepare it) and the prepared."""

    points: np.ndarray  # (N, 3) raw (deskewed) points, metres
    labels: np.ndarray  # (N,) raw labels
    scan: PreparedScan
    deskewed: bool = False  # the points were motion-compensated
    point_times: np.ndarray | None = None  # (N,) s after the stamp, as given
    deskew_note: str = ''  # why not, when preprocess.deskew is on
    input_points: np.ndarray | None = None  # (N, 3) as given, when deskewed
    rotation_only: bool = False  # deskewed by the gyro's rotation alone (no velocity yet)
    motion: Any = None  # the SweepMotion / PiecewiseSweepMotion it was deskewed with


class Preprocessor:
    """Turns a raw scan into the prepared scan of the odometry."""

    def __init__(self, registration: Any) -> None:
        """Prepare with ``registration`` (a :class:`~mlsemreg_ros.core.pipeline.Registration`)."""
        self.registration = registration

    def deskew(
        self,
        points: np.ndarray,
        point_times: np.ndarray | None,
        motion: deskew.SweepMotion | deskew.PiecewiseSweepMotion | None = None,
    ) -> np.ndarray:
        """
        Motion-compensate ``points`` (N, 3) by their ``point_times`` (N,), seconds.

        The seam of a deskew step (``docs/extending.md``): :func:`core.deskew.deskew` with
        the motion within the sweep. Called for every scan; ``motion`` is None (and the
        points are returned as they are) when :meth:`refusal` refused the scan.
        """
        if point_times is None or motion is None:
            return points
        return deskew.deskew(points, point_times, motion)

    def refusal(self, points: np.ndarray, point_times: np.ndarray | None, motion: Any) -> str:
        """Why the scan is not deskewed ('' if it is): the mode, the times, the motion."""
        if self.registration.config.preprocess.deskew == 'off':
            return 'preprocess.deskew is off'
        why = deskew.time_span_refusal(point_times, int(np.shape(points)[0]))
        if not why and motion is None:
            why = 'the motion within the sweep is unknown (no prediction yet)'
        return why

    def __call__(
        self,
        points: np.ndarray,
        labels: np.ndarray,
        point_times: np.ndarray | None = None,
        motion: deskew.SweepMotion | deskew.PiecewiseSweepMotion | None = None,
    ) -> PreprocessedScan:
        """Deskew and prepare lazily (descriptors on demand, :meth:`Registration.complete`)."""
        why = self.refusal(points, point_times, motion)
        given = points
        points = self.deskew(points, point_times, None if why else motion)
        scan = self.registration.prepare(points, labels, lazy=True)
        on = self.registration.config.preprocess.deskew == 'on'
        return PreprocessedScan(
            np.asarray(points),
            np.asarray(labels),
            scan,
            deskewed=not why,
            point_times=point_times,
            deskew_note=f'not deskewed: {why}' if why and on else '',
            input_points=None if why else np.asarray(given),
            motion=None if why else motion,
        )
