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
More odometry peers of ``eval-bag --baseline``: GenZ-ICP and KISS-SLAM, on the same scans.

Both are used as :class:`~mlsemreg_ros.evaluation.estimators.KissIcpEstimator` uses
KISS-ICP: default configuration for a 100 m sensor, deskew on where the scans carry
per-point times, every estimate accepted (neither has a failure signal).
"""

from __future__ import annotations

import contextlib
import io
from typing import Any

from mlsemreg_ros.datasets.source import Scan
from mlsemreg_ros.evaluation.estimators import KissIcpEstimator
import numpy as np


class GenZIcpEstimator(KissIcpEstimator):
    """
    GenZ-ICP on the same scans, deskew on.

    Lee et al., "GenZ-ICP: Generalizable and Degeneracy-Robust LiDAR Odometry Using an
    Adaptive Weighting", RA-L 2024; PyPI ``genz-icp``. Point-to-plane and point-to-point
    ICP weighted by the planarity of the scene. Its deskew is taken to be the one of
    KISS-ICP 0.x it was forked from: times in sweep units, the scan referred to time 0.5,
    the last frame-to-frame motion spread over one unit. The times
    are given as ``0.5 + (t - t_last) / gap``, with ``gap`` the time since the previous
    scan given to it (one sweep at stride 1): the scan is referred to its last point,
    as the ground truth and KISS-ICP are, and the motion spans the real gap at any stride.
    """

    method = 'GenZ-ICP'
    progress_label = ' (genz-icp)'

    @staticmethod
    def _create(max_range: float) -> Any:
        """Return GenZ-ICP in its default configuration for ``max_range``, deskew on."""
        from genz_icp.config import load_config
        from genz_icp.genz_icp import GenZICP

        config = load_config(None)  # its own voxel size (0.3 m) and planarity threshold
        config.data.deskew = True  # used only on scans with per-point times
        config.data.max_range = max_range
        return GenZICP(config)

    def _inputs(self, scan: Scan) -> tuple[np.ndarray, np.ndarray]:
        """Return the points and the times in GenZ-ICP's unit (empty: no deskew)."""
        points = np.asarray(scan.xyz, dtype=np.float64)
        times = scan.point_times
        gap_s = 1e-9 * (scan.stamp_ns - self._previous_stamp) if self._previous_stamp else 0.0
        self._previous_stamp = scan.stamp_ns
        if times is None or times.shape != (points.shape[0],) or np.ptp(times) == 0.0:
            return points, np.zeros(0)
        times = np.asarray(times, dtype=np.float64)
        unit = gap_s if gap_s > 0.0 else float(np.ptp(times))
        return points, 0.5 + (times - times.max()) / unit

    def _register(self, points: np.ndarray, times: np.ndarray) -> np.ndarray:
        """Register one scan; return its pose (4, 4)."""
        self.odometry.register_frame(points, times if times.size else None)
        return np.asarray(self.odometry.last_pose, dtype=np.float64).copy()


class KissSlamEstimator(KissIcpEstimator):
    """
    KISS-SLAM on the same scans, deskew on.

    Guadagnino et al., "KISS-SLAM: A Simple, Robust, and Accurate 3D LiDAR SLAM System With
    Enhanced Generalization Capabilities", IROS 2025; PyPI ``kiss-slam``. KISS-ICP odometry
    split into local maps every 100 m, MapClosures loop detection between
    local maps, and a pose graph. The pose of a scan is the one KISS-SLAM holds when the
    scan is processed (its current local map's optimized key pose times the odometry pose
    in it): what an online user would read. The loops it closed are in :attr:`closures`.
    """

    method = 'KISS-SLAM'
    progress_label = ' (kiss-slam)'

    @staticmethod
    def _create(max_range: float) -> Any:
        """Return KISS-SLAM in its default configuration for ``max_range``, deskew on."""
        from kiss_slam.config import load_config
        from kiss_slam.slam import KissSLAM

        config = load_config(None)
        config.odometry.preprocessing.deskew = True
        config.odometry.preprocessing.max_range = max_range
        config.odometry.mapping.voxel_size = max_range / 100.0
        config.occupancy_mapper.max_range = max_range
        return KissSLAM(config)

    def _register(self, points: np.ndarray, times: np.ndarray) -> np.ndarray:
        """Register one scan (KISS-SLAM prints its loop decisions: kept in :attr:`log`)."""
        with contextlib.redirect_stdout(io.StringIO()) as printed:
            self.odometry.process_scan(points, times)
        self.log = getattr(self, 'log', '') + printed.getvalue()
        return np.asarray(self.odometry.local_map_graph.last_local_map.endpose).copy()

    @property
    def closures(self) -> list[tuple[int, int]]:
        """(source local map, query local map) of every loop KISS-SLAM accepted."""
        return list(self.odometry.get_closures())
