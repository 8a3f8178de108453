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
``odometry.still_start``: with no motion known, a scan a sweep later starts from the last pose.

The simulated solid-state drive of seed 7 with geometric labels: its 70 deg scans give the
global registration nothing to hold (every first pair refused for 30 scans, RR 0 % over the
first 16). With the still start the pair after the one-second restart (scan 11 onto scan 10)
is aligned from scan 10's pose and tracking starts. About 15 s.
"""

import csv
from pathlib import Path

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry import Odometry
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.tools import eval_bag, simulate
import numpy as np


def test_a_still_start_only_a_sweep_after_the_last_pose() -> None:
    """A Prediction at the last accepted pose, flagged still, only within the time bound."""
    config = RegistrationConfig()
    odometry = Odometry(Registration(config))
    assert odometry._still_start(1_000_000_000) is None  # no pose yet
    rng = np.random.default_rng(0)
    points = np.c_[rng.uniform(-20, 20, (4000, 2)), rng.uniform(-1.8, 3.0, 4000)]
    odometry.process(points, None, 1_000_000_000)
    assert odometry.keyframe is not None
    still = odometry._still_start(1_100_000_000)
    assert still is not None and still.still
    assert np.array_equal(still.T_odom_current, odometry.pose)
    assert odometry._still_start(1_200_000_000) is None  # 0.2 s > 0.15 s
    config.odometry.still_start = 0.0
    odometry.reconfigure(config)
    assert odometry._still_start(1_100_000_000) is None  # off


def test_the_solid_state_drive_starts_from_a_still_pose(tmp_path: Path) -> None:
    drive = tmp_path / 'livox7'
    arguments = [str(drive), '--realism', 'field', '--frames', '16', '--seed', '7']
    assert simulate.main([*arguments, '--sensor', 'livox', '--quiet']) == 0
    out = tmp_path / 'run'
    options = ['--labels', 'geometric', '--no-plots', '--quiet', '--output', str(out)]
    assert eval_bag.main([str(drive), *options]) == 0
    with open(out / 'frames.csv', newline='') as table:
        rows = list(csv.DictReader(table))
    accepted = [int(r['frame']) for r in rows if r['accepted'] == 'True' and r['frame'] != '0']
    wrong = [r['frame'] for r in rows if r['accepted'] == 'True' and r['success'] == 'False']
    assert wrong in ([], ['0']), wrong  # the first scan starts the odometry (no pair)
    assert {11, 12, 13, 14, 15} <= set(accepted), accepted
