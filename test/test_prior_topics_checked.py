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
The offline replay's prior topics pass the node's checks at arrival (datasets/prior_topics.py).

Hostile IMU and wheel messages, in the order a bag recorded them: each one that cannot be
right is dropped with the node's reason, the good ones are kept in stamp order, and no
message makes the reading raise.
"""

from __future__ import annotations

from types import SimpleNamespace as NS

from mlsemreg_ros.datasets import prior_topics
import numpy as np
import pytest


def _stamp(t: float, **kw: int) -> NS:
    sec, nanosec = divmod(round(t * 1e9), 10**9)
    return NS(stamp=NS(sec=kw.get('sec', sec), nanosec=kw.get('nanosec', nanosec)), frame_id='imu')


def _v(x: float, y: float = 0.0, z: float = 0.0) -> NS:
    return NS(x=x, y=y, z=z)


def _imu(t: float, gyro: float = 0.1, accel: float = 9.81, **kw: int) -> NS:
    return NS(header=_stamp(t, **kw), angular_velocity=_v(gyro), linear_acceleration=_v(accel))


def _wheel(t: float, x: float, q: tuple = (0.0, 0.0, 0.0, 1.0), **kw: int) -> NS:
    orientation = NS(x=q[0], y=q[1], z=q[2], w=q[3])
    pose = NS(pose=NS(position=_v(x), orientation=orientation))
    twist = NS(twist=NS(linear=_v(1.0), angular=_v(0.0)))
    return NS(header=_stamp(t, **kw), child_frame_id='base', pose=pose, twist=twist)


def test_hostile_imu_messages_are_dropped_with_the_nodes_reasons(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    nan = float('nan')
    messages = [
        _imu(1.00),
        _imu(1.01, gyro=nan),
        _imu(1.02, gyro=1e6),
        _imu(1.03, accel=1e300),
        _imu(0.0),  # stamp 0
        _imu(1.04, nanosec=2**32 - 1),
        _imu(1.05),
        _imu(1.05, gyro=3.0),  # a repeated stamp
        _imu(1.02),  # backwards
        NS(header=None),  # unreadable
        _imu(1.06),
    ]
    monkeypatch.setattr(prior_topics, '_topic_messages', lambda *a: iter(messages))
    imu, dropped = prior_topics.read_checked_imu('bag', '/imu/data')
    assert np.allclose(imu.stamps_ns * 1e-9, [1.00, 1.05, 1.06])
    assert np.all(np.isfinite(imu.angular_velocity)) and imu.angular_velocity.shape == (3, 3)
    assert dropped == {
        'nonfinite_gyro': 1,
        'gyro_limit': 1,
        'accel_limit': 1,
        'zero_stamp': 1,
        'bad_nanosec': 1,
        'duplicate_stamp': 1,
        'backwards_stamp': 1,
        'unreadable': 1,
    }


def test_hostile_wheel_messages_are_dropped_and_never_raise(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    messages = [
        _wheel(1.00, 0.0),
        _wheel(1.02, 0.2, q=(0.0, 0.0, 0.0, 0.0)),  # zero quaternion
        _wheel(1.04, 0.4, q=(0.0, 0.0, 0.0, 1e-300)),
        _wheel(1.06, float('nan')),
        _wheel(1.08, 1000.0),  # a jump of 1 km
        _wheel(1.10, 1.0),
    ]
    monkeypatch.setattr(prior_topics, '_topic_messages', lambda *a: iter(messages))
    wheel, dropped = prior_topics.read_checked_wheel('bag', '/wheel/odometry')
    assert np.allclose(wheel.stamps_ns * 1e-9, [1.00, 1.10])
    assert np.allclose(wheel.poses[-1][:3, 3], [1.0, 0.0, 0.0])
    assert dropped == {'zero_quaternion': 2, 'nonfinite_position': 1, 'pose_jump': 1}
