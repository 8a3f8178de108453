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

"""The odometry's trust rules (core/odometry/trust.py): known answers on made-up alignments."""

from __future__ import annotations

from mlsemreg_ros.core.alignment.alignment import Alignment
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry.trust import MAX_TRACKING_GAP, Trust
import numpy as np
import pytest

ODOMETRY = RegistrationConfig().odometry


def _alignment(shift_m: float, inliers: int, points: int = 1000) -> Alignment:
    """Return an alignment that moved the identity guess by ``shift_m`` along x."""
    refined = np.eye(4)
    refined[0, 3] = shift_m
    return Alignment(refined, np.eye(4), True, 5, inliers, points, 1.0, np.eye(6))


def test_a_candidate_is_trusted_within_the_correction_bounds_and_the_usual_inliers() -> None:
    trust = Trust()
    kept = _alignment(0.1, 900)
    assert trust.judge('prediction', np.eye(4), kept, ODOMETRY).acceptable
    moved = _alignment(ODOMETRY.max_correction_translation + 0.5, 900)
    assert 'max_correction' in trust.judge('global', np.eye(4), moved, ODOMETRY).refusal
    few = _alignment(0.1, int(1000 * ODOMETRY.min_inlier_fraction) - 1)
    assert 'min_inlier_fraction' in trust.judge('global', np.eye(4), few, ODOMETRY).refusal


def test_relative_inliers_follow_the_accepted_history_and_a_restart_forgets_it() -> None:
    trust = Trust()
    share = ODOMETRY.min_relative_inlier_fraction
    usual, low = 0.95, 0.95 * share - 0.05
    candidate = _alignment(0.1, int(1000 * low))
    assert low >= ODOMETRY.min_inlier_fraction  # only the relative rule can refuse it
    assert trust.judge('prediction', np.eye(4), candidate, ODOMETRY).acceptable  # no history
    for _ in range(3):
        trust.accepted(usual)
    trust.accepted(None)  # not aligned to the map: not recorded
    refusal = trust.judge('prediction', np.eye(4), candidate, ODOMETRY).refusal
    assert 'min_relative_inlier_fraction' in refusal
    trust.restart()
    assert trust.judge('prediction', np.eye(4), candidate, ODOMETRY).acceptable


@pytest.mark.parametrize(
    ('shift_m', 'gap', 'in_a_row', 'why'),
    [
        (0.05, 1.0, 0, ''),
        (ODOMETRY.tracking_translation + 0.1, 1.0, 0, 'odometry.tracking_'),
        (0.05, MAX_TRACKING_GAP + 0.5, 0, 'gap'),
        (0.05, 1.0, ODOMETRY.global_interval, 'global_interval'),
    ],
)
def test_tracking_trusts_a_small_correction_without_a_gap_for_a_while(
    shift_m, gap, in_a_row, why
) -> None:
    trust = Trust()
    trust.tracked_in_a_row = in_a_row
    predicted = trust.judge('prediction', np.eye(4), _alignment(shift_m, 950), ODOMETRY)
    refusal = trust.tracking_refusal(predicted, gap, ODOMETRY)
    assert (why in refusal) if why else refusal == ''
    assert 'no prediction' in trust.tracking_refusal(None, 1.0, ODOMETRY)
