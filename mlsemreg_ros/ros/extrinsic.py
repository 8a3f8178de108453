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
The sensor extrinsic ``T_base_sensor`` and the odometry moved from the sensor to the base.

The odometry estimates ``T_odom_sensor`` (odom: the sensor at the first scan). The node
publishes the base instead, as KISS-ICP does (``docs/field_prior.md``)::

    T_odom_base = X @ T_odom_sensor @ X^-1      X = T_base_sensor

so the odom frame is the base at the first scan. A body twist and a covariance (ROS order
``[x, y, z, roll, pitch, yaw]``) move with the adjoint of ``X``. No rclpy here; the TF
lookup imports tf2_ros only when asked (:func:`lookup_extrinsic`).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any

from mlsemreg_ros.codec.poses import transform_message_to_matrix
from mlsemreg_ros.core.rigid import invert_transform
from mlsemreg_ros.core.settings import param
import numpy as np
from scipy.spatial.transform import Rotation

_LENGTH = {'unit': 'm', 'low': -100.0, 'high': 100.0}
_ANGLE = {'unit': 'rad', 'low': -2.0 * math.pi, 'high': 2.0 * math.pi}


@dataclass
class ExtrinsicConfig:
    """``T_base_sensor``: the sensor's pose in ``base_frame`` (read-only: set at startup)."""

    x: float = param(0.0, 'Sensor position in base_frame, x.', **_LENGTH)
    y: float = param(0.0, 'Sensor position in base_frame, y.', **_LENGTH)
    z: float = param(0.0, 'Sensor position in base_frame, z.', **_LENGTH)
    roll: float = param(0.0, 'Sensor roll about the base x axis (fixed-axis x-y-z).', **_ANGLE)
    pitch: float = param(0.0, 'Sensor pitch about the base y axis.', **_ANGLE)
    yaw: float = param(0.0, 'Sensor yaw about the base z axis.', **_ANGLE)

    def matrix(self) -> np.ndarray:
        """Return ``T_base_sensor`` (4, 4): ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (REP 103)."""
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler('xyz', [self.roll, self.pitch, self.yaw]).as_matrix()
        T[:3, 3] = [self.x, self.y, self.z]
        return T

    def is_identity(self) -> bool:
        """Tell whether every field is zero."""
        return not any((self.x, self.y, self.z, self.roll, self.pitch, self.yaw))


def adjoint(T: np.ndarray) -> np.ndarray:
    """Return the (6, 6) adjoint of ``T`` for twists ``[v, w]``: ``v' = R v + t x R w``."""
    R, t = T[:3, :3], T[:3, 3]
    skew = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    out = np.zeros((6, 6))
    out[:3, :3] = R
    out[:3, 3:] = skew @ R
    out[3:, 3:] = R
    return out


@dataclass(frozen=True)
class BaseOutput:
    """A step's pose, covariance, twist and twist covariance moved to the base."""

    pose: np.ndarray
    covariance: np.ndarray
    twist: np.ndarray
    twist_covariance: np.ndarray


def to_base(
    X: np.ndarray,
    pose: np.ndarray,
    covariance: np.ndarray,
    twist: np.ndarray,
    twist_covariance: np.ndarray,
) -> BaseOutput:
    """Move ``T_odom_sensor`` and its twist to ``T_odom_base`` (``X = T_base_sensor``)."""
    A = adjoint(X)
    return BaseOutput(
        X @ pose @ invert_transform(X),
        A @ covariance @ A.T,
        A @ twist,
        A @ twist_covariance @ A.T,
    )


def tf_available() -> bool:
    """Tell whether tf2_ros can be imported."""
    try:
        import tf2_ros  # noqa: F401
    except ImportError:
        return False
    return True


def lookup_extrinsic(buffer: Any, base_frame: str, sensor_frame: str) -> np.ndarray | None:
    """Return ``T_base_sensor`` from a tf2 buffer (None when not yet available)."""
    from rclpy.time import Time

    try:
        stamped = buffer.lookup_transform(base_frame, sensor_frame, Time())
    except Exception:  # tf2 raises its own lookup, connectivity and extrapolation errors
        return None
    return transform_message_to_matrix(stamped.transform)


class ExtrinsicSource:
    """
    ``T_base_sensor`` for the node: the parameters, or TF's static transform.

    With ``extrinsic_source: tf`` and tf2_ros importable, a tf2 buffer and listener are
    created on ``node`` and the transform ``base_frame -> sensor frame`` is looked up until
    it is found (then kept: a mounted sensor does not move). Until then, and without
    tf2_ros, the parameters hold, with a warning (``warnings``, logged by the node).
    """

    def __init__(self, node: Any, config: Any) -> None:
        """Read ``config`` (NodeConfig) and, for tf, start listening on ``node``."""
        self.base_frame = config.base_frame
        self.parameter = config.T_base_sensor.matrix()
        self.source = config.extrinsic_source
        self.warnings: list[str] = []
        self._buffer = None
        self._found: dict[str, np.ndarray] = {}
        if self.source == 'tf':
            if tf_available():
                from tf2_ros import Buffer, TransformListener

                self._buffer = Buffer()
                self._listener = TransformListener(self._buffer, node)
            else:
                self.warnings.append(
                    'extrinsic_source is tf but tf2_ros is not importable: using the '
                    'T_base_sensor parameters'
                )

    def matrix(self, sensor_frame: str) -> np.ndarray:
        """Return ``T_base_sensor`` for clouds in ``sensor_frame`` (identity without a base)."""
        if not self.base_frame:
            return np.eye(4)
        if self._buffer is None:
            return self.parameter
        if sensor_frame not in self._found:
            found = lookup_extrinsic(self._buffer, self.base_frame, sensor_frame)
            if found is None:
                self.warnings.append(
                    f'no TF {self.base_frame} -> {sensor_frame} yet: using the T_base_sensor '
                    'parameters'
                )
                return self.parameter
            self._found[sensor_frame] = found
        return self._found[sensor_frame]
