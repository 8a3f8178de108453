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
Node-level parameters (frames, QoS, output); no rclpy here.

The algorithm's parameters live in :mod:`mlsemreg_ros.core.config`; this module
holds only what the ROS node adds around them, with the same engine
(:class:`~mlsemreg_ros.core.config.Settings`) and
:func:`~mlsemreg_ros.core.config.param` metadata, so both are turned into ROS
parameters (with descriptors) by the same code. Flat names are
``<field>`` or ``<section>.<field>``, e.g. ``odom_frame``, ``qos.depth``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from mlsemreg_ros.core.config import param, RegistrationConfig, Settings
from mlsemreg_ros.ros.extrinsic import ExtrinsicConfig


@dataclass
class QosConfig:
    """QoS of the ``points`` subscription (read-only: set at startup)."""

    reliability: str = param(
        'best_effort',
        'best_effort: sensor-data QoS (drivers publish best effort); reliable: '
        'for bag playback or reliable publishers.',
        choices=('best_effort', 'reliable'),
    )
    depth: int = param(5, 'History depth of the points subscription.', low=1, high=1000)


@dataclass
class PathConfig:
    """The ``mlsemreg/path`` output."""

    max_length: int = param(
        10000,
        'Poses kept in mlsemreg/path; the oldest are dropped (0: unlimited).',
        low=0,
        high=10000000,
    )
    publish_period: float = param(
        1.0,
        'Minimum time between two mlsemreg/path messages; the path is published only '
        'while someone subscribes (its cost grows with its length).',
        unit='s',
        low=0.0,
        high=3600.0,
    )


#: Parameters that only take effect at startup (declared read-only).
READ_ONLY: tuple[str, ...] = (
    'qos.reliability',
    'qos.depth',
    'keep_freed_memory',
    'imu_topic',
    'wheel_odometry_topic',
    'extrinsic_source',
    *(f'T_base_sensor.{f.name}' for f in dataclasses.fields(ExtrinsicConfig)),
)


@dataclass
class NodeConfig(Settings):
    """Everything the node needs besides the core's RegistrationConfig (same engine)."""

    label_field: str = param(
        'label',
        'Name of the PointCloud2 field holding the semantic label (any integer or '
        'float datatype).',
    )
    odom_frame: str = param(
        'odom',
        'Frame of mlsemreg/odometry and mlsemreg/path (the pose of '
        'the first scan after startup or reset).',
    )
    base_frame: str = param(
        '',
        "Child frame of the odometry and TF; '' uses the cloud's frame_id. With a "
        "base_frame the published pose is the base's: T_odom_base = T_base_sensor "
        'T_odom_sensor T_base_sensor^-1 (odom: the base at the first scan; '
        'docs/field_prior.md).',
    )
    extrinsic_source: str = param(
        'parameter',
        'Where T_base_sensor comes from: parameter (the T_base_sensor.* parameters) or tf '
        "(TF's base_frame -> cloud frame transform, looked up at the first scan; without "
        'tf2_ros or before the transform exists: the parameters, with a warning; '
        'read-only).',
        choices=('parameter', 'tf'),
    )
    imu_topic: str = param(
        '',
        "sensor_msgs/Imu topic fed to the motion prior (motion_prior.*; ''"
        ': none; sensor-data QoS; read-only).',
    )
    wheel_odometry_topic: str = param(
        '',
        "nav_msgs/Odometry wheel-odometry topic fed to the motion prior (''"
        ': none; sensor-data QoS; read-only).',
    )
    publish_outliers: bool = param(
        False, 'Also draw outlier correspondences (red) in mlsemreg/correspondences.'
    )
    publish_tf: bool = param(True, 'Broadcast TF odom_frame -> base_frame (needs tf2_ros).')
    invert_tf: bool = param(
        False,
        'Broadcast base_frame -> odom_frame instead (when base_frame already has a '
        'parent in the TF tree).',
    )
    frame_change: str = param(
        'reset',
        "What a change of the clouds' frame_id does: reset (the odometry restarts "
        'in the new frame) or skip (scans in another frame are skipped).',
        choices=('reset', 'skip'),
    )
    keep_freed_memory: bool = param(
        True,
        'At startup, let glibc keep freed memory for reuse (mallopt): the per-scan '
        'temporaries stop costing page faults and the resident size stays at its working '
        'set instead of swinging by several MB (read-only).',
    )
    local_map_period: float = param(
        1.0,
        'Minimum time between two mlsemreg/local_map clouds (published only while '
        'someone subscribes; 0: never).',
        unit='s',
        low=0.0,
        high=3600.0,
    )
    publish_predicted_on_refusal: bool = param(
        True,
        'A refused scan still publishes mlsemreg/odometry and TF, from the prediction of '
        'the motion model (or the IMU) with its covariance inflated by the uncertainty of '
        'the prediction; /diagnostics says published: prediction. Never on mlsemreg/transform, '
        'never on the path.',
    )
    reset_keeps_pose: bool = param(
        False,
        'mlsemreg/reset restarts the odometry at its current pose (and covariance) instead '
        'of at identity; the keyframe and the local map are dropped either way.',
    )
    map_cloud_voxel_size: float = param(
        0.5,
        'Voxel size of the latched mlsemreg/map cloud (the map keyframes in the map frame, '
        'published on map load, save_map and loop closure; 0: not published).',
        unit='m',
        low=0.0,
        high=100.0,
    )
    qos: QosConfig = field(default_factory=QosConfig)
    path: PathConfig = field(default_factory=PathConfig)
    T_base_sensor: ExtrinsicConfig = field(default_factory=ExtrinsicConfig)  # noqa: N815, RUF100

    def check(self) -> list[str]:
        """Frame names and the label field."""
        errors = []
        if not self.label_field:
            errors.append('label_field must not be empty')
        if not self.odom_frame:
            errors.append('odom_frame must not be empty')
        for key in ('odom_frame', 'base_frame'):
            if getattr(self, key).startswith('/'):
                errors.append(
                    f"{key}={getattr(self, key)!r}: tf2 frame ids must not start with '/'"
                )
        if self.base_frame and self.base_frame == self.odom_frame:
            errors.append(f'base_frame and odom_frame are both {self.odom_frame!r}')
        if not self.base_frame and not self.T_base_sensor.is_identity():
            errors.append('T_base_sensor is set but base_frame is empty: name the base frame')
        if not self.base_frame and self.extrinsic_source == 'tf':
            errors.append('extrinsic_source: tf needs a base_frame')
        for key in ('imu_topic', 'wheel_odometry_topic'):
            if getattr(self, key).strip() != getattr(self, key):
                errors.append(f'{key}={getattr(self, key)!r}: no surrounding spaces')
        return errors


def all_parameter_fields() -> list[tuple[str, dataclasses.Field, Any]]:
    """``(flat_name, field, default)`` of every node parameter: node-level, then core."""
    return NodeConfig.parameter_fields() + RegistrationConfig.parameter_fields()
