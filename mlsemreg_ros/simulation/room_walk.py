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
A handheld walk through the room of one real scan, as a rosbag2 with ground truth (issue 35).

One real scan is a room seen once. The walk carries a sensor through it: a figure of eight
of ``radius`` m about the scan's origin (walking speed between 0.47 and 1 times
``peak_speed``), the heading swinging at up to ``yaw_rate`` deg/s, with a little roll,
pitch and step bob. Each sweep (``rate`` Hz) is the room's points seen from the sensor
*at each point's own time*: every point is moved into the sensor frame of the instant it
was measured, so the sweep is motion-distorted as a real one is and its per-point
``time`` field undoes that. Each sweep keeps a random share ``keep`` of the points with
Gaussian noise ``noise_m`` per coordinate, as ``mlsemreg self-pairs`` does for its copies
(evaluation/self_pairs.py). Occlusion does not change as the sensor moves: the walk stays
near the origin (1-2 m), where the room looks nearly the same.

A point's time within the sweep is its azimuth's: a spinning sensor turns clockwise (seen
from above) once per sweep, starting at the first point of the file. The real scans'
own ``time_stamp`` field (the VLP-16's) spans 1.3 ms, a packet's time rather than the
sweep's, so it is not used.

Bag layout (datasets/bag.py): ``/points`` PointCloud2 x, y, z, intensity (when the file
has one) and ``time`` (float32 s after the header stamp = the sweep start; the bag's log
time is the sweep end), ``/ground_truth/odometry`` T_world_sensor at the sweep start
(world = the first sweep start), and ``poses.txt`` / ``times.txt`` beside it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mlsemreg_ros.datasets.bag import BagLayout, BagWriter
import numpy as np
from scipy.spatial.transform import Rotation

#: Roll and pitch sway amplitude (deg), and the step bob's height (m) and rate (Hz).
SWAY_DEG = 2.0
BOB_M = 0.02
STEP_HZ = 1.8
#: Angular frequencies (rad/s) of the heading's two swings, the slower one dominant.
YAW_SWINGS = ((1.3, 1.0), (2.9, 0.3))


@dataclass(frozen=True)
class RoomWalk:
    """How the sensor walks through the room and how each sweep is sampled."""

    frames: int = 40
    rate_hz: float = 10.0
    radius_m: float = 1.5  # the figure of eight's half length (its half width is half that)
    peak_speed: float = 1.2  # m/s, on the figure's crossing; the slowest is 0.47 of it
    yaw_rate_deg: float = 60.0  # the heading's largest rate
    keep: float = 0.7
    noise_m: float = 0.02
    seed: int = 0

    def __post_init__(self) -> None:
        """Refuse values that make no walk."""
        if self.frames < 2 or self.rate_hz <= 0.0 or self.radius_m <= 0.0:
            raise ValueError('a walk needs 2 frames or more, a positive rate and radius')
        if self.peak_speed <= 0.0 or self.yaw_rate_deg < 0.0:
            raise ValueError('the peak speed must be positive and the yaw rate not negative')
        if not 0.0 < self.keep <= 1.0 or self.noise_m < 0.0:
            raise ValueError('keep must be in (0, 1] and the noise not negative')


class WalkTrajectory:
    """T_room_sensor(t) of a :class:`RoomWalk`: smooth, analytic, vectorized over times."""

    def __init__(self, walk: RoomWalk) -> None:
        rng = np.random.default_rng(walk.seed)
        self.walk = walk
        self.heading = rng.uniform(-np.pi, np.pi)  # of the figure of eight in the room
        # x = a sin(w t), y = (a / 2) sin(2 w t): speed a w sqrt(cos^2 u + cos^2 2u) <= a w sqrt 2
        self.omega = walk.peak_speed / (walk.radius_m * np.sqrt(2.0))
        self.phases = rng.uniform(0.0, 2.0 * np.pi, size=len(YAW_SWINGS) + 3)
        self.yaw_phases = np.split(self.phases, [len(YAW_SWINGS)])[0]
        duration = walk.frames / walk.rate_hz
        grid = np.linspace(0.0, duration, 4096)
        rate = sum(
            weight * w * np.cos(w * grid + phase)
            for (w, weight), phase in zip(YAW_SWINGS, self.yaw_phases, strict=True)
        )
        peak = float(np.max(np.abs(rate)))
        self.yaw_scale = np.radians(walk.yaw_rate_deg) / peak if peak > 0.0 else 0.0

    def positions(self, t: np.ndarray) -> np.ndarray:
        """Return where the sensor is in the room, (N, 3), at the times ``t`` (N,) in s."""
        t = np.asarray(t, dtype=np.float64)
        a = self.walk.radius_m
        u = self.omega * t
        along, across = a * np.sin(u), 0.5 * a * np.sin(2.0 * u)
        c, s = np.cos(self.heading), np.sin(self.heading)
        bob = BOB_M * np.sin(2.0 * np.pi * STEP_HZ * t + self.phases[-1])
        return np.stack([c * along - s * across, s * along + c * across, bob], axis=1)

    def rotations(self, t: np.ndarray) -> Rotation:
        """Sensor orientations in the room at times ``t`` (yaw, then pitch and roll sway)."""
        t = np.asarray(t, dtype=np.float64)
        yaw = self.yaw_scale * sum(
            weight * (np.sin(w * t + phase) - np.sin(phase))
            for (w, weight), phase in zip(YAW_SWINGS, self.yaw_phases, strict=True)
        )
        k = len(YAW_SWINGS)
        pitch = np.radians(SWAY_DEG) * np.sin(1.1 * t + self.phases[k])
        roll = np.radians(SWAY_DEG) * np.sin(1.7 * t + self.phases[k + 1])
        return Rotation.from_euler('ZYX', np.stack([yaw, pitch, roll], axis=1))

    def poses(self, t: np.ndarray) -> np.ndarray:
        """T_room_sensor (N, 4, 4) at times ``t``."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        poses = np.tile(np.eye(4), (t.size, 1, 1))
        poses[:, :3, :3] = self.rotations(t).as_matrix()
        poses[:, :3, 3] = self.positions(t)
        return poses


def sweep_times(points: np.ndarray, period_s: float) -> np.ndarray:
    """Each point's time (s) in a clockwise sweep of ``period_s`` starting at the first point."""
    azimuth = np.arctan2(points[:, 1], points[:, 0])
    turned = np.mod(azimuth[0] - azimuth, 2.0 * np.pi)
    return period_s * turned / (2.0 * np.pi)


def seen_from_walk(
    room_points: np.ndarray,
    times: np.ndarray,
    trajectory: WalkTrajectory,
    start_s: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """
    One sweep starting at ``start_s``: kept points in the sensor frame of their own instants.

    Returns the points (M, 3) and the indices (M,) of the room's points they are.
    """
    walk = trajectory.walk
    n = len(room_points)
    chosen = np.sort(rng.choice(n, size=max(1, round(walk.keep * n)), replace=False))
    at = start_s + times[chosen]
    rotation = trajectory.rotations(at)
    local = rotation.inv().apply(room_points[chosen] - trajectory.positions(at))
    return local + rng.normal(0.0, walk.noise_m, local.shape), chosen


@dataclass(frozen=True)
class WrittenWalk:
    """What :func:`write_room_walk` wrote."""

    frames: int
    points: int  # over all sweeps
    farthest_m: float  # the sensor's largest distance from the scan's origin
    peak_yaw_rate_deg: float  # measured on the sweep starts' poses
    path_m: float  # walked between the first and last sweep start


def write_room_walk(
    out: str | Path,
    room_points: np.ndarray,
    walk: RoomWalk,
    intensity: np.ndarray | None = None,
    layout: BagLayout | None = None,
) -> WrittenWalk:
    """Write the walk through ``room_points`` (N, 3), the scan's frame, as a new rosbag2."""
    from mlsemreg_ros.codec.pose_files import write_kitti_poses

    layout = layout or BagLayout()
    out = Path(out)
    room_points = np.asarray(room_points, dtype=np.float64)
    finite = np.all(np.isfinite(room_points), axis=1)
    room_points = room_points[finite]
    if intensity is not None:
        intensity = np.asarray(intensity, dtype=np.float32)[finite]
    trajectory = WalkTrajectory(walk)
    period = 1.0 / walk.rate_hz
    times = sweep_times(room_points, period)
    starts = np.arange(walk.frames) / walk.rate_hz
    T_room_sensor = trajectory.poses(starts)
    T_world_sensor = np.linalg.inv(T_room_sensor[0]) @ T_room_sensor
    rng = np.random.default_rng(walk.seed + 1)
    stamp0, period_ns = 1_000_000_000, round(1e9 * period)
    points = 0
    with BagWriter(out, storage=layout.storage, compress=layout.compress) as bag:
        for index, start in enumerate(starts):
            stamp = stamp0 + index * period_ns
            xyz, chosen = seen_from_walk(room_points, times, trajectory, start, rng)
            bag.write_ground_truth(stamp, T_world_sensor[index], layout)
            bag.write_cloud(
                stamp,
                xyz,
                None,
                None if intensity is None else intensity[chosen],
                frame_id=layout.frame_id,
                topic=layout.points_topic,
                extra_fields={'time': times[chosen].astype(np.float32)},
                log_time_ns=stamp + period_ns,
            )
            points += len(xyz)
    write_kitti_poses(out / 'poses.txt', T_world_sensor)
    np.savetxt(out / 'times.txt', starts, fmt='%.6e')
    yaw = np.unwrap(trajectory.rotations(starts).as_euler('ZYX')[:, 0])
    steps = np.linalg.norm(np.diff(T_room_sensor[:, :3, 3], axis=0), axis=1)
    return WrittenWalk(
        walk.frames,
        points,
        float(np.max(np.linalg.norm(T_room_sensor[:, :2, 3], axis=1))),
        float(np.degrees(np.max(np.abs(np.diff(yaw)))) * walk.rate_hz),
        float(np.sum(steps)),
    )
