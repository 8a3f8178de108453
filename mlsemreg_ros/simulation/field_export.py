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
A field-mode drive as a rosbag2 (``mlsemreg simulate --realism field``).

Topics (header stamps; bag receive times in brackets):

- ``/points`` PointCloud2 [sweep end]: x, y, z, intensity (float32), label (uint32,
  the network's raw SemanticKITTI id | instance << 16), time (float32 s after the
  header stamp = sweep start), label_gt (uint32, the true raw id, moving classes
  252-259), t (uint32 ns after the stamp; Ouster models only), ring (uint16);
- ``/ground_truth/odometry`` Odometry: T_world_sensor at each sweep start;
- ``/imu/data`` Imu (sensor frame, no orientation) and ``/wheel/odometry`` Odometry
  (frame ``odom``, child the sensor frame, twist = measured speed and yaw rate).

Side files: ``poses.txt`` and ``times.txt`` (KITTI format, sweep starts),
``trajectory.npz`` (the true pose at the IMU times, the true IMU signals and biases)
and ``simulation.yaml`` (parameters, gravity in the world frame, topics, fields).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
import time

from mlsemreg_ros.datasets.bag import BagLayout, BagWriter, IMU_TOPIC, WHEEL_TOPIC
from mlsemreg_ros.simulation.field import FieldConfig, FieldSimulation
import numpy as np
import yaml

ODOM_FRAME = 'odom'


@dataclass
class FieldReport:
    """What :func:`write_field_bag` wrote, and how long it took."""

    frames: int
    points_per_scan: float
    path_m: float
    setup_s: float  # world, route, actors, IMU
    total_s: float
    sensor: str = ''
    profile: str = ''
    route: str = ''
    rate_hz: float | None = None  # None: the sensor's own

    def summary(self, out: Path) -> str:
        """Return the one line ``mlsemreg simulate --realism field`` prints."""
        return (
            f'wrote {out}: {self.frames} {self.sensor} sweeps'
            + (f' at {self.rate_hz:g} Hz' if self.rate_hz else '')
            + f' ({self.profile}, {self.route}), '
            f'{self.points_per_scan:.0f} points/scan, {self.path_m:.1f} m driven; setup '
            f'{self.setup_s:.1f} s, total {self.total_s:.1f} s'
        )


def _cloud_fields(sim: FieldSimulation, frame) -> dict[str, np.ndarray]:
    """Return the extra point fields of one sweep (after x, y, z, intensity, label)."""
    scan = frame.scan
    _, truth = sim.raw_labels(frame)
    fields = {'time': scan.times.astype(np.float32), 'label_gt': truth}
    if sim.model.ouster_time:
        fields['t'] = np.round(scan.times * 1e9).astype(np.uint32)
    fields['ring'] = scan.ring
    return fields


def write_field_bag(
    out: Path, config: FieldConfig, layout: BagLayout | None = None, progress: bool = True
) -> FieldReport:
    """Simulate ``config`` in field mode and write the bag folder ``out`` (must not exist)."""
    from mlsemreg_ros.codec.pose_files import write_kitti_poses
    from tqdm import tqdm

    layout = layout or BagLayout()
    start = time.perf_counter()
    sim = FieldSimulation(config)
    built = time.perf_counter()
    period_ns = round(sim.model.period * 1e9)
    imu_stamps = sim.stamp_ns(sim.imu.times)
    wheel_stamps = sim.stamp_ns(sim.wheel.times)
    imu_cfg, wheel_cfg = config.imu, config.wheel
    gyro_var = (imu_cfg.gyro_noise_density**2) * imu_cfg.rate_hz
    accel_var = (imu_cfg.accel_noise_density**2) * imu_cfg.rate_hz
    next_imu = next_wheel = 0
    points = 0
    stamps = []
    frames = tqdm(sim, total=len(sim), desc='simulate', unit='scan', disable=not progress)
    with BagWriter(out, storage=layout.storage, compress=layout.compress) as bag:

        def inertial_until(limit_ns: int) -> None:
            nonlocal next_imu, next_wheel
            while next_imu < imu_stamps.size and imu_stamps[next_imu] <= limit_ns:
                i = next_imu
                bag.write_imu(
                    int(imu_stamps[i]),
                    sim.imu.angular_velocity[i],
                    sim.imu.linear_acceleration[i],
                    frame_id=layout.frame_id,
                    topic=IMU_TOPIC,
                    gyro_variance=gyro_var,
                    accel_variance=accel_var,
                )
                next_imu += 1
            while next_wheel < wheel_stamps.size and wheel_stamps[next_wheel] <= limit_ns:
                i = next_wheel
                cov = np.zeros(36)
                cov[[0, 7, 35]] = [wheel_cfg.speed_noise**2, 1e-4, wheel_cfg.yaw_rate_noise**2]
                bag.write_odometry(
                    int(wheel_stamps[i]),
                    sim.wheel.poses[i],
                    frame_id=ODOM_FRAME,
                    child_frame_id=layout.frame_id,
                    topic=WHEEL_TOPIC,
                    twist=(
                        np.array([sim.wheel.speed[i], 0.0, 0.0]),
                        np.array([0.0, 0.0, sim.wheel.yaw_rate[i]]),
                    ),
                )
                next_wheel += 1

        for frame in frames:
            inertial_until(frame.stamp_ns)
            bag.write_ground_truth(frame.stamp_ns, frame.pose, layout)
            inertial_until(frame.stamp_ns + period_ns)
            label, _ = sim.raw_labels(frame)
            bag.write_cloud(
                frame.stamp_ns,
                frame.scan.points,
                label,
                frame.scan.intensity,
                frame_id=layout.frame_id,
                topic=layout.points_topic,
                extra_fields=_cloud_fields(sim, frame),
                log_time_ns=frame.stamp_ns + period_ns,
            )
            points += len(frame.scan)
            stamps.append(frame.stamp_ns)
        inertial_until(np.iinfo(np.int64).max)
    write_kitti_poses(out / 'poses.txt', sim.poses)
    np.savetxt(out / 'times.txt', (np.asarray(stamps) - stamps[0]) / 1e9, fmt='%.6e')
    np.savez_compressed(
        out / 'trajectory.npz',
        stamps_ns=imu_stamps,
        T_world_sensor=sim.relative_poses(sim.imu.times),
        true_angular_velocity=sim.imu.true_angular_velocity,
        true_specific_force=sim.imu.true_specific_force,
        gyro_bias=sim.imu.gyro_bias,
        accel_bias=sim.imu.accel_bias,
        wheel_stamps_ns=wheel_stamps,
        wheel_true_speed=sim.wheel.true_speed,
    )
    (out / 'simulation.yaml').write_text(yaml.safe_dump(_metadata(sim, layout), sort_keys=False))
    path_m = float(np.sum(np.linalg.norm(np.diff(sim.poses[:, :3, 3], axis=0), axis=1)))
    return FieldReport(
        len(stamps),
        points / max(len(stamps), 1),
        path_m,
        built - start,
        time.perf_counter() - start,
        config.sensor,
        config.profile,
        config.route,
        config.rate,
    )


def _metadata(sim: FieldSimulation, layout: BagLayout) -> dict:
    model = sim.model
    fields = ['x', 'y', 'z', 'intensity', 'label', 'time', 'label_gt']
    fields += ['t'] if model.ouster_time else []
    meta = {
        'realism': 'field',
        'simulation': dataclasses.asdict(sim.config),
        'frames': sim.frames,
        'sensor': {
            'model': model.name,
            'beams': model.beams,
            'columns': model.columns,
            'elevations_deg': [round(e, 4) for e in model.elevations_deg],
            'max_range_m': model.max_range,
            'min_range_m': model.min_range,
            'period_s': model.period,
            'scan_interval_s': sim.interval,
            'pattern': 'rosette (non-repetitive)' if model.rosette else 'spinning',
            'rotation': (
                'rosette of two counter-rotating prisms around x'
                if model.rosette
                else 'clockwise seen from above, sweep starts behind (azimuth 180 deg)'
            ),
        },
        'stamps': 'header stamp = sweep start; time/t = offset of the column from it',
        'point_fields': [*fields, 'ring'],
        'topics': {
            'points': layout.points_topic,
            'ground_truth': layout.gt_topic,
            'imu': IMU_TOPIC,
            'wheel_odometry': WHEEL_TOPIC,
        },
        'frames_ids': {'sensor': layout.frame_id, 'world': layout.world_frame, 'odom': ODOM_FRAME},
        'imu_extrinsic': 'identity (IMU frame = sensor frame)',
        'gravity_in_world': [float(v) for v in sim.gravity_in_world],
        'wheel_scale_error': sim.config.wheel.scale_error,
        'route': {'kind': sim.config.route, 'length_m': float(sim.path.length)},
        'world': {
            'triangles': sim.world.num_triangles,
            'objects': sim.world.object_counts,
        },
    }
    if sim.loop_length is not None:
        meta['route']['loop_length_m'] = float(sim.loop_length)
    if sim.actors is not None:
        meta['actors'] = sim.actors.summary()
    if sim.profile.stop_spacing is not None:
        meta['stops_arc_length_m'] = [round(float(s), 2) for s in sim.drive.stops]
    return meta
