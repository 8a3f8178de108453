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
The second start of the sweep alignment (``core/odometry/sweep_starts.py``).

A hand turns its sensor back: the deskew assumed the last poses' -34 deg/s, the sweep turned
at +50 deg/s, and the rigid alignment of the bent scan landed 4 deg off. From the deskew's
twist alone the sweep alignment stays in the wrong basin (this is how the handheld VLP-16
drive at stride 3 published poses 8 deg off); the twist the pose implies (+40 deg/s here)
brings it back. A car's poses agree with its deskew, and it gets no second start unless the
twists differ by more than the pairing distance.
"""

from __future__ import annotations

from mlsemreg_ros.core.alignment import sweep_alignment
from mlsemreg_ros.core.config import SweepAlignmentConfig
from mlsemreg_ros.core.features.deskew import SweepMotion
from mlsemreg_ros.core.odometry import sweep_starts
from mlsemreg_ros.core.odometry.motion_model import ConstantVelocityModel
from mlsemreg_ros.core.rigid import invert_transform, rotation_angle_deg
import numpy as np
import pytest
from test_sweep_alignment import _pose, _sweep, street  # noqa: F401 (the fixture)


def _yaw_rate(deg_s: float, speed: float = 1.4) -> SweepMotion:
    return SweepMotion(np.array([0.0, 0.0, np.radians(deg_s)]), np.array([speed, 0.0, 0.0]))


def _count_starts(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Return a list that gets one entry per sweep alignment ``align_from_starts`` runs."""
    calls = []
    original = sweep_alignment.align_sweep

    def counted(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(sweep_starts, 'align_sweep', counted)
    return calls


def test_the_pose_s_twist_brings_a_sweep_bent_the_wrong_way_back(street) -> None:  # noqa: F811
    world, gaussians = street
    truth, stale = _yaw_rate(50.0), _yaw_rate(-34.0)
    T_true = _pose(2.0, 0.5, 10.0)
    raw, times = _sweep(world, T_true, truth)
    T_initial = T_true @ _pose(0.3, 0.2, -5.0) @ invert_transform(_pose(0, 0, 0))
    config = SweepAlignmentConfig()
    alone = sweep_alignment.align_sweep(raw, times, gaussians, T_initial, stale, config)
    both = sweep_starts.align_from_starts(
        raw, times, gaussians, T_initial, stale, _yaw_rate(40.0), config
    )
    error = invert_transform(T_true) @ both.T_target_source
    assert rotation_angle_deg(error) < 0.5
    assert np.linalg.norm(error[:3, 3]) < 0.3
    assert np.degrees(both.motion.omega[2]) == pytest.approx(50.0, abs=20.0)
    # from the deskew's twist alone the sweep is bent further the wrong way (-73 deg/s)
    assert np.degrees(alone.motion.omega[2]) < -34.0
    # change_m is measured against the deskew's twist, as the odometry's min_change test wants
    assert both.change_m == pytest.approx(sweep_starts.bend_m(raw, times, both.motion, stale))


def test_a_car_gets_no_second_start(street, monkeypatch) -> None:  # noqa: F811
    world, gaussians = street
    truth = _yaw_rate(5.0, speed=10.0)  # a car
    T_true = _pose(2.0, 0.5, 10.0)
    raw, times = _sweep(world, T_true, truth)
    calls = _count_starts(monkeypatch)
    sweep_starts.align_from_starts(
        raw, times, gaussians, T_true, truth, _yaw_rate(5.5, speed=10.1), SweepAlignmentConfig()
    )
    assert len(calls) == 1


@pytest.mark.parametrize(
    ('implied_deg_s', 'starts'), [(15.0, 1), (20.0, 1), (30.0, 1), (40.0, 1), (60.0, 2)]
)
def test_a_second_start_only_beyond_the_first_starts_reach(
    street,  # noqa: F811
    monkeypatch,
    implied_deg_s,
    starts,
) -> None:
    # a car's implied yaw rate, off by 10-15 deg/s of pose noise, bends the sweep by
    # 0.6-0.9 m (over min_change, within max_distance); a hand's at stride 1 by 1-2.2 m
    # (30-40 deg/s off here: 1.5-2.1 m), within the first start's reach (2.5 pairing
    # distances): no second start; 55 deg/s off: 3.4 m, two
    world, gaussians = street
    truth = _yaw_rate(5.0, speed=10.0)
    T_true = _pose(2.0, 0.5, 10.0)
    raw, times = _sweep(world, T_true, truth)
    config = SweepAlignmentConfig()
    implied = _yaw_rate(implied_deg_s, speed=10.0)
    bend = sweep_starts.bend_m(raw, times, implied, truth)
    assert config.min_change < bend
    reach = sweep_starts.SECOND_START_REACH * config.max_distance
    assert (bend > reach) == (starts == 2)
    assert sweep_starts.second_start_bend(config) == reach
    calls = _count_starts(monkeypatch)
    sweep_starts.align_from_starts(raw, times, gaussians, T_true, truth, implied, config)
    assert len(calls) == starts


def test_the_implied_twist_is_the_motion_since_the_last_accepted_pose() -> None:
    model = ConstantVelocityModel()
    assert sweep_starts.implied_twist(model, np.eye(4), 10**9) is None
    model.update(np.eye(4), 10**9)
    moved = _pose(1.0, 0.0, 15.0)
    moved[2, 3] = 0.0
    twist = sweep_starts.implied_twist(model, moved, 10**9 + 300_000_000)
    assert np.degrees(twist.omega[2]) == pytest.approx(50.0, abs=1e-6)
