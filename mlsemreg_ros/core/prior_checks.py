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
Sanity of motion-prior samples at arrival, against physical limits (ROS-free).

One IMU or wheel-odometry sample that cannot be right is dropped where it arrives, with a
reason; the samples that remain make the prior (``core/motion_prior.py``). The limits
(``docs/ros_interface.md``, *What the node drops*):

- every value finite; a stamp after 0 (0 means unset) with ``nanosec`` below 10^9;
- IMU: angular rate at most :data:`MAX_GYRO_RAD_S` (35 rad/s, above the +-2000 deg/s = 34.9
  rad/s full scale of common MEMS gyros), specific force at most :data:`MAX_ACCEL_M_S2`
  (16 g, the widest common accelerometer range);
- wheel odometry: an orientation quaternion of unit norm within
  :data:`QUATERNION_NORM_TOLERANCE` (zero, denormal and far-from-unit norms are dropped);
  between two kept poses at most :data:`MAX_WHEEL_SPEED_M_S` (70 m/s, 252 km/h) plus
  :data:`WHEEL_JUMP_SLACK_M`, and a heading change at most :data:`MAX_GYRO_RAD_S` times
  the interval plus :data:`WHEEL_TURN_SLACK_RAD`;
- per stream (:class:`StreamGate`): stamps strictly increasing (a duplicate or backward
  stamp is dropped), no jump forward of more than :data:`MAX_STREAM_GAP_S`. A stream that
  really restarted (a bag looping, a driver restarted, a wheel odometry reset to the
  origin) is followed after :data:`RESTART_RUN` consecutive samples consistent with one
  another but not with the old stream; those samples are dropped, and the model forgets
  the old stream.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

STANDARD_GRAVITY = 9.80665
#: The largest angular rate (rad/s) an IMU sample may hold.
MAX_GYRO_RAD_S = 35.0
#: The largest specific force (m/s^2) an IMU sample may hold: 16 g.
MAX_ACCEL_M_S2 = 16.0 * STANDARD_GRAVITY
#: A quaternion whose norm is further than this from 1 is not an orientation.
QUATERNION_NORM_TOLERANCE = 0.01
#: The highest speed (m/s) between two wheel poses.
MAX_WHEEL_SPEED_M_S = 70.0
#: ... plus this distance (m): the noise of two close poses.
WHEEL_JUMP_SLACK_M = 0.5
#: ... and a heading change of at most MAX_GYRO_RAD_S per second plus this (rad).
WHEEL_TURN_SLACK_RAD = 0.1
#: The longest forward gap (s) within a stream; a later sample starts a candidate restart.
MAX_STREAM_GAP_S = 5.0
#: Consecutive samples consistent with one another that restart a stream.
RESTART_RUN = 10
#: Reasons for a stamp (the same words for every stream).
STAMP_PROBLEMS = ('zero_stamp', 'negative_stamp', 'bad_nanosec')

NS_PER_S = 1_000_000_000


def stamp_problem(sec: Any, nanosec: Any) -> tuple[int, str]:
    """Return ``(stamp_ns, '')`` of a ``builtin_interfaces/Time``, or ``(0, reason)``."""
    sec, nanosec = int(sec), int(nanosec)
    if not 0 <= nanosec < NS_PER_S:
        return 0, 'bad_nanosec'
    if sec < 0:
        return 0, 'negative_stamp'
    stamp = sec * NS_PER_S + nanosec
    if stamp == 0:
        return 0, 'zero_stamp'
    return stamp, ''


def safe_norm(vector: np.ndarray) -> float:
    """Return the Euclidean norm of a finite vector without overflow (1e300 stays 1e300)."""
    v = np.asarray(vector, dtype=np.float64)
    largest = float(np.max(np.abs(v))) if v.size else 0.0
    if largest == 0.0:
        return 0.0
    return largest * float(np.sqrt(np.sum((v / largest) ** 2)))


def imu_problem(gyro: np.ndarray, accel: np.ndarray) -> str:
    """Why an IMU sample (rad/s, m/s^2; 3 each) cannot be right ('' if it can)."""
    if not np.all(np.isfinite(gyro)):
        return 'nonfinite_gyro'
    if not np.all(np.isfinite(accel)):
        return 'nonfinite_accel'
    if safe_norm(gyro) > MAX_GYRO_RAD_S:
        return 'gyro_limit'
    if safe_norm(accel) > MAX_ACCEL_M_S2:
        return 'accel_limit'
    return ''


def quaternion_problem(quaternion: np.ndarray) -> str:
    """Why ``(x, y, z, w)`` is not an orientation ('' if it is, to within the tolerance)."""
    q = np.asarray(quaternion, dtype=np.float64)
    if not np.all(np.isfinite(q)):
        return 'nonfinite_orientation'
    norm = safe_norm(q)
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        return 'zero_quaternion' if norm < QUATERNION_NORM_TOLERANCE else 'nonunit_quaternion'
    return ''


def pose_matrix(position: np.ndarray, quaternion: np.ndarray) -> np.ndarray:
    """Return the 4x4 pose of a position and a unit quaternion ``(x, y, z, w)`` (normalised)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(np.asarray(quaternion, dtype=np.float64)).as_matrix()
    T[:3, 3] = position
    return T


def wheel_problem(position: np.ndarray, quaternion: np.ndarray) -> str:
    """Why a wheel pose cannot be right ('' if it can): non-finite or not an orientation."""
    if not np.all(np.isfinite(np.asarray(position, dtype=np.float64))):
        return 'nonfinite_position'
    return quaternion_problem(quaternion)


def wheel_jump(previous: np.ndarray, pose: np.ndarray, span_s: float) -> str:
    """Why ``pose`` cannot follow ``previous`` after ``span_s`` seconds ('' if it can)."""
    distance = float(np.linalg.norm(pose[:3, 3] - previous[:3, 3]))
    if distance > MAX_WHEEL_SPEED_M_S * span_s + WHEEL_JUMP_SLACK_M:
        return 'pose_jump'
    cosine = 0.5 * (float(np.trace(previous[:3, :3].T @ pose[:3, :3])) - 1.0)
    turn = float(np.arccos(np.clip(cosine, -1.0, 1.0)))
    if turn > MAX_GYRO_RAD_S * span_s + WHEEL_TURN_SLACK_RAD:
        return 'pose_jump'
    return ''


@dataclass
class Admission:
    """What :meth:`StreamGate.admit` decided about one sample."""

    reason: str = ''  # why it is dropped ('' : kept)
    restarted: bool = False  # kept as the first sample of a new stream: forget the old one


class StreamGate:
    """
    The order of one stream's samples: duplicates, backward stamps and jumps are dropped.

    ``consistent(previous_value, value, span_s) -> reason`` checks two samples beyond
    their stamps (the wheels' plausible speed); None checks stamps only. Samples that
    fail against the stream but agree with one another (:data:`RESTART_RUN` in a row) are
    a new stream: the last of them is kept with ``restarted``.
    """

    def __init__(
        self,
        consistent: Callable[[Any, Any, float], str] | None = None,
        restart_run: int = RESTART_RUN,
        max_gap_s: float = MAX_STREAM_GAP_S,
    ) -> None:
        """Start with no sample."""
        self._consistent = consistent
        self._restart_run = max(int(restart_run), 1)
        self._max_gap_ns = round(max_gap_s * NS_PER_S)
        self.last: tuple[int, Any] | None = None
        self._run: list[tuple[int, Any]] = []

    def admit(self, stamp_ns: int, value: Any = None) -> Admission:
        """Keep or drop the sample at ``stamp_ns`` (valid on its own) with ``value``."""
        reason = self._after(self.last, stamp_ns, value)
        if not reason:
            self.last, self._run = (stamp_ns, value), []
            return Admission()
        if self._run and not self._after(self._run[-1], stamp_ns, value):
            self._run.append((stamp_ns, value))
        else:
            self._run = [(stamp_ns, value)]
        if len(self._run) >= self._restart_run:
            self.last, self._run = (stamp_ns, value), []
            return Admission(restarted=True)
        return Admission(reason)

    def _after(self, previous: tuple[int, Any] | None, stamp_ns: int, value: Any) -> str:
        """Why the sample cannot follow ``previous`` ('' if it can)."""
        if previous is None:
            return ''
        gap = stamp_ns - previous[0]
        if gap == 0:
            return 'duplicate_stamp'
        if gap < 0:
            return 'backwards_stamp'
        if gap > self._max_gap_ns:
            return 'stamp_jump'
        if self._consistent is not None:
            return self._consistent(previous[1], value, gap * 1e-9)
        return ''
