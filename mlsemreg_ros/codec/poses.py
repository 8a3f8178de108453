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
Poses as 4x4 matrices <-> quaternions and pose/transform messages, without importing ROS.

Quaternions are ``x, y, z, w`` (the ROS order) with ``w >= 0``. The message functions are
duck-typed: ``geometry_msgs/Pose`` (``position``, ``orientation``) and
``geometry_msgs/Transform`` (``translation``, ``rotation``) of rclpy or of a rosbags
typestore.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def matrix_to_quaternion(rotations: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) as ``x, y, z, w`` (w >= 0) of rotation matrices (..., 3, 3)."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(rotations, dtype=np.float64)
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    q = np.where(q[:, 3:4] < 0.0, -q, q)
    return q.reshape((*R.shape[:-2], 4))


def quaternion_to_matrix(quaternions: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of quaternions (..., 4) given as ``x, y, z, w``."""
    from scipy.spatial.transform import Rotation

    q = np.asarray(quaternions, dtype=np.float64)
    return Rotation.from_quat(q.reshape(-1, 4)).as_matrix().reshape((*q.shape[:-1], 3, 3))


def pose_to_matrix(
    position: tuple[float, float, float], orientation: tuple[float, float, float, float]
) -> np.ndarray:
    """(4, 4) from a position and an ``x, y, z, w`` quaternion."""
    T = np.eye(4)
    T[:3, :3] = quaternion_to_matrix(np.asarray(orientation, dtype=np.float64))
    T[:3, 3] = position
    return T


def pose_message_to_matrix(pose: Any) -> np.ndarray:
    """(4, 4) of a ``geometry_msgs/Pose``."""
    p, q = pose.position, pose.orientation
    return pose_to_matrix((p.x, p.y, p.z), (q.x, q.y, q.z, q.w))


def transform_message_to_matrix(transform: Any) -> np.ndarray:
    """(4, 4) of a ``geometry_msgs/Transform``."""
    t, q = transform.translation, transform.rotation
    return pose_to_matrix((t.x, t.y, t.z), (q.x, q.y, q.z, q.w))
