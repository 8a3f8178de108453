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
Hostile input through the real node (``mlsemreg fuzz-node``): the runner of the cases.

mlsemreg_node runs in its own process with ``imu_topic`` and ``wheel_odometry_topic`` set.
Per case (``evaluation/hostile_cases.py``) a probe resets the node, publishes the case's
prior messages (a right stream with the hostile messages in place; paced, since the node's
sensor-data QoS keeps 5 messages waiting) and its hostile cloud if it has one, then three
good scans of a pair: the keyframe at ``t0`` and ``t1``, the moved scan at ``t2``.

Recorded per case: a *crash* (the node process ended; it is started again), the clouds
*answered* on ``/diagnostics`` within the timeout, the good scans *published and right* (the
first at identity, then ``T_keyframe_current`` within 5 deg / 0.6 m of identity at ``t1`` and
of the pair's truth at ``t2``), every *wrong* transform published for a good scan, and the
node's drop counts the case added.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import time
from typing import Any

from mlsemreg_ros.codec.poses import pose_message_to_matrix, transform_message_to_matrix
from mlsemreg_ros.core.metrics import rotation_error_deg, translation_error_m
from mlsemreg_ros.evaluation.hostile_cases import Case, case_streams, hostile_cloud, Timeline
import numpy as np
from scipy.spatial.transform import Rotation

#: Pause after each prior message (s): the node's subscription keeps 5 waiting.
PUBLISH_PAUSE_S = 0.001
#: Success bounds of a published pose (the node tests' and the issue's).
MAX_RE_DEG, MAX_TE_M = 5.0, 0.6
#: Counters of the node's /diagnostics that the fuzz reports per case.
COUNTED = (
    '_dropped',
    'callback_errors',
    'prior_refused',
    'deskew_refused',
    'frames_malformed',
    'errors',
)


@dataclass
class CaseResult:
    """What the node did with one case."""

    name: str
    group: str
    crashed: bool
    clouds: int  # clouds published
    answered: int  # ... answered on /diagnostics
    good: int  # good scans after the hostile input
    good_right: int  # ... published and right
    wrong: int  # transforms of good scans published outside the bounds
    counts: dict[str, int]  # what the node counted during the case
    notes: str = ''


class PriorPublisher:
    """Builds and publishes the IMU and wheel messages of a case from the probe node."""

    def __init__(self, node: Any, imu_topic: str, wheel_topic: str) -> None:
        """Create the two publishers (sensor-data QoS, as the node subscribes)."""
        from nav_msgs.msg import Odometry
        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import Imu

        self._classes = {'imu': Imu, 'wheel': Odometry}
        self.publishers = {
            'imu': node.create_publisher(Imu, imu_topic, qos_profile_sensor_data),
            'wheel': node.create_publisher(Odometry, wheel_topic, qos_profile_sensor_data),
        }

    def connected(self) -> bool:
        """Whether the node subscribes to both topics."""
        return all(p.get_subscription_count() > 0 for p in self.publishers.values())

    def publish(self, stream: str, messages: list[tuple[float, dict]]) -> None:
        """Publish the messages in order, paced."""
        build = self._imu if stream == 'imu' else self._wheel
        publisher = self.publishers[stream]
        for t, fields in messages:
            publisher.publish(build(t, fields))
            time.sleep(PUBLISH_PAUSE_S)

    def _stamp(self, msg: Any, t: float, fields: dict) -> None:
        sec, nanosec = divmod(round(fields.get('stamp_s', t) * 1e9), 10**9)
        msg.header.stamp.sec = int(fields.get('sec', sec))
        msg.header.stamp.nanosec = int(fields.get('nanosec', nanosec))

    def _imu(self, t: float, fields: dict) -> Any:
        msg = self._classes['imu']()
        self._stamp(msg, t, fields)
        msg.header.frame_id = fields.get('frame', 'velodyne')
        w, a = msg.angular_velocity, msg.linear_acceleration
        w.x, w.y, w.z = (float(v) for v in fields.get('gyro', (0.0, 0.0, 0.0)))
        a.x, a.y, a.z = (float(v) for v in fields.get('accel', (0.0, 0.0, 9.81)))
        return msg

    def _wheel(self, t: float, fields: dict) -> Any:
        msg = self._classes['wheel']()
        self._stamp(msg, t, fields)
        msg.header.frame_id, msg.child_frame_id = 'odom', 'velodyne'
        pose = fields.get('pose', np.eye(4))
        with np.errstate(all='ignore'):
            quaternion = fields.get('quaternion', Rotation.from_matrix(pose[:3, :3]).as_quat())
        position = fields.get('position', pose[:3, 3])
        o, p = msg.pose.pose.orientation, msg.pose.pose.position
        o.x, o.y, o.z, o.w = (float(v) for v in quaternion)
        p.x, p.y, p.z = (float(v) for v in position)
        return msg


def _right(estimate: np.ndarray, truth: np.ndarray) -> bool:
    re = rotation_error_deg(estimate[:3, :3], truth[:3, :3])
    te = translation_error_m(estimate[:3, 3], truth[:3, 3])
    return re <= MAX_RE_DEG and te <= MAX_TE_M


def _counts(status: dict | None) -> dict[str, int]:
    if not status:
        return {}
    out = {}
    for key, value in status.items():
        if any(word in key for word in COUNTED):
            try:
                out[key] = int(value)
            except (TypeError, ValueError):
                continue
    return out


def run_case(
    case: Case,
    pair: Any,
    timeline: Timeline,
    probe: Any,
    priors: PriorPublisher,
    alive: Callable[[], bool],
    before: dict[str, int],
    rng: np.random.Generator,
    timeout_s: float = 30.0,
    keyframe_twice: bool = True,
) -> tuple[CaseResult, dict[str, int]]:
    """
    Drive one case; return its result and the node's counts after it.

    ``keyframe_twice`` False sends the keyframe at ``t0`` and the moved scan at ``t2`` only:
    on real scans a keyframe registered onto itself (inlier fraction 1) makes the next scan
    fail the relative-inlier rule (``odometry.min_relative_inlier_fraction``), whatever the
    prior.
    """
    if not probe.reset(timeout=timeout_s):
        return CaseResult(
            case.name, case.group, not alive(), 0, 0, 3, 0, 0, {}, 'no reset'
        ), before
    for stream, messages in case_streams(case, pair.trans_gt, timeline, rng).items():
        priors.publish(stream, messages)
    clouds, answered, last = 0, 0, None
    notes = []
    moved = case.cloud is not None and case.cloud.get('moved', False)
    first = case.cloud is not None and not moved  # the hostile cloud before the scans
    if first:
        stamp = probe.stamp(timeline.t0 - timeline.interval)
        probe.publish(_hostile(probe, stamp, pair.pts_dst, pair.label_dst, case.cloud, rng))
        clouds += 1
        status = probe.status_for(stamp, timeout_s)
        if status is not None:
            answered += 1
            last = status
            notes.append(f'cloud: {status["message"][:90]}')
    good_right, wrong = 0, 0
    scans = [(pair.pts_dst, pair.label_dst)] * 2 + [(pair.pts_src, pair.label_src)]
    truths = [np.eye(4), np.eye(4), pair.trans_gt]
    for k, (t, (points, labels), truth) in enumerate(
        zip(timeline.scans, scans, truths, strict=True)
    ):
        if not keyframe_twice and (k == 1 or (k == 0 and first)):
            continue  # (the hostile cloud is the keyframe)
        stamp = probe.stamp(t)
        if moved and k == 2:  # the hostile cloud itself: answered, and right if published
            probe.publish(_hostile(probe, stamp, points, labels, case.cloud, rng))
        else:
            probe.publish(probe.cloud(points, np.asarray(labels).astype(np.uint32), stamp))
        clouds += 1
        status = probe.status_for(stamp, timeout_s)
        if status is None:
            notes.append(f'no answer at {t:.2f} s')
            continue
        answered += 1
        last = status
        if moved and k == 2:
            notes.append(f'moved scan: {status["message"][:90]}')
        if status['message'].startswith('first scan'):  # the odometry starts at identity
            truth = np.eye(4)  # (the moved scan, when the hostile keyframe was skipped)
            odometry = probe.wait_for('odometry', stamp, 5.0)
            pose = pose_message_to_matrix(odometry.pose.pose) if odometry is not None else None
            good_right += pose is not None and _right(pose, truth)
            continue
        transform = probe.wait_for('transform', stamp, 5.0) if status['level'] < 2 else None
        if transform is None:
            notes.append(f'{t:.2f} s: {status["message"][:90]}')
            continue
        if _right(transform_message_to_matrix(transform.transform), truth):
            good_right += not (moved and k == 2)
        else:
            wrong += 1
            notes.append(f'{t:.2f} s wrong: {status["message"][:90]}')
    after = _counts(last) or before
    added = {k: v - before.get(k, 0) for k, v in after.items() if v - before.get(k, 0) > 0}
    with probe._cond:  # forget what the probe received (its memory, not the node's)
        for messages in probe.received.values():
            messages.clear()
    result = CaseResult(
        case.name,
        case.group,
        not alive(),
        clouds,
        answered,
        3 - moved if keyframe_twice else 2 - moved - first,
        good_right,
        wrong,
        added,
        '; '.join(notes),
    )
    return result, after


def _hostile(
    probe: Any, stamp: Any, points: np.ndarray, labels: np.ndarray, spec: dict, rng: Any
) -> Any:
    """Return the case's cloud with a hostile time field."""
    from std_msgs.msg import Header

    header = Header(stamp=stamp, frame_id='velodyne')
    labels = np.asarray(labels).astype(np.uint32)
    return hostile_cloud(probe._msg_classes, header, points, labels, spec, rng)
