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
Hostile IMU and wheel messages (issue 34): converted to finite numbers or dropped with a reason.

Property tests (hypothesis, derandomized) of the ROS-free converters of ``ros/prior_inputs.py``
on any message of the right shape, known answers of the stream gate and the physical limits
of ``core/prior_checks.py``, and the callback guards of ``ros/callback_guard.py``.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st
from mlsemreg_ros.core.prior_checks import (
    MAX_ACCEL_M_S2,
    MAX_GYRO_RAD_S,
    RESTART_RUN,
    StreamGate,
    wheel_jump,
)
from mlsemreg_ros.ros.callback_guard import (
    DropCounter,
    failed_service,
    guard,
    spin_guarded,
)
from mlsemreg_ros.ros.prior_inputs import imu_sample, PriorInbox, wheel_sample
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

PROPERTY = settings(
    max_examples=300,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)

#: Any float64 a message field can hold, with the hostile ones often.
floats = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True),
    st.sampled_from([0.0, -0.0, 1e-300, 5e-324, 1e300, -1e300, float('nan'), 1.0, 9.81]),
)
#: ``builtin_interfaces/Time``: sec int32, nanosec uint32.
stamps = st.builds(
    SimpleNamespace,
    sec=st.one_of(st.integers(-(2**31), 2**31 - 1), st.sampled_from([0, 1, 1_700_000_000])),
    nanosec=st.one_of(st.integers(0, 2**32 - 1), st.sampled_from([0, 999_999_999, 10**9])),
)


def _vector(x: float, y: float, z: float) -> SimpleNamespace:
    return SimpleNamespace(x=x, y=y, z=z)


vectors = st.builds(_vector, floats, floats, floats)
quaternions = st.builds(lambda x, y, z, w: SimpleNamespace(x=x, y=y, z=z, w=w), *[floats] * 4)
headers = st.builds(SimpleNamespace, stamp=stamps, frame_id=st.sampled_from(['', 'imu', 'x']))
imu_messages = st.builds(
    SimpleNamespace, header=headers, angular_velocity=vectors, linear_acceleration=vectors
)
wheel_messages = st.builds(
    lambda header, position, orientation: SimpleNamespace(
        header=header,
        child_frame_id='base_link',
        pose=SimpleNamespace(pose=SimpleNamespace(position=position, orientation=orientation)),
    ),
    headers,
    vectors,
    quaternions,
)


def _stamp_ok(stamp: Any) -> bool:
    return 0 <= stamp.nanosec < 10**9 and stamp.sec >= 0 and (stamp.sec, stamp.nanosec) != (0, 0)


@PROPERTY
@given(imu_messages)
def test_an_imu_message_converts_to_finite_numbers_within_the_limits_or_has_a_reason(
    msg: Any,
) -> None:
    sample, why = imu_sample(msg)
    if sample is None:
        assert why
        return
    assert why == '' and _stamp_ok(msg.header.stamp)
    assert sample.stamp_ns == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec > 0
    assert np.all(np.isfinite(sample.gyro)) and np.all(np.isfinite(sample.accel))
    assert np.linalg.norm(sample.gyro) <= MAX_GYRO_RAD_S
    assert np.linalg.norm(sample.accel) <= MAX_ACCEL_M_S2


@PROPERTY
@given(wheel_messages)
def test_a_wheel_message_converts_to_a_finite_rigid_pose_or_has_a_reason(msg: Any) -> None:
    sample, why = wheel_sample(msg)
    if sample is None:
        assert why
        return
    assert _stamp_ok(msg.header.stamp)
    T = sample.pose
    assert np.all(np.isfinite(T))
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
    assert np.linalg.det(T[:3, :3]) > 0.999
    q = msg.pose.pose.orientation
    expected = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    np.testing.assert_allclose(T[:3, :3], expected, atol=1e-9)


@PROPERTY
@given(st.lists(st.one_of(imu_messages, wheel_messages, st.just(None)), max_size=30))
def test_the_inbox_never_raises_and_hands_over_only_ordered_finite_samples(
    messages: list[Any],
) -> None:
    inbox, model = PriorInbox(), _Model()
    for msg in messages:
        if msg is None or hasattr(msg, 'angular_velocity'):
            inbox.on_imu(msg)
        if msg is None or hasattr(msg, 'pose'):
            inbox.on_wheel(msg)
    inbox.flush(model, 'lidar', '', np.eye(4))
    for stamps, *values in model.imu + [(s, p) for s, p, _ in model.wheel]:
        assert np.all(np.diff(stamps) > 0) and np.all(stamps > 0)
        assert all(np.all(np.isfinite(v)) for v in values)
    kept = sum(len(s) for s, *_ in model.imu + model.wheel)
    dropped = inbox.drops.count('imu_dropped') + inbox.drops.count('wheel_dropped')
    imu_or_none = sum(m is None or hasattr(m, 'angular_velocity') for m in messages)
    wheel_or_none = sum(m is None or hasattr(m, 'pose') for m in messages)
    assert kept + dropped == imu_or_none + wheel_or_none  # each message: kept or counted


class _Model:
    def __init__(self) -> None:
        self.imu: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.wheel: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.forgotten: list[str] = []

    def add_imu(self, stamps: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> None:
        self.imu.append((stamps, gyro, accel))

    def add_wheel(self, stamps: np.ndarray, poses: np.ndarray, extrinsic: np.ndarray) -> None:
        self.wheel.append((stamps, poses, extrinsic))

    def forget(self, source: str) -> None:
        self.forgotten.append(source)


def _imu(seconds: float, gyro: float = 0.1, accel: float = 9.81, nanosec: int | None = None):
    sec = int(seconds)
    nano = round((seconds - sec) * 1e9) if nanosec is None else nanosec
    return SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=nano), frame_id=''),
        angular_velocity=_vector(0.0, 0.0, gyro),
        linear_acceleration=_vector(0.0, 0.0, accel),
    )


def _wheel(seconds: float, x: float, quaternion: tuple[float, ...] = (0, 0, 0, 1)) -> Any:
    msg = _imu(seconds)
    qx, qy, qz, qw = quaternion
    pose = SimpleNamespace(
        position=_vector(x, 0.0, 0.0), orientation=SimpleNamespace(x=qx, y=qy, z=qz, w=qw)
    )
    return SimpleNamespace(header=msg.header, child_frame_id='', pose=SimpleNamespace(pose=pose))


@pytest.mark.parametrize(
    ('msg', 'reason'),
    [
        (_imu(1.0, gyro=float('nan')), 'nonfinite_gyro'),
        (_imu(1.0, accel=float('inf')), 'nonfinite_accel'),
        (_imu(1.0, gyro=1e6), 'gyro_limit'),
        (_imu(1.0, gyro=36.0), 'gyro_limit'),
        (_imu(1.0, accel=1e300), 'accel_limit'),
        (_imu(1.0, accel=17 * 9.81), 'accel_limit'),
        (_imu(0.0), 'zero_stamp'),
        (_imu(1.0, nanosec=2**32 - 1), 'bad_nanosec'),
        (_imu(1.0, nanosec=10**9), 'bad_nanosec'),
        (_imu(-1.0), 'negative_stamp'),
        (SimpleNamespace(header=None), 'unreadable'),
        (_wheel(1.0, 0.0, (0, 0, 0, 0)), 'zero_quaternion'),
        (_wheel(1.0, 0.0, (0, 0, 0, 1e-300)), 'zero_quaternion'),
        (_wheel(1.0, 0.0, (0, 0, 0, 2.0)), 'nonunit_quaternion'),
        (_wheel(1.0, 0.0, (0, 0, float('inf'), 1)), 'nonfinite_orientation'),
        (_wheel(1.0, float('nan')), 'nonfinite_position'),
    ],
)
def test_each_hostile_message_is_dropped_with_its_reason(msg: Any, reason: str) -> None:
    inbox = PriorInbox()
    (inbox.on_wheel if hasattr(msg, 'pose') else inbox.on_imu)(msg)
    stream = 'wheel' if hasattr(msg, 'pose') else 'imu'
    assert inbox.drops.count(f'{stream}_dropped.{reason}') == 1
    assert inbox.drops.snapshot(('imu', 'wheel'))[f'{stream}_dropped'] == 1
    assert inbox.counts == {'imu': 0, 'wheel': 0}


def test_the_limits_keep_a_hard_drive() -> None:
    """A car braking at 1.2 g, turning at 2 rad/s, over a 20 g bump is not all dropped."""
    inbox = PriorInbox()
    for k, (gyro, accel) in enumerate([(2.0, 12.0), (5.0, 9.81 * 1.2), (34.0, 15.9 * 9.81)]):
        inbox.on_imu(_imu(1.0 + 0.005 * k, gyro, accel))
    assert inbox.counts['imu'] == 3
    inbox.on_wheel(_wheel(1.0, 0.0))
    inbox.on_wheel(_wheel(1.1, 6.0))  # 60 m/s
    inbox.on_wheel(_wheel(1.2, 14.0))  # 80 m/s: a jump
    assert inbox.counts['wheel'] == 2 and inbox.drops.count('wheel_dropped.pose_jump') == 1


def test_duplicate_backward_and_far_stamps_are_dropped_and_a_restart_is_followed() -> None:
    gate = StreamGate()
    assert gate.admit(10**9).reason == ''
    assert gate.admit(10**9).reason == 'duplicate_stamp'
    assert gate.admit(10**9 - 1).reason == 'backwards_stamp'
    assert gate.admit(10**9 + 6 * 10**9).reason == 'stamp_jump'  # one far-future sample
    assert gate.admit(10**9 + 5_000_000).reason == ''  # the stream goes on
    # 200 messages sharing one stamp: the first kept, every other dropped
    reasons = [gate.admit(2 * 10**9).reason for _ in range(200)]
    assert reasons[0] == '' and set(reasons[1:]) == {'duplicate_stamp'}
    # the stream restarts 1 s back (a bag looping): followed after RESTART_RUN samples
    back = [gate.admit(10**9 + k * 5_000_000) for k in range(RESTART_RUN)]
    assert [a.reason for a in back[:-1]] == ['backwards_stamp'] * (RESTART_RUN - 1)
    assert back[-1].reason == '' and back[-1].restarted
    assert gate.admit(10**9 + RESTART_RUN * 5_000_000).reason == ''


def test_a_restarted_wheel_stream_makes_the_model_forget_the_old_one() -> None:
    inbox, model = PriorInbox(), _Model()
    for k in range(5):
        inbox.on_wheel(_wheel(1.0 + 0.1 * k, 1.0 * k))
    for k in range(RESTART_RUN):  # the wheel odometry reset to the origin 100 m back
        inbox.on_wheel(_wheel(1.5 + 0.1 * k, -100.0 + k))
    inbox.flush(model, 'lidar', '', np.eye(4))
    assert model.forgotten == ['wheel']
    assert len(model.wheel) == 1 and model.wheel[0][0].size == 1  # the new stream's first
    assert inbox.drops.count('wheel_dropped.pose_jump') == RESTART_RUN - 1


def test_lost_messages_after_a_stream_pause_give_no_prior_across_the_hole() -> None:
    """
    Issue 34's wrong pose under load: the fuzz's cases 5 s apart, the first messages lost.

    The new case's wheel messages continue the old stream (within the gate's gap and speed),
    so the old ones stay; the prior at the keyframe must not interpolate across the hole.
    """
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.odometry.prior_model import PriorMotionModel

    inbox, model = PriorInbox(), PriorMotionModel(RegistrationConfig())
    for t in np.arange(0.0, 2.1, 0.02):  # the previous case: ends 20 m away, turned 14 deg
        s = min(t, 1.0)
        turn = tuple(Rotation.from_euler('z', 14.0 * s, degrees=True).as_quat())
        inbox.on_wheel(_wheel(1000.0 + t, 20.0 * s, turn))
    for t in np.arange(5.8, 7.1, 0.02):  # this case from 5 s later, its first 0.8 s lost
        inbox.on_wheel(_wheel(1000.0 + t, 20.0 * min(max(t - 6.0, 0.0), 1.0)))
    assert inbox.counts['wheel'] == 105 + 65  # every one kept: one stream, no restart
    inbox.flush(model, 'lidar', '', np.eye(4))
    keyframe = round(1005.0 * 1e9)  # the keyframe at t0, the moved scan at t0 + 2 s
    model.update(np.eye(4), keyframe)
    assert model.relative_prior(keyframe + 2 * 10**9) is None  # t0 lies in the hole
    assert model.predict(keyframe + 2 * 10**9) is None
    model.cfg.max_sample_gap = 0.0  # as before: interpolated across the 3.7 s hole
    prior = model.relative_prior(keyframe + 2 * 10**9)
    assert np.linalg.norm(prior.T[:3, 3] - [20.0, 0.0, 0.0]) > 2.0


def test_wheel_jump_allows_plausible_motion() -> None:
    still = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    assert wheel_jump(still, ((5.0, 0.0, 0.0), still[1]), 0.1) == ''
    assert wheel_jump(still, ((8.0, 0.0, 0.0), still[1]), 0.1) == 'pose_jump'
    turned = (still[0], tuple(Rotation.from_euler('z', 3.0).as_quat()))  # 3 rad
    assert wheel_jump(still, turned, 0.01) == 'pose_jump' and wheel_jump(still, turned, 0.1) == ''


def test_a_model_that_refuses_samples_costs_only_those_samples() -> None:
    class Refusing(_Model):
        def add_imu(self, *args: Any) -> None:
            raise ValueError('prior samples must be finite')

    inbox = PriorInbox()
    inbox.on_imu(_imu(1.0))
    inbox.on_imu(_imu(1.01))
    inbox.flush(Refusing(), 'lidar', '', np.eye(4))
    assert inbox.drops.count('imu_dropped.model_refused') == 2


def test_the_guard_counts_logs_throttled_and_answers() -> None:
    logged: list[str] = []
    now = [0.0]
    drops = DropCounter(logged.append, period_s=5.0, clock=lambda: now[0])

    def broken(msg: Any) -> None:
        raise RuntimeError(f'bad {msg}')

    callback = guard('points', broken, drops, on_error=lambda error, msg: f'answered {msg}')
    assert callback(1) == 'answered 1' and callback(2) == 'answered 2'
    assert drops.count('callback_errors') == 2 and drops.count('callback_errors.points') == 2
    assert len(logged) == 1 and 'bad 1' in logged[0]  # throttled
    for _ in range(3):
        drops.drop('imu', 'nonfinite_gyro')
    now[0] = 6.0
    drops.drop('imu', 'nonfinite_gyro')
    assert drops.count('imu_dropped') == 4
    assert [t for t in logged if 'imu' in t][-1].endswith('(2 more since the last report)')
    response = SimpleNamespace(success=True, message='')
    service = guard('reset', lambda request, response: 1 / 0, drops, failed_service)
    assert service(None, response) is response and response.success is False
    assert 'ZeroDivisionError' in response.message
    assert guard('reset', service, drops) is service  # guarded once


def test_the_guarded_spin_goes_on_after_a_raising_callback() -> None:
    class Executor:
        calls = 0

        def spin_once(self, timeout_sec: float) -> None:
            self.calls += 1
            if self.calls == 2:
                raise ValueError('Found zero norm quaternions')

    executor, drops = Executor(), DropCounter()
    spin_guarded(executor, lambda: executor.calls < 5, drops)
    assert executor.calls == 5 and drops.count('callback_errors.executor') == 1


#: A time field of any datatype, offset, count and values on a small cloud.
time_fields = st.fixed_dictionaries(
    {
        'datatype': st.integers(0, 10),
        'count': st.integers(0, 3),
        'offset': st.integers(-4, 24),
        'name': st.sampled_from(['time', 't', 'timestamp', 'time_stamp', 'offset_time']),
        'values': st.lists(floats, min_size=4, max_size=4),
        'stamp': stamps,
        'unit': st.sampled_from(['auto', 's', 'ms', 'us', 'ns', 'hours']),
    }
)


@PROPERTY
@given(time_fields)
def test_a_time_field_converts_to_one_sweep_near_the_stamp_or_says_why(spec: dict) -> None:
    from mlsemreg_ros.codec.pointcloud2 import (
        DATATYPES,
        decode_point_times,
        pointcloud2_to_arrays,
        PointCloudError,
    )
    from msg_stubs import Cloud, Field

    n, step = 4, 24  # x, y, z float32 at 0..12, then 12 bytes for the time field
    data = np.zeros((n, step), dtype=np.uint8)
    data[:, :12] = np.arange(1, 13, dtype=np.float32).view(np.uint8)[: 12 * n].reshape(n, 12)
    dtype = DATATYPES.get(spec['datatype'])
    offset = spec['offset']
    if dtype is not None and 0 <= offset and offset + dtype.itemsize <= step:
        with np.errstate(all='ignore'):
            raw = np.asarray(spec['values']).astype(dtype)
        end = offset + dtype.itemsize
        data[:, offset:end] = raw.view(np.uint8).reshape(n, -1)
    fields = [Field(a, 4 * k, 7, 1) for k, a in enumerate('xyz')]
    fields.append(Field(spec['name'], offset, spec['datatype'], spec['count']))
    stamp = spec['stamp']
    msg = Cloud(
        header=SimpleNamespace(stamp=stamp, frame_id='lidar'),
        width=n,
        fields=fields,
        point_step=step,
        row_step=step * n,
        data=data.tobytes(),
    )
    times, note = decode_point_times(msg, '', spec['unit'])  # never raises
    assert note
    if times is not None:
        assert times.shape == (n,) and np.all(np.isfinite(times))
        assert float(times.max() - times.min()) <= 1.0 and np.abs(times).max() <= 1.0
    try:
        cloud = pointcloud2_to_arrays(msg, require_labels=False, time_unit=spec['unit'])
    except PointCloudError as error:  # only a time field past the point step is malformed
        assert 'does not fit' in str(error) and spec['name'] in str(error)
        return
    if cloud.point_times is None:
        assert cloud.time_note
    else:
        np.testing.assert_array_equal(cloud.point_times, times)


def test_the_prior_guard_flags_a_prior_far_from_the_registration() -> None:
    from mlsemreg_ros.core.features.deskew import PiecewiseSweepMotion
    from mlsemreg_ros.core.odometry.motion_model import Prediction
    from mlsemreg_ros.core.odometry.prior_guard import (
        better_without_prior,
        prior_disagreement,
        sweep_disagreement_deg,
    )

    def turn(deg: float) -> np.ndarray:
        out = np.eye(4)
        out[:3, :3] = Rotation.from_euler('z', deg, degrees=True).as_matrix()
        return out

    stamp, last = 10**9, (np.eye(4), 10**9 - 100_000_000)  # 0.1 s before
    chosen = SimpleNamespace(accepted=True, pose=turn(5.0), inlier_fraction=0.8)
    model = SimpleNamespace(last_source='imu')
    agrees = prior_disagreement(Prediction(turn(4.0), 1), chosen, None, model, last, stamp, 3.0)
    assert agrees == ''
    why = prior_disagreement(Prediction(turn(9.0), 1), chosen, None, model, last, stamp, 3.0)
    assert "prior's rotation is 4.00 deg" in why
    cv = SimpleNamespace(last_source='constant_velocity')  # no prior: never flagged
    assert prior_disagreement(Prediction(turn(30.0), 1), chosen, None, cv, last, stamp, 3.0) == ''
    rejected = SimpleNamespace(accepted=False, pose=None, inlier_fraction=None)
    assert 'rejected' in prior_disagreement(None, rejected, None, model, last, stamp, 3.0)
    # the gyro within a 0.1 s sweep: 5 deg expected (the registration's rate), 5 or 15 deg seen
    times = np.array([-0.1, 0.0])
    for gyro_deg, expected in ((5.0, 0.0), (15.0, 10.0)):
        rotations = np.stack([turn(-gyro_deg)[:3, :3], np.eye(3)])
        motion = PiecewiseSweepMotion.from_rotations(times, rotations, np.zeros(3))
        assert abs(sweep_disagreement_deg(motion, last, turn(5.0), stamp) - expected) < 1e-6
        assert sweep_disagreement_deg(motion, (np.eye(4), 0), turn(5.0), stamp) == 0.0  # 1 s
    # the registration without the prior is kept when it aligns at least as well
    worse = SimpleNamespace(accepted=True, inlier_fraction=0.7)
    assert not better_without_prior(chosen, worse) and better_without_prior(worse, chosen)
    assert better_without_prior(rejected, worse) and not better_without_prior(chosen, rejected)


def test_a_rejection_is_retried_without_the_prior_only_after_an_accepted_scan() -> None:
    from mlsemreg_ros.core.odometry.prior_guard import prior_disagreement

    rejected = SimpleNamespace(accepted=False, pose=None, inlier_fraction=None)
    model = SimpleNamespace(last_source='wheel')
    assert prior_disagreement(None, rejected, None, model, None, 10**9, 3.0, 0)
    assert prior_disagreement(None, rejected, None, model, None, 10**9, 3.0, 1) == ''
