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
The trajectory metrics: evo's ATE / RPE, and the KITTI segment metric by hand.

evo's ATE is checked against the hand-written ATE it replaced, the KITTI segment metric
(our own code) on a case computed by hand.
"""

import math

from mlsemreg_ros.core.metrics import kitti_odometry_errors
from mlsemreg_ros.evaluation.trajectory import ate_rmse, rpe_rmse, trajectory_errors
from mlsemreg_ros.simulation.sequence import Simulation, SimulationConfig
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

#: The hand-written ATE (Umeyama SE(3) alignment, then RMSE; core/metrics.py before evo) on
#: the demo drive's ground truth (seed 0, 100 scans) against :func:`drifted`, as it printed.
OLD_ATE_ALIGNED_M = 0.17403493918974403
OLD_ATE_UNALIGNED_M = 0.3954315048059763


def line(frames: int) -> np.ndarray:
    """Ground truth along x, 1 m per frame."""
    poses = np.tile(np.eye(4), (frames, 1, 1))
    poses[:, 0, 3] = np.arange(frames, dtype=float)
    return poses


def drifted(truth: np.ndarray) -> np.ndarray:
    """``truth`` with a seeded random-walk position drift and heading drift."""
    rng = np.random.default_rng(7)
    frames = truth.shape[0]
    drift = np.cumsum(rng.normal(0, 0.02, (frames, 3)), axis=0)
    yaw = np.cumsum(rng.normal(0, 0.002, frames))
    estimate = truth.copy()
    for k in range(frames):
        R = Rotation.from_euler('z', yaw[k]).as_matrix()
        estimate[k, :3, :3] = R @ truth[k, :3, :3]
        estimate[k, :3, 3] = R @ truth[k, :3, 3] + drift[k]
    return estimate


def test_evo_ate_matches_the_old_hand_written_ate_on_the_demo_drive() -> None:
    truth = Simulation(SimulationConfig(seed=0, frames=100)).poses
    estimate = drifted(truth)
    assert ate_rmse(estimate, truth, align=True) == pytest.approx(OLD_ATE_ALIGNED_M, abs=1e-6)
    assert ate_rmse(estimate, truth, align=False) == pytest.approx(OLD_ATE_UNALIGNED_M, abs=1e-6)


def test_kitti_segment_metric_of_a_hand_computed_case() -> None:
    # 111 frames, 1 m apart: the only segment is 100 m from frame 0, which ends at frame 101
    # (the first frame more than 100 m on). The estimate overshoots by 2 %: it puts frame 101
    # at 103.02 m, an error of 2.02 m over 100 m.
    truth = line(111)
    estimate = truth.copy()
    estimate[:, 0, 3] *= 1.02
    t_err, r_err = kitti_odometry_errors(estimate, truth)
    assert t_err == pytest.approx(2.02)
    assert r_err == pytest.approx(0.0, abs=1e-9)
    # Every estimated pose turned by 0.01 rad per frame, positions right: frame 101 is off
    # by 1.01 rad over 100 m, i.e. degrees(1.01) deg per 100 m, and no translation error.
    turned = truth.copy()
    turned[:, :3, :3] = Rotation.from_euler('z', 0.01 * np.arange(111)[:, None]).as_matrix()
    t_err, r_err = kitti_odometry_errors(turned, truth)
    assert t_err == pytest.approx(0.0, abs=1e-9)
    assert r_err == pytest.approx(math.degrees(1.01))


def test_rpe_per_step_and_per_100_m_of_a_constant_overshoot() -> None:
    truth = line(251)
    estimate = truth.copy()
    estimate[:, 0, 3] *= 1.02  # every 1 m step 2 cm too long
    assert rpe_rmse(estimate, truth) == pytest.approx(0.02)
    # evo pairs scans 100 m +- 10 % apart: 2 cm per metre over 90..110 m
    assert rpe_rmse(estimate, truth, 100.0, metres=True) == pytest.approx(2.0, rel=0.01)
    assert rpe_rmse(line(50), line(50), 100.0, metres=True) is None  # no pair 100 m apart
    errors = trajectory_errors(estimate, truth)
    assert set(errors) == {'ate_rmse_m', 'ate_unaligned_m', 'rpe_step_m', 'rpe_100m_m'}
    # unaligned: 2 % of the distance from the start, RMS over 0..250 m
    expected = 0.02 * math.sqrt(np.mean(np.arange(251.0) ** 2))
    assert errors['ate_unaligned_m'] == pytest.approx(expected)
    assert errors['ate_rmse_m'] <= errors['ate_unaligned_m']  # straight: first-pose alignment


def test_positions_alone_are_accepted() -> None:
    truth = line(20)[:, :3, 3]
    assert ate_rmse(truth + np.array([3.0, 4.0, 0.0]), truth, align=False) == pytest.approx(5.0)
    with pytest.raises(ValueError, match='differ in shape'):
        ate_rmse(truth[:5], truth)
