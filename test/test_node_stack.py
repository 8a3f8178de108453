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
mlsemreg_node's continuous output with the real rclpy (ros/outputs.py).

A refused scan still publishes odometry from the core's prediction with an inflated
covariance (and nothing on ``mlsemreg/transform``); ``mlsemreg/cloud_registered`` carries
the scan in ``odom``; the ``/diagnostics`` heartbeat says ``no input for N s``. The scans
are one synthetic street seen from a sensor that drives 0.5 m per 0.1 s along x; the
refused scan is uniform noise.
"""

from __future__ import annotations

import itertools
from typing import Any

from mlsemreg_ros.codec.pointcloud2 import pointcloud2_to_arrays
from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair
from mlsemreg_ros.ros.probe import node_and_probe, NodeProbe, to_stamp
import numpy as np
from pose_messages import pose_message, pose_of, publish_pose, yawed
import pytest
from ros_domains import domain_id
from scipy.spatial import cKDTree

pytestmark = pytest.mark.usefixtures('rclpy_module')  # skip without rclpy (conftest.py)

DOMAIN_ID = domain_id('node_stack')
TIMEOUT_S = 60.0
STEP_M = 0.5  # the sensor's motion per scan along x
_stamps = itertools.count(100)


@pytest.fixture(scope='module')
def ros() -> Any:
    from sensor_msgs.msg import PointCloud2

    args = ['--ros-args', '-p', 'keypoints.count:=1500']
    with node_and_probe(DOMAIN_ID, args) as (node, probe):
        probe.received['cloud_registered'] = []
        probe.node.create_subscription(
            PointCloud2, 'mlsemreg/cloud_registered', probe._recorder('cloud_registered'), 10
        )
        yield node, probe


@pytest.fixture(scope='module')
def street() -> tuple[np.ndarray, np.ndarray]:
    pair = synthetic_pair(seed=0)
    return pair.pts_dst, pair.label_dst.astype(np.uint32)


@pytest.fixture
def probe(ros: Any) -> NodeProbe:
    _, probe = ros
    assert probe.reset()
    assert all(r.successful for r in probe.set_parameters({'publish_predicted_on_refusal': True}))
    return probe


def send(probe: NodeProbe, points: np.ndarray, labels: np.ndarray) -> tuple[Any, dict]:
    stamp = to_stamp(next(_stamps) * 0.1)
    probe.publish(probe.cloud(points, labels, stamp))
    status = probe.status_for(stamp, TIMEOUT_S)
    assert status is not None, 'no diagnostics for the scan'
    return stamp, status


def drive(probe: NodeProbe, street: tuple[np.ndarray, np.ndarray], scans: int) -> list[Any]:
    """Send the street from x = 0, STEP_M, ...; every scan must be accepted."""
    points, labels = street
    stamps = []
    for k in range(scans):
        stamp, status = send(probe, points - [k * STEP_M, 0.0, 0.0], labels)
        assert status['level'] == 0, status['message']
        stamps.append(stamp)
    return stamps


def noise(street: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    labels = rng.choice(np.unique(street[1]), 3000).astype(np.uint32)
    return rng.uniform(-30.0, 30.0, (3000, 3)), labels


def covariance(msg: Any) -> np.ndarray:
    return np.asarray(msg.pose.covariance).reshape(6, 6)


def test_a_refused_scan_publishes_the_predicted_odometry_with_inflated_covariance(
    probe: NodeProbe, street: Any
) -> None:
    stamps = drive(probe, street, 4)
    last = probe.wait_for('odometry', stamps[-1], 5.0)
    assert last is not None
    stamp, status = send(probe, *noise(street))
    assert status['level'] == 1 and 'frame rejected' in status['message'], status['message']
    assert status['published'] == 'prediction', status
    assert 'from the prediction' in status['message']
    msg = probe.wait_for('odometry', stamp, 5.0)
    assert msg is not None, 'no odometry for the refused scan'
    position = msg.pose.pose.position
    expected_x = 4 * STEP_M  # constant velocity: one more step
    assert abs(position.x - expected_x) < 0.1 and abs(position.y) < 0.1, position
    before, after = np.diag(covariance(last)), np.diag(covariance(msg))
    assert np.all(after > before), (before, after)
    assert after[0] >= (0.2 * STEP_M) ** 2  # at least the model's error of one step
    assert probe.wait_for('transform', stamp, 1.0) is None, 'a refused scan on transform'


def test_publish_predicted_on_refusal_false_publishes_nothing(
    probe: NodeProbe, street: Any
) -> None:
    assert all(r.successful for r in probe.set_parameters({'publish_predicted_on_refusal': False}))
    drive(probe, street, 4)
    stamp, status = send(probe, *noise(street))
    assert status['published'] == 'nothing', status
    assert probe.wait_for('odometry', stamp, 1.0) is None


def test_cloud_registered_is_the_scan_in_odom(probe: NodeProbe, street: Any) -> None:
    stamps = drive(probe, street, 3)
    msg = probe.wait_for('cloud_registered', stamps[-1], 5.0)
    assert msg is not None, 'no mlsemreg/cloud_registered'
    assert msg.header.frame_id == 'odom'
    cloud = pointcloud2_to_arrays(msg, 'label')
    assert cloud.xyz.shape[0] > 1000
    # moved by the pose (x = 2 STEP_M), the points are the street's again
    distances, _ = cKDTree(street[0]).query(cloud.xyz)
    assert np.median(distances) < 0.05, np.median(distances)
    unmoved, _ = cKDTree(street[0]).query(cloud.xyz - [2 * STEP_M, 0.0, 0.0])
    assert np.median(unmoved) > 0.2  # the check can tell a pose that was not applied


@pytest.mark.parametrize('topic', ['mlsemreg/set_pose', '/initialpose'])
def test_a_pose_without_a_map_sets_the_odometry_pose(
    probe: NodeProbe, street: Any, topic: str
) -> None:
    drive(probe, street, 2)  # somewhere else first
    given = yawed(10.0, 5.0, 30.0)
    publish_pose(probe, topic, pose_message('odom', given))
    stamps = drive(probe, street, 2)
    first = probe.wait_for('odometry', stamps[0], 5.0)
    assert first is not None
    np.testing.assert_allclose(pose_of(first), given, atol=1e-3)
    second = probe.wait_for('odometry', stamps[1], 5.0)
    expected = given.copy()
    expected[:3, 3] += given[:3, :3] @ [STEP_M, 0.0, 0.0]  # driven on from there
    np.testing.assert_allclose(pose_of(second)[:3, 3], expected[:3, 3], atol=0.1)


def test_a_pose_in_an_unknown_frame_is_refused(probe: NodeProbe, street: Any) -> None:
    drive(probe, street, 1)
    publish_pose(probe, 'mlsemreg/set_pose', pose_message('velodyne', yawed(10.0, 5.0, 30.0)))
    stamps = drive(probe, street, 2)
    msg = probe.wait_for('odometry', stamps[1], 5.0)
    assert abs(pose_of(msg)[0, 3] - STEP_M) < 0.1  # the odometry went on, not restarted


def test_reset_keeps_the_pose_when_asked(probe: NodeProbe, street: Any) -> None:
    drive(probe, street, 3)  # at x = 2 STEP_M (the fixture's reset applied at identity)
    assert all(r.successful for r in probe.set_parameters({'reset_keeps_pose': True}))
    try:
        assert probe.reset()
        stamp = drive(probe, street, 1)[0]
        msg = probe.wait_for('odometry', stamp, 5.0)
        assert abs(pose_of(msg)[0, 3] - 2 * STEP_M) < 0.05
    finally:
        assert all(r.successful for r in probe.set_parameters({'reset_keeps_pose': False}))
    assert probe.reset()
    stamp = drive(probe, street, 1)[0]
    msg = probe.wait_for('odometry', stamp, 5.0)
    np.testing.assert_allclose(pose_of(msg), np.eye(4), atol=1e-9)


def test_the_heartbeat_says_no_input(ros: Any) -> None:
    _, probe = ros

    def heartbeat() -> Any:
        for _, msg in reversed(probe.received['diagnostics']):
            for status in msg.status:
                if status.name.endswith(': heartbeat') and status.message.startswith(
                    'no input for'
                ):
                    return status
        return None

    status = probe.wait_until(heartbeat, 10.0)
    assert status is not None, 'no heartbeat saying "no input for N s"'
    values = {kv.key: kv.value for kv in status.values}
    assert float(values['seconds_since_input']) >= 1.0

    def beats() -> list[float]:
        return [
            received
            for received, msg in probe.received['diagnostics']
            for status in msg.status
            if status.name.endswith(': heartbeat')
        ]

    start = len(beats())
    assert probe.wait_until(lambda: len(beats()) >= start + 4, 10.0), 'heartbeat stopped'
    gaps = np.diff(beats()[start:][:4])
    assert np.all((gaps > 0.5) & (gaps < 2.0)), gaps  # 1 Hz (steady clock, receipt jitter)


class RecordingBroadcaster:
    """
    Stands in for tf2_ros' ``TransformBroadcaster`` (no tf2_ros or tf2_msgs wheel exists).

    The broadcaster only wraps what it is given in a ``tf2_msgs/TFMessage`` on ``/tf``;
    recording the ``TransformStamped`` the node hands it checks everything the node decides:
    whether TF goes out for a scan, with which frames, stamp and pose.
    """

    def __init__(self) -> None:
        self.sent: list[Any] = []

    def sendTransform(self, transform: Any) -> None:  # tf2_ros' name
        self.sent.append(transform)

    def at(self, stamp: Any) -> list[Any]:
        return [t for t in self.sent if t.header.stamp == stamp]


@pytest.fixture
def tf(ros: Any, probe: NodeProbe) -> Any:
    node, _ = ros
    original, node._tf = node._tf, RecordingBroadcaster()
    try:
        yield node._tf
    finally:
        node._tf = original


@pytest.mark.parametrize('publish_predicted', [True, False])
def test_a_refused_scan_broadcasts_tf_from_the_prediction_unless_turned_off(
    probe: NodeProbe, street: Any, tf: RecordingBroadcaster, publish_predicted: bool
) -> None:
    parameters = {'publish_predicted_on_refusal': publish_predicted}
    assert all(r.successful for r in probe.set_parameters(parameters))
    stamps = drive(probe, street, 4)
    assert probe.wait_for('odometry', stamps[-1], 5.0) is not None
    assert [len(tf.at(s)) for s in stamps] == [1, 1, 1, 1]  # every accepted scan
    stamp, status = send(probe, *noise(street))
    assert status['level'] == 1 and 'frame rejected' in status['message'], status['message']
    if not publish_predicted:
        assert status['published'] == 'nothing', status
        assert probe.wait_for('odometry', stamp, 1.0) is None
        assert tf.at(stamp) == [], 'TF for a refused scan with publish_predicted_on_refusal off'
        return
    odometry = probe.wait_for('odometry', stamp, 5.0)
    assert odometry is not None, 'no odometry for the refused scan'
    (transform,) = tf.at(stamp)
    assert transform.header.frame_id == 'odom'
    assert transform.child_frame_id == odometry.child_frame_id
    moved = transform.transform.translation
    assert abs(moved.x - 4 * STEP_M) < 0.1 and abs(moved.y) < 0.1, moved  # one more step
    assert abs(moved.x - odometry.pose.pose.position.x) < 1e-9  # the odometry's pose
    assert probe.wait_for('transform', stamp, 1.0) is None, 'a refused scan on transform'


def test_a_loop_closure_publishes_the_map_again(
    ros: Any, probe: NodeProbe, street: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """
    ``mlsemreg/map`` goes out again on a loop closure while mapping (ros/map_services.py).

    A real loop closure needs a drive around a block; here the map's verdict on an ordinary
    scan is relabelled ``loop`` (the closure itself is tested in test_maps.py), so what is
    checked is the node's wiring: the map is published on the event, and only on it.
    """
    from dataclasses import replace

    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    node, _ = ros
    received: list[Any] = []
    volatile = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)  # no latched copy
    subscription = probe.node.create_subscription(
        PointCloud2, 'mlsemreg/map', received.append, volatile
    )
    try:
        assert probe.wait_until(lambda: probe.node.count_subscribers('mlsemreg/map') >= 1, 10.0)
        drive(probe, street, 3)  # mapping: keyframes go into the map, no loop
        probe.wait_until(lambda: received, 1.0)
        assert received == [], 'mlsemreg/map published without a loop closure'
        localization = node._map.localization
        verdict = localization.update
        monkeypatch.setattr(
            localization, 'update', lambda *a, **k: replace(verdict(*a, **k), event='loop')
        )
        stamp = drive(probe, street, 1)[0]
        assert probe.wait_until(lambda: received, 10.0), 'no mlsemreg/map after a loop closure'
        assert received[0].header.frame_id == 'map'
        assert received[0].header.stamp == stamp
        assert received[0].width * received[0].height > 100
    finally:
        probe.node.destroy_subscription(subscription)
