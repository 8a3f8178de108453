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
"""The compiled FPFH (core/features/fpfh_kernels.py) equals the NumPy FPFH bit for bit."""

from mlsemreg_ros.core.features import kernels
from mlsemreg_ros.core.features.fpfh import fpfh_at_keypoints
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair
import numpy as np
import pytest

pytestmark = pytest.mark.skipif(not kernels.AVAILABLE, reason='numba is not installed')


def _scene(seed: int) -> np.ndarray:
    """Ground 1.7 m below the sensor, a box, a pole and scattered clutter."""
    rng = np.random.default_rng(seed)
    ground = np.c_[rng.uniform(-6, 6, (1500, 2)), rng.normal(-1.7, 0.03, 1500)]
    box = rng.uniform(-1, 1, (500, 3)) * [1.0, 1.5, 0.6] + [3.0, -2.0, -0.8]
    pole = np.c_[rng.normal(-3.0, 0.05, (150, 2)), rng.uniform(-1.7, 2.0, 150)]
    clutter = rng.uniform(-8, 8, (80, 3))
    return np.r_[ground, box, pole, clutter]


def _both(*args: object, **kwargs: object) -> tuple[np.ndarray, np.ndarray]:
    return (
        fpfh_at_keypoints(*args, **kwargs, compiled=True),
        fpfh_at_keypoints(*args, **kwargs, compiled=False),
    )


@pytest.mark.parametrize('seed', [0, 1, 2])
@pytest.mark.parametrize(('support_voxel', 'snap'), [(0.5, True), (0.5, False), (0.0, False)])
def test_compiled_fpfh_equals_numpy_on_random_scenes(
    seed: int, support_voxel: float, snap: bool
) -> None:
    points = _scene(seed)
    rng = np.random.default_rng(100 + seed)
    indices = rng.integers(0, len(points), 300)  # unsorted, with repeats
    viewpoint = rng.normal(0, 0.5, 3)
    ours, reference = _both(
        points, indices, 0.9, 1.5, support_voxel, viewpoint=viewpoint, snap=snap
    )
    assert ours.dtype == reference.dtype == np.float32 and ours.shape == (300, 33)
    assert np.count_nonzero(reference.any(axis=1)) > 250  # not a trivially empty case
    np.testing.assert_array_equal(ours, reference)


@pytest.mark.parametrize(('normal_radius', 'feature_radius'), [(1.2, 0.7), (0.5, 0.5)])
def test_compiled_fpfh_equals_numpy_for_other_radii(
    normal_radius: float, feature_radius: float
) -> None:
    points = _scene(7)
    indices = np.arange(0, len(points), 5)
    for snap in (True, False):
        ours, reference = _both(points, indices, normal_radius, feature_radius, 0.4, snap=snap)
        np.testing.assert_array_equal(ours, reference)


@pytest.mark.parametrize('compiled', [True, False])
def test_flat_grid_known_answer(compiled: bool) -> None:
    # A 3 x 3 grid on the ground: every normal is +z, every pair feature is
    # (alpha, phi, theta) = (0, 0, 0) -> bin 5 of each block; SPFH 100 + neighbours 100.
    x, y = np.meshgrid([-0.5, 0.0, 0.5], [-0.5, 0.0, 0.5])
    points = np.c_[x.ravel(), y.ravel(), np.full(9, -1.7)]
    descriptors = fpfh_at_keypoints(points, np.arange(9), 0.9, 1.5, compiled=compiled)
    expected = np.zeros(33, dtype=np.float32)
    expected[[5, 16, 27]] = 200.0
    np.testing.assert_allclose(descriptors, np.tile(expected, (9, 1)), rtol=1e-6)


@pytest.mark.parametrize('compiled', [True, False])
def test_isolated_points_and_tiny_clouds(compiled: bool) -> None:
    points = np.array([[0.0, 0.0, -1.7], [0.5, 0.0, -1.7], [40.0, 0.0, 0.0]])
    descriptors = fpfh_at_keypoints(points, np.array([2, 0, 1, 2]), 0.9, 1.5, compiled=compiled)
    assert not descriptors[0].any() and not descriptors[3].any()
    # Two points: fewer than two neighbours -> normal +z (towards the origin), one pair.
    np.testing.assert_allclose(descriptors[1].reshape(3, 11).sum(axis=1), 200.0, rtol=1e-6)
    np.testing.assert_array_equal(descriptors[1], descriptors[2])
    single = fpfh_at_keypoints(points[:1], np.array([0]), 0.9, 1.5, compiled=compiled)
    assert single.shape == (1, 33) and not single.any()


def test_prepared_scans_are_identical_with_and_without_kernels(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    pair = synthetic_pair(3)
    registration = Registration()
    prepared = []
    for mode in ('numba', 'numpy'):
        monkeypatch.setenv(kernels.ENV_SWITCH, mode)
        prepared.append(registration.prepare(pair.pts_src, pair.label_src))
    ours, reference = prepared
    for field in ('points', 'labels', 'keypoints', 'keypoint_indices', 'descriptors', 'local_ss'):
        np.testing.assert_array_equal(getattr(ours, field), getattr(reference, field))
    assert len(ours.keypoints) > 100


@pytest.mark.parametrize('support_voxel', [0.2, 0.5, 1.3])
def test_bounded_snapping_finds_the_nearest_support_centroid(support_voxel: float) -> None:
    from mlsemreg_ros.core.features.features import voxel_centroids
    from mlsemreg_ros.core.features.fpfh import _snap
    from scipy.spatial import cKDTree

    points = _scene(11)
    support = voxel_centroids(points, support_voxel, compiled=False)[0]
    tree = cKDTree(support)
    np.testing.assert_array_equal(_snap(tree, points, support_voxel), tree.query(points)[1])
