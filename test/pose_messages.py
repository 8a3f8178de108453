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

"""Pose messages for the rclpy tests: build, publish to the node, read back."""

from __future__ import annotations

import time
from typing import Any

from mlsemreg_ros.codec.poses import pose_message_to_matrix, transform_message_to_matrix
from mlsemreg_ros.datasets.synthetic_scene import motion
import numpy as np
from scipy.spatial.transform import Rotation


def pose_message(frame: str, T: np.ndarray, sigma_m: float = 0.5, sigma_yaw: float = 0.26) -> Any:
    """Build a PoseWithCovarianceStamped of ``T`` (4, 4), as RViz's 2D Pose Estimate sends it."""
    from geometry_msgs.msg import PoseWithCovarianceStamped

    msg = PoseWithCovarianceStamped()
    msg.header.frame_id = frame
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    p.x, p.y, p.z = (float(v) for v in T[:3, 3])
    q.x, q.y, q.z, q.w = (float(v) for v in Rotation.from_matrix(T[:3, :3]).as_quat())
    covariance = np.zeros((6, 6))
    covariance[0, 0] = covariance[1, 1] = sigma_m**2
    covariance[5, 5] = sigma_yaw**2
    msg.pose.covariance = covariance.reshape(-1).tolist()
    return msg


def publish_pose(probe: Any, topic: str, msg: Any) -> None:
    """Publish a pose once the node subscribes, and give it time to arrive before a scan."""
    from geometry_msgs.msg import PoseWithCovarianceStamped

    publisher = probe.node.create_publisher(PoseWithCovarianceStamped, topic, 10)
    assert probe.wait_until(lambda: publisher.get_subscription_count() > 0, 10.0)
    publisher.publish(msg)
    time.sleep(1.0)  # the request waits in the node for the next scan
    probe.node.destroy_publisher(publisher)


def pose_of(msg: Any) -> np.ndarray:
    return pose_message_to_matrix(msg.pose.pose)


def matrix(message: Any) -> np.ndarray:
    """Return the (4, 4) of a geometry_msgs Transform or Pose."""
    if hasattr(message, 'translation'):
        return transform_message_to_matrix(message)
    return pose_message_to_matrix(message)


def yawed(x: float, y: float, yaw_deg: float) -> np.ndarray:
    return motion(yaw_deg, (x, y, 0.0))
