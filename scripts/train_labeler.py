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
Train the geometric labeler's per-voxel classifier on simulated field drives only.

Renders every ``--every``-th sweep of the simulated field drives of ``--seeds`` (true
labels, no network noise; ``simulation/field.py``), voxelizes each at
``features.voxel_size`` as the odometry does, runs the geometric labeler on it and takes
the classifier features of its points above the ground with their voxel's true class
(the majority of its points, collapsed to the classifier's six outputs). Fits the
perceptron of ``core/labeling/geometric_learned.py`` by L-BFGS (SciPy) on a class-weighted
cross-entropy, reports the accuracy on the last seed's drive (held out), and writes the
weights (docs/labels.md)::

    PYTHONPATH=$PWD .venv/bin/python scripts/train_labeler.py \\
        --out config/labels/geometric_classifier.npz
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.features import kernels
from mlsemreg_ros.core.labeling import geometric_learned as learned
from mlsemreg_ros.core.labeling.geometric import GeometricLabeler
from mlsemreg_ros.simulation.field import FieldConfig, FieldSimulation
import numpy as np
from scipy.optimize import minimize

OTHER = len(learned.CLASS_LEARNING_IDS)  # the "other" output (unlabeled)
CROP_SQUARE = 50.0  # m, half the side of the square pair files keep


def class_lut() -> np.ndarray:
    """Output class (0..5) of every learning id 0..255."""
    lut = np.full(256, OTHER, dtype=np.int64)
    for k, ids in enumerate(learned.CLASS_LEARNING_IDS):
        lut[list(ids)] = k
    return lut


def drive_scans(seed: int, frames: int, every: int, voxel: float) -> list[tuple]:
    """Voxel centroids (V, 3) and true classes (V,) of every ``every``-th sweep of a drive."""
    sim = FieldSimulation(FieldConfig(seed=seed, frames=frames, network_labels=False))
    lut = class_lut()
    scans = []
    for index in range(0, frames, every):
        scan = sim.frame(index).scan
        inverse, sums, sizes = kernels.voxel_grid(scan.points.astype(np.float64), voxel)
        votes = np.zeros((sizes.shape[0], OTHER + 1), dtype=np.int64)
        np.add.at(votes, (inverse, lut[scan.labels]), 1)
        scans.append((sums / sizes[:, None], votes.argmax(axis=1)))
    return scans


def samples(scans: list[tuple], crops: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """
    Features (n, F) and true classes (n,) of the voxels above the ground of ``scans``.

    Each scan is used whole and, for every height in ``crops``, cut to the points below
    that height in the sensor frame within a 50 m square (as pair files are cut).
    """
    labeler = GeometricLabeler(RegistrationConfig().geometric_labels)
    labeler.collect = {}
    xs, ys = [], []
    for points, truth in scans:
        keeps = [np.ones(len(points), bool)] + [
            (points[:, 2] <= z) & (np.abs(points[:, :2]).max(axis=1) <= CROP_SQUARE) for z in crops
        ]
        for keep in keeps:
            labeler.label(points[keep])
            xs.append(labeler.collect['features'])
            ys.append(truth[keep][labeler.collect['rows']])
    return np.concatenate(xs), np.concatenate(ys)


def train(
    x: np.ndarray, y: np.ndarray, hidden: int, iterations: int, decay: float, seed: int
) -> learned.VoxelClassifier:
    """Fit the perceptron on a class-weighted cross-entropy (weights ~ 1 / sqrt(count))."""
    classes = OTHER + 1
    mean = x.mean(axis=0)
    scale = np.maximum(x.std(axis=0), 1e-6)
    z = (x - mean) / scale
    counts = np.bincount(y, minlength=classes).astype(np.float64)
    weight_of = np.where(counts > 0, 1.0 / np.sqrt(np.maximum(counts, 1.0)), 0.0)
    weight_of[0] = 0.0  # ground above the segmentation's ground: not the classifier's to say
    w = weight_of[y]
    w /= w.sum()
    onehot = np.eye(classes)[y]
    f = x.shape[1]
    shapes = [(f, hidden), (hidden,), (hidden, classes), (classes,)]
    sizes = [int(np.prod(s)) for s in shapes]

    def unpack(theta: np.ndarray) -> list[np.ndarray]:
        parts = np.split(theta, np.cumsum(sizes)[:-1])
        return [p.reshape(s) for p, s in zip(parts, shapes, strict=True)]

    def loss(theta: np.ndarray) -> tuple[float, np.ndarray]:
        w1, b1, w2, b2 = unpack(theta)
        a = np.tanh(z @ w1 + b1)
        logits = a @ w2 + b2
        logits -= logits.max(axis=1, keepdims=True)
        p = np.exp(logits)
        p /= p.sum(axis=1, keepdims=True)
        value = -np.sum(w * np.log(np.maximum((p * onehot).sum(axis=1), 1e-12)))
        value += 0.5 * decay * (np.sum(w1**2) + np.sum(w2**2))
        d_logits = (p - onehot) * w[:, None]
        g_w2 = a.T @ d_logits + decay * w2
        g_b2 = d_logits.sum(axis=0)
        d_a = (d_logits @ w2.T) * (1.0 - a**2)
        g_w1 = z.T @ d_a + decay * w1
        g_b1 = d_a.sum(axis=0)
        return value, np.concatenate([g.ravel() for g in (g_w1, g_b1, g_w2, g_b2)])

    rng = np.random.default_rng(seed)
    theta = np.concatenate(
        [
            rng.normal(0, 1 / np.sqrt(f), sizes[0]),
            np.zeros(hidden),
            rng.normal(0, 1 / np.sqrt(hidden), sizes[2]),
            np.zeros(classes),
        ]
    )
    result = minimize(loss, theta, jac=True, method='L-BFGS-B', options={'maxiter': iterations})
    w1, b1, w2, b2 = unpack(result.x)
    return learned.VoxelClassifier(mean, scale, w1, b1, w2, b2)


def report(name: str, model: learned.VoxelClassifier, x: np.ndarray, y: np.ndarray) -> None:
    """Print accuracy and per-class recall / precision."""
    pred = model.probabilities(x).argmax(axis=1)
    names = ('ground', 'building', 'vegetation', 'pole', 'vehicle', 'other')
    cells = []
    for k, label in enumerate(names):
        truth, ours = y == k, pred == k
        recall = 100 * (truth & ours).sum() / max(truth.sum(), 1)
        precision = 100 * (truth & ours).sum() / max(ours.sum(), 1)
        cells.append(f'{label} {recall:.0f}/{precision:.0f}')
    print(
        f'{name}: accuracy {100 * (pred == y).mean():.1f} %, recall/precision: ' + ', '.join(cells)
    )


def main() -> None:
    """Render, train, report, write."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--seeds', default='1,2,3,4', help='drives; the last is held out')
    parser.add_argument('--frames', type=int, default=200)
    parser.add_argument('--every', type=int, default=10)
    parser.add_argument('--hidden', type=int, default=24)
    parser.add_argument('--iterations', type=int, default=400)
    parser.add_argument('--decay', type=float, default=1e-4)
    parser.add_argument('--crop', default='2.0', help='also train on scans cut below these z')
    parser.add_argument('--cache', type=Path, default=None, help='keep rendered sweeps here')
    parser.add_argument('--out', type=Path, default=Path('config/labels/geometric_classifier.npz'))
    args = parser.parse_args()
    voxel = RegistrationConfig().features.voxel_size
    seeds = [int(s) for s in args.seeds.split(',')]
    crops = tuple(float(z) for z in args.crop.split(',') if z)
    data = []
    for seed in seeds:
        cache = (
            args.cache / f'drive_s{seed}_f{args.frames}_e{args.every}.npz' if args.cache else None
        )
        if cache is not None and cache.exists():
            with np.load(cache) as z:
                scans = [(z[f'p{i}'], z[f't{i}']) for i in range(int(z['count']))]
        else:
            scans = drive_scans(seed, args.frames, args.every, voxel)
            if cache is not None:
                cache.parent.mkdir(parents=True, exist_ok=True)
                arrays = {f'p{i}': p for i, (p, _) in enumerate(scans)}
                arrays.update({f't{i}': t for i, (_, t) in enumerate(scans)})
                np.savez(cache, count=len(scans), **arrays)
        data.append(samples(scans, crops))
        print(
            f'seed {seed}: {len(data[-1][1])} samples, '
            f'classes {np.bincount(data[-1][1], minlength=OTHER + 1)}'
        )
    held = data[-1]
    x = np.concatenate([d[0] for d in data[:-1]] or [held[0]])
    y = np.concatenate([d[1] for d in data[:-1]] or [held[1]])
    model = train(x, y, args.hidden, args.iterations, args.decay, seed=0)
    report('train', model, x, y)
    report(f'held-out seed {seeds[-1]}', model, *held)
    # the shipped model is refitted on every drive
    model = train(
        np.concatenate([d[0] for d in data]),
        np.concatenate([d[1] for d in data]),
        args.hidden,
        args.iterations,
        args.decay,
        seed=0,
    )
    model.save(args.out, seeds=np.array(seeds), every=np.array(args.every))
    print(f'wrote {args.out} ({args.out.stat().st_size} bytes)')


if __name__ == '__main__':
    main()
