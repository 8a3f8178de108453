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
Odometry: keyframe policies, pose accumulation, refusal to advance on failures, the local map.

A scripted registration stands in for the pipeline for the bookkeeping of the
scan-to-keyframe chain (``fine.method: off``); the fine-alignment odometry runs the
real pipeline and small_gicp on a synthetic street drive.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from mlsemreg_ros.core.config import ConfigError, KeyframeConfig, RegistrationConfig
from mlsemreg_ros.core.metrics import rotation_error_deg
from mlsemreg_ros.core.odometry import is_new_keyframe, Odometry
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.results import Correspondences, RegistrationResult
from mlsemreg_ros.core.rigid import invert_transform, rotation_angle_deg
from mlsemreg_ros.datasets.synthetic_scene import motion
from mlsemreg_ros.simulation.trajectory import euler_to_matrix
import numpy as np
import pytest
from street_map import street_drive

CHAIN = RegistrationConfig().replace({'fine.method': 'off'})


def transform(x: float, yaw_deg: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = euler_to_matrix(np.zeros(1), np.zeros(1), np.radians([yaw_deg]))[0]
    T[0, 3] = x
    return T


@dataclass
class Tagged:
    """Stand-in for a PreparedScan (with enough points and keypoints to be a keyframe)."""

    scan_id: int
    timings_ms: dict[str, float] = field(default_factory=dict)
    points: np.ndarray = field(default_factory=lambda: np.zeros((2000, 3)))
    keypoints: np.ndarray = field(default_factory=lambda: np.zeros((500, 3)))


class ScriptedRegistration:
    """prepare() tags each scan; register() returns scripted (transform, success)."""

    def __init__(
        self, script: list[tuple[np.ndarray, bool]], config: RegistrationConfig = CHAIN
    ) -> None:
        self.script = list(script)
        self.config = config
        self.calls: list[tuple[int, int]] = []
        self.prepared = 0

    def prepare(self, points: np.ndarray, labels: np.ndarray, lazy: bool = False) -> Any:
        self.prepared += 1
        if len(points) < 4:  # a degenerate scan
            return Tagged(int(points[0, 0]), points=points, keypoints=points)
        return Tagged(int(points[0, 0]))  # the scan id, written into its first point

    def register(self, source: Any, target: Any, refine: bool = True) -> RegistrationResult:
        self.calls.append((source.scan_id, target.scan_id))
        T, success = self.script.pop(0)
        empty = np.zeros(0, dtype=np.int64)
        return RegistrationResult(
            T,
            Correspondences(empty, empty, np.zeros(0, np.float32)),
            np.zeros((0, 3)),
            np.zeros((0, 3)),
            np.zeros(0, bool),
            success,
            'ml-semreg',
            '' if success else 'too few inliers',
        )


def scan(scan_id: int) -> tuple[np.ndarray, np.ndarray]:
    points = np.zeros((4, 3))
    points[0, 0] = scan_id
    return points, np.zeros(4, np.int64)


def test_every_frame_accumulates_and_refuses_to_advance_on_failure() -> None:
    script = [(transform(1.0), True), (transform(50.0), False), (transform(2.0), True)]
    registration = ScriptedRegistration(script)
    odometry = Odometry(registration)
    first = odometry.process(*scan(0), stamp_ns=10)
    assert first.result is None and first.accepted and first.new_keyframe
    np.testing.assert_array_equal(first.pose, np.eye(4))
    step = odometry.process(*scan(1), stamp_ns=20)
    assert step.accepted and step.new_keyframe and step.keyframe_index == 0
    np.testing.assert_allclose(step.pose, transform(1.0))
    failed = odometry.process(*scan(2), stamp_ns=30)
    assert not failed.accepted and not failed.new_keyframe and failed.keyframe_index == 1
    assert failed.reason == 'too few inliers'
    np.testing.assert_allclose(failed.pose, transform(1.0))  # held, not moved by 50 m
    recovered = odometry.process(*scan(3), stamp_ns=40)
    assert recovered.keyframe_index == 1  # registered onto the kept keyframe, not scan 2
    np.testing.assert_allclose(recovered.pose, transform(3.0))
    assert registration.calls == [(1, 0), (2, 1), (3, 1)]
    assert registration.prepared == 4  # the keyframe's prepared scan is cached


def test_distance_policy_keeps_the_keyframe_until_it_moved_or_turned() -> None:
    script = [
        (transform(0.4), True),
        (transform(0.8), True),
        (transform(1.2), True),
        (transform(0.1, yaw_deg=12.0), True),
        (transform(0.1), True),
    ]
    config = CHAIN.replace(
        {
            'keyframe.policy': 'distance',
            'keyframe.min_distance': 1.0,
            'keyframe.min_rotation': 10.0,
        }
    )
    odometry = Odometry(ScriptedRegistration(script, config))
    steps = [odometry.process(*scan(k)) for k in range(6)]
    assert [s.new_keyframe for s in steps] == [True, False, False, True, True, False]
    assert [s.keyframe_index for s in steps] == [0, 0, 0, 0, 3, 4]
    np.testing.assert_allclose(steps[3].pose, transform(1.2))
    np.testing.assert_allclose(steps[4].pose, transform(1.2) @ transform(0.1, 12.0))


def test_non_finite_estimates_are_refused_and_reset_restarts() -> None:
    bad = np.full((4, 4), np.nan)
    registration = ScriptedRegistration([(bad, True), (transform(1.0), True)])
    odometry = Odometry(registration)
    odometry.process(*scan(0))
    assert not odometry.process(*scan(1)).accepted
    odometry.reset()
    assert odometry.keyframe is None
    restart = odometry.process(*scan(2))
    assert restart.index == 0 and restart.new_keyframe
    np.testing.assert_array_equal(restart.pose, np.eye(4))


def test_keyframe_policy_validation_and_helpers() -> None:
    with pytest.raises(ConfigError, match='is not one of'):
        RegistrationConfig().replace({'keyframe.policy': 'sometimes'})
    with pytest.raises(ConfigError, match='below its minimum'):
        RegistrationConfig().replace({'keyframe.min_distance': -1.0})
    policy = KeyframeConfig('distance', 1.0, 5.0)
    assert not is_new_keyframe(policy, transform(0.5, 4.0))
    assert is_new_keyframe(policy, transform(0.5, 6.0)) and is_new_keyframe(policy, transform(1))
    assert is_new_keyframe(KeyframeConfig(), np.eye(4))
    assert abs(rotation_angle_deg(transform(0.0, 30.0)) - 30.0) < 1e-9


def test_a_degenerate_scan_never_becomes_the_keyframe() -> None:
    registration = ScriptedRegistration([(transform(1.0), True)])
    odometry = Odometry(registration)
    tiny = odometry.process(np.zeros((3, 3)), np.zeros(3, np.int64), stamp_ns=5)
    assert not tiny.accepted and 'no keyframe yet' in tiny.reason
    assert 'keyframe.min_points' in tiny.reason and odometry.keyframe is None
    first = odometry.process(*scan(1), stamp_ns=10)
    assert first.index == 0 and first.new_keyframe and first.source == 'first'
    assert odometry.process(*scan(2), stamp_ns=20).accepted


def test_a_run_of_failures_reinitialises_at_the_last_pose() -> None:
    script = [(transform(1.0), True)] + [(transform(9.0), False)] * 3 + [(transform(2.0), True)]
    config = CHAIN.replace({'keyframe.max_failures': 3})
    odometry = Odometry(ScriptedRegistration(script, config))
    steps = [odometry.process(*scan(k), stamp_ns=10 * (k + 1)) for k in range(6)]
    assert [s.accepted for s in steps] == [True, True, False, False, False, True]
    third = steps[4]
    assert (
        third.source == 'reinitialized'
        and third.new_keyframe
        and 'the last accepted pose' in third.reason
    )
    np.testing.assert_allclose(third.pose, transform(1.0))  # held, not moved
    assert steps[5].keyframe_index == 4  # registered onto the re-initialised keyframe
    np.testing.assert_allclose(steps[5].pose, transform(3.0))
    assert steps[5].covariance[0, 0] >= 100.0  # the unknown motion of the gap is admitted
    assert steps[2].source == steps[3].source == ''


def test_a_refused_first_pair_makes_the_newer_scan_the_keyframe_at_once() -> None:
    """Issue 29 item 2: with no motion known, later scans do not face an ever older keyframe."""
    script = [(transform(9.0), False), (transform(2.0), True), (transform(9.0), False)]
    config = CHAIN.replace({'keyframe.max_failures': 3, 'keyframe.restart_gap': 0.0})
    odometry = Odometry(ScriptedRegistration(script, config))
    steps = [odometry.process(*scan(k), stamp_ns=10 * (k + 1)) for k in range(4)]
    assert [s.accepted for s in steps] == [True, False, True, False]
    refused = steps[1]
    assert refused.source == 'reinitialized' and refused.new_keyframe
    assert 'no motion known' in refused.reason and refused.keyframe_index == 1
    np.testing.assert_allclose(refused.pose, np.eye(4))  # held: nothing wrong published
    assert refused.covariance[0, 0] >= 100.0  # the jump is flagged
    assert steps[2].keyframe_index == 1  # one step from the newer keyframe
    np.testing.assert_allclose(steps[2].pose, transform(2.0))
    assert steps[3].source == ''  # a pair was accepted: back to keyframe.max_failures


@pytest.mark.parametrize('gap_s', [0.1, 2.0])
def test_a_refused_scan_soon_after_the_keyframe_keeps_it(gap_s: float) -> None:
    """``keyframe.restart_gap``: a refused first pair restarts only when far in time."""
    script = [(transform(9.0), False), (transform(2.0), True)]
    odometry = Odometry(ScriptedRegistration(script, CHAIN.replace({'keyframe.max_failures': 3})))
    period = int(gap_s * 1e9)
    steps = [odometry.process(*scan(k), stamp_ns=period * (k + 1)) for k in range(3)]
    assert [s.accepted for s in steps] == [True, False, True]
    restarted = steps[1].source == 'reinitialized'
    assert restarted == (gap_s >= 1.0)
    assert steps[2].keyframe_index == (1 if restarted else 0)


def test_duplicate_stamps_are_skipped_and_backward_stamps_reset() -> None:
    registration = ScriptedRegistration([(transform(1.0), True), (transform(1.0), True)])
    odometry = Odometry(registration)
    odometry.process(*scan(0), stamp_ns=100)
    assert odometry.process(*scan(1), stamp_ns=200).accepted
    duplicate = odometry.process(*scan(2), stamp_ns=200)
    assert not duplicate.accepted and 'duplicate stamp' in duplicate.reason
    assert registration.prepared == 2  # not even prepared
    looped = odometry.process(*scan(3), stamp_ns=50)  # the bag started again
    assert looped.accepted and looped.source == 'first' and 'went backwards' in looped.reason
    np.testing.assert_array_equal(looped.pose, np.eye(4))
    assert odometry.process(*scan(4), stamp_ns=150).keyframe_index == 0
    unstamped = Odometry(ScriptedRegistration([(transform(1.0), True)] * 2))
    assert all(unstamped.process(*scan(k)).accepted for k in range(3))  # 0 = unstamped


def test_reconfigure_prepares_the_keyframe_again_only_when_preparation_changes() -> None:
    registration = ScriptedRegistration([])
    odometry = Odometry(registration)
    odometry.process(*scan(0), stamp_ns=10)
    assert registration.prepared == 1
    odometry.reconfigure(registration.config.replace({'estimator.min_inliers': 20}))
    assert registration.prepared == 1  # estimator-only change: cached keyframe kept
    odometry.reconfigure(registration.config.replace({'semantic.local_radius': 1.0}))
    assert registration.prepared == 2  # Local-SS changes: keyframe prepared again
    assert registration.config.semantic.local_radius == 1.0


# -- fine alignment against the local map (real pipeline, synthetic street) -------------
STEP_M = 1.5  # metres between scans of the synthetic drive
FRAMES = 8


@pytest.fixture(scope='module')
def drive() -> list[tuple[np.ndarray, np.ndarray, np.ndarray, int]]:
    """(points, labels, T_world_sensor, stamp_ns) of a drive down the synthetic street."""
    return street_drive(FRAMES, -20.0, STEP_M)


def _pose_errors(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    delta = invert_transform(truth) @ estimate
    return rotation_error_deg(delta[:3, :3], np.eye(3)), float(np.linalg.norm(delta[:3, 3]))


def test_map_odometry_follows_the_drive_to_centimetres(drive: Any) -> None:
    odometry = Odometry(Registration(RegistrationConfig().replace({'keypoints.count': 1000})))
    origin = drive[0][2]
    sources = []
    for points, labels, pose, stamp in drive:
        step = odometry.process(points, labels, stamp)
        assert step.accepted, step.reason
        sources.append(step.source)
        re, te = _pose_errors(step.pose, invert_transform(origin) @ pose)
        assert re < 0.05 and te < 0.02, (step.index, re, te)
        assert step.covariance.shape == (6, 6) and np.all(
            np.linalg.eigvalsh(step.covariance) >= -1e-12
        )
    assert sources[0] == 'first' and set(sources[2:]) <= {
        'prediction+global',
        'global',
        'prediction',
    }
    assert step.twist is not None  # ~15 m/s along x at 10 Hz stamps
    assert abs(step.twist[0] - STEP_M / 0.1) < 0.5
    assert odometry.local_map.insertions == FRAMES and len(odometry.local_map) > 0
    odometry.reset()
    assert odometry.local_map.empty and len(odometry.local_map) == 0
    assert odometry.keyframe is None and odometry.predict(0) is None


class FlippingRegistration(Registration):
    """The real pipeline, but the global estimate of one frame is turned by 180 deg."""

    flip_call = 3

    def __init__(self, config: RegistrationConfig) -> None:
        super().__init__(config)
        self.calls = 0

    def register(self, source: Any, target: Any, refine: bool = True) -> RegistrationResult:
        result = super().register(source, target, refine=refine)
        self.calls += 1
        if self.calls == self.flip_call:
            result.transform = motion(180.0, (0.0, 0.0, 0.0)) @ result.transform
        return result


@pytest.mark.parametrize('constant_velocity', [True, False])
def test_a_flipped_global_estimate_is_never_published(drive: Any, constant_velocity: bool) -> None:
    config = RegistrationConfig().replace(
        {
            'keypoints.count': 1000,
            'odometry.constant_velocity': constant_velocity,
            'odometry.global_registration': 'always',
        }
    )
    odometry = Odometry(FlippingRegistration(config))
    origin = drive[0][2]
    steps = [odometry.process(points, labels, stamp) for points, labels, _, stamp in drive]
    flipped = steps[FlippingRegistration.flip_call]
    if constant_velocity:  # the refined prediction wins against the flipped estimate
        assert flipped.accepted and flipped.source == 'prediction', flipped.reason
        assert 'disagrees' in flipped.reason
        assert [c.name for c in flipped.candidates] == ['prediction', 'global']
    else:  # no other candidate: the frame is rejected, the pose stays
        assert not flipped.accepted and 'global' in flipped.reason
        np.testing.assert_array_equal(flipped.pose, steps[FlippingRegistration.flip_call - 1].pose)
    for step, (_, _, pose, _) in zip(steps, drive, strict=True):
        if step.accepted:  # whatever was accepted is right
            re, te = _pose_errors(step.pose, invert_transform(origin) @ pose)
            assert re < 0.1 and te < 0.05, (step.index, step.source, re, te)
    after = FlippingRegistration.flip_call + 1
    assert all(s.accepted for s in steps[after:])


def test_on_demand_tracks_by_the_prediction_and_registers_globally_when_due(drive: Any) -> None:
    """Global registration: first frames, every global_interval-th scan, after a gap."""
    config = RegistrationConfig().replace({'keypoints.count': 1000, 'odometry.global_interval': 3})
    registration = FlippingRegistration(config)
    registration.flip_call = -1  # no flip: count the global registrations
    odometry = Odometry(registration)
    origin = drive[0][2]
    steps = []
    for k, (points, labels, pose, stamp) in enumerate(drive):
        if k == FRAMES - 1:
            stamp += 300_000_000  # a gap of three frame intervals in the stamps
        step = odometry.process(points, labels, stamp)
        assert step.accepted, step.reason
        re, te = _pose_errors(step.pose, invert_transform(origin) @ pose)
        assert re < 0.05 and te < 0.02, (step.index, step.source, re, te)
        steps.append(step)
    tracked = [s.result is None and s.source == 'prediction' for s in steps]
    # 0 first, 1 global (no velocity yet), then at most 2 tracked in a row, the gap: global
    assert tracked[:2] == [False, False] and not tracked[-1]
    assert tracked[2:4] == [True, True] and not tracked[4]
    assert registration.calls == sum(not t for t in tracked[1:])
    assert all('tracked' in s.reason for s, t in zip(steps, tracked, strict=True) if t)
    always = Odometry(Registration(config.replace({'odometry.global_registration': 'always'})))
    always_steps = [always.process(p, lab, st) for p, lab, _, st in drive[:4]]
    assert all(s.result is not None for s in always_steps[1:])  # every scan registered


def test_a_scan_stream_that_jumps_back_and_forth_is_never_tracked_wrongly(drive: Any) -> None:
    """Scans back and forth: the motion model is wrong every time; what is published is right."""
    odometry = Odometry(Registration(RegistrationConfig().replace({'keypoints.count': 1000})))
    origin = drive[0][2]
    order = [0, 3, 0, 3, 0, 3, 0]  # 4.5 m back and forth
    for k, which in enumerate(order):
        points, labels, pose, _ = drive[which]
        step = odometry.process(points, labels, 100_000_000 * (k + 1))
        if step.accepted:
            re, te = _pose_errors(step.pose, invert_transform(origin) @ pose)
            assert re < 0.1 and te < 0.05, (k, step.source, re, te)
        if k > 1:
            assert step.result is not None, (k, step.reason)  # never tracked: registered
