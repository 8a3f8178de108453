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
Never stuck after a refusal (issue 29): a keyframe must deserve it, recovery within two scans.

Known answers on hand-made clouds (a flat ground, a corridor, a street) for the keyframe's
structure rule; the real pipeline and small_gicp on a synthetic street drive for the
recovery: a degenerate first scan, a degenerate scan in the middle, a run of refusals that
ends in a relocalization onto a past keyframe or a flagged re-initialisation.
"""

from __future__ import annotations

from typing import Any

from mlsemreg_ros.core.alignment.alignment import AlignmentCloud
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.metrics import rotation_error_deg
from mlsemreg_ros.core.odometry import Odometry
from mlsemreg_ros.core.odometry.local_map import structure_ratio
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.results import RegistrationResult
from mlsemreg_ros.core.rigid import invert_transform
from mlsemreg_ros.datasets.synthetic_scene import motion, scan_at, street_scene
import numpy as np
import pytest
from street_map import street_drive

STEP_M = 1.5  # metres between scans of the synthetic drive
FRAMES = 11
CONFIG = RegistrationConfig().replace({'keypoints.count': 1000})
DEGENERATE = (np.array([[5.0, 0.0, 0.0], [0.0, 5.0, 0.0], [5.0, 5.0, 1.0]]), np.full(3, 9))


def _ground(rng: np.random.Generator, n: int = 20000) -> np.ndarray:
    return np.c_[rng.uniform(-30, 30, (n, 2)), rng.normal(0.0, 0.02, n)]


@pytest.fixture(scope='module')
def drive() -> list[tuple[np.ndarray, np.ndarray, np.ndarray, int]]:
    """(points, labels, T_world_sensor, stamp_ns) of a drive down the synthetic street."""
    return street_drive(FRAMES, -25.0, STEP_M, first_stamp=1)


def _right(step: Any, truth: np.ndarray) -> bool:
    delta = invert_transform(truth) @ step.pose
    return (
        rotation_error_deg(delta[:3, :3], np.eye(3)) < 0.5 and np.linalg.norm(delta[:3, 3]) < 0.1
    )


# -- 1. a keyframe must deserve it ----------------------------------------------------------
def test_structure_ratio_known_answers() -> None:
    rng = np.random.default_rng(0)
    ground = _ground(rng)
    walls = [
        np.c_[rng.uniform(-30, 30, 8000), np.full(8000, side), rng.uniform(0, 3, 8000)]
        for side in (-3.0, 3.0)
    ]
    corridor = np.vstack([ground[:8000] * [1.0, 0.1, 1.0], *walls])
    world, labels = street_scene(seed=3)
    street, _ = scan_at(world, labels, motion(0.0, (-25.0, 0.0, 0.0)), seed=1)
    ratios = {
        name: structure_ratio(AlignmentCloud.build(points, 0.5, 10))
        for name, points in (('ground', ground), ('corridor', corridor), ('street', street))
    }
    assert ratios['ground'][0] < 0.005  # nothing pins x and y
    assert ratios['corridor'][0] < 0.01  # nothing pins the corridor's axis
    assert abs(ratios['corridor'][1][0]) > 0.99  # ... which is x
    assert ratios['street'][0] > 0.1
    assert structure_ratio(AlignmentCloud.build(DEGENERATE[0]))[0] == 0.0


def test_a_scan_without_structure_becomes_no_keyframe(drive: Any) -> None:
    odometry = Odometry(Registration(CONFIG))
    ground = _ground(np.random.default_rng(1))
    flat = odometry.process(ground, np.full(len(ground), 9), stamp_ns=50_000_000)
    assert not flat.accepted and odometry.keyframe is None
    assert 'no keyframe yet' in flat.reason and 'too little structure' in flat.reason
    assert 'keyframe.min_structure' in flat.reason
    points, labels, _, stamp = drive[0]
    first = odometry.process(points, labels, stamp)
    assert first.accepted and first.source == 'first' and first.new_keyframe
    unchecked = Odometry(Registration(CONFIG.replace({'keyframe.min_structure': 0.0})))
    assert unchecked.process(ground, np.full(len(ground), 9), stamp_ns=1).accepted


# -- 2. recovery within two scans --------------------------------------------------------
def test_a_degenerate_first_scan_then_the_drive_registers(drive: Any) -> None:
    odometry = Odometry(Registration(CONFIG))
    tiny = odometry.process(*DEGENERATE, stamp_ns=50_000_000)
    assert not tiny.accepted and 'no keyframe yet' in tiny.reason
    origin = drive[0][2]
    steps = [odometry.process(points, labels, stamp) for points, labels, _, stamp in drive[:10]]
    truths = [invert_transform(origin) @ pose for _, _, pose, _ in drive[:10]]
    right = [s.accepted and _right(s, t) for s, t in zip(steps, truths, strict=True)]
    pairs = zip(steps, truths, strict=True)
    wrong = [s.index for s, t in pairs if s.accepted and not _right(s, t)]
    assert sum(right) >= 8 and not wrong, [(s.index, s.source, s.reason) for s in steps]


def test_the_scan_after_a_degenerate_one_registers(drive: Any) -> None:
    odometry = Odometry(Registration(CONFIG))
    origin = drive[0][2]
    steps = []
    for k, (points, labels, _, stamp) in enumerate(drive[:8]):
        if k == 4:
            steps.append(odometry.process(*DEGENERATE, stamp_ns=stamp))
            continue
        steps.append(odometry.process(points, labels, stamp))
    assert not steps[4].accepted
    for k in (5, 6, 7):  # the next scan: the prediction over the gap and the keyframe
        truth = invert_transform(origin) @ drive[k][2]
        assert steps[k].accepted and _right(steps[k], truth), (k, steps[k].reason)
    assert steps[5].keyframe_index == 3  # the degenerate scan never became the keyframe


class BlindRegistration(Registration):
    """The real pipeline, but registrations onto the targets in ``blind`` fail."""

    def __init__(self, config: RegistrationConfig) -> None:
        super().__init__(config)
        self.blind: set[int] = set()

    def register(self, source: Any, target: Any, refine: bool = True) -> RegistrationResult:
        result = super().register(source, target, refine=refine)
        if id(target) in self.blind:
            result.success, result.message = False, 'blind to this keyframe'
        return result


def test_a_run_of_refusals_relocalizes_onto_a_past_keyframe(drive: Any) -> None:
    config = CONFIG.replace({'keyframe.max_failures': 2, 'odometry.constant_velocity': False})
    registration = BlindRegistration(config)
    odometry = Odometry(registration)
    origin = drive[0][2]
    steps = []
    for k, (points, labels, _, stamp) in enumerate(drive[:7]):
        if k == 4:  # the keyframe (scan 3) stops registering anything
            registration.blind.add(id(odometry.keyframe.prepared))
        steps.append(odometry.process(points, labels, stamp))
    assert not steps[4].accepted and steps[4].source == ''
    assert steps[5].accepted and steps[5].source == 'relocalized', steps[5].reason
    assert 'past keyframe 2' in steps[5].reason and '2 frames rejected' in steps[5].reason
    for k in (5, 6):
        assert _right(steps[k], invert_transform(origin) @ drive[k][2]), k


def test_without_a_past_keyframe_the_run_reinitialises_flagged(drive: Any) -> None:
    config = CONFIG.replace(
        {
            'keyframe.max_failures': 2,
            'keyframe.relocalization_keyframes': 0,
            'odometry.constant_velocity': False,
        }
    )
    registration = BlindRegistration(config)
    odometry = Odometry(registration)
    steps = []
    for k, (points, labels, _, stamp) in enumerate(drive[:6]):
        if k == 4:
            registration.blind.add(id(odometry.keyframe.prepared))
        steps.append(odometry.process(points, labels, stamp))
    assert not steps[5].accepted and steps[5].source == 'reinitialized'
    assert 'relocalization failed (no past keyframe)' in steps[5].reason
    assert steps[5].covariance[0, 0] >= 100.0  # the jump is flagged
    np.testing.assert_array_equal(steps[5].pose, steps[3].pose)


# -- 2. no veto: a candidate refused by a rule its own evidence overrules ------------------
def _blind_from(config: RegistrationConfig, drive: Any, blind_from: int, frames: int) -> list:
    registration = BlindRegistration(config)
    odometry = Odometry(registration)
    steps = []
    for k, (points, labels, _, stamp) in enumerate(drive[:frames]):
        if k == blind_from:  # from here on every global registration fails
            registration.blind.add(id(odometry.keyframe.prepared))
        steps.append(odometry.process(points, labels, stamp))
    return steps


def test_a_prediction_refused_only_by_its_correction_is_judged_on_its_basin(drive: Any) -> None:
    """The global registration fails; the prediction moved more than the bound, yet is right."""
    config = CONFIG.replace({'odometry.max_correction_translation': 0.05})
    steps = _blind_from(config, drive, 3, 4)
    step = steps[3]
    assert 'moved its guess by' in step.reason and 'blind to this keyframe' in step.reason
    assert step.accepted and step.source == 'prediction', step.reason
    assert 'prediction accepted on its own evidence' in step.reason
    assert 'perturbed starts came back to it' in step.reason
    # the first pair moved 0.07 m > 0.05 m: refused, and scan 0 stays the keyframe
    # (0.1 s after it, within keyframe.restart_gap)
    assert steps[1].source == '' and steps[2].keyframe_index == 0
    assert _right(step, invert_transform(drive[0][2]) @ drive[3][2])
    unchecked = _blind_from(config.replace({'near_miss.enabled': False}), drive, 3, 4)
    assert not unchecked[3].accepted and 'own evidence' not in unchecked[3].reason


def test_a_right_global_pose_is_not_vetoed_by_the_inlier_history(drive: Any) -> None:
    """A successful registration whose map inliers are below the usual share stays accepted."""
    config = CONFIG.replace(
        {'odometry.constant_velocity': False, 'odometry.min_relative_inlier_fraction': 1.0}
    )
    origin = drive[0][2]
    for enabled in (True, False):
        odometry = Odometry(Registration(config.replace({'near_miss.enabled': enabled})))
        steps = [odometry.process(*drive[0][:2], drive[0][3])]
        for points, labels, _, stamp in drive[1:4]:
            for _ in range(10):  # the last frames overlapped the map far more than this one
                odometry.tracker.history.append(1.0)
            steps.append(odometry.process(points, labels, stamp))
        if not enabled:
            assert not any(s.accepted for s in steps[1:])
            assert all('min_relative_inlier_fraction' in s.reason for s in steps[1:])
            continue
        for step in steps[1:]:
            assert step.accepted and step.source == 'global', step.reason
            assert 'global accepted on its own evidence' in step.reason
            assert 'min_relative_inlier_fraction' in step.reason
            assert _right(step, invert_transform(origin) @ drive[step.index][2]), step.reason
