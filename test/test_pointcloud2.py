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

"""PointCloud2 <-> NumPy: every label datatype, organized clouds, every malformed case."""

from __future__ import annotations

import dataclasses
from typing import Any

from mlsemreg_ros.codec.pointcloud2 import (
    arrays_to_pointcloud2,
    DATATYPE_BY_NAME,
    FLOAT32,
    pointcloud2_to_arrays,
    PointCloudError,
    UINT16,
    UINT32,
)
from msg_stubs import Cloud, Field
import numpy as np
import pytest


def _scene(n: int = 50, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.uniform(-20, 20, size=(n, 3)), rng.integers(0, 20, size=n)


def _cloud(xyz: np.ndarray, labels: np.ndarray | None = None, **kw: Any) -> Cloud:
    return arrays_to_pointcloud2(Cloud, Field, None, xyz, labels, **kw)


@pytest.mark.parametrize('name', list(DATATYPE_BY_NAME))
def test_every_label_datatype_round_trips(name: str) -> None:
    xyz, _ = _scene()
    signed = name.startswith(('int', 'float'))
    labels = np.arange(-25 if signed else 0, 25 if signed else 50)
    msg = _cloud(xyz, labels, label_datatype=name)
    assert msg.fields[-1].datatype == DATATYPE_BY_NAME[name]
    out = pointcloud2_to_arrays(msg)
    assert out.labels.dtype == np.int64
    np.testing.assert_array_equal(out.labels, labels)
    np.testing.assert_allclose(out.xyz, xyz, atol=1e-5)
    assert out.xyz.dtype == np.float64 and out.xyz.shape == (50, 3)
    assert out.intensity is None and out.dropped_nonfinite == 0


def test_raw_labels_keep_instance_bits() -> None:
    xyz, _ = _scene(4)
    semantic = np.array([10, 40, 252, 80], dtype=np.uint32)
    instance = np.array([0, 7, 65535, 3], dtype=np.uint32)
    raw = semantic | (instance << np.uint32(16))
    out = pointcloud2_to_arrays(_cloud(xyz, raw))
    np.testing.assert_array_equal(out.labels, raw.astype(np.int64))
    np.testing.assert_array_equal(out.labels & 0xFFFF, semantic)
    # The same bits in an int32 field read back as (negative) int64, bit for bit.
    out = pointcloud2_to_arrays(_cloud(xyz, raw.view(np.int32), label_datatype='int32'))
    np.testing.assert_array_equal(out.labels & 0xFFFFFFFF, raw)


def test_intensity_and_custom_label_field() -> None:
    xyz, labels = _scene(10)
    msg = _cloud(xyz, labels, intensity=np.linspace(0, 1, 10), label_field='class')
    out = pointcloud2_to_arrays(msg, label_field='class')
    np.testing.assert_allclose(out.intensity, np.linspace(0, 1, 10), atol=1e-7)
    assert out.intensity.dtype == np.float32
    with pytest.raises(PointCloudError, match="missing label field 'label'"):
        pointcloud2_to_arrays(msg)


def test_organized_cloud_with_row_padding() -> None:
    # 2 x 3 points, point_step 24 with an unused 'ring' field and padding, row_step 80.
    height, width, point_step, row_step = 2, 3, 24, 80
    dtype = np.dtype(
        {
            'names': ['ring', 'x', 'y', 'z', 'label'],
            'formats': ['<u2', '<f4', '<f4', '<f4', '<u4'],
            'offsets': [0, 4, 8, 12, 18],
            'itemsize': point_step,
        }
    )
    buf = np.full(height * row_step, 0xAB, dtype=np.uint8)  # garbage in all padding
    xyz = np.arange(18, dtype=np.float32).reshape(6, 3)
    labels = np.array([1, 2, 3, 4, 5, 70 | (9 << 16)], dtype=np.uint32)
    for r in range(height):
        row = np.ndarray((width,), dtype=dtype, buffer=buf, offset=r * row_step)
        span = slice(r * width, (r + 1) * width)
        for name, col in zip('xyz', xyz[span].T, strict=True):
            row[name] = col
        row['label'] = labels[span]
    msg = Cloud(
        height=height,
        width=width,
        point_step=point_step,
        row_step=row_step,
        data=buf.tobytes(),
        fields=[
            Field('ring', 0, UINT16),
            Field('x', 4, FLOAT32),
            Field('y', 8, FLOAT32),
            Field('z', 12, FLOAT32),
            Field('label', 18, UINT32),
        ],
    )
    out = pointcloud2_to_arrays(msg)
    np.testing.assert_array_equal(out.xyz, xyz)
    np.testing.assert_array_equal(out.labels, labels)
    # The same buffer as a NumPy uint8 array (rosbags) and as a list of ints.
    for data in (buf, list(buf)):
        out = pointcloud2_to_arrays(dataclasses.replace(msg, data=data))
        np.testing.assert_array_equal(out.labels, labels)


def test_nonfinite_points_are_dropped_and_counted() -> None:
    xyz, labels = _scene(6)
    xyz[1, 0], xyz[4, 2] = np.nan, np.inf
    out = pointcloud2_to_arrays(_cloud(xyz, labels))
    assert out.dropped_nonfinite == 2
    np.testing.assert_array_equal(out.labels, labels[[0, 2, 3, 5]])
    np.testing.assert_allclose(out.xyz, xyz[[0, 2, 3, 5]], atol=1e-5)
    with pytest.raises(PointCloudError, match='all 6 points have NaN/inf'):
        pointcloud2_to_arrays(_cloud(np.full((6, 3), np.nan), labels))


def test_labels_optional() -> None:
    xyz, _ = _scene(5)
    out = pointcloud2_to_arrays(_cloud(xyz), require_labels=False)
    assert out.labels is None and len(out) == 5


def _good() -> Cloud:
    xyz, labels = _scene(8)
    return _cloud(xyz, labels)


def _with_field(msg: Cloud, name: str, **changes: Any) -> Cloud:
    fields = [dataclasses.replace(f, **changes) if f.name == name else f for f in msg.fields]
    return dataclasses.replace(msg, fields=fields)


MALFORMED = {
    'missing x': (
        lambda m: dataclasses.replace(m, fields=m.fields[1:]),
        r"missing coordinate field\(s\) \['x'\]",
    ),
    'missing label': (
        lambda m: dataclasses.replace(m, fields=m.fields[:3]),
        "missing label field 'label'",
    ),
    'unsupported datatype': (
        lambda m: _with_field(m, 'label', datatype=9),
        "'label' has unsupported datatype 9",
    ),
    'count 3': (lambda m: _with_field(m, 'x', count=3), "'x' has count 3"),
    'field beyond point_step': (
        lambda m: _with_field(m, 'label', offset=14),
        "'label' .* does not fit in point_step 16",
    ),
    'row_step too small': (
        lambda m: dataclasses.replace(m, row_step=m.row_step - 1),
        'row_step 127 < width 8 x point_step 16',
    ),
    'data too short': (
        lambda m: dataclasses.replace(m, data=m.data[:-3]),
        'data has 125 bytes, expected .* = 128',
    ),
    'data too long': (lambda m: dataclasses.replace(m, data=m.data + b'\0'), 'data has 129 bytes'),
    'point_step vs data': (
        lambda m: dataclasses.replace(m, point_step=20),
        'row_step 128 < width 8 x point_step 20',
    ),
    'big-endian': (lambda m: dataclasses.replace(m, is_bigendian=True), 'big-endian'),
    'zero points': (
        lambda m: dataclasses.replace(m, width=0, row_step=0, data=b''),
        'zero points',
    ),
    'zero height': (lambda m: dataclasses.replace(m, height=0), 'zero points'),
    'duplicate field': (
        lambda m: dataclasses.replace(m, fields=m.fields + m.fields[:1]),
        "'x' appears twice",
    ),
    'count-0 x': (
        lambda m: _with_field(m, 'x', count=0),
        r"missing coordinate field\(s\) \['x'\].*ignored count-0 field\(s\): \['x'\]",
    ),
    'count-0 label': (
        lambda m: _with_field(m, 'label', count=0),
        "missing label field 'label'.*count-0 field",
    ),
    'negative count': (lambda m: _with_field(m, 'label', count=-1), "'label' has count -1"),
    'negative sizes': (
        lambda m: dataclasses.replace(m, height=-1, width=-8),
        'negative height -1 or width -8',
    ),
}


@pytest.mark.parametrize('case', list(MALFORMED))
def test_malformed_clouds_raise_with_reason(case: str) -> None:
    mutate, pattern = MALFORMED[case]
    with pytest.raises(PointCloudError, match=pattern):
        pointcloud2_to_arrays(mutate(_good()))


def test_float_labels_must_be_integral_and_finite() -> None:
    xyz, _ = _scene(3)
    with pytest.raises(PointCloudError, match='non-integral'):
        pointcloud2_to_arrays(_cloud(xyz, np.array([1.0, 2.5, 3.0]), label_datatype='float32'))
    with pytest.raises(PointCloudError, match='NaN/inf'):
        pointcloud2_to_arrays(_cloud(xyz, np.array([1.0, np.nan, 3.0]), label_datatype='float64'))


def test_writer_rejects_labels_that_do_not_fit() -> None:
    xyz, _ = _scene(3)
    with pytest.raises(PointCloudError, match='do not fit uint8'):
        _cloud(xyz, np.array([1, 300, 2]), label_datatype='uint8')
    with pytest.raises(PointCloudError, match='do not fit uint32'):
        _cloud(xyz, np.array([1, -1, 2]))
    with pytest.raises(PointCloudError, match='unknown label datatype'):
        _cloud(xyz, np.array([1, 1, 2]), label_datatype='int64')
    with pytest.raises(PointCloudError, match='label has 2 values for 3 points'):
        _cloud(xyz, np.array([1, 2]))


def test_rclpy_message_round_trip() -> None:
    msg_mod = pytest.importorskip('sensor_msgs.msg', reason='rclpy message wheels not installed')
    header_mod = pytest.importorskip('std_msgs.msg')
    xyz, labels = _scene(100)
    header = header_mod.Header(frame_id='velodyne')
    msg = arrays_to_pointcloud2(
        msg_mod.PointCloud2,
        msg_mod.PointField,
        header,
        xyz,
        labels.astype(np.uint32),
        intensity=np.ones(100),
    )
    assert isinstance(msg, msg_mod.PointCloud2) and msg.header.frame_id == 'velodyne'
    assert [f.name for f in msg.fields] == ['x', 'y', 'z', 'intensity', 'label']
    assert msg.fields[-1].datatype == msg_mod.PointField.UINT32
    out = pointcloud2_to_arrays(msg)
    np.testing.assert_array_equal(out.labels, labels)
    np.testing.assert_allclose(out.xyz, xyz, atol=1e-5)


def test_rosbags_typestore_round_trip_through_cdr() -> None:
    typesys = pytest.importorskip('rosbags.typesys', reason='rosbags not installed')
    store = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    types = store.types
    header = types['std_msgs/msg/Header'](
        stamp=types['builtin_interfaces/msg/Time'](sec=3, nanosec=5), frame_id='velodyne'
    )
    xyz, labels = _scene(100)
    raw = labels.astype(np.uint32) | (np.uint32(4) << np.uint32(16))
    msg = arrays_to_pointcloud2(
        types['sensor_msgs/msg/PointCloud2'], types['sensor_msgs/msg/PointField'], header, xyz, raw
    )
    assert msg.fields[0].datatype == types['sensor_msgs/msg/PointField'].FLOAT32
    blob = store.serialize_cdr(msg, msg.__msgtype__)
    back = store.deserialize_cdr(blob, msg.__msgtype__)
    out = pointcloud2_to_arrays(back)
    np.testing.assert_array_equal(out.labels, raw)
    np.testing.assert_allclose(out.xyz, xyz, atol=1e-5)


def _with_extra_field(msg: Cloud, extra: Field) -> Cloud:
    return dataclasses.replace(msg, fields=[*msg.fields, extra])


def test_count_0_fields_are_ignored() -> None:
    # Issue 11: an unused intensity declared with count 0 made a usable cloud rejected.
    xyz, labels = _scene(8)
    msg = _cloud(xyz, labels)
    for extra in (
        Field('intensity', 0, FLOAT32, count=0),
        Field('ring', 40, 99, count=0),
        Field('x', 999, 0, count=0),
    ):  # even a second, count-0 'x'
        out = pointcloud2_to_arrays(_with_extra_field(msg, extra))
        assert out.ignored_fields == (extra.name,) and out.intensity is None
        np.testing.assert_array_equal(out.labels, labels)
        np.testing.assert_allclose(out.xyz, xyz, atol=1e-5)
    assert pointcloud2_to_arrays(msg).ignored_fields == ()


def test_unreadable_optional_intensity_is_ignored() -> None:
    xyz, labels = _scene(8)
    msg = _cloud(xyz, labels, intensity=np.ones(8))
    for changes in ({'count': 3}, {'datatype': 9}):
        out = pointcloud2_to_arrays(_with_field(msg, 'intensity', **changes))
        assert out.intensity is None and out.ignored_fields == ('intensity',)
        np.testing.assert_array_equal(out.labels, labels)
    # A layout error stays an error, optional field or not.
    with pytest.raises(PointCloudError, match=r"'intensity' .* does not fit"):
        pointcloud2_to_arrays(_with_field(msg, 'intensity', offset=msg.point_step - 2))


def test_int32_raw_label_of_minus_2_31_decodes_and_converts() -> None:
    from mlsemreg_ros.core.matching.labels import LabelMap

    xyz, _ = _scene(4)
    raw = np.array([0x80000000, 40 | (3 << 16), 70, 81 | (0xFFFF << 16)], dtype=np.uint32)
    out = pointcloud2_to_arrays(_cloud(xyz, raw.view(np.int32), label_datatype='int32'))
    assert out.labels.dtype == np.int64 and out.labels[0] == -(2**31)
    converted = LabelMap.load().convert(out.labels)
    assert converted.scheme == 'raw' and converted.out_of_scheme == 0
    np.testing.assert_array_equal(converted.ids, [0, 9, 15, 19])
