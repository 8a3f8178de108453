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
Property-based fuzzing of the input path (issue 11): PointCloud2 -> labels -> scan -> odometry.

Hypothesis, derandomized (the same examples on every run, so CI is reproducible) and
without an example database. ``MLSEMREG_FUZZ_SCALE=10`` runs ten times as many examples
(still derandomized); the default keeps the file at a few seconds on two cores.

Properties: the decoder either raises :class:`PointCloudError` or returns arrays of the
right shapes and dtypes, and on well-formed clouds exactly the values an independent
per-point reader finds; :meth:`LabelMap.convert` equals a per-value reference of the
documented rules or raises :class:`LabelError`; ``Odometry.process`` and
``Registration.prepare`` raise nothing but :class:`LabelError` on finite scans of any
size (0, 1, 3 points, identical points, ...) and on any scan after :func:`sanitize_scan`.
"""

from __future__ import annotations

import array
from dataclasses import dataclass, replace
import os
from typing import Any

from hypothesis import event, example, given, HealthCheck, Phase, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from mlsemreg_ros.codec.pointcloud2 import (
    CloudArrays,
    DATATYPES,
    pointcloud2_to_arrays,
    PointCloudError,
)
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.features.scan_input import sanitize_scan
from mlsemreg_ros.core.matching.labels import LabelConversion, LabelError, LabelMap, SCHEMES
from mlsemreg_ros.core.odometry import Odometry, OdometryStep
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.results import PreparedScan
from mlsemreg_ros.datasets.synthetic_scene import motion, scan_at, street_scene
from msg_stubs import Cloud, Field
import numpy as np
import pytest

LABELS = LabelMap.load()
SCALE = max(1, int(os.environ.get('MLSEMREG_FUZZ_SCALE', '1')))


def fuzz_settings(max_examples: int, deadline_ms: int, **kwargs: Any) -> settings:
    """Derandomized, database-free settings (the same examples on every machine)."""
    return settings(
        max_examples=max_examples * SCALE,
        deadline=deadline_ms,
        derandomize=True,
        database=None,
        print_blob=True,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
        **kwargs,
    )


def _containers(data: bytes) -> st.SearchStrategy:
    """Wrap ``data`` as rclpy (bytes, array), rosbags (uint8 array) or other containers."""
    return st.sampled_from(
        [
            data,
            bytearray(data),
            np.frombuffer(data, np.uint8).copy(),
            list(data),
            array.array('B', data),
            memoryview(data),
        ]
    )


def _check_cloud(out: CloudArrays, msg: Cloud) -> None:
    """Shapes and dtypes of a successful decode."""
    n = len(out)
    assert n >= 1 and out.xyz.shape == (n, 3) and out.xyz.dtype == np.float64
    assert np.isfinite(out.xyz).all()
    assert out.dropped_nonfinite >= 0
    assert n + out.dropped_nonfinite == int(msg.height) * int(msg.width)
    assert out.labels is None or (out.labels.shape == (n,) and out.labels.dtype == np.int64)
    assert out.intensity is None or (
        out.intensity.shape == (n,) and out.intensity.dtype == np.float32
    )
    assert isinstance(out.ignored_fields, tuple)
    assert all(isinstance(name, str) for name in out.ignored_fields)


def _check_conversion(out: LabelConversion, n: int) -> None:
    """Shapes, dtypes and ranges of a label conversion."""
    assert out.ids.shape == (n,) and out.ids.dtype == np.int32
    assert n == 0 or (out.ids.min() >= 0 and out.ids.max() < LABELS.num_classes)
    assert out.scheme in ('learning', 'raw') and out.requested in SCHEMES
    assert 0 <= out.out_of_scheme <= n
    assert 0.0 <= out.raw_share <= 1.0 and 0.0 <= out.learning_share <= 1.0


# -- PointCloud2: well-formed clouds of random layout and content ------------------------
@dataclass
class Spec:
    """One field of a generated cloud and the values written into it (None: filler)."""

    name: str
    datatype: int
    count: int
    offset: int = 0
    values: np.ndarray | None = None


def _coordinate_values(dtype: np.dtype, n: int) -> st.SearchStrategy:
    if dtype.kind == 'f':  # any float, NaN, inf and huge included
        return hnp.arrays(dtype, n, elements=hnp.from_dtype(dtype))
    return hnp.arrays(dtype, n)


def _label_values(dtype: np.dtype, n: int) -> st.SearchStrategy:
    if dtype.kind != 'f':
        ids = [v for v in (0, 1, 9, 13, 19, 20, 40, 70, 252, 300, -1) if _fits(v, dtype)]
        return hnp.arrays(
            dtype, n, elements=st.one_of(st.sampled_from(ids), hnp.from_dtype(dtype))
        )
    # Mostly integral floats (valid labels), sometimes anything (NaN, 0.5, 1e30, ...).
    integral = st.integers(-(2**31), 2**32).map(float).filter(lambda v: float(dtype.type(v)) == v)
    anything = hnp.from_dtype(dtype)
    return hnp.arrays(dtype, n, elements=st.one_of(integral, integral, integral, anything))


@st.composite
def well_formed_clouds(draw: st.DrawFn) -> tuple[Cloud, list[Spec], str, bool]:
    """Draw a valid little-endian cloud of random layout, padding and content, and its specs."""
    height, width = draw(st.integers(1, 3)), draw(st.integers(1, 6))
    n = height * width
    types = st.sampled_from(sorted(DATATYPES))
    label_field = draw(st.sampled_from(['label', 'class']))
    specs = [Spec(name, draw(types), 1) for name in ('x', 'y', 'z')]
    has_label, require_labels = draw(st.booleans()), draw(st.booleans())
    if has_label:
        specs.append(Spec(label_field, draw(types), 1))
    if draw(st.booleans()):  # intensity: readable, count 0, or unreadable (count 2 / type 9)
        specs.append(
            Spec(
                'intensity',
                draw(st.sampled_from([*sorted(DATATYPES), 9])),
                draw(st.sampled_from([1, 1, 0, 2])),
            )
        )
    for name in draw(
        st.lists(st.sampled_from(['ring', 'time', 'rgb', 'x', 'label']), max_size=2, unique=True)
    ):
        # Unused extras, count 0 for the names of required fields.
        count = 0 if name in ('x', 'label') else draw(st.integers(0, 3))
        specs.append(Spec(name, draw(st.integers(0, 10)), count))
    specs = draw(st.permutations(specs))
    offset = 0
    for spec in specs:  # pack with random gaps; count-0 fields may point anywhere
        size = (
            DATATYPES[spec.datatype].itemsize * spec.count
            if spec.datatype in DATATYPES
            else 4 * spec.count
        )
        if spec.count == 0:
            spec.offset = draw(st.integers(0, 64))
            continue
        spec.offset = offset + draw(st.integers(0, 3))
        offset = spec.offset + size
    point_step = offset + draw(st.integers(0, 4))
    row_step = width * point_step + draw(st.integers(0, 7))
    buffer = bytearray(draw(st.binary(min_size=height * row_step, max_size=height * row_step)))
    for spec in specs:
        if spec.count != 1 or spec.datatype not in DATATYPES:
            continue
        if spec.name in ('intensity', 'ring', 'time', 'rgb'):
            spec.values = draw(_coordinate_values(DATATYPES[spec.datatype], n))
        elif spec.name in ('x', 'y', 'z'):
            spec.values = draw(_coordinate_values(DATATYPES[spec.datatype], n))
        else:
            spec.values = draw(_label_values(DATATYPES[spec.datatype], n))
        raw = spec.values.astype(DATATYPES[spec.datatype]).tobytes()
        size = DATATYPES[spec.datatype].itemsize
        for i in range(n):  # the reference writer: one point at a time
            start = (i // width) * row_step + (i % width) * point_step + spec.offset
            buffer[slice(start, start + size)] = raw[slice(i * size, (i + 1) * size)]
    msg = Cloud(
        height=height,
        width=width,
        point_step=point_step,
        row_step=row_step,
        fields=[Field(s.name, s.offset, s.datatype, s.count) for s in specs],
        data=draw(_containers(bytes(buffer))),
    )
    return msg, specs, label_field, require_labels


def _expected_error(specs: list[Spec], label_field: str, require_labels: bool) -> str | None:
    """Return why a well-formed cloud must be rejected for its content, or None."""
    by_name = {s.name: s for s in specs if s.count != 0}
    if label_field not in by_name and require_labels:
        return 'missing label field'
    xyz = np.stack([by_name[c].values.astype(np.float64) for c in 'xyz'], axis=1)
    finite = np.isfinite(xyz).all(axis=1)
    if not finite.any():
        return 'have NaN/inf coordinates'
    label = by_name.get(label_field)
    if label is not None and label.values.dtype.kind == 'f':
        kept = label.values[finite].astype(np.float64)
        if not np.isfinite(kept).all():
            return 'holds NaN/inf values'
        if np.any(kept != np.round(kept)):
            return 'non-integral'
        if np.any(np.abs(kept) > 2.0**53):
            return 'beyond 2'
    return None


@fuzz_settings(300, 1000)
@given(well_formed_clouds())
def test_decoder_reads_well_formed_clouds_exactly(case: tuple) -> None:
    msg, specs, label_field, require_labels = case
    reason = _expected_error(specs, label_field, require_labels)
    if reason is not None:
        with pytest.raises(PointCloudError, match=reason):
            pointcloud2_to_arrays(msg, label_field, require_labels)
        return
    out = pointcloud2_to_arrays(msg, label_field, require_labels)
    _check_cloud(out, msg)
    by_name = {s.name: s for s in specs if s.count != 0}
    xyz = np.stack([by_name[c].values.astype(np.float64) for c in 'xyz'], axis=1)
    finite = np.isfinite(xyz).all(axis=1)
    np.testing.assert_array_equal(out.xyz, xyz[finite])
    assert out.dropped_nonfinite == int(np.count_nonzero(~finite))
    if label_field in by_name:
        np.testing.assert_array_equal(out.labels, by_name[label_field].values[finite])
    else:
        assert out.labels is None
    intensity = by_name.get('intensity')
    if intensity is not None and intensity.values is not None:
        with np.errstate(over='ignore'):  # float64 beyond float32: inf, as the decoder
            expected = intensity.values[finite].astype(np.float32)
        np.testing.assert_array_equal(out.intensity, expected)
    else:
        assert out.intensity is None
    ignored = {s.name for s in specs if s.count == 0}
    if intensity is not None and intensity.values is None:
        ignored.add('intensity')
    assert set(out.ignored_fields) == ignored
    if out.labels is not None:  # the decoded labels go on to the label conversion
        try:
            conversion = LABELS.convert(out.labels)
        except LabelError as error:
            assert 'are not, more than' in str(error)
        else:
            _check_conversion(conversion, len(out))


# -- PointCloud2: broken clouds -------------------------------------------------------------
def _mutations(msg: Cloud) -> st.SearchStrategy:
    """One structural defect (or a harmless change) of a well-formed message."""
    data = bytes(msg.data)  # bytes, bytearray, memoryview, array, uint8 array or list
    small = st.integers(-8, 8)
    field_index = st.integers(0, len(msg.fields) - 1)

    def change_field(i: int, **changes: Any) -> Cloud:
        fields = list(msg.fields)
        fields[i] = replace(fields[i], **changes)
        return replace(msg, fields=fields)

    return st.one_of(
        st.builds(lambda d: replace(msg, point_step=msg.point_step + d), small),
        st.builds(lambda d: replace(msg, row_step=msg.row_step + d), small),
        st.builds(lambda h: replace(msg, height=h), st.integers(-2, 5)),
        st.builds(lambda w: replace(msg, width=w), st.integers(-2, 8)),
        st.builds(lambda k: replace(msg, data=data[: max(0, len(data) - k)]), st.integers(1, 9)),
        st.builds(lambda b: replace(msg, data=data + b), st.binary(min_size=1, max_size=9)),
        st.just(replace(msg, is_bigendian=True)),
        st.builds(lambda i, t: change_field(i, datatype=t), field_index, st.integers(-1, 12)),
        st.builds(lambda i, c: change_field(i, count=c), field_index, st.integers(-1, 4)),
        st.builds(lambda i, o: change_field(i, offset=o), field_index, st.integers(-4, 80)),
        st.builds(
            lambda i: replace(msg, fields=[f for j, f in enumerate(msg.fields) if j != i]),
            field_index,
        ),
        st.builds(lambda i: replace(msg, fields=[*msg.fields, msg.fields[i]]), field_index),
        st.builds(lambda n: change_field(0, name=n), st.text(max_size=3)),
    )


@fuzz_settings(300, 1000)
@given(st.data())
def test_decoder_rejects_broken_clouds_cleanly(data: st.DataObject) -> None:
    msg, _, label_field, require_labels = data.draw(well_formed_clouds())
    for _ in range(data.draw(st.integers(1, 3))):
        msg = data.draw(_mutations(msg))
    try:
        out = pointcloud2_to_arrays(msg, label_field, require_labels)
    except PointCloudError:
        return
    _check_cloud(out, msg)


_FIELD_NAMES = st.one_of(
    st.sampled_from(['x', 'y', 'z', 'label', 'intensity', 'ring']), st.text(max_size=4)
)


@fuzz_settings(300, 1000)
@given(
    fields=st.lists(
        st.builds(
            Field, _FIELD_NAMES, st.integers(-4, 64), st.integers(-1, 12), st.integers(-1, 4)
        ),
        max_size=7,
    ),
    height=st.integers(-2, 4),
    width=st.integers(-2, 6),
    point_step=st.integers(-4, 48),
    row_step=st.integers(-4, 300),
    payload=st.binary(max_size=1200),
    exact=st.booleans(),
    bigendian=st.booleans(),
    require_labels=st.booleans(),
)
@example(
    fields=[
        Field('x', 0, 7),
        Field('y', 4, 7),
        Field('z', 8, 7),
        Field('label', 12, 6),
        Field('intensity', 16, 7, 0),
    ],
    height=1,
    width=2,
    point_step=16,
    row_step=32,
    payload=b'\0' * 32,
    exact=True,
    bigendian=False,
    require_labels=True,
)
def test_decoder_survives_random_messages(
    fields: list[Field],
    height: int,
    width: int,
    point_step: int,
    row_step: int,
    payload: bytes,
    exact: bool,
    bigendian: bool,
    require_labels: bool,
) -> None:
    if exact and height > 0 and row_step > 0:  # the size check passes: reach the layout
        payload = (
            payload * (height * row_step // max(len(payload), 1) + 1)
            if payload
            else bytes(height * row_step)
        )[: height * row_step]
    msg = Cloud(
        height=height,
        width=width,
        fields=fields,
        is_bigendian=bigendian,
        point_step=point_step,
        row_step=row_step,
        data=payload,
    )
    try:
        out = pointcloud2_to_arrays(msg, 'label', require_labels)
    except PointCloudError:
        return
    _check_cloud(out, msg)


# -- labels: every dtype against a per-value reference of the documented rules ----------
_LABEL_DTYPES = [
    np.dtype(t)
    for t in (
        np.bool_,
        np.int8,
        np.int16,
        np.int32,
        np.int64,
        np.uint8,
        np.uint16,
        np.uint32,
        np.uint64,
        np.float16,
        np.float32,
        np.float64,
    )
]
_INTERESTING = (
    0,
    1,
    9,
    13,
    19,
    20,
    40,
    50,
    70,
    81,
    252,
    259,
    260,
    1234,
    65535,
    40 | (7 << 16),
    252 | (0xFFFF << 16),
    2**31,
    2**32 - 1,
    2**32,
    2**32 + 40,
    -1,
    -(2**31),
    -(2**31) - 1,
)
_KNOWN_RAW = set(np.flatnonzero(LABELS.raw_known).tolist())


@st.composite
def label_arrays(draw: st.DrawFn) -> np.ndarray:
    """Labels of any dtype: ids of both schemes, instance bits, extremes, NaN, fractions."""
    dtype = draw(st.sampled_from(_LABEL_DTYPES))
    if dtype.kind == 'b':
        elements = st.booleans()
    else:
        fitting = [v for v in _INTERESTING if _fits(v, dtype)]
        elements = st.one_of(st.sampled_from(fitting), st.integers(0, 19), hnp.from_dtype(dtype))
    shape = draw(st.one_of(st.integers(0, 40), st.tuples(st.integers(0, 8), st.just(1))))
    return draw(hnp.arrays(dtype, shape, elements=elements))


def _fits(value: int, dtype: np.dtype) -> bool:
    if dtype.kind == 'f':
        with np.errstate(over='ignore'):
            return float(dtype.type(value)) == value
    info = np.iinfo(dtype)
    return info.min <= value <= info.max


def _reference(labels: np.ndarray, scheme: str, limit: float) -> tuple[list[int], str, int]:
    """Per-value reading of the rules in the labels module docstring (or raise)."""
    if scheme not in SCHEMES:
        raise LabelError('unknown label scheme')
    values = labels.reshape(-1).tolist()
    if labels.dtype.kind == 'f':
        if not all(np.isfinite(values)):
            raise LabelError('labels contain NaN or inf')
        if any(v != round(v) for v in values):
            raise LabelError('float labels must hold integral values')
    ints = [int(v) for v in values]
    fits = [-(2**31) <= v < 2**32 for v in ints]
    patterns = [v % 2**32 if ok else 0 for v, ok in zip(ints, fits, strict=True)]
    learning = [ok and p < LABELS.num_classes for p, ok in zip(patterns, fits, strict=True)]
    raw = [ok and (p & 0xFFFF) in _KNOWN_RAW for p, ok in zip(patterns, fits, strict=True)]
    informative = [p != 0 for p in patterns]
    count = sum(informative)
    raw_share = sum(r and i for r, i in zip(raw, informative, strict=True)) / max(count, 1)
    learning_share = sum(a and i for a, i in zip(learning, informative, strict=True)) / max(
        count, 1
    )
    used = scheme
    if scheme == 'auto':
        used = 'raw' if raw_share - learning_share >= 0.25 else 'learning'
    valid = raw if used == 'raw' else learning
    ids = [
        (int(LABELS.raw_lut[p & 0xFFFF]) if used == 'raw' else p) if ok else 0
        for p, ok in zip(patterns, valid, strict=True)
    ]
    out = valid.count(False)
    if out > limit * len(values):
        raise LabelError('are not, more than')
    return ids, used, out


@fuzz_settings(400, 1000)
@given(
    labels=label_arrays(),
    scheme=st.sampled_from([*SCHEMES, 'kitti']),
    limit=st.sampled_from([0.5, 0.5, 0.0, 1.0]),
)
def test_label_conversion_matches_the_reference(
    labels: np.ndarray, scheme: str, limit: float
) -> None:
    try:
        expected = _reference(labels, scheme, limit)
    except LabelError as error:
        with pytest.raises(LabelError, match=str(error).split(':')[0]):
            LABELS.convert(labels, scheme, max_out_of_scheme=limit)
        return
    out = LABELS.convert(labels, scheme, max_out_of_scheme=limit)
    _check_conversion(out, labels.size)
    assert (out.ids.tolist(), out.scheme, out.out_of_scheme) == expected
    assert out.requested == scheme
    if limit == 0.5:  # the default limit: to_learning is convert().ids
        np.testing.assert_array_equal(LABELS.to_learning(labels, scheme), out.ids)


@fuzz_settings(200, 1000)
@given(
    learning=hnp.arrays(np.int64, st.integers(1, 200), elements=st.integers(0, 19)),
    instance=st.integers(0, 0xFFFF),
    stray=st.integers(20, 2**32 - 1),
)
def test_raw_and_learning_readings_agree(learning: np.ndarray, instance: int, stray: int) -> None:
    raw = LABELS.to_raw(learning, np.full(learning.shape, instance))
    for dtype in (np.uint32, np.int32, np.int64, np.float64):
        np.testing.assert_array_equal(
            LABELS.to_learning(
                raw.astype(np.uint32).view(np.int32).astype(dtype)
                if dtype in (np.int32, np.int64)
                else raw.astype(dtype),
                'raw',
            ),
            learning,
        )
    # One stray value never changes the reading of the rest of a learning scan.
    corrupted = np.append(learning, stray)
    out = LABELS.convert(corrupted, 'learning', max_out_of_scheme=1.0)
    np.testing.assert_array_equal(out.ids[:-1], learning)
    assert out.ids[-1] == 0 and out.out_of_scheme == 1


# -- scans through the core ---------------------------------------------------------------
_HOSTILE = (np.nan, np.inf, -np.inf, 1e30, -1e30, 1e300, 1e19)


_WORLD = street_scene(0)  # (points, learning ids) of a labeled street, ~42k points


@st.composite
def scans(draw: st.DrawFn, hostile: bool) -> tuple[np.ndarray, np.ndarray]:
    """
    Draw a scan (points (N, 3), labels (N,)) for the core.

    A street seen from a random nearby pose, or 0-2000 random, identical, collinear,
    planar or clustered points; labels in either scheme, corrupted or garbage, of several
    dtypes; optionally poisoned with NaN/inf/huge coordinates.
    """
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    shape = draw(
        st.sampled_from(['street', 'uniform', 'identical', 'line', 'plane', 'cluster', 'street'])
    )
    n = draw(st.one_of(st.sampled_from([0, 1, 2, 3, 4]), st.sampled_from([12, 60, 400, 2000])))
    scale = draw(st.sampled_from([1e-3, 1.0, 30.0, 1e4]))
    learning = rng.integers(0, 20, n)
    if shape == 'street':
        pose = motion(
            draw(st.floats(-10.0, 10.0)),
            (draw(st.floats(-3.0, 3.0)), draw(st.floats(-3.0, 3.0)), 0.0),
        )
        points, learning = scan_at(*_WORLD, pose, int(rng.integers(2**31)), max_points=n)
        n = len(points)
    elif shape == 'identical':
        points = np.tile(rng.uniform(-1, 1, 3) * scale, (n, 1))
    elif shape == 'line':
        points = np.outer(rng.uniform(-1, 1, n), rng.normal(size=3)) * scale
    elif shape == 'plane':
        points = np.c_[rng.uniform(-1, 1, (n, 2)) * scale, np.zeros(n)]
    elif shape == 'cluster':
        points = rng.normal(size=(n, 3)) * 0.05 + rng.uniform(-1, 1, 3) * scale
    else:
        points = rng.uniform(-1, 1, (n, 3)) * scale
    if hostile and n:
        for _ in range(draw(st.integers(1, 3))):
            points[rng.integers(n), rng.integers(3)] = draw(st.sampled_from(_HOSTILE))
    kind = draw(
        st.sampled_from(['learning', 'raw', 'corrupted', 'constant', 'landmarks', 'garbage'])
    )
    event(f'{shape} scan, {kind} labels')
    if kind == 'raw':
        labels = LABELS.to_raw(learning, rng.integers(0, 99, n)).astype(np.int64)
    elif kind == 'corrupted':  # a share of values outside 0-19 (raw ids and junk)
        labels = np.where(
            rng.random(n) < draw(st.sampled_from([0.001, 0.1, 0.4, 0.6])),
            rng.choice([20, 40, 300, 2**31], n),
            learning,
        )
    elif kind == 'constant':
        labels = np.full(n, draw(st.sampled_from([0, 9, 16, 40])))
    elif kind == 'landmarks':
        labels = rng.choice([16, 18, 19], n)
    elif kind == 'garbage':
        labels = rng.integers(0, 2**32, n, dtype=np.int64)
    else:
        labels = learning.astype(np.int64)
    dtype = draw(st.sampled_from([np.int64, np.uint32, np.int32, np.float64]))
    if dtype == np.int32:  # raw ids as a signed field: the uint32 bit pattern
        return points, labels.astype(np.uint32).view(np.int32)
    return points, labels.astype(dtype)


_REGISTRATION = Registration()
_SMALL = Registration(
    RegistrationConfig().replace(
        {'features.voxel_size': 0.0, 'keypoints.count': 10, 'keypoints.sampling': 'voxel'}
    )
)


def _check_prepared(scan: PreparedScan) -> None:
    v, m = scan.points.shape[0], scan.keypoints.shape[0]
    assert scan.points.shape == (v, 3) and scan.points.dtype == np.float64
    assert scan.labels.shape == (v,) and scan.labels.dtype == np.int32
    assert scan.keypoints.shape == (m, 3) and scan.keypoint_indices.shape == (m,)
    assert scan.descriptors.shape[0] == m and scan.descriptors.dtype == np.float32
    assert np.isfinite(scan.descriptors).all()
    assert scan.local_ss.shape == (m, LABELS.num_classes)
    assert scan.landmarks.centroids.shape == (len(scan.landmarks), 3)


def _check_step(step: OdometryStep) -> None:
    assert isinstance(step, OdometryStep)
    assert step.pose.shape == (4, 4) and np.isfinite(step.pose).all()
    assert isinstance(step.accepted, bool) and isinstance(step.new_keyframe, bool)
    if step.prepared is not None:
        _check_prepared(step.prepared)
    if step.new_keyframe:  # a degenerate scan never becomes the keyframe
        keyframe = RegistrationConfig().keyframe
        assert len(step.prepared.points) >= keyframe.min_points
    if step.result is None and step.source == 'prediction':  # tracked: no global registration
        assert step.accepted and step.relative is not None and np.isfinite(step.relative).all()
        return
    if step.result is None:  # the first scan, or a scan that could not start the odometry
        assert step.relative is None and step.accepted == (step.source == 'first')
        assert step.accepted or step.reason
        return
    result = step.result
    k = len(result.correspondences)
    assert result.transform.shape == (4, 4)
    assert result.source_points.shape == (k, 3) and result.target_points.shape == (k, 3)
    assert result.inlier_mask.shape == (k,) and result.inlier_mask.dtype == bool
    assert result.mode in ('ml-semreg', 'gm-only', 'plain')
    if step.accepted:
        assert np.isfinite(result.transform).all()


def _odometry_run(stream: list[tuple], sanitize: bool) -> None:
    """Run scans through a fresh Odometry (the node's core); only LabelError may escape."""
    odometry = Odometry(_REGISTRATION)
    for stamp_ns, (points, labels) in enumerate(stream):
        if sanitize:
            clean = sanitize_scan(points, labels)
            points, labels = clean.points, clean.labels
        event(f'scan of {len(points)} points')
        try:
            step = odometry.process(points, labels, stamp_ns)
        except LabelError:
            event('LabelError')
            continue
        event(
            'first scan'
            if step.result is None
            else f'registered: {step.result.mode}, accepted {step.accepted}'
        )
        _check_step(step)


@fuzz_settings(50, 10000)
@given(stream=st.lists(scans(hostile=False), min_size=2, max_size=4))
@example(
    stream=[(np.zeros((0, 3)), np.zeros(0, np.int64)), (np.ones((3, 3)), np.array([9, 9, 9]))]
)
@example(
    stream=[
        (np.ones((1, 3)), np.array([16])),
        (np.zeros((0, 3)), np.zeros(0)),
        (np.ones((50, 3)), np.full(50, 16)),
    ]
)
def test_odometry_survives_degenerate_finite_scans(stream: list[tuple]) -> None:
    _odometry_run(stream, sanitize=False)


@fuzz_settings(50, 10000)
@given(stream=st.lists(scans(hostile=True), min_size=2, max_size=4))
@example(
    stream=[
        (np.array([[1e30, 1e30, 1e30], [1.0, 2.0, 3.0]]), np.array([9, 13])),
        (np.array([[np.nan, 0.0, 0.0]] * 3), np.array([9, 9, 9])),
    ]
)
def test_odometry_survives_hostile_scans_after_sanitize_scan(stream: list[tuple]) -> None:
    _odometry_run(stream, sanitize=True)


@fuzz_settings(40, 5000, phases=[Phase.explicit, Phase.generate])
@given(scan=scans(hostile=True))
@example(
    scan=(
        np.vstack([np.random.default_rng(0).uniform(-20, 20, (500, 3)), [[np.nan, 0.0, 0.0]]]),
        np.arange(501) % 20,
    )
)
def test_prepare_survives_unsanitized_hostile_scans(scan: tuple) -> None:
    points, labels = scan
    try:
        prepared = _REGISTRATION.prepare(points, labels)
    except LabelError:
        return
    _check_prepared(prepared)


@fuzz_settings(60, 5000)
@given(scan=scans(hostile=True), small=st.booleans())
def test_prepare_survives_sanitized_scans(scan: tuple, small: bool) -> None:
    clean = sanitize_scan(*scan)
    registration = _SMALL if small else _REGISTRATION
    try:
        prepared = registration.prepare(clean.points, clean.labels)
    except LabelError:
        return
    _check_prepared(prepared)
    assert prepared.points.shape[0] <= len(clean)
