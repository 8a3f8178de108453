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
Tracking against the local map: candidates, the trust rule and its state.

A candidate is an initial guess of ``T_odom_current`` refined against the map and judged
by the rules of ``core/alignment/fine_alignment.py`` (absolute bounds, then the inlier fraction
relative to the last accepted frames). A scan is *tracked* (accepted by its refined
prediction alone, no global registration) when :func:`tracking_refusal` finds nothing.
"""

from __future__ import annotations

import time

from mlsemreg_ros.core.alignment.alignment import AlignmentCloud
from mlsemreg_ros.core.alignment.fine_alignment import (
    alignment_cloud,
    Candidate,
    InlierHistory,
    refinement_refusal,
    RefinementBounds,
    relative_inlier_refusal,
    tracking_refusal,
)
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry.local_map import LocalMap
from mlsemreg_ros.core.odometry.motion_model import Prediction
from mlsemreg_ros.core.odometry.steps import Decision
from mlsemreg_ros.core.results import PreparedScan
import numpy as np


class Tracker:
    """Refines guesses against ``map`` and decides whether the prediction is trusted."""

    def __init__(self, local_map: LocalMap) -> None:
        """Track against ``local_map`` (the odometry's ``map``)."""
        self.map = local_map
        self.history = InlierHistory()  # inlier fractions of the last accepted frames
        self.tracked_in_a_row = 0  # scans accepted by the refined prediction alone

    def restart(self) -> None:
        """Forget the history (a new map)."""
        self.history.clear()
        self.tracked_in_a_row = 0

    def candidate(
        self, name: str, T_initial: np.ndarray, cloud: AlignmentCloud, cfg: RegistrationConfig
    ) -> Candidate:
        """Refine ``T_initial`` against the map and judge the result."""
        alignment = self.map.align(cloud, T_initial)
        refusal = refinement_refusal(
            alignment, RefinementBounds.of(cfg.odometry)
        ) or relative_inlier_refusal(
            alignment, cfg.odometry.min_relative_inlier_fraction, self.history
        )
        return Candidate(name, np.asarray(T_initial).copy(), alignment, refusal)

    def refine_prediction(
        self,
        scan: PreparedScan,
        prediction: Prediction | None,
        cfg: RegistrationConfig,
        timings: dict[str, float],
    ) -> Candidate | None:
        """Refine the motion model's prediction against the map (None without one)."""
        if prediction is None:
            return None
        tic = time.perf_counter()
        cloud = alignment_cloud(scan, cfg.fine)  # all cores: small_gicp has the GIL
        timings['fine_cloud_ms'] = 1e3 * (time.perf_counter() - tic)
        tic = time.perf_counter()
        candidate = self.candidate('prediction', prediction.T_odom_current, cloud, cfg)
        timings['fine_prediction_ms'] = 1e3 * (time.perf_counter() - tic)
        return candidate

    def refusal(
        self,
        predicted: Candidate | None,
        prediction: Prediction | None,
        cfg: RegistrationConfig,
    ) -> str:
        """Why the refined prediction may not be accepted alone ('' if it may)."""
        gap = prediction.stamp_gap if prediction is not None else 1.0
        return tracking_refusal(predicted, cfg.odometry, self.tracked_in_a_row, gap, self.history)

    def track(self, predicted: Candidate, cfg: RegistrationConfig) -> Decision:
        """Accept the scan by its refined prediction (no global registration)."""
        self.tracked_in_a_row += 1
        alignment = predicted.alignment
        return Decision(
            source='prediction',
            reason=f'tracked ({self.tracked_in_a_row} in a row)',
            pose=alignment.T_target_source,
            frame_covariance=alignment.covariance(cfg.odometry.covariance_scale, axes='source'),
            inlier_fraction=alignment.inlier_fraction,
            candidates=[predicted],
        )
