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

"""mlsemreg-demo on a 4-scan drive: the real node, the player, the recording, the scores."""

from __future__ import annotations

import csv
import json
from pathlib import Path

from mlsemreg_ros.codec.pose_files import read_kitti_poses
from mlsemreg_ros.codec.stamps import parse_seconds
from mlsemreg_ros.evaluation.scoring import SUMMARY_KEYS
from mlsemreg_ros.ros import demo_run
from mlsemreg_ros.tools import demo, eval_bag
import numpy as np
import pytest
from ros_domains import domain_id

pytestmark = [pytest.mark.slow, pytest.mark.usefixtures('rclpy_module')]  # conftest.py

DOMAIN_ID = domain_id('demo')


def test_demo_runs_the_node_on_a_short_drive_and_scores_it(tmp_path: Path) -> None:
    out = tmp_path / 'demo'
    args = [
        '--frames',
        '4',
        '--cache-dir',
        str(tmp_path / 'cache'),
        '-o',
        str(out),
        '--domain-id',
        str(DOMAIN_ID),
        '--set',
        'keypoints.count=1200',
        '--quiet',
    ]
    assert demo.main(args) == 0, (out / 'node.log').read_text()
    summary = json.loads((out / 'summary.json').read_text())
    assert tuple(summary) == SUMMARY_KEYS
    assert summary['n_frames'] == 4
    assert summary['registration_recall_pct'] == 100.0
    assert summary['translation_error_cm'] < 20.0
    with open(out / 'frames.csv') as f:
        rows = list(csv.DictReader(f))
    assert [int(r['keyframe_index']) for r in rows] == [0, 0, 1, 2]
    assert all(r['accepted'] == 'True' for r in rows)
    for name in ('trajectory.png', 'errors.png', 'correspondences.png'):
        assert (out / name).exists()
    assert (out / 'recorded_odometry' / 'metadata.yaml').exists()
    # The second run reuses the cached sequence.
    bag = demo_run.ensure_sequence(tmp_path / 'cache', 4, 0, True)
    assert bag == tmp_path / 'cache' / 'sim_seed0_4f'
    # The node and the offline replay give the same poses on the same bag (one code path).
    offline = tmp_path / 'offline'
    assert (
        eval_bag.main(
            [
                str(bag),
                '-o',
                str(offline),
                '--quiet',
                '--no-plots',
                '--set',
                'keypoints.count=1200',
            ]
        )
        == 0
    )
    node_poses = read_kitti_poses(out / 'trajectory_kitti.txt')
    np.testing.assert_allclose(
        node_poses, read_kitti_poses(offline / 'trajectory_kitti.txt'), atol=1e-6
    )
    assert np.abs(node_poses[-1, :3, 3]).max() > 1.0  # it moved


def test_parse_stamp_is_exact() -> None:
    assert parse_seconds('1700000000.200000048') == 1_700_000_000_200_000_048
    assert parse_seconds('12.5') == 12_500_000_000
