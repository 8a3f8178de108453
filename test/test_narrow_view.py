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
A narrow view in a turn (core/odometry/narrow_view.py, issue 35).

Known answers of the overlap a turn leaves, of the relative-inlier rule scaled by it and of
the turn bound; and (slow, about 30 s) the simulated solid-state drive of seed 1 at stride
5 with geometric labels, whose scan 25 begins a 22 deg-a-step turn: the constant-velocity
guess is 12 deg off and the global registration fails, so it and every scan after it were
refused. Turned starts register it right, and the next one. Also (slow, about 35 s each) at
stride 1: the seed-5 drive, whose scan 108 begins a turn, registered and keeping the turn
(a place the near-miss starts found, held as tracked: ``turn_starts.held_basins``), and the
seed-1 drive, whose scan 4 waited for the sweep alignment's confirmation on session 19's code
(now scan 2 is found along the view) and whose scans 20-29 are right; and the seed-7 drive's
start into a turn at stride 1 (session 20).
"""

from pathlib import Path
from types import SimpleNamespace

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry.motion_model import Prediction
from mlsemreg_ros.core.odometry.narrow_view import (
    CAP_ROTATION,
    held_bound,
    MIN_OVERLAP,
    turn_bound,
    unbent_confirmation_refusal,
    View,
    view_overlap,
)
from mlsemreg_ros.core.odometry.rotated_starts import yaw_rotated
from mlsemreg_ros.core.odometry.steps import Decision
from mlsemreg_ros.core.odometry.trust import InlierHistory, relative_inlier_refusal
from mlsemreg_ros.core.odometry.turn_starts import (
    held_basins,
    started,
    turn_offsets,
    turn_starts,
)
import numpy as np
import pytest
from sim_bags import assert_no_wrong_pose, evaluated_rows, simulated_drive


def test_a_turn_leaves_a_share_of_a_narrow_view_and_all_of_a_ring() -> None:
    """``1 - turn / span`` on a partial view, clipped; 1 on a full ring or with no pose."""
    assert view_overlap(30.0, 360.0) == 1.0
    assert view_overlap(0.0, 70.0) == 1.0
    assert view_overlap(21.0, 70.0) == pytest.approx(0.7)
    assert view_overlap(-21.0, 70.0) == pytest.approx(0.7)
    assert view_overlap(69.0, 70.0) == MIN_OVERLAP
    view = View(span_deg=70.0)
    assert view.overlap(yaw_rotated(np.eye(4), 21.0)) == 1.0  # no last pose yet
    view.since((np.eye(4), 1_000_000_000), 1_500_000_000)
    assert view.gap_s == pytest.approx(0.5)
    assert view.overlap(yaw_rotated(np.eye(4), 21.0)) == pytest.approx(0.7)
    assert View(span_deg=350.0).overlap(yaw_rotated(np.eye(4), 21.0)) == 1.0


def test_the_relative_inlier_rule_expects_less_after_a_turn() -> None:
    """Scan 25 of the seed-1 drive kept 0.34 of the scan after 0.55-0.69: right, and refused."""
    history = InlierHistory()
    for fraction in (0.55, 0.69, 0.65):
        history.append(fraction)
    alignment = SimpleNamespace(inlier_fraction=0.34)
    assert relative_inlier_refusal(alignment, 0.6, history)  # 0.34 < 0.6 x 0.65
    assert 'after the turn' in relative_inlier_refusal(alignment, 0.6, history, 0.9)
    assert not relative_inlier_refusal(alignment, 0.6, history, 0.7)  # 0.34 >= 0.27


def test_the_turn_bound() -> None:
    """The floor, a turn rate over the gap (plus the predicted turn on a narrow view), the cap."""
    view = View(span_deg=70.0)
    assert turn_bound(view, np.eye(4), 5.0, 45.0) == 5.0  # no last pose: the floor
    view.since((np.eye(4), 1_000_000_000), 1_100_000_000)  # 0.1 s: 4.5 deg
    assert turn_bound(view, np.eye(4), 5.0, 45.0) == pytest.approx(5.0)
    assert turn_bound(view, yaw_rotated(np.eye(4), 8.0), 5.0, 45.0) == pytest.approx(12.5)
    assert turn_bound(view, yaw_rotated(np.eye(4), 0.8), 5.0, 45.0) == pytest.approx(5.3)
    ring = View(span_deg=360.0)  # a full ring: the larger of 1.5 x 8 and 4.5 deg
    ring.since((np.eye(4), 1_000_000_000), 1_100_000_000)
    assert turn_bound(ring, yaw_rotated(np.eye(4), 8.0), 5.0, 45.0) == pytest.approx(12.0)
    assert turn_bound(ring, yaw_rotated(np.eye(4), 0.8), 5.0, 45.0) == pytest.approx(5.0)
    view.since((np.eye(4), 1_000_000_000), 1_500_000_000)  # 0.5 s
    assert turn_bound(view, np.eye(4), 5.0, 45.0) == pytest.approx(22.5)
    view.since((np.eye(4), 1_000_000_000), 2_000_000_000)  # 1 s
    assert turn_bound(view, np.eye(4), 5.0, 45.0) == CAP_ROTATION


def test_the_held_bound() -> None:
    """The correction bound plus a turn rate over the gap, within the cap."""
    view = View(span_deg=70.0)
    assert held_bound(view, 5.0, 45.0) == 5.0  # no last pose: the floor
    view.since((np.eye(4), 1_000_000_000), 1_100_000_000)  # 0.1 s: 5 + 4.5 deg
    assert held_bound(view, 5.0, 45.0) == pytest.approx(9.5)
    assert held_bound(view, 5.0, 0.0) == pytest.approx(5.0)
    view.since((np.eye(4), 1_000_000_000), 2_000_000_000)  # 1 s
    assert held_bound(view, 5.0, 45.0) == CAP_ROTATION


def test_the_turned_starts_offsets() -> None:
    """Every 2.5 deg on a narrow view, finest first, strictly within the bound, up to 20 deg."""
    assert turn_offsets(2.5) == []
    assert turn_offsets(5.0) == [2.5, -2.5]  # a turn's onset at stride 1 (0.1 s)
    assert turn_offsets(9.0) == [2.5, -2.5, 5.0, -5.0, 7.5, -7.5]
    assert turn_offsets(13.5)[-2:] == [12.5, -12.5] and len(turn_offsets(13.5)) == 10
    assert turn_offsets(30.0)[-2:] == [20.0, -20.0] and len(turn_offsets(30.0)) == 16
    assert turn_offsets(22.5, fine=False) == [10.0, -10.0, 20.0, -20.0]  # a full ring
    assert turn_offsets(5.0, fine=False) == []


def test_a_narrow_views_turned_start_is_also_judged_on_the_scan_it_deskews() -> None:
    """On a narrow view: the start on the scan, then on the scan deskewed by its own twist."""
    scan, redone, T_start = object(), object(), yaw_rotated(np.eye(4), -5.0)
    judged_on: list[tuple[str, object]] = []
    asked: list[np.ndarray] = []

    def judged(name: str, T: np.ndarray, on: object) -> SimpleNamespace:
        judged_on.append((name, on))
        return SimpleNamespace(name=name, T_initial=T, on=on)

    def redeskew(T: np.ndarray) -> object:
        asked.append(T)
        return redone

    out = started(judged, T_start, scan, True, redeskew)
    assert [(c.name, c.on) for c, _ in out] == [('turn', scan), ('rotated', redone)]
    assert out[0][1] is None and np.allclose(out[1][1], T_start)
    assert len(asked) == 1 and np.allclose(asked[0], T_start)  # deskewed by the start's twist
    judged_on.clear()
    assert [c.on for c, _ in started(judged, T_start, scan, False, redeskew)] == [scan]  # ring
    assert [c.on for c, _ in started(judged, T_start, scan, True, None)] == [scan]
    assert [c.on for c, _ in started(judged, T_start, scan, True, lambda T: None)] == [scan]


def test_an_unbent_sweep_alignment_confirms_a_pose_it_keeps() -> None:
    """Its own pose within near_miss.weak_confirmation: confirmed; farther, or none: not."""
    config = RegistrationConfig()
    bound = config.near_miss.weak_confirmation
    near, far = np.eye(4), np.eye(4)
    near[1, 3] = 0.5 * bound
    far[1, 3] = 2.0 * bound
    assert unbent_confirmation_refusal(np.eye(4), near, config) == ''
    assert 'moved it by' in unbent_confirmation_refusal(np.eye(4), far, config)
    assert 'did not replace' in unbent_confirmation_refusal(np.eye(4), None, config)


def test_no_held_basin_for_a_refused_or_a_well_held_prediction() -> None:
    """Only an acceptable refined prediction that kept less than tracking asks is looked at."""
    config = RegistrationConfig()
    share = config.odometry.tracking_min_inlier_fraction
    for refusal, fraction in (('refused', 0.5), ('', share), ('', 0.95)):
        refined = SimpleNamespace(
            acceptable=not refusal, alignment=SimpleNamespace(inlier_fraction=fraction)
        )
        assert held_basins(None, refined, np.eye(4), None, config) == []


def test_no_turned_start_from_a_still_start_without_a_prediction_or_when_off() -> None:
    """The refused decision comes back untouched: nothing else is asked of the tracker."""
    config = RegistrationConfig()
    refused = Decision(source='', reason='refused')
    moving = Prediction(np.eye(4), 1.0)
    still = Prediction(np.eye(4), 1.0, still=True)
    last = (np.eye(4), 1_000_000_000)
    ring, narrow = View(span_deg=360.0), View(span_deg=70.0)
    ring.since(last, 1_500_000_000)
    narrow.since(last, 1_500_000_000)
    for view, prediction in ((ring, still), (narrow, still), (narrow, None)):
        tracker = SimpleNamespace(trust=SimpleNamespace(view=view))
        assert turn_starts(tracker, refused, prediction, None, config) is refused
    config.odometry.turn_rate = 0.0
    for view in (ring, narrow):
        tracker = SimpleNamespace(trust=SimpleNamespace(view=view))
        assert turn_starts(tracker, refused, moving, None, config) is refused


def _run(drive: Path, out: Path, *options: str, labels: str = 'geometric') -> list[dict[str, str]]:
    return evaluated_rows(drive, out, '--labels', labels, '--stride', '5', *options)


@pytest.mark.slow
def test_the_solid_state_drive_keeps_its_turn_at_stride_5(tmp_path: Path) -> None:
    drive = simulated_drive(tmp_path / 'livox1', 'livox', 36, 1)
    rows = _run(drive, tmp_path / 'run')
    assert_no_wrong_pose(rows)
    by_frame = {int(r['frame']): r for r in rows}
    assert by_frame[5]['source'] == 'turn', by_frame[5]['message']
    assert all(by_frame[k]['success'] == 'True' for k in (5, 6)), rows
    before = _run(drive, tmp_path / 'off', '--set', 'odometry.turn_rate=0')
    assert before[5]['accepted'] == 'False'  # the code before: refused, and the rest


@pytest.mark.slow
def test_a_ring_without_labels_keeps_its_turn_at_stride_5(tmp_path: Path) -> None:
    """
    A VLP-16 at 2 Hz entering a 90 deg turn, unlabeled: scan 5 is 11.8 deg off its guess.

    The start turned by 20 deg lands 6 deg further in the right basin; its correction from
    that start was refused by the car's 5 deg bound, and the global registration without
    labels finds 38 inliers: scan 5 and every later scan of the turn were refused.
    """
    # the route follows the drive's length: 60 frames, as measured
    drive = simulated_drive(tmp_path / 'vlp1', 'vlp16', 60, 1)
    rows = _run(drive, tmp_path / 'run', '--max-frames', '36', labels='none')
    assert_no_wrong_pose(rows)
    by_frame = {int(r['frame']): r for r in rows}
    assert by_frame[5]['source'] == 'turn', by_frame[5]['message']
    assert all(r['success'] == 'True' for r in rows[1:]), [r['message'] for r in rows]
    off = ('--max-frames', '36', '--set', 'odometry.turn_rate=0')
    before = _run(drive, tmp_path / 'off', *off, labels='none')
    assert before[5]['accepted'] == 'False'


@pytest.mark.slow
def test_the_solid_state_drive_keeps_a_turns_onset_at_stride_1(tmp_path: Path) -> None:
    """
    Seed 5's scan 108: the guess 3.9 deg off, its refinement 0.56 m off and disputed.

    The near-miss starts all found one place keeping 0.94 of the scan (0.17 m from the
    truth); on main it and the next nine scans were refused (docs/sensors.md, session 19).
    """
    drive = simulated_drive(tmp_path / 'livox5', 'livox', 120, 5)
    rows = evaluated_rows(drive, tmp_path / 'run', '--labels', 'geometric', '--max-frames', '112')
    assert_no_wrong_pose(rows)
    by_frame = {int(r['frame']): r for r in rows}
    assert by_frame[108]['source'] == 'turn', by_frame[108]['message']
    assert all(by_frame[k]['success'] == 'True' for k in range(108, 112)), rows[108:]


@pytest.mark.slow
def test_the_solid_state_drive_of_seed_1_at_stride_1(tmp_path: Path) -> None:
    """Scans 2-4 right from the search along the view, and scans 20-29 through the two basins."""
    drive = simulated_drive(tmp_path / 'livox1', 'livox', 60, 1)
    rows = evaluated_rows(drive, tmp_path / 'run', '--labels', 'geometric', '--max-frames', '30')
    assert_no_wrong_pose(rows)
    # scan 4: confirmed by an unbent sweep alignment on session 19's code (scans 1-3 refused);
    # since session 20 scan 2 is found along the view and scans 2-4 are right from it
    assert 'search along the view' in rows[2]['message'], rows[2]['message']
    assert all(r['success'] == 'True' for r in rows[2:5]), [r['message'] for r in rows[2:5]]
    # scans 22-23: "two basins" along the road on session 18's code; on livox1's branch scan
    # 23 came from a 5 deg turned start, merged with the other session-19 rules by its
    # prediction: either way every scan of that stretch right
    assert all(r['success'] == 'True' for r in rows[20:30]), [r['message'] for r in rows[20:30]]


@pytest.mark.slow
def test_the_solid_state_drive_of_seed_7_keeps_its_start_at_stride_1(tmp_path: Path) -> None:
    """
    Seed 7 starts into a 43 deg/s turn: its second scan refused, then no prediction.

    On session 19's code scans 1-10 were refused (a still start covers only the second scan,
    the search along the view only sparse streams). Now the third is found along the view
    (0.2 s from the keyframe) and the turn's onset, scan 4, is registered by a turned start
    judged on the scan deskewed by its own twist (docs/sensors.md, session 20).
    """
    drive = simulated_drive(tmp_path / 'livox7', 'livox', 60, 7)
    rows = evaluated_rows(drive, tmp_path / 'run', '--labels', 'geometric', '--max-frames', '12')
    assert_no_wrong_pose(rows)
    assert 'search along the view' in rows[2]['message'], rows[2]['message']
    assert rows[4]['source'] == 'turn', rows[4]['message']
    assert all(r['success'] == 'True' for r in rows[2:12]), [r['message'] for r in rows[2:12]]
