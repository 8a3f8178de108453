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
Setting the pose from outside (docs/ros_interface.md, *Setting the pose*).

Two geometry_msgs/PoseWithCovarianceStamped topics, in the ``map`` frame
(``map.frame_id``) or ``odom_frame``; the pose is the base's (``base_frame``, or the
cloud's frame without one), as RViz's "2D Pose Estimate" sends it:

- ``/initialpose``: with a map loaded (``map.load_path``) it **seeds** a relocalization:
  the odometry restarts and the next scan is relocalized against the map keyframes near
  the pose only, and accepted only within the search radius and yaw window that the
  covariance gives (``core/maps/seed.py``); the map's verdict rules apply, so a wrong seed
  is refused (``/diagnostics``: ``map.event: refused``, ``seed refused: ...``) and the node
  stays unlocalized, relocalizing every scan as at startup. Without a map it sets the
  odometry pose like ``mlsemreg/set_pose``.
- ``mlsemreg/set_pose``: **sets** the pose, unchecked. In ``odom_frame`` (or in the map
  frame without a loaded map, through ``map -> odom``) the odometry restarts at it from
  the next scan (and so does the map being built, as after a reset); in the map frame of
  a loaded map it sets ``map -> odom`` so that the current pose is the given one.

A topic, not a service: a service needs an interface package (rosidl, CMake, a C compiler
and generated type support built into the venv), which this pure-Python package does not
build (docs/ros_interface.md, *Setting the pose*, has the measurement). The callbacks only
convert and queue; the worker applies the latest request before its next scan.
"""

from __future__ import annotations

from dataclasses import dataclass
import threading
from typing import Any

from geometry_msgs.msg import PoseWithCovarianceStamped
from mlsemreg_ros.core.maps.seed import PoseSeed
from mlsemreg_ros.core.rigid import invert_transform
import numpy as np
from scipy.spatial.transform import Rotation


@dataclass(frozen=True)
class PoseRequest:
    """A pose from a topic: what to do with it and where."""

    kind: str  # 'initialpose' (seed with a map) or 'set_pose'
    frame_id: str
    T_frame_base: np.ndarray  # (4, 4)
    covariance: np.ndarray  # (6, 6) base axes, ROS order


class PoseMessageError(ValueError):
    """A pose message that cannot be used."""


def pose_request(kind: str, msg: Any) -> PoseRequest:
    """Convert a PoseWithCovarianceStamped; raise :class:`PoseMessageError` if unusable."""
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    position = np.array([p.x, p.y, p.z], dtype=np.float64)
    quaternion = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
    covariance = np.asarray(msg.pose.covariance, dtype=np.float64).reshape(6, 6)
    if not (np.all(np.isfinite(position)) and np.all(np.isfinite(quaternion))):
        raise PoseMessageError('pose holds NaN/inf')
    if not np.all(np.isfinite(covariance)):
        raise PoseMessageError('covariance holds NaN/inf')
    if abs(np.linalg.norm(quaternion) - 1.0) > 1e-2:
        raise PoseMessageError(f'orientation is not a unit quaternion: {quaternion.tolist()}')
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(quaternion).as_matrix()
    T[:3, 3] = position
    return PoseRequest(kind, msg.header.frame_id, T, covariance)


def to_sensor_axes(covariance: np.ndarray, T_base_sensor: np.ndarray) -> np.ndarray:
    """Rotate a base-axes covariance (6, 6) into the sensor's axes (no lever arm)."""
    axes = np.zeros((6, 6))
    axes[:3, :3] = axes[3:, 3:] = T_base_sensor[:3, :3].T
    return axes @ covariance @ axes.T


class PoseInput:
    """Subscribes the pose topics and applies their latest request in the worker."""

    def __init__(self, node: Any) -> None:
        """Subscribe ``/initialpose`` and ``mlsemreg/set_pose`` on ``node``."""
        self._node = node
        self._lock = threading.Lock()
        self._pending: PoseRequest | None = None
        for kind, topic in (('initialpose', '/initialpose'), ('set_pose', 'mlsemreg/set_pose')):
            node.create_subscription(
                PoseWithCovarianceStamped, topic, self._callback(kind, topic), 10
            )

    def _callback(self, kind: str, topic: str) -> Any:
        def receive(msg: PoseWithCovarianceStamped) -> None:
            try:
                request = pose_request(kind, msg)
            except PoseMessageError as error:
                self._node.get_logger().warning(f'{topic}: pose skipped: {error}')
                return
            with self._lock:
                self._pending = request  # the latest one wins
            self._node.get_logger().info(
                f'{topic}: pose in {request.frame_id!r} received; applied before the next scan'
            )

        return receive

    def take(self) -> PoseRequest | None:
        """Return the waiting request (once), or None."""
        with self._lock:
            request, self._pending = self._pending, None
            return request

    def apply(
        self,
        request: PoseRequest,
        odometry: Any,
        localization: Any,
        odom_frame: str,
        T_base_sensor: np.ndarray,
    ) -> tuple[bool, str]:
        """Apply ``request`` (worker thread); return (applied, what was done or why not)."""
        X, X_inv = T_base_sensor, invert_transform(T_base_sensor)
        frame = request.frame_id or odom_frame
        map_frame = localization.frame_id
        if frame not in (map_frame, odom_frame):
            return False, f'frame {frame!r} is neither {map_frame!r} nor {odom_frame!r}'
        covariance = to_sensor_axes(request.covariance, X)
        T_map_odom = localization.T_map_odom  # sensor odom; None while unlocalized
        loaded = localization.mode == 'localization'
        if frame == map_frame:
            T_map_sensor = request.T_frame_base @ X
        elif T_map_odom is not None:
            T_map_sensor = T_map_odom @ X_inv @ request.T_frame_base @ X
        else:
            T_map_sensor = None
        if request.kind == 'initialpose' and loaded:
            if T_map_sensor is None:
                return False, f'a seed in {odom_frame!r} needs map -> odom: use the map frame'
            restart = (
                invert_transform(T_map_odom) @ T_map_sensor
                if T_map_odom is not None
                else odometry.pose
            )
            odometry.restart_at(restart, covariance)
            seed = PoseSeed.from_covariance(T_map_sensor, request.covariance)
            localization.seed(seed)
            return True, (
                f'relocalizing the next scan around the seed (radius {seed.radius_m:.1f} m, '
                f'yaw window {np.degrees(seed.yaw_window_rad):.0f} deg)'
            )
        if frame == map_frame and loaded:
            localization.force(T_map_sensor, odometry.pose)
            return True, 'map -> odom set so that the current pose is the given one (unchecked)'
        if frame == map_frame:
            if T_map_odom is None:
                return False, 'no map -> odom yet to place a map-frame pose'
            T_odom_sensor = invert_transform(T_map_odom) @ T_map_sensor
        else:
            T_odom_sensor = X_inv @ request.T_frame_base @ X
        odometry.restart_at(T_odom_sensor, covariance)
        return True, 'the odometry restarts at the given pose from the next scan'
