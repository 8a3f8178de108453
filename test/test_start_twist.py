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
The first pair under a second hypothesis of its first scan's twist (core/odometry/start_twist.py).

Known answers of the covariance's inflation, and a synthetic street drive whose first scan
is swept driving straight while the car then turns: the pair's mean twist bends the first
scan by the turn rate, and the pose it gives depends on a twist nobody measured. Beyond
``near_miss.start_twist_spread`` the pose is published with its covariance covering the
gap (its error then within 2.5 standard deviations; unchecked, beyond 3.5), or refused.
"""

from __future__ import annotations

from typing import Any

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry import Odometry
from mlsemreg_ros.core.odometry.start_twist import inflated_covariance
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.rigid import invert_transform
from mlsemreg_ros.datasets.synthetic_scene import motion, scan_at, street_scene
import numpy as np
import pytest

SWEEP_S = 0.1
SPEED = 8.0  # m/s along x
GAP_S = 2.0  # between the two scans
CONFIG = RegistrationConfig().replace({'keypoints.count': 1000})


def test_the_covariance_grows_along_the_gap_only() -> None:
    covariance = np.diag([0.01, 0.04, 0.01, 1e-4, 1e-4, 1e-4])
    disputed = np.array([0.3, 0.4, 0.0, 0.0, 0.0, 0.02])
    out = inflated_covariance(covariance, disputed)
    u = np.array([0.6, 0.8, 0.0])
    assert u @ out[:3, :3] @ u == pytest.approx(0.25)  # the gap 0.5 m, squared
    assert out[2, 2] == pytest.approx(0.01)  # across it: as it was
    assert out[5, 5] == pytest.approx(0.02**2)
    assert out[3, 3] == pytest.approx(1e-4) and out[4, 4] == pytest.approx(1e-4)
    assert np.allclose(out, out.T) and np.all(np.linalg.eigvalsh(out) > 0)
    wide = np.diag([1.0] * 6)  # already covers the gap: unchanged
    assert np.array_equal(inflated_covariance(wide, disputed), wide)


def _swept(points: np.ndarray, yaw_rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Return the points as a sweep sees them moving at SPEED along x turning at ``yaw_rate``."""
    times = (np.arctan2(points[:, 1], points[:, 0]) + np.pi) / (2.0 * np.pi) * SWEEP_S
    angle = yaw_rate * times  # the sensor at stamp + t: Rz(yaw_rate t), SPEED t along x
    shifted = points - np.c_[SPEED * times, np.zeros((len(times), 2))]
    c, s = np.cos(angle), np.sin(angle)
    seen = np.c_[c * shifted[:, 0] + s * shifted[:, 1], -s * shifted[:, 0] + c * shifted[:, 1]]
    return np.c_[seen, shifted[:, 2]], times


def _drive(yaw_deg: float) -> tuple[list[tuple[Any, ...]], np.ndarray]:
    """Scan 0 swept straight, scan 1 two seconds on, turned by ``yaw_deg`` and swept turning."""
    world, labels = street_scene(seed=3)
    pose_0 = motion(0.0, (-25.0, 0.0, 0.0))
    pose_1 = motion(yaw_deg, (-25.0 + SPEED * GAP_S, -2.0, 0.0))
    scans = []
    for k, (pose, rate) in enumerate(((pose_0, 0.0), (pose_1, np.radians(yaw_deg) / GAP_S))):
        points, scan_labels = scan_at(world, labels, pose, seed=1 + k, max_points=30000)
        seen, times = _swept(points, rate)
        scans.append((seen, scan_labels, 1_000_000_000 + round(k * GAP_S * 1e9), times))
    return scans, invert_transform(pose_0) @ pose_1


@pytest.fixture(scope='module')
def turn() -> tuple[list[tuple[Any, ...]], np.ndarray]:
    """Return the drive of a car turning 80 deg after its straight first sweep (-40 deg/s)."""
    return _drive(-80.0)


def _second(scans: list[tuple[Any, ...]], config: RegistrationConfig) -> Any:
    odometry = Odometry(Registration(config))
    steps = [odometry.process(p, labels, stamp, point_times=t) for p, labels, stamp, t in scans]
    assert steps[0].accepted
    return steps[1]


def _mahalanobis_translation(step: Any, truth: np.ndarray) -> float:
    error = invert_transform(truth) @ step.pose  # small: the translation in the pose's axes
    covariance = step.frame_covariance[:3, :3]
    return float(np.sqrt(error[:3, 3] @ np.linalg.solve(covariance, error[:3, 3])))


def test_a_first_pair_whose_pose_follows_the_unknown_twist_is_inflated_or_refused(
    turn: Any,
) -> None:
    scans, truth = turn
    inflated = _second(scans, CONFIG)
    assert inflated.accepted and 'covariance inflated' in inflated.reason, inflated.reason
    assert np.linalg.norm((invert_transform(truth) @ inflated.pose)[:3, 3]) > 0.2
    assert _mahalanobis_translation(inflated, truth) < 2.5  # 1.99
    unchecked = _second(scans, CONFIG.replace({'near_miss.start_twist_spread': 0.0}))
    assert unchecked.accepted and 'rotation rate' not in unchecked.reason
    assert np.allclose(unchecked.pose, inflated.pose)  # the pose is not moved
    assert _mahalanobis_translation(unchecked, truth) > 3.5  # 4.36: not covered
    refused = _second(scans, CONFIG.replace({'near_miss.start_twist_action': 'refuse'}))
    assert not refused.accepted and 'refused: the first scan without a rotation' in refused.reason


def test_a_first_pair_that_barely_turns_is_left_as_it_is() -> None:
    scans, truth = _drive(-4.0)  # the mean twist: -2 deg/s, a bend of 0.2 deg
    step = _second(scans, CONFIG)
    assert step.accepted and 'the first scan without a rotation rate moves' in step.reason
    assert 'inflated' not in step.reason and 'refused' not in step.reason
    assert np.linalg.norm((invert_transform(truth) @ step.pose)[:3, 3]) < 0.1
