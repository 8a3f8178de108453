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
A narrow view refused on a sparse stream, searched against the map's scans (map_search.py).

Where the search runs (a refused partial view with a motion model's prediction, the scan
before more than 0.3 s away, a map of at least two scans) and where it leaves the decision
alone, by hand; the map's cloud on a hand-made pair of keyframes; the seeds' yaws; and
(slow, about 40 s) the simulated solid-state drive of seed 1 at stride 10 with geometric
labels: scan 3 (bag scan 30), turned 32.5 deg from the keyframe with a prediction 2.6 m /
31.7 deg off, was refused on session 21's code and is now registered right, and scan 4
after it (a turned start confirmed by its sweep alignment, ``sparse_turn.SWEEP_MIN_SHARE``).
"""

import csv
from pathlib import Path
from types import SimpleNamespace

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry.local_map import Keyframe
from mlsemreg_ros.core.odometry.map_search import (
    map_cloud,
    map_seeds,
    MAP_YAWS_DEG,
    search_local_map,
)
from mlsemreg_ros.core.odometry.motion_model import Prediction
from mlsemreg_ros.core.odometry.narrow_view import View
from mlsemreg_ros.core.odometry.recovery import PastKeyframes
from mlsemreg_ros.core.odometry.seeded_search import SEED_ALONG_M
from mlsemreg_ros.core.rigid import rotation_angle_deg
from mlsemreg_ros.tools import eval_bag, simulate
import numpy as np
import pytest


class _Untouchable:
    """A registration the search must not call."""

    config = RegistrationConfig()

    def prepare(self, *args: object) -> None:
        raise AssertionError('the search ran')


class _Recording:
    """A registration that records what it prepares and returns a stand-in scan."""

    def __init__(self) -> None:
        self.prepared: list[tuple[np.ndarray, np.ndarray]] = []

    def prepare(self, points: np.ndarray, labels: np.ndarray) -> str:
        self.prepared.append((points, labels))
        return 'prepared'


def _pose(x: float, yaw_deg: float) -> np.ndarray:
    yaw = np.radians(yaw_deg)
    T = np.eye(4)
    T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    T[0, 3] = x
    return T


def _keyframe(index: int, pose: np.ndarray, points: np.ndarray) -> Keyframe:
    labels = np.full(len(points), index, dtype=np.int64)
    return Keyframe(index, index, points, labels, None, pose)  # type: ignore[arg-type]


def _odometry(view: View, past: int = 1, registration: object = None) -> SimpleNamespace:
    keyframes = PastKeyframes(5)
    for k in range(past):
        keyframes.remember(_keyframe(k, _pose(float(k), 0.0), np.zeros((1, 3))))
    registration = registration if registration is not None else _Untouchable()
    return SimpleNamespace(
        tracker=SimpleNamespace(trust=SimpleNamespace(view=view)),
        config=RegistrationConfig(),
        global_registration=SimpleNamespace(registration=registration),
        registration=registration,
        keyframe=_keyframe(9, _pose(5.0, 0.0), np.zeros((1, 3))),
        past_keyframes=keyframes,
    )


@pytest.mark.parametrize(
    'view, accepted, still, past',
    [
        (View(span_deg=360.0, scan_gap_s=1.0), False, False, 2),  # a full ring
        (View(span_deg=70.0, scan_gap_s=0.1), False, False, 2),  # a dense stream (stride 1)
        (View(span_deg=70.0, scan_gap_s=0.3), False, False, 2),  # the edge: not sparse
        (View(span_deg=70.0, scan_gap_s=1.0), True, False, 2),  # accepted already
        (View(span_deg=70.0, scan_gap_s=1.0), False, True, 2),  # a still start
        (View(span_deg=70.0, scan_gap_s=1.0), False, False, 0),  # the map is the keyframe
    ],
)
def test_the_search_leaves_every_other_decision_alone(
    view: View, accepted: bool, still: bool, past: int
) -> None:
    chosen = SimpleNamespace(accepted=accepted)
    prediction = Prediction(np.eye(4), 1.0, still=still)
    odometry = _odometry(view, past)
    assert search_local_map(odometry, prediction, SimpleNamespace(), chosen, {}) is chosen
    assert search_local_map(odometry, None, SimpleNamespace(), chosen, {}) is chosen


def test_the_map_cloud_places_each_scan_by_its_pose_in_the_keyframe_frame() -> None:
    registration = _Recording()
    odometry = _odometry(View(span_deg=70.0, scan_gap_s=1.0), 0, registration)
    odometry.preprocessor = SimpleNamespace(exclude_moving=lambda *args: None)
    point = np.array([[1.0, 0.0, 0.0]])
    odometry.past_keyframes.remember(_keyframe(1, _pose(2.0, 90.0), point))  # older
    odometry.past_keyframes.remember(_keyframe(2, _pose(3.0, 0.0), point))  # newer
    odometry.keyframe = _keyframe(3, _pose(4.0, 0.0), point)
    cloud = map_cloud(odometry)
    assert cloud is not None and cloud.prepared == 'prepared'
    assert cloud.index == 3 and np.array_equal(cloud.pose, odometry.keyframe.pose)
    points, labels = registration.prepared[0]
    # newest first: keyframe 2 at x=3 (1 m behind), keyframe 1 at x=2 turned 90 deg, then 3
    assert np.allclose(points, [[0.0, 0.0, 0.0], [-2.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    assert labels.tolist() == [2, 1, 3]


def test_the_map_cloud_needs_two_scans() -> None:
    odometry = _odometry(View(span_deg=70.0, scan_gap_s=1.0), 0, _Recording())
    assert map_cloud(odometry) is None


def test_the_seeds_turn_the_prediction_up_to_40_deg_and_move_it_along() -> None:
    predicted = _pose(10.0, 30.0)
    seeds = map_seeds(predicted)
    assert len(seeds) == len(MAP_YAWS_DEG) * len(SEED_ALONG_M)
    turns = sorted({round(rotation_angle_deg(np.linalg.solve(predicted, s))) for s in seeds})
    assert turns == [0, 8, 16, 24, 32, 40]
    moves = {round(float(np.linalg.norm(np.linalg.solve(predicted, s)[:3, 3]))) for s in seeds}
    assert moves == {abs(a) for a in SEED_ALONG_M}


@pytest.mark.slow
def test_the_solid_state_drive_keeps_the_braking_turn_at_stride_10(tmp_path: Path) -> None:
    drive = tmp_path / 'livox1'  # the route follows the drive's length: 60 frames
    arguments = [str(drive), '--realism', 'field', '--frames', '60', '--seed', '1']
    assert simulate.main([*arguments, '--sensor', 'livox', '--quiet']) == 0
    out = tmp_path / 'run'
    options = ['--labels', 'geometric', '--stride', '10']
    options += ['--no-plots', '--quiet', '--output', str(out)]
    assert eval_bag.main([str(drive), *options]) == 0
    with open(out / 'frames.csv', newline='') as table:
        rows = list(csv.DictReader(table))
    assert len(rows) == 6
    wrong = [r['frame'] for r in rows if r['accepted'] == 'True' and r['success'] == 'False']
    assert wrong in ([], ['0']), wrong  # the first scan starts the odometry (no pair)
    row = rows[3]  # refused on session 21's code
    assert row['accepted'] == 'True', row['message']
    assert row['success'] == 'True', row['message']
    assert 'against the map scans' in row['message'], row['message']
    row = rows[4]  # a turned start whose sweep kept 0.14 of the scan (sparse_turn.py)
    assert row['accepted'] == 'True', row['message']
    assert row['success'] == 'True', row['message']
