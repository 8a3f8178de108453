#!/usr/bin/env python3
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
Building or vegetation from context: does any context feature separate them better than the rules.

For every scan of the pair files (``pts_src`` and ``pts_dst``), the points that the geometric
labeler calls building (50) or vegetation (70) and that the pair file's network labels call
building / fence (learning ids 13, 14) or vegetation / trunk / terrain (15-17). Per range
band: the points, the true building share, the rules' accuracy, building recall and
precision; then, per context feature, the best accuracy of one threshold (either side):

- ``thickness`` and ``linearity``: the 2D covariance of the above-ground points in the
  ``(2 radius + 1)^2`` window of ``--cell`` columns around each point's column (a facade
  is a thin straight line seen from above, a hedge or a crown a thick one);
- ``run_length`` and ``run_linearity``: the same of the columns the rules call building
  only (a facade is a long straight run of vertical cells), for the building points;
- ``column_top``: the highest point above the ground in the point's 1 m column.

A feature beats the rules only where its accuracy exceeds both the rules' and the majority
share (``1 - building share``: calling everything vegetation).

Usage (docs/labels.md)::

    PYTHONPATH=$PWD .venv/bin/python scripts/building_context.py PAIR_DIR [--cell 0.5] \\
        [--radius 1]
"""

from __future__ import annotations

import argparse
import itertools
from pathlib import Path

from mlsemreg_ros.core.labeling import geometric
from mlsemreg_ros.datasets.pairs import load_pair
import numpy as np

BUILDING_IDS = (13, 14)  # learning ids: building, fence
VEGETATION_IDS = (15, 16, 17)  # vegetation, trunk, terrain
BANDS = (0.0, 10.0, 20.0, 40.0, 100.0)
FEATURES = ('thickness', 'linearity', 'run_length', 'run_linearity', 'column_top')


def window_shape(points: np.ndarray, rows: np.ndarray, size: float, radius: int) -> np.ndarray:
    """
    Per point of ``rows``: 2D thickness (m), linearity and extent (m) of its window.

    The 2D covariance of the points of the ``(2 radius + 1)^2`` columns of ``size`` around
    each point's column (window sums of the moments, as the labeler's column windows);
    thickness is the square root of the smaller eigenvalue, extent ``sqrt(12 l1)`` (the
    length of a uniform run).
    """
    out = np.full((rows.shape[0], 3), np.nan)
    if rows.shape[0] == 0:
        return out
    xy = points[rows, :2] - points[rows, :2].mean(axis=0)
    columns = geometric.Columns.of(points[rows], size)
    moments = (
        np.ones(rows.shape[0]),
        xy[:, 0],
        xy[:, 1],
        xy[:, 0] ** 2,
        xy[:, 1] ** 2,
        xy[:, 0] * xy[:, 1],
    )
    sums = [
        columns.window_sum(np.bincount(columns.index, m, columns.count), radius) for m in moments
    ]
    count = np.maximum(sums[0], 1.0)
    mx, my = sums[1] / count, sums[2] / count
    cxx, cyy, cxy = sums[3] / count - mx * mx, sums[4] / count - my * my, sums[5] / count - mx * my
    half_trace = (cxx + cyy) / 2
    disc = np.sqrt(np.maximum(half_trace**2 - (cxx * cyy - cxy * cxy), 0.0))
    major, minor = half_trace + disc, np.maximum(half_trace - disc, 0.0)
    shape = np.stack(
        [np.sqrt(minor), (major - minor) / np.maximum(major, 1e-12), np.sqrt(12 * major)], 1
    )
    return shape[columns.index]


def scan_rows(
    labeler: geometric.GeometricLabeler,
    points: np.ndarray,
    truth: np.ndarray,
    cell: float,
    radius: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(is building (K,), rules say building (K,), range m (K,), features (K, F))``."""
    raw = labeler.label(points).raw
    height = labeler._ground(points)[0]  # the labeler's heights above the ground
    above = np.flatnonzero((raw != geometric.UNLABELED) & (raw != geometric.ROAD))
    building = np.flatnonzero(raw == geometric.BUILDING)
    features = np.full((points.shape[0], len(FEATURES)), np.nan)
    features[above, :2] = window_shape(points, above, cell, radius)[:, :2]
    run = window_shape(points, building, cell, radius)
    features[building, 2], features[building, 3] = run[:, 2], run[:, 1]
    columns = geometric.Columns.of(points[above], 1.0)
    top = np.full(columns.count, -np.inf)
    np.maximum.at(top, columns.index, height[above])
    features[above, 4] = top[columns.index]
    true_building = np.isin(truth, BUILDING_IDS)
    chosen = np.isin(raw, (geometric.BUILDING, geometric.VEGETATION)) & (
        true_building | np.isin(truth, VEGETATION_IDS)
    )
    return (
        true_building[chosen],
        raw[chosen] == geometric.BUILDING,
        np.linalg.norm(points[chosen, :2], axis=1),
        features[chosen],
    )


def best_threshold(values: np.ndarray, is_building: np.ndarray) -> tuple[float, str]:
    """Best accuracy of one threshold on ``values`` (either side), and the rule as text."""
    finite = np.isfinite(values)
    if finite.sum() < 10:
        return float('nan'), ''
    x, y = values[finite], is_building[finite]
    best, text = -1.0, ''
    for threshold in np.unique(np.quantile(x, np.linspace(0.02, 0.98, 49))):
        for side, building in (('>=', x >= threshold), ('<', x < threshold)):
            accuracy = float(np.mean(building == y))
            if accuracy > best:
                best, text = accuracy, f'building if {side} {threshold:.3g}'
    return best, text


def main() -> None:
    """Print the rules' and the context features' accuracy per range band."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('pairs', type=Path)
    parser.add_argument('--cell', type=float, default=0.5, help='column size, m')
    parser.add_argument('--radius', type=int, default=1, help='window radius, columns')
    args = parser.parse_args()
    rows: list[list[np.ndarray]] = [[] for _ in range(4)]
    labeler = geometric.GeometricLabeler()
    for file in sorted(args.pairs.glob('*.npz')):
        pair = load_pair(file)
        for points, truth in ((pair.pts_src, pair.label_src), (pair.pts_dst, pair.label_dst)):
            found = scan_rows(labeler, points, np.asarray(truth), args.cell, args.radius)
            for store, value in zip(rows, found, strict=True):
                store.append(value)
    is_building, rules, distance, features = (np.concatenate(r) for r in rows)
    print(f'{args.pairs.name}: building vs vegetation, {is_building.shape[0]} points')
    print('(run_length and run_linearity over the points the rules call building only:')
    print(" compare them with the rules' precision there)")
    bands = [*itertools.pairwise(BANDS), (BANDS[0], BANDS[-1])]
    for low, high in bands:
        band = (distance >= low) & (distance < high)
        y, r = is_building[band], rules[band]
        if not band.any():
            continue
        cells = [
            f'{low:.0f}-{high:.0f} m: {band.sum():6d} points, building {y.mean():.2f} '
            f'(all vegetation: accuracy {1 - y.mean():.3f})',
            f'rules: accuracy {np.mean(r == y):.3f}, building recall {r[y].mean():.2f}, '
            f'precision {y[r].mean() if r.any() else float("nan"):.2f}',
        ]
        for j, name in enumerate(FEATURES):
            accuracy, text = best_threshold(features[band, j], y)
            cells.append(f'{name} {accuracy:.3f} ({text})')
        print('\n    '.join(cells))


if __name__ == '__main__':
    main()
