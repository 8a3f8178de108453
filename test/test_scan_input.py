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

"""Coordinate hygiene: non-finite and out-of-range points dropped and counted."""

from __future__ import annotations

import warnings

from mlsemreg_ros.core.config import ConfigError, field_of, RegistrationConfig
from mlsemreg_ros.core.features import features
from mlsemreg_ros.core.features.scan_input import (
    MAX_RANGE_LIMIT_M,
    sanitize_scan,
    sanitize_scan_for,
    SanitizedScan,
)
import numpy as np
import pytest


def _scan(n: int = 2000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.uniform(-40.0, 40.0, size=(n, 3)), rng.integers(0, 20, size=n)


def test_clean_scan_passes_unchanged() -> None:
    points, labels = _scan()
    out = sanitize_scan(points, labels)
    assert isinstance(out, SanitizedScan) and len(out) == 2000 and out.dropped == 0
    np.testing.assert_array_equal(out.points, points)
    np.testing.assert_array_equal(out.labels, labels)
    assert out.keep.dtype == bool and out.keep.all()


def test_each_kind_is_dropped_and_counted() -> None:
    points, labels = _scan(10)
    points[0] = [np.nan, 0.0, 0.0]
    points[1] = [0.0, np.inf, 0.0]
    points[2] = [-np.inf, np.nan, 1.0]
    points[3] = [1e30, 0.0, 0.0]
    points[4] = [1e300, 1e300, 1e300]  # its squared norm overflows to inf: far, no warning
    points[5] = [150.0, 150.0, 0.0]  # 212 m
    points[6] = [0.1, 0.1, 0.0]
    points[7] = [0.0, 0.0, 0.0]
    points[8] = [200.0, 0.0, 0.0]  # on the bound: kept
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        out = sanitize_scan(points, labels, max_range=200.0, min_range=0.5)
    assert (out.dropped_nonfinite, out.dropped_far, out.dropped_near) == (3, 3, 2)
    assert out.dropped == 8 and len(out) == 2
    np.testing.assert_array_equal(out.keep, [False] * 8 + [True, True])
    np.testing.assert_array_equal(out.points, points[8:])
    np.testing.assert_array_equal(out.labels, labels[8:])
    assert out.points.dtype == np.float64 and out.labels.dtype == labels.dtype


def test_labels_optional_shapes_and_dtypes() -> None:
    points, _ = _scan(6)
    out = sanitize_scan(points.astype(np.float32).reshape(-1))  # flat 3N float32
    assert out.labels is None and out.points.shape == (6, 3) and out.points.dtype == np.float64
    empty = sanitize_scan(np.zeros((0, 3)), np.zeros(0, np.uint32))
    assert len(empty) == 0 and empty.labels.shape == (0,) and empty.dropped == 0
    with pytest.raises(ValueError, match='6 points but 5 labels'):
        sanitize_scan(points, np.zeros(5))
    with pytest.raises(ValueError, match=r'points must be \(N, 3\)'):
        sanitize_scan(np.zeros((4, 2)))


@pytest.mark.parametrize(
    'max_range, min_range, reason',
    [
        (0.0, 0.0, 'max_range=0.0 must lie in'),
        (np.inf, 0.0, 'max_range=inf must lie in'),
        (np.nan, 0.0, 'max_range=nan must lie in'),
        (2 * MAX_RANGE_LIMIT_M, 0.0, 'must lie in \\(0, 1e\\+06\\] m'),
        (10.0, 10.0, 'min_range=10.0 must lie in \\[0, features.max_range=10.0\\)'),
        (10.0, -1.0, 'min_range=-1.0'),
    ],
)
def test_invalid_ranges_raise(max_range: float, min_range: float, reason: str) -> None:
    with pytest.raises(ConfigError, match=reason):
        sanitize_scan(np.zeros((1, 3)), max_range=max_range, min_range=min_range)


def test_config_fields_and_limit_agree() -> None:
    config = RegistrationConfig()
    assert (config.features.max_range, config.features.min_range) == (200.0, 0.0)
    assert field_of('features.max_range').metadata['high'] == MAX_RANGE_LIMIT_M
    with pytest.raises(ConfigError, match=r'features.max_range=0.5 is below its minimum 1.0'):
        config.replace({'features.max_range': 0.5})
    with pytest.raises(ConfigError, match=r'features.max_range=2000000.0 is above'):
        config.replace({'features.max_range': 2e6})
    with pytest.raises(ConfigError, match=r'features.min_range=-1.0 is below'):
        config.replace({'features.min_range': -1.0})
    near = config.replace({'features.min_range': 3.0, 'features.max_range': 50.0})
    points = np.array([[1.0, 0.0, 0.0], [10.0, 0.0, 0.0], [60.0, 0.0, 0.0]])
    out = sanitize_scan_for(points, None, near.features)
    assert (out.dropped_near, out.dropped_far, len(out)) == (1, 1, 1)


def test_a_point_at_1e30_no_longer_collapses_the_voxel_grid() -> None:
    # Issue 11: one point at 1e30 turned 17,600 voxels into 32 ("invalid value in cast").
    points, labels = _scan(20000, seed=4)
    clean_points, clean_labels = features.voxel_downsample(points, labels, 0.3)
    for bad in (
        [1e30] * 3,
        [1e30, 2.0, 3.0],
        [-1e30] * 3,
        [1e300] * 3,
        [np.inf, 0.0, 0.0],
        [np.nan] * 3,
    ):
        dirty = np.vstack([points, [bad]])
        out = sanitize_scan(dirty, np.append(labels, 9))
        assert out.dropped == 1
        with warnings.catch_warnings():
            warnings.simplefilter('error')  # no 'invalid value encountered in cast'
            voxels, voxel_labels = features.voxel_downsample(out.points, out.labels, 0.3)
        assert voxels.shape == clean_points.shape, bad
        np.testing.assert_array_equal(voxels, clean_points)
        np.testing.assert_array_equal(voxel_labels, clean_labels)


def test_points_at_the_range_limit_keep_the_voxel_grid_exact() -> None:
    # The farthest points the guard lets through (1e6 m) at a small voxel size.
    points, labels = _scan(500, seed=5)
    far = np.vstack([points, [[MAX_RANGE_LIMIT_M, 0.0, 0.0], [0.0, -MAX_RANGE_LIMIT_M, 0.0]]])
    out = sanitize_scan(far, np.append(labels, [1, 2]), max_range=MAX_RANGE_LIMIT_M)
    assert out.dropped == 0
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        voxels, _ = features.voxel_downsample(out.points, out.labels, 0.05)
    reference, _ = features.voxel_downsample(points, labels, 0.05)
    assert voxels.shape[0] == reference.shape[0] + 2


def test_voxel_groups_alone_survive_a_point_at_1e30() -> None:
    points, _ = _scan(20000, seed=4)
    _, clean = features.voxel_groups(points, 0.3)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        _, dirty = features.voxel_groups(np.vstack([points, [[1e30, 1e30, 1e30]]]), 0.3)
    assert dirty == clean + 1
