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

"""The keyframe's share of a scan's covariance (``covariance.keyframe_share``)."""

from __future__ import annotations

from dataclasses import replace

from mlsemreg_ros.core.alignment.covariance import (
    keyframe_covariances,
    keyframe_shares,
    keyframe_term,
    no_calibration,
)
from mlsemreg_ros.evaluation.covariance_calibration import (
    CovarianceSample,
    load_samples,
    nees_values,
    pose_error,
    save_samples,
    transform_log,
)
import numpy as np
from scipy.spatial.transform import Rotation

OFF = no_calibration()
ON = replace(OFF, keyframe_share=1.0, keyframe_residual_ratio=2.0)


def _transform(rotvec: np.ndarray, translation: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = translation
    return T


def test_a_keyframe_yaw_moves_a_scan_ten_metres_ahead_sideways() -> None:
    """A yaw variance s^2 at the keyframe: d^2 s^2 sideways at a scan d metres ahead."""
    sigma, distance = np.radians(0.5), 10.0
    keyframe = np.diag([0, 0, 0, 0, 0, sigma**2])
    T = _transform(np.zeros(3), np.array([distance, 0.0, 0.0]))
    moved = keyframe_covariances(keyframe[None], T[None], np.ones(1))[0]
    assert np.isclose(moved[1, 1], (distance * sigma) ** 2)
    assert np.isclose(moved[5, 5], sigma**2)
    assert np.isclose(abs(moved[1, 5]), distance * sigma**2)
    assert np.isclose(moved[0, 0], 0.0) and np.isclose(moved[2, 2], 0.0)
    half = keyframe_covariances(keyframe[None], T[None], np.array([0.5]))[0]
    assert np.allclose(half, 0.5 * moved)


def test_the_keyframe_covariance_follows_the_relative_pose_error() -> None:
    """Monte Carlo: a keyframe perturbed by its covariance moves the relative pose so."""
    rng = np.random.default_rng(3)
    root = rng.normal(size=(6, 6)) * np.array([0.05] * 3 + [0.004] * 3)[:, None]
    keyframe = root @ root.T
    T = _transform(np.array([0.1, -0.2, 0.7]), np.array([6.0, -2.0, 0.3]))
    errors = []
    for delta in rng.multivariate_normal(np.zeros(6), keyframe, size=20000):
        perturbed = np.linalg.inv(_transform(delta[3:], delta[:3])) @ T  # inv(K exp(d)) S
        errors.append(pose_error(perturbed, T))
    empirical = np.cov(np.array(errors).T)
    predicted = keyframe_covariances(keyframe[None], T[None], np.ones(1))[0]
    scale = np.sqrt(np.outer(np.diag(predicted), np.diag(predicted)))
    assert np.all(np.abs(empirical - predicted) <= 0.06 * scale + 1e-12)


def test_only_a_keyframe_that_fitted_looser_passes_its_covariance_on() -> None:
    """The keyframe's residual above keyframe_residual_ratio times the scan's; both known."""
    shares = keyframe_shares(
        np.array([0.3, 0.3, 0.3, 0.0, 0.3]), np.array([0.9, 0.5, 0.61, 3.0, 0.0]), ON
    )
    assert np.allclose(shares, [1.0, 0.0, 1.0, 0.0, 0.0])
    assert np.allclose(keyframe_shares(np.array([0.3]), np.array([3.0]), OFF), 0.0)
    bounded = replace(ON, keyframe_scan_residual=0.5)  # a loose scan: its own error
    assert np.allclose(
        keyframe_shares(np.array([0.3, 0.6]), np.array([3.0, 6.0]), bounded), [1, 0]
    )
    keyframe, T = np.eye(6) * 1e-4, _transform(np.zeros(3), np.array([5.0, 0, 0]))
    assert np.any(keyframe_term(keyframe, T, 0.3, 3.0, ON) != 0)
    assert np.all(keyframe_term(keyframe, T, 0.3, 0.4, ON) == 0)
    assert np.all(keyframe_term(None, T, 0.3, 3.0, ON) == 0)  # the first keyframe
    assert np.all(keyframe_term(keyframe, T, 0.3, 3.0, OFF) == 0)


def test_samples_keep_their_keyframe_and_it_reaches_the_nees(tmp_path) -> None:
    """The keyframe link survives a round trip; a loose keyframe lowers the next NEES."""
    T = _transform(np.array([0, 0, 0.3]), np.array([10.0, 0.0, 0.0]))
    keyframe = CovarianceSample(np.zeros(6), np.eye(6) * 1e-2, residual_variance=3.0)
    scan = CovarianceSample(
        np.full(6, 0.1), np.eye(6) * 1e-4, residual_variance=0.3, keyframe_back=1
    )
    scan.relative = transform_log(T)
    save_samples(tmp_path / 'k.npz', [keyframe, scan])
    first, kept = load_samples(tmp_path / 'k.npz')
    assert (first.keyframe_back, kept.keyframe_back) == (0, 1)
    assert np.allclose(kept.relative, transform_log(T))
    alone = nees_values([first, kept], 1.0, OFF)
    linked = nees_values([first, kept], 1.0, ON)
    assert linked[0] == alone[0] and linked[1] < alone[1] / 4
    tight = replace(kept, residual_variance=2.0)  # the keyframe fitted as well: no share
    assert nees_values([first, tight], 1.0, ON)[1] == nees_values([first, tight], 1.0, OFF)[1]
