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
An external motion prior: the relative motion of the sensor between two stamps, with covariance.

Two sources (``docs/field_prior.md``):

- **IMU** (gyro and accelerometer in the sensor frame). The rotation is the product of the
  gyro increments ``exp((w - b_g) dt)`` (bias ``b_g`` removed); the translation integrates
  the specific force rotated into the frame of the start stamp plus an acceleration offset
  ``c`` (gravity, and the accelerometer bias, in the odom frame), starting from the velocity
  at the start stamp, which comes from the last two accepted poses.
  Both ``b_g`` and ``c`` are estimated online from the accepted poses
  (:class:`ImuBiasEstimator`).
- **Wheel odometry** (poses of a planar dead-reckoning, ``T_odom_child``): the relative pose
  between the two stamps, interpolated between messages, with the child frame moved to
  the sensor frame by ``T_child_sensor``; its speed scale is estimated online.

This module is ROS-free and does not import the odometry: the motion model that uses it is
``core/odometry/prior_model.py``. Its configuration is :class:`MotionPriorConfig`
(section ``motion_prior``).
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core.rigid import invert_transform
from mlsemreg_ros.core.settings import param
import numpy as np
from scipy.spatial.transform import Rotation

#: A bias residual larger than this (rad/s) is an outlier (a wrong pose), not the bias.
MAX_GYRO_RESIDUAL = 0.05
#: An acceleration residual larger than this (m/s^2) is an outlier, not the offset (once the
#: running-mean start is over: the first estimate, from the accelerometer alone, is off by
#: the vehicle's acceleration at that time).
MAX_ACCEL_RESIDUAL = 5.0
#: Window (s) around a stamp whose accelerometer mean initialises the gravity offset.
GRAVITY_WINDOW_S = 0.1
#: Minimum distance (m) of an interval for a wheel speed-scale update.
MIN_SCALE_DISTANCE = 0.2


@dataclass
class MotionPriorConfig:
    """The external motion prior (IMU or wheel odometry) of the odometry's prediction."""

    source: str = param(
        'auto',
        'Which prior predicts the next scan: imu, wheel, auto (the IMU when its messages '
        'cover the interval, else the wheel odometry, else constant velocity) or none '
        '(constant velocity only). Without prior messages every choice is the '
        'constant-velocity prediction.',
        choices=('none', 'imu', 'wheel', 'auto'),
    )
    gyro_bias_gain: float = param(
        0.1,
        'Low-pass gain of the online gyro bias estimate (the residual between the '
        'integrated and the accepted rotation, per accepted scan; 0: no estimate).',
        low=0.0,
        high=1.0,
    )
    accel_gain: float = param(
        0.1,
        'Low-pass gain of the online acceleration offset (gravity and accelerometer bias '
        'in the odom frame, from the residual between the integrated and the accepted '
        'translation; 0: keep the initial gravity estimate).',
        low=0.0,
        high=1.0,
    )
    wheel_scale_gain: float = param(
        0.05,
        'Low-pass gain of the online wheel speed-scale estimate (distance by the wheels '
        'over distance by the accepted poses; 0: trust the wheels).',
        low=0.0,
        high=1.0,
    )
    gyro_noise: float = param(
        1.7e-4,
        'Gyro white-noise density (the prior covariance).',
        unit='rad/s/sqrt(Hz)',
        low=0.0,
        high=1.0,
    )
    gyro_bias_sigma: float = param(
        1e-3,
        'Uncertainty of the gyro bias estimate (the prior covariance).',
        unit='rad/s',
        low=0.0,
        high=1.0,
    )
    accel_noise: float = param(
        2e-3,
        'Accelerometer white-noise density (the prior covariance).',
        unit='m/s^2/sqrt(Hz)',
        low=0.0,
        high=10.0,
    )
    accel_sigma: float = param(
        0.1,
        'Uncertainty of the acceleration offset (gravity direction, accelerometer bias; '
        'the prior covariance).',
        unit='m/s^2',
        low=0.0,
        high=100.0,
    )
    velocity_sigma: float = param(
        0.05,
        'Uncertainty of the velocity taken from the last accepted poses (the IMU prior '
        'covariance).',
        unit='m/s',
        low=0.0,
        high=100.0,
    )
    wheel_distance_noise: float = param(
        0.02,
        'Wheel odometry translation error per metre driven (the prior covariance).',
        low=0.0,
        high=1.0,
    )
    wheel_rotation_noise: float = param(
        0.003,
        'Wheel odometry rotation noise (the prior covariance).',
        unit='rad/sqrt(s)',
        low=0.0,
        high=1.0,
    )
    max_span: float = param(
        5.0,
        'The longest interval a prior bridges (dropped frames, strides); beyond it the '
        'constant-velocity rule applies.',
        unit='s',
        low=0.0,
        high=3600.0,
    )
    max_extrapolation: float = param(
        0.05,
        'How far past its last (or before its first) message a prior may hold the '
        'measured rate; a longer shortfall means the prior does not cover the interval.',
        unit='s',
        low=0.0,
        high=10.0,
    )
    trusted_translation_sigma: float = param(
        0.2,
        'A prior whose translation standard deviation over the interval is at most this '
        '(and rotation within motion_prior.trusted_rotation_sigma) bridges a gap in the '
        'stamps: tracking may accept the scan as after one frame interval.',
        unit='m',
        low=0.0,
        high=100.0,
    )
    trusted_rotation_sigma: float = param(
        1.0,
        '... and rotation standard deviation at most this.',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    max_disagreement: float = param(
        3.0,
        'A scan registered with the prior is registered again without it when it was '
        'rejected, or when the prior rotation over the interval (or, by twice this, the gyro '
        'rotation within the sweep) is further than this from the registration; the registration '
        'aligned with more inliers is kept (core/odometry/prior_guard.py).',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    gyro_rescue: float = param(
        1.0,
        'A scan rejected with no prediction (the second after a start: the IMU prior has no '
        'velocity yet) is accepted from its refused global pose when the map trusts that '
        "pose's refinement and the refinement is within this of the gyro rotation over the "
        'interval (the refused pose itself within 4 times this; core/odometry/gyro_rescue.py; '
        '0: off).',
        unit='deg',
        low=0.0,
        high=30.0,
    )
    max_sample_gap: float = param(
        0.5,
        'A prior whose messages leave a hole longer than this within the interval (lost '
        'messages, a stream that stopped and went on) does not cover it: nothing is '
        'interpolated across the hole (0: no such check).',
        unit='s',
        low=0.0,
        high=3600.0,
    )
    buffer: float = param(
        30.0,
        'Prior messages older than this before the last accepted scan are dropped.',
        unit='s',
        low=1.0,
        high=3600.0,
    )


@dataclass(frozen=True)
class RelativePrior:
    """The sensor's motion from stamp ``t0`` to stamp ``t1``, with covariance."""

    T: np.ndarray  # (4, 4) T_sensor(t0)_sensor(t1)
    covariance: np.ndarray  # (6, 6) ROS order [x, y, z, roll, pitch, yaw], frame at t0
    source: str  # 'imu' or 'wheel'
    span_s: float  # t1 - t0

    def sigmas(self) -> tuple[float, float]:
        """Return the largest translation (m) and rotation (deg) standard deviation."""
        diagonal = np.sqrt(np.maximum(np.diag(self.covariance), 0.0))
        return float(diagonal[:3].max()), float(np.degrees(diagonal[3:].max()))


class SampleBuffer:
    """Time-sorted samples (stamps in ns, one row of values each); old ones can be dropped."""

    def __init__(self, width: tuple[int, ...]) -> None:
        """Hold rows of shape ``width``."""
        self.width = width
        self.stamps = np.zeros(0, dtype=np.int64)
        self.values = np.zeros((0, *width))

    def __len__(self) -> int:
        """Return the number of samples held."""
        return int(self.stamps.size)

    def add(self, stamps_ns: np.ndarray, values: np.ndarray) -> None:
        """Append samples (any order; equal stamps keep the last one)."""
        stamps = np.atleast_1d(np.asarray(stamps_ns, dtype=np.int64))
        values = np.asarray(values, dtype=np.float64).reshape(stamps.size, *self.width)
        if not np.all(np.isfinite(values)):
            raise ValueError('prior samples must be finite')
        stamps = np.concatenate([self.stamps, stamps])
        values = np.concatenate([self.values, values])
        if stamps.size > 1 and np.any(np.diff(stamps) <= 0):
            order = np.argsort(stamps, kind='stable')
            stamps, values = stamps[order], values[order]
            keep = np.append(stamps[1:] != stamps[:-1], True)
            stamps, values = stamps[keep], values[keep]
        self.stamps, self.values = stamps, values

    def drop_before(self, stamp_ns: int) -> None:
        """Drop samples before ``stamp_ns``, keeping the last one before it."""
        first = max(int(np.searchsorted(self.stamps, stamp_ns, side='right')) - 1, 0)
        if first:
            self.stamps, self.values = self.stamps[first:], self.values[first:]

    def covers(self, t0_ns: int, t1_ns: int, slack_ns: int, max_gap_ns: int = 0) -> bool:
        """
        Tell whether the samples reach ``[t0, t1]`` within ``slack_ns`` at both ends.

        With ``max_gap_ns`` > 0 they must also have no hole longer than that over the
        interval (between the samples that bracket it): lost messages, or a stream that
        stopped and went on, are not interpolated across.
        """
        stamps = self.stamps
        if not (
            stamps.size >= 2 and stamps[0] <= t0_ns + slack_ns and stamps[-1] >= t1_ns - slack_ns
        ):
            return False
        if max_gap_ns <= 0:
            return True
        first = max(int(np.searchsorted(stamps, t0_ns, side='right')) - 1, 0)
        end = min(int(np.searchsorted(stamps, t1_ns, side='left')), stamps.size - 1) + 1
        return end - first < 2 or int(np.diff(stamps[first:end]).max()) <= max_gap_ns

    def clear(self) -> None:
        """Drop every sample."""
        self.stamps = np.zeros(0, dtype=np.int64)
        self.values = np.zeros((0, *self.width))


def quaternion_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return the Hamilton products ``a b`` of quaternions (n, 4), scalar last (scipy's order)."""
    ax, ay, az, aw = a.T
    bx, by, bz, bw = b.T
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=1,
    )


def prefix_rotations(increments: Rotation) -> Rotation:
    """
    Return the running products ``r_0 r_1 ... r_i`` of ``increments`` (vectorised).

    A Hillis-Steele scan: log2(n) products of whole quaternion arrays instead of n single
    compositions.
    """
    quats = increments.as_quat()
    offset = 1
    while offset < len(quats):
        combined = quaternion_product(quats[:-offset], quats[offset:])
        quats = np.concatenate([quats[:offset], combined])
        offset *= 2
    return Rotation.from_quat(quats)


@dataclass(frozen=True)
class ImuSegment:
    """The IMU integrated from ``t0`` over ``duration``: piecewise constant sub-intervals."""

    duration: float  # s
    rotation: np.ndarray  # (3, 3) R_t0_t1 (gyro, bias removed)
    dt: np.ndarray  # (m,) sub-interval lengths, s
    tau: np.ndarray  # (m,) sub-interval midpoints, s after t0
    R_mid: np.ndarray  # (m, 3, 3) R_t0_tau at the midpoints
    force: np.ndarray  # (m, 3) specific force at the midpoints (sensor frame, m/s^2)

    def accelerations(self, offset_t0: np.ndarray) -> np.ndarray:
        """Return the (m, 3) accelerations in the frame at ``t0``: rotated force plus ``c``."""
        return np.einsum('nij,nj->ni', self.R_mid, self.force) + offset_t0

    def displacement(self, velocity_t0: np.ndarray, offset_t0: np.ndarray) -> np.ndarray:
        """Return the translation over the segment: ``v T + sum a dt (T - tau)`` (frame t0)."""
        a = self.accelerations(offset_t0)
        return velocity_t0 * self.duration + (self.dt * (self.duration - self.tau)) @ a

    def first_moment(self, offset_t0: np.ndarray) -> np.ndarray:
        """Return ``int (tau - t0) a dtau`` over the segment (frame t0): a velocity term."""
        return (self.dt * self.tau) @ self.accelerations(offset_t0)


def integrate_imu(
    stamps_ns: np.ndarray,
    gyro: np.ndarray,
    accel: np.ndarray,
    t0_ns: int,
    t1_ns: int,
    gyro_bias: np.ndarray,
) -> ImuSegment:
    """
    Integrate IMU samples from ``t0`` to ``t1`` (``t1 >= t0``).

    The sub-intervals are cut at every sample stamp inside ``(t0, t1)``; on each the rate
    and the specific force are linearly interpolated at its midpoint (held constant past
    the first or last sample). Rotation increments ``exp((w - b_g) dt)`` are composed by
    :func:`prefix_rotations`.
    """
    inside = stamps_ns[(stamps_ns > t0_ns) & (stamps_ns < t1_ns)]
    edges = np.concatenate([[t0_ns], inside, [t1_ns]]).astype(np.int64)
    edges_s = (edges - t0_ns) * 1e-9
    dt = np.diff(edges_s)
    tau = 0.5 * (edges_s[1:] + edges_s[:-1])
    sample_s = (np.asarray(stamps_ns, dtype=np.int64) - t0_ns) * 1e-9
    w = np.stack([np.interp(tau, sample_s, gyro[:, k]) for k in range(3)], axis=1) - gyro_bias
    f = np.stack([np.interp(tau, sample_s, accel[:, k]) for k in range(3)], axis=1)
    if dt.size == 0 or edges_s[-1] <= 0.0:
        eye = np.eye(3)
        return ImuSegment(
            0.0, eye, np.zeros(0), np.zeros(0), np.zeros((0, 3, 3)), np.zeros((0, 3))
        )
    increments = Rotation.from_rotvec(w * dt[:, None])
    at_edges = prefix_rotations(increments)  # R_t0_edge[i + 1]
    starts = Rotation.concatenate([Rotation.identity(), at_edges[:-1]])
    mid = starts * Rotation.from_rotvec(w * (0.5 * dt)[:, None])
    return ImuSegment(float(edges_s[-1]), at_edges[-1].as_matrix(), dt, tau, mid.as_matrix(), f)


def imu_covariance(cfg: MotionPriorConfig, span: float) -> np.ndarray:
    """Return the (6, 6) covariance of an IMU prior over ``span`` seconds (diagonal)."""
    rotation = cfg.gyro_noise**2 * span + (cfg.gyro_bias_sigma * span) ** 2
    translation = (
        (cfg.velocity_sigma * span) ** 2
        + (0.5 * cfg.accel_sigma * span**2) ** 2
        + cfg.accel_noise**2 * span**3 / 3.0
    )
    return np.diag([translation] * 3 + [rotation] * 3)


def wheel_covariance(cfg: MotionPriorConfig, span: float, distance: float) -> np.ndarray:
    """Return the (6, 6) covariance of a wheel prior over ``span`` s and ``distance`` m."""
    translation = (cfg.wheel_distance_noise * distance) ** 2 + 1e-6
    rotation = cfg.wheel_rotation_noise**2 * span
    return np.diag([translation] * 3 + [rotation] * 3)


class ImuBiasEstimator:
    """
    The gyro bias and the acceleration offset, low-passed from the accepted poses.

    Per accepted interval ``[t_a, t_b]``: the gyro residual ``log(R_imu^T R_accepted) / dt``
    is ``b_hat - b`` to first order, so ``b_hat -= gain * residual``; the translation
    residual divided by its sensitivity to a constant odom-frame acceleration
    (``dt (dt_prev + dt) / 2`` with the velocity from the previous interval) moves the offset
    ``c``. The gain starts at ``1 / n`` (a running mean) and settles at the configured gain.
    """

    def __init__(self) -> None:
        """Start with a zero gyro bias and no acceleration offset."""
        self.gyro_bias = np.zeros(3)
        self.offset_odom: np.ndarray | None = None  # c: gravity + bias, odom frame
        self.gyro_updates = 0
        self.accel_updates = 0

    def reset(self) -> None:
        """Forget the offset (the odom frame changes); the gyro bias is the sensor's: kept."""
        self.offset_odom = None
        self.accel_updates = 0

    def update_gyro(self, segment: ImuSegment, R_accepted: np.ndarray, gain: float) -> bool:
        """Move the gyro bias by the residual of one interval (False: outlier or no gain)."""
        if gain <= 0.0 or segment.duration <= 0.0:
            return False
        error = Rotation.from_matrix(segment.rotation.T @ R_accepted).as_rotvec()
        residual = error / segment.duration
        if np.linalg.norm(residual) > MAX_GYRO_RESIDUAL:
            return False
        self.gyro_updates += 1
        self.gyro_bias = self.gyro_bias - max(gain, 1.0 / self.gyro_updates) * residual
        return True

    def update_offset(self, error_odom: np.ndarray, sensitivity: float, gain: float) -> bool:
        """Move the acceleration offset by a translation residual (odom frame, m)."""
        if gain <= 0.0 or sensitivity <= 0.0 or self.offset_odom is None:
            return False
        correction = error_odom / sensitivity
        warm = self.accel_updates * gain >= 1.0  # past the running-mean start
        if warm and np.linalg.norm(correction) > MAX_ACCEL_RESIDUAL:
            return False
        self.accel_updates += 1
        self.offset_odom = self.offset_odom + max(gain, 1.0 / self.accel_updates) * correction
        return True


def _hat(vectors: np.ndarray) -> np.ndarray:
    """Return the skew matrices (n, 3, 3) of ``vectors`` (n, 3)."""
    x, y, z = vectors.T
    zero = np.zeros_like(x)
    return np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=1).reshape(-1, 3, 3)


def _left_jacobian(rotvecs: np.ndarray) -> np.ndarray:
    """Return SO(3)'s left Jacobians (n, 3, 3): ``I + (1 - cos)/th^2 K + (th - sin)/th^3 K^2``."""
    theta = np.linalg.norm(rotvecs, axis=1)[:, None, None]
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 0.5, (1.0 - np.cos(safe)) / safe**2)
    b = np.where(small, 1.0 / 6.0, (safe - np.sin(safe)) / safe**3)
    K = _hat(rotvecs)
    return np.eye(3) + a * K + b * (K @ K)


def interpolate_poses(stamps_ns: np.ndarray, poses: np.ndarray, at_ns: np.ndarray) -> np.ndarray:
    """
    Return poses (k, 4, 4) at ``at_ns``, on the constant twist between neighbouring messages.

    The relative pose of the two neighbours is scaled on SE(3) (``exp(s log(T0^-1 T1))``),
    so a constant-twist motion (a circle driven at constant speed) is interpolated exactly;
    past either end the twist of the two end messages is extrapolated.
    """
    at = np.atleast_1d(np.asarray(at_ns, dtype=np.int64))
    upper = np.clip(np.searchsorted(stamps_ns, at, side='right'), 1, len(stamps_ns) - 1)
    lower = upper - 1
    span = (stamps_ns[upper] - stamps_ns[lower]).astype(np.float64)
    s = ((at - stamps_ns[lower]) / np.where(span > 0, span, 1.0))[:, None]
    P0, P1 = poses[lower], poses[upper]
    delta = invert_transform(P0) @ P1
    rotvec = Rotation.from_matrix(delta[:, :3, :3]).as_rotvec()
    v = np.linalg.solve(_left_jacobian(rotvec), delta[:, :3, 3:])[..., 0]  # log translation
    step = np.tile(np.eye(4), (at.size, 1, 1))
    step[:, :3, :3] = Rotation.from_rotvec(rotvec * s).as_matrix()
    step[:, :3, 3] = np.einsum('nij,nj->ni', _left_jacobian(rotvec * s), v * s)
    return P0 @ step
