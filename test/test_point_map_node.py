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

"""mlsemreg_node in a map imported from a PLY point map (real rclpy): map -> odom."""

from __future__ import annotations

from pathlib import Path

from mlsemreg_ros.codec.pose_files import write_tum_poses
from mlsemreg_ros.codec.poses import transform_message_to_matrix
from mlsemreg_ros.core.maps.cloud_files import write_cloud
from mlsemreg_ros.core.metrics import rotation_error_deg
from mlsemreg_ros.core.rigid import invert_transform
from mlsemreg_ros.datasets.synthetic_scene import motion, scan_at, street_scene
from mlsemreg_ros.ros.probe import node_and_probe, to_stamp
from mlsemreg_ros.tools.cli import app
import numpy as np
from pose_messages import pose_of
import pytest
from ros_domains import domain_id
from street_map import STREET_SEED
from typer.testing import CliRunner

pytestmark = pytest.mark.usefixtures('rclpy_module')  # skip without rclpy (conftest.py)

TIMEOUT_S = 120.0


@pytest.fixture(scope='module')
def imported_map(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`mlsemreg map import` of a labeled survey of the street, along a drive on its axis."""
    root = tmp_path_factory.mktemp('point_map')
    world, labels = street_scene(seed=STREET_SEED)
    write_cloud(root / 'survey.ply', world, labels)
    return _import_along_the_street(root / 'survey.ply')


def _import_along_the_street(survey: Path) -> Path:
    """`mlsemreg map import SURVEY` along a drive on the street's axis; return the map."""
    root = survey.parent
    trajectory = np.stack([motion(0.0, (x, 0.0, 0.0)) for x in np.arange(-40.0, 41.0, 1.0)])
    write_tum_poses(root / 'drive.tum', np.arange(len(trajectory)) * 10**8, trajectory)
    run = CliRunner().invoke(
        app,
        [
            *('map', 'import', str(survey), str(root / 'map')),
            *('--trajectory', str(root / 'drive.tum'), '--set', 'map.keyframe_distance=15'),
        ],
    )
    assert run.exit_code == 0, f'{run.output}{run.exception}'
    return root / 'map'


def test_a_node_localizes_in_an_imported_point_map(imported_map: Path) -> None:
    args = ['--ros-args', '-p', f'map.load_path:={imported_map}']
    with node_and_probe(domain_id('point_map_node'), args) as (_, probe):
        from geometry_msgs.msg import TransformStamped

        probe.received['map_pose'] = []
        probe.node.create_subscription(
            TransformStamped, 'mlsemreg/map_pose', probe._recorder('map_pose'), 10
        )
        world, labels = street_scene(seed=STREET_SEED)
        truth = motion(-40.0, (7.0, -1.0, 0.0))  # between two keyframes, turned: no guess
        points, scan_labels = scan_at(world, labels, truth, seed=901, max_points=15000)
        stamp = to_stamp(10.0)
        probe.publish(probe.cloud(points, scan_labels.astype(np.uint32), stamp))
        assert probe.status_for(stamp, TIMEOUT_S) is not None, 'no diagnostics for the scan'
        found = probe.wait_for('map_pose', stamp, 10.0)
        assert found is not None, 'no mlsemreg/map_pose in the imported map'
        assert (found.header.frame_id, found.child_frame_id) == ('map', 'odom')
        error = invert_transform(truth) @ transform_message_to_matrix(found.transform)
        assert np.linalg.norm(error[:3, 3]) < 0.3
        assert rotation_error_deg(error[:3, :3], np.eye(3)) < 2.0


def test_scans_without_labels_localize_in_an_imported_unlabeled_pcd_map(
    tmp_path: Path,
) -> None:
    """
    An unlabeled PCD survey, imported, and a drive of unlabeled clouds: every scan placed right.

    The node labels both with the geometric labeler (``label_source: auto``, no label field);
    a scan is right within 0.3 m and 2 deg of the truth; >= 90 % must be placed, none wrong.
    """
    world, _ = street_scene(seed=STREET_SEED)
    write_cloud(tmp_path / 'survey.pcd', world)  # x, y, z only
    imported = _import_along_the_street(tmp_path / 'survey.pcd')
    args = ['--ros-args', '-p', f'map.load_path:={imported}']
    with node_and_probe(domain_id('point_map_node'), args) as (_, probe):
        from geometry_msgs.msg import TransformStamped

        probe.received['map_pose'] = []
        probe.node.create_subscription(
            TransformStamped, 'mlsemreg/map_pose', probe._recorder('map_pose'), 10
        )
        placed, wrong = 0, []
        drive = [motion(-40.0, (-20.0 + 1.0 * k, -1.0, 0.0)) for k in range(6)]
        for k, truth in enumerate(drive):
            points, _ = scan_at(
                world, np.zeros(len(world), np.uint32), truth, seed=930 + k, max_points=15000
            )
            stamp = to_stamp(20.0 + 0.1 * k)
            probe.publish(probe.cloud(points, None, stamp))
            assert probe.status_for(stamp, TIMEOUT_S) is not None, 'no diagnostics for the scan'
            found = probe.wait_for('map_pose', stamp, 5.0)
            odometry = probe.wait_for('odometry', stamp, 5.0)
            if found is None or odometry is None:
                continue
            estimate = transform_message_to_matrix(found.transform) @ pose_of(odometry)
            error = invert_transform(truth) @ estimate
            right = np.linalg.norm(error[:3, 3]) < 0.3
            right = right and rotation_error_deg(error[:3, :3], np.eye(3)) < 2.0
            placed += 1
            if not right:
                wrong.append((k, error[:3, 3].round(2).tolist()))
    assert not wrong, f'wrong map poses: {wrong}'
    assert placed >= 0.9 * len(drive), f'{placed} of {len(drive)} scans placed in the map'
