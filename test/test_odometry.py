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
Odometry: keyframe policies, pose accumulation, refusal to advance on failures.

A scripted registration stands in for the pipeline, so these tests check the
bookkeeping alone (the real pipeline runs in test_eval_bag.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from mlsemreg_ros.core.config import ConfigError, RegistrationConfig
from mlsemreg_ros.core.odometry import KeyframePolicy, Odometry, rotation_angle_deg
from mlsemreg_ros.core.results import Correspondences, RegistrationResult
from mlsemreg_ros.simulation.trajectory import euler_to_matrix
import numpy as np
import pytest


def transform(x: float, yaw_deg: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = euler_to_matrix(np.zeros(1), np.zeros(1), np.radians([yaw_deg]))[0]
    T[0, 3] = x
    return T


@dataclass
class Tagged:
    """Stand-in for a PreparedScan."""

    scan_id: int
    timings_ms: dict[str, float] = field(default_factory=dict)


class ScriptedRegistration:
    """prepare() tags each scan; register() returns scripted (transform, success)."""

    def __init__(self, script: list[tuple[np.ndarray, bool]]) -> None:
        self.script = list(script)
        self.config = RegistrationConfig()
        self.calls: list[tuple[int, int]] = []
        self.prepared = 0

    def prepare(self, points: np.ndarray, labels: np.ndarray) -> Any:
        self.prepared += 1
        return Tagged(int(points[0, 0]))  # the scan id, written into its first point

    def register(self, source: Any, target: Any) -> RegistrationResult:
        self.calls.append((source.scan_id, target.scan_id))
        T, success = self.script.pop(0)
        empty = np.zeros(0, dtype=np.int64)
        return RegistrationResult(T, Correspondences(empty, empty, np.zeros(0, np.float32)),
                                  np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, bool),
                                  success, 'ml-semreg', '' if success else 'too few inliers')


def scan(scan_id: int) -> tuple[np.ndarray, np.ndarray]:
    points = np.zeros((4, 3))
    points[0, 0] = scan_id
    return points, np.zeros(4, np.int64)


def test_every_frame_accumulates_and_refuses_to_advance_on_failure() -> None:
    script = [(transform(1.0), True), (transform(50.0), False), (transform(2.0), True)]
    registration = ScriptedRegistration(script)
    odometry = Odometry(registration, KeyframePolicy('every_frame'))
    first = odometry.process(*scan(0), stamp_ns=10)
    assert first.result is None and first.accepted and first.new_keyframe
    np.testing.assert_array_equal(first.pose, np.eye(4))
    step = odometry.process(*scan(1), stamp_ns=20)
    assert step.accepted and step.new_keyframe and step.keyframe_index == 0
    np.testing.assert_allclose(step.pose, transform(1.0))
    failed = odometry.process(*scan(2), stamp_ns=30)
    assert not failed.accepted and not failed.new_keyframe and failed.keyframe_index == 1
    np.testing.assert_allclose(failed.pose, transform(1.0))  # held, not moved by 50 m
    recovered = odometry.process(*scan(3), stamp_ns=40)
    assert recovered.keyframe_index == 1  # registered onto the kept keyframe, not scan 2
    np.testing.assert_allclose(recovered.pose, transform(3.0))
    assert registration.calls == [(1, 0), (2, 1), (3, 1)]
    assert registration.prepared == 4  # the keyframe's prepared scan is cached


def test_distance_policy_keeps_the_keyframe_until_it_moved_or_turned() -> None:
    script = [(transform(0.4), True), (transform(0.8), True), (transform(1.2), True),
              (transform(0.1, yaw_deg=12.0), True), (transform(0.1), True)]
    registration = ScriptedRegistration(script)
    odometry = Odometry(registration, KeyframePolicy('distance', min_distance=1.0,
                                                     min_rotation=10.0))
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


def test_policy_validation_and_helpers() -> None:
    with pytest.raises(ConfigError):
        KeyframePolicy('sometimes')
    with pytest.raises(ConfigError):
        KeyframePolicy('distance', min_distance=-1.0)
    policy = KeyframePolicy.from_flat({'keyframe.policy': 'distance',
                                       'keyframe.min_rotation': 5})
    assert policy == KeyframePolicy('distance', 1.0, 5.0)
    assert KeyframePolicy.from_config(policy) == policy
    assert abs(rotation_angle_deg(transform(0.0, 30.0)) - 30.0) < 1e-9


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
