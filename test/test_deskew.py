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

"""Deskew (core/features/deskew.py): a skewed sweep with a known motion is straightened."""

from __future__ import annotations

from typing import Any

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.features.deskew import (
    deskew,
    PiecewiseSweepMotion,
    se3_log,
    sweep_motion,
    SweepMotion,
    time_span_refusal,
)
from mlsemreg_ros.core.odometry import Odometry
from mlsemreg_ros.core.odometry.preprocess import Preprocessor
import numpy as np
import pytest
from scipy.linalg import expm

STAMP_NS = 5_000_000_000
PERIOD_S = 0.1


def _twist_matrix(omega: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    out = np.zeros((4, 4))
    wx, wy, wz = omega
    out[:3, :3] = [[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]]
    out[:3, 3] = velocity
    return out


def _pose(t: float, omega: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """Return the true pose at ``t`` s after the stamp (identity at the stamp)."""
    return expm(t * _twist_matrix(omega, velocity))


def _sweep(
    omega: np.ndarray, velocity: np.ndarray, n: int = 4000, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points (= the frame at the stamp), their times and their skewed measurements."""
    rng = np.random.default_rng(seed)
    columns = 360
    column = np.sort(rng.integers(0, columns, n))
    azimuth = 2 * np.pi * column / columns
    times = column / columns * PERIOD_S  # column by column over the sweep
    ranges = rng.uniform(5.0, 60.0, n)
    world = np.stack(
        [ranges * np.cos(azimuth), ranges * np.sin(azimuth), rng.uniform(-2.0, 3.0, n)], axis=1
    )
    skewed = np.empty_like(world)
    for c in np.unique(column):  # the reference: one matrix exponential per column
        T = _pose(c / columns * PERIOD_S, omega, velocity)
        rows = column == c
        skewed[rows] = (world[rows] - T[:3, 3]) @ T[:3, :3]  # T^-1 p
    return world, times, skewed


MOTIONS = {
    'straight 10 m/s': (np.zeros(3), np.array([10.0, 0.0, 0.0])),
    'turn 30 deg/s at 8 m/s': (np.array([0.0, 0.0, np.radians(30.0)]), np.array([8.0, 0.5, 0.0])),
    'aggressive 60 deg/s, pitch, 14 m/s': (
        np.array([0.05, 0.1, np.radians(60.0)]),
        np.array([14.0, -0.3, 0.2]),
    ),
}


@pytest.mark.parametrize('name', list(MOTIONS))
def test_a_sweep_with_a_known_motion_is_straightened_below_1_cm(name: str) -> None:
    omega, velocity = MOTIONS[name]
    world, times, skewed = _sweep(omega, velocity)
    before = np.linalg.norm(skewed - world, axis=1).max()
    # the motion as the odometry sees it: last accepted pose one period ago, predicted pose
    motion = sweep_motion(
        _pose(-PERIOD_S, omega, velocity),
        STAMP_NS - int(PERIOD_S * 1e9),
        np.eye(4),
        STAMP_NS,
    )
    straightened = deskew(skewed, times, motion)
    after = np.linalg.norm(straightened - world, axis=1)
    assert before > 0.5  # the skew is real (metres at the sweep end)
    assert after.max() < 0.01, f'{name}: {after.max():.4f} m'
    assert after.max() < 1e-6  # exact for a constant twist


def test_a_turn_that_starts_within_the_sweep_is_straightened_by_the_gyros_rotations() -> None:
    # 8 m/s straight for the first 40 ms, then a 45 deg/s turn (a yaw-rate step, as at the
    # start of a turn): one constant twist over the sweep cannot follow it, the gyro can.
    velocity, rate, step_s = np.array([8.0, 0.0, 0.0]), np.radians(45.0), 0.04
    straight, turn = np.zeros(3), np.array([0.0, 0.0, rate])

    def pose(t: float) -> np.ndarray:
        if t <= step_s:
            return _pose(t, straight, velocity)
        return _pose(step_s, straight, velocity) @ _pose(t - step_s, turn, velocity)

    rng = np.random.default_rng(3)
    n = 3000
    times = np.sort(rng.uniform(0.0, PERIOD_S, n))
    azimuth = 2 * np.pi * times / PERIOD_S
    ranges = rng.uniform(5.0, 60.0, n)
    world = np.stack(
        [ranges * np.cos(azimuth), ranges * np.sin(azimuth), rng.uniform(-2.0, 3.0, n)], axis=1
    )
    skewed = np.empty_like(world)
    for k, t in enumerate(times):
        T = pose(t)
        skewed[k] = (world[k] - T[:3, 3]) @ T[:3, :3]
    nodes = np.linspace(0.0, PERIOD_S, 21)  # a 200 Hz gyro; the step falls on a node
    rotations = np.stack([pose(t)[:3, :3] for t in nodes])
    gyro = PiecewiseSweepMotion.from_rotations(nodes, rotations, velocity)
    after_gyro = np.linalg.norm(deskew(skewed, times, gyro) - world, axis=1).max()
    average = sweep_motion(np.eye(4), STAMP_NS, pose(PERIOD_S), STAMP_NS + int(PERIOD_S * 1e9))
    after_twist = np.linalg.norm(deskew(skewed, times, average) - world, axis=1).max()
    assert after_gyro < 1e-6  # exact: a constant twist on every segment
    assert after_twist > 0.1  # one twist over the sweep leaves decimetres


def test_piecewise_motion_of_one_twist_is_that_twist() -> None:
    omega, velocity = MOTIONS['aggressive 60 deg/s, pitch, 14 m/s']
    world, times, skewed = _sweep(omega, velocity)
    nodes = np.array([-0.01, 0.0, 0.013, 0.05, 0.1])  # uneven, one before the stamp
    rotations = np.stack([_pose(t, omega, velocity)[:3, :3] for t in nodes])
    piecewise = PiecewiseSweepMotion.from_rotations(nodes, rotations, velocity)
    np.testing.assert_allclose(
        piecewise.poses, np.stack([_pose(t, omega, velocity) for t in nodes]), atol=1e-9
    )
    np.testing.assert_allclose(deskew(skewed, times, piecewise), world, atol=1e-6)


def test_piecewise_motion_keeps_the_twists_it_was_built_from() -> None:
    omega, velocity = MOTIONS['aggressive 60 deg/s, pitch, 14 m/s']
    nodes = np.array([-0.01, 0.0, 0.013, 0.05, 0.1])
    rotations = np.stack([_pose(t, omega, velocity)[:3, :3] for t in nodes])
    piecewise = PiecewiseSweepMotion.from_rotations(nodes, rotations, velocity)
    for *_, twist in piecewise.segments():  # the twists themselves, no log
        assert np.array_equal(twist.velocity, velocity)
        np.testing.assert_allclose(twist.omega, omega, atol=1e-9)
    # built from poses alone: the twists are their logs, the same motion
    from_poses = PiecewiseSweepMotion(piecewise.times, piecewise.poses)
    for kept, logged in zip(piecewise.segments(), from_poses.segments(), strict=True):
        np.testing.assert_allclose(logged[2].omega, kept[2].omega, atol=1e-9)
        np.testing.assert_allclose(logged[2].velocity, kept[2].velocity, atol=1e-9)
    world, times, skewed = _sweep(omega, velocity)
    np.testing.assert_allclose(deskew(skewed, times, from_poses), world, atol=1e-6)


def test_the_odometry_deskews_with_the_motion_models_prediction() -> None:
    omega, velocity = MOTIONS['turn 30 deg/s at 8 m/s']
    world, times, skewed = _sweep(omega, velocity, n=600)
    seen = []

    class _Capture:
        config = RegistrationConfig()

        def prepare(self, points: np.ndarray, labels: np.ndarray, lazy: bool = False) -> Any:
            seen.append(np.array(points))
            raise RuntimeError('prepared')

    odometry = Odometry(_Capture())
    odometry.keyframe = object()  # a running odometry (the registration is not needed here)
    period_ns = int(PERIOD_S * 1e9)
    for k in (2, 1):  # two accepted poses before the stamp: a constant-velocity prediction
        pose, stamp = _pose(-k * PERIOD_S, omega, velocity), STAMP_NS - k * period_ns
        odometry.motion_model.update(pose, stamp)
        odometry._accepted.append((pose, stamp))
    odometry._last_accepted = (_pose(-PERIOD_S, omega, velocity), STAMP_NS - period_ns)
    labels = np.zeros(len(world), np.int64)
    with pytest.raises(RuntimeError, match='prepared'):
        odometry.process(skewed, labels, STAMP_NS, point_times=times)
    assert np.linalg.norm(seen[-1] - world, axis=1).max() < 0.01
    odometry.registration.config = RegistrationConfig.from_dict({'preprocess.deskew': 'off'})
    with pytest.raises(RuntimeError, match='prepared'):
        odometry.process(skewed, labels, STAMP_NS + 1, point_times=times)
    assert np.array_equal(seen[-1], skewed)


class _Prepare:
    def __init__(self, mode: str) -> None:
        self.config = RegistrationConfig.from_dict({'preprocess.deskew': mode})

    def prepare(self, points: np.ndarray, labels: np.ndarray, lazy: bool = False) -> Any:
        return points


@pytest.mark.parametrize('mode', ['off', 'auto', 'on'])
def test_without_deskew_the_points_are_bit_identical(mode: str) -> None:
    omega, velocity = MOTIONS['straight 10 m/s']
    rng = np.random.default_rng(1)
    points = rng.normal(size=(500, 3)) * 20.0
    times = np.linspace(0.0, 0.1, 500)
    motion = SweepMotion(omega, velocity)
    labels = np.zeros(500, np.int64)
    preprocessor = Preprocessor(_Prepare(mode))
    cases = [(None, motion), (times, None)] + ([(times, motion)] if mode == 'off' else [])
    for given_times, given_motion in cases:
        out = preprocessor(points, labels, given_times, given_motion)
        assert not out.deskewed and out.points.tobytes() == points.tobytes()
        assert bool(out.deskew_note) == (mode == 'on')
    if mode != 'off':
        assert preprocessor(points, labels, times, motion).deskewed


def test_no_times_no_deskew_note_when_auto() -> None:
    assert time_span_refusal(None, 3) == 'the scan has no per-point times'
    assert 'same time' in time_span_refusal(np.zeros(3), 3)
    assert 'not one sweep' in time_span_refusal(np.array([0.0, 5.0]), 2)
    assert 'for 3 points' in time_span_refusal(np.zeros(2), 3)
    assert 'finite' in time_span_refusal(np.array([0.0, np.nan]), 2)
    assert time_span_refusal(np.array([-0.1, 0.0]), 2) == ''


def test_properties_identity_inverse_rigidity_and_the_matrix_exponential() -> None:
    rng = np.random.default_rng(7)
    for _ in range(5):
        motion = SweepMotion(rng.normal(size=3) * 0.8, rng.normal(size=3) * 10.0)
        points = rng.normal(size=(300, 3)) * 30.0
        times = rng.uniform(-0.1, 0.1, 300)
        out = deskew(points, times, motion)
        # a point at the stamp does not move; zero motion moves nothing
        np.testing.assert_array_equal(deskew(points, np.zeros(300), motion), points)
        still = SweepMotion(np.zeros(3), np.zeros(3))
        np.testing.assert_array_equal(deskew(points, times, still), points)
        # the reverse motion undoes it
        back = deskew(out, times, SweepMotion(-motion.omega, -motion.velocity))
        np.testing.assert_allclose(back, points, atol=1e-9)
        # points of one time move rigidly
        same = deskew(points[:50], np.full(50, 0.07), motion)
        np.testing.assert_allclose(
            np.linalg.norm(same[1:] - same[0], axis=1),
            np.linalg.norm(points[1:50] - points[0], axis=1),
            rtol=1e-12,
        )
        # every point follows exp(tau * twist) (scipy's matrix exponential)
        for i in range(0, 300, 60):
            T = expm(times[i] * _twist_matrix(motion.omega, motion.velocity))
            np.testing.assert_allclose(out[i], T[:3, :3] @ points[i] + T[:3, 3], atol=1e-9)
        # the logarithm inverts the exponential
        T = expm(0.1 * _twist_matrix(motion.omega, motion.velocity))
        phi, rho = se3_log(T)
        np.testing.assert_allclose(phi, 0.1 * motion.omega, atol=1e-9)
        np.testing.assert_allclose(rho, 0.1 * motion.velocity, atol=1e-9)


def test_sweep_motion_needs_a_duration() -> None:
    assert sweep_motion(np.eye(4), 0, np.eye(4), STAMP_NS) is None
    assert sweep_motion(np.eye(4), STAMP_NS, np.eye(4), STAMP_NS) is None
    with pytest.raises(ValueError, match='point times'):
        deskew(np.zeros((3, 3)), np.zeros(2), SweepMotion(np.zeros(3), np.ones(3)))


def test_kiss_icp_gets_the_times_and_an_anchor_when_scans_are_further_apart() -> None:
    pytest.importorskip('kiss_icp')
    from mlsemreg_ros.datasets.source import Scan
    from mlsemreg_ros.evaluation.estimators import KissIcpEstimator

    kiss = KissIcpEstimator()
    xyz = np.random.default_rng(0).normal(size=(100, 3)) * 10.0
    times = np.linspace(0.0, 0.099, 100)

    def scan(index: int, stamp_ns: int, point_times: np.ndarray | None) -> Scan:
        return Scan(index, stamp_ns, xyz, None, None, 'lidar', None, point_times)

    points, given = kiss._inputs(scan(0, STAMP_NS, None))  # the clean world: no deskew
    assert given.size == 0 and points.shape == (100, 3)
    points, given = kiss._inputs(scan(1, STAMP_NS + 100_000_000, times))  # consecutive
    assert np.array_equal(given, times) and points.shape == (100, 3)
    points, given = kiss._inputs(scan(11, STAMP_NS + 1_100_000_000, times))  # stride 10
    assert points.shape == (101, 3) and np.linalg.norm(points[-1]) > kiss.max_range
    assert given[-1] == pytest.approx(times.max() - 1.0)
