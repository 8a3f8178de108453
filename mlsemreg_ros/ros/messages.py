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
Message building for the node's outputs: transform, odometry, path, diagnostics.

Poses are 4x4 homogeneous matrices ``T_parent_child`` (``p_parent = T @ p_child``).
No arithmetic here: quaternions come from :mod:`mlsemreg_ros.codec.poses`, inversion from
:mod:`mlsemreg_ros.core.rigid`; the registration, covariances and twist live in the core.
"""

from __future__ import annotations

from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Pose, PoseStamped, Transform, TransformStamped
from mlsemreg_ros.codec.poses import matrix_to_quaternion
from nav_msgs.msg import Odometry
import numpy as np
from std_msgs.msg import Header


def _transform(transform: np.ndarray) -> Transform:
    x, y, z, w = matrix_to_quaternion(transform[:3, :3])
    out = Transform()
    out.translation.x, out.translation.y, out.translation.z = map(float, transform[:3, 3])
    out.rotation.x, out.rotation.y, out.rotation.z, out.rotation.w = (
        float(x),
        float(y),
        float(z),
        float(w),
    )
    return out


def pose_msg(transform: np.ndarray) -> Pose:
    """4x4 -> geometry_msgs/Pose."""
    t = _transform(transform)
    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = (
        t.translation.x,
        t.translation.y,
        t.translation.z,
    )
    pose.orientation = t.rotation
    return pose


def transform_msg(stamp: Time, parent: str, child: str, transform: np.ndarray) -> TransformStamped:
    """4x4 ``T_parent_child`` -> TransformStamped."""
    return TransformStamped(
        header=Header(stamp=stamp, frame_id=parent),
        child_frame_id=child,
        transform=_transform(transform),
    )


def pose_stamped(stamp: Time, frame: str, transform: np.ndarray) -> PoseStamped:
    """4x4 -> PoseStamped (a path entry)."""
    return PoseStamped(header=Header(stamp=stamp, frame_id=frame), pose=pose_msg(transform))


def odometry_msg(
    stamp: Time,
    frame: str,
    child: str,
    pose: np.ndarray,
    pose_covariance: np.ndarray,
    twist: np.ndarray,
    twist_covariance: np.ndarray,
) -> Odometry:
    """nav_msgs/Odometry; covariances (6, 6) in ROS order ``[x, y, z, roll, pitch, yaw]``."""
    msg = Odometry(header=Header(stamp=stamp, frame_id=frame), child_frame_id=child)
    msg.pose.pose = pose_msg(pose)
    msg.pose.covariance = np.asarray(pose_covariance, dtype=np.float64).reshape(-1)
    msg.twist.twist.linear.x, msg.twist.twist.linear.y, msg.twist.twist.linear.z = (
        float(v) for v in twist[:3]
    )
    msg.twist.twist.angular.x, msg.twist.twist.angular.y, msg.twist.twist.angular.z = (
        float(v) for v in twist[3:]
    )
    msg.twist.covariance = np.asarray(twist_covariance, dtype=np.float64).reshape(-1)
    return msg


LEVELS = {
    'ok': DiagnosticStatus.OK,
    'warn': DiagnosticStatus.WARN,
    'error': DiagnosticStatus.ERROR,
}


def diagnostics_msg(
    stamp: Time, name: str, hardware_id: str, level: str, message: str, values: dict[str, Any]
) -> DiagnosticArray:
    """Build a DiagnosticArray with one status; floats are written with 3 decimals."""
    pairs = [
        KeyValue(key=k, value=f'{v:.3f}' if isinstance(v, float) else str(v))
        for k, v in values.items()
    ]
    status = DiagnosticStatus(
        level=LEVELS[level], name=name, message=message, hardware_id=hardware_id, values=pairs
    )
    return DiagnosticArray(header=Header(stamp=stamp), status=[status])
