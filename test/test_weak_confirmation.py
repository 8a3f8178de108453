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
A weakly held pose accepted on its own evidence needs the sweep alignment's confirmation.

``near_miss.min_weak_support`` refused every own-evidence candidate whose weakest direction
held fewer than 10 inliers' worth of information, the right solid-state first registrations
(support 7.6 and 4.4) with the wrong ones (3.1 and 5.2). Such a candidate is now accepted
only if the sweep alignment, with the scan deskewed by the motion the candidate implies,
keeps a pose within ``near_miss.weak_confirmation`` of it (issue 35). Known answers with
the start's deskew and the sweep alignment stubbed; the solid-state drive of seed 1 at
stride 10, whose first registration is right and was refused; and that of seed 7 at stride 5,
whose first registration, 0.96 m off, the sweep alignment moves by 0.82 m (not published).
"""

from types import SimpleNamespace

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry import Odometry, tracking
from mlsemreg_ros.core.odometry.steps import Decision
from mlsemreg_ros.core.odometry.trust import Trust
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.simulation.field import FieldConfig, FieldSimulation
import numpy as np
import pytest


def _translation(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    return T


@pytest.mark.parametrize(
    ('moved_m', 'kept', 'confirmed'),
    [(0.0, True, True), (0.21, True, True), (0.82, True, False), (0.1, False, False)],
)
def test_the_sweep_alignment_confirms_a_pose_it_keeps_close(
    moved_m: float, kept: bool, confirmed: bool
) -> None:
    refusal = tracking.weak_confirmation_refusal(
        _translation(10.0), _translation(10.0 + moved_m), kept, RegistrationConfig()
    )
    assert (refusal == '') == confirmed, refusal


class _Map:
    """A local map that records what it holds."""

    def __init__(self) -> None:
        self.scans: list[str] = ['the first scan deskewed']
        self.empty = False

    def clear(self) -> None:
        self.scans = []

    def insert_scan(self, scan: str, pose: np.ndarray) -> None:
        self.scans.append(scan)


def _align_accepted(monkeypatch, moved_m: float) -> tuple[tracking.Tracker, _Map, tuple, Decision]:
    """``Tracker.align_accepted`` of a weak decision at a start; the sweep moves it."""
    local_map = _Map()
    tracker = tracking.Tracker(local_map, Trust())
    tracker.trust.history.append(0.5)
    swept = _translation(10.0 + moved_m)
    redone = SimpleNamespace(scan='the scan deskewed by the sweep')
    tracker.deskew_start = lambda start, raw, pose, *args: (raw, pose)
    tracker.align_sweep = lambda raw, pose, *args: (
        redone,
        swept,
        'sweep alignment: bent',
        None,
        1.0,
    )
    monkeypatch.setattr(tracking, 'implied_twist', lambda *args: None)
    first = SimpleNamespace(scan='the first scan', points='first points', labels='first labels')
    keyframe = SimpleNamespace(stamp_ns=0, points=None, labels=None, prepared=None)
    chosen = Decision('global', 'accepted on its own evidence', pose=_translation(10.0))
    chosen.inlier_fraction, chosen.confirm_weak = 0.2, True
    raw = SimpleNamespace(scan='the scan')
    out = tracker.align_accepted(
        chosen, raw, (first, np.eye(4), 0), 1, keyframe, None, None, RegistrationConfig()
    )
    return tracker, local_map, (out, raw, redone, swept, keyframe), chosen


def test_an_unconfirmed_weak_pose_leaves_map_keyframe_and_history(monkeypatch) -> None:
    tracker, local_map, (out, raw, _, _, keyframe), chosen = _align_accepted(monkeypatch, 0.82)
    scan, pose, twist = out
    assert pose is None and scan is raw and twist is None
    assert 'not confirmed' in chosen.reason and 'near_miss.weak_confirmation' in chosen.reason
    assert local_map.scans == ['the first scan']  # the start's deskew undone
    assert keyframe.prepared == 'the first scan' and keyframe.points == 'first points'
    assert tracker.trust.history.typical() == 0.5  # the refused fraction not recorded


def test_a_confirmed_weak_pose_is_the_sweeps(monkeypatch) -> None:
    tracker, local_map, (out, _, redone, swept, _), chosen = _align_accepted(monkeypatch, 0.21)
    scan, pose, _ = out
    assert scan is redone
    np.testing.assert_allclose(pose, swept)
    assert 'confirmed by the sweep alignment' in chosen.reason
    assert local_map.scans == ['the first scan deskewed']
    assert tracker.trust.history.typical() == pytest.approx(0.35)  # 0.5 and 0.2


@pytest.mark.slow
def test_the_right_solid_state_first_registration_is_accepted() -> None:
    """Field drive seed 1, livox, stride 10 (1 s): scan 10 onto scan 0 is right, support 7.6."""
    sim = FieldSimulation(FieldConfig(seed=1, frames=60, sensor='livox'))
    frames = [sim.frame(k) for k in (0, 10)]
    truth = np.linalg.solve(frames[0].pose, frames[1].pose)
    outcomes = {}
    for confirmation in (0.0, None):  # 0: refused outright, the code before
        config = RegistrationConfig()
        if confirmation is not None:
            config = config.replace({'near_miss.weak_confirmation': confirmation})
        odometry = Odometry(Registration(config))
        for frame in frames:
            points = frame.scan.points.astype(np.float32).astype(np.float64)  # as in the bag
            labels, _ = sim.raw_labels(frame)  # the bag's label field
            step = odometry.process(points, labels, frame.stamp_ns, point_times=frame.scan.times)
        error = np.linalg.norm(np.linalg.solve(truth, step.pose)[:3, 3])
        outcomes[confirmation] = (step.accepted, error, step.reason)
    accepted, _, reason = outcomes[0.0]
    assert not accepted and 'min_weak_support' in reason, outcomes
    accepted, error, reason = outcomes[None]
    assert accepted and error < 0.3 and 'confirmed by the sweep alignment' in reason, outcomes


@pytest.mark.slow
def test_a_wrong_weak_pose_the_sweep_moves_is_not_published() -> None:
    """Field drive seed 7, livox, stride 5: scan 5 onto scan 0 was accepted 0.96 m off."""
    sim = FieldSimulation(FieldConfig(seed=7, frames=60, sensor='livox'))
    frames = [sim.frame(k) for k in (0, 5)]
    truth = np.linalg.solve(frames[0].pose, frames[1].pose)
    # Since session 14 (the first keyframe's pair refined, the BEV search's full graph off)
    # this pose is refused before the weak confirmation sees it, with either setting of
    # odometry.refine_first_keyframe; the rule itself is tested above on its own.
    for refine_first in (True, False):
        config = RegistrationConfig().replace({'odometry.refine_first_keyframe': refine_first})
        odometry = Odometry(Registration(config))
        for frame in frames:
            points = frame.scan.points.astype(np.float32).astype(np.float64)  # as in the bag
            labels, _ = sim.raw_labels(frame)
            step = odometry.process(points, labels, frame.stamp_ns, point_times=frame.scan.times)
        error = np.linalg.norm(np.linalg.solve(truth, step.pose)[:3, 3])
        assert not step.accepted or error < 0.6, (refine_first, error, step.reason)


def test_a_pose_on_its_own_evidence_needs_every_start_back_home() -> None:
    """starts_back: the count when every start came back, 0 when one left or none ran."""
    from mlsemreg_ros.core.odometry.second_look import starts_back

    config = RegistrationConfig()
    limit = config.near_miss.agreement_translation

    def at(x: float) -> SimpleNamespace:
        T = np.eye(4)
        T[0, 3] = x
        return SimpleNamespace(T_target_source=T)

    home = at(1.0)
    back = SimpleNamespace(others=[at(1.0 + 0.5 * limit), at(1.0 - 0.5 * limit)])
    left = SimpleNamespace(others=[at(1.0), at(1.0 + 2.0 * limit)])
    assert starts_back(home, back, config) == 2
    assert starts_back(home, left, config) == 0
    assert starts_back(home, SimpleNamespace(others=[]), config) == 0
