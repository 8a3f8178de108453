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


"""Weighted Kabsch (batched SVD) known answers: exact recovery, weights, reflections."""

from __future__ import annotations

from mlsemreg_ros.core.rigid import apply_transform, invert_transform, weighted_rigid_transform
import numpy as np
import pytest
from scipy.spatial.transform import Rotation


def _random_transforms(rng: np.random.Generator, count: int) -> np.ndarray:
    transforms = np.tile(np.eye(4), (count, 1, 1))
    transforms[:, :3, :3] = Rotation.random(count, random_state=rng).as_matrix()
    transforms[:, :3, 3] = rng.uniform(-30.0, 30.0, (count, 3))
    return transforms


def test_exact_recovery_batched() -> None:
    rng = np.random.default_rng(0)
    truth = _random_transforms(rng, 8)
    src = rng.uniform(-10.0, 10.0, (8, 25, 3))
    dst = apply_transform(truth, src)
    estimate = weighted_rigid_transform(src, dst)
    assert estimate.shape == (8, 4, 4)
    np.testing.assert_allclose(estimate, truth, atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(estimate[:, :3, :3]), 1.0, atol=1e-12)


def test_zero_weights_ignore_outliers() -> None:
    rng = np.random.default_rng(1)
    truth = _random_transforms(rng, 1)[0]
    src = rng.uniform(-10.0, 10.0, (40, 3))
    dst = apply_transform(truth, src)
    dst[:15] += rng.uniform(-20.0, 20.0, (15, 3))  # gross outliers
    weights = np.ones(40)
    weights[:15] = 0.0
    np.testing.assert_allclose(weighted_rigid_transform(src, dst, weights), truth, atol=1e-9)
    # the same outliers with uniform weights do spoil the estimate
    assert np.abs(weighted_rigid_transform(src, dst) - truth).max() > 0.1


def test_weights_are_scale_free() -> None:
    rng = np.random.default_rng(2)
    src = rng.normal(size=(30, 3))
    dst = src @ Rotation.random(random_state=rng).as_matrix().T + rng.normal(0.0, 0.1, (30, 3))
    weights = rng.uniform(0.1, 1.0, 30)
    np.testing.assert_allclose(
        weighted_rigid_transform(src, dst, weights),
        weighted_rigid_transform(src, dst, 1e3 * weights),
        atol=1e-9,
    )


def test_reflection_is_fixed() -> None:
    # dst is a mirror image of src: the best *rotation* must still have det +1
    rng = np.random.default_rng(3)
    src = rng.normal(size=(20, 3))
    dst = src * np.array([1.0, 1.0, -1.0])
    estimate = weighted_rigid_transform(src, dst)
    rotation = estimate[:3, :3]
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-9)
    assert np.linalg.det(rotation) == pytest.approx(1.0)


def test_planar_points_keep_a_proper_rotation() -> None:
    # coplanar points give a rank-2 covariance: the SVD sign fix must not flip the plane
    rng = np.random.default_rng(4)
    truth = _random_transforms(rng, 1)[0]
    src = np.column_stack([rng.uniform(-5.0, 5.0, (30, 2)), np.zeros(30)])
    estimate = weighted_rigid_transform(src, apply_transform(truth, src))
    np.testing.assert_allclose(estimate, truth, atol=1e-9)


@pytest.mark.parametrize('count', [0, 1, 2])
def test_degenerate_sets_are_finite(count: int) -> None:
    src = np.arange(3 * count, dtype=float).reshape(count, 3)
    estimate = weighted_rigid_transform(src, src + 1.0)
    assert estimate.shape == (4, 4)
    assert np.isfinite(estimate).all()
    if count:
        np.testing.assert_allclose(apply_transform(estimate, src), src + 1.0, atol=1e-9)


def test_all_zero_weights_fall_back_to_uniform() -> None:
    src = np.random.default_rng(5).normal(size=(2, 10, 3))
    weights = np.zeros((2, 10))
    weights[1] = 1.0
    estimate = weighted_rigid_transform(src, src + 2.0, weights)
    np.testing.assert_allclose(estimate[:, :3, 3], 2.0, atol=1e-9)


def test_shape_errors() -> None:
    with pytest.raises(ValueError, match='src and dst'):
        weighted_rigid_transform(np.zeros((4, 3)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match='weights'):
        weighted_rigid_transform(np.zeros((4, 3)), np.zeros((4, 3)), np.ones(5))


def test_apply_transform_broadcasts() -> None:
    rng = np.random.default_rng(6)
    transforms = _random_transforms(rng, 3)
    points = rng.normal(size=(7, 3))
    moved = apply_transform(transforms, points)
    assert moved.shape == (3, 7, 3)
    homogeneous = np.column_stack([points, np.ones(7)])
    np.testing.assert_allclose(moved[1], (homogeneous @ transforms[1].T)[:, :3])


def test_invert_transform_of_a_stack() -> None:
    rng = np.random.default_rng(4)
    stack = np.tile(np.eye(4), (5, 1, 1))
    stack[:, :3, :3] = Rotation.random(5, random_state=4).as_matrix()
    stack[:, :3, 3] = rng.normal(0.0, 10.0, (5, 3))
    inverse = invert_transform(stack)
    np.testing.assert_allclose(inverse @ stack, np.tile(np.eye(4), (5, 1, 1)), atol=1e-12)
    np.testing.assert_allclose(invert_transform(stack[0]), np.linalg.inv(stack[0]), atol=1e-12)
