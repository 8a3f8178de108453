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


"""Field mode of the simulator: clean mode unchanged, skew, time fields, actors, IMU, routes."""

from __future__ import annotations

import hashlib
from pathlib import Path

from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.datasets.bag import (
    BagLayout,
    BagScanReader,
    open_reader,
    read_imu,
    read_wheel_odometry,
)
from mlsemreg_ros.simulation.export import write_simulation_bag
from mlsemreg_ros.simulation.field import FieldConfig, FieldSimulation
from mlsemreg_ros.simulation.field_export import write_field_bag
from mlsemreg_ros.simulation.field_lidar import FieldLidar, LabeledMesh
from mlsemreg_ros.simulation.inertial import true_motion
from mlsemreg_ros.simulation.lidar import LidarConfig
from mlsemreg_ros.simulation.sensors import HDL64, SENSORS
from mlsemreg_ros.simulation.sequence import Simulation, SimulationConfig
from mlsemreg_ros.tools import cli
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

LABELS = LabelMap.load()

#: sha256 of the clean simulator's arrays and bag, computed on main's code before field
#: mode was added (``--realism clean`` must stay bit-identical; same machine and libraries).
CLEAN_SIM_SHA256 = 'e0fa25182ddc48f29da4e068133bfe0112127663b1fcf36f40b6a7c74e2a1455'
CLEAN_BLUR_SHA256 = '9d13aeee30e41a0841ad0e153e8b664b81c1a83bdc8d996a2e63caf96aedfd5b'
CLEAN_BAG_SHA256 = 'fbd01235ffddbaf00066bff906c988c3928f5290fa02dc23ec5f7e2687e57e9c'
SMALL_LIDAR = LidarConfig(beams=32, azimuth_steps=512)


def _sim_hash(config: SimulationConfig) -> str:
    h = hashlib.sha256()
    sim = Simulation(config)
    h.update(np.ascontiguousarray(sim.poses).tobytes())
    for f in sim:
        scan = f.scan
        for a in (scan.points, scan.labels, scan.instances, scan.intensity, scan.ring):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(np.ascontiguousarray(f.clean_labels).tobytes())
        h.update(np.ascontiguousarray(f.pose).tobytes())
        h.update(str(f.stamp_ns).encode())
    return h.hexdigest()


def test_clean_mode_is_bit_identical_to_before_field_mode(tmp_path: Path) -> None:
    assert _sim_hash(SimulationConfig(seed=0, frames=3)) == CLEAN_SIM_SHA256
    blurred = SimulationConfig(
        seed=2, frames=2, lidar=SMALL_LIDAR, blur_radius=1.0, flip_fraction=0.05
    )
    assert _sim_hash(blurred) == CLEAN_BLUR_SHA256
    out = tmp_path / 'bag'
    write_simulation_bag(out, SimulationConfig(seed=1, frames=3, lidar=SMALL_LIDAR), BagLayout(),
                         progress=False)  # fmt: skip
    h = hashlib.sha256()
    reader = open_reader(out)
    for connection, t, raw in reader.messages():
        h.update(connection.topic.encode())
        h.update(str(t).encode())
        h.update(bytes(raw))
    reader.close()
    h.update((out / 'poses.txt').read_bytes())
    h.update((out / 'times.txt').read_bytes())
    assert h.hexdigest() == CLEAN_BAG_SHA256


class _ConstantVelocity:
    """A drive along +x at ``speed`` m/s, sensor 1.73 m up, level."""

    def __init__(self, speed: float) -> None:
        self.speed = speed

    def poses(self, t: np.ndarray) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        poses = np.tile(np.eye(4), (t.size, 1, 1))
        poses[:, 0, 3] = self.speed * t
        poses[:, 2, 3] = 1.73
        return poses


def _wall(x: float) -> LabeledMesh:
    """Build a wall across the road at ``x`` (y in +-60 m, z in 0..12 m)."""
    vertices = np.array([[x, -60, 0], [x, 60, 0], [x, 60, 12], [x, -60, 12]], np.float32)
    triangles = np.array([[0, 1, 2], [0, 2, 3]], np.uint32)
    return LabeledMesh(vertices, triangles, np.full(2, 13, np.int32), np.zeros(2, np.uint32),
                       np.zeros(2, bool))  # fmt: skip


def test_a_wall_seen_while_moving_is_skewed_by_v_dt_and_times_follow_azimuth() -> None:
    speed, wall = 10.0, 20.0
    model = HDL64.__class__(**{**HDL64.__dict__, 'range_noise': 0.0, 'dropout': 0.0})
    lidar = FieldLidar(_wall(wall), model)
    scan = lidar.sweep(_ConstantVelocity(speed), 0.0, np.random.default_rng(0))
    assert len(scan) > 1000
    t = scan.times
    assert t.min() >= 0.0 and t.max() < model.period
    # Time is the column's: clockwise from behind, so azimuth (in the scan's own frame)
    # gives the time within one column step.
    azimuth = np.arctan2(scan.points[:, 1], scan.points[:, 0])
    expected = model.period * np.mod(np.pi - azimuth, 2 * np.pi) / (2 * np.pi)
    assert np.max(np.abs(expected - t)) < 1.01 * model.period / model.columns
    # Points are ordered by time.
    assert np.all(np.diff(t) >= 0.0)
    # Skew: the wall is at x = 20 - v t in the frame of each point's instant.
    x = scan.points[:, 0].astype(np.float64)
    np.testing.assert_allclose(x + speed * t, wall, atol=2e-3)
    assert x.max() - x.min() > 0.5 * speed * (t.max() - t.min())  # really skewed
    slope = np.polyfit(t, x, 1)[0]
    assert slope == pytest.approx(-speed, rel=0.01)


@pytest.fixture(scope='module')
def field_sim() -> FieldSimulation:
    return FieldSimulation(FieldConfig(seed=0, frames=40, sensor='vlp16'))


def test_each_point_matches_the_sensor_pose_at_its_own_time(field_sim: FieldSimulation) -> None:
    frame = field_sim.frame(20)
    scan = frame.scan
    t0 = field_sim.sweep_starts[20]
    poses = field_sim.drive.poses(t0 + scan.times)
    at_own_time = np.einsum('nij,nj->ni', poses[:, :3, :3], scan.points) + poses[:, :3, 3]
    error = np.linalg.norm(at_own_time - scan.world_points, axis=1)
    assert np.median(error) < 0.05  # range noise (3 cm) only
    start = field_sim.drive.poses(np.array([t0]))[0]
    at_start = scan.points @ start[:3, :3].T + start[:3, 3]
    late = scan.times > 0.05
    skew = np.linalg.norm(at_start[late] - scan.world_points[late], axis=1)
    assert np.median(skew) > 0.4  # about 10 m/s x 0.075 s


def test_moving_objects_carry_moving_raw_ids_and_their_learning_class(
    field_sim: FieldSimulation,
) -> None:
    summary = field_sim.actors.summary()
    assert summary['moving']['car'] > 0 and summary['moving']['person'] > 0
    seen = 0
    for k in range(0, 40, 4):
        frame = field_sim.frame(k)
        scan = frame.scan
        label, truth = field_sim.raw_labels(frame)
        raw = truth & 0xFFFF
        moving = scan.moving
        seen += int(moving.sum())
        assert np.all((raw[moving] >= 252) & (raw[moving] <= 259))
        assert np.all(raw[~moving] < 252)
        np.testing.assert_array_equal(LABELS.to_learning(truth, 'raw'), scan.labels)
        assert set(np.unique(scan.labels[moving])) <= {1, 6, 7}
        # The network's label keeps the moving id only where its class is right.
        right = moving & (frame.labels == scan.labels)
        np.testing.assert_array_equal(label[right] & 0xFFFF, raw[right])
    assert seen > 100


def test_network_labels_are_wrong_on_some_points_and_flicker(field_sim: FieldSimulation) -> None:
    a, b = field_sim.frame(10), field_sim.frame(11)
    wrong = np.mean(a.labels != a.scan.labels)
    assert 0.03 < wrong < 0.4
    # A network never predicts unlabeled.
    assert not np.any(a.labels == 0)
    # Deterministic per frame, different between frames.
    np.testing.assert_array_equal(field_sim.frame(10).labels, a.labels)
    assert not np.array_equal(
        a.labels != a.scan.labels, b.labels[: len(a.scan)] != b.scan.labels[: len(a.scan)]
    )


def test_imu_integrates_to_the_true_rotation_over_a_sweep(field_sim: FieldSimulation) -> None:
    imu = field_sim.imu
    for k in (5, 17, 33):
        t0 = field_sim.sweep_starts[k]
        inside = (imu.times >= t0 - 1e-9) & (imu.times <= t0 + 0.1 + 1e-9)
        times, gyro = imu.times[inside], imu.angular_velocity[inside]
        rotation = Rotation.identity()
        for i in range(times.size - 1):
            rotation = rotation * Rotation.from_rotvec(
                0.5 * (gyro[i] + gyro[i + 1]) * (times[i + 1] - times[i])
            )
        ends = field_sim.drive.poses(np.array([times[0], times[-1]]))
        truth = Rotation.from_matrix(ends[0, :3, :3].T @ ends[1, :3, :3])
        assert np.degrees((truth.inv() * rotation).magnitude()) < 0.1  # bias 0.3 deg/s x 0.1 s
    # Gravity is in the accelerometer: about 9.81 m/s^2 on average, mostly along +z.
    assert np.mean(imu.linear_acceleration[:, 2]) == pytest.approx(9.81, abs=0.3)


def test_wheel_speed_has_the_configured_scale_error(field_sim: FieldSimulation) -> None:
    wheel = field_sim.wheel
    moving = wheel.true_speed > 1.0
    ratio = np.median(wheel.speed[moving] / wheel.true_speed[moving])
    assert ratio == pytest.approx(1.0 + field_sim.config.wheel.scale_error, abs=0.003)


@pytest.mark.parametrize('name', sorted(SENSORS))
def test_sensor_models_have_their_beams_and_range(name: str) -> None:
    model = SENSORS[name]
    assert model.beams == {'hdl64': 64, 'hdl32': 32, 'vlp16': 16, 'os128': 128, 'livox': 1}[name]
    # A box room around the sensor (30 m walls, 40 m high, with a floor): every beam hits.
    vertices = np.array(
        [[x, y, z] for z in (0.0, 40.0) for x, y in ((-30, -30), (30, -30), (30, 30), (-30, 30))],
        np.float32,
    )
    faces = [[0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4],
             [3, 4, 7], [0, 2, 1], [0, 3, 2]]  # fmt: skip
    n = len(faces)
    world = LabeledMesh(vertices, np.array(faces, np.uint32), np.full(n, 13, np.int32),
                        np.zeros(n, np.uint32), np.zeros(n, bool))  # fmt: skip
    lidar = FieldLidar(world, model)
    scan = lidar.sweep(_ConstantVelocity(0.0), 0.0, np.random.default_rng(1))
    np.testing.assert_array_equal(np.unique(scan.ring), np.arange(model.beams))
    assert len(scan) == pytest.approx(model.beams * model.columns * (1 - model.dropout), rel=0.02)
    assert np.linalg.norm(scan.points, axis=1).max() <= model.max_range
    elevation = np.degrees(np.arctan2(scan.points[:, 2], np.hypot(*scan.points[:, :2].T)))
    low, high = model.elevation_range_deg()
    assert elevation.max() <= high + 0.5
    assert elevation.min() >= low - 0.5
    assert np.unique(scan.column).size <= model.columns


def test_aggressive_profile_brakes_stops_and_turns_hard() -> None:
    def dynamics(profile: str) -> tuple[float, float, float]:
        sim = FieldSimulation(
            FieldConfig(
                seed=0, frames=200, profile=profile, moving_objects=False, network_labels=False
            )
        )
        t = np.arange(sim.sweep_starts[0], sim.sweep_starts[-1], 0.02)
        omega, _, velocity = true_motion(sim.drive, t)
        accel = np.gradient(velocity[:, 0], t)
        return (
            float(np.abs(accel).max()),
            float(velocity[:, 0].min()),
            float(np.degrees(np.abs(omega[:, 2]).max())),
        )

    accel, slowest, yaw_rate = dynamics('aggressive')
    assert accel > 5.0 and slowest < 0.05 and yaw_rate > 55.0
    accel, slowest, yaw_rate = dynamics('normal')
    assert accel < 4.0 and slowest > 3.0


def test_loop_route_returns_to_its_start_and_revisits_streets_both_ways() -> None:
    sim = FieldSimulation(
        FieldConfig(seed=0, frames=0, route='loop', moving_objects=False, network_labels=False)
    )
    poses = sim.poses
    assert len(sim) > 500
    xy = poses[:, :2, 3]
    heading = np.arctan2(poses[:, 1, 0], poses[:, 0, 0])
    assert np.linalg.norm(xy[-6]) < 2.0  # back at the start
    step = 5
    a, b = np.arange(0, len(xy), step), np.arange(0, len(xy), step)
    distance = np.linalg.norm(xy[a][:, None] - xy[b][None], axis=2)
    later = (b[None] - a[:, None]) > 150  # at least 15 s later
    turn = np.abs(np.angle(np.exp(1j * (heading[b][None] - heading[a][:, None]))))
    same = later & (distance < 1.0) & (turn < np.radians(20))
    opposite = later & (distance < 5.0) & (turn > np.radians(160))
    assert same.sum() > 10 and opposite.sum() > 30


def test_field_bag_round_trip(tmp_path: Path) -> None:
    out = tmp_path / 'field'
    config = FieldConfig(seed=1, frames=3, sensor='os128')
    report = write_field_bag(out, config, progress=False)
    assert report.frames == 3
    sim = FieldSimulation(config)
    reader = BagScanReader(out)
    for scan in reader.scans():
        frame = sim.frame(scan.index)
        np.testing.assert_allclose(scan.point_times, frame.scan.times, atol=1e-7)
        np.testing.assert_allclose(scan.pose, frame.pose, atol=1e-9)
        assert scan.stamp_ns == frame.stamp_ns
    reader.close()
    imu = read_imu(out)
    assert imu.frame_id == 'lidar'
    assert np.median(np.diff(imu.stamps_ns)) == 5_000_000  # 200 Hz
    assert imu.stamps_ns[0] < sim.stamp_ns(sim.sweep_starts[0])
    wheel = read_wheel_odometry(out)
    assert wheel.child_frame_id == 'lidar' and len(wheel) > 10
    np.testing.assert_allclose(wheel.linear_velocity[:, 0], sim.wheel.speed)
    reader = open_reader(out)
    fields = None
    for connection, _, raw in reader.messages():
        if connection.topic == '/points':
            msg = reader.deserialize(raw, connection.msgtype)
            fields = {f.name: (f.datatype, f.offset) for f in msg.fields}
            break
    reader.close()
    assert fields is not None and fields['time'][0] == 7 and fields['t'][0] == 6
    assert {'label', 'label_gt', 'ring', 'intensity'} <= set(fields)


@pytest.mark.parametrize('network', ['rangenet++', 'salsanext'])
def test_the_simulate_command_writes_a_field_bag_with_each_network(
    tmp_path: Path, network: str
) -> None:
    # the command passed its options on by position and once lost --network (TypeError)
    out = tmp_path / 'cli_field'
    argv = ['simulate', str(out), '--realism', 'field', '--frames', '2', '--sensor', 'vlp16']
    assert cli.main([*argv, '--network', network, '--quiet']) == 0
    reader = BagScanReader(out)
    assert [scan.index for scan in reader.scans()] == [0, 1]
    reader.close()
