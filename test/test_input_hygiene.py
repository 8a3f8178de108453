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
Named regressions of issue 11's input failures, ROS-free, end to end.

Each goes the node's way: PointCloud2 (duck-typed stand-in) -> decoder -> sanitize_scan ->
label conversion -> Registration. The failures as the issue measured them:

- a single label 20 in a learning-id scan made ``auto`` read it as raw ids;
- an int32 raw label of -2**31 (instance bits set, class 0) was rejected;
- an optional field with count 0 (an unused intensity) made a usable cloud rejected;
- one point at 1e30 collapsed the voxel grid (32 voxels instead of 17,600).
"""

from __future__ import annotations

import dataclasses
import warnings

from mlsemreg_ros.codec.pointcloud2 import (
    arrays_to_pointcloud2,
    FLOAT32,
    pointcloud2_to_arrays,
)
from mlsemreg_ros.core.features import features
from mlsemreg_ros.core.features.scan_input import sanitize_scan_for
from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.metrics import rotation_error_deg, translation_error_m
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair
from msg_stubs import Cloud, Field
import numpy as np
import pytest

LABELS = LabelMap.load()


@pytest.fixture(scope='module')
def pair():
    """Return two labeled street scans with learning ids and trunk/pole/sign/car landmarks."""
    return synthetic_pair(0, max_points=8000)


@pytest.fixture(scope='module')
def registration() -> Registration:
    """Return a registration with the default (node) parameters."""
    return Registration()


def _decode(xyz: np.ndarray, labels: np.ndarray, **kw) -> tuple[np.ndarray, np.ndarray]:
    """Through a PointCloud2 and back, as the node receives a scan."""
    cloud = pointcloud2_to_arrays(arrays_to_pointcloud2(Cloud, Field, None, xyz, labels, **kw))
    return cloud.xyz, cloud.labels


def _assert_registered(result, trans_gt: np.ndarray) -> None:
    assert result.success and result.mode == 'ml-semreg', result.message
    assert rotation_error_deg(result.transform[:3, :3], trans_gt[:3, :3]) < 1.0
    assert translation_error_m(result.transform[:3, 3], trans_gt[:3, 3]) < 0.3


def test_issue11_one_label_of_20_keeps_the_learning_scheme(pair, registration) -> None:
    clean = registration.register_scans(pair.pts_src, pair.label_src, pair.pts_dst, pair.label_dst)
    src, dst = pair.label_src.copy(), pair.label_dst.copy()
    src[0] = dst[0] = 20  # before: both scans read as raw ids (road 9 -> 0, pole 18 -> truck)
    conversion = LABELS.convert(src)
    assert conversion.scheme == 'learning' and conversion.out_of_scheme == 1
    prepared = registration.prepare(*_decode(pair.pts_src, src))
    reference = registration.prepare(pair.pts_src, pair.label_src)
    assert np.mean(prepared.labels == reference.labels) > 0.999
    assert len(prepared.landmarks) == len(reference.landmarks)
    result = registration.register_scans(pair.pts_src, src, pair.pts_dst, dst)
    _assert_registered(result, pair.trans_gt)
    assert result.num_inliers >= 0.9 * clean.num_inliers


def test_issue11_int32_raw_label_minus_2_31_is_accepted(pair, registration) -> None:
    raw = LABELS.to_raw(pair.label_src, np.arange(len(pair.label_src)) % 50)
    raw[::100] = 0x80000000  # -2**31 as int32: instance 0x8000, class 0 (unlabeled)
    xyz, labels = _decode(pair.pts_src, raw.view(np.int32), label_datatype='int32')
    assert labels.min() == -(2**31)
    conversion = LABELS.convert(labels)
    assert conversion.scheme == 'raw' and conversion.out_of_scheme == 0
    expected = pair.label_src.copy()
    expected[::100] = 0
    np.testing.assert_array_equal(conversion.ids, expected)
    raw_dst = LABELS.to_raw(pair.label_dst).view(np.int32)
    result = registration.register_scans(
        xyz, labels, *_decode(pair.pts_dst, raw_dst, label_datatype='int32')
    )
    _assert_registered(result, pair.trans_gt)


def test_issue11_count_0_intensity_field_is_ignored(pair, registration) -> None:
    msg = arrays_to_pointcloud2(Cloud, Field, None, pair.pts_src, pair.label_src)
    msg = dataclasses.replace(msg, fields=[*msg.fields, Field('intensity', 0, FLOAT32, 0)])
    cloud = pointcloud2_to_arrays(msg)  # before: PointCloudError "count 0"
    assert cloud.ignored_fields == ('intensity',) and cloud.intensity is None
    assert len(cloud) == len(pair.pts_src)
    np.testing.assert_array_equal(cloud.labels, pair.label_src)
    result = registration.register_scans(cloud.xyz, cloud.labels, pair.pts_dst, pair.label_dst)
    _assert_registered(result, pair.trans_gt)


def test_issue11_point_at_1e30_keeps_the_voxel_grid(pair, registration) -> None:
    config = registration.config
    xyz = np.vstack([pair.pts_src, [[1e30, 1e30, 1e30]]])
    labels = np.append(pair.label_src, 9)
    xyz, labels = _decode(xyz, labels)  # float32 on the wire: 1e30 survives, not inf
    assert np.abs(xyz).max() == pytest.approx(1e30, rel=1e-6)
    scan = sanitize_scan_for(xyz, labels, config.features)
    assert (scan.dropped_far, scan.dropped_nonfinite, len(scan)) == (1, 0, len(pair.pts_src))
    clean_voxels, _ = features.voxel_downsample(
        pair.pts_src, pair.label_src, config.features.voxel_size
    )
    with warnings.catch_warnings():
        warnings.simplefilter('error')  # before: "invalid value encountered in cast"
        voxels, _ = features.voxel_downsample(scan.points, scan.labels, config.features.voxel_size)
    assert voxels.shape == clean_voxels.shape and voxels.shape[0] > 5000
    result = registration.register_scans(scan.points, scan.labels, pair.pts_dst, pair.label_dst)
    _assert_registered(result, pair.trans_gt)
