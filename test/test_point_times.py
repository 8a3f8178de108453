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

"""Per-point time decoding: every driver convention, known answers on hand-made clouds."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mlsemreg_ros.codec.pointcloud2 import (
    decode_point_times,
    FLOAT32,
    FLOAT64,
    pointcloud2_to_arrays,
    UINT32,
)
from msg_stubs import Cloud, Field
import numpy as np
import pytest

#: A header stamp of 1.7e9 s (2023), with nanoseconds, as a driver's.
STAMP_SEC, STAMP_NANOSEC = 1_700_000_000, 250_000_000
STAMP_S = STAMP_SEC + 1e-9 * STAMP_NANOSEC
#: The true per-point times of the hand-made sweep: 0..0.1 s after the stamp.
TRUE_TIMES = np.linspace(0.0, 0.099, 12)


@dataclass
class _Time:
    sec: int
    nanosec: int


@dataclass
class _Header:
    stamp: _Time
    frame_id: str = 'lidar'


def _cloud(extra: dict[str, tuple[int, np.ndarray]], stamp: tuple[int, int] | None = None) -> Any:
    """Build a cloud with x, y, z float32 and the ``extra`` fields ``name: (datatype, values)``."""
    from mlsemreg_ros.codec.pointcloud2 import DATATYPES

    n = TRUE_TIMES.size
    spec = [('x', FLOAT32), ('y', FLOAT32), ('z', FLOAT32), *((k, v[0]) for k, v in extra.items())]
    dtype = np.dtype([(name, DATATYPES[datatype]) for name, datatype in spec])
    packed = np.zeros(n, dtype=dtype)
    packed['x'] = np.arange(n, dtype=np.float32) + 1.0
    for name, (_, values) in extra.items():
        packed[name] = values
    fields = [Field(name, dtype.fields[name][1], datatype, 1) for name, datatype in spec]
    sec, nanosec = stamp if stamp is not None else (STAMP_SEC, STAMP_NANOSEC)
    return Cloud(
        header=_Header(_Time(sec, nanosec)),
        width=n,
        fields=fields,
        point_step=dtype.itemsize,
        row_step=dtype.itemsize * n,
        data=packed.tobytes(),
    )


CONVENTIONS = {
    # Velodyne driver: float32 seconds after the stamp (sweep start)
    'velodyne time s': {'time': (FLOAT32, TRUE_TIMES)},
    # Ouster driver: uint32 nanoseconds after the stamp
    'ouster t ns': {'t': (UINT32, np.round(TRUE_TIMES * 1e9))},
    # Hesai / RoboSense: float64 absolute seconds
    'hesai timestamp abs s': {'timestamp': (FLOAT64, STAMP_S + TRUE_TIMES)},
    # Livox (livox_ros_driver2 PointCloud2): float64 absolute nanoseconds
    'livox timestamp abs ns': {
        'timestamp': (FLOAT64, (STAMP_SEC * 10**9 + STAMP_NANOSEC) + TRUE_TIMES * 1e9)
    },
    # Livox custom point: offset_time, uint32 ns after the stamp
    'livox offset_time ns': {'offset_time': (UINT32, np.round(TRUE_TIMES * 1e9))},
    'time_stamp ns': {'time_stamp': (UINT32, np.round(TRUE_TIMES * 1e9))},
    # a t field in float seconds
    't float s': {'t': (FLOAT32, TRUE_TIMES)},
    # microseconds and milliseconds, found from the span
    'time us': {'time': (UINT32, np.round(TRUE_TIMES * 1e6))},
    'time ms float': {'time': (FLOAT32, TRUE_TIMES * 1e3)},
}


@pytest.mark.parametrize('name', list(CONVENTIONS))
def test_every_convention_is_decoded_to_seconds_after_the_stamp(name: str) -> None:
    times, note = decode_point_times(_cloud(CONVENTIONS[name]))
    assert times is not None, note
    assert times.dtype == np.float64
    np.testing.assert_allclose(times, TRUE_TIMES, atol=1e-6, err_msg=note)


def test_velodyne_times_before_the_sweep_end_stay_negative() -> None:
    before_end = TRUE_TIMES - 0.1  # drivers that stamp the sweep end
    times, _ = decode_point_times(_cloud({'time': (FLOAT32, before_end)}))
    np.testing.assert_allclose(times, before_end, atol=1e-7)


def test_absolute_float64_nanoseconds_keep_sub_microsecond_offsets() -> None:
    stamp_ns = STAMP_SEC * 10**9 + STAMP_NANOSEC
    offsets = np.array([0, 1, 7, 99_999_999] + [5] * (TRUE_TIMES.size - 4), dtype=np.int64)
    msg = _cloud({'timestamp': (FLOAT64, (stamp_ns + offsets).astype(np.float64))})
    times, note = decode_point_times(msg)
    np.testing.assert_allclose(times, offsets * 1e-9, atol=3e-7, err_msg=note)


def test_first_convention_wins_and_the_field_and_unit_are_configurable() -> None:
    msg = _cloud({'time': (FLOAT32, TRUE_TIMES), 't': (UINT32, np.round(TRUE_TIMES * 2e9))})
    auto, _ = decode_point_times(msg)
    np.testing.assert_allclose(auto, TRUE_TIMES, atol=1e-7)
    chosen, _ = decode_point_times(msg, time_field='t')
    np.testing.assert_allclose(chosen, 2 * TRUE_TIMES, atol=1e-7)
    as_ms, _ = decode_point_times(msg, time_field='time', time_unit='ms')
    np.testing.assert_allclose(as_ms, 1e-3 * TRUE_TIMES, rtol=1e-6)
    as_us, note = decode_point_times(msg, time_field='t', time_unit='us')  # 198 s: not a sweep
    assert as_us is None and 'span 198 s' in note and 'not used for deskew' in note


@pytest.mark.parametrize(
    ('extra', 'stamp', 'why'),
    [
        # float64 absolute seconds 1.7e9 s away from the header stamp (a stamp of 100 s)
        ({'timestamp': (FLOAT64, STAMP_S + TRUE_TIMES)}, (100, 0), 's from the header stamp'),
        # relative seconds 5 s after the stamp
        ({'time': (FLOAT32, 5.0 + TRUE_TIMES)}, None, 's from the header stamp'),
        # a span of 50 s whatever the unit (float seconds, explicit)
        ({'time': (FLOAT32, 500 * TRUE_TIMES)}, None, 'span'),
        # float64 values beyond float range once scaled
        ({'time': (FLOAT64, np.full(TRUE_TIMES.size, 1e308) * TRUE_TIMES)}, None, 'span'),
    ],
)
def test_times_that_are_not_one_sweep_near_the_stamp_are_not_used_and_warned(
    extra: dict, stamp: tuple[int, int] | None, why: str
) -> None:
    msg = _cloud(extra, stamp=stamp)
    unit = 's' if 'time' in extra else 'auto'
    times, note = decode_point_times(msg, time_unit=unit)
    assert times is None and why in note
    cloud = pointcloud2_to_arrays(msg, require_labels=False, time_unit=unit)
    assert cloud.point_times is None and cloud.time_warning == cloud.time_note != ''
    plain = pointcloud2_to_arrays(_cloud({}), require_labels=False)
    assert plain.point_times is None and plain.time_warning == ''  # no field: no warning


def test_a_time_field_past_the_point_step_is_malformed() -> None:
    from mlsemreg_ros.codec.pointcloud2 import PointCloudError

    msg = _cloud({'time': (FLOAT32, TRUE_TIMES)})
    msg.fields[-1] = Field('time', msg.fields[-1].offset, FLOAT64, 1)  # 8 bytes from 12 of 16
    with pytest.raises(PointCloudError, match=r"field 'time' .* does not fit"):
        pointcloud2_to_arrays(msg, require_labels=False)
    pointcloud2_to_arrays(msg, require_labels=False, time_field=None)  # times not read: fine


def test_the_arrays_carry_the_times_of_the_finite_points() -> None:
    msg = _cloud({'time': (FLOAT32, TRUE_TIMES)})
    xyz = np.frombuffer(bytearray(msg.data), dtype=np.uint8).copy()
    step = msg.point_step
    xyz[slice(2 * step, 2 * step + 4)] = np.frombuffer(np.float32(np.nan).tobytes(), np.uint8)
    msg.data = xyz.tobytes()
    cloud = pointcloud2_to_arrays(msg, require_labels=False)
    assert cloud.dropped_nonfinite == 1 and len(cloud) == TRUE_TIMES.size - 1
    np.testing.assert_allclose(cloud.point_times, np.delete(TRUE_TIMES, 2), atol=1e-7)
    assert 'time' in cloud.time_note


@pytest.mark.parametrize(
    ('extra', 'kwargs', 'why'),
    [
        ({}, {}, 'no per-point time field'),
        ({'time': (FLOAT32, TRUE_TIMES)}, {'time_field': 'stamp'}, "'stamp' not in the cloud"),
        ({'time': (FLOAT32, np.full(TRUE_TIMES.size, np.nan))}, {}, 'NaN/inf'),
        ({'time': (FLOAT32, TRUE_TIMES)}, {'time_unit': 'hours'}, 'unknown time unit'),
    ],
)
def test_missing_or_bad_time_fields_give_none_and_say_why(
    extra: dict, kwargs: dict, why: str
) -> None:
    msg = _cloud(extra)
    times, note = decode_point_times(msg, **kwargs)
    assert times is None and why in note
    cloud = pointcloud2_to_arrays(msg, require_labels=False, **kwargs)  # never raises
    assert cloud.point_times is None and why in cloud.time_note


def test_unreadable_time_field_is_ignored() -> None:
    msg = _cloud({'time': (FLOAT32, TRUE_TIMES)})
    msg.fields[-1] = Field('time', msg.fields[-1].offset, 42, 1)  # unknown datatype
    times, note = decode_point_times(msg)
    assert times is None and 'unreadable' in note


def test_times_can_be_skipped_and_an_unstamped_cloud_keeps_relative_times() -> None:
    msg = _cloud({'time': (FLOAT32, TRUE_TIMES)}, stamp=(0, 0))
    assert pointcloud2_to_arrays(msg, require_labels=False, time_field=None).point_times is None
    times, _ = decode_point_times(msg)
    np.testing.assert_allclose(times, TRUE_TIMES, atol=1e-7)
