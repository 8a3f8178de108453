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
The odometry peers of ``eval-bag --baseline`` (KISS-ICP, GenZ-ICP, KISS-SLAM) in one run.

A 6-scan simulated drive (seed 0, 1 m apart, no per-point times): every peer must follow it
(GenZ-ICP 0.3.2 goes backwards from its first scan on the seed-3 world, so the seed is
fixed), write its own results folder with trajectories that evo
reads, and a missing peer must stop the command with the install line, not a traceback.
"""

from __future__ import annotations

from collections.abc import Callable
import json
from pathlib import Path

from mlsemreg_ros.evaluation import peer_runs
from mlsemreg_ros.tools import eval_bag, simulate
import pytest

PEERS = ('kiss-icp', 'genz-icp', 'kiss-slam')


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp('peers') / 'sim'
    args = [str(out), '--frames', '6', '--seed', '0', '--quiet']
    assert simulate.main(args) == 0
    return out


def test_every_peer_runs_on_the_same_scans_and_writes_its_results(
    bag: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for name in PEERS:
        if peer_runs.missing_peers([name]):
            pytest.skip(f'{name} is not installed: {peer_runs.missing_peers([name])}')
    out = bag.parent / 'all'
    args = [str(bag), '-o', str(out), '--quiet', '--no-plots', '--set', 'keypoints.count=1500']
    for name in PEERS:
        args += ['--baseline', name]
    assert eval_bag.main(args) == 0
    printed = capsys.readouterr().out
    for method in ('KISS-ICP', 'GenZ-ICP', 'KISS-SLAM'):
        assert method in printed
    for name in PEERS:
        summary = json.loads((out / name / 'summary.json').read_text())
        assert summary['n_frames'] == 6
        assert summary['registration_recall_pct'] == 100.0, name
        assert summary['ate_rmse_m'] < 0.1, name
        for trajectory in ('trajectory_tum.txt', 'trajectory_kitti.txt'):
            assert len((out / name / trajectory).read_text().splitlines()) == 6
        details = json.loads((out / name / 'details.json').read_text())
        assert details['n_accepted'] == 5
    assert 'wrong poses published' in printed


def test_a_missing_peer_is_named_with_its_install_line(
    bag: Path, not_installed: Callable[[str], None], capsys: pytest.CaptureFixture[str]
) -> None:
    not_installed('genz_icp')
    code = eval_bag.main([str(bag), '-o', str(bag.parent / 'missing'), '--baseline', 'genz-icp'])
    assert code == 2
    err = capsys.readouterr().err
    assert 'genz-icp' in err and "pip install 'genz-icp==0.3.2'" in err
    assert not (bag.parent / 'missing').exists()  # stopped before anything ran
    with pytest.raises(peer_runs.PeerUnavailable, match='genz-icp'):
        peer_runs.odometry_estimator('genz-icp')
