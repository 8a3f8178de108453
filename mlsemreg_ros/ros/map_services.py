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
The node's map interface: ``map -> odom``, relocalization and saving (docs/maps.md).

The core (:class:`mlsemreg_ros.core.maps.localization.MapLocalization`) owns the state; this
layer converts and publishes:

- publishes ``mlsemreg/map_pose`` (geometry_msgs/TransformStamped ``T_map_odom``: header
  ``map.frame_id``, child ``odom_frame``, stamped with the scan that gave it; every scan
  while localized) and ``mlsemreg/map_path`` (nav_msgs/Path of the keyframes in the map
  frame, after every new keyframe or loop closure while mapping);
- broadcasts TF ``map.frame_id -> odom_frame`` with the same transform (tf2_ros);
- publishes ``mlsemreg/map`` (sensor_msgs/PointCloud2 in the map frame, latched: transient
  local, so a late subscriber gets the last one): every keyframe moved by its pose,
  voxelised to ``map_cloud_voxel_size``, with ``intensity`` and ``label`` fields (the
  points of ``mlsemreg map export``: ``core/maps/point_map.py``); on map load, on
  ``save_map`` and on every loop closure;
- serves ``mlsemreg/relocalize`` (std_srvs/Trigger: relocalize the next scan against the
  keyframes without an initial guess) and ``mlsemreg/save_map`` (std_srvs/Trigger: write
  the map folder to ``map.save_path``).

``map.load_path`` is read at startup: with a map the node starts unlocalized (no
``map_pose``) and relocalizes every scan until one is accepted.
"""

from __future__ import annotations

from typing import Any

from geometry_msgs.msg import TransformStamped
from mlsemreg_ros.codec.pointcloud2 import arrays_to_pointcloud2
from mlsemreg_ros.core.maps.localization import LocalizationUpdate, MapLocalization
from mlsemreg_ros.core.maps.map_io import load_store, MapError
from mlsemreg_ros.core.maps.point_map import export_points
from mlsemreg_ros.core.rigid import invert_transform
from mlsemreg_ros.ros import messages
from nav_msgs.msg import Path
import numpy as np
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header
from std_srvs.srv import Trigger


class MapServices:
    """Map topics and services of a node around its odometry."""

    def __init__(self, node: Any, odometry: Any, config: Any, tf: Any = None) -> None:
        """Load ``map.load_path`` (if set) and create the topics and services on ``node``."""
        self.node = node
        self.odometry = odometry
        self.tf = tf
        self.T_base_sensor = np.eye(4)  # the odom frame is the base's (ros/extrinsic.py)
        core = config.core
        registration = odometry.registration
        store = None
        if core.map.load_path:
            try:
                store, data = load_store(core.map.load_path, core, registration.label_map)
            except MapError as error:
                node.get_logger().error(f'map.load_path: {error}; mapping from scratch instead')
            else:
                node.get_logger().info(
                    f'loaded the map {core.map.load_path} ({len(store)} keyframes, frame '
                    f'{data.frame_id!r}): unlocalized until a scan relocalizes'
                )
        self.localization = MapLocalization(registration, store, core.map.frame_id)
        self.localization.prepare_map()  # map.prepare_on_load, on a background thread
        self._pub_pose = node.create_publisher(TransformStamped, 'mlsemreg/map_pose', 10)
        self._pub_path = node.create_publisher(Path, 'mlsemreg/map_path', 1)
        node.create_service(Trigger, 'mlsemreg/relocalize', self._on_relocalize)
        node.create_service(Trigger, 'mlsemreg/save_map', self._on_save)
        latched = QoSProfile(
            depth=1,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
            reliability=ReliabilityPolicy.RELIABLE,
        )
        self._pub_map = node.create_publisher(PointCloud2, 'mlsemreg/map', latched)
        self._map_voxel_size = config.node.map_cloud_voxel_size
        if store is not None:
            self.publish_map(node.get_clock().now().to_msg())

    def close(self) -> None:
        """Stop the map's background preparation (the node shuts down)."""
        self.localization.close()

    def after_step(self, scan: Any, step: Any, config: Any) -> LocalizationUpdate:
        """Update ``map -> odom`` with one odometry step and publish it (worker thread)."""
        localization = self.localization
        if localization.store.config is not config.core:
            localization.store.config = config.core
        if step.source == 'first' and step.index == 0:
            localization.reset()  # the odometry (re)started at identity
        update = localization.update(
            self.odometry, step, scan.xyz, scan.labels, getattr(scan, 'point_times', None)
        )
        if update.message and update.event in ('relocalized', 'recovered', 'loop'):
            self.node.get_logger().info(update.message)
        elif update.event == 'refused':
            self.node.get_logger().info(
                f'not localized: {update.message}', throttle_duration_sec=5.0
            )
        if update.T_map_odom is not None:
            self._publish(scan.stamp, update.T_map_odom, config.node.odom_frame, config)
        if localization.mode == 'mapping' and (update.event == 'loop' or step.new_keyframe):
            self._publish_path(scan.stamp)
        self._map_voxel_size = config.node.map_cloud_voxel_size
        if update.event == 'loop':
            self.publish_map(scan.stamp)
        return update

    def _publish(self, stamp: Any, T_map_odom: Any, odom_frame: str, config: Any) -> None:
        T_map_odom = T_map_odom @ invert_transform(self.T_base_sensor)  # odom at the base
        msg = messages.transform_msg(stamp, self.localization.frame_id, odom_frame, T_map_odom)
        self._pub_pose.publish(msg)
        if self.tf is not None and config.node.publish_tf:
            self.tf.sendTransform(msg)

    def publish_map(self, stamp: Any) -> int:
        """Publish the latched ``mlsemreg/map`` cloud; return its points (0: off or empty)."""
        if self._map_voxel_size <= 0:
            return 0
        with self.localization.lock:
            cloud = export_points(list(self.localization.store), self._map_voxel_size)
        if cloud.points.shape[0] == 0:
            return 0
        header = Header(stamp=stamp, frame_id=self.localization.frame_id)
        self._pub_map.publish(
            arrays_to_pointcloud2(
                PointCloud2, PointField, header, cloud.points, cloud.labels, cloud.intensity
            )
        )
        return int(cloud.points.shape[0])

    def _publish_path(self, stamp: Any) -> None:
        if self._pub_path.get_subscription_count() == 0:
            return
        frame = self.localization.frame_id
        path = Path(header=Header(stamp=stamp, frame_id=frame))
        with self.localization.lock:
            path.poses = [
                messages.pose_stamped(stamp, frame, k.T_map_keyframe)
                for k in self.localization.store
            ]
        self._pub_path.publish(path)

    def _on_relocalize(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        localization = self.localization
        if len(localization.store) == 0:
            response.success, response.message = False, 'no keyframes to relocalize against'
            return response
        localization.request_relocalization()
        response.success = True
        response.message = (
            f'the next scan is relocalized against {len(localization.store)} keyframes'
        )
        return response

    def _on_save(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        path = self.localization.registration.config.map.save_path
        if not path:
            response.success, response.message = False, 'map.save_path is not set'
            return response
        try:
            written = self.localization.save(path)
        except MapError as error:
            response.success, response.message = False, str(error)
            return response
        response.success = True
        response.message = f'saved {len(self.localization.store)} keyframes to {written}'
        self.publish_map(self.node.get_clock().now().to_msg())
        self.node.get_logger().info(response.message)
        return response
