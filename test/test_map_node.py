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

"""mlsemreg_node with a map (real rclpy): map -> odom for a scan of the map's world; save_map."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mlsemreg_ros.codec.poses import transform_message_to_matrix
from mlsemreg_ros.core.maps.map_io import load_map
from mlsemreg_ros.core.metrics import rotation_error_deg
from mlsemreg_ros.core.rigid import invert_transform
from mlsemreg_ros.datasets.synthetic_scene import motion, scan_at, street_scene
from mlsemreg_ros.ros.probe import node_and_probe, NodeProbe, to_stamp
import numpy as np
import pytest
from ros_domains import domain_id
from street_map import street_map_folder, STREET_SEED  # noqa: F401 (the map_folder fixture)

pytestmark = pytest.mark.usefixtures('rclpy_module')  # skip without rclpy (conftest.py)

TIMEOUT_S = 120.0


@pytest.fixture(scope='module')
def ros(map_folder: Path, tmp_path_factory: pytest.TempPathFactory) -> Any:
    saved = tmp_path_factory.mktemp('saved') / 'copy'
    args = [
        '--ros-args',
        '-p',
        f'map.load_path:={map_folder}',
        '-p',
        f'map.save_path:={saved}',
    ]
    with node_and_probe(domain_id('map_node'), args) as (node, probe):
        from geometry_msgs.msg import TransformStamped

        probe.received['map_pose'] = []
        probe.node.create_subscription(
            TransformStamped, 'mlsemreg/map_pose', probe._recorder('map_pose'), 10
        )
        yield node, probe, saved


def _send(probe: NodeProbe, pose: np.ndarray, stamp_s: float, seed: int) -> Any:
    world, labels = street_scene(seed=STREET_SEED)
    points, scan_labels = scan_at(world, labels, pose, seed=seed, max_points=15000)
    stamp = to_stamp(stamp_s)
    probe.publish(probe.cloud(points, scan_labels.astype(np.uint32), stamp))
    assert probe.status_for(stamp, TIMEOUT_S) is not None, 'no diagnostics for the scan'
    return stamp


def test_a_node_started_with_a_map_publishes_map_to_odom(ros: Any) -> None:
    _, probe, _ = ros
    truth = motion(-40.0, (7.0, -1.0, 0.0))  # between two keyframes, turned: no guess
    stamp = _send(probe, truth, 10.0, seed=901)
    found = probe.wait_for('map_pose', stamp, 10.0)
    assert found is not None, 'no mlsemreg/map_pose for a scan of the map'
    assert (found.header.frame_id, found.child_frame_id) == ('map', 'odom')
    # the first scan is the odom origin: T_map_odom is the scan's pose in the map
    error = invert_transform(truth) @ transform_message_to_matrix(found.transform)
    assert np.linalg.norm(error[:3, 3]) < 0.3
    assert rotation_error_deg(error[:3, :3], np.eye(3)) < 2.0
    # localized: the next scan is tracked by the odometry and map -> odom keeps holding
    stamp = _send(probe, truth @ motion(2.0, (1.0, 0.0, 0.0)), 10.1, seed=902)
    again = probe.wait_for('map_pose', stamp, 10.0)
    assert again is not None
    assert np.linalg.norm(transform_message_to_matrix(again.transform)[:3, 3] - truth[:3, 3]) < 0.3


def test_save_map_writes_the_loaded_map(ros: Any, map_folder: Path) -> None:
    from std_srvs.srv import Trigger

    _, probe, saved = ros
    client = probe.node.create_client(Trigger, 'mlsemreg/save_map')
    assert client.wait_for_service(timeout_sec=10.0)
    future = client.call_async(Trigger.Request())
    assert probe.wait_until(lambda: future.done(), 30.0)
    assert future.result().success, future.result().message
    original, copy = load_map(map_folder), load_map(saved)
    assert len(copy.keyframes) == len(original.keyframes)
    for a, b in zip(original.keyframes, copy.keyframes, strict=True):
        assert np.array_equal(a.points, b.points) and np.allclose(
            a.T_map_keyframe, b.T_map_keyframe
        )
    relocalize = probe.node.create_client(Trigger, 'mlsemreg/relocalize')
    assert relocalize.wait_for_service(timeout_sec=10.0)
    future = relocalize.call_async(Trigger.Request())
    assert probe.wait_until(lambda: future.done(), 30.0)
    assert future.result().success
