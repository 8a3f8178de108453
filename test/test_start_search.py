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
A narrow view's first pair searched along its view axis (core/odometry/start_search.py).

Known answers of the view axis, the seeds' reach and their poses; nothing runs on a full
ring, with a prediction, one sweep from the keyframe (a still start's reach) or when off; and
(slow, about 5 s of CPU) the first pair of the simulated solid-state drive of seed 5 at
stride 10 with geometric labels, 10 m apart: the global registration alone refuses it
(4-42 true correspondences of about 3000), the search along the view registers it right.
"""

from pathlib import Path

from first_pair_search import assert_first_pair_found, assert_untouched, view_at
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry.seeded_search import SEED_YAWS_DEG
from mlsemreg_ros.core.odometry.start_search import (
    along_offsets,
    search_along_view,
    view_axis,
    view_seeds,
)
from mlsemreg_ros.datasets.factory import open_scan_source
from mlsemreg_ros.tools import simulate
import numpy as np
import pytest


def _cone(heading_deg: float, half_width_deg: float = 35.0, count: int = 2000) -> np.ndarray:
    """Points 2-40 m away within ``half_width_deg`` of the azimuth ``heading_deg``."""
    rng = np.random.default_rng(0)
    azimuth = np.radians(heading_deg + rng.uniform(-half_width_deg, half_width_deg, count))
    ranges = rng.uniform(2.0, 40.0, count)
    z = rng.uniform(-1.7, 3.0, count)
    return np.column_stack([ranges * np.cos(azimuth), ranges * np.sin(azimuth), z])


def test_the_view_axis_is_where_the_points_lie() -> None:
    for heading in (0.0, 90.0, -135.0):
        axis = view_axis(_cone(heading))
        expected = [np.cos(np.radians(heading)), np.sin(np.radians(heading))]
        assert axis is not None and np.allclose(axis, expected, atol=0.02)
    ring = _cone(0.0, half_width_deg=180.0, count=20000)
    axis = view_axis(ring)  # a full ring has no direction to speak of: a tiny mean
    assert axis is None or np.isclose(np.linalg.norm(axis), 1.0)
    assert view_axis(np.zeros((10, 3))) is None  # every point at the sensor


def test_the_seeds_reach_the_fastest_motion_in_the_gap() -> None:
    assert along_offsets(0.5) == [0.0, 4.0, 8.0]  # 7.5 m at 15 m/s
    assert along_offsets(1.0) == [0.0, 4.0, 8.0, 12.0, 16.0]  # 15 m
    assert along_offsets(0.0) == [0.0]
    origin = np.eye(4)
    origin[:3, 3] = [5.0, -2.0, 0.3]
    seeds = view_seeds(origin, np.array([0.0, 1.0]), 1.0)
    assert len(seeds) == len(SEED_YAWS_DEG) * 5
    moved = {tuple(np.round(s[:3, 3], 6)) for s in seeds}
    assert moved == {(5.0, -2.0 + d, 0.3) for d in (0.0, 4.0, 8.0, 12.0, 16.0)}
    yaws = {round(float(np.degrees(np.arctan2(s[1, 0], s[0, 0]))), 6) for s in seeds}
    assert yaws == {float(y) for y in SEED_YAWS_DEG}


def test_nothing_runs_on_a_ring_with_a_prediction_or_when_off() -> None:
    """The refused decision comes back untouched: nothing else is asked of the odometry."""
    ring, narrow = view_at(360.0, 2_000_000_000), view_at(70.0, 2_000_000_000)
    # 10 Hz: the scan after the keyframe, a still start's reach
    near = view_at(70.0, 1_100_000_000)
    config = RegistrationConfig()
    off = config.replace({'odometry.view_search_overlap': 0.0})
    assert_untouched(
        search_along_view,
        (
            (ring, None, config),  # a full ring
            (narrow, object(), config),  # a motion model's prediction
            (narrow, None, off),  # off
            (near, None, config),  # 0.1 s from the keyframe: odometry.still_start covers it
        ),
    )


@pytest.mark.slow
def test_the_solid_states_first_pair_10_m_apart_registers(tmp_path: Path) -> None:
    drive = tmp_path / 'livox5'
    arguments = [str(drive), '--realism', 'field', '--frames', '11', '--seed', '5']
    assert simulate.main([*arguments, '--sensor', 'livox', '--quiet']) == 0
    scans = list(open_scan_source(drive).scans(1))
    first, last = scans[0], scans[10]
    assert np.linalg.norm(np.linalg.solve(first.pose, last.pose)[:3, 3]) > 9.0  # 10 m/s, 1 s
    assert_first_pair_found(
        first,
        last,
        {'label_source': 'geometric'},
        'odometry.view_search_overlap',
        0.85,
        'search along the view',
    )
