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
The motion-prior topics of a bag (IMU, wheel odometry), merged by time with its scans.

``mlsemreg eval-bag BAG --imu-topic /imu/data --wheel-topic /wheel/odometry`` reads them
whole (:func:`read_prior_topics`) and, before each scan, hands the motion model every
message stamped up to the end of that scan's sweep (:meth:`PriorTopics.feed_until`): what a
node would have received by the time the cloud arrives (``docs/field_prior.md``).

The messages pass the node's checks at arrival, in the order the bag recorded them
(``core/prior_checks.py``, ``docs/hostile_input.md``): non-finite values, IMU samples beyond
the physical limits, zero or non-unit quaternions, bad stamps, duplicate or backward stamps
and wheel jumps are dropped, counted by reason in :attr:`PriorTopics.dropped` and logged. A
message that cannot be read at all is dropped as ``unreadable``; reading the topics never
raises for the content of one message.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
import logging
import math
from pathlib import Path
from typing import Any

from mlsemreg_ros.core.prior_checks import (
    imu_problem,
    pose_matrix,
    stamp_problem,
    StreamGate,
    unit_quaternion,
    wheel_jump,
    wheel_problem,
)
from mlsemreg_ros.datasets.bag import (
    _topic_messages,
    IMU,
    ImuArrays,
    ODOMETRY,
    WheelOdometryArrays,
)
from mlsemreg_ros.datasets.source import SourceError
import numpy as np

LOG = logging.getLogger(__name__)


@dataclass
class PriorTopics:
    """IMU and wheel-odometry messages of a bag and how many were handed on."""

    imu: ImuArrays | None = None
    wheel: WheelOdometryArrays | None = None
    fed: dict[str, int] = field(default_factory=lambda: {'imu': 0, 'wheel': 0})
    dropped: dict[str, dict[str, int]] = field(default_factory=dict)  # stream -> reason -> n

    def __bool__(self) -> bool:
        """Tell whether there is any prior topic."""
        return self.imu is not None or self.wheel is not None

    def feed_until(self, model: Any, stamp_ns: int) -> None:
        """Hand ``model`` (``add_imu`` / ``add_wheel``) the messages stamped up to ``stamp_ns``."""
        if self.imu is not None:
            start = self.fed['imu']
            stop = int(np.searchsorted(self.imu.stamps_ns, stamp_ns, side='right'))
            if stop > start:
                model.add_imu(
                    self.imu.stamps_ns[start:stop],
                    self.imu.angular_velocity[start:stop],
                    self.imu.linear_acceleration[start:stop],
                )
                self.fed['imu'] = stop
        if self.wheel is not None:
            start = self.fed['wheel']
            stop = int(np.searchsorted(self.wheel.stamps_ns, stamp_ns, side='right'))
            if stop > start:
                model.add_wheel(self.wheel.stamps_ns[start:stop], self.wheel.poses[start:stop])
                self.fed['wheel'] = stop


def read_prior_topics(
    bag: str | Path, imu_topic: str | None = None, wheel_topic: str | None = None
) -> PriorTopics:
    """Read the IMU and wheel-odometry topics of ``bag`` ('' or None: not read)."""
    topics = PriorTopics()
    if imu_topic:
        topics.imu, topics.dropped['imu'] = read_checked_imu(bag, imu_topic)
        if not len(topics.imu):
            raise SourceError(f'{bag}: IMU topic {imu_topic!r} has no usable messages')
    if wheel_topic:
        topics.wheel, topics.dropped['wheel'] = read_checked_wheel(bag, wheel_topic)
        if not len(topics.wheel):
            raise SourceError(
                f'{bag}: wheel odometry topic {wheel_topic!r} has no usable messages'
            )
    for stream, reasons in topics.dropped.items():
        if reasons:
            counts = ', '.join(f'{why} {n}' for why, n in sorted(reasons.items()))
            LOG.warning('%s: %s messages dropped at arrival: %s', bag, stream, counts)
    return topics


def _floats(vector: Any) -> tuple[float, float, float]:
    return float(vector.x), float(vector.y), float(vector.z)


def read_checked_imu(bag: str | Path, topic: str) -> tuple[ImuArrays, dict[str, int]]:
    """Read a sensor_msgs/Imu topic through the node's checks; the kept and the drops."""
    gate, dropped, kept, frame = StreamGate(), Counter(), [], ''
    for msg in _topic_messages(bag, topic, (IMU,)):  # the order the bag recorded them
        try:
            stamp_ns, why = stamp_problem(msg.header.stamp.sec, msg.header.stamp.nanosec)
            gyro, accel = _floats(msg.angular_velocity), _floats(msg.linear_acceleration)
            frame = frame or str(msg.header.frame_id)
        except Exception:  # any attribute or conversion error: not a message we can read
            dropped['unreadable'] += 1
            continue
        why = why or imu_problem(gyro, accel) or gate.admit(stamp_ns).reason
        if why:
            dropped[why] += 1
        else:
            kept.append((stamp_ns, gyro, accel))
    kept.sort(key=lambda sample: sample[0])  # a restarted stream: merged by stamp
    stamps = np.array([k[0] for k in kept], dtype=np.int64)
    gyro = np.array([k[1] for k in kept], dtype=np.float64).reshape(-1, 3)
    accel = np.array([k[2] for k in kept], dtype=np.float64).reshape(-1, 3)
    return ImuArrays(stamps, gyro, accel, frame), dict(dropped)


def read_checked_wheel(bag: str | Path, topic: str) -> tuple[WheelOdometryArrays, dict[str, int]]:
    """Read a nav_msgs/Odometry topic through the node's checks; the kept and the drops."""
    gate = StreamGate(lambda a, b, span: wheel_jump(a, b, span))
    dropped, kept, frames = Counter(), [], ('', '')
    for msg in _topic_messages(bag, topic, (ODOMETRY,)):
        try:
            stamp_ns, why = stamp_problem(msg.header.stamp.sec, msg.header.stamp.nanosec)
            pose, twist = msg.pose.pose, msg.twist.twist
            q = pose.orientation
            quaternion = (float(q.x), float(q.y), float(q.z), float(q.w))
            position = _floats(pose.position)
            velocity, rate = _floats(twist.linear), _floats(twist.angular)
            frames = frames if frames[0] else (str(msg.header.frame_id), str(msg.child_frame_id))
        except Exception:  # any attribute or conversion error
            dropped['unreadable'] += 1
            continue
        why = why or wheel_problem(position, quaternion)
        if not why:
            unit = unit_quaternion(quaternion)
            why = gate.admit(stamp_ns, (position, unit)).reason
        if why:
            dropped[why] += 1
            continue
        finite = all(math.isfinite(v) for v in velocity + rate)  # the twist is not checked
        zero = (0.0, 0.0, 0.0)
        kept.append(
            (
                stamp_ns,
                pose_matrix(position, unit),
                velocity if finite else zero,
                rate if finite else zero,
            )
        )
    kept.sort(key=lambda sample: sample[0])
    return WheelOdometryArrays(
        np.array([k[0] for k in kept], dtype=np.int64),
        np.array([k[1] for k in kept], dtype=np.float64).reshape(-1, 4, 4),
        np.array([k[2] for k in kept], dtype=np.float64).reshape(-1, 3),
        np.array([k[3] for k in kept], dtype=np.float64).reshape(-1, 3),
        *frames,
    ), dict(dropped)


def sweep_end_ns(stamp_ns: int, point_times: np.ndarray | None) -> int:
    """Return the stamp of a scan's last point (its header stamp without point times)."""
    if point_times is None or not len(point_times):
        return stamp_ns
    return stamp_ns + max(round(float(np.max(point_times)) * 1e9), 0)
