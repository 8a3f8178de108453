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
from types import SimpleNamespace

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry import Odometry
from mlsemreg_ros.core.odometry.narrow_view import View
from mlsemreg_ros.core.odometry.ring_start_search import (
    forward_seeds,
    search_along_forward,
)
from mlsemreg_ros.core.odometry.seeded_search import SEED_YAWS_DEG
from mlsemreg_ros.core.odometry.steps import Decision
from mlsemreg_ros.core.pipeline import Registration
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
    refused = Decision(source='', reason='refused')
    last = (np.eye(4), 1_000_000_000)
    ring, narrow = View(span_deg=360.0), View(span_deg=70.0)
    ring.since(last, 2_000_000_000)
    narrow.since(last, 2_000_000_000)
    dense = View(span_deg=360.0)  # 10 Hz: a scan after a refused one, 0.2 s from the keyframe
    dense.since(last, 1_100_000_000)
    dense.since(last, 1_200_000_000)
    far = View(span_deg=360.0)  # 3 s after the keyframe (stride 30 at 10 Hz)
    far.since(last, 4_000_000_000)
    config = RegistrationConfig()
    off = config.replace({'odometry.ring_search_overlap': 0.0})
    for view, prediction, cfg in (
        (far, None, config),  # beyond odometry.ring_search_max_gap
        (narrow, None, config),  # a narrow view: core/odometry/start_search.py
        (ring, object(), config),  # a motion model's prediction
        (ring, None, off),  # off
        (dense, None, config),  # a dense stream: 0.1 s from the scan before
    ):
        odometry = SimpleNamespace(
            config=cfg, tracker=SimpleNamespace(trust=SimpleNamespace(view=view))
        )
        assert search_along_forward(odometry, 2_000_000_000, prediction, None, refused, {}) is (
            refused
        )


@pytest.mark.slow
def test_a_rings_first_pair_10_m_apart_registers_without_labels(tmp_path: Path) -> None:
    drive = tmp_path / 'hdl32_7'
    arguments = [str(drive), '--realism', 'field', '--frames', '60', '--seed', '7']
    assert simulate.main([*arguments, '--sensor', 'hdl32', '--quiet']) == 0
    scans = list(open_scan_source(drive).scans(1))
    first, last = scans[42], scans[52]
    truth = np.linalg.solve(first.pose, last.pose)
    assert np.linalg.norm(truth[:3, 3]) > 9.0  # 1 s apart
    steps = {}
    for name, overlap in (('before', 0.0), ('after', 0.97)):
        config = RegistrationConfig().replace(
            {'label_source': 'none', 'odometry.ring_search_overlap': overlap}
        )
        odometry = Odometry(Registration(config))
        for scan in (first, last):
            steps[name] = odometry.process(
                scan.xyz, scan.labels, scan.stamp_ns, point_times=scan.point_times
            )
    assert not steps['before'].accepted  # the code before: the global registration refuses
    after = steps['after']
    assert after.accepted and 'search along the forward axis' in after.reason, after.reason
    error = np.linalg.solve(truth, after.relative)
    assert np.linalg.norm(after.relative[:3, 3] - truth[:3, 3]) < 0.6
    assert np.degrees(np.arccos(np.clip((np.trace(error[:3, :3]) - 1) / 2, -1, 1))) < 5.0
