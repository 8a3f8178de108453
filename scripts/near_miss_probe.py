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
Near-miss probe: the pair fine alignment started off the truth; where it lands, and the check.

For each pair file of DIR, the pair GICP starts from the ground truth moved by 2 m (with a
3 deg yaw) and by 3 m, in 4 directions; each landing is judged right or wrong (0.6 m / 5 deg)
and by the near-miss check (core/alignment/near_miss.py, ``near_miss.*``): right landings
refused are the check's cost, wrong landings kept are what it misses. Usage::

    PYTHONPATH=$PWD .venv/bin/python scripts/near_miss_probe.py DIR [--set near_miss.starts=2]
"""

from __future__ import annotations

import argparse
import dataclasses

from mlsemreg_ros.core.alignment.alignment import align_pair
from mlsemreg_ros.core.alignment.fine_alignment import alignment_cloud
from mlsemreg_ros.core.alignment.near_miss import (
    home_first,
    judge_basins,
    PointToDistribution,
)
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.rigid import rotation_angle_deg
from mlsemreg_ros.core.settings import parse_overrides
from mlsemreg_ros.datasets.pairs import list_pairs, load_pair
import numpy as np

STARTS = ((2.0, 3.0), (3.0, 0.0))  # (m off the truth, yaw deg)
DIRECTIONS = 4


def probe(path: str, registration: Registration) -> list[tuple[float, float, bool]]:
    """Return (TE m, RE deg, refused) of every landing from a start off the truth."""
    cfg, pair = registration.config, load_pair(path)
    source, target = registration.prepare_scans(
        {
            'points': pair.pts_src,
            'labels': pair.label_src,
            'keypoints': pair.kpts_src,
            'voxelize': False,
        },
        {
            'points': pair.pts_dst,
            'labels': pair.label_dst,
            'keypoints': pair.kpts_dst,
            'voxelize': False,
        },
    )
    s, t = (
        alignment_cloud(source, cfg.fine, pair=True),
        alignment_cloud(target, cfg.fine, pair=True),
    )
    fit = PointToDistribution(s, t, cfg.fine.max_correspondence_distance)

    def align(T: np.ndarray, iterations: int = cfg.fine.max_iterations):
        fine = dataclasses.replace(cfg.fine, max_iterations=iterations)
        return align_pair(s, t, T, fine, cfg.fine.pair_method)

    out = []
    for k in range(DIRECTIONS):
        angle = 2 * np.pi * k / DIRECTIONS
        for distance, yaw in STARTS:
            step = np.eye(4)
            c, n = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
            step[:2, :2] = [[c, -n], [n, c]]
            step[:2, 3] = distance * np.array([np.cos(angle), np.sin(angle)])
            landed = align(pair.trans_gt @ step)
            error = np.linalg.solve(pair.trans_gt, landed.T_target_source)
            # the starts as the pair stage runs them (near_miss.home_iterations)
            starts = home_first(align, landed, cfg.near_miss, cfg.fine.max_iterations)
            verdict = judge_basins(landed, starts, fit, cfg.near_miss)
            out.append(
                (
                    float(np.linalg.norm(error[:3, 3])),
                    rotation_angle_deg(error),
                    bool(verdict.refusal),
                )
            )
    return out


def main() -> None:
    """Print each landing off the truth and the counts."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('directory')
    parser.add_argument('--set', action='append', default=[], help='section.key=value')
    args = parser.parse_args()
    config = RegistrationConfig().replace(parse_overrides(args.set))
    registration = Registration(config)
    counts = {'right kept': 0, 'right refused': 0, 'wrong kept': 0, 'wrong refused': 0}
    for path in list_pairs(args.directory):
        for te, re, refused in probe(path, registration):
            right = te <= 0.6 and re <= 5.0
            key = f'{"right" if right else "wrong"} {"refused" if refused else "kept"}'
            counts[key] += 1
            if not (right and not refused and te < 0.3):
                print(f'{path.stem}: landed {te:.2f} m / {re:.2f} deg, {key}')
    print(counts)


if __name__ == '__main__':
    main()
