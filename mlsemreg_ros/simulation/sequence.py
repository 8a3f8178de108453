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
A simulated labeled LiDAR sequence: world + route + sensor + label degradation.

Everything derives from one seed through independent streams
(``np.random.default_rng([seed, stream, ...])``): the street grid, each block,
the route, the motion, and per frame the sensor noise and the label degradation.
Frame ``k`` of a seed is therefore identical whatever the number of frames.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field, replace

from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.simulation.degrade import boundary_blur, random_flips
from mlsemreg_ros.simulation.lidar import Lidar, LidarConfig, LidarScan
from mlsemreg_ros.simulation.trajectory import Path2D, plan_route, sensor_poses, TrajectoryConfig
from mlsemreg_ros.simulation.world import build_world, StreetGrid, World, WorldConfig
import numpy as np

#: Route planned beyond the last frame (> braking distance from cruise speed), metres.
ROUTE_LOOKAHEAD_M = 60.0

#: Header stamp of frame 0 (2023-11-14T22:13:20Z): a fixed, non-zero ROS time.
START_TIME_NS = 1_700_000_000 * 10**9


@dataclass
class SimulationConfig:
    """What to simulate: seed, length, rate, speed, sensor, world and label degradation."""

    seed: int = 0
    frames: int = 200
    rate_hz: float = 10.0
    step: float = 1.0  # metres per frame on straights (1 m at 10 Hz = 36 km/h); slower in turns
    blur_radius: float = 0.0  # boundary blur radius, metres (0: clean labels)
    blur_probability: float = 0.5
    flip_fraction: float = 0.0  # share of points given a random other class
    start_time_ns: int = START_TIME_NS
    lidar: LidarConfig = field(default_factory=LidarConfig)
    world: WorldConfig = field(default_factory=WorldConfig)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)


def drive_poses(
    config: SimulationConfig, path: Path2D, frames: int, rng: np.random.Generator
) -> np.ndarray:
    """World poses (F, 4, 4) of ``frames`` scans along ``path`` (``config``: step, mount, rate)."""
    return sensor_poses(
        path,
        frames,
        config.step,
        config.lidar.mount_height,
        rng,
        config.trajectory,
        dt=1.0 / config.rate_hz,
    )


@dataclass
class SimFrame:
    """One simulated sweep with its ground truth."""

    index: int
    stamp_ns: int
    pose: np.ndarray  # (4, 4) T_world_sensor, world = the first sensor pose (KITTI style)
    scan: LidarScan  # labels after degradation
    clean_labels: np.ndarray  # (N,) int32 learning ids before degradation


class Simulation:
    """Builds the world and route once; renders frames on demand."""

    def __init__(
        self, config: SimulationConfig | None = None, label_map: LabelMap | None = None
    ) -> None:
        cfg = config if config is not None else SimulationConfig()
        self.config = cfg
        self.label_map = label_map if label_map is not None else LabelMap.load()
        world_cfg = replace(cfg.world, seed=cfg.seed)
        self.grid = StreetGrid.generate(world_cfg)
        # Plan beyond the last frame: the car brakes for turns ahead of it, so frame k
        # must see the same route whatever the number of frames.
        length = max(cfg.frames - 1, 1) * cfg.step + ROUTE_LOOKAHEAD_M
        self.path: Path2D = plan_route(
            self.grid, length, np.random.default_rng([cfg.seed, 3]), cfg.trajectory
        )
        self.world_poses = drive_poses(
            cfg, self.path, cfg.frames, np.random.default_rng([cfg.seed, 4])
        )
        route_xy = self.path.waypoints()
        self.world: World = build_world(self.grid, route_xy, world_cfg, self.label_map)
        self.lidar = Lidar(self.world, cfg.lidar)
        self._origin_inv = np.linalg.inv(self.world_poses[0])
        self._classes = np.arange(1, self.label_map.num_classes, dtype=np.int32)

    def __len__(self) -> int:
        return self.config.frames

    @property
    def poses(self) -> np.ndarray:
        """Ground truth (F, 4, 4) relative to the first sensor pose (frame 0 = identity)."""
        return self._origin_inv @ self.world_poses

    def stamp_ns(self, index: int) -> int:
        """Header stamp of frame ``index``."""
        return self.config.start_time_ns + round(index * 1e9 / self.config.rate_hz)

    def frame(self, index: int) -> SimFrame:
        """Render frame ``index`` (deterministic for the seed)."""
        cfg = self.config
        scan = self.lidar.scan(
            self.world_poses[index], np.random.default_rng([cfg.seed, 5, index])
        )
        clean = scan.labels
        labels = clean
        rng = np.random.default_rng([cfg.seed, 6, index])
        if cfg.blur_radius > 0.0:
            labels = boundary_blur(scan.points, labels, cfg.blur_radius, rng, cfg.blur_probability)
        if cfg.flip_fraction > 0.0:
            labels = random_flips(labels, cfg.flip_fraction, self._classes, rng)
        if labels is not clean:
            instances = np.where(labels == clean, scan.instances, 0).astype(np.uint32)
            scan = replace(scan, labels=labels, instances=instances)
        return SimFrame(index, self.stamp_ns(index), self.poses[index], scan, clean)

    def __iter__(self) -> Iterator[SimFrame]:
        for index in range(self.config.frames):
            yield self.frame(index)

    def raw_labels(self, scan: LidarScan) -> np.ndarray:
        """Return the raw labels (N,) uint32 of a scan: SemanticKITTI id | instance << 16."""
        return self.label_map.to_raw(scan.labels, scan.instances)
