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
"""Known-answer tests of the pair metrics (paper Sec. 4.1) and the sequence metrics (ATE: evo)."""

import math

from mlsemreg_ros.core.metrics import (
    evaluate_pair,
    inlier_mask,
    kitti_odometry_errors,
    PairMetrics,
    rotation_error_deg,
    summarize,
    translation_error_m,
)
from mlsemreg_ros.evaluation.trajectory import ate_rmse
import numpy as np
import pytest
from scipy.spatial.transform import Rotation


def rigid(yaw_deg: float = 0.0, t=(0.0, 0.0, 0.0), axis: str = 'z') -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler(axis, yaw_deg, degrees=True).as_matrix()
    T[:3, 3] = t
    return T


def test_rotation_error_of_known_rotations():
    assert rotation_error_deg(rigid(90)[:3, :3], np.eye(3)) == pytest.approx(90.0)
    assert rotation_error_deg(rigid(-30, axis='x')[:3, :3], np.eye(3)) == pytest.approx(30.0)
    assert rotation_error_deg(rigid(180)[:3, :3], np.eye(3)) == pytest.approx(180.0)
    R = rigid(37, axis='y')[:3, :3]
    assert rotation_error_deg(R, R) == 0.0  # clipped: no NaN from rounding above 1


def test_translation_error_of_3_4_0_is_5_m():
    assert translation_error_m(np.array([3.0, 4.0, 0.0]), np.zeros(3)) == pytest.approx(5.0)


def test_inlier_mask_uses_the_ground_truth_and_a_strict_threshold():
    T_gt = rigid(90, (1.0, 0.0, 0.0))
    src = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [2.0, 0.0, 0.0]])
    dst = src @ T_gt[:3, :3].T + T_gt[:3, 3]
    dst[1] += [0.6, 0.0, 0.0]  # exactly at the threshold: not an inlier (< 0.6)
    dst[2] += [0.0, 0.0, 0.59]
    np.testing.assert_array_equal(inlier_mask(src, dst, T_gt, 0.6), [True, False, True])


def test_evaluate_pair_known_answer():
    T_gt = rigid(10, (5.0, 0.0, 0.0))
    rng = np.random.default_rng(0)
    src = rng.uniform(-10, 10, (10, 3))
    dst = src @ T_gt[:3, :3].T + T_gt[:3, 3]
    dst[:4] += 5.0  # four outliers
    estimate = rigid(10, (8.0, 4.0, 0.0))
    m = evaluate_pair(estimate, src, dst, T_gt)
    assert (m.inlier_number, m.n_correspondences) == (6, 10)
    assert m.inlier_ratio_pct == pytest.approx(60.0)
    assert m.translation_error_cm == pytest.approx(500.0)
    assert m.rotation_error_deg == pytest.approx(0.0, abs=1e-6)
    assert not m.success


@pytest.mark.parametrize(
    ('yaw', 'dx', 'success'),
    [
        (5.0, 0.0, True),
        (5.01, 0.0, False),
        (0.0, 0.6, True),
        (0.0, 0.6001, False),
        (4.9, 0.59, True),
    ],
)
def test_success_boundaries_are_inclusive(yaw, dx, success):
    T_gt = rigid(0, (0.0, 2.0, 3.0))  # x = 0 so that 0 + 0.6 is exactly 0.6
    estimate = T_gt @ rigid(yaw)
    estimate[:3, 3] += [dx, 0.0, 0.0]
    assert evaluate_pair(estimate, np.zeros((0, 3)), np.zeros((0, 3)), T_gt).success is success


def test_non_finite_estimate_fails_and_empty_correspondences_give_zero_ratio():
    m = evaluate_pair(np.full((4, 4), np.nan), np.zeros((0, 3)), np.zeros((0, 3)), np.eye(4))
    assert not m.success and math.isnan(m.rotation_error_deg)
    assert (m.inlier_number, m.inlier_ratio_pct, m.n_correspondences) == (0, 0.0, 0)


def test_summary_averages_errors_over_successful_pairs_only():
    metrics = [
        PairMetrics(100, 10.0, 1000, 1.0, 20.0, True),
        PairMetrics(50, 5.0, 1000, 3.0, 40.0, True),
        PairMetrics(0, 0.0, 1000, 90.0, 900.0, False),
        PairMetrics(10, 1.0, 1000, 7.0, 50.0, False),
    ]
    s = summarize(metrics)
    assert s['n_pairs'] == 4
    assert s['inlier_number'] == pytest.approx(40.0)
    assert s['inlier_ratio_pct'] == pytest.approx(4.0)
    assert s['registration_recall_pct'] == pytest.approx(50.0)
    assert s['rotation_error_deg'] == pytest.approx(2.0)
    assert s['translation_error_cm'] == pytest.approx(30.0)
    failed = summarize(metrics[2:])
    assert failed['registration_recall_pct'] == 0.0
    assert failed['rotation_error_deg'] is None and failed['translation_error_cm'] is None


def trajectory(frames: int = 400, step_m: float = 1.0, seed: int = 0) -> np.ndarray:
    """Make a smooth planar trajectory of (frames, 4, 4) poses, ``step_m`` between frames."""
    rng = np.random.default_rng(seed)
    yaw = np.cumsum(rng.normal(0, 0.01, frames))
    poses = np.tile(np.eye(4), (frames, 1, 1))
    poses[:, :3, :3] = Rotation.from_euler('z', yaw[:, None]).as_matrix()
    heading = np.stack([np.cos(yaw), np.sin(yaw), np.zeros(frames)], axis=1)
    poses[1:, :3, 3] = np.cumsum(step_m * heading[:-1], axis=0)
    return poses


def test_ate_is_zero_for_identical_and_rigidly_moved_trajectories():
    gt = trajectory()
    assert ate_rmse(gt[:, :3, 3], gt[:, :3, 3]) == pytest.approx(0.0, abs=1e-12)
    moved = np.einsum('ij,fjk->fik', rigid(33, (10.0, -4.0, 2.0), axis='y'), gt)
    assert ate_rmse(moved, gt, align=True) == pytest.approx(0.0, abs=1e-9)
    assert ate_rmse(moved, gt, align=False) > 1.0


def test_ate_of_a_constant_offset_without_alignment():
    gt = trajectory()[:, :3, 3]
    assert ate_rmse(gt + np.array([3.0, 4.0, 0.0]), gt, align=False) == pytest.approx(5.0)


def test_kitti_errors_zero_for_identical_and_none_below_100_m():
    gt = trajectory()
    t_err, r_err = kitti_odometry_errors(gt, gt)
    assert t_err == pytest.approx(0.0, abs=1e-9) and r_err == pytest.approx(0.0, abs=1e-6)
    assert kitti_odometry_errors(gt[:90], gt[:90]) is None


def test_kitti_translation_error_of_a_constant_scale_drift():
    # Straight line, 1 m per frame; the estimate overshoots every step by 2 %.
    frames, scale = 1000, 1.02
    gt = np.tile(np.eye(4), (frames, 1, 1))
    gt[:, 0, 3] = np.arange(frames, dtype=float)
    est = gt.copy()
    est[:, 0, 3] *= scale
    # Segment L ends at the first frame with distance > L, i.e. L + 1 m later (devkit).
    lengths = np.arange(100, 900, 100, dtype=float)
    starts = np.arange(0, frames, 10)
    errors = [
        (scale - 1) * (length + 1) / length
        for s in starts
        for length in lengths
        if s + length + 1 < frames
    ]
    t_err, r_err = kitti_odometry_errors(est, gt)
    assert t_err == pytest.approx(100 * np.mean(errors))
    assert t_err == pytest.approx(2.0, rel=0.01)
    assert r_err == pytest.approx(0.0, abs=1e-9)


def test_kitti_rotation_error_of_a_constant_yaw_drift():
    # Straight line along x; the estimate's heading turns by 0.01 deg per frame (1 m).
    frames, drift_deg = 300, 0.01
    gt = np.tile(np.eye(4), (frames, 1, 1))
    gt[:, 0, 3] = np.arange(frames, dtype=float)
    est = gt.copy()
    est[:, :3, :3] = Rotation.from_euler(
        'z', drift_deg * np.arange(frames)[:, None], degrees=True
    ).as_matrix()
    _, r_err = kitti_odometry_errors(est, gt)
    # Each segment L spans L + 1 frames: (L + 1) * 0.01 deg over L m, in deg per 100 m.
    lengths = np.arange(100, 900, 100, dtype=float)
    expected = [
        drift_deg * (length + 1) / length * 100
        for s in range(0, frames, 10)
        for length in lengths
        if s + length + 1 < frames
    ]
    assert r_err == pytest.approx(np.mean(expected))
