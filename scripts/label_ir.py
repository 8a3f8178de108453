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
What labels are worth to the matching: the correspondences' inlier ratio per label variant.

Matching only (ML-SemReg's Group and Mask Matching, defaults), no estimation: for every pair
file, the share of correspondences within ``evaluation.inlier_threshold`` of each other at
the true pose (IR, %), the inliers and the correspondences, for the labels

- ``field``: the pair file's labels;
- ``collapse``: the pair file's labels collapsed to the five classes geometry can tell
  (ground, building + fence, vegetation, pole + trunk + sign, vehicle): the geometric
  labeler's ceiling;
- ``geometric``: the geometric labeler's (``label_source: geometric``);
- ``top2``: the geometric labels, every keypoint also in the groups of its points'
  runner-up classes (``GeometricLabels.second``);
- ``union``: the geometric labels' correspondences united with plain matching (the
  widening of poorer labels, ``quality.widened``);
- ``none``: no labels.

Each cell also gives the scans' BMR-SS landmarks and how many of the source's are **found
again**: a target landmark of the same class within ``RECUR_DISTANCE`` (xy) at the true
pose (Mask Matching compares the same landmarks across scans; docs/labels.md).

Usage (docs/labels.md)::

    PYTHONPATH=$PWD .venv/bin/python scripts/label_ir.py PAIR_DIR [--descriptor gedi] \\
        [--reverse] [--labels field,collapse,geometric,top2,union,none] \\
        [--set geometric_labels.vehicle_max_length=6.5]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.features import kernels
from mlsemreg_ros.core.labeling import quality
from mlsemreg_ros.core.labeling.source import LabelSource
from mlsemreg_ros.core.matching import matching, signatures
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.results import Landmarks
from mlsemreg_ros.datasets.pairs import load_pair
from mlsemreg_ros.evaluation.settings import EvaluationSettings
import numpy as np
from scipy.spatial import cKDTree

#: The five classes geometry can tell, as groups of learning ids (the collapse's target id).
FIVE_CLASSES = {
    9: (9, 10, 11, 12, 17),  # ground: road, parking, sidewalk, other-ground, terrain
    13: (13, 14),  # building + fence
    15: (15,),  # vegetation
    18: (16, 18, 19),  # trunk + pole + traffic-sign
    1: (1, 2, 3, 4, 5),  # vehicles
}
VARIANTS = ('field', 'collapse', 'geometric', 'top2', 'union', 'none')
#: A source landmark is found again when the target has one of its class this near (xy, m).
RECUR_DISTANCE = 1.0


def collapse(labels: np.ndarray) -> np.ndarray:
    """Learning ids collapsed to :data:`FIVE_CLASSES` (everything else unlabeled)."""
    out = np.zeros(len(labels), dtype=np.int64)
    for target, ids in FIVE_CLASSES.items():
        out[np.isin(labels, ids)] = target
    return out


def recurring(source: Landmarks, target: Landmarks, truth: np.ndarray) -> int:
    """Source landmarks with a target landmark of their class within RECUR_DISTANCE (xy)."""
    if len(source) == 0 or len(target) == 0:
        return 0
    moved = source.centroids @ truth[:3, :3].T + truth[:3, 3]
    found = 0
    for cls in np.unique(source.classes):
        theirs = target.centroids[target.classes == cls]
        if len(theirs):
            gap, _ = cKDTree(theirs[:, :2]).query(moved[source.classes == cls, :2])
            found += int((gap < RECUR_DISTANCE).sum())
    return found


def geometric_both(
    source: LabelSource, config: RegistrationConfig, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Geometric labels and runner-up classes (learning ids) of ``points``, per voxel."""
    inverse, sums, sizes = kernels.voxel_grid(points, config.features.voxel_size)
    out = source.labeler(config).label(sums / sizes[:, None])
    lut = source.label_map.raw_lut
    return lut[out.raw[inverse]].astype(np.int64), lut[out.second[inverse]].astype(np.int64)


def main() -> None:
    """Print IR / inliers / correspondences per pair and their means per label variant."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('pairs', type=Path)
    parser.add_argument('--descriptor', choices=('fpfh', 'gedi'), default='fpfh')
    parser.add_argument('--reverse', action='store_true', help='register dst onto src')
    parser.add_argument('--labels', default=','.join(VARIANTS))
    parser.add_argument('--set', action='append', default=[], help='KEY=VALUE override')
    args = parser.parse_args()
    variants = args.labels.split(',')
    overrides = dict(item.split('=', 1) for item in args.set)
    config = RegistrationConfig().replace({'label_source': 'geometric', **overrides})
    registration = Registration(config)
    source = LabelSource(registration.label_map)
    threshold = EvaluationSettings().evaluation.inlier_threshold
    semantic, kind = config.semantic, config.matcher.kind
    rows: dict[str, list[tuple[int, ...]]] = {v: [] for v in variants}
    for file in sorted(args.pairs.glob('*.npz')):
        pair = load_pair(file)
        gedi = pair.descriptors('gedi') if args.descriptor == 'gedi' else (None, None)
        sides = [
            (pair.pts_src, pair.label_src, pair.kpts_src, gedi[0]),
            (pair.pts_dst, pair.label_dst, pair.kpts_dst, gedi[1]),
        ]
        truth = pair.trans_gt
        if args.reverse:
            sides, truth = sides[::-1], np.linalg.inv(truth)
        # descriptors once per scan (FPFH does not depend on the labels)
        plain = [
            registration.prepare(
                p, np.zeros(len(p), np.int64), keypoints=k, descriptors=d, voxelize=False
            )
            for p, _, k, d in sides
        ]
        geometric = [geometric_both(source, config, p) for p, *_ in sides]
        for variant in variants:
            scans = []
            for (points, field, _, _), base, (first, second) in zip(
                sides, plain, geometric, strict=True
            ):
                labels = {
                    'field': field,
                    'collapse': collapse(np.asarray(field)),
                    'none': np.zeros(len(points), np.int64),
                }.get(variant, first)
                scan = registration.prepare(
                    points,
                    labels,
                    keypoints=base.keypoints,
                    descriptors=base.descriptors,
                    voxelize=False,
                )
                if variant == 'top2':
                    scan.local_ss = scan.local_ss | signatures.local_semantic_signature(
                        points,
                        second,
                        scan.keypoints,
                        semantic.local_radius,
                        registration.label_map.num_classes,
                        ignored=registration._ignored_ids,
                        undefined=registration._undefined_ids,
                    )
                scans.append(scan)
            corr = matching.ml_semreg(scans[0], scans[1], semantic, kind).correspondences
            if variant == 'union':
                corr = quality.widened(
                    corr,
                    matching.match_descriptors(scans[0].descriptors, scans[1].descriptors, kind),
                )
            moved = scans[0].keypoints[corr.source] @ truth[:3, :3].T + truth[:3, 3]
            gap = np.linalg.norm(moved - scans[1].keypoints[corr.target], axis=1)
            marks = scans[0].landmarks, scans[1].landmarks
            rows[variant].append(
                (
                    int((gap < threshold).sum()),
                    len(corr),
                    len(marks[0]),
                    len(marks[1]),
                    recurring(marks[0], marks[1], truth),
                )
            )
        print(
            file.stem,
            '  '.join(
                f'{v} {100 * i / max(n, 1):.2f} % ({i}/{n}, landmarks {a}/{b} found {f})'
                for v in variants
                for i, n, a, b, f in rows[v][-1:]
            ),
            flush=True,
        )
    print(
        f'{args.pairs.name} {args.descriptor}{" reversed" if args.reverse else ""}: '
        'mean IR % / inliers / correspondences, median inliers, pairs with '
        'estimator.min_inliers, source landmarks found again / all'
    )
    least = config.estimator.min_inliers
    for variant in variants:
        values = np.array(rows[variant], dtype=float).reshape(-1, 5)
        ratio = 100 * values[:, 0] / np.maximum(values[:, 1], 1)
        print(
            f'  {variant:10s} {ratio.mean():6.2f}  {values[:, 0].mean():7.1f}  '
            f'{values[:, 1].mean():7.0f}  {np.median(values[:, 0]):6.0f}  '
            f'{int((values[:, 0] >= least).sum()):3d}  '
            f'{int(values[:, 4].sum())}/{int(values[:, 2].sum())}'
        )


if __name__ == '__main__':
    main()
