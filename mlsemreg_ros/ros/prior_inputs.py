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
The node's motion-prior inputs: IMU and wheel-odometry messages, checked and queued for the core.

The subscription callbacks (executor thread) only convert a message to numbers
(:func:`imu_sample`, :func:`wheel_sample`), check them against physical limits and the
stream's order (``core/prior_checks.py``) and append them to an inbox; a message that
cannot be used is dropped there with a reason and counted (``imu_dropped``,
``wheel_dropped`` and ``<stream>_dropped.<reason>`` in ``/diagnostics``). No callback
raises. The worker hands the inbox to the motion model in one batch right before each
scan (:meth:`PriorInbox.flush`), so the buffers of the core are touched by one thread
and a message costs no array copy. Frames (``docs/field_prior.md``): an IMU in the cloud's
frame is used as it is, one in ``base_frame`` is rotated into the sensor frame by
``T_base_sensor`` (the lever arm is ignored); wheel odometry whose child frame is
``base_frame`` is moved to the sensor with ``T_base_sensor``, one whose child is the
cloud's frame is used as it is.
"""

from __future__ import annotations

from dataclasses import dataclass
import threading
from typing import Any

from mlsemreg_ros.core.prior_checks import (
    imu_problem,
    pose_matrix,
    stamp_problem,
    StreamGate,
    wheel_jump,
    wheel_problem,
)
from mlsemreg_ros.ros.callback_guard import DropCounter
import numpy as np

#: The streams of the inbox (their ``<stream>_dropped`` counts are always published).
STREAMS = ('imu', 'wheel')


@dataclass(frozen=True)
class ImuSample:
    """One IMU message as numbers: stamp (ns), angular rate (rad/s), specific force (m/s^2)."""

    stamp_ns: int
    gyro: np.ndarray  # (3,)
    accel: np.ndarray  # (3,)
    frame_id: str


@dataclass(frozen=True)
class WheelSample:
    """One wheel-odometry message as numbers: stamp (ns) and ``T_odom_child`` (4, 4)."""

    stamp_ns: int
    pose: np.ndarray  # (4, 4)
    child_frame_id: str


def _vector(v: Any) -> np.ndarray:
    return np.array([float(v.x), float(v.y), float(v.z)], dtype=np.float64)


def imu_sample(msg: Any) -> tuple[ImuSample | None, str]:
    """
    Convert a sensor_msgs/Imu to finite numbers within the IMU limits, or give the reason.

    Never raises: a message whose fields cannot be read is ``'unreadable'``. The orientation
    and the covariances are not read (many IMUs publish no orientation).
    """
    try:
        stamp = msg.header.stamp
        stamp_ns, why = stamp_problem(stamp.sec, stamp.nanosec)
        gyro, accel = _vector(msg.angular_velocity), _vector(msg.linear_acceleration)
        frame = str(msg.header.frame_id)
    except Exception:  # any attribute or conversion error: not an IMU message we can read
        return None, 'unreadable'
    why = why or imu_problem(gyro, accel)
    if why:
        return None, why
    return ImuSample(stamp_ns, gyro, accel, frame), ''


def wheel_sample(msg: Any) -> tuple[WheelSample | None, str]:
    """Convert a nav_msgs/Odometry to a finite rigid pose, or give the reason; never raises."""
    try:
        stamp = msg.header.stamp
        stamp_ns, why = stamp_problem(stamp.sec, stamp.nanosec)
        pose = msg.pose.pose
        q = pose.orientation
        quaternion = np.array([float(q.x), float(q.y), float(q.z), float(q.w)])
        position = _vector(pose.position)
        child = str(msg.child_frame_id)
    except Exception:  # any attribute or conversion error
        return None, 'unreadable'
    why = why or wheel_problem(position, quaternion)
    if why:
        return None, why
    return WheelSample(stamp_ns, pose_matrix(position, quaternion), child), ''


class PriorInbox:
    """IMU and wheel messages waiting for the worker; frame checks and counts."""

    def __init__(self, drops: DropCounter | None = None) -> None:
        """Start empty; count the drops in ``drops`` (a new counter if None)."""
        self._lock = threading.Lock()
        self._imu: list[ImuSample] = []
        self._wheel: list[WheelSample] = []
        self.counts = {'imu': 0, 'wheel': 0}  # messages kept
        self.drops = drops if drops is not None else DropCounter()
        self._gates = {
            'imu': StreamGate(),
            'wheel': StreamGate(lambda a, b, span: wheel_jump(a, b, span)),
        }
        self._restarted: set[str] = set()  # streams whose old samples the model forgets
        self.warnings: list[str] = []  # frame mismatches, once each
        self._warned: set[str] = set()

    def on_imu(self, msg: Any) -> None:
        """Take a sensor_msgs/Imu (executor thread); drop it with a reason if unusable."""
        sample, why = imu_sample(msg)
        self._admit('imu', sample, why, self._imu, None)

    def on_wheel(self, msg: Any) -> None:
        """Take a nav_msgs/Odometry of the wheels (executor thread); drop it if unusable."""
        sample, why = wheel_sample(msg)
        self._admit('wheel', sample, why, self._wheel, 'pose')

    def _admit(
        self, stream: str, sample: Any, why: str, queue: list[Any], value: str | None
    ) -> None:
        """Queue a converted sample that keeps its stream's order, or count the drop."""
        if sample is not None:
            with self._lock:
                admission = self._gates[stream].admit(
                    sample.stamp_ns, getattr(sample, value) if value else None
                )
                why = admission.reason
                if not why:
                    if admission.restarted:
                        queue.clear()
                        self._restarted.add(stream)
                    queue.append(sample)
                    self.counts[stream] += 1
        if why:
            stamp = f'stamp {sample.stamp_ns} ns' if sample is not None else 'its stamp'
            self.drops.drop(stream, why, f'{stamp} (see docs/ros_interface.md)')

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
            restarted, self._restarted = self._restarted, set()
        if not hasattr(model, 'add_imu'):
            return
        forget = getattr(model, 'forget', None)
        for stream in sorted(restarted):
            if forget is not None:
                forget(stream)
        if imu:
            stamps = np.array([m.stamp_ns for m in imu], dtype=np.int64)
            gyro = np.array([m.gyro for m in imu], dtype=np.float64)
            accel = np.array([m.accel for m in imu], dtype=np.float64)
            rotation = self._rotation_to_sensor(
                imu[-1].frame_id, sensor_frame, base_frame, T_base_sensor
            )
            if rotation is not None:
                gyro, accel = gyro @ rotation, accel @ rotation  # R_sensor_imu v, row-wise
            self._hand_over('imu', len(imu), model.add_imu, stamps, gyro, accel)
        if wheel:
            stamps = np.array([m.stamp_ns for m in wheel], dtype=np.int64)
            poses = np.array([m.pose for m in wheel])
            child = self._child_to_sensor(
                wheel[-1].child_frame_id, sensor_frame, base_frame, T_base_sensor
            )
            self._hand_over('wheel', len(wheel), model.add_wheel, stamps, poses, child)

    def _hand_over(self, stream: str, count: int, add: Any, *arrays: Any) -> None:
        """Give the samples to the model; if it refuses them, they are dropped and counted."""
        try:
            add(*arrays)
        except Exception as error:  # checked samples: a model that refuses them is a bug
            for _ in range(count):
                self.drops.drop(stream, 'model_refused', repr(error))

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
