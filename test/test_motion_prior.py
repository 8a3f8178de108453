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

"""The motion prior: IMU and wheel known answers, online biases, the constant-velocity fallback."""

from __future__ import annotations

import itertools
from typing import Any

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.motion_prior import (
    integrate_imu,
    interpolate_poses,
    prefix_rotations,
    SampleBuffer,
)
from mlsemreg_ros.core.odometry import (
    ConstantVelocityModel,
    MOTION_MODELS,
    Odometry,
    PriorMotionModel,
)
from mlsemreg_ros.core.odometry.prior_model import node_rotations
from mlsemreg_ros.core.rigid import invert_transform, rotation_angle_deg
from mlsemreg_ros.datasets.prior_topics import PriorTopics, sweep_end_ns
from mlsemreg_ros.simulation.inertial import ImuConfig, simulate_imu
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

SCAN_NS = 100_000_000  # 10 Hz
T0_NS = 1_700_000_000_000_000_000


class _Drive:
    """An analytic drive (the simulator's ``poses(times)`` interface): turning, pitching."""

    def poses(self, times: np.ndarray) -> np.ndarray:
        t = np.asarray(times, dtype=np.float64)
        yaw = 0.8 * t + 0.3 * np.sin(2.0 * t)
        pitch = 0.05 * np.sin(3.0 * t)
        roll = 0.03 * np.cos(1.7 * t)
        out = np.tile(np.eye(4), (t.size, 1, 1))
        out[:, :3, :3] = Rotation.from_euler('zyx', np.stack([yaw, pitch, roll], 1)).as_matrix()
        out[:, :3, 3] = np.stack([10.0 * t + np.sin(t), 2.0 * np.sin(t), 0.1 * np.sin(2 * t)], 1)
        return out


def _quiet_imu(**changes: float) -> ImuConfig:
    names = ('gyro_noise_density', 'gyro_bias_walk', 'accel_noise_density', 'accel_bias_walk')
    values = dict.fromkeys((*names, 'gyro_turn_on_bias', 'accel_turn_on_bias'), 0.0)
    values.update(changes)
    return ImuConfig(**values)


def _imu_model(config: ImuConfig, seconds: float = 6.0, seed: int = 0):
    """Return a prior model fed with a simulated IMU over ``seconds``, and the truth."""
    drive = _Drive()
    samples = simulate_imu(drive, 0.0, seconds, config, np.random.default_rng(seed))
    stamps = T0_NS + np.round(samples.times * 1e9).astype(np.int64)
    cfg = RegistrationConfig()
    cfg.motion_prior.source = 'imu'
    model = PriorMotionModel(cfg)
    model.add_imu(stamps, samples.angular_velocity, samples.linear_acceleration)
    scan_times = np.arange(0.2, seconds - 0.2, 0.1)
    truth = drive.poses(scan_times)
    truth = invert_transform(truth[0]) @ truth  # odom: the first scan
    return model, T0_NS + np.round(scan_times * 1e9).astype(np.int64), truth


def _errors(predicted: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    error = invert_transform(truth) @ predicted
    return float(np.linalg.norm(error[:3, 3])), rotation_angle_deg(error)


def test_the_prior_rotation_from_a_simulated_imu_matches_the_truth() -> None:
    model, stamps, truth = _imu_model(_quiet_imu())
    errors = []
    for k, (stamp, pose) in enumerate(zip(stamps, truth, strict=True)):
        if k >= 2:
            prediction = model.predict(int(stamp))
            errors.append(_errors(prediction.T_odom_current, pose))
        model.update(pose, int(stamp))
    translation, rotation = np.array(errors).T
    assert model.counts == {'imu': len(errors)}
    assert rotation.max() < 0.002  # deg per 0.1 s; constant velocity is off by up to 3 deg
    assert translation[3:].max() < 0.002  # m, once the gravity offset is learned
    # the offset is gravity in the odom frame (the first scan's sensor frame)
    first = _Drive().poses(np.array([0.2]))[0]
    gravity = first[:3, :3].T @ np.array([0.0, 0.0, -9.80665])
    np.testing.assert_allclose(model.bias.offset_odom, gravity, atol=0.02)


def test_the_gyro_rotations_within_a_sweep_match_the_truth() -> None:
    model, _, _ = _imu_model(_quiet_imu())
    stamp = T0_NS + 3 * SCAN_NS  # 0.3 s into the drive
    times, rotations = model.sweep_rotations(stamp, 0.0, 0.1)
    assert times[0] == 0.0 and abs(times[-1] - 0.1) < 1e-9 and len(times) >= 20  # 200 Hz
    poses = _Drive().poses(0.3 + times)
    truth = np.einsum('ji,njk->nik', poses[0, :3, :3], poses[:, :3, :3])  # R_stamp_node
    error = Rotation.from_matrix(np.einsum('nji,njk->nik', truth, rotations)).magnitude()
    assert np.degrees(error).max() < 1e-3  # deg, over a sweep turning about 5 deg
    assert model.sweep_rotations(stamp, 0.0, 60.0) is None  # beyond the IMU's samples
    wheels = PriorMotionModel(model_config('wheel'))
    assert wheels.sweep_rotations(stamp, 0.0, 0.1) is None  # no gyro


@pytest.mark.parametrize(
    'nodes',
    [
        [-2_000_000, 0, 5_000_000, 10_000_000, 12_500_000, 15_000_000, 20_000_000, 23_000_000],
        [3_000_000, 5_000_000, 7_000_000],  # the stamp between two samples
        [20_000_000, 24_000_000, 31_000_000],  # past the last sample: its rate is held
        [-9_000_000, -4_000_000, 0],  # before the first sample: its rate is held
    ],
)
def test_node_rotations_are_integrate_imu_interval_by_interval(
    nodes: list[int],
) -> None:
    rng = np.random.default_rng(4)
    stamps = np.arange(0, 5) * 5_000_000 + T0_NS  # 200 Hz
    gyro, accel = rng.normal(0.0, 0.8, (5, 3)), rng.normal(0.0, 9.0, (5, 3))
    bias = np.array([0.01, -0.02, 0.005])
    nodes_ns = np.asarray(nodes, dtype=np.int64) + T0_NS
    expected = [
        integrate_imu(stamps, gyro, accel, int(t0), int(t1), bias).rotation
        for t0, t1 in itertools.pairwise(nodes_ns)
    ]
    np.testing.assert_allclose(node_rotations(stamps, gyro, nodes_ns, bias), expected, atol=1e-12)
    one = node_rotations(stamps[:1], gyro[:1], nodes_ns, bias)  # a single sample: held
    single = [
        integrate_imu(stamps[:1], gyro[:1], accel[:1], int(t0), int(t1), bias).rotation
        for t0, t1 in itertools.pairwise(nodes_ns)
    ]
    np.testing.assert_allclose(one, single, atol=1e-12)


def test_integrated_rotation_of_a_constant_rate_is_its_exponential() -> None:
    rate = np.array([0.3, -0.2, 1.1])  # rad/s
    stamps = np.arange(0, 21) * 5_000_000  # 200 Hz over 0.1 s
    gyro = np.tile(rate, (stamps.size, 1))
    segment = integrate_imu(stamps, gyro, np.zeros_like(gyro), 1_000_000, 97_000_000, np.zeros(3))
    expected = Rotation.from_rotvec(rate * 0.096).as_matrix()
    np.testing.assert_allclose(segment.rotation, expected, atol=1e-12)
    biased = integrate_imu(
        stamps, gyro + 0.01, np.zeros_like(gyro), 0, 100_000_000, np.full(3, 0.01)
    )
    np.testing.assert_allclose(biased.rotation, Rotation.from_rotvec(rate * 0.1).as_matrix())


def test_prefix_rotations_compose_in_order() -> None:
    increments = Rotation.from_rotvec(np.random.default_rng(1).normal(0, 0.3, (37, 3)))
    running = prefix_rotations(increments)
    expected = Rotation.identity()
    for k in range(37):
        expected = expected * increments[k]
        np.testing.assert_allclose(running[k].as_matrix(), expected.as_matrix(), atol=1e-12)


def test_the_gyro_bias_estimate_converges_on_a_known_bias() -> None:
    bias = np.array([0.004, -0.006, 0.003])  # rad/s, the simulator's turn-on size
    model, stamps, truth = _imu_model(_quiet_imu(), seconds=8.0)
    model = PriorMotionModel(model_config('imu'))
    drive = _Drive()
    samples = simulate_imu(drive, 0.0, 8.0, _quiet_imu(), np.random.default_rng(0))
    imu_stamps = T0_NS + np.round(samples.times * 1e9).astype(np.int64)
    model.add_imu(imu_stamps, samples.angular_velocity + bias, samples.linear_acceleration)
    for stamp, pose in zip(stamps, truth, strict=True):
        model.update(pose, int(stamp))
    np.testing.assert_allclose(model.bias.gyro_bias, bias, atol=2e-4)
    assert model.bias.gyro_updates == len(stamps) - 1


def test_the_gyro_bias_estimate_converges_with_noise_and_bias_walk() -> None:
    config = ImuConfig()  # the simulator's defaults: EuRoC ADIS16448 noise, random turn-on bias
    drive = _Drive()
    samples = simulate_imu(drive, 0.0, 12.0, config, np.random.default_rng(3))
    model = PriorMotionModel(model_config('imu'))
    stamps = T0_NS + np.round(samples.times * 1e9).astype(np.int64)
    model.add_imu(stamps, samples.angular_velocity, samples.linear_acceleration)
    scan_times = np.arange(0.2, 11.8, 0.1)
    truth = drive.poses(scan_times)
    for t, pose in zip(scan_times, truth, strict=True):
        model.update(pose, T0_NS + round(t * 1e9))
    true_bias = samples.gyro_bias[-1]
    assert np.linalg.norm(true_bias) > 0.003  # the test means something
    assert np.linalg.norm(model.bias.gyro_bias - true_bias) < 0.15 * np.linalg.norm(true_bias)


def model_config(source: str) -> RegistrationConfig:
    """Return a default configuration with ``motion_prior.source``."""
    cfg = RegistrationConfig()
    cfg.motion_prior.source = source
    return cfg


def _planar(x: float, y: float, yaw: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler('z', yaw).as_matrix()
    T[:2, 3] = [x, y]
    return T


def _circle(times: np.ndarray, speed: float = 8.0, rate: float = 0.4) -> np.ndarray:
    """Poses of a base driving a circle: speed m/s, yaw rate rad/s."""
    radius = speed / rate
    yaw = rate * times
    return np.array(
        [_planar(radius * np.sin(a), radius * (1 - np.cos(a)), a) for a in yaw]
    ).reshape(-1, 4, 4)


def test_the_wheel_prior_is_the_interpolated_relative_pose_in_the_sensor_frame() -> None:
    T_base_sensor = _planar(1.2, 0.3, 0.1)
    T_base_sensor[2, 3] = 1.7
    wheel_times = np.arange(0.0, 3.0, 0.02)  # 50 Hz
    base = _circle(wheel_times)
    model = PriorMotionModel(model_config('wheel'))
    model.cfg.wheel_scale_gain = 0.0
    model.add_wheel(T0_NS + np.round(wheel_times * 1e9).astype(np.int64), base, T_base_sensor)
    scan_times = np.array([0.51, 0.613, 0.7157])  # between wheel messages
    sensor = _circle(scan_times) @ T_base_sensor
    sensor = invert_transform(sensor[0]) @ sensor
    stamps = T0_NS + np.round(scan_times * 1e9).astype(np.int64)
    model.update(sensor[0], int(stamps[0]))
    prediction = model.predict(int(stamps[1]))  # one pose is enough for the wheels
    assert model.last_source == 'wheel'
    translation, rotation = _errors(prediction.T_odom_current, sensor[1])
    assert translation < 2e-4 and rotation < 1e-3  # interpolation between 20 ms messages
    model.update(sensor[1], int(stamps[1]))
    prior = model.relative_prior(int(stamps[2]))
    assert prior.source == 'wheel' and prior.span_s == pytest.approx(0.1027)
    assert np.all(np.diag(prior.covariance) > 0)
    translation, rotation = _errors(sensor[1] @ prior.T, sensor[2])
    assert translation < 2e-4 and rotation < 1e-3


def test_a_wheel_stream_with_a_hole_is_not_interpolated_across_it() -> None:
    """
    Issue 34's unreproduced wrong pose: the last stream's messages still buffered.

    The fuzz's previous case ended 20 m away and 14 deg turned; this case's wheel messages
    until 0.8 s after the keyframe were lost. Interpolating across the 3.8 s hole put the
    keyframe's wheel pose 4.5 m and 3 deg off the truth (a prior the guard refused, while the
    registration it seeded was kept); now such a stream does not cover the interval.
    """
    previous_end = _planar(-20.5, 2.4, np.radians(14.0))
    old = np.arange(-5.05, -2.95, 0.02)  # the previous case, standing still at its end
    new = np.arange(0.8, 2.05, 0.02)  # this case: standing at the origin until 1 s
    truth = _planar(-20.6, 2.6, np.radians(12.0))
    moving = np.clip(new - 1.0, 0.0, 1.0)  # then driven to the truth at 2 s
    poses = [previous_end] * len(old) + [
        _planar(-20.6 * s, 2.6 * s, np.radians(12 * s)) for s in moving
    ]
    times = np.concatenate([old, new])
    model = PriorMotionModel(model_config('wheel'))
    model.add_wheel(T0_NS + np.round(times * 1e9).astype(np.int64), np.array(poses))
    model.update(np.eye(4), T0_NS)  # the keyframe
    assert model.relative_prior(T0_NS + 2 * 10**9) is None  # the hole: no prior
    model.cfg.max_sample_gap = 0.0  # as before: interpolated across 3.8 s
    prior = model.relative_prior(T0_NS + 2 * 10**9)
    assert _errors(prior.T, truth)[0] > 2.0
    model.cfg.max_sample_gap = 5.0  # a hole shorter than the bound is interpolated
    assert model.relative_prior(T0_NS + 2 * 10**9) is not None


def test_the_sample_buffer_covers_only_without_a_longer_hole() -> None:
    buffer = SampleBuffer((1,))
    stamps = np.array([0, 10, 20, 60, 70, 80])
    buffer.add(stamps, np.zeros((6, 1)))
    assert buffer.covers(5, 75, 0) and buffer.covers(5, 75, 0, max_gap_ns=40)
    assert not buffer.covers(5, 75, 0, max_gap_ns=39)  # 20 -> 60 lies inside
    assert buffer.covers(62, 75, 0, max_gap_ns=10)  # the hole is before the interval
    assert buffer.covers(0, 15, 0, max_gap_ns=10)
    assert not buffer.covers(15, 62, 0, max_gap_ns=30)  # bracketed by 10 and 70


def test_the_wheel_scale_error_is_learned_from_the_accepted_poses() -> None:
    wheel_times = np.arange(0.0, 8.0, 0.02)
    true = _circle(wheel_times, speed=10.0, rate=0.1)
    reported = true.copy()
    reported[:, :3, 3] *= 1.02  # a wheel radius 2 % too large
    model = PriorMotionModel(model_config('wheel'))
    model.add_wheel(T0_NS + np.round(wheel_times * 1e9).astype(np.int64), reported)
    scan_times = np.arange(0.1, 7.9, 0.1)
    poses = _circle(scan_times, speed=10.0, rate=0.1)
    errors = []
    for t, pose in zip(scan_times, poses, strict=True):
        stamp = T0_NS + round(t * 1e9)
        prediction = model.predict(stamp)
        if prediction is not None:
            errors.append(_errors(prediction.T_odom_current, pose)[0])
        model.update(pose, stamp)
    assert model.wheel_scale == pytest.approx(1.02, abs=1e-3)
    assert errors[0] > 0.015  # 2 % of 1 m
    assert max(errors[-20:]) < 0.002


def test_without_messages_the_prior_is_exactly_constant_velocity() -> None:
    rng = np.random.default_rng(4)
    model, reference = PriorMotionModel(model_config('auto')), ConstantVelocityModel()
    stamp = T0_NS
    for k in range(12):
        stamp += SCAN_NS * (1 + (k % 4 == 3))  # some dropped frames
        a, b = model.predict(stamp), reference.predict(stamp)
        assert (a is None) == (b is None)
        if a is not None:
            assert np.array_equal(a.T_odom_current, b.T_odom_current)
            assert a.stamp_gap == b.stamp_gap
        pose = _planar(k + rng.normal(0, 0.1), rng.normal(0, 0.1), rng.normal(0, 0.05))
        model.update(pose, stamp)
        reference.update(pose, stamp)
    assert model.last_source == 'constant_velocity'


def test_the_odometry_builds_the_prior_model_unless_the_source_is_none() -> None:
    assert MOTION_MODELS['prior'] is PriorMotionModel
    assert isinstance(Odometry(config=RegistrationConfig()).motion_model, PriorMotionModel)
    assert isinstance(Odometry(config=model_config('none')).motion_model, ConstantVelocityModel)


def test_an_imu_that_spans_a_gap_reports_one_frame_interval() -> None:
    model, stamps, truth = _imu_model(_quiet_imu())
    for k in range(5):
        model.update(truth[k], int(stamps[k]))
    prediction = model.predict(int(stamps[8]))  # three scans lost
    assert prediction.stamp_gap == 1.0
    assert _errors(prediction.T_odom_current, truth[8])[0] < 0.01
    cv = ConstantVelocityModel()
    for k in range(5):
        cv.update(truth[k], int(stamps[k]))
    assert cv.predict(int(stamps[8])).stamp_gap == pytest.approx(4.0)
    model.cfg.max_span = 0.2  # beyond the span: constant velocity
    assert model.predict(int(stamps[8])).stamp_gap == pytest.approx(4.0)
    assert model.last_source == 'constant_velocity'


def test_an_imu_that_stops_short_of_the_stamp_does_not_predict() -> None:
    model, stamps, truth = _imu_model(_quiet_imu(), seconds=1.0)
    for k in range(3):
        model.update(truth[k], int(stamps[k]))
    assert model.relative_prior(int(stamps[3])) is not None
    assert model.relative_prior(int(stamps[2]) + 2 * 10**9) is None  # 2 s after the last sample


def test_the_sample_buffer_sorts_drops_and_rejects() -> None:
    buffer = SampleBuffer((2,))
    buffer.add(np.array([30, 10]), np.array([[3.0, 3.0], [1.0, 1.0]]))
    buffer.add(np.array([20, 30]), np.array([[2.0, 2.0], [4.0, 4.0]]))
    np.testing.assert_array_equal(buffer.stamps, [10, 20, 30])
    np.testing.assert_array_equal(buffer.values[:, 0], [1.0, 2.0, 4.0])
    buffer.drop_before(25)
    np.testing.assert_array_equal(buffer.stamps, [20, 30])  # keeps the one before
    with pytest.raises(ValueError, match='finite'):
        buffer.add(np.array([40]), np.array([[np.nan, 0.0]]))


def test_interpolated_poses_are_exact_on_a_constant_twist() -> None:
    times = np.array([0.0, 0.02, 0.04])
    poses = _circle(times)
    np.testing.assert_allclose(
        interpolate_poses(np.array([0, 20, 40]), poses, np.array([10, 30, 50])),
        _circle(np.array([0.01, 0.03, 0.05])),
        atol=1e-6,
    )


class _Recorder:
    def __init__(self) -> None:
        self.imu: list[np.ndarray] = []
        self.wheel: list[np.ndarray] = []

    def add_imu(self, stamps: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> None:
        self.imu.append(stamps)

    def add_wheel(self, stamps: np.ndarray, poses: np.ndarray) -> None:
        self.wheel.append(stamps)


def test_prior_topics_are_fed_once_up_to_the_sweep_end() -> None:
    from mlsemreg_ros.datasets.bag import ImuArrays, WheelOdometryArrays

    stamps = np.arange(0, 50, 5, dtype=np.int64)
    imu = ImuArrays(stamps, np.zeros((10, 3)), np.zeros((10, 3)), 'velodyne')
    wheel = WheelOdometryArrays(
        stamps[::2], np.tile(np.eye(4), (5, 1, 1)), np.zeros((5, 3)), np.zeros((5, 3)), 'o', 'v'
    )
    topics, recorder = PriorTopics(imu, wheel), _Recorder()
    assert sweep_end_ns(10, np.array([0.0, 1.2e-8])) == 22
    assert sweep_end_ns(10, None) == 10
    topics.feed_until(recorder, 22)
    topics.feed_until(recorder, 22)
    topics.feed_until(recorder, 100)
    np.testing.assert_array_equal(np.concatenate(recorder.imu), stamps)
    assert [len(s) for s in recorder.imu] == [5, 5]
    np.testing.assert_array_equal(np.concatenate(recorder.wheel), stamps[::2])


@pytest.fixture(scope='module')
def field_bag(tmp_path_factory: pytest.TempPathFactory) -> Any:
    from mlsemreg_ros.simulation.field import FieldConfig
    from mlsemreg_ros.simulation.field_export import write_field_bag

    out = tmp_path_factory.mktemp('prior') / 'field'
    write_field_bag(out, FieldConfig(seed=2, frames=5, sensor='vlp16'), progress=False)
    return out


@pytest.mark.slow  # a field bag and two eval-bag runs: about 20 s, 60 s under load
def test_eval_bag_replays_the_prior_topics(field_bag: Any) -> None:
    import json

    from mlsemreg_ros.tools import eval_bag

    out = field_bag.parent / 'imu'
    args = [
        str(field_bag),
        '-o',
        str(out),
        '--quiet',
        '--no-plots',
        '--set',
        'keypoints.count=1500',
    ]
    assert (
        eval_bag.main([*args, '--imu-topic', '/imu/data', '--wheel-topic', '/wheel/odometry']) == 0
    )
    details = json.loads((out / 'details.json').read_text())
    # auto: the wheels predict scan 1 (one pose is enough), the IMU scans 2..4 (two needed)
    assert details['prediction_sources'] == {'wheel': 1, 'imu': 3}
    assert eval_bag.main([*args, '--imu-topic', '/no/such/topic']) == 2


def test_a_motion_prior_change_reaches_the_model() -> None:
    odometry = Odometry(config=RegistrationConfig())
    model = odometry.motion_model
    odometry.reconfigure(RegistrationConfig().replace({'motion_prior.max_span': 1.0}))
    assert odometry.motion_model is model and model.cfg.max_span == 1.0
    odometry.reconfigure(RegistrationConfig().replace({'motion_prior.source': 'none'}))
    assert isinstance(odometry.motion_model, ConstantVelocityModel)
