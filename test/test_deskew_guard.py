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
The deskew check (core/odometry/deskew_guard.py): a deskew that bends the scan is not used.

Known answers of the comparison, and a real dev pair whose moved scan carries a plausible
time field that does not give the capture times (a uint8 counter read as milliseconds, as
``mlsemreg fuzz-node`` sends it, with its IMU and wheel streams): with the check the scan
is registered raw, the pose is right and the step says why.
"""

from __future__ import annotations

from pathlib import Path

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry import Odometry
from mlsemreg_ros.core.odometry.deskew_guard import (
    deskew_refusal,
    DeskewCheckSchedule,
    FIRST_CHECKS,
)
from mlsemreg_ros.core.pipeline import Registration
import numpy as np
import pytest

DEV_PAIRS = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'kitti_pairs_dev'


def test_the_deskew_is_refused_only_when_the_raw_scan_keeps_more_inliers() -> None:
    assert deskew_refusal(0.53, 0.57, 0.0).startswith('the raw scan aligns better: 0.570')
    assert deskew_refusal(0.57, 0.53, 0.0) == ''
    assert deskew_refusal(0.53, 0.53, 0.0) == ''  # equal: the deskew is kept
    assert deskew_refusal(0.53, 0.55, 0.05) == ''  # within the margin: 0.55 < 1.05 x 0.53
    assert deskew_refusal(0.53, 0.57, 0.05).startswith('the raw scan')  # 7.5 % more
    # the default margin: the bent dev pair with the smallest gap is refused (2.1 % more),
    # the good IMU deskew of the field drive with the largest gap is kept (1.0 % more)
    margin = RegistrationConfig().preprocess.deskew_check_margin
    assert deskew_refusal(0.336, 0.343, margin) and not deskew_refusal(0.817, 0.825, margin)
    assert deskew_refusal(None, 0.9, 0.0) == '' and deskew_refusal(0.5, None, 0.0) == ''


def _checked(
    schedule: DeskewCheckSchedule, times: np.ndarray, interval: int, kept: bool, slow: bool = True
) -> bool:
    """Ask the schedule about one scan; record the check as ``kept`` if it is due."""
    due = schedule.due(times, interval, slow)
    if due:
        schedule.checked(times, kept)
    return due


def test_the_check_runs_on_every_scan_until_three_kept_the_deskew_then_every_interval() -> None:
    assert FIRST_CHECKS == 3
    sweep = np.linspace(0.0, 0.1, 100)  # a 0.1 s sweep
    schedule = DeskewCheckSchedule()
    due = [_checked(schedule, sweep, 4, kept=True) for _ in range(11)]
    assert due == [True] * 3 + [False, False, False, True] * 2  # then every 4th scan
    assert all(_checked(DeskewCheckSchedule(), sweep, 1, kept=True) for _ in range(5))
    # a check that refuses the deskew: every scan again until 3 in a row kept it
    assert [_checked(schedule, sweep, 4, kept=True) for _ in range(3)] == [False] * 3
    assert _checked(schedule, sweep, 4, kept=False)
    again = [_checked(schedule, sweep, 4, kept=True) for _ in range(7)]
    assert again == [True] * 3 + [False, False, False, True]
    # a time field whose span moves by more than a fifth is checked at once
    assert _checked(schedule, 2.0 * sweep, 4, kept=True)
    assert not _checked(schedule, 2.1 * sweep, 4, kept=True)  # 5 %: not a change
    assert _checked(schedule, None, 4, kept=True)  # no finite times: checked
    schedule.reset()  # an odometry reset: every scan again
    assert [_checked(schedule, sweep, 4, kept=True) for _ in range(4)] == [True] * 3 + [False]


def test_a_periodic_check_waits_for_a_globally_registered_scan() -> None:
    sweep = np.linspace(0.0, 0.1, 100)
    schedule = DeskewCheckSchedule()
    assert all(_checked(schedule, sweep, 4, kept=True, slow=False) for _ in range(3))
    # due at the 4th scan, but tracked scans pass until a global one (the 6th) comes
    due = [_checked(schedule, sweep, 4, kept=True, slow=k == 5) for k in range(8)]
    assert due == [False, False, False, False, False, True, False, False]
    # no global scan at all: checked after two intervals
    due = [_checked(schedule, sweep, 4, kept=True, slow=False) for _ in range(8)]
    assert due == [False] * 5 + [True, False, False]
    # a refusal, a reset or a moved span still check the next (tracked) scans at once
    assert _checked(schedule, 2.0 * sweep, 4, kept=False, slow=False)
    assert all(_checked(schedule, 2.0 * sweep, 4, kept=True, slow=False) for _ in range(3))


def _moved_scan_with_a_counter_for_times(check: bool) -> tuple[object, np.ndarray]:
    from mlsemreg_ros.datasets.pairs import list_pairs, load_pair
    from mlsemreg_ros.evaluation.hostile_cases import good_streams, Timeline

    pair = load_pair(list_pairs(DEV_PAIRS)[4])
    cfg = RegistrationConfig().replace({'keypoints.count': 2000, 'preprocess.deskew_check': check})
    odometry = Odometry(Registration(cfg))
    timeline = Timeline(1000.0, 1.0)  # the keyframe at t0, the moved scan at t2 (fuzz-node)
    streams = good_streams(pair.trans_gt, timeline)  # the pair's motion: 200 Hz IMU, 50 Hz wheels
    model = odometry.motion_model

    def feed(after: float, until: float) -> None:
        imu = [(t, f['gyro']) for t, f in streams['imu'] if after < t <= until]
        wheel = [(t, f['pose']) for t, f in streams['wheel'] if after < t <= until]
        stamps = np.array([round(t * 1e9) for t, _ in imu], dtype=np.int64)
        gravity = np.tile([0.0, 0.0, 9.81], (len(imu), 1))
        model.add_imu(stamps, np.stack([gyro for _, gyro in imu]), gravity)
        stamps = np.array([round(t * 1e9) for t, _ in wheel], dtype=np.int64)
        model.add_wheel(stamps, np.stack([pose for _, pose in wheel]))

    t0, _, t2 = timeline.scans
    feed(0.0, t0)
    odometry.process(pair.pts_dst, pair.label_dst, round(t0 * 1e9))
    feed(t0, t2 + 0.1)
    rng = np.random.default_rng(0)
    counter = np.round(np.sort(rng.uniform(0.0, 0.1, len(pair.pts_src))) * 2000)
    times = counter.astype(np.uint8) * 1e-3  # 0..200 read as ms: a plausible 0.2 s sweep
    step = odometry.process(pair.pts_src, pair.label_src, round(t2 * 1e9), point_times=times)
    return step, pair.trans_gt


@pytest.mark.skipif(not DEV_PAIRS.is_dir(), reason=f'no dev pairs at {DEV_PAIRS}')
def test_a_scan_bent_by_its_time_field_is_registered_raw() -> None:
    step, truth = _moved_scan_with_a_counter_for_times(check=True)
    assert step.accepted and not step.deskewed
    assert step.deskew_refusal.startswith('not used: the raw scan aligns better')
    assert np.linalg.norm((np.linalg.inv(truth) @ step.pose)[:3, 3]) < 0.6
