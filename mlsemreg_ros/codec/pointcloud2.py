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
``sensor_msgs/PointCloud2`` <-> NumPy, vectorized, without importing ROS.

Both functions are duck-typed on the message: they work with rclpy's
``sensor_msgs.msg.PointCloud2`` and with the message classes of a rosbags
typestore (same attribute names: ``header, height, width, fields[name, offset,
datatype, count], is_bigendian, point_step, row_step, data, is_dense``).

Reading builds one structured dtype from the fields (offsets, ``itemsize =
point_step``) and views the buffer with strides ``(row_step, point_step)``, so
organized clouds with row padding need no copy and no Python loop over points.

Only ``x, y, z`` and the label field are required. Fields with ``count 0`` are
ignored wherever they are (a required one then counts as missing), and so is an
optional ``intensity`` field that cannot be read (count above 1, unknown
datatype); :attr:`CloudArrays.ignored_fields` names them. Labels are returned
as stored (int64); :meth:`mlsemreg_ros.core.labels.LabelMap.convert` reads them as
uint32 bit patterns, so an int32 raw label of -2**31 (instance bits set, class 0)
is an ordinary raw id.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

# sensor_msgs/PointField datatype constants (defined here so ROS is not imported).
INT8 = 1
UINT8 = 2
INT16 = 3
UINT16 = 4
INT32 = 5
UINT32 = 6
FLOAT32 = 7
FLOAT64 = 8

#: PointField datatype -> little-endian NumPy dtype.
DATATYPES: dict[int, np.dtype] = {
    INT8: np.dtype('<i1'),
    UINT8: np.dtype('<u1'),
    INT16: np.dtype('<i2'),
    UINT16: np.dtype('<u2'),
    INT32: np.dtype('<i4'),
    UINT32: np.dtype('<u4'),
    FLOAT32: np.dtype('<f4'),
    FLOAT64: np.dtype('<f8'),
}

#: Datatype names accepted by :func:`arrays_to_pointcloud2` for the label field.
DATATYPE_BY_NAME: dict[str, int] = {
    'int8': INT8,
    'uint8': UINT8,
    'int16': INT16,
    'uint16': UINT16,
    'int32': INT32,
    'uint32': UINT32,
    'float32': FLOAT32,
    'float64': FLOAT64,
}


class PointCloudError(ValueError):
    """A PointCloud2 message cannot be converted; the message says why."""


@dataclass
class CloudArrays:
    """The finite points of one PointCloud2 as arrays."""

    xyz: np.ndarray  # (N, 3) float64, metres, in the message's frame
    labels: np.ndarray | None  # (N,) int64 raw label values as stored (instance bits kept)
    intensity: np.ndarray | None  # (N,) float32
    dropped_nonfinite: int  # points dropped because x, y or z was NaN/inf
    ignored_fields: tuple[str, ...] = ()  # count-0 fields and unreadable optional fields

    def __len__(self) -> int:
        return int(self.xyz.shape[0])


def _field_dtype(field: Any) -> np.dtype:
    """Return the NumPy dtype of one count-1 PointField, or raise PointCloudError."""
    if int(field.count) != 1:
        raise PointCloudError(
            f'field {field.name!r} has count {field.count}; only count 1 is supported'
        )
    try:
        return DATATYPES[int(field.datatype)]
    except KeyError:
        raise PointCloudError(
            f'field {field.name!r} has unsupported datatype {field.datatype} '
            f'(known: 1-8, INT8..FLOAT64)'
        ) from None


def _buffer(data: Any) -> np.ndarray:
    """View the message's ``data`` (bytes, array.array, NumPy array or list) as uint8."""
    if isinstance(data, np.ndarray):
        return np.ascontiguousarray(data).view(np.uint8).reshape(-1)
    try:
        return np.frombuffer(memoryview(data).cast('B'), dtype=np.uint8)
    except TypeError:
        return np.asarray(data, dtype=np.uint8).reshape(-1)


def pointcloud2_to_arrays(
    msg: Any, label_field: str = 'label', require_labels: bool = True
) -> CloudArrays:
    """
    Convert a PointCloud2 to xyz (N, 3) float64, raw labels (N,) int64 and intensity.

    Any integer or float label datatype is accepted and converted losslessly to
    int64 (signed types keep their sign; the core reads the uint32 bit pattern);
    float labels must hold integral values. SemanticKITTI instance bits are kept
    here (the core's LabelMap masks them). Points with a NaN/inf coordinate are
    dropped and counted; count-0 fields and an unreadable optional ``intensity``
    are ignored and named; every other defect raises :class:`PointCloudError`
    with the reason.
    """
    if bool(msg.is_bigendian):
        raise PointCloudError('big-endian point clouds are not supported')
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    if height < 0 or width < 0:
        raise PointCloudError(f'negative height {height} or width {width}')
    if height * width == 0:
        raise PointCloudError(f'cloud has zero points (height={height}, width={width})')
    fields, ignored = {}, []
    for f in msg.fields:
        if int(f.count) == 0:  # declared but holds no value (e.g. an unused intensity)
            ignored.append(str(f.name))
            continue
        if f.name in fields:
            raise PointCloudError(f'field {f.name!r} appears twice')
        fields[f.name] = f
    missing = [name for name in ('x', 'y', 'z') if name not in fields]
    if missing:
        raise PointCloudError(
            f'missing coordinate field(s) {missing}; fields: {list(fields)}'
            + _count0_note(ignored)
        )
    wanted = ['x', 'y', 'z']
    if label_field in fields:
        wanted.append(label_field)
    elif require_labels:
        raise PointCloudError(
            f'missing label field {label_field!r}; fields: {list(fields)} '
            f'(set the label_field parameter)' + _count0_note(ignored)
        )
    if 'intensity' in fields and 'intensity' not in wanted:
        if _readable(fields['intensity']):
            wanted.append('intensity')
        else:
            ignored.append('intensity')
    names, formats, offsets = [], [], []
    for name in wanted:
        dtype, offset = _field_dtype(fields[name]), int(fields[name].offset)
        if offset < 0 or offset + dtype.itemsize > point_step:
            raise PointCloudError(
                f'field {name!r} (offset {offset}, {dtype.itemsize} bytes) does not fit in '
                f'point_step {point_step}'
            )
        names.append(name)
        formats.append(dtype)
        offsets.append(offset)
    if row_step < width * point_step:
        raise PointCloudError(f'row_step {row_step} < width {width} x point_step {point_step}')
    buffer = _buffer(msg.data)
    if buffer.size != height * row_step:
        raise PointCloudError(
            f'data has {buffer.size} bytes, expected height {height} x row_step {row_step} '
            f'= {height * row_step}'
        )
    dtype = np.dtype(
        {'names': names, 'formats': formats, 'offsets': offsets, 'itemsize': point_step}
    )
    points = np.ndarray(
        (height, width), dtype=dtype, buffer=buffer, strides=(row_step, point_step)
    ).reshape(-1)
    xyz = np.stack([points['x'], points['y'], points['z']], axis=1).astype(np.float64)
    finite = np.isfinite(xyz).all(axis=1)
    dropped = int(finite.size - np.count_nonzero(finite))
    if dropped == finite.size:
        raise PointCloudError(f'all {dropped} points have NaN/inf coordinates')
    keep = None if dropped == 0 else finite
    labels = None
    if label_field in names:
        labels = _labels_to_int64(
            points[label_field] if keep is None else points[label_field][keep], label_field
        )
    intensity = None
    if 'intensity' in names:
        values = points['intensity'] if keep is None else points['intensity'][keep]
        with np.errstate(over='ignore'):  # float64 beyond float32 range: inf, no warning
            intensity = values.astype(np.float32)
    return CloudArrays(
        xyz if keep is None else xyz[keep], labels, intensity, dropped, tuple(ignored)
    )


def _readable(field: Any) -> bool:
    """Whether an optional field has count 1 and a known datatype."""
    return int(field.count) == 1 and int(field.datatype) in DATATYPES


def _count0_note(ignored: list[str]) -> str:
    """Name the count-0 fields in a missing-field error, if any."""
    return f'; ignored count-0 field(s): {ignored}' if ignored else ''


def _labels_to_int64(values: np.ndarray, name: str) -> np.ndarray:
    """Labels of any supported datatype -> int64, losslessly; floats must be integral."""
    if values.dtype.kind == 'f':
        if not np.all(np.isfinite(values)):
            raise PointCloudError(f'label field {name!r} holds NaN/inf values')
        if np.any(values != np.round(values)):
            raise PointCloudError(f'label field {name!r} holds non-integral float values')
        if np.any(np.abs(values) > 2.0**53):
            raise PointCloudError(f'label field {name!r} holds floats beyond 2^53')
    return values.astype(np.int64)


def arrays_to_pointcloud2(
    msg_cls: type,
    field_cls: type,
    header: Any,
    xyz: np.ndarray,
    labels: np.ndarray | None = None,
    intensity: np.ndarray | None = None,
    label_datatype: str = 'uint32',
    label_field: str = 'label',
) -> Any:
    """
    Build an unorganized (height 1) PointCloud2 from arrays.

    Layout: ``x, y, z`` float32, then ``intensity`` float32 (if given), then
    the label field (``label_datatype``, uint32 by default; values must be
    representable exactly). ``msg_cls``/``field_cls`` are rclpy's
    ``sensor_msgs.msg.PointCloud2``/``PointField`` or a rosbags typestore's; rosbags
    classes get ``data`` as a uint8 array, rclpy classes get bytes.
    """
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    n = xyz.shape[0]
    spec: list[tuple[str, int]] = [('x', FLOAT32), ('y', FLOAT32), ('z', FLOAT32)]
    columns: dict[str, np.ndarray] = {'x': xyz[:, 0], 'y': xyz[:, 1], 'z': xyz[:, 2]}
    if intensity is not None:
        spec.append(('intensity', FLOAT32))
        columns['intensity'] = np.asarray(intensity).reshape(-1)
    if labels is not None:
        if label_datatype not in DATATYPE_BY_NAME:
            raise PointCloudError(
                f'unknown label datatype {label_datatype!r}; use one of {list(DATATYPE_BY_NAME)}'
            )
        datatype = DATATYPE_BY_NAME[label_datatype]
        values = np.asarray(labels).reshape(-1)
        cast = values.astype(DATATYPES[datatype])
        if not np.array_equal(
            cast.astype(values.dtype), values, equal_nan=values.dtype.kind == 'f'
        ):
            raise PointCloudError(f'labels do not fit {label_datatype} exactly')
        spec.append((label_field, datatype))
        columns[label_field] = cast
    for name, column in columns.items():
        if column.shape[0] != n:
            raise PointCloudError(f'{name} has {column.shape[0]} values for {n} points')
    offsets, offset = [], 0
    for _, datatype in spec:
        offsets.append(offset)
        offset += DATATYPES[datatype].itemsize
    dtype = np.dtype(
        {
            'names': [s[0] for s in spec],
            'formats': [DATATYPES[s[1]] for s in spec],
            'offsets': offsets,
            'itemsize': offset,
        }
    )
    packed = np.empty(n, dtype=dtype)
    for name, column in columns.items():
        packed[name] = column
    data = packed.view(np.uint8).reshape(-1)
    fields = [
        field_cls(name=name, offset=off, datatype=datatype, count=1)
        for (name, datatype), off in zip(spec, offsets, strict=True)
    ]
    rosbags_style = hasattr(msg_cls, '__msgtype__')
    return msg_cls(
        header=header,
        height=1,
        width=n,
        fields=fields,
        is_bigendian=False,
        point_step=offset,
        row_step=offset * n,
        data=data.copy() if rosbags_style else data.tobytes(),
        is_dense=bool(np.isfinite(xyz).all()),
    )
