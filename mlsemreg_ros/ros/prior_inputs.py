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
The node's motion-prior inputs: IMU and wheel-odometry messages, collected for the core.

The subscription callbacks (executor thread) only convert a message to numbers and append
it to an inbox; the worker hands the inbox to the motion model in one batch right before
each scan (:meth:`PriorInbox.flush`), so the buffers of the core are touched by one thread
and a message costs no array copy. Frames (``docs/field_prior.md``): an IMU in the cloud's
frame is used as it is, one in ``base_frame`` is rotated into the sensor frame by
``T_base_sensor`` (the lever arm is ignored); wheel odometry whose child frame is
``base_frame`` is moved to the sensor with ``T_base_sensor``, one whose child is the
cloud's frame is used as it is.
"""

from __future__ import annotations

import threading
from typing import Any

from mlsemreg_ros.codec.stamps import stamp_to_ns
import numpy as np
from scipy.spatial.transform import Rotation


def _pose_matrix(pose: Any) -> np.ndarray:
    q, p = pose.orientation, pose.position
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = [p.x, p.y, p.z]
    return T


class PriorInbox:
    """IMU and wheel messages waiting for the worker; frame checks and counts."""

    def __init__(self) -> None:
        """Start empty."""
        self._lock = threading.Lock()
        self._imu: list[tuple[int, list[float], list[float], str]] = []
        self._wheel: list[tuple[int, np.ndarray, str]] = []
        self.counts = {'imu': 0, 'wheel': 0}
        self.warnings: list[str] = []  # frame mismatches, once each
        self._warned: set[str] = set()

    def on_imu(self, msg: Any) -> None:
        """Take a sensor_msgs/Imu (executor thread)."""
        w, a = msg.angular_velocity, msg.linear_acceleration
        item = (stamp_to_ns(msg.header.stamp), [w.x, w.y, w.z], [a.x, a.y, a.z])
        with self._lock:
            self._imu.append((*item, msg.header.frame_id))
            self.counts['imu'] += 1

    def on_wheel(self, msg: Any) -> None:
        """Take a nav_msgs/Odometry of the wheels (executor thread)."""
        item = (stamp_to_ns(msg.header.stamp), _pose_matrix(msg.pose.pose), msg.child_frame_id)
        with self._lock:
            self._wheel.append(item)
            self.counts['wheel'] += 1

    def flush(
        self, model: Any, sensor_frame: str, base_frame: str, T_base_sensor: np.ndarray
    ) -> None:
        """
        Hand the waiting messages to ``model`` (``add_imu`` / ``add_wheel``; worker thread).

        A model that takes no prior messages (``motion_prior.source: none``) drops them.
        """
        with self._lock:
            imu, self._imu = self._imu, []
            wheel, self._wheel = self._wheel, []
        if not hasattr(model, 'add_imu'):
            return
        if imu:
            stamps = np.array([m[0] for m in imu], dtype=np.int64)
            gyro = np.array([m[1] for m in imu], dtype=np.float64)
            accel = np.array([m[2] for m in imu], dtype=np.float64)
            rotation = self._rotation_to_sensor(
                imu[-1][3], sensor_frame, base_frame, T_base_sensor
            )
            if rotation is not None:
                gyro, accel = gyro @ rotation, accel @ rotation  # R_sensor_imu v, row-wise
            model.add_imu(stamps, gyro, accel)
        if wheel:
            stamps = np.array([m[0] for m in wheel], dtype=np.int64)
            poses = np.array([m[1] for m in wheel])
            child = wheel[-1][2]
            model.add_wheel(
                stamps,
                poses,
                self._child_to_sensor(child, sensor_frame, base_frame, T_base_sensor),
            )

    def _rotation_to_sensor(
        self, frame: str, sensor: str, base: str, T_base_sensor: np.ndarray
    ) -> np.ndarray | None:
        """Return ``R_imu_sensor`` for row vectors (None: the IMU is in the sensor frame)."""
        if not frame or frame == sensor:
            return None
        if base and frame == base:
            return T_base_sensor[:3, :3]  # v_sensor = R_base_sensor^T v_base
        self._warn(
            f'imu frame {frame!r} is neither the cloud frame {sensor!r} nor base_frame '
            f'{base!r}: used as if it were the cloud frame'
        )
        return None

    def _child_to_sensor(
        self, child: str, sensor: str, base: str, T_base_sensor: np.ndarray
    ) -> np.ndarray:
        """Return ``T_child_sensor`` of the wheel odometry's child frame."""
        if base and child == base:
            return T_base_sensor
        if child and child != sensor:
            self._warn(
                f'wheel odometry child frame {child!r} is neither the cloud frame {sensor!r} '
                f'nor base_frame {base!r}: used as if it were the cloud frame'
            )
        return np.eye(4)

    def _warn(self, message: str) -> None:
        if message not in self._warned:
            self._warned.add(message)
            self.warnings.append(message)


def subscribe_prior_topics(node: Any, inbox: PriorInbox, config: Any, model: Any) -> list[str]:
    """
    Subscribe ``node`` to the configured IMU and wheel topics (sensor-data QoS).

    Returns what to log: the subscriptions, and a note when the motion model takes no
    prior messages (``motion_prior.source: none``; a live change may enable it).
    """
    topics = {'imu': config.node.imu_topic, 'wheel': config.node.wheel_odometry_topic}
    if not any(topics.values()):
        return []
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Imu

    notes = []
    if topics['imu']:
        node.create_subscription(Imu, topics['imu'], inbox.on_imu, qos_profile_sensor_data)
        notes.append(f'motion prior: IMU on {node.resolve_topic_name(topics["imu"])}')
    if topics['wheel']:
        node.create_subscription(
            Odometry, topics['wheel'], inbox.on_wheel, qos_profile_sensor_data
        )
        notes.append(f'motion prior: wheel odometry on {node.resolve_topic_name(topics["wheel"])}')
    if not hasattr(model, 'add_imu'):
        notes.append(
            f'motion_prior.source is {config.core.motion_prior.source}: the prior messages '
            'are dropped until it changes'
        )
    return notes
