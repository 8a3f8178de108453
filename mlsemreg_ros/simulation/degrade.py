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
Label degradation: the paper's boundary blur and random label flips.

Boundary blur (paper appendix "Robustness Analysis for Semantic Label
Generation"): a point is a boundary point if a point of another class lies
within the blur radius; each boundary point, with probability 0.5, takes one of
those other classes, chosen uniformly among the distinct classes present within
the radius.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def _neighbourhood_classes(
    points: np.ndarray, class_index: np.ndarray, radius: float
) -> np.ndarray:
    """
    Return, per point, a bit mask (N,) uint64 of the classes in its 3x3x3 cell block.

    Cells have edge ``radius``, so every point within ``radius`` of a point lies in
    the 27 cells around it: the mask is a superset of the classes within reach.
    """
    cells = np.floor(points / radius).astype(np.int64)
    cells -= cells.min(axis=0) - 1  # >= 1, so the -1 neighbours stay >= 0
    keys = (cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2]
    bits = np.left_shift(np.uint64(1), class_index.astype(np.uint64))
    order = np.argsort(keys, kind='stable')
    unique, first = np.unique(keys[order], return_index=True)
    cell_mask = np.bitwise_or.reduceat(bits[order], first)
    mask = np.zeros(points.shape[0], dtype=np.uint64)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                neighbour = keys + ((dx << 42) + (dy << 21) + dz)
                slot = np.minimum(np.searchsorted(unique, neighbour), unique.size - 1)
                found = unique[slot] == neighbour
                mask[found] |= cell_mask[slot[found]]
    return mask


def classes_within(
    points: np.ndarray, labels: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """
    Find which classes have a point within ``radius`` of each point (exact).

    - ``points``: (N, 3) metres.
    - ``labels``: (N,) integer class ids.
    - ``radius``: metres.

    Returns ``classes`` (C,), the distinct labels, and ``present`` (N, C) bool,
    true where class ``classes[c]`` has a point within ``radius`` of point i (own
    class included). A coarse cell grid first rules out the classes that cannot be
    within reach; only the remaining (point, class) pairs are queried, one KD-tree
    per class.
    """
    points = np.asarray(points, dtype=np.float64)
    classes, class_index = np.unique(labels, return_inverse=True)
    class_index = class_index.reshape(-1)
    present = np.zeros((labels.shape[0], classes.size), dtype=bool)
    present[np.arange(labels.shape[0]), class_index] = True
    if classes.size > 63:  # bit masks hold 63 classes; query everything instead
        nearby = np.full(labels.shape[0], np.iinfo(np.uint64).max, dtype=np.uint64)
    else:
        nearby = _neighbourhood_classes(points, class_index, radius)
    for c in range(classes.size):
        member = class_index == c
        candidates = np.flatnonzero(
            ~member & ((nearby >> np.uint64(c)) & np.uint64(1)).astype(bool)
        )
        if candidates.size == 0:
            continue
        tree = cKDTree(points[member])
        distance, _ = tree.query(points[candidates], k=1, distance_upper_bound=radius, workers=-1)
        present[candidates, c] = np.isfinite(distance)
    return classes, present


def boundary_blur(
    points: np.ndarray,
    labels: np.ndarray,
    radius: float,
    rng: np.random.Generator,
    probability: float = 0.5,
) -> np.ndarray:
    """
    Blur class boundaries: boundary points take another nearby class with ``probability``.

    - ``points``: (N, 3) metres.
    - ``labels``: (N,) integer class ids (any scheme).
    - ``radius``: blur radius in metres (paper: 1 m); 0 returns a copy.
    - ``rng``: random generator.
    - ``probability``: chance that a boundary point changes class (paper: 0.5).

    Returns (N,) new labels of the same dtype.
    """
    labels = np.asarray(labels)
    out = labels.copy()
    if radius <= 0.0 or labels.size == 0:
        return out
    classes, present = classes_within(np.asarray(points, dtype=np.float64), labels, radius)
    own = np.searchsorted(classes, labels)
    present[np.arange(labels.size), own] = False  # other classes only
    boundary = present.any(axis=1) & (rng.random(labels.size) < probability)
    rows = np.flatnonzero(boundary)
    scores = rng.random((rows.size, classes.size)) * present[rows]  # uniform among present
    out[rows] = classes[np.argmax(scores, axis=1)]
    return out


def random_flips(
    labels: np.ndarray, fraction: float, classes: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """Give a random ``fraction`` of the points a uniformly drawn other class of ``classes``."""
    labels = np.asarray(labels)
    out = labels.copy()
    classes = np.asarray(classes)
    if fraction <= 0.0 or labels.size == 0 or classes.size < 2:
        return out
    rows = np.flatnonzero(rng.random(labels.size) < fraction)
    # Draw among the classes except the point's own: shift past its position.
    own = np.searchsorted(classes, labels[rows])
    own_known = (own < classes.size) & (classes[np.minimum(own, classes.size - 1)] == labels[rows])
    draw = rng.integers(0, classes.size - own_known.astype(np.int64), rows.size)
    draw = np.where(own_known & (draw >= own), draw + 1, draw)
    out[rows] = classes[draw].astype(labels.dtype)
    return out


def class_confusions(
    labels: np.ndarray,
    fraction: float,
    pairs: list[tuple[int, int]],
    rng: np.random.Generator,
) -> np.ndarray:
    """
    Confuse class pairs: a ``fraction`` of the points of each paired class take a partner.

    ``pairs``: ``(a, b)`` class ids confused both ways. A class in several pairs (e.g.
    vegetation with building and with terrain) takes one of its partners, drawn evenly.
    Every point is decided once, from the labels as given.
    """
    labels = np.asarray(labels)
    out = labels.copy()
    if fraction <= 0.0 or labels.size == 0:
        return out
    partners: dict[int, list[int]] = {}
    for a, b in pairs:
        partners.setdefault(int(a), []).append(int(b))
        partners.setdefault(int(b), []).append(int(a))
    hit = rng.random(labels.size) < fraction
    for own, others in partners.items():
        rows = np.flatnonzero(hit & (labels == own))
        choice = np.asarray(others, dtype=np.int64)[rng.integers(0, len(others), rows.size)]
        out[rows] = choice.astype(labels.dtype)
    return out
