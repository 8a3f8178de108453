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
The sweep alignment may not take an accepted pose beyond the correction bounds (issue 35).

``Tracker.align_sweep`` aligns an accepted scan again with its sweep twist free, and judges
the result by the map alignment started from the sweep fit's own estimate: on a solid-state
drive a sweep fit slid an accepted pose 2.6 m along a weakly held road and the map alignment,
started there, agreed with it. The whole move from the accepted pose is bounded now
(``Trust.replacement_refusal``). Known answers with the sweep fit and the map stubbed.
"""

from types import SimpleNamespace

from mlsemreg_ros.core.alignment.alignment import Alignment
from mlsemreg_ros.core.alignment.sweep_alignment import SweepAlignment
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.features.deskew import SweepMotion
from mlsemreg_ros.core.odometry import tracking
from mlsemreg_ros.core.odometry.trust import Candidate
import numpy as np
import pytest


def _translation(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    return T


def _align_sweep(monkeypatch, slide_m: float) -> tuple[np.ndarray, np.ndarray, str]:
    """Run ``Tracker.align_sweep`` on an accepted pose whose sweep fit slides ``slide_m``."""
    cfg = RegistrationConfig()
    cfg.moving_objects.matching = 'drop'
    pose = _translation(10.0)
    slid = _translation(10.0 + slide_m)
    tracker = tracking.Tracker(SimpleNamespace(empty=False))
    tracker.map_gaussians = lambda: np.zeros((tracking.MIN_SWEEP_MAP_VOXELS, 3))
    bent = SweepMotion(np.array([0.0, 0.0, 0.3]), np.array([5.0, 0.0, 0.0]))
    monkeypatch.setattr(
        tracking,
        'align_from_starts',
        lambda *args: SweepAlignment(slid, bent, change_m=5.0, pairs=500, iterations=5),
    )

    def candidate(name, T_initial, scan, config):  # the map agrees with wherever it starts
        alignment = Alignment(T_initial, T_initial, True, 3, 900, 1000, 1.0, np.eye(6) * 1e3)
        return Candidate(name, T_initial, alignment, '')

    tracker.candidate = candidate
    points = np.random.default_rng(0).uniform(-20, 20, (2000, 3))
    raw = SimpleNamespace(
        motion=SweepMotion(np.zeros(3), np.array([5.0, 0.0, 0.0])),
        input_points=points,
        point_times=np.linspace(0.0, 0.1, len(points)),
        labels=np.zeros(len(points), dtype=np.uint32),
    )
    redone = SimpleNamespace(deskewed=True, scan='the scan deskewed by the sweep fit')
    preprocessor = SimpleNamespace(scan=lambda *args: redone)
    _, T, note, _, _ = tracker.align_sweep(raw, pose, preprocessor, cfg, None)
    return T, slid, note


def test_a_sweep_fit_that_slides_the_pose_beyond_the_bound_is_not_kept(monkeypatch) -> None:
    T, _, note = _align_sweep(monkeypatch, slide_m=2.6)  # the solid-state drive's slide
    np.testing.assert_allclose(T, _translation(10.0))  # the accepted pose stays
    assert 'not kept' in note and 'the accepted pose' in note


@pytest.mark.parametrize('slide_m', [0.0, 0.85])  # the handheld walk's largest move: 0.85 m
def test_a_sweep_fit_within_the_bound_replaces_the_pose(monkeypatch, slide_m: float) -> None:
    T, slid, note = _align_sweep(monkeypatch, slide_m=slide_m)
    np.testing.assert_allclose(T, slid)
    assert 'not kept' not in note
