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

"""Known answers of the prediction's covariance (core) and the continuous outputs' helpers."""

from __future__ import annotations

import itertools
from typing import Any

from mlsemreg_ros.core.odometry.steps import (
    MIN_PREDICTION_SIGMA,
    prediction_covariance,
    PREDICTION_MODEL_ERROR,
)
import numpy as np
import pytest
from scipy.spatial.transform import Rotation


def make_transform(rotation: np.ndarray, translation: list[float]) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rotation, translation
    return T


def test_prediction_covariance_of_a_straight_step() -> None:
    predicted = make_transform(np.eye(3), [1.0, 0.0, 0.0])
    pose_cov = np.diag([1e-4] * 3 + [1e-6] * 3)
    frame = np.diag([4e-4] * 3 + [1e-6] * 3)
    cov = prediction_covariance(pose_cov, np.eye(4), predicted, frame, stamp_gap=2.0)
    sigma_t = PREDICTION_MODEL_ERROR * 1.0
    sigma_r = MIN_PREDICTION_SIGMA[1] * 2.0  # no rotation: the floor, per interval
    expected = pose_cov + np.diag([sigma_t**2] * 3 + [sigma_r**2] * 3) + frame * 4.0
    np.testing.assert_allclose(cov, expected, rtol=1e-12)


def test_prediction_covariance_is_rotated_into_odom_axes() -> None:
    R = Rotation.from_euler('z', 90, degrees=True).as_matrix()
    last = make_transform(R, [0.0, 0.0, 0.0])
    predicted = make_transform(R, [0.0, 1.0, 0.0])  # 1 m along the body's x
    frame = np.diag([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # uncertain along the body's x only
    cov = prediction_covariance(np.zeros((6, 6)), last, predicted, frame, 1.0)
    assert cov[1, 1] == pytest.approx(1.0 + PREDICTION_MODEL_ERROR**2)  # body x = odom y
    assert cov[0, 0] == pytest.approx(PREDICTION_MODEL_ERROR**2)


def test_a_longer_gap_never_shrinks_the_prediction_covariance() -> None:
    predicted = make_transform(np.eye(3), [0.1, 0.0, 0.0])
    covs = [
        np.diag(prediction_covariance(np.zeros((6, 6)), np.eye(4), predicted, None, gap))
        for gap in (0.5, 1.0, 2.0, 5.0)
    ]
    assert np.allclose(covs[0], covs[1])  # below one interval: one interval
    assert all(np.all(b >= a) for a, b in itertools.pairwise(covs))


def test_registered_points_go_through_the_pose_and_the_extrinsic() -> None:
    pytest.importorskip('rclpy')
    from mlsemreg_ros.ros.outputs import registered_points

    points = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    T_odom_sensor = make_transform(np.eye(3), [5.0, 0.0, 0.0])
    T_base_sensor = make_transform(np.eye(3), [0.0, 0.0, 1.5])
    out = registered_points(points, T_odom_sensor, T_base_sensor)
    np.testing.assert_allclose(out, [[6.0, 0.0, 1.5], [5.0, 2.0, 1.5]])


class _FakeNode:
    def create_timer(self, *args: Any, **kwargs: Any) -> None:
        return None


def test_heartbeat_status_counts_seconds_without_input() -> None:
    pytest.importorskip('rclpy')
    from mlsemreg_ros.ros.outputs import Heartbeat

    heartbeat = Heartbeat(_FakeNode(), None)
    start = heartbeat._started
    level, message, _ = heartbeat.status(start + 3.2)
    assert (level, message) == ('warn', 'no input for 3 s (no scan since start)')
    heartbeat.note_input()
    last = heartbeat._last_input
    assert heartbeat.status(last + 0.5)[:2] == ('ok', 'receiving input')
    assert heartbeat.status(last + 7.6)[:2] == ('warn', 'no input for 8 s')
