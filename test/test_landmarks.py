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
"""Known-answer tests of landmark extraction (Euclidean clustering per class)."""

from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.matching.landmarks import extract_landmarks
import numpy as np

LABELS = LabelMap.load()
POLE, TRUNK, ROAD = LABELS.id_of('pole'), LABELS.id_of('trunk'), LABELS.id_of('road')


def _column(x: float, y: float, n: int = 6) -> np.ndarray:
    return np.column_stack([np.full(n, x), np.full(n, y), np.linspace(0, 3, n)])


def test_two_poles_five_metres_apart_are_two_landmarks_with_their_centroids():
    points = np.vstack([_column(0, 0), _column(5, 0)])
    labels = np.full(len(points), POLE)
    marks = extract_landmarks(points, labels, np.array([POLE]), 1.5, 3)
    order = np.argsort(marks.centroids[:, 0])
    np.testing.assert_allclose(marks.centroids[order], [[0, 0, 1.5], [5, 0, 1.5]])
    assert marks.classes.tolist() == [POLE, POLE]


def test_small_clusters_are_noise_and_other_classes_are_not_landmarks():
    points = np.vstack([_column(0, 0, 2), _column(10, 0, 5), _column(20, 0, 5)])
    labels = np.r_[np.full(2, POLE), np.full(5, POLE), np.full(5, ROAD)]
    marks = extract_landmarks(points, labels, np.array([POLE]), 1.5, 3)
    assert len(marks) == 1
    np.testing.assert_allclose(marks.centroids[0, :2], [10, 0])


def test_adjacent_classes_are_never_merged_and_chains_connect():
    trunk = _column(0.5, 0)
    chain = np.column_stack([np.arange(0, 6.0, 1.0), np.zeros(6), np.zeros(6)])  # 1 m links
    points = np.vstack([trunk, chain])
    labels = np.r_[np.full(len(trunk), TRUNK), np.full(len(chain), POLE)]
    marks = extract_landmarks(points, labels, np.array([POLE, TRUNK]), 1.5, 3)
    assert sorted(marks.classes.tolist()) == sorted([POLE, TRUNK])
    np.testing.assert_allclose(marks.centroids[marks.classes == POLE][0], [2.5, 0, 0])


def test_clustering_is_in_the_xy_plane():
    stacked = np.array([[0, 0, 0], [0, 0, 5], [0, 0, 10], [0.1, 0, 20]], float)
    marks = extract_landmarks(stacked, np.full(4, POLE), np.array([POLE]), 1.5, 3)
    assert len(marks) == 1  # vertical gaps do not split a pole


def test_no_landmark_points_gives_empty_landmarks():
    marks = extract_landmarks(np.zeros((3, 3)), np.full(3, ROAD), np.array([POLE]), 1.5, 3)
    assert len(marks) == 0 and marks.centroids.shape == (0, 3)
