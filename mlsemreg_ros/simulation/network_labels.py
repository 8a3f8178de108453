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
Labels as a single-scan segmentation network predicts them (field mode).

The error rate of each class comes from a published network's per-class IoU on the
SemanticKITTI test set. With as many false positives as misses (a symmetric
confusion), ``IoU = (1 - e) / (1 + e)``, so a share ``e = (1 - IoU) / (1 + IoU)`` of the
class's points is mislabeled (car: 91.4 % IoU -> 4.5 %; truck: 25.7 % -> 59 %).
The tables (learning-id order car ... traffic-sign, values in %):

- RangeNet53++ with kNN post-processing, 64 x 2048 (Milioto et al., "RangeNet++:
  Fast and Accurate LiDAR Semantic Segmentation", IROS 2019, table I; mIoU 52.2);
- SalsaNext (Cortinhal et al., "SalsaNext: Fast, Uncertainty-aware Semantic
  Segmentation of LiDAR Point Clouds", ISVC 2020, table I; mIoU 59.5).

The errors are spread over the mechanisms seen in such networks' outputs:

- **regions**: world-anchored cells (1.5-5 m, per class) that the network gets
  wrong, the same cells from scan to scan but flickering (each confusable cell is
  wrong in half of the scans); building cells are 5 m and go mostly to
  vegetation, so parts of a wall read as vegetation (and hedges as building);
- **whole instances** (things): a car read as a truck, a cyclist as a person, in
  some scans;
- **object boundaries**: a point whose range-image neighbour has another class
  takes that class (a range image's blurred edges);
- **salt**: isolated random errors.

Points that are truly ``unlabeled`` (SemanticKITTI's other-object and the like) are
never predicted unlabeled: a network trained on the 19 classes gives every point
one of them, consistently per 1.5 m cell. The targets of each class's errors are
the plausible confusions in :data:`CONFUSIONS`. ``docs/simulation.md`` gives the
per-class IoU the model reaches in the simulated world.
"""

from __future__ import annotations

from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.simulation.field_lidar import FieldScan
import numpy as np

#: Per-class IoU (%) on the SemanticKITTI test set, learning ids 1..19.
IOU_PERCENT = {
    'rangenet++': (
        91.4, 25.7, 34.4, 25.7, 23.0, 38.3, 38.8, 4.8, 91.8, 65.0,
        75.2, 27.8, 87.4, 58.6, 80.5, 55.1, 64.6, 47.9, 55.9,
    ),
    'salsanext': (
        91.9, 48.3, 38.6, 38.9, 31.9, 60.2, 59.0, 19.4, 91.7, 63.7,
        75.8, 29.1, 90.2, 64.2, 81.8, 63.6, 66.5, 54.3, 62.1,
    ),
}  # fmt: skip

#: Where each class's errors go (class -> {wrong class: weight}).
CONFUSIONS: dict[str, dict[str, float]] = {
    'unlabeled': {
        'building': 0.1, 'vegetation': 0.15, 'fence': 0.2, 'pole': 0.2, 'car': 0.1,
        'terrain': 0.25,
    },
    'car': {
        'truck': 0.3, 'other-vehicle': 0.3, 'building': 0.15, 'fence': 0.1, 'vegetation': 0.15,
    },
    'bicycle': {
        'motorcycle': 0.3, 'bicyclist': 0.3, 'person': 0.1, 'vegetation': 0.15, 'pole': 0.15,
    },
    'motorcycle': {'bicycle': 0.4, 'motorcyclist': 0.2, 'car': 0.2, 'vegetation': 0.2},
    'truck': {'car': 0.5, 'other-vehicle': 0.35, 'building': 0.15},
    'other-vehicle': {'car': 0.4, 'truck': 0.4, 'building': 0.2},
    'person': {'bicyclist': 0.3, 'pole': 0.25, 'vegetation': 0.2, 'trunk': 0.15, 'building': 0.1},
    'bicyclist': {'person': 0.4, 'bicycle': 0.3, 'motorcyclist': 0.2, 'car': 0.1},
    'motorcyclist': {'bicyclist': 0.4, 'motorcycle': 0.3, 'person': 0.3},
    'road': {'parking': 0.4, 'sidewalk': 0.35, 'terrain': 0.15, 'other-ground': 0.1},
    'parking': {'road': 0.5, 'sidewalk': 0.3, 'terrain': 0.1, 'other-ground': 0.1},
    'sidewalk': {'road': 0.35, 'parking': 0.25, 'terrain': 0.25, 'other-ground': 0.15},
    'other-ground': {'sidewalk': 0.35, 'terrain': 0.35, 'road': 0.2, 'parking': 0.1},
    'building': {'vegetation': 0.55, 'fence': 0.25, 'pole': 0.1, 'car': 0.1},
    'fence': {'vegetation': 0.45, 'building': 0.35, 'terrain': 0.1, 'pole': 0.1},
    'vegetation': {'terrain': 0.35, 'building': 0.3, 'fence': 0.2, 'trunk': 0.15},
    'trunk': {'vegetation': 0.55, 'pole': 0.35, 'building': 0.1},
    'terrain': {'vegetation': 0.45, 'sidewalk': 0.25, 'road': 0.15, 'parking': 0.15},
    'pole': {'trunk': 0.35, 'traffic-sign': 0.25, 'building': 0.2, 'vegetation': 0.2},
    'traffic-sign': {'pole': 0.6, 'building': 0.2, 'vegetation': 0.2},
}  # fmt: skip

THINGS = (
    'car', 'bicycle', 'motorcycle', 'truck', 'other-vehicle', 'person', 'bicyclist',
    'motorcyclist',
)  # fmt: skip
#: Region cell edge per class, metres (default 1.5).
CELL_M = {'building': 5.0, 'road': 3.0, 'sidewalk': 3.0, 'parking': 3.0, 'terrain': 3.0,
          'vegetation': 3.0, 'other-ground': 3.0, 'fence': 2.5}  # fmt: skip
#: Shares of a class's error budget: region, whole instance, boundary, salt.
THING_SHARES = (0.25, 0.3, 0.3, 0.15)
STUFF_SHARES = (0.5, 0.0, 0.35, 0.15)
#: Share of the scans in which a confusable cell or instance is wrong (flicker).
FLICKER = 0.5

_MASK = np.uint64(0xFFFFFFFFFFFFFFFF)


def _mix(x: np.ndarray) -> np.ndarray:
    """SplitMix64 finaliser on uint64 arrays."""
    with np.errstate(over='ignore'):
        x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return x ^ (x >> np.uint64(31))


def hash_uniform(*keys: np.ndarray | int) -> np.ndarray:
    """Uniform [0, 1) values, a deterministic function of the integer keys (broadcast)."""
    arrays = np.broadcast_arrays(*[np.asarray(k, dtype=np.int64) for k in keys])
    h = np.full(arrays[0].shape, 0x9E3779B97F4A7C15, dtype=np.uint64)
    with np.errstate(over='ignore'):
        for a in arrays:
            h = _mix(h ^ (a.astype(np.uint64) + np.uint64(0x632BE59BD9B4E019)))
    return (h >> np.uint64(11)).astype(np.float64) / float(1 << 53)


class NetworkLabelModel:
    """Predicts a network's labels for a sweep from its true labels and geometry."""

    def __init__(self, label_map: LabelMap, seed: int, network: str = 'rangenet++') -> None:
        if network not in IOU_PERCENT:
            raise ValueError(f'unknown network {network!r}; use one of {sorted(IOU_PERCENT)}')
        self.label_map, self.seed, self.network = label_map, int(seed), network
        n = label_map.num_classes
        iou = np.concatenate([[0.0], np.asarray(IOU_PERCENT[network]) / 100.0])
        self.error_rate = (1.0 - iou) / (1.0 + iou)
        self.error_rate[0] = 1.0  # a 19-class network never predicts unlabeled
        targets = np.zeros((n, n))
        for name, weights in CONFUSIONS.items():
            for other, w in weights.items():
                targets[label_map.id_of(name), label_map.id_of(other)] = w
        targets /= np.maximum(targets.sum(axis=1, keepdims=True), 1e-12)
        self._cumulative = np.cumsum(targets, axis=1)
        thing = np.zeros(n, dtype=bool)
        thing[label_map.ids_of(THINGS)] = True
        shares = np.where(thing[:, None], THING_SHARES, STUFF_SHARES)
        self.region_rate = self.error_rate * shares[:, 0]
        self.instance_rate = self.error_rate * shares[:, 1]
        self.boundary_rate = self.error_rate * shares[:, 2]
        self.salt_rate = self.error_rate * shares[:, 3]
        self.region_rate[0], self.boundary_rate[0], self.salt_rate[0] = 1.0, 0.0, 0.0
        self.cell = np.full(n, 1.5)
        for name, size in CELL_M.items():
            self.cell[label_map.id_of(name)] = size

    def _target(self, labels: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Draw the wrong class by ``u`` (n,) in [0, 1) from each label's confusions."""
        cumulative = self._cumulative[labels]
        return np.minimum((cumulative < u[:, None]).sum(axis=1), cumulative.shape[1] - 1)

    def _persistent(self, rate: np.ndarray, fixed: np.ndarray, flicker: np.ndarray) -> np.ndarray:
        """Wrong in this scan: confusable (``fixed`` < 2 rate) and on (``flicker``)."""
        confusable = np.minimum(1.0, rate / FLICKER)
        on = np.where(confusable > 0, rate / np.maximum(confusable, 1e-12), 0.0)
        return (fixed < confusable) & (flicker < on)

    def predict(self, scan: FieldScan, index: int) -> np.ndarray:
        """Predicted learning ids (N,) int32 of sweep ``index``."""
        truth = scan.labels.astype(np.int64)
        out = truth.copy()
        changed = np.zeros(truth.size, dtype=bool)
        seed = self.seed
        # Whole instances (things).
        inst = scan.instances.astype(np.int64)
        has = (inst > 0) & (self.instance_rate[truth] > 0)
        if has.any():
            rate = self.instance_rate[truth[has]]
            wrong = self._persistent(
                rate, hash_uniform(inst[has], seed, 4), hash_uniform(inst[has], seed, 5, index)
            )
            rows = np.flatnonzero(has)[wrong]
            out[rows] = self._target(truth[rows], hash_uniform(inst[rows], seed, 6))
            changed[rows] = True
        # World-anchored regions.
        cells = np.floor(scan.world_points / self.cell[truth][:, None]).astype(np.int64)
        keys = (cells[:, 0], cells[:, 1], cells[:, 2], truth, seed)
        wrong = self._persistent(
            self.region_rate[truth],
            hash_uniform(*keys, 1),
            np.where(truth == 0, 0.0, hash_uniform(*keys, 2, index)),
        )
        wrong &= ~changed
        out[wrong] = self._target(truth[wrong], hash_uniform(*keys, 3)[wrong])
        changed |= wrong
        rng = np.random.default_rng([seed, 7, index])
        # Boundaries in the range image.
        neighbour = self._range_image_neighbour(scan, truth, rng)
        boundary = (neighbour >= 0) & ~changed
        counts = np.bincount(truth, minlength=self.error_rate.size)
        on_boundary = np.bincount(truth[boundary], minlength=self.error_rate.size)
        p = np.minimum(1.0, self.boundary_rate * counts / np.maximum(on_boundary, 1))
        flip = boundary & (rng.random(truth.size) < p[truth])
        out[flip] = neighbour[flip]
        changed |= flip
        # Salt.
        salt = ~changed & (rng.random(truth.size) < self.salt_rate[truth])
        out[salt] = self._target(truth[salt], rng.random(int(salt.sum())))
        return out.astype(np.int32)

    def _range_image_neighbour(
        self, scan: FieldScan, labels: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        """Per point, a random range-image neighbour's other class, never unlabeled (else -1)."""
        columns = int(scan.column.max()) + 1 if len(scan) else 1
        beams = int(scan.ring.max()) + 1 if len(scan) else 1
        image = np.full((columns, beams), -1, dtype=np.int64)
        col, ring = scan.column.astype(np.int64), scan.ring.astype(np.int64)
        image[col, ring] = labels
        found = np.full(labels.size, -1, dtype=np.int64)
        best = np.full(labels.size, -1.0)
        for dc, dr in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            other = image[(col + dc) % columns, np.clip(ring + dr, 0, beams - 1)]
            score = np.where((other > 0) & (other != labels), rng.random(labels.size), -1.0)
            better = score > best
            found[better], best[better] = other[better], score[better]
        return found
