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
A near-miss dispute judged again once the sweep is deskewed again (core/odometry/swept_dispute.py).

The HDL-64 field drive of seed 7 at stride 5 with geometric labels: its first pair (scans 0
and 5, no motion known, neither deskewed) has two basins 0.62 m apart, both about 0.6 m
from the truth. Refused (as before session 19), the scan is lost; judged again on the
scans the start's deskew and the sweep alignment made, the pose is right and alone in its
basin. A scan another path accepts is left as it is.
"""

from __future__ import annotations

import csv
from pathlib import Path
from types import SimpleNamespace

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry.steps import Decision
from mlsemreg_ros.core.odometry.swept_dispute import judged_again, swept_refusal
from mlsemreg_ros.simulation.field import FieldSimulation
from mlsemreg_ros.tools import cli
import numpy as np
import pytest


def test_a_scan_not_deskewed_again_keeps_its_dispute() -> None:
    def never(*_: object) -> None:
        raise AssertionError('nothing is aligned again: the scan is the same')

    tracker = SimpleNamespace(candidate=never, map=SimpleNamespace(align_scan=never))
    refusal = swept_refusal(tracker, np.eye(4), None, False, RegistrationConfig())
    assert refusal == 'still refused: the sweep was not deskewed again'


def test_the_disputed_pose_is_taken_only_when_nothing_accepted_the_scan() -> None:
    disputed = Decision('global', '', pose=np.eye(4), swept_dispute='global: two basins')
    refused = Decision('', 'global: near miss: two basins', timings_ms={'x': 1.0})
    accepted = Decision('prediction', 'tracked', pose=np.eye(4))
    assert judged_again(disputed, 'scan', 'raw', accepted) == ('raw', accepted)
    assert judged_again(None, 'scan', 'raw', refused) == ('raw', refused)
    scan, chosen = judged_again(disputed, 'scan', 'raw', refused)
    assert scan == 'scan' and chosen.accepted and chosen.swept_dispute
    assert chosen.reason == refused.reason and chosen.timings_ms == {'x': 1.0}


def _frames(out: Path) -> list[dict[str, str]]:
    with open(out / 'frames.csv') as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_a_first_pair_disputed_on_skewed_sweeps_is_right_once_deskewed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # scans 0 and 5 of the 60-scan drive (its moving objects follow the drive's length)
    monkeypatch.setattr(FieldSimulation, '__iter__', lambda sim: iter(map(sim.frame, (0, 5))))
    monkeypatch.setattr(FieldSimulation, '__len__', lambda sim: 2)
    drive = tmp_path / 'field7_hdl64'
    simulate = ['simulate', str(drive), '--realism', 'field', '--frames', '60', '--seed', '7']
    assert cli.main([*simulate, '--sensor', 'hdl64', '--quiet']) == 0
    runs = {}
    for recheck in ('true', 'false'):
        out = tmp_path / recheck
        argv = ['eval-bag', str(drive), '--labels', 'geometric', '--no-plots', '--quiet']
        cli.main([*argv, '--output', str(out), '--set', f'near_miss.recheck_swept={recheck}'])
        runs[recheck] = _frames(out)[1]  # the first pair: scan 5 onto scan 0
    before, after = runs['false'], runs['true']
    assert before['accepted'] == 'False' and 'two basins' in before['message']
    assert after['accepted'] == 'True' and after['success'] == 'True'
    assert float(after['te_cm']) < 20.0  # both basins lay about 60 cm off
    assert 'one basin after the sweep was deskewed again' in after['message']
