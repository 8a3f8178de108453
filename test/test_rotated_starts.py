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
Issue 35: yaw-rotated starts of the map alignment (core/odometry/rotated_starts.py).

A map alignment that converges to the true pose only from starts within its basin (6 deg of
yaw here), judged by the real trust rules: a car's tight bound tries no rotated start; a
hand's widened bound finds the true pose from a rotated start; two basins give none; a start
refused only for its bent sweep is deskewed again and tracked, its move judged from the
prediction (session 18).
"""

from __future__ import annotations

from mlsemreg_ros.core.alignment.alignment import Alignment
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry import rotated_starts
from mlsemreg_ros.core.odometry.motion_bound import GAIN
from mlsemreg_ros.core.odometry.rotated_starts import best_rotated_start, yaw_rotated
from mlsemreg_ros.core.odometry.trust import Candidate, Trust
from mlsemreg_ros.core.rigid import rotation_angle_deg
import numpy as np
import pytest

ODOMETRY = RegistrationConfig().odometry
BASIN_DEG = 6.0


def _yaw_of(T: np.ndarray) -> float:
    return float(np.degrees(np.arctan2(T[1, 0], T[0, 0])))


class _World:
    """A map alignment that reaches a true yaw only from within :data:`BASIN_DEG` of it."""

    def __init__(
        self, truths_deg: list[float], inliers: float = 0.85, bound_deg: float = 0.0
    ) -> None:
        self.truths, self.inliers, self.starts = truths_deg, inliers, []
        self.trust = Trust()
        if bound_deg:  # a hand's recent prediction error: the bounds widen to bound_deg
            self.trust.motion_bound.predicted(np.eye(4))
            self.trust.motion_bound.accepted(yaw_rotated(np.eye(4), bound_deg / GAIN))

    def refine(self, T_start: np.ndarray, inliers: float | None = None) -> Candidate:
        self.starts.append(_yaw_of(T_start))
        near = [t for t in self.truths if abs(t - _yaw_of(T_start)) < BASIN_DEG]
        result = yaw_rotated(np.eye(4), near[0]) if near else T_start
        kept = (self.inliers if inliers is None else inliers) if near else 0.15
        alignment = Alignment(result, T_start, True, 5, int(1000 * kept), 1000, 1.0, np.eye(6))
        return self.trust.judge('prediction', T_start, alignment, ODOMETRY)

    def refusal(self, candidate: Candidate) -> str:
        return self.trust.tracking_refusal(candidate, 1.0, ODOMETRY)


def test_the_rotation_is_about_the_sensors_own_vertical() -> None:
    T = np.eye(4)
    T[:3, 3] = [1.0, 2.0, 0.5]
    turned = yaw_rotated(T, 15.0)
    assert np.allclose(turned[:3, 3], T[:3, 3])
    assert rotation_angle_deg(np.linalg.solve(T, turned)) == pytest.approx(15.0)


def test_a_car_tries_no_rotated_start() -> None:
    world = _World([12.0])
    chosen = best_rotated_start(
        np.eye(4), ODOMETRY.max_correction_rotation, world.refine, world.refusal
    )
    assert chosen is None and world.starts == []
    assert rotated_starts.offsets_within(5.0) == []


def test_a_hand_turn_is_found_from_a_rotated_start_within_the_bound() -> None:
    world = _World([13.0])
    chosen = best_rotated_start(np.eye(4), 18.0, world.refine, world.refusal)
    assert chosen is not None
    assert _yaw_of(chosen.alignment.T_target_source) == pytest.approx(13.0)
    assert 20.0 not in world.starts  # outside the 18 deg bound: not tried


def test_two_basins_give_no_rotated_start() -> None:
    world = _World([11.0, -11.0])
    assert best_rotated_start(np.eye(4), 25.0, world.refine, world.refusal) is None


def test_a_start_refused_for_its_bent_sweep_is_deskewed_again_and_tracked() -> None:
    world = _World([-12.0], inliers=0.6, bound_deg=18.0)  # under tracking_min_inlier_fraction
    assert best_rotated_start(np.eye(4), 18.0, world.refine, world.refusal) is None
    redone = []

    def redeskewed(T: np.ndarray) -> Candidate:
        redone.append(_yaw_of(T))
        return world.refine(T, inliers=0.85)

    chosen = best_rotated_start(np.eye(4), 18.0, world.refine, world.refusal, redeskewed)
    assert chosen is not None and redone == [pytest.approx(-12.0)]
    assert _yaw_of(chosen.alignment.T_target_source) == pytest.approx(-12.0)
    # deskewed again and still under the tracking rules: not taken
    stays = best_rotated_start(
        np.eye(4), 18.0, world.refine, world.refusal, lambda T: world.refine(T, inliers=0.6)
    )
    assert stays is None


def _shifted(T: np.ndarray, metres: float) -> np.ndarray:
    moved = np.array(T, dtype=np.float64)
    moved[:3, 3] += moved[:3, :3] @ np.array([metres, 0.0, 0.0])
    return moved


def test_a_start_deskewed_again_is_judged_from_the_prediction_not_from_its_start() -> None:
    """
    The scan deskewed again moves the pose from the rotated start's refined pose.

    Here the first pass lands 0.45 m aside along x, the second pass comes back to within
    0.1 m of the prediction's place: 0.55 m from its start (over
    ``odometry.tracking_translation`` 0.5 m), 0.1 m from the prediction. Judged from its
    start it was refused (the code before session 18); judged from the prediction it is
    tracked. A second pass that lands 0.7 m from the prediction stays refused.
    """
    world = _World([-12.0], inliers=0.6, bound_deg=18.0)
    first_pass = world.refine

    def aside(T: np.ndarray, inliers: float | None = None) -> Candidate:
        candidate = first_pass(T, inliers)
        alignment = candidate.alignment
        alignment.T_target_source = _shifted(alignment.T_target_source, 0.45)
        return world.trust.judge('prediction', alignment.T_initial, alignment, ODOMETRY)

    def redeskewed(T: np.ndarray, back: float) -> Candidate:
        alignment = first_pass(T, inliers=0.85).alignment
        alignment.T_initial = np.array(T)
        alignment.T_target_source = _shifted(alignment.T_target_source, back)
        return world.trust.judge('prediction', T, alignment, ODOMETRY)

    chosen = best_rotated_start(
        np.eye(4), 18.0, aside, world.refusal, lambda T: redeskewed(T, -0.1)
    )
    assert chosen is not None
    assert np.linalg.norm(chosen.alignment.T_target_source[:3, 3]) == pytest.approx(0.1, abs=1e-6)
    far = best_rotated_start(np.eye(4), 18.0, aside, world.refusal, lambda T: redeskewed(T, 0.7))
    assert far is None


def test_a_hand_turn_at_stride_3_is_tracked_from_a_rotated_start_and_right() -> None:
    """The simulated handheld VLP-16 walk (seed 5, no IMU), every 3rd scan, scans 0-33."""
    from mlsemreg_ros.core.odometry import Odometry
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.simulation.field import FieldConfig, FieldSimulation

    sim = FieldSimulation(FieldConfig(seed=5, frames=36, sensor='vlp16', profile='handheld'))
    odometry = Odometry(Registration(RegistrationConfig()))
    rotated, first = 0, None
    for k in range(0, 36, 3):
        frame = sim.frame(k)
        first = frame.pose if first is None else first
        points = frame.scan.points.astype(np.float32).astype(np.float64)  # as in the bag
        step = odometry.process(points, frame.labels, frame.stamp_ns, point_times=frame.scan.times)
        assert step.accepted, step.reason
        error = np.linalg.solve(np.linalg.solve(first, frame.pose), step.pose)
        assert np.linalg.norm(error[:3, 3]) < 0.5 and rotation_angle_deg(error) < 2.0, (
            k,
            step.reason,
        )
        rotated += 'yaw-rotated start' in step.reason
    assert rotated >= 1
