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
"""``sweep_alignment.steady_*``: which tracked scans skip the sweep alignment (known answers)."""

from mlsemreg_ros.core.alignment.alignment import Alignment
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry.steps import Decision
from mlsemreg_ros.core.odometry.tracking import steady
from mlsemreg_ros.core.odometry.trust import Candidate
import numpy as np
from scipy.spatial.transform import Rotation


def _tracked(shift_m: float, turn_deg: float, held: bool = True) -> Decision:
    """Return a scan tracked by its prediction, which the alignment moved by shift and turn."""
    moved = np.eye(4)
    moved[:3, :3] = Rotation.from_euler('z', turn_deg, degrees=True).as_matrix()
    moved[0, 3] = shift_m
    alignment = Alignment(moved, np.eye(4), True, 5, 900, 1000, 1.0, np.eye(6))
    candidate = Candidate('prediction', np.eye(4), alignment, '')
    decision = Decision.of_alignment('prediction', 'tracked (1 in a row)', alignment, 1.0)
    decision.candidates = [candidate]
    decision.held = held
    return decision


def test_a_tracked_scan_the_alignment_barely_moved_skips_the_sweep_alignment() -> None:
    config = RegistrationConfig()
    assert config.sweep_alignment.steady_correction == 0.05
    assert steady(_tracked(0.02, 0.05), config)
    assert not steady(_tracked(0.08, 0.05), config)  # moved: the motion changed
    assert not steady(_tracked(0.02, 0.5), config)  # turned
    assert not steady(_tracked(0.02, 0.05, held=False), config)  # a rotated or still start
    off = config.replace({'sweep_alignment.steady_correction': 0.0})
    assert not steady(_tracked(0.0, 0.0), off)
