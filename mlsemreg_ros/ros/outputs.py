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
The node's continuous output stream (docs/ros_interface.md, *Continuous output*).

- ``mlsemreg/cloud_registered`` (sensor_msgs/PointCloud2 in ``odom_frame``): the scan as
  the odometry kept it (deskewed, moving objects dropped), moved by its accepted pose;
  built only while someone subscribes.
- a ``/diagnostics`` heartbeat (status ``<node>: heartbeat``) every
  :data:`HEARTBEAT_PERIOD_S` of steady time, whatever the input does: ``receiving
  input`` or ``no input for N s``, so a silent sensor is told apart from a dead node.
  Steady time: a paused bag with ``use_sim_time`` does not stop it.

The odometry and TF of a refused scan (``publish_predicted_on_refusal``) come from the
core's prediction (``OdometryStep.predicted_pose``, ``predicted_covariance``); the node
publishes them through its own pose output.
"""

from __future__ import annotations

import threading
import time
from typing import Any

from mlsemreg_ros.codec.pointcloud2 import arrays_to_pointcloud2
from mlsemreg_ros.ros import messages
import numpy as np
from rclpy.clock import Clock, ClockType
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

#: Period of the ``/diagnostics`` heartbeat (s).
HEARTBEAT_PERIOD_S = 1.0
#: The heartbeat warns once the last scan is older than this (s).
NO_INPUT_AFTER_S = 1.0


def registered_points(
    points: np.ndarray, T_odom_sensor: np.ndarray, T_base_sensor: np.ndarray
) -> np.ndarray:
    """
    Points (N, 3) of the sensor frame in the published odom frame (the base's).

    The published pose is ``T_odom_base = X T_odom_sensor X^-1`` (``ros/extrinsic.py``,
    ``X = T_base_sensor``), so a point goes to ``T_odom_base X p = X T_odom_sensor p``.
    """
    T = T_base_sensor @ T_odom_sensor
    return points @ T[:3, :3].T + T[:3, 3]


class Heartbeat:
    """Says on ``/diagnostics`` every second how long ago the last scan arrived."""

    def __init__(self, node: Any, publisher: Any) -> None:
        """Start a steady-clock timer on ``node`` that publishes on ``publisher``."""
        self._node, self._publisher = node, publisher
        self._lock = threading.Lock()
        self._started = time.monotonic()
        self._last_input: float | None = None  # time.monotonic() of the last scan
        self.timer = node.create_timer(
            HEARTBEAT_PERIOD_S, self.beat, clock=Clock(clock_type=ClockType.STEADY_TIME)
        )

    def note_input(self) -> None:
        """Record that a scan arrived (the subscription callback)."""
        with self._lock:
            self._last_input = time.monotonic()

    def status(self, now: float | None = None) -> tuple[str, str, dict[str, Any]]:
        """Return (level, message, values) of the heartbeat at ``now`` (monotonic s)."""
        now = time.monotonic() if now is None else now
        with self._lock:
            last = self._last_input
        silent = now - (last if last is not None else self._started)
        values: dict[str, Any] = {'seconds_since_input': silent, 'input_seen': last is not None}
        if silent < NO_INPUT_AFTER_S:
            return 'ok', 'receiving input', values
        never = ' (no scan since start)' if last is None else ''
        return 'warn', f'no input for {silent:.0f} s{never}', values

    def beat(self) -> None:
        """Publish one heartbeat status (timer callback)."""
        level, message, values = self.status()
        node = self._node
        self._publisher.publish(
            messages.diagnostics_msg(
                node.get_clock().now().to_msg(),
                f'{node.get_name()}: heartbeat',
                node.get_fully_qualified_name(),
                level,
                message,
                values,
            )
        )


class RegisteredCloud:
    """``mlsemreg/cloud_registered``: accepted scans in the odom frame, while watched."""

    def __init__(self, node: Any) -> None:
        """Create the publisher on ``node``."""
        self.publisher = node.create_publisher(PointCloud2, 'mlsemreg/cloud_registered', 1)

    def publish(self, stamp: Any, odom_frame: str, step: Any, T_base_sensor: np.ndarray) -> bool:
        """Publish an accepted step's points in ``odom_frame`` (False: nobody looks or none)."""
        if self.publisher.get_subscription_count() == 0 or step.points is None:
            return False
        xyz = registered_points(step.points, step.pose, T_base_sensor)
        labels = step.labels  # raw values; kept when a uint32 field holds them
        if labels is None or labels.size == 0 or labels.min() < 0 or labels.max() >= 2**32:
            labels = None
        header = Header(stamp=stamp, frame_id=odom_frame)
        self.publisher.publish(arrays_to_pointcloud2(PointCloud2, PointField, header, xyz, labels))
        return True
