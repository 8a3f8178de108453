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
"""Short simulated bags for the end-to-end tests (``mlsemreg simulate``)."""

from __future__ import annotations

from pathlib import Path


def simulated_bag(out: Path, frames: int, seed: int) -> Path:
    """Simulate ``frames`` scans of ``seed`` into ``out`` (1024 columns keep it fast)."""
    from mlsemreg_ros.tools import simulate

    args = [str(out), '--frames', str(frames), '--seed', str(seed)]
    assert simulate.main([*args, '--azimuth-steps', '1024', '--quiet']) == 0
    return out


def simulated_drive(out: Path, sensor: str, frames: int, seed: int) -> Path:
    """Simulate ``frames`` scans of ``seed`` from ``sensor`` (the field's realism) into ``out``."""
    from mlsemreg_ros.tools import simulate

    args = [str(out), '--realism', 'field', '--frames', str(frames), '--seed', str(seed)]
    assert simulate.main([*args, '--sensor', sensor, '--quiet']) == 0
    return out


def evaluated_rows(drive: Path, out: Path, *options: str) -> list[dict[str, str]]:
    """Run ``mlsemreg eval-bag`` on ``drive`` into ``out`` (quiet, no plots); its frames.csv."""
    import csv

    from mlsemreg_ros.tools import eval_bag

    arguments = [str(drive), *options, '--no-plots', '--quiet', '--output', str(out)]
    assert eval_bag.main(arguments) == 0
    with open(out / 'frames.csv', newline='') as table:
        return list(csv.DictReader(table))


def assert_no_wrong_pose(rows: list[dict[str, str]]) -> None:
    """Assert no frame of ``rows`` was accepted outside the success bounds but the first."""
    wrong = [r['frame'] for r in rows if r['accepted'] == 'True' and r['success'] == 'False']
    assert wrong in ([], ['0']), wrong  # the first scan starts the odometry (no pair)
