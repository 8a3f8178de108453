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
"""Known-answer and property tests of Local-SS (eq. 1), BMR-SS (eq. 5) and eq. 6."""

from mlsemreg_ros.core import threads as thread_settings
from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.matching.signatures import (
    binary_multi_ring_signature,
    bmr_signature_sparse,
    local_semantic_signature,
    scene_similarity,
)
from mlsemreg_ros.core.results import Landmarks
import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist
from scipy.spatial.transform import Rotation

LABELS = LabelMap.load()
POLE, ROAD, CAR = LABELS.id_of('pole'), LABELS.id_of('road'), LABELS.id_of('car')
UNLABELED, BUILDING = LABELS.id_of('unlabeled'), LABELS.id_of('building')


def test_local_ss_holds_exactly_the_labels_within_radius():
    points = np.array([[0, 0, 0], [0.5, 0, 0], [0, 0.7, 0], [0.9, 0, 0], [5, 5, 5]], float)
    labels = np.array([POLE, ROAD, ROAD, CAR, BUILDING])
    signature = local_semantic_signature(points, labels, points[:1], 0.8, LABELS.num_classes)
    assert set(np.flatnonzero(signature[0])) == {POLE, ROAD}  # car at 0.9 m is outside


def test_local_ss_radius_is_inclusive_and_isolated_keypoint_is_empty():
    points = np.array([[0, 0, 0], [0.8, 0, 0]], float)
    labels = np.array([POLE, CAR])
    keypoints = np.array([[0, 0, 0], [50, 0, 0]], float)
    signature = local_semantic_signature(points, labels, keypoints, 0.8, LABELS.num_classes)
    assert set(np.flatnonzero(signature[0])) == {POLE, CAR}
    assert not signature[1].any()


def test_ignored_and_undefined_classes():
    points = np.array([[0, 0, 0], [0.1, 0, 0], [10, 0, 0], [10.1, 0, 0]], float)
    labels = np.array([ROAD, CAR, ROAD, UNLABELED])
    keypoints = points[[0, 2]]
    signature = local_semantic_signature(
        points,
        labels,
        keypoints,
        0.5,
        LABELS.num_classes,
        ignored=np.array([CAR]),
        undefined=np.array([UNLABELED]),
    )
    assert set(np.flatnonzero(signature[0])) == {ROAD}  # car ignored
    expected = set(range(LABELS.num_classes)) - {CAR, UNLABELED}  # member of every group
    assert set(np.flatnonzero(signature[1])) == expected


def test_undefined_membership_does_not_depend_on_keypoint_order():
    rng = np.random.default_rng(3)
    points = rng.uniform(-5, 5, (400, 3))
    labels = rng.choice([ROAD, CAR, POLE, UNLABELED], 400)
    keypoints = points[:60]
    order = rng.permutation(60)
    a = local_semantic_signature(
        points, labels, keypoints, 1.0, LABELS.num_classes, undefined=np.array([UNLABELED])
    )
    b = local_semantic_signature(
        points, labels, keypoints[order], 1.0, LABELS.num_classes, undefined=np.array([UNLABELED])
    )
    np.testing.assert_array_equal(a[order], b)


def test_bmr_landmark_at_4_6_m_sets_ring_4():
    landmarks = Landmarks(np.array([[4.6, 0.0, 0.0]]), np.array([POLE]))
    signature = binary_multi_ring_signature(
        np.zeros((1, 3)), landmarks, np.array([CAR, POLE]), 33, 1.5
    )
    assert signature.shape == (1, 66)
    assert np.flatnonzero(signature[0]).tolist() == [33 + 3]  # class row 1, ring 4 (index 3)


def test_bmr_ignores_landmarks_beyond_the_last_ring_and_unlisted_classes():
    landmarks = Landmarks(
        np.array([[49.6, 0, 0], [1.0, 0, 0], [2.0, 0, 0]]), np.array([POLE, CAR, POLE])
    )
    signature = binary_multi_ring_signature(np.zeros((1, 3)), landmarks, np.array([POLE]), 33, 1.5)
    assert np.flatnonzero(signature[0]).tolist() == [1]  # 49.6 m >= 33 * 1.5; car unlisted


def test_bmr_is_rotation_and_translation_invariant():
    rng = np.random.default_rng(7)
    keypoints = rng.uniform(-40, 40, (300, 3))
    landmarks = Landmarks(rng.uniform(-40, 40, (25, 3)), rng.choice([CAR, POLE, ROAD], 25))
    rotation = Rotation.random(random_state=11).as_matrix()
    shift = np.array([12.0, -3.0, 1.5])
    moved = Landmarks(landmarks.centroids @ rotation.T + shift, landmarks.classes)
    classes = np.array([CAR, POLE, ROAD])
    before = binary_multi_ring_signature(keypoints, landmarks, classes, 33, 1.5)
    after = binary_multi_ring_signature(keypoints @ rotation.T + shift, moved, classes, 33, 1.5)
    # ring boundaries are exact in theory; allow the odd float round-off flip at a boundary
    assert (before != after).sum() <= 2
    assert before.sum() > 300


def test_sparse_bmr_equals_dense_and_is_binary_with_duplicate_landmarks():
    landmarks = Landmarks(
        np.array([[3.0, 0, 0], [0, 3.1, 0], [10, 0, 0]]), np.array([POLE, POLE, CAR])
    )
    keypoints = np.array([[0, 0, 0], [1, 1, 0]], float)
    classes = np.array([POLE, CAR])
    dense = binary_multi_ring_signature(keypoints, landmarks, classes, 10, 1.5)
    sparse = bmr_signature_sparse(keypoints, landmarks, classes, 10, 1.5)
    np.testing.assert_array_equal(sparse.toarray().astype(bool), dense)
    assert sparse.max() == 1


def test_scene_similarity_counts_shared_class_ring_bins():
    source = np.zeros((1, 6), bool)
    target = np.zeros((2, 6), bool)
    source[0, [0, 2, 4]] = True
    target[0, [0, 2, 5]] = True
    target[1, [1, 3]] = True
    np.testing.assert_array_equal(scene_similarity(source, target), [[2, 0]])


@pytest.mark.parametrize('threads', [1, 2])
def test_local_ss_equals_brute_force_in_parallel_parts_and_with_a_given_tree(threads, monkeypatch):
    monkeypatch.setattr(thread_settings, '_requested', threads)
    rng = np.random.default_rng(12)
    points = rng.uniform(-6, 6, (3000, 3))
    labels = rng.integers(0, LABELS.num_classes, 3000)
    keypoints = np.vstack([points[:1000], rng.uniform(-7, 7, (600, 3))])  # >= 2 parts
    expected = np.zeros((len(keypoints), LABELS.num_classes), bool)
    near = cdist(keypoints, points) <= 0.8
    for i in range(len(keypoints)):
        expected[i, labels[near[i]]] = True
    got = local_semantic_signature(points, labels, keypoints, 0.8, LABELS.num_classes)
    np.testing.assert_array_equal(got, expected)
    shared = local_semantic_signature(
        points, labels, keypoints, 0.8, LABELS.num_classes, points_tree=cKDTree(points)
    )
    np.testing.assert_array_equal(shared, expected)
