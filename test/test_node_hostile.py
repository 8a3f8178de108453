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
Hostile IMU and wheel messages through the real rclpy node (issue 34).

The node runs with ``imu_topic`` and ``wheel_odometry_topic`` set (as test/test_node.py
runs it, in a private rclpy context). Each case publishes a prior stream that is right
(the gyro of the pair's rotation, wheel poses of its motion) with a hostile message in it,
then three good scans (the keyframe twice, then the moved scan of a synthetic pair), and
checks that the moved scan is published and right, that the hostile message was dropped
for its reason and counted in ``/diagnostics``, and that no callback raised.
"""

from __future__ import annotations

import itertools
from typing import Any

from mlsemreg_ros.core.metrics import rotation_error_deg, translation_error_m
from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair
from mlsemreg_ros.ros.probe import node_and_probe, to_stamp
import numpy as np
import pytest
from ros_domains import domain_id
from scipy.spatial.transform import Rotation

pytestmark = pytest.mark.usefixtures('rclpy_module')  # skip without rclpy (conftest.py)

DOMAIN_ID = domain_id('node_hostile')
TIMEOUT_S = 60.0
SCAN_S = 0.1
IMU_S = 0.005  # 200 Hz
_scans = itertools.count(1000)  # 100 s on: after test_node's stamps in the same process


@pytest.fixture(scope='module')
def ros() -> Any:
    args = ['--ros-args', '-p', 'keypoints.count:=1500']
    args += ['-p', 'imu_topic:=imu/data', '-p', 'wheel_odometry_topic:=wheel/odometry']
    with node_and_probe(DOMAIN_ID, args) as (node, probe):
        from nav_msgs.msg import Odometry
        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import Imu

        publishers = {
            'imu': probe.node.create_publisher(Imu, 'imu/data', qos_profile_sensor_data),
            'wheel': probe.node.create_publisher(
                Odometry, 'wheel/odometry', qos_profile_sensor_data
            ),
        }
        assert probe.wait_until(
            lambda: all(p.get_subscription_count() for p in publishers.values()), 20.0
        )
        yield node, probe, publishers


def _imu(t: float, gyro: Any, accel: Any = (0.0, 0.0, 9.81), nanosec: int | None = None) -> Any:
    from sensor_msgs.msg import Imu

    msg = Imu()
    msg.header.stamp = to_stamp(t)
    if nanosec is not None:
        msg.header.stamp.nanosec = nanosec
    msg.header.frame_id = 'velodyne'
    w, a = msg.angular_velocity, msg.linear_acceleration
    w.x, w.y, w.z = (float(v) for v in gyro)
    a.x, a.y, a.z = (float(v) for v in accel)
    return msg


def _wheel(t: float, pose: np.ndarray, quaternion: Any = None) -> Any:
    from nav_msgs.msg import Odometry

    msg = Odometry()
    msg.header.stamp = to_stamp(t)
    msg.header.frame_id = 'odom'
    msg.child_frame_id = 'velodyne'
    q = Rotation.from_matrix(pose[:3, :3]).as_quat() if quaternion is None else quaternion
    o, p = msg.pose.pose.orientation, msg.pose.pose.position
    o.x, o.y, o.z, o.w = (float(v) for v in q)
    p.x, p.y, p.z = (float(v) for v in pose[:3, 3])
    return msg


def _publish(node: Any, publisher: Any, stream: str, messages: list[Any]) -> None:
    """Publish one by one, each until the node kept or dropped it (sensor QoS keeps 5)."""
    inbox, drops = node._prior, node.callback_drops

    def seen() -> int:
        return inbox.counts[stream] + drops.count(f'{stream}_dropped')

    for msg in messages:
        before = seen()
        for _ in range(3):  # best effort: publish again if it was lost
            publisher.publish(msg)
            deadline = 2.0
            if _wait(lambda b=before: seen() > b, deadline):
                break


def _wait(predicate: Any, timeout: float) -> bool:
    import time

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.002)
    return False


def _scan_times() -> list[float]:
    """Return the stamps (s) of the three scans of a case."""
    return [next(_scans) * SCAN_S for _ in range(3)]


def _true_motion(pair: Any, times: list[float]) -> tuple[np.ndarray, Any]:
    """Return the gyro rate (rad/s) of the pair's rotation over the last interval, and poses."""
    rate = Rotation.from_matrix(pair.trans_gt[:3, :3]).as_rotvec() / SCAN_S

    def pose(t: float) -> np.ndarray:
        s = float(np.clip((t - times[1]) / SCAN_S, 0.0, 1.0))
        out = np.eye(4)
        out[:3, :3] = Rotation.from_rotvec(rate * SCAN_S * s).as_matrix()
        out[:3, 3] = pair.trans_gt[:3, 3] * s
        return out

    return rate, pose


def _send_scans(probe: Any, pair: Any, times: list[float]) -> dict:
    """Publish the keyframe twice, then the moved scan; return the moved scan's status."""
    clouds = [(pair.pts_dst, pair.label_dst)] * 2 + [(pair.pts_src, pair.label_src)]
    status = {}
    for t, (points, labels) in zip(times, clouds, strict=True):
        stamp = to_stamp(t)
        probe.publish(probe.cloud(points, np.asarray(labels).astype(np.uint32), stamp))
        status = probe.status_for(stamp, TIMEOUT_S)
        assert status is not None, f'no diagnostics for the scan at {t:.1f} s'
    return status


def _assert_right(probe: Any, pair: Any, t: float, status: dict) -> None:
    assert status['level'] in (0, 1) and 'registered' in status['message'], status['message']
    msg = probe.wait_for('transform', to_stamp(t), 5.0)
    assert msg is not None, 'the good scan after the hostile input was not published'
    q, p = msg.transform.rotation, msg.transform.translation
    estimate = np.eye(4)
    estimate[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    estimate[:3, 3] = [p.x, p.y, p.z]
    re = rotation_error_deg(estimate[:3, :3], pair.trans_gt[:3, :3])
    te = translation_error_m(estimate[:3, 3], pair.trans_gt[:3, 3])
    assert re <= 5.0 and te <= 0.6, f'RE {re:.2f} deg, TE {te:.3f} m'


def _imu_stream(rate: np.ndarray, times: list[float]) -> list[tuple[float, Any]]:
    """Return (t, message) of a 200 Hz IMU over the three scans: the pair's rotation rate."""
    stamps = np.arange(times[0] - 0.05, times[2] + 0.05 + 1e-9, IMU_S)
    gyro = [rate if times[1] < t <= times[2] else np.zeros(3) for t in stamps]
    return [(float(t), _imu(float(t), g)) for t, g in zip(stamps, gyro, strict=True)]


def _start(ros: Any, seed: int) -> tuple[Any, Any, Any, Any, list[float], np.ndarray, Any]:
    """Reset the node; return it, the probe, the publishers, a pair, its times and motion."""
    node, probe, publishers = ros
    assert probe.reset()
    pair = synthetic_pair(seed=seed)
    times = _scan_times()
    rate, pose = _true_motion(pair, times)
    return node, probe, publishers, pair, times, rate, pose


def test_a_zero_quaternion_wheel_message_is_dropped_and_the_next_scans_are_right(ros: Any) -> None:
    node, probe, publishers, pair, times, _, pose = _start(ros, 0)
    stamps = np.arange(times[0] - 0.05, times[2] + 0.05 + 1e-9, 0.05)  # 20 Hz
    messages = [_wheel(float(t), pose(float(t))) for t in stamps]
    messages.insert(3, _wheel(float(stamps[2]) + 0.01, np.eye(4), (0.0, 0.0, 0.0, 0.0)))
    messages.insert(6, _wheel(float(stamps[4]) + 0.01, np.eye(4), (0.0, 0.0, 0.0, 1e-300)))
    _publish(node, publishers['wheel'], 'wheel', messages)
    status = _send_scans(probe, pair, times)
    _assert_right(probe, pair, times[2], status)
    assert int(status['wheel_dropped.zero_quaternion']) == 2
    assert int(status['callback_errors']) == 0  # dropped by the checks, not by the guard


def test_a_nan_imu_message_is_dropped_and_the_next_scans_are_right(ros: Any) -> None:
    node, probe, publishers, pair, times, rate, _ = _start(ros, 1)
    stream = _imu_stream(rate, times)
    middle = times[1] + 0.5 * SCAN_S + 0.001  # within the moved scan's interval
    hostile = [
        (middle, _imu(middle, (float('nan'), 0.0, 0.0))),
        (middle + 0.001, _imu(middle + 0.001, (0.0, 0.0, 0.0), (float('inf'), 0.0, 9.81))),
        (middle + 0.002, _imu(middle + 0.002, (1e6, 0.0, 0.0))),
    ]
    messages = [m for _, m in sorted(stream + hostile, key=lambda item: item[0])]
    _publish(node, publishers['imu'], 'imu', messages)
    status = _send_scans(probe, pair, times)
    _assert_right(probe, pair, times[2], status)
    for reason in ('nonfinite_gyro', 'nonfinite_accel', 'gyro_limit'):
        assert int(status[f'imu_dropped.{reason}']) >= 1, reason
    assert int(status['callback_errors']) == 0


def test_an_imu_burst_with_duplicated_stamps_does_not_bend_the_next_scans(ros: Any) -> None:
    node, probe, publishers, pair, times, rate, _ = _start(ros, 2)
    before = node.callback_drops.count('imu_dropped.duplicate_stamp')
    stream = _imu_stream(rate, times)
    burst_at = times[1] + 0.5 * SCAN_S + 0.0025  # between two samples of the stream
    rng = np.random.default_rng(34)  # within the gyro limit: only the stamps are wrong
    burst = [(burst_at, _imu(burst_at, rng.uniform(-20.0, 20.0, 3))) for _ in range(100)]
    bad_stamps = [  # stamp 0 and nanosec 2^32 - 1 among them
        (burst_at + 0.001, _imu(0.0, (5.0, 0.0, 0.0))),
        (burst_at + 0.001, _imu(burst_at, (5.0, 0.0, 0.0), nanosec=2**32 - 1)),
    ]
    timeline = sorted(stream + bad_stamps, key=lambda item: item[0])
    cut = next(k for k, (t, _) in enumerate(timeline) if t > burst_at)
    messages = [m for _, m in timeline[:cut]] + [m for _, m in burst + timeline[cut:]]
    _publish(node, publishers['imu'], 'imu', messages)
    status = _send_scans(probe, pair, times)
    _assert_right(probe, pair, times[2], status)
    duplicates = node.callback_drops.count('imu_dropped.duplicate_stamp') - before
    assert duplicates >= 99  # (and a copy the probe published again, if one was late)
    assert int(status['imu_dropped.zero_stamp']) >= 1
    assert int(status['imu_dropped.bad_nanosec']) >= 1
    assert int(status['callback_errors']) == 0
