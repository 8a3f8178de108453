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
"""Known-answer tests of voxel downsampling, keypoint sampling, FPFH at keypoints, validity."""

from kernel_modes import kernel_mode  # noqa: F401 (autouse: numba and NumPy)
from mlsemreg_ros.core.features.features import (
    fpfh_open3d_at,
    sample_keypoints,
    valid_descriptor_mask,
    voxel_downsample,
)
import numpy as np
import open3d as o3d
import pytest


def test_voxel_downsample_gives_centroids_and_majority_labels():
    points = np.array(
        [
            [0.1, 0.1, 0.1],
            [0.2, 0.2, 0.2],
            [0.3, 0.3, 0.3],  # voxel (0, 0, 0): labels 5, 7, 7
            [1.2, 0.1, 0.1],
            [1.4, 0.3, 0.1],  # voxel (1, 0, 0): a 3-vs-9 tie -> 3
            [-0.5, 0.5, 0.5],  # voxel (-1, 0, 0), alone
        ]
    )
    labels = np.array([5, 7, 7, 9, 3, 2], dtype=np.int32)
    out_pts, out_labels = voxel_downsample(points, labels, 1.0)
    assert out_labels.dtype == np.int32
    assert out_pts.shape == (3, 3)
    order = np.argsort(out_pts[:, 0])
    np.testing.assert_allclose(
        out_pts[order], [[-0.5, 0.5, 0.5], [0.2, 0.2, 0.2], [1.3, 0.2, 0.1]]
    )
    np.testing.assert_array_equal(out_labels[order], [2, 7, 3])


def test_voxel_downsample_majority_on_a_random_cloud_matches_a_loop():
    rng = np.random.default_rng(3)
    points = rng.uniform(0, 4, (3000, 3))
    labels = rng.integers(0, 4, 3000).astype(np.int32)
    out_pts, out_labels = voxel_downsample(points, labels, 1.0)
    keys = np.floor(points).astype(int)
    for p, label in zip(out_pts, out_labels, strict=True):
        members = np.all(keys == np.floor(p).astype(int), axis=1)
        np.testing.assert_allclose(p, points[members].mean(axis=0))
        counts = np.bincount(labels[members], minlength=4)
        assert label == np.flatnonzero(counts == counts.max())[0]
    assert len(out_pts) == len(np.unique(keys, axis=0))


def test_voxel_downsample_nonpositive_size_is_identity():
    points = np.arange(12, dtype=float).reshape(4, 3)
    labels = np.array([1, 2, 3, 4])
    out_pts, out_labels = voxel_downsample(points, labels, 0.0)
    np.testing.assert_array_equal(out_pts, points)
    np.testing.assert_array_equal(out_labels, labels)


@pytest.mark.parametrize('sampling', ['random', 'voxel'])
def test_keypoint_sampling_is_deterministic_and_bounded(sampling):
    rng = np.random.default_rng(0)
    points = rng.uniform(-20, 20, (5000, 3))
    first = sample_keypoints(points, 300, sampling, 2.0, seed=7)
    again = sample_keypoints(points, 300, sampling, 2.0, seed=7)
    other = sample_keypoints(points, 300, sampling, 2.0, seed=8)
    assert first.dtype == np.int64 and len(first) == 300
    assert len(np.unique(first)) == 300 and first.min() >= 0 and first.max() < 5000
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first, other)


def test_random_sampling_returns_all_points_in_order_when_few():
    points = np.zeros((10, 3))
    np.testing.assert_array_equal(sample_keypoints(points, 50, 'random', 1.0, 0), np.arange(10))


def test_voxel_sampling_takes_the_point_nearest_each_voxel_centroid():
    points = np.array(
        [
            [0.1, 0.1, 0.1],
            [0.5, 0.5, 0.5],
            [0.8, 0.8, 0.8],  # centroid ~ 0.47
            [2.1, 0.0, 0.0],
            [2.9, 0.0, 0.0],
            [2.4, 0.0, 0.0],
        ]
    )  # centroid 2.47
    chosen = sample_keypoints(points, 10, 'voxel', 1.0, 0)
    np.testing.assert_array_equal(chosen, [1, 5])
    assert len(sample_keypoints(points, 1, 'voxel', 1.0, 0)) == 1


def test_fpfh_at_equals_the_full_computation_at_those_points():
    rng = np.random.default_rng(1)
    ground = np.c_[rng.uniform(-5, 5, (1500, 2)), rng.normal(0, 0.02, 1500)]
    box = rng.uniform(-1, 1, (600, 3)) * [1, 1, 0.5]
    points = np.r_[ground, box + np.array([2.0, 2.0, 1.0])]
    indices = rng.permutation(len(points))[:200]  # unsorted, as the pipeline passes them
    indices = np.r_[indices, indices[:3]]  # and with repeats
    ours = fpfh_open3d_at(points, indices, 0.9, 30, 1.5, 100)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.9, max_nn=30))
    full = o3d.pipelines.registration.compute_fpfh_feature(
        cloud, o3d.geometry.KDTreeSearchParamHybrid(radius=1.5, max_nn=100)
    )
    full = np.asarray(full.data).T
    assert ours.shape == (203, 33) and ours.dtype == np.float32
    np.testing.assert_allclose(ours, full[indices], rtol=1e-5, atol=1e-4)
    assert fpfh_open3d_at(points, np.zeros(0, dtype=np.int64), 0.9, 30, 1.5, 100).shape == (0, 33)


def test_fpfh_of_an_isolated_point_is_invalid():
    rng = np.random.default_rng(2)
    points = np.r_[rng.uniform(-2, 2, (400, 3)), [[100.0, 100.0, 100.0]]]
    descriptors = fpfh_open3d_at(points, np.array([0, 400]), 0.9, 30, 1.5, 100)
    np.testing.assert_array_equal(valid_descriptor_mask(descriptors), [True, False])


def test_valid_descriptor_mask_drops_nan_inf_and_zero_rows():
    d = np.array([[1.0, 0.0], [np.nan, 1.0], [0.0, 0.0], [np.inf, 2.0], [0.0, -3.0]])
    np.testing.assert_array_equal(valid_descriptor_mask(d), [True, False, False, False, True])


@pytest.mark.parametrize('distinct_labels', [5, 3000])  # dense count table / sorted pairs
def test_voxel_majority_label_matches_a_brute_force_count(distinct_labels: int):
    rng = np.random.default_rng(distinct_labels)
    points = rng.uniform(0.0, 3.0, (4000, 3))
    labels = rng.integers(0, distinct_labels, 4000)
    centroids, voxel_labels = voxel_downsample(points, labels, 0.5)
    keys = [tuple(k) for k in np.floor(points / 0.5).astype(int)]
    votes: dict = {}
    for key, label in zip(keys, labels, strict=True):
        votes.setdefault(key, {}).setdefault(int(label), 0)
        votes[key][int(label)] += 1
    expected = {key: min(c, key=lambda lab: (-c[lab], lab)) for key, c in votes.items()}
    found = {
        tuple(np.floor(c / 0.5).astype(int)): int(lab)
        for c, lab in zip(centroids, voxel_labels, strict=True)
    }
    assert found == expected
