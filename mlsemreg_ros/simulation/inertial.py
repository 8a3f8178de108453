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
IMU and wheel odometry of a field-mode drive, derived from its continuous pose.

The IMU frame is the sensor (LiDAR) frame: identity extrinsic, x forward, y left,
z up. True rates come from central differences of :meth:`ContinuousDrive.poses`
(1 ms): the body angular velocity ``log(R(t-h)^T R(t+h)) / 2h`` and the specific
force ``R^T (a + g e_z)`` (gravity 9.80665 m/s^2 along the world -z, so a car at
rest measures +9.81 on its z axis). Measurements add white noise and a bias that
starts at a random turn-on value and random-walks; the noise densities default to
the ADIS16448 figures of the EuRoC MAV dataset (Burri et al., IJRR 2016).

Wheel odometry reports the forward speed times ``1 + scale_error`` (a wrong wheel
radius) and the yaw rate (a yaw-rate gyro on the axle) with noise, and the planar
pose dead-reckoned from them, in frame ``odom`` with the sensor frame as child.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.simulation.motion import ContinuousDrive
import numpy as np
from scipy.spatial.transform import Rotation

GRAVITY = 9.80665


@dataclass
class ImuConfig:
    """IMU rate, white-noise densities, bias random walks and turn-on biases (SI units)."""

    rate_hz: float = 200.0
    gyro_noise_density: float = 1.7e-4  # rad/s/sqrt(Hz)
    gyro_bias_walk: float = 1.9e-5  # rad/s^2/sqrt(Hz)
    accel_noise_density: float = 2.0e-3  # m/s^2/sqrt(Hz)
    accel_bias_walk: float = 3.0e-3  # m/s^3/sqrt(Hz)
    gyro_turn_on_bias: float = 0.005  # rad/s sigma per axis (0.3 deg/s)
    accel_turn_on_bias: float = 0.05  # m/s^2 sigma per axis


@dataclass
class WheelConfig:
    """Wheel odometry rate, speed scale error and noise (SI units)."""

    rate_hz: float = 50.0
    scale_error: float = 0.02  # reported speed = (1 + scale_error) * true speed
    speed_noise: float = 0.02  # m/s sigma
    yaw_rate_noise: float = 0.003  # rad/s sigma
    yaw_rate_bias: float = 0.002  # rad/s, constant


@dataclass
class ImuSamples:
    """IMU measurements and the truth they came from, at drive times ``times``."""

    times: np.ndarray  # (n,) seconds (drive time)
    angular_velocity: np.ndarray  # (n, 3) rad/s, measured
    linear_acceleration: np.ndarray  # (n, 3) m/s^2, measured specific force
    true_angular_velocity: np.ndarray  # (n, 3)
    true_specific_force: np.ndarray  # (n, 3)
    gyro_bias: np.ndarray  # (n, 3)
    accel_bias: np.ndarray  # (n, 3)


@dataclass
class WheelSamples:
    """Wheel odometry at drive times ``times``."""

    times: np.ndarray  # (n,) seconds
    speed: np.ndarray  # (n,) m/s forward, measured (scale error included)
    yaw_rate: np.ndarray  # (n,) rad/s, measured
    true_speed: np.ndarray  # (n,)
    poses: np.ndarray  # (n, 4, 4) planar dead-reckoned T_odom_sensor (odom = first sample)


def true_motion(
    drive: ContinuousDrive, times: np.ndarray, h: float = 1e-3
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Body angular velocity (n, 3), specific force (n, 3) and body velocity (n, 3) at ``times``.

    Central differences of the pose over ``2 h`` seconds, in the sensor frame.
    """
    times = np.asarray(times, dtype=np.float64)
    before, now, after = drive.poses(times - h), drive.poses(times), drive.poses(times + h)
    relative = np.einsum('nji,njk->nik', before[:, :3, :3], after[:, :3, :3])
    omega = Rotation.from_matrix(relative).as_rotvec() / (2.0 * h)
    accel = (after[:, :3, 3] - 2.0 * now[:, :3, 3] + before[:, :3, 3]) / h**2
    accel[:, 2] += GRAVITY
    rotation_t = np.transpose(now[:, :3, :3], (0, 2, 1))
    force = np.einsum('nij,nj->ni', rotation_t, accel)
    velocity = np.einsum('nij,nj->ni', rotation_t, (after[:, :3, 3] - before[:, :3, 3]) / (2 * h))
    return omega, force, velocity


def _random_walk(
    rng: np.random.Generator, n: int, turn_on: float, walk: float, dt: float
) -> np.ndarray:
    start = rng.normal(0.0, turn_on, 3)
    steps = rng.normal(0.0, walk * np.sqrt(dt), (n, 3))
    steps[0] = 0.0
    return start + np.cumsum(steps, axis=0)


def _sample_times(t0: float, t1: float, rate_hz: float) -> tuple[np.ndarray, float]:
    """Return the times (n,) every ``1 / rate_hz`` s from ``t0`` up to ``t1``, and that period."""
    dt = 1.0 / rate_hz
    return t0 + dt * np.arange(int(np.floor((t1 - t0) / dt)) + 1), dt


def simulate_imu(
    drive: ContinuousDrive, t0: float, t1: float, config: ImuConfig, rng: np.random.Generator
) -> ImuSamples:
    """IMU samples at ``config.rate_hz`` over drive times [t0, t1]."""
    times, dt = _sample_times(t0, t1, config.rate_hz)
    omega, force, _ = true_motion(drive, times)
    n = times.size
    gyro_bias = _random_walk(rng, n, config.gyro_turn_on_bias, config.gyro_bias_walk, dt)
    accel_bias = _random_walk(rng, n, config.accel_turn_on_bias, config.accel_bias_walk, dt)
    root_rate = np.sqrt(config.rate_hz)
    gyro = omega + gyro_bias + rng.normal(0.0, config.gyro_noise_density * root_rate, (n, 3))
    accel = force + accel_bias + rng.normal(0.0, config.accel_noise_density * root_rate, (n, 3))
    return ImuSamples(times, gyro, accel, omega, force, gyro_bias, accel_bias)


def simulate_wheel(
    drive: ContinuousDrive, t0: float, t1: float, config: WheelConfig, rng: np.random.Generator
) -> WheelSamples:
    """Wheel odometry at ``config.rate_hz`` over drive times [t0, t1]."""
    times, dt = _sample_times(t0, t1, config.rate_hz)
    omega, _, velocity = true_motion(drive, times)
    n = times.size
    true_speed = velocity[:, 0]
    speed = (1.0 + config.scale_error) * true_speed + rng.normal(0.0, config.speed_noise, n)
    speed = np.where(np.abs(true_speed) < 1e-3, 0.0, speed)  # wheels at rest read zero
    yaw_rate = omega[:, 2] + config.yaw_rate_bias + rng.normal(0.0, config.yaw_rate_noise, n)
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (yaw_rate[1:] + yaw_rate[:-1]) * dt)])
    mean_speed = 0.5 * (speed[1:] + speed[:-1])
    mid_yaw = 0.5 * (yaw[1:] + yaw[:-1])
    xy = np.zeros((n, 2))
    xy[1:, 0] = np.cumsum(mean_speed * np.cos(mid_yaw) * dt)
    xy[1:, 1] = np.cumsum(mean_speed * np.sin(mid_yaw) * dt)
    poses = np.tile(np.eye(4), (n, 1, 1))
    c, s = np.cos(yaw), np.sin(yaw)
    poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = c, -s, s, c
    poses[:, :2, 3] = xy
    return WheelSamples(times, speed, yaw_rate, true_speed, poses)
