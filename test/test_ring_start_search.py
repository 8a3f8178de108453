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
A full ring's first pair searched along its forward axis (core/odometry/ring_start_search.py).

Known answers of the seeds (along the keyframe's +x, turned); nothing runs on a narrow view,
with a prediction, on a dense stream (0.1 s from the scan before), 3 s after the keyframe
or when off; and (slow)
the first pair of the simulated HDL-32 drive of seed 7 (60 scans) at stride 10 without
labels, scans 42 and 52, 10 m apart: the global registration alone refuses it, the search
along the forward axis registers it right.
"""

from pathlib import Path

from first_pair_search import assert_first_pair_found, assert_untouched, view_at
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry.ring_start_search import (
    forward_seeds,
    search_along_forward,
)
from mlsemreg_ros.core.odometry.seeded_search import SEED_YAWS_DEG
from mlsemreg_ros.datasets.factory import open_scan_source
from mlsemreg_ros.tools import simulate
import numpy as np
import pytest


def test_the_seeds_lie_along_the_keyframes_forward_axis() -> None:
    keyframe = np.eye(4)
    keyframe[:2, :2] = [[0.0, -1.0], [1.0, 0.0]]  # heading +y of the odometry frame
    keyframe[:3, 3] = [5.0, -2.0, 0.3]
    seeds = forward_seeds(keyframe, 1.0)  # 15 m at 15 m/s: 0, 4, ..., 16 m
    assert len(seeds) == len(SEED_YAWS_DEG) * 5
    moved = {tuple(np.round(s[:3, 3], 6)) for s in seeds}
    assert moved == {(5.0, -2.0 + d, 0.3) for d in (0.0, 4.0, 8.0, 12.0, 16.0)}
    relative = [np.linalg.solve(keyframe, s) for s in seeds]
    yaws = {round(float(np.degrees(np.arctan2(t[1, 0], t[0, 0]))), 6) for t in relative}
    assert yaws == {float(y) for y in SEED_YAWS_DEG}


def test_nothing_runs_on_a_narrow_view_far_with_a_prediction_or_when_off() -> None:
    """The refused decision comes back untouched: nothing else is asked of the odometry."""
    ring, narrow = view_at(360.0, 2_000_000_000), view_at(70.0, 2_000_000_000)
    # 10 Hz: a scan after a refused one, 0.2 s from the keyframe
    dense = view_at(360.0, 1_100_000_000, 1_200_000_000)
    far = view_at(360.0, 4_000_000_000)  # 3 s after the keyframe (stride 30 at 10 Hz)
    config = RegistrationConfig()
    off = config.replace({'odometry.ring_search_overlap': 0.0})
    assert_untouched(
        search_along_forward,
        (
            (far, None, config),  # beyond odometry.ring_search_max_gap
            (narrow, None, config),  # a narrow view: core/odometry/start_search.py
            (ring, object(), config),  # a motion model's prediction
            (ring, None, off),  # off
            (dense, None, config),  # a dense stream: 0.1 s from the scan before
        ),
    )


@pytest.mark.slow
def test_a_rings_first_pair_10_m_apart_registers_without_labels(tmp_path: Path) -> None:
    drive = tmp_path / 'hdl32_7'
    arguments = [str(drive), '--realism', 'field', '--frames', '60', '--seed', '7']
    assert simulate.main([*arguments, '--sensor', 'hdl32', '--quiet']) == 0
    scans = list(open_scan_source(drive).scans(1))
    first, last = scans[42], scans[52]
    assert np.linalg.norm(np.linalg.solve(first.pose, last.pose)[:3, 3]) > 9.0  # 1 s apart
    assert_first_pair_found(
        first,
        last,
        {'label_source': 'none'},
        'odometry.ring_search_overlap',
        0.97,
        'search along the forward axis',
    )
