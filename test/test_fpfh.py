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
"""Known-answer and property tests of the vectorized FPFH (core/features/fpfh.py)."""

from kernel_modes import kernel_mode  # noqa: F401 (autouse: numba and NumPy)
from mlsemreg_ros.core.features.fpfh import (
    estimate_normals,
    fpfh_at_keypoints,
    pair_feature_bins,
    smallest_eigenvectors,
)
import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation


def _soa(rows: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(rows, dtype=np.float32).T)


def _darboux_reference(
    p1: np.ndarray, n1: np.ndarray, p2: np.ndarray, n2: np.ndarray
) -> tuple[float, float, float]:
    """Pair features with the explicit Darboux frame (Rusu et al. 2009, as in Open3D)."""
    d = p2 - p1
    u = d / np.linalg.norm(d)
    if np.arccos(abs(n1 @ u)) > np.arccos(abs(n2 @ u)):
        n1, n2, u = n2, n1, -u
    v = np.cross(u, n1)
    v /= np.linalg.norm(v)
    w = np.cross(n1, v)
    return float(np.arctan2(w @ n2, n1 @ n2)), float(v @ n2), float(u @ n1)


def _ground_and_box(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    ground = np.c_[rng.uniform(-5, 5, (1500, 2)), rng.normal(-1.7, 0.02, 1500)]
    box = rng.uniform(-1, 1, (600, 3)) * [1, 1, 0.5] + [2.0, 2.0, -0.5]
    return np.r_[ground, box]


def test_coplanar_pair_has_the_middle_bins():
    # Two points on a plane with the plane's normal: alpha = phi = theta = 0 -> bin 5 each.
    bins = pair_feature_bins(
        _soa([[1.0, 0.0, 0.0]]), _soa([[0.0, 0.0, 1.0]]), _soa([[0.0, 0.0, 1.0]])
    )
    np.testing.assert_array_equal(bins[:, 0], [5, 5, 5])


def test_perpendicular_normal_pair_known_answer():
    # p1 = 0 with n1 = +z, p2 = (1, 0, 0). With n2 = +x the line is along p2's normal, so
    # p2 is the source and its Darboux frame is degenerate: the all-zero feature (Open3D).
    bins = pair_feature_bins(
        _soa([[1.0, 0.0, 0.0]]), _soa([[0.0, 0.0, 1.0]]), _soa([[1.0, 0.0, 0.0]])
    )
    np.testing.assert_array_equal(bins[:, 0], [5, 5, 5])
    # n2 = (0.8, 0, 0.6): p2 is still the source (|0.8| > |0|), u_s = -x, so
    # theta = u_s.n_s = -0.8 -> bin floor(11 * 0.2 / 2) = 1; v = +y, phi = v.n_t = 0 -> 5;
    # w = (-0.6, 0, 0.8), alpha = atan2(w.n_t, n_s.n_t) = atan2(0.8, 0.6) = 0.927 -> 7.
    bins = pair_feature_bins(
        _soa([[1.0, 0.0, 0.0]]), _soa([[0.0, 0.0, 1.0]]), _soa([[0.8, 0.0, 0.6]])
    )
    np.testing.assert_array_equal(bins[:, 0], [7, 5, 1])


def test_pair_features_equal_the_explicit_darboux_frame_and_are_symmetric():
    rng = np.random.default_rng(0)
    p1, p2 = rng.normal(size=(2, 500, 3))
    n1, n2 = rng.normal(size=(2, 500, 3))
    n1 /= np.linalg.norm(n1, axis=1, keepdims=True)
    n2 /= np.linalg.norm(n2, axis=1, keepdims=True)
    reference = np.array([_darboux_reference(*args) for args in zip(p1, n1, p2, n2, strict=True)])
    scaled = (reference - [-np.pi, -1.0, -1.0]) / [2 * np.pi, 2.0, 2.0] * 11
    expected = np.clip(np.floor(scaled), 0, 10).astype(int)
    clear = np.all(np.abs(scaled - np.round(scaled)) > 1e-3, axis=1)  # away from bin edges
    ours = pair_feature_bins(_soa(p2 - p1), _soa(n1), _soa(n2)).T
    assert clear.sum() > 450
    np.testing.assert_array_equal(ours[clear], expected[clear])
    swapped = pair_feature_bins(_soa(p1 - p2), _soa(n2), _soa(n1)).T
    np.testing.assert_array_equal(swapped[clear], ours[clear])


def test_smallest_eigenvectors_match_lapack():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(400, 3, 3))
    spd = a @ a.transpose(0, 2, 1)
    spd[:50] = np.diag([4.0, 1.0, 1e-4])  # a flat patch: exact answer +-z
    upper = spd[:, [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]
    ours = smallest_eigenvectors(upper)
    reference = np.linalg.eigh(spd)[1][:, :, 0]
    np.testing.assert_allclose(np.abs(np.einsum('ij,ij->i', ours, reference)), 1.0, atol=1e-6)
    np.testing.assert_allclose(np.abs(ours[:50, 2]), 1.0)


def test_ground_normals_point_up_towards_the_sensor():
    points = _ground_and_box(4)[:1500]  # ground plane 1.7 m below the sensor
    pairs = cKDTree(points).query_pairs(0.9, output_type='ndarray')
    delta = (points[pairs[:, 1]] - points[pairs[:, 0]]).T
    normals = estimate_normals(points, (pairs[:, 0], pairs[:, 1]), delta)
    assert normals.shape == (3, 1500)
    assert np.percentile(normals[2], 1) > 0.99


def test_fpfh_equals_open3d_given_the_same_normals():
    points = _ground_and_box(1)
    rng = np.random.default_rng(5)
    indices = rng.permutation(len(points))[:300]
    ours = fpfh_at_keypoints(points, indices, 0.9, 1.5)
    pairs = cKDTree(points).query_pairs(0.9, output_type='ndarray')
    delta = (points[pairs[:, 1]] - points[pairs[:, 0]]).T
    normals = estimate_normals(points, (pairs[:, 0], pairs[:, 1]), delta)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.normals = o3d.utility.Vector3dVector(normals.T.astype(np.float64))
    full = o3d.pipelines.registration.compute_fpfh_feature(
        cloud, o3d.geometry.KDTreeSearchParamRadius(1.5)
    )
    reference = np.asarray(full.data).T[indices]
    assert ours.shape == (300, 33) and ours.dtype == np.float32
    # Float32 pair features and radius-boundary points move at most a pair or two
    # between bins; most rows agree to rounding.
    difference = np.abs(ours - reference).sum(axis=1)
    assert np.median(difference) < 0.1  # of a row total of 600
    assert np.percentile(difference, 95) < 10.0  # of a row total of 600


def test_fpfh_is_invariant_to_a_rigid_motion_of_scan_and_sensor():
    points = _ground_and_box(6)
    indices = np.arange(0, len(points), 7)
    rotation = Rotation.random(random_state=7).as_matrix()
    offset = np.array([3.0, -2.0, 0.5])
    moved = points @ rotation.T + offset
    before = fpfh_at_keypoints(points, indices, 0.9, 1.5)
    after = fpfh_at_keypoints(moved, indices, 0.9, 1.5, viewpoint=offset)
    difference = np.abs(before - after).sum(axis=1)
    assert np.median(difference) < 1e-2
    assert np.percentile(difference, 95) < 10.0


def test_support_voxels_keep_keypoints_apart_and_isolated_points_are_zero():
    points = np.r_[_ground_and_box(8), [[60.0, 60.0, 0.0]]]
    indices = np.array([0, 1, 2, len(points) - 1, 0])
    descriptors = fpfh_at_keypoints(points, indices, 0.9, 1.5, support_voxel=0.6)
    assert descriptors.shape == (5, 33) and descriptors.dtype == np.float32
    assert not descriptors[3].any()
    blocks = descriptors[:3].reshape(3, 3, 11).sum(axis=2)
    np.testing.assert_allclose(blocks, 200.0, rtol=1e-5)  # SPFH 100 + weighted mean 100
    np.testing.assert_array_equal(descriptors[4], descriptors[0])
    # On the ground plane the coarse support barely changes the descriptor.
    exact = fpfh_at_keypoints(points, indices, 0.9, 1.5)
    assert np.abs(descriptors[:3] - exact[:3]).sum(axis=1).max() < 60.0  # of 600
    assert fpfh_at_keypoints(points, np.zeros(0, dtype=np.int64), 0.9, 1.5).shape == (0, 33)


def test_snapped_keypoints_take_the_fpfh_of_their_nearest_support_centroid():
    points = _ground_and_box(9)
    indices = np.array([3, 50, 1600, 3])
    snapped = fpfh_at_keypoints(points, indices, 0.9, 1.5, support_voxel=0.6, snap=True)
    own = fpfh_at_keypoints(points, indices, 0.9, 1.5, support_voxel=0.6)
    assert snapped.shape == own.shape == (4, 33)
    np.testing.assert_array_equal(snapped[0], snapped[3])
    blocks = snapped.reshape(4, 3, 11).sum(axis=2)
    np.testing.assert_allclose(blocks, 200.0, rtol=1e-5)
    # on the plane the nearest centroid sees nearly the keypoint's own neighbourhood
    assert np.abs(snapped[:2] - own[:2]).sum(axis=1).max() < 100.0  # of 600
