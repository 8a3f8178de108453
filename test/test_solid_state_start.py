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
Regression: a solid-state drive whose second scan is refused still registers (stride 1).

The simulated solid-state drive of seed 5 (30 sweeps): the first pair is refused (its global
registration tilts the ground 10.7 deg). While every refused first pair restarted on the
refused scan, each next pair was a first pair again, registered globally, and the drive
registered 0 %; with ``keyframe.restart_gap`` the third scan faces the first and tracking
starts (93 %). About 10 s.
"""

import json
from pathlib import Path

from mlsemreg_ros.tools import eval_bag, simulate


def test_the_solid_state_drive_registers_after_a_refused_first_pair(tmp_path: Path) -> None:
    drive = tmp_path / 'livox'
    arguments = [str(drive), '--realism', 'field', '--frames', '30', '--seed', '5']
    assert simulate.main([*arguments, '--sensor', 'livox', '--quiet']) == 0
    out = tmp_path / 'run'
    assert eval_bag.main([str(drive), '--no-plots', '--quiet', '--output', str(out)]) == 0
    summary = json.loads((out / 'summary.json').read_text())
    assert summary['registration_recall_pct'] >= 85.0, summary
