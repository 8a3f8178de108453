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
Where the geometric labels go wrong: their confusion against the 5-class collapse.

For every scan of the pair files (``pts_src`` and ``pts_dst``), the geometric labels
(``label_source: geometric``, with ``--set`` overrides) against the pair file's labels
collapsed to the five classes geometry can tell (``label_ir.collapse``). Prints the
row-normalised confusion (truth rows, geometric columns, % of the row), each class's
precision, and the recall of each class per range band.

Usage (docs/labels.md)::

    PYTHONPATH=$PWD .venv/bin/python scripts/label_confusion.py PAIR_DIR \\
        [--set geometric_labels.vehicle_max_length=6.5]
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.labeling.source import LabelSource
from mlsemreg_ros.datasets.pairs import load_pair
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from label_ir import collapse, geometric_both

CLASSES = {
    9: 'ground',
    13: 'building',
    15: 'vegetation',
    18: 'pole/trunk',
    1: 'vehicle',
    0: 'unlab.',
}
BANDS = (0.0, 10.0, 20.0, 35.0, 80.0)


def confusion_by_band(points: np.ndarray, truth: np.ndarray, ours: np.ndarray) -> np.ndarray:
    """
    Counts (bands, C, C) of (truth, ours) pairs per range band of :data:`BANDS`.

    ``truth`` and ``ours`` (N,) are collapsed ids (keys of :data:`CLASSES`, anything else
    counts as unlabeled); rows and columns follow the order of :data:`CLASSES`.
    """
    lut = np.full(256, list(CLASSES).index(0), dtype=np.int64)
    for i, c in enumerate(CLASSES):
        lut[c] = i
    band = np.digitize(np.linalg.norm(points[:, :2], axis=1), BANDS[1:-1])
    out = np.zeros((len(BANDS) - 1, len(CLASSES), len(CLASSES)))
    np.add.at(out, (band, lut[np.clip(truth, 0, 255)], lut[np.clip(ours, 0, 255)]), 1)
    return out


def main() -> None:
    """Print the confusion, precision and per-band recall over the pair files' scans."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('pairs', type=Path)
    parser.add_argument('--set', action='append', default=[], help='KEY=VALUE override')
    args = parser.parse_args()
    overrides = dict(item.split('=', 1) for item in args.set)
    config = RegistrationConfig().replace({'label_source': 'geometric', **overrides})
    source = LabelSource()
    ids = list(CLASSES)
    confusion = np.zeros((len(BANDS) - 1, len(ids), len(ids)))
    for file in sorted(args.pairs.glob('*.npz')):
        pair = load_pair(file)
        for points, field in ((pair.pts_src, pair.label_src), (pair.pts_dst, pair.label_dst)):
            truth = collapse(np.asarray(field))
            ours = collapse(geometric_both(source, config, points)[0])
            confusion += confusion_by_band(points, truth, ours)
    total = confusion.sum(axis=0)
    names = [CLASSES[c] for c in ids]
    print('truth \\ ours  ' + ' '.join(f'{n:>10s}' for n in names) + '   points')
    for i, name in enumerate(names[:-1]):
        row = total[i] / max(total[i].sum(), 1) * 100
        print(f'{name:12s} ' + ' '.join(f'{v:10.1f}' for v in row) + f'  {int(total[i].sum()):7d}')
    precision = np.diag(total) / np.maximum(total[:-1].sum(axis=0), 1) * 100
    print('precision    ' + ' '.join(f'{v:10.1f}' for v in precision[:-1]))
    recall = np.diag(total)[:-1] / np.maximum(total[:-1].sum(axis=1), 1) * 100
    f1 = 2 * precision[:-1] * recall / np.maximum(precision[:-1] + recall, 1e-9)
    print('F1           ' + ' '.join(f'{v:10.1f}' for v in f1))
    print(f'accuracy {np.trace(total[:-1, :-1]) / total[:-1].sum() * 100:.1f} %')
    print(
        'recall per range band (m): '
        + ', '.join(f'{BANDS[b]:g}-{BANDS[b + 1]:g}' for b in range(len(BANDS) - 1))
    )
    for i, name in enumerate(names[:-1]):
        cells = []
        for b in range(len(BANDS) - 1):
            n = confusion[b, i].sum()
            cells.append(f'{100 * confusion[b, i, i] / max(n, 1):5.1f} ({int(n):6d})')
        print(f'  {name:12s} ' + '  '.join(cells))


if __name__ == '__main__':
    main()
