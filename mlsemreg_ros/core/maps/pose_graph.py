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
The keyframe pose graph, optimized with GTSAM (docs/maps.md).

Nodes are keyframes (``T_map_keyframe``); edges are the odometry between consecutive
keyframes and the verified loop closures (``T_a_b`` from a registration the confidence
rule accepted). The first keyframe is fixed by a tight prior. Odometry edges get standard
deviations proportional to the distance travelled (``map.odometry_sigma_*`` per metre,
at least 0.1 m worth); loop edges ``map.loop_sigma_*`` (Gaussian: a loop edge is only
added after the confidence rule accepted its registration and its pose lay within
``map.loop_search_radius`` of the drifting one, core/maps/mapping.py; a robust kernel would
let the odometry keep part of the drift it is meant to remove). The solver is GTSAM's
Levenberg-Marquardt.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
from mlsemreg_ros.core.config import MapConfig
import numpy as np

#: Least distance (m) an odometry edge's noise is scaled by.
MIN_EDGE_TRAVEL_M = 0.1
#: Standard deviation of the prior on the first keyframe (rad and m).
PRIOR_SIGMA = 1e-6


@dataclass
class LoopEdge:
    """A verified loop closure: ``T_a_b`` maps keyframe ``b``'s frame into ``a``'s."""

    a: int
    b: int
    T_a_b: np.ndarray


def _noise(rotation_rad: float, translation_m: float) -> gtsam.noiseModel.Base:
    # GTSAM's Pose3 tangent order: rotation (rx, ry, rz), then translation (tx, ty, tz)
    sigmas = np.array([rotation_rad] * 3 + [translation_m] * 3, dtype=np.float64)
    return gtsam.noiseModel.Diagonal.Sigmas(sigmas)


class PoseGraph:
    """Keyframe poses, odometry edges and loop edges; :meth:`optimize` with GTSAM."""

    def __init__(self, config: MapConfig) -> None:
        """Noise models from ``config`` (``map.*_sigma_*``)."""
        self.config = config
        self.poses: dict[int, np.ndarray] = {}  # initial estimates, T_map_keyframe
        self.order: list[int] = []
        self.odometry: list[tuple[int, int, np.ndarray]] = []
        self.loops: list[LoopEdge] = []

    def __len__(self) -> int:
        return len(self.order)

    def add_keyframe(
        self, keyframe_id: int, T_map_keyframe: np.ndarray, T_previous_keyframe: np.ndarray | None
    ) -> None:
        """Add a node; ``T_previous_keyframe``: the odometry from the previous node to it."""
        if self.order and T_previous_keyframe is not None:
            self.odometry.append((self.order[-1], keyframe_id, np.asarray(T_previous_keyframe)))
        self.poses[keyframe_id] = np.asarray(T_map_keyframe, dtype=np.float64).copy()
        self.order.append(keyframe_id)

    def add_loop(self, a: int, b: int, T_a_b: np.ndarray) -> None:
        """Add a verified loop edge between two existing nodes."""
        if a not in self.poses or b not in self.poses:
            raise KeyError(f'loop {a} -> {b}: unknown keyframe')
        self.loops.append(LoopEdge(a, b, np.asarray(T_a_b, dtype=np.float64).copy()))

    def optimize(self) -> dict[int, np.ndarray]:
        """Optimized ``T_map_keyframe`` of every node (also kept as the new estimates)."""
        if not self.order:
            return {}
        cfg = self.config
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        for keyframe_id, pose in self.poses.items():
            values.insert(keyframe_id, gtsam.Pose3(pose))
        first = self.order[0]
        graph.add(
            gtsam.PriorFactorPose3(
                first, gtsam.Pose3(self.poses[first]), _noise(PRIOR_SIGMA, PRIOR_SIGMA)
            )
        )
        for a, b, T_a_b in self.odometry:
            travel = max(float(np.linalg.norm(T_a_b[:3, 3])), MIN_EDGE_TRAVEL_M)
            noise = _noise(
                np.radians(cfg.odometry_sigma_rotation) * travel,
                cfg.odometry_sigma_translation * travel,
            )
            graph.add(gtsam.BetweenFactorPose3(a, b, gtsam.Pose3(T_a_b), noise))
        loop_noise = _noise(np.radians(cfg.loop_sigma_rotation), cfg.loop_sigma_translation)
        for loop in self.loops:
            graph.add(
                gtsam.BetweenFactorPose3(loop.a, loop.b, gtsam.Pose3(loop.T_a_b), loop_noise)
            )
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(100)
        result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
        self.poses = {k: result.atPose3(k).matrix() for k in self.order}
        return dict(self.poses)
