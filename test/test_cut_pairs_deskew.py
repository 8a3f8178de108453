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
``cut-pairs --deskew``: pair files hold motion-compensated sweeps, as the maps' keyframes.

A raw simulated sweep spreads over the car's motion during it (about 0.9 m at 9 m/s), while
the truth refers to the sweep's start; on such pairs ``eval-pairs`` accepted poses 0.6-2 m
off (docs/hard_pairs.md, "Raw sweeps in the pair files"). Known answers on a hand-made sweep,
and the 40 m HDL-32 pair that was accepted 2.06 m off (slow).
"""

from __future__ import annotations

from pathlib import Path

from mlsemreg_ros.datasets.hard_pairs import DESKEWERS, make_pair, PairChoice, read_frames
from mlsemreg_ros.datasets.source import Scan
import numpy as np
import pytest

SPEED_M_S = 9.0
SWEEP_S = 0.1


def _wall() -> np.ndarray:
    """Return a wall 10 m ahead (x = 10), 2 m wide and high, in the world frame."""
    y, z = np.meshgrid(np.linspace(-1.0, 1.0, 21), np.linspace(0.0, 2.0, 11))
    return np.column_stack([np.full(y.size, 10.0), y.ravel(), z.ravel()])


def _sweep(index: int) -> Scan:
    """Return the wall seen from a sensor driving along x at 9 m/s, each point at its time."""
    start = (index + 1) * SWEEP_S  # a stamp of 0 means unstamped
    wall = _wall()
    times = np.linspace(0.0, SWEEP_S, len(wall), endpoint=False)
    pose = np.eye(4)
    pose[0, 3] = SPEED_M_S * start
    raw = wall - pose[:3, 3] - np.outer(SPEED_M_S * times, [1.0, 0.0, 0.0])  # at each instant
    labels = np.full(len(wall), 50, dtype=np.int64)
    return Scan(index, int(start * 1e9), raw, labels, None, 'lidar', pose, times)


def test_deskew_by_truth_maps_a_raw_sweep_to_its_stamp() -> None:
    scans = [_sweep(i) for i in range(3)]
    for scan in DESKEWERS['truth'](iter(scans)):
        expected = _wall() - scan.pose[:3, 3]  # the wall from the sweep's start
        np.testing.assert_allclose(scan.xyz, expected, atol=1e-9)
    raw = list(DESKEWERS['none'](iter(scans)))
    skew = np.abs(raw[1].xyz - (_wall() - raw[1].pose[:3, 3])).max()
    assert skew == pytest.approx(SPEED_M_S * SWEEP_S * (1 - 1 / 231), rel=1e-6)


def test_read_frames_refuses_an_unknown_deskew(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match='deskew must be one of truth, odometry, none'):
        read_frames(tmp_path, 0.3, 60.0, progress=False, deskew='sometimes')


@pytest.mark.slow
def test_the_skewed_40_m_hdl32_pair_is_right_once_deskewed(tmp_path: Path) -> None:
    """Seed 6, hdl32, frames 93 and 137, FPFH: the raw sweeps' pose was 2.06 m off, accepted."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.evaluation.pairs import run_pair
    from mlsemreg_ros.evaluation.settings import EvaluationConfig
    from mlsemreg_ros.tools import simulate

    drive = tmp_path / 'f6'
    arguments = [str(drive), '--realism', 'field', '--frames', '200', '--seed', '6']
    assert simulate.main([*arguments, '--sensor', 'hdl32', '--quiet']) == 0
    verdicts = {}
    for deskew in ('none', 'truth', 'odometry'):
        frames = read_frames(drive, 0.3, 60.0, progress=False, deskew=deskew)
        by_index = {frame.index: frame for frame in frames}
        pair = make_pair(
            [by_index[93], by_index[137]], PairChoice('stride', 0, 1, 40.0, 0.0, 0.0), 'p', 5000, 7
        )
        config = RegistrationConfig().replace({'threads': 1})
        result, metrics, _ = run_pair(Registration(config), pair, 'fpfh', EvaluationConfig())
        verdicts[deskew] = (result.success, metrics.success, metrics.translation_error_cm)
    for deskew in ('truth', 'odometry'):
        accepted, right, error_cm = verdicts[deskew]
        assert right, f'{deskew}: {error_cm:.0f} cm off ({verdicts})'
        assert accepted or deskew == 'odometry', verdicts
    assert not verdicts['none'][1], f'the raw sweeps register right now: {verdicts}'
