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
Field mode of the simulator: skewed sweeps, moving actors, a network's labels, IMU, wheels.

The world, street grid and seed streams are the clean simulator's
(:mod:`mlsemreg_ros.simulation.sequence`); on top of them:

- the drive is continuous in time (:mod:`.motion`, profile ``normal``,
  ``aggressive`` or ``handheld``) on a random-walk route (``street``) or on the
  ``loop`` route (:mod:`.routes`), and starts ``lead_in`` seconds before the first
  sweep so the car is already moving;
- sweep ``k`` starts at drive time ``lead_in + k / rate`` (default: back to back at the
  sensor's 10 Hz; ``SensorModel.at_rate``) and is acquired column by column while the
  car moves (:mod:`.field_lidar`, sensor from :mod:`.sensors`);
- ground truth is the sensor pose at each sweep's start (the header stamp),
  relative to the pose at the first sweep's start;
- IMU and wheel odometry come from the same drive (:mod:`.inertial`);
- moving actors and parked cars that leave (:mod:`.actors`) and a network's labels
  (:mod:`.network_labels`) are added when enabled.

Everything derives from the seed through independent streams, so frame ``k`` is the
same whatever the number of frames (except the loop route with ``frames=0``, which
takes as many frames as the loop needs).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field, replace

from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.simulation.actors import Actors
from mlsemreg_ros.simulation.field_lidar import FieldLidar, FieldScan, LabeledMesh
from mlsemreg_ros.simulation.inertial import (
    ImuConfig,
    ImuSamples,
    simulate_imu,
    simulate_wheel,
    WheelConfig,
    WheelSamples,
)
from mlsemreg_ros.simulation.motion import ContinuousDrive, motion_profile
from mlsemreg_ros.simulation.routes import plan_loop
from mlsemreg_ros.simulation.sensors import sensor_model
from mlsemreg_ros.simulation.sequence import ROUTE_LOOKAHEAD_M, START_TIME_NS
from mlsemreg_ros.simulation.trajectory import plan_route, TrajectoryConfig
from mlsemreg_ros.simulation.world import build_world, StreetGrid, WorldConfig
import numpy as np

ROUTES = ('street', 'loop')

#: SemanticKITTI raw id of the moving version of a learning class (others have none).
MOVING_RAW_IDS = {1: 252, 7: 253, 6: 254, 8: 255, 4: 258, 5: 259}


@dataclass
class FieldConfig:
    """What to simulate in field mode (see the module docstring)."""

    seed: int = 0
    frames: int = 200  # 0: the whole loop route (route 'loop' only)
    sensor: str = 'hdl64'
    profile: str = 'normal'
    route: str = 'street'
    speed: float | None = None  # cruise speed m/s on straights (None: the profile's)
    rate: float | None = None  # scans per second (None: the sensor's 10 Hz)
    moving_objects: bool = True
    network_labels: bool = True
    network: str = 'rangenet++'  # whose per-class IoU the label model follows
    lead_in: float = 1.0  # seconds driven before the first sweep
    imu_lead: float = 0.5  # IMU and wheel samples start this long before the first sweep
    start_time_ns: int = START_TIME_NS
    imu: ImuConfig = field(default_factory=ImuConfig)
    wheel: WheelConfig = field(default_factory=WheelConfig)
    world: WorldConfig = field(default_factory=WorldConfig)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)

    def validate(self) -> None:
        """Raise ValueError naming the bad setting."""
        sensor_model(self.sensor).at_rate(self.rate)
        motion_profile(self.profile)
        if self.route not in ROUTES:
            raise ValueError(f'unknown route {self.route!r}; use one of {list(ROUTES)}')
        if self.frames < 0 or (self.frames == 0 and self.route != 'loop'):
            raise ValueError(f'frames must be >= 1 (0 only with route loop), got {self.frames}')
        from mlsemreg_ros.simulation.network_labels import IOU_PERCENT

        if self.network not in IOU_PERCENT:
            raise ValueError(f'unknown network {self.network!r}; use one of {sorted(IOU_PERCENT)}')
        if self.speed is not None and not 0.5 <= self.speed <= 40.0:
            raise ValueError(f'speed must lie in [0.5, 40] m/s, got {self.speed}')


@dataclass
class FieldFrame:
    """One field-mode sweep, its labels and its ground truth."""

    index: int
    stamp_ns: int  # header stamp = sweep start
    pose: np.ndarray  # (4, 4) T_world_sensor at the sweep start, world = first sweep start
    scan: FieldScan  # true labels, instances and moving flags
    labels: np.ndarray  # (N,) int32 learning ids as the simulated network predicts them


class FieldSimulation:
    """Builds world, route, drive, IMU and wheel odometry once; renders sweeps on demand."""

    def __init__(self, config: FieldConfig | None = None, label_map: LabelMap | None = None):
        cfg = config if config is not None else FieldConfig()
        cfg.validate()
        self.config = cfg
        self.label_map = label_map if label_map is not None else LabelMap.load()
        self.model = sensor_model(cfg.sensor).at_rate(cfg.rate)
        self.profile = motion_profile(cfg.profile)
        world_cfg = replace(cfg.world, seed=cfg.seed)
        self.world_config = world_cfg
        self.grid = StreetGrid.generate(world_cfg)
        traj = self.profile.trajectory_config(cfg.trajectory)
        speed = cfg.speed if cfg.speed is not None else self.profile.cruise_speed
        period = 1.0 / cfg.rate if cfg.rate is not None else self.model.period
        self.interval = period  # between sweep starts
        route_rng = np.random.default_rng([cfg.seed, 3])
        self.loop_length: float | None = None
        if cfg.route == 'loop':
            self.path, self.loop_length = plan_loop(self.grid, route_rng, traj, ROUTE_LOOKAHEAD_M)
        else:
            length = (max(cfg.frames - 1, 1) * period + cfg.lead_in) * speed + ROUTE_LOOKAHEAD_M
            self.path = plan_route(self.grid, length, route_rng, traj)
        stops, dwell = self._stops(np.random.default_rng([cfg.seed, 21]))
        phases = np.random.default_rng([cfg.seed, 4]).uniform(0.0, 2.0 * np.pi, size=4)
        mount = self.profile.mount_height or self.model.mount_height
        self.drive = ContinuousDrive(
            self.path, speed, traj, mount, phases, stops, dwell, self.profile.sway
        )
        self.frames = cfg.frames if cfg.frames > 0 else self._loop_frames()
        self.sweep_starts = cfg.lead_in + period * np.arange(self.frames)
        self.world_poses = self.drive.poses(self.sweep_starts)
        self._origin_inv = np.linalg.inv(self.world_poses[0])
        route_xy = self.path.waypoints()
        self.world = build_world(self.grid, route_xy, world_cfg, self.label_map)
        self.actors = None
        static = LabeledMesh(
            self.world.vertices,
            self.world.triangles,
            self.world.triangle_labels,
            self.world.triangle_instances,
            np.zeros(self.world.num_triangles, dtype=bool),
        )
        if cfg.moving_objects:
            self.actors = Actors.generate(self, np.random.default_rng([cfg.seed, 40]))
            static = self.actors.static_mesh(static)
        self.lidar = FieldLidar(static, self.model)
        self.label_model = None
        if cfg.network_labels:
            from mlsemreg_ros.simulation.network_labels import NetworkLabelModel

            self.label_model = NetworkLabelModel(self.label_map, cfg.seed, cfg.network)
        t0, t1 = self.sweep_starts[0] - cfg.imu_lead, self.sweep_starts[-1] + period
        self.imu: ImuSamples = simulate_imu(
            self.drive, t0, t1, cfg.imu, np.random.default_rng([cfg.seed, 30])
        )
        self.wheel: WheelSamples = simulate_wheel(
            self.drive, t0, t1, cfg.wheel, np.random.default_rng([cfg.seed, 31])
        )

    def _stops(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Arc lengths (k,) of the full stops of the profile and their dwell times (k,)."""
        spacing = self.profile.stop_spacing
        if spacing is None:
            return np.zeros(0), np.zeros(0)
        gaps = rng.uniform(*spacing, size=int(self.path.length / spacing[0]) + 1)
        stops = np.cumsum(gaps)
        stops = stops[stops < self.path.length - 5.0]
        dwell = np.maximum(rng.uniform(*self.profile.stop_dwell, size=stops.size), 1e-2)
        return stops, dwell

    def _loop_frames(self) -> int:
        """Frames until the loop route is back at the first sweep's place (and 5 more)."""
        assert self.loop_length is not None
        first = float(self.drive.arc_length(np.array([self.config.lead_in]))[0])
        t_back = float(self.drive.time_at_arc_length(np.array([first + self.loop_length]))[0])
        return int(np.ceil((t_back - self.config.lead_in) / self.interval)) + 5

    def __len__(self) -> int:
        return self.frames

    @property
    def poses(self) -> np.ndarray:
        """Ground truth (F, 4, 4) at the sweep starts, relative to the first (identity)."""
        return self._origin_inv @ self.world_poses

    def relative_poses(self, times: np.ndarray) -> np.ndarray:
        """Ground truth (n, 4, 4) at any drive times, in the ground-truth world frame."""
        return self._origin_inv @ self.drive.poses(times)

    @property
    def gravity_in_world(self) -> np.ndarray:
        """Gravity (3,) m/s^2 in the ground-truth world frame (the first sweep's sensor frame)."""
        from mlsemreg_ros.simulation.inertial import GRAVITY

        return self._origin_inv[:3, :3] @ np.array([0.0, 0.0, -GRAVITY])

    def stamp_ns(self, drive_time: np.ndarray | float) -> np.ndarray:
        """Header stamps (ns, int64) of drive times (s)."""
        offset = np.asarray(drive_time, dtype=np.float64) - self.config.lead_in
        return self.config.start_time_ns + np.round(offset * 1e9).astype(np.int64)

    def frame(self, index: int) -> FieldFrame:
        """Render sweep ``index`` (deterministic for the seed)."""
        cfg = self.config
        t0 = float(self.sweep_starts[index])
        dynamic = self.actors.dynamic_mesh(t0, self) if self.actors is not None else None
        scan = self.lidar.sweep(
            self.drive, t0, np.random.default_rng([cfg.seed, 5, index]), dynamic
        )
        labels = scan.labels
        if self.label_model is not None:
            labels = self.label_model.predict(scan, index)
        return FieldFrame(index, int(self.stamp_ns(t0)), self.poses[index], scan, labels)

    def __iter__(self) -> Iterator[FieldFrame]:
        for index in range(self.frames):
            yield self.frame(index)

    def raw_labels(self, frame: FieldFrame) -> tuple[np.ndarray, np.ndarray]:
        """
        ``(label, label_gt)`` (N,) uint32 raw SemanticKITTI ids | instance << 16.

        ``label_gt`` is the truth: moving objects carry the moving raw ids (252-259).
        ``label`` is the network's: points it gives the true class of a moving object
        carry that moving id too (as a moving-object segmentation would), and the
        instance bits only where the class is right.
        """
        scan, predicted = frame.scan, frame.labels
        lut = np.asarray(self.label_map.learning_to_raw_ids, dtype=np.int64).copy()
        moving_lut = lut.copy()
        for learning, raw in MOVING_RAW_IDS.items():
            moving_lut[learning] = raw
        truth = np.where(scan.moving, moving_lut[scan.labels], lut[scan.labels])
        gt = truth.astype(np.uint32) | (scan.instances.astype(np.uint32) << np.uint32(16))
        right = predicted == scan.labels
        net = np.where(scan.moving & right, moving_lut[predicted], lut[predicted])
        instance = np.where(right, scan.instances, 0).astype(np.uint32)
        return net.astype(np.uint32) | (instance << np.uint32(16)), gt
