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

    deskew(points, point_times)      where motion compensation plugs in (a no-op today)
    registration.prepare(lazy=True)  sanitize, labels, voxelize, keypoints; descriptors and
                                     signatures only if a global registration needs them
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mlsemreg_ros.core.results import PreparedScan
import numpy as np


@dataclass
class PreprocessedScan:
    """A scan as the odometry uses it: the raw arrays (to re-prepare it) and the prepared."""

    points: np.ndarray  # (N, 3) raw (deskewed) points, metres
    labels: np.ndarray  # (N,) raw labels
    scan: PreparedScan


class Preprocessor:
    """Turns a raw scan into the prepared scan of the odometry."""

    def __init__(self, registration: Any) -> None:
        """Prepare with ``registration`` (a :class:`~mlsemreg_ros.core.pipeline.Registration`)."""
        self.registration = registration

    def deskew(self, points: np.ndarray, point_times: np.ndarray | None) -> np.ndarray:
        """
        Motion-compensate ``points`` (N, 3) by their ``point_times`` (N,), seconds.

        The seam of a deskew step: today the points are returned as they are (also
        without per-point times).
        """
        return points

    def __call__(
        self, points: np.ndarray, labels: np.ndarray, point_times: np.ndarray | None = None
    ) -> PreprocessedScan:
        """Deskew and prepare lazily (descriptors on demand, :meth:`Registration.complete`)."""
        points = self.deskew(points, point_times)
        scan = self.registration.prepare(points, labels, lazy=True)
        return PreprocessedScan(np.asarray(points), np.asarray(labels), scan)
