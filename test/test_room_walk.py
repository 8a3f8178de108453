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
The handheld walk through a real scan's room (simulation/room_walk.py, issue 35).

Known answers on a hand-made room: the walk's speed, turn rate and reach; each sweep is
the room seen from the sensor at each point's own time (undone exactly with the true
trajectory); the bag carries the ground truth relative to the first sweep and the times.
"""

from __future__ import annotations

from pathlib import Path

from mlsemreg_ros.simulation.room_walk import (
    RoomWalk,
    seen_from_walk,
    sweep_times,
    WalkTrajectory,
    write_room_walk,
)
import numpy as np
import pytest


def _room() -> np.ndarray:
    """Return a 6 x 4 x 2.6 m room with a cupboard, 10 cm apart, the sensor 1 m up."""
    rng = np.random.default_rng(3)
    faces = []
    for lo, hi in (
        ((-3.0, -2.0, 0.0), (3.0, -2.0, 2.6)),
        ((-3.0, 2.0, 0.0), (3.0, 2.0, 2.6)),
        ((-3.0, -2.0, 0.0), (-3.0, 2.0, 2.6)),
        ((3.0, -2.0, 0.0), (3.0, 2.0, 2.6)),
        ((-3.0, -2.0, 0.0), (3.0, 2.0, 0.0)),
        ((1.5, 1.2, 0.0), (2.5, 1.2, 1.8)),  # the cupboard's front
    ):
        lo_, hi_ = np.asarray(lo), np.asarray(hi)
        extent = hi_ - lo_
        count = int(np.prod(extent[extent > 0.0]) / 0.01)
        faces.append(lo_ + rng.random((count, 3)) * (hi_ - lo_))
    return np.vstack(faces) - np.array([0.0, 0.0, 1.0])


def _read_walk(path: Path) -> list:
    """Return the walk's scans as the bag reader gives them (it warns: no label field)."""
    from mlsemreg_ros.datasets.bag import BagScanReader

    reader = BagScanReader(path)
    try:
        with pytest.warns(UserWarning, match='unlabeled'):
            return list(reader.scans())
    finally:
        reader.close()


def test_the_walk_stays_in_the_room_at_walking_speed_and_turn_rate() -> None:
    """A figure of eight within the radius, 0.47-1 x the peak speed, turning at the set rate."""
    walk = RoomWalk(frames=60, radius_m=1.5, peak_speed=1.2, yaw_rate_deg=60.0, seed=4)
    trajectory = WalkTrajectory(walk)
    t = np.linspace(0.0, walk.frames / walk.rate_hz, 3001)
    positions = trajectory.positions(t)
    np.testing.assert_allclose(positions[0], [0.0, 0.0, positions[0, 2]], atol=1e-12)
    assert np.max(np.linalg.norm(positions[:, :2], axis=1)) <= 1.5 + 1e-9
    speed = np.linalg.norm(np.diff(positions[:, :2], axis=0), axis=1) / np.diff(t)
    assert 0.45 * 1.2 <= speed.min() and speed.max() <= 1.2 + 1e-3
    yaw = np.unwrap(trajectory.rotations(t).as_euler('ZYX')[:, 0])
    assert np.degrees(np.max(np.abs(np.diff(yaw) / np.diff(t)))) == pytest.approx(60.0, rel=0.02)
    assert yaw[0] == pytest.approx(0.0, abs=1e-12)


def test_each_sweep_is_the_room_seen_from_the_sensor_at_each_points_own_time() -> None:
    """Undone with the true pose at each point's time, a sweep lands back on the room."""
    room = _room()
    walk = RoomWalk(keep=1.0, noise_m=0.0, seed=1)
    trajectory = WalkTrajectory(walk)
    times = sweep_times(room, 0.1)
    assert times[0] == 0.0 and 0.0 <= times.min() and times.max() < 0.1
    start = 0.7
    local, chosen = seen_from_walk(room, times, trajectory, start, np.random.default_rng(0))
    np.testing.assert_array_equal(chosen, np.arange(len(room)))
    at = start + times
    back = trajectory.rotations(at).apply(local) + trajectory.positions(at)
    np.testing.assert_allclose(back, room, atol=1e-9)
    # the sweep start's pose alone leaves the motion's distortion: centimetres to decimetres
    T = trajectory.poses(np.array([start]))[0]
    rigid = local @ T[:3, :3].T + T[:3, 3]
    skew = np.linalg.norm(rigid - room, axis=1)
    assert 0.02 < skew.max() < 0.5


def test_the_bag_holds_the_sweeps_their_times_and_the_truth_from_the_first_sweep(
    tmp_path: Path,
) -> None:
    """The bag reads back as 12 unlabeled sweeps with times and T_world_sensor of the walk."""
    room = _room()
    walk = RoomWalk(frames=12, seed=2)
    written = write_room_walk(tmp_path / 'walk', room, walk)
    assert written.frames == 12 and written.farthest_m <= walk.radius_m
    poses = WalkTrajectory(walk).poses(np.arange(12) / walk.rate_hz)
    expected = np.linalg.inv(poses[0]) @ poses
    scans = _read_walk(tmp_path / 'walk')
    assert len(scans) == 12
    for scan, pose in zip(scans, expected, strict=True):
        assert scan.labels is None and len(scan) == round(0.7 * len(room))
        np.testing.assert_allclose(scan.pose, pose, atol=1e-6)
        assert scan.point_times is not None
        assert 0.0 <= scan.point_times.min() and scan.point_times.max() < 0.1
    assert (tmp_path / 'walk' / 'poses.txt').is_file()


def test_a_walk_needs_two_frames_and_a_share_of_the_points() -> None:
    """Values that make no walk are refused."""
    with pytest.raises(ValueError):
        RoomWalk(frames=1)
    with pytest.raises(ValueError):
        RoomWalk(keep=0.0)


def test_a_late_first_keyframe_is_scored_against_its_own_scan() -> None:
    """
    The odometry's counter starts again at the first keyframe; eval maps it to that scan.

    A room too thin for a keyframe at the car defaults (the VLP-16's walk) starts the
    odometry on scan 3, counter 0: the next scan's keyframe is scan 3, not scan 0.
    """
    from types import SimpleNamespace

    from mlsemreg_ros.datasets.source import Scan
    from mlsemreg_ros.evaluation.estimators import OdometryEstimator

    counters = iter([0, 0, 0, 0, 1, 2])  # scans 0-2 refused (counter reset), 3 first
    keyframes = iter([0, 0, 0, 0, 0, 1])

    class _Odometry:
        keyframe = None

        def process(self, *args: object, **kwargs: object) -> SimpleNamespace:
            return SimpleNamespace(
                index=next(counters),
                keyframe_index=next(keyframes),
                pose=np.eye(4),
                relative=np.eye(4),
                result=None,
                accepted=True,
                latency_ms=0.0,
                reason='',
                source='prediction',
                frame_covariance=None,
                timings_ms={},
                deskewed=False,
                new_keyframe=False,
            )

    estimator = OdometryEstimator(_Odometry())
    scans = [Scan(i, i, np.zeros((1, 3)), None, None, 'lidar') for i in range(6)]
    keyframe_scans = [estimator.step(scan).keyframe_index for scan in scans]
    assert keyframe_scans[4:] == [3, 4]


def test_the_odometry_tracks_a_walk_through_the_hand_made_room(tmp_path: Path) -> None:
    """12 deskewed sweeps at 10 Hz, turning up to 60 deg/s: each accepted, within 2 deg / 5 cm."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.metrics import rotation_error_deg, translation_error_m
    from mlsemreg_ros.core.odometry import Odometry

    write_room_walk(tmp_path / 'walk', _room(), RoomWalk(frames=12, seed=0))
    scans = _read_walk(tmp_path / 'walk')
    odometry = Odometry(config=RegistrationConfig())
    for scan in scans:
        step = odometry.process(scan.xyz, None, scan.stamp_ns, point_times=scan.point_times)
        pose = np.asarray(step.pose)
        assert step.accepted, step.reason
        assert rotation_error_deg(pose[:3, :3], scan.pose[:3, :3]) < 2.0
        assert translation_error_m(pose[:3, 3], scan.pose[:3, 3]) < 0.05
