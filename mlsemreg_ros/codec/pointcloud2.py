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
as stored (int64); :meth:`mlsemreg_ros.core.matching.labels.LabelMap.convert` reads them as
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
    point_times: np.ndarray | None = None  # (N,) float64 s after the header stamp
    time_note: str = ''  # how the times were decoded, or why there are none
    time_warning: str = ''  # a time field is there but not used (why), '' otherwise

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
    msg: Any,
    label_field: str = 'label',
    require_labels: bool = True,
    time_field: str | None = '',
    time_unit: str = 'auto',
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

    Per-point times are decoded by :func:`decode_point_times` (``time_field`` '' detects
    the field, None skips the times) into :attr:`CloudArrays.point_times`; a time field that
    cannot be read gives no times and a :attr:`CloudArrays.time_note`, never an error.
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
        _check_fits(name, offset, dtype.itemsize, point_step)
        names.append(name)
        formats.append(dtype)
        offsets.append(offset)
    time_name = _time_field_name(fields, time_field) if time_field is not None else ''
    if time_name and _readable(fields[time_name]):  # a time field past the point: malformed
        size = DATATYPES[int(fields[time_name].datatype)].itemsize
        _check_fits(time_name, int(fields[time_name].offset), size, point_step)
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
    times, note = None, ''
    if time_field is not None:
        times, note = decode_point_times(msg, time_field, time_unit)
        if times is not None and keep is not None:
            times = times[keep]
    return CloudArrays(
        xyz if keep is None else xyz[keep],
        labels,
        intensity,
        dropped,
        tuple(ignored),
        times,
        note,
        note if times is None and not note.startswith(NO_TIME_FIELD) else '',
    )


def _check_fits(name: str, offset: int, size: int, point_step: int) -> None:
    """Raise PointCloudError if a field of ``size`` bytes at ``offset`` overruns the point."""
    if offset < 0 or offset + size > point_step:
        raise PointCloudError(
            f'field {name!r} (offset {offset}, {size} bytes) does not fit in '
            f'point_step {point_step}'
        )


def _time_field_name(fields: dict[str, Any], time_field: str) -> str:
    """Return the time field :func:`decode_point_times` reads ('' if none)."""
    if time_field:
        return time_field if time_field in fields else ''
    return next((n for n in TIME_FIELDS if n in fields), '')


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


#: Per-point time fields, in the order auto-detection tries them: Velodyne ``time`` (float
#: s after the stamp, or before the sweep end: negative), Ouster ``t`` (uint32 ns),
#: Hesai/RoboSense ``timestamp`` (float64 absolute s), Livox ``time_stamp``/``offset_time``
#: (ns). ``docs/field.md`` lists the conventions.
TIME_FIELDS = ('time', 't', 'timestamp', 'time_stamp', 'offset_time')
#: Seconds per unit of a time field.
TIME_UNITS: dict[str, float] = {'s': 1.0, 'ms': 1e-3, 'us': 1e-6, 'ns': 1e-9}
#: Times within this many seconds of the header stamp (and nearer to it than to 0) are absolute.
ABSOLUTE_TOLERANCE_S = 10.0
#: A relative time field whose span in its default unit lies in this range (s) keeps it.
PLAUSIBLE_SPAN_S = (1e-3, 1.0)
#: Auto-detected units aim at a sweep of about this span (s).
TYPICAL_SPAN_S = 0.1
#: Times further than this (s) from the header stamp, after the unit detection, are not a
#: sweep stamped at its start or end: the cloud is registered without deskew.
MAX_STAMP_OFFSET_S = 1.0
#: The note of a cloud without any time field (no warning).
NO_TIME_FIELD = 'no per-point time field'


def decode_point_times(
    msg: Any, time_field: str = '', time_unit: str = 'auto'
) -> tuple[np.ndarray | None, str]:
    """
    Return the per-point times (N,) float64, seconds after the header stamp, and a note.

    ``time_field`` '' tries :data:`TIME_FIELDS` in order; ``time_unit`` 'auto' takes the
    unit from the values (:func:`_time_unit`). Absolute times (near the stamp) have the
    stamp subtracted; relative ones are kept as they are, negative ones too (Velodyne
    drivers that count back from the sweep end). No usable field gives ``(None, why)``
    (never an error: a cloud without times is registered without deskew).
    """
    from mlsemreg_ros.codec.stamps import stamp_to_ns

    if time_unit != 'auto' and time_unit not in TIME_UNITS:
        return None, f'unknown time unit {time_unit!r} (auto, {", ".join(TIME_UNITS)})'
    fields = {str(f.name): f for f in msg.fields if int(f.count) != 0}
    if time_field:
        if time_field not in fields:
            return None, f'time field {time_field!r} not in the cloud (fields: {list(fields)})'
        name = time_field
    else:
        name = _time_field_name(fields, '')
        if not name:
            return None, NO_TIME_FIELD + ' (' + ', '.join(TIME_FIELDS) + ')'
    field_ = fields[name]
    if not _readable(field_):
        return None, (
            f'time field {name!r} is unreadable (count {field_.count}, datatype {field_.datatype})'
        )
    dtype, offset = DATATYPES[int(field_.datatype)], int(field_.offset)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    height, width = int(msg.height), int(msg.width)
    buffer = _buffer(msg.data)
    if offset < 0 or offset + dtype.itemsize > point_step or buffer.size != height * row_step:
        return None, f'time field {name!r} does not fit the cloud layout'
    view = np.ndarray(
        (height, width),
        dtype=np.dtype(
            {'names': [name], 'formats': [dtype], 'offsets': [offset], 'itemsize': point_step}
        ),
        buffer=buffer,
        strides=(row_step, point_step),
    ).reshape(-1)[name]
    values = view.astype(np.float64)
    if not np.all(np.isfinite(values)):
        return None, f'time field {name!r} holds NaN/inf values'
    stamp = getattr(getattr(msg, 'header', None), 'stamp', None)
    stamp_ns = stamp_to_ns(stamp) if stamp is not None else 0
    units = TIME_UNITS if time_unit == 'auto' else {time_unit: TIME_UNITS[time_unit]}
    absolute = _absolute_unit(values, stamp_ns, units)
    if absolute:
        scale = TIME_UNITS[absolute]
        if view.dtype.kind in 'iu':  # exact integer arithmetic before the scaling
            stamp_units = round(stamp_ns * 1e-9 / scale)
            times = (view.astype(np.int64) - stamp_units).astype(np.float64) * scale
        else:
            times = values - stamp_ns * 1e-9 / scale
            times *= scale
        return _plausible(times, f'{name!r}: absolute {absolute}, stamp subtracted')
    unit = time_unit if time_unit != 'auto' else _time_unit(values, view.dtype.kind)
    return _plausible(values * TIME_UNITS[unit], f'{name!r}: {unit} after the stamp')


def _plausible(times: np.ndarray, note: str) -> tuple[np.ndarray | None, str]:
    """
    Return the decoded times and their note, or None and why they are not one sweep.

    After the unit detection, a span above the plausible maximum (:data:`PLAUSIBLE_SPAN_S`)
    or times further than :data:`MAX_STAMP_OFFSET_S` from the header stamp (an absolute
    field far from the stamp, a wrong unit) are not used: the cloud is registered without
    deskew, and the node warns in ``/diagnostics``.
    """
    if not np.all(np.isfinite(times)):  # finite values may overflow in the unit's scaling
        return None, f'{note}: times not finite, not used for deskew'
    if times.size == 0:
        return times, note
    span = float(times.max() - times.min())
    if span > PLAUSIBLE_SPAN_S[1]:
        high = PLAUSIBLE_SPAN_S[1]
        return None, f'{note}: span {span:.3g} s (> {high:g} s), not used for deskew'
    offset = float(np.max(np.abs(times)))
    if offset > MAX_STAMP_OFFSET_S:
        return None, (
            f'{note}: up to {offset:.3g} s from the header stamp (> {MAX_STAMP_OFFSET_S:g} s), '
            'not used for deskew'
        )
    return times, note


def _absolute_unit(values: np.ndarray, stamp_ns: int, units: dict[str, float]) -> str:
    """Return the unit in which ``values`` are absolute times near the stamp ('' if none)."""
    if not stamp_ns or values.size == 0:
        return ''
    stamp_s, median = stamp_ns * 1e-9, float(np.median(values))
    for unit, scale in units.items():
        seconds = median * scale
        gap = abs(seconds - stamp_s)
        if gap < ABSOLUTE_TOLERANCE_S and gap < abs(seconds):
            return unit
    return ''


def _time_unit(values: np.ndarray, kind: str) -> str:
    """
    Return the unit of relative times: the datatype's default if its span is plausible.

    Floats default to seconds and integers to nanoseconds; when that span lies outside
    :data:`PLAUSIBLE_SPAN_S`, the unit whose span is nearest :data:`TYPICAL_SPAN_S` (on a
    log scale) among those not longer than the plausible maximum is taken.
    """
    default = 's' if kind == 'f' else 'ns'
    span = float(values.max() - values.min()) if values.size else 0.0
    if span == 0.0:
        return default
    low, high = PLAUSIBLE_SPAN_S
    if low <= span * TIME_UNITS[default] <= high:
        return default
    candidates = [u for u, scale in TIME_UNITS.items() if span * scale <= high] or ['ns']
    return min(candidates, key=lambda u: abs(np.log10(span * TIME_UNITS[u] / TYPICAL_SPAN_S)))
