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

"""Field mode's sensors, platforms and rates: HDL-32E, the Livox rosette, handheld, 2-20 Hz."""

from __future__ import annotations

from pathlib import Path

from mlsemreg_ros.datasets.bag import BagScanReader, read_imu
from mlsemreg_ros.simulation.field import FieldConfig, FieldSimulation
from mlsemreg_ros.simulation.field_lidar import FieldLidar, LabeledMesh
from mlsemreg_ros.simulation.inertial import true_motion
from mlsemreg_ros.simulation.sensors import HDL32, LIVOX, SENSORS, VLP16
from mlsemreg_ros.tools import cli
import numpy as np
import pytest


class _Still:
    """A sensor standing 1.73 m above the origin, level."""

    def poses(self, t: np.ndarray) -> np.ndarray:
        poses = np.tile(np.eye(4), (np.atleast_1d(t).size, 1, 1))
        poses[:, 2, 3] = 1.73
        return poses


def _room() -> LabeledMesh:
    """Build a box room around the sensor (30 m walls, 40 m high, with a floor)."""
    vertices = np.array(
        [[x, y, z] for z in (0.0, 40.0) for x, y in ((-30, -30), (30, -30), (30, 30), (-30, 30))],
        np.float32,
    )
    faces = [[0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4],
             [3, 4, 7], [0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]]  # fmt: skip
    n = len(faces)
    return LabeledMesh(vertices, np.array(faces, np.uint32), np.full(n, 13, np.int32),
                       np.zeros(n, np.uint32), np.zeros(n, bool))  # fmt: skip


def _elevation_deg(points: np.ndarray) -> np.ndarray:
    return np.degrees(np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1])))


def test_hdl32_beams_are_at_their_elevations() -> None:
    elevations = np.asarray(HDL32.elevations_deg)
    assert HDL32.beams == 32
    assert elevations[0] == pytest.approx(10.67) and elevations[-1] == pytest.approx(-30.67)
    np.testing.assert_allclose(np.diff(elevations), -41.34 / 31)  # 1.33 deg apart
    scan = FieldLidar(_room(), HDL32).sweep(_Still(), 0.0, np.random.default_rng(0))
    # Directions are exact (the noise is along the ray): each point lies on its beam's cone.
    error = _elevation_deg(scan.points.astype(np.float64)) - elevations[scan.ring]
    assert np.abs(error).max() < 0.01
    assert np.unique(scan.ring).size == 32


def test_livox_rosette_fills_a_70_degree_circle_and_never_repeats() -> None:
    lidar = FieldLidar(_room(), LIVOX)
    scans = [lidar.sweep(_Still(), 0.1 * k, np.random.default_rng(k)) for k in range(10)]
    directions = [s.points / np.linalg.norm(s.points, axis=1, keepdims=True) for s in scans]
    off_axis = np.degrees(np.arccos(np.clip(np.concatenate(directions)[:, 0], -1, 1)))
    assert off_axis.max() <= 35.2 + 0.01  # the 70.4 deg field of view
    assert np.quantile(off_axis, 0.99) > 33.0
    assert np.all(scans[0].ring == 0) and LIVOX.beams == 1

    def cells(d: np.ndarray) -> set[tuple[int, int]]:  # 1 deg cells of the field of view
        angles = np.degrees(np.column_stack([np.arctan2(d[:, 1], d[:, 0]), np.arcsin(d[:, 2])]))
        return set(map(tuple, np.floor(angles).astype(int)))

    # Non-repetitive: each frame draws other cells, and the coverage grows with time.
    one, two = cells(directions[0]), cells(directions[1])
    assert len(one ^ two) > 0.5 * len(one)
    union = set().union(*(cells(d) for d in directions))
    assert len(union) > 2.5 * len(one)
    disk = np.pi * 35.2**2
    assert len(union) > 0.6 * disk


@pytest.mark.parametrize('name', sorted(SENSORS))
def test_per_point_times_span_the_sweep_in_firing_order(name: str) -> None:
    model = SENSORS[name]
    scan = FieldLidar(_room(), model).sweep(_Still(), 0.0, np.random.default_rng(2))
    assert scan.times.min() >= 0.0 and scan.times.max() < model.period
    assert scan.times.max() > 0.95 * model.period
    assert np.all(np.diff(scan.times) >= 0) and np.all(np.diff(scan.column) >= 0)
    np.testing.assert_allclose(
        scan.times, model.column_times(0.0)[scan.column], atol=model.period / model.columns
    )


@pytest.mark.parametrize('rate', [2.0, 20.0])
def test_2_and_20_hz_drives_have_their_interval_sweep_and_truth(rate: float) -> None:
    sim = FieldSimulation(
        FieldConfig(seed=3, frames=5, sensor='vlp16', rate=rate, moving_objects=False)
    )
    interval = 1.0 / rate
    period = 0.05 if rate == 20.0 else 0.1  # 20 Hz: the sensor turns faster; 2 Hz: key frames
    assert sim.model.period == pytest.approx(period)
    assert sim.model.columns == (900 if rate == 20.0 else VLP16.columns)
    stamps = np.array([sim.frame(k).stamp_ns for k in range(5)])
    np.testing.assert_array_equal(np.diff(stamps), round(interval * 1e9))
    frame = sim.frame(4)
    assert frame.scan.times.max() < period
    np.testing.assert_allclose(frame.pose, sim.relative_poses(sim.sweep_starts[[4]])[0])
    speed = np.linalg.norm(np.diff(sim.poses[:, :3, 3], axis=0), axis=1) / interval
    assert np.all((speed > 3.0) & (speed < 10.5))  # the car's speed, whatever the rate
    assert sim.imu.times[0] < sim.sweep_starts[0] and sim.imu.times[-1] >= sim.sweep_starts[-1]
    assert frame.labels.shape == frame.scan.labels.shape


def test_rate_outside_the_sensor_range_is_refused() -> None:
    with pytest.raises(ValueError, match='rate'):
        FieldConfig(rate=25.0).validate()
    assert SENSORS['hdl64'].at_rate(10.0) is SENSORS['hdl64']
    assert SENSORS['hdl64'].at_rate(5.0).columns == 2 * 2083


def test_a_2_hz_bag_keeps_labels_imu_and_per_point_times(tmp_path: Path) -> None:
    out = tmp_path / 'rate2'
    argv = ['simulate', str(out), '--realism', 'field', '--frames', '3', '--sensor', 'hdl32']
    assert cli.main([*argv, '--rate', '2', '--quiet']) == 0
    sim = FieldSimulation(FieldConfig(seed=0, frames=3, sensor='hdl32', rate=2.0))
    reader = BagScanReader(out)
    scans = list(reader.scans())
    reader.close()
    assert [s.stamp_ns for s in scans] == [sim.frame(k).stamp_ns for k in range(3)]
    for scan in scans:
        frame = sim.frame(scan.index)
        np.testing.assert_allclose(scan.point_times, frame.scan.times, atol=1e-7)
        assert scan.labels.shape == frame.scan.labels.shape and scan.labels.any()
    imu = read_imu(out)
    assert imu.stamps_ns[0] < scans[0].stamp_ns and imu.stamps_ns[-1] > scans[-1].stamp_ns


def test_handheld_profile_walks_turns_sways_and_steps() -> None:
    sim = FieldSimulation(
        FieldConfig(seed=1, frames=600, profile='handheld', moving_objects=False,
                    network_labels=False)
    )  # fmt: skip
    t = np.arange(sim.sweep_starts[0], sim.sweep_starts[-1], 0.01)
    omega, _, velocity = true_motion(sim.drive, t)
    poses = sim.drive.poses(t)
    speed = np.linalg.norm(velocity, axis=1)
    horizontal = np.linalg.norm(velocity[:, :2], axis=1)
    assert np.median(horizontal) == pytest.approx(1.4, abs=0.15)  # walking
    assert speed.max() < 2.0
    yaw_rate = np.degrees(np.abs(omega[:, 2]))
    assert 60.0 < yaw_rate.max() <= 90.0  # looking around, and corners
    assert np.degrees(np.abs(omega[:, :2])).max() < 30.0
    pitch = np.degrees(np.arcsin(-poses[:, 2, 0]))
    roll = np.degrees(np.arctan2(poses[:, 2, 1], poses[:, 2, 2]))
    assert 1.5 < pitch.std() < 6.0 and 1.5 < roll.std() < 6.0
    # Steps: the height oscillates at the step rate (1.8 Hz), 2.5 cm up and down.
    height = poses[:, 2, 3] - np.convolve(poses[:, 2, 3], np.ones(101) / 101, mode='same')
    spectrum = np.abs(np.fft.rfft(height[200:-200]))
    frequencies = np.fft.rfftfreq(height[200:-200].size, 0.01)
    assert frequencies[np.argmax(spectrum)] == pytest.approx(1.8, abs=0.05)
    assert sim.drive.mount_height == 1.4
    # A walker pauses: standing still, the hand still moves.
    standing = horizontal < 0.05
    assert standing.any() and np.degrees(np.abs(omega[standing])).max() > 5.0
