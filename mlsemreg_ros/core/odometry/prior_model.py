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
The motion model with an external prior (IMU or wheel odometry), constant velocity without one.

Registered as ``'prior'`` (``docs/extending.md``); the odometry uses it unless
``motion_prior.source`` is ``none`` (:func:`motion_model_name`). The math is in
:mod:`mlsemreg_ros.core.motion_prior`; how to use it in ``docs/field_prior.md``.

Feeding: :meth:`PriorMotionModel.add_imu` and :meth:`PriorMotionModel.add_wheel` take
messages in any thread (a lock guards the buffers). Until a prior covers the interval
from the last accepted pose to the requested stamp, every prediction is exactly the
constant-velocity model's.
"""

from __future__ import annotations

import itertools
import threading

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.motion_prior import (
    GRAVITY_WINDOW_S,
    imu_covariance,
    ImuBiasEstimator,
    integrate_imu,
    interpolate_poses,
    MIN_SCALE_DISTANCE,
    MotionPriorConfig,
    RelativePrior,
    SampleBuffer,
    wheel_covariance,
)
from mlsemreg_ros.core.odometry.motion_model import (
    ConstantVelocityModel,
    DEFAULT_MOTION_MODEL,
    motion_model,
    Prediction,
)
from mlsemreg_ros.core.rigid import invert_transform
import numpy as np

#: The name of the prior motion model in ``MOTION_MODELS``.
PRIOR_MOTION_MODEL = 'prior'


def motion_model_name(config: RegistrationConfig) -> str:
    """Return the motion model the odometry builds for ``config``."""
    return DEFAULT_MOTION_MODEL if config.motion_prior.source == 'none' else PRIOR_MOTION_MODEL


@motion_model(PRIOR_MOTION_MODEL)
class PriorMotionModel:
    """
    Predicts with the IMU or the wheel odometry when they cover the gap, else constant velocity.

    ``last_source`` tells which one made the last prediction ('imu', 'wheel',
    'constant_velocity' or '' for none).
    """

    def __init__(self, config: RegistrationConfig | None = None) -> None:
        """Use ``config.motion_prior`` (defaults when None)."""
        self.cfg: MotionPriorConfig = (
            config.motion_prior if config is not None else MotionPriorConfig()
        )
        self._cv = ConstantVelocityModel(config)
        self._lock = threading.Lock()
        self._imu = SampleBuffer((6,))  # gyro (rad/s), specific force (m/s^2)
        self._segments: tuple = (None, None, {})  # (stamps, values, {interval: segment})
        self._wheel = SampleBuffer((4, 4))  # T_odom_child
        self.T_child_sensor = np.eye(4)  # wheel odometry child frame -> sensor frame
        self.bias = ImuBiasEstimator()
        self.wheel_scale = 1.0  # wheel distance / true distance
        self._scale_updates = 0
        self._accepted: list[tuple[np.ndarray, int]] = []  # last three (pose, stamp)
        self.last_source = ''
        self.counts: dict[str, int] = {}  # predictions by source

    # -- feeding -------------------------------------------------------------------
    def add_imu(self, stamps_ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> None:
        """Take IMU samples: stamps (n,) ns, angular rate and specific force (n, 3)."""
        values = np.concatenate([np.reshape(gyro, (-1, 3)), np.reshape(accel, (-1, 3))], axis=1)
        with self._lock:
            self._imu.add(stamps_ns, values)

    def add_wheel(
        self, stamps_ns: np.ndarray, poses: np.ndarray, T_child_sensor: np.ndarray | None = None
    ) -> None:
        """Take wheel odometry poses ``T_odom_child`` (n, 4, 4), optionally ``T_child_sensor``."""
        with self._lock:
            if T_child_sensor is not None:
                self.T_child_sensor = np.asarray(T_child_sensor, dtype=np.float64).copy()
            self._wheel.add(stamps_ns, np.reshape(poses, (-1, 4, 4)))

    def constant_velocity(self, stamp_ns: int) -> Prediction | None:
        """Return the constant-velocity prediction at ``stamp_ns`` (the prior left out)."""
        return self._cv.predict(stamp_ns)

    def forget(self, source: str) -> None:
        """Drop every sample of ``source`` ('imu' or 'wheel'): its stream restarted."""
        with self._lock:
            (self._imu if source == 'imu' else self._wheel).clear()

    # -- the protocol ----------------------------------------------------------------
    def predict(self, stamp_ns: int) -> Prediction | None:
        """Return the prior's prediction at ``stamp_ns``, or the constant-velocity one."""
        constant = self._cv.predict(stamp_ns)
        if self.cfg.source == 'none' or not self._accepted:
            self.last_source = 'constant_velocity' if constant is not None else ''
            return constant
        with self._lock:
            prior = self.relative_prior(stamp_ns)
        if prior is None:
            self.last_source = 'constant_velocity' if constant is not None else ''
            self._count(self.last_source)
            return constant
        pose, _ = self._accepted[-1]
        gap = constant.stamp_gap if constant is not None else 1.0
        sigma_t, sigma_r = prior.sigmas()
        if (
            sigma_t <= self.cfg.trusted_translation_sigma
            and sigma_r <= self.cfg.trusted_rotation_sigma
        ):
            gap = min(gap, 1.0)  # the prior spans the gap: as good as one frame interval
        self.last_source = prior.source
        self._count(prior.source)
        return Prediction(pose @ prior.T, gap, (sigma_t, sigma_r))

    @property
    def last_accepted(self) -> tuple[np.ndarray, int] | None:
        """Return the last accepted ``(pose, stamp_ns)``, or None before the first."""
        return self._cv.last_accepted

    def update(self, pose: np.ndarray, stamp_ns: int) -> None:
        """Take an accepted pose: learn the biases and the wheel scale from the last interval."""
        self._cv.update(pose, stamp_ns)
        with self._lock:
            self._accepted = [*self._accepted[-2:], (np.asarray(pose, float).copy(), stamp_ns)]
            if len(self._accepted) >= 2 and self.cfg.source != 'none':
                self._learn()
            keep = self._accepted[0][1] - round(self.cfg.buffer * 1e9)
            self._imu.drop_before(keep)
            self._wheel.drop_before(keep)

    def reset(self) -> None:
        """Forget the poses (and the odom-frame offset); the messages and the gyro bias stay."""
        self._cv.reset()
        self._accepted = []
        self.bias.reset()

    def sweep_rotations(
        self, stamp_ns: int, first_s: float, last_s: float
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """
        Return the gyro's rotations within a sweep ``[stamp + first_s, stamp + last_s]``.

        ``(times (K,), R (K, 3, 3))``: ``R[k]`` is the sensor's rotation at ``stamp +
        times[k]`` in the frame at the stamp (bias removed); the nodes are the sweep's ends,
        the stamp and every IMU sample in between. None without IMU samples over the sweep.
        The deskew takes the rotation from here and the translation from the accepted
        poses (``core/features/deskew.py``, :class:`PiecewiseSweepMotion`).
        """
        if self.cfg.source not in ('imu', 'auto'):
            return None
        start = min(stamp_ns + round(first_s * 1e9), stamp_ns)
        end = max(stamp_ns + round(last_s * 1e9), stamp_ns)
        if end <= start:
            return None
        with self._lock:
            if not self._imu.covers(start, end, self._slack(), self._gap()):
                return None
            first = max(int(np.searchsorted(self._imu.stamps, start)) - 1, 0)
            last = int(np.searchsorted(self._imu.stamps, end, side='right')) + 1
            stamps, values = self._imu.stamps[first:last], self._imu.values[first:last]
            bias = self.bias.gyro_bias
            inside = stamps[(stamps > start) & (stamps < end) & (stamps != stamp_ns)]
            nodes = np.unique(np.concatenate([[start, stamp_ns, end], inside]).astype(np.int64))
            steps = node_rotations(stamps, values[:, :3], nodes, bias)  # one pass, all nodes
        # R_start_node: the running product, in the order integrate_imu's callers compose
        rotations = np.stack(list(itertools.accumulate(steps, np.matmul, initial=np.eye(3))))
        at_stamp = rotations[int(np.searchsorted(nodes, stamp_ns))]
        return (nodes - stamp_ns) * 1e-9, np.einsum('ji,njk->nik', at_stamp, rotations)

    def gyro_rotation(self, stamp_ns: int) -> np.ndarray | None:
        """
        Return the gyro's rotation (3, 3) from the last accepted scan to ``stamp_ns``.

        ``R_last_current``, bias removed; None without an IMU covering the interval. Unlike
        the IMU prior it needs no velocity: it is there for the second scan after a start.
        """
        if self.cfg.source not in ('imu', 'auto') or not self._accepted:
            return None
        t0 = self._accepted[-1][1]
        if not 0.0 < (stamp_ns - t0) * 1e-9 <= self.cfg.max_span:
            return None
        with self._lock:
            if not self._imu.covers(t0, stamp_ns, self._slack(), self._gap()):
                return None
            return np.asarray(self._segment(t0, stamp_ns).rotation, dtype=np.float64).copy()

    # -- the prior -----------------------------------------------------------------
    def relative_prior(self, stamp_ns: int) -> RelativePrior | None:
        """Return the prior from the last accepted pose to ``stamp_ns`` (None: not covered)."""
        if not self._accepted:
            return None
        t0 = self._accepted[-1][1]
        span = (stamp_ns - t0) * 1e-9
        if span < 0.0 or span > self.cfg.max_span:
            return None
        source = self.cfg.source
        if source in ('imu', 'auto'):
            prior = self._imu_prior(t0, stamp_ns)
            if prior is not None or source == 'imu':
                return prior
        return self._wheel_prior(t0, stamp_ns)

    def _slack(self) -> int:
        return round(self.cfg.max_extrapolation * 1e9)

    def _gap(self) -> int:
        """Return the longest hole (ns) between messages a prior is interpolated across."""
        return round(self.cfg.max_sample_gap * 1e9)

    def _segment(self, t0: int, t1: int):
        """
        Return the IMU integrated over ``[t0, t1]``, memoised while the samples stay.

        A scan asks for each interval up to three times (the prediction, the velocity,
        the learning); the same interval, samples and gyro bias give the same segment.
        The buffer's arrays are replaced, never written, when samples come or go.
        """
        imu, bias = self._imu, self.bias.gyro_bias
        if self._segments[0] is not imu.stamps or self._segments[1] is not imu.values:
            self._segments = (imu.stamps, imu.values, {})
        known = self._segments[2]
        key = (t0, t1, np.asarray(bias, dtype=np.float64).tobytes())
        if key not in known:
            values = imu.values
            known[key] = integrate_imu(imu.stamps, values[:, :3], values[:, 3:], t0, t1, bias)
        return known[key]

    def _offset(self, pose: np.ndarray, stamp_ns: int) -> np.ndarray:
        """Return the acceleration offset in odom (initialised from the accelerometer at rest)."""
        if self.bias.offset_odom is None:
            half = round(0.5 * GRAVITY_WINDOW_S * 1e9)
            near = np.abs(self._imu.stamps - stamp_ns) <= half
            force = self._imu.values[near, 3:] if near.any() else self._imu.values[-1:, 3:]
            self.bias.offset_odom = -pose[:3, :3] @ force.mean(axis=0)
        return self.bias.offset_odom

    def _velocity(self, index: int) -> tuple[np.ndarray, float] | None:
        """Velocity (odom) at accepted pose ``index`` and the previous interval (None: no pair)."""
        if len(self._accepted) + index < 1:
            return None
        (P_b, t_b), (P_a, t_a) = self._accepted[index - 1], self._accepted[index]
        duration = (t_a - t_b) * 1e-9
        if duration <= 0.0:
            return None
        velocity = (P_a[:3, 3] - P_b[:3, 3]) / duration
        if self._imu.covers(t_b, t_a, self._slack(), self._gap()):
            segment = self._segment(t_b, t_a)
            offset = P_b[:3, :3].T @ self._offset(P_b, t_b)
            velocity = velocity + P_b[:3, :3] @ segment.first_moment(offset) / duration
            return velocity, duration
        return velocity, 0.0

    def _imu_prior(self, t0: int, t1: int, index: int = -1) -> RelativePrior | None:
        if not self._imu.covers(t0, t1, self._slack(), self._gap()):
            return None
        known = self._velocity(index)
        if known is None:
            return None
        velocity, _ = known
        pose = self._accepted[index][0]
        R = pose[:3, :3]
        segment = self._segment(t0, t1)
        T = np.eye(4)
        T[:3, :3] = segment.rotation
        if self.bias.accel_updates or index != -1:
            offset = R.T @ self._offset(pose, t0)
            T[:3, 3] = segment.displacement(R.T @ velocity, offset)
        else:  # no offset learned yet (gravity unknown): the gyro turns a constant velocity
            (P_b, t_b), _ = self._accepted[-2], self._accepted[-1]
            T[:3, 3] = R.T @ (pose[:3, 3] - P_b[:3, 3]) * (segment.duration / span_s(t_b, t0))
        span = segment.duration
        return RelativePrior(T, imu_covariance(self.cfg, span), 'imu', span)

    def _wheel_relative(self, t0: int, t1: int) -> np.ndarray | None:
        wheel = self._wheel
        if not wheel.covers(t0, t1, self._slack(), self._gap()):
            return None
        W0, W1 = interpolate_poses(wheel.stamps, wheel.values, np.array([t0, t1]))
        X = self.T_child_sensor
        return invert_transform(X) @ invert_transform(W0) @ W1 @ X

    def _wheel_prior(self, t0: int, t1: int) -> RelativePrior | None:
        relative = self._wheel_relative(t0, t1)
        if relative is None:
            return None
        relative[:3, 3] /= self.wheel_scale
        span = (t1 - t0) * 1e-9
        distance = float(np.linalg.norm(relative[:3, 3]))
        return RelativePrior(relative, wheel_covariance(self.cfg, span, distance), 'wheel', span)

    # -- learning from the accepted poses -------------------------------------------------
    def _learn(self) -> None:
        """Learn from the interval between the last two accepted poses."""
        (P_a, t_a), (P_b, t_b) = self._accepted[-2], self._accepted[-1]
        span = (t_b - t_a) * 1e-9
        if span <= 0.0 or span > self.cfg.max_span:
            return
        accepted = invert_transform(P_a) @ P_b
        if self._imu.covers(t_a, t_b, self._slack(), self._gap()):
            self._learn_imu(P_a, t_a, P_b, t_b, accepted)
        relative = self._wheel_relative(t_a, t_b)
        if relative is not None and self.cfg.wheel_scale_gain > 0.0:
            moved = float(np.linalg.norm(accepted[:3, 3]))
            if moved >= MIN_SCALE_DISTANCE:
                ratio = float(np.linalg.norm(relative[:3, 3])) / moved
                if 0.5 < ratio < 2.0:
                    self._scale_updates += 1
                    gain = max(self.cfg.wheel_scale_gain, 1.0 / self._scale_updates)
                    self.wheel_scale += gain * (ratio - self.wheel_scale)

    def _learn_imu(
        self, P_a: np.ndarray, t_a: int, P_b: np.ndarray, t_b: int, accepted: np.ndarray
    ) -> None:
        """Update the acceleration offset (translation residual), then the gyro bias."""
        if len(self._accepted) >= 3:
            prior = self._imu_prior(t_a, t_b, index=-2)
            if prior is not None:
                known = self._velocity(-2)
                previous = known[1] if known is not None else 0.0
                error_odom = P_a[:3, :3] @ (accepted[:3, 3] - prior.T[:3, 3])
                self.bias.update_offset(
                    error_odom,
                    0.5 * span_s(t_a, t_b) * (previous + span_s(t_a, t_b)),
                    self.cfg.accel_gain,
                )
        segment = self._segment(t_a, t_b)
        self.bias.update_gyro(segment, accepted[:3, :3], self.cfg.gyro_bias_gain)

    def _count(self, source: str) -> None:
        if source:
            self.counts[source] = self.counts.get(source, 0) + 1


def node_rotations(
    stamps_ns: np.ndarray, gyro: np.ndarray, nodes_ns: np.ndarray, gyro_bias: np.ndarray
) -> np.ndarray:
    """
    Return the gyro's rotation over each interval between consecutive nodes, all at once.

    ``(K - 1, 3, 3)``: ``R_node[k]_node[k + 1]`` for nodes (K,) ns increasing, with no sample
    stamp strictly between two nodes (:meth:`PriorMotionModel.sweep_rotations`): on each
    interval the rate is interpolated at its midpoint (held past the first or last
    sample), bias removed, ``exp(w dt)``. This is what
    :func:`~mlsemreg_ros.core.motion_prior.integrate_imu` computes over one interval, with
    the times taken from the first node instead of each interval's start (equal to 1e-12).
    """
    from scipy.spatial.transform import Rotation

    origin = int(nodes_ns[0])
    sample_s = (np.asarray(stamps_ns, dtype=np.int64) - origin) * 1e-9
    node_s = (np.asarray(nodes_ns, dtype=np.int64) - origin) * 1e-9
    middle = 0.5 * (node_s[1:] + node_s[:-1])
    rate = np.stack([np.interp(middle, sample_s, gyro[:, k]) for k in range(3)], axis=1)
    return Rotation.from_rotvec((rate - gyro_bias) * np.diff(node_s)[:, None]).as_matrix()


def span_s(t0_ns: int, t1_ns: int) -> float:
    """Return ``t1 - t0`` in seconds."""
    return (t1_ns - t0_ns) * 1e-9
