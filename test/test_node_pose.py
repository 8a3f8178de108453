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
mlsemreg_node with a loaded map (real rclpy): ``/initialpose`` seeds the relocalization.

The map is the synthetic street of test_map_node.py (five keyframes 15 m apart). A
localized node is "kidnapped": a scan from another place with ``/initialpose`` near it is
relocalized around the seed; a seed 45 m from the scan is refused, not adopted.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mlsemreg_ros.codec.poses import transform_message_to_matrix
from mlsemreg_ros.core.metrics import rotation_error_deg
from mlsemreg_ros.datasets.synthetic_scene import motion, scan_at, street_scene
from mlsemreg_ros.ros.probe import node_and_probe, NodeProbe, to_stamp
import numpy as np
from pose_messages import pose_message, pose_of, publish_pose
import pytest
from ros_domains import domain_id
from street_map import street_map_folder, STREET_SEED  # noqa: F401 (the map_folder fixture)

pytestmark = pytest.mark.usefixtures('rclpy_module')  # skip without rclpy (conftest.py)

TIMEOUT_S = 120.0


@pytest.fixture(scope='module')
def probe(map_folder: Path, tmp_path_factory: pytest.TempPathFactory) -> Any:
    from geometry_msgs.msg import TransformStamped

    saved = tmp_path_factory.mktemp('saved') / 'copy'
    args = ['--ros-args', '-p', f'map.load_path:={map_folder}', '-p', f'map.save_path:={saved}']
    with node_and_probe(domain_id('node_pose'), args) as (_, probe):
        probe.received['map_pose'] = []
        probe.node.create_subscription(
            TransformStamped, 'mlsemreg/map_pose', probe._recorder('map_pose'), 10
        )
        yield probe


def send(probe: NodeProbe, pose: np.ndarray, stamp_s: float, seed: int) -> tuple[Any, dict]:
    world, labels = street_scene(seed=STREET_SEED)
    points, scan_labels = scan_at(world, labels, pose, seed=seed, max_points=15000)
    stamp = to_stamp(stamp_s)
    probe.publish(probe.cloud(points, scan_labels.astype(np.uint32), stamp))
    status = probe.status_for(stamp, TIMEOUT_S)
    assert status is not None, 'no diagnostics for the scan'
    return stamp, status


def map_pose_of(probe: NodeProbe, stamp: Any, timeout: float = 10.0) -> np.ndarray | None:
    """T_map_sensor of the scan stamped ``stamp``: map -> odom composed with its odometry."""
    found = probe.wait_for('map_pose', stamp, timeout)
    odometry = probe.wait_for('odometry', stamp, timeout)
    if found is None or odometry is None:
        return None
    return transform_message_to_matrix(found.transform) @ pose_of(odometry)


def assert_at(estimate: np.ndarray | None, truth: np.ndarray) -> None:
    assert estimate is not None, 'not localized'
    error = np.linalg.inv(truth) @ estimate
    assert np.linalg.norm(error[:3, 3]) < 0.3, error[:3, 3]
    assert rotation_error_deg(error[:3, :3], np.eye(3)) < 2.0


def test_initialpose_moves_a_localization_to_the_seeded_place(probe: NodeProbe) -> None:
    start = motion(0.0, (-28.0, 0.2, 0.0))
    stamp, _ = send(probe, start, 10.0, seed=911)
    assert_at(map_pose_of(probe, stamp), start)  # localized globally at startup
    kidnapped = motion(12.0, (17.0, 0.8, 0.0))  # 45 m on: the odometry cannot follow
    seed = kidnapped @ motion(4.0, (0.6, -0.4, 0.0))  # a click in RViz: near, not exact
    publish_pose(probe, '/initialpose', pose_message('map', seed))
    stamp, status = send(probe, kidnapped, 20.0, seed=912)
    assert status.get('map.event') == 'relocalized', status
    assert 'around the seed' in status['map.message']
    assert_at(map_pose_of(probe, stamp), kidnapped)


def test_a_wrong_seed_is_refused(probe: NodeProbe) -> None:
    truth = motion(12.0, (17.5, 0.8, 0.0))
    wrong = motion(0.0, (-28.0, 0.0, 0.0))  # 45 m from where the scan was taken
    publish_pose(probe, '/initialpose', pose_message('map', wrong))
    stamp, status = send(probe, truth, 30.0, seed=913)
    assert status.get('map.event') == 'refused', status
    assert status['map.message'].startswith('seed refused'), status['map.message']
    assert probe.wait_for('map_pose', stamp, 2.0) is None, 'a wrong seed was adopted'
    # unseeded, the next scan relocalizes globally: the refusal was the seed's
    stamp, _ = send(probe, truth @ motion(0.0, (0.5, 0.0, 0.0)), 30.1, seed=914)
    assert_at(map_pose_of(probe, stamp), truth @ motion(0.0, (0.5, 0.0, 0.0)))


def test_set_pose_in_the_map_frame_sets_map_to_odom(probe: NodeProbe) -> None:
    """With a loaded map, ``mlsemreg/set_pose`` in ``map`` is taken as it is (unchecked)."""
    here = motion(0.0, (-13.0, 0.3, 0.0))
    publish_pose(probe, '/initialpose', pose_message('map', here))  # wherever it was before
    stamp, _ = send(probe, here, 40.0, seed=921)
    assert_at(map_pose_of(probe, stamp), here)
    given = here @ motion(6.0, (1.5, -0.7, 0.0))  # not where the scan is: not checked
    publish_pose(probe, 'mlsemreg/set_pose', pose_message('map', given))
    stamp, status = send(probe, here, 40.1, seed=922)  # the sensor stood still
    assert status['level'] == 0, status['message']
    assert_at(map_pose_of(probe, stamp), given)


def test_the_map_arrives_at_a_late_subscriber(probe: NodeProbe, map_folder: Path) -> None:
    from mlsemreg_ros.codec.pointcloud2 import pointcloud2_to_arrays
    from mlsemreg_ros.core.maps.map_io import load_map
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from scipy.spatial import cKDTree
    from sensor_msgs.msg import PointCloud2

    received: list[Any] = []
    latched = QoSProfile(
        depth=1,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
        reliability=ReliabilityPolicy.RELIABLE,
    )
    # subscribed long after the node published it at startup (the fixture's first test ran)
    subscription = probe.node.create_subscription(
        PointCloud2, 'mlsemreg/map', received.append, latched
    )
    try:
        assert probe.wait_until(lambda: received, 20.0), 'no mlsemreg/map at a late subscriber'
    finally:
        probe.node.destroy_subscription(subscription)
    msg = received[0]
    assert msg.header.frame_id == 'map'
    cloud = pointcloud2_to_arrays(msg, 'label')
    full = np.concatenate(
        [
            k.points @ k.T_map_keyframe[:3, :3].T + k.T_map_keyframe[:3, 3]
            for k in load_map(map_folder).keyframes
        ]
    )
    assert 1000 < cloud.xyz.shape[0] < full.shape[0]  # downsampled
    distances, _ = cKDTree(full).query(cloud.xyz)
    assert np.median(distances) < 0.5  # in the map frame, on the keyframes' points
    assert np.max(cloud.xyz[:, 0]) - np.min(cloud.xyz[:, 0]) > 60.0  # all five keyframes


def test_save_map_publishes_the_map_again(probe: NodeProbe) -> None:
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2
    from std_srvs.srv import Trigger

    received: list[Any] = []
    volatile = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)  # no latched copy
    subscription = probe.node.create_subscription(
        PointCloud2, 'mlsemreg/map', received.append, volatile
    )
    client = probe.node.create_client(Trigger, 'mlsemreg/save_map')
    try:
        assert client.wait_for_service(timeout_sec=10.0)
        assert probe.wait_until(lambda: probe.node.count_subscribers('mlsemreg/map') >= 1, 10.0)
        future = client.call_async(Trigger.Request())
        assert probe.wait_until(lambda: future.done(), 60.0)
        assert future.result().success, future.result().message
        assert probe.wait_until(lambda: received, 10.0), 'no mlsemreg/map after save_map'
    finally:
        probe.node.destroy_subscription(subscription)
        probe.node.destroy_client(client)
