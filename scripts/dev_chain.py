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
The real KITTI dev chain streamed through the odometry (scans about 20 m apart), issue 29.

The 11 scans of the chained dev pairs (``pts_dst`` of one pair is ``pts_src`` of the next) go
through ``Odometry`` at 10 Hz stamps with the default parameters. ``--degenerate first``
sends a 3-point scan first; ``insert:K`` sends one between scans K-1 and K (half an interval
after K-1); ``replace:K`` sends it in place of scan K (its stamp; the next scan is then about
40 m from the map). Each accepted scan is judged by its pose relative to the last accepted
one (right within 0.6 m / 5 deg of the truth). Usage::

    PYTHONPATH=$PWD .venv/bin/python scripts/dev_chain.py [DIR] \\
        [--degenerate first|insert:5|replace:5] [--set near_miss.enabled=false]
"""

from __future__ import annotations

import argparse

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry import Odometry
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.rigid import rotation_angle_deg
from mlsemreg_ros.core.settings import parse_overrides
from mlsemreg_ros.datasets.pairs import dev_pairs_dir, list_pairs, load_pair
import numpy as np

DEGENERATE = (np.array([[5.0, 0.0, 0.0], [0.0, 5.0, 0.0], [5.0, 5.0, 1.0]]), np.full(3, 40))
INTERVAL_NS = 100_000_000


def chain(directory: str) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[np.ndarray]]:
    """Return the chain's scans and their poses in the first scan's frame."""
    pairs = [load_pair(path) for path in list_pairs(directory)]
    scans = [(pairs[0].pts_src, pairs[0].label_src)] + [(p.pts_dst, p.label_dst) for p in pairs]
    poses = [np.eye(4)]
    for pair in pairs:  # trans_gt: T_dst_src
        poses.append(poses[-1] @ np.linalg.inv(pair.trans_gt))
    return scans, poses


def feed(scans: list, degenerate: str) -> list[tuple[int | None, tuple, int]]:
    """Return (chain index or None, (points, labels), stamp ns) in the order sent."""
    kind, _, at = degenerate.partition(':')
    k_at = int(at) if at else -1
    out, stamp = [], 0
    if kind == 'first':
        stamp += INTERVAL_NS
        out.append((None, DEGENERATE, stamp))
    for k, scan in enumerate(scans):
        if kind == 'insert' and k == k_at:
            out.append((None, DEGENERATE, stamp + INTERVAL_NS // 2))
        stamp += INTERVAL_NS
        if kind == 'replace' and k == k_at:
            out.append((None, DEGENERATE, stamp))
            continue
        out.append((k, scan, stamp))
    return out


def main() -> None:
    """Stream the chain; print each scan's verdict and the counts."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('directory', nargs='?', default=str(dev_pairs_dir()))
    parser.add_argument('--degenerate', default='', help='first, insert:K or replace:K')
    parser.add_argument('--set', action='append', default=[], help='section.key=value')
    args = parser.parse_args()
    config = RegistrationConfig().replace(parse_overrides(args.set))
    scans, poses = chain(args.directory)
    odometry = Odometry(Registration(config))
    last, right, wrong = None, 0, 0
    for k, (points, labels), stamp in feed(scans, args.degenerate):
        step = odometry.process(points, labels, stamp)
        verdict = ''
        if k is not None and step.accepted:
            if last is None:
                ok = True
            else:
                truth = np.linalg.inv(poses[last[0]]) @ poses[k]
                error = np.linalg.solve(truth, np.linalg.inv(last[1]) @ step.pose)
                te, re = float(np.linalg.norm(error[:3, 3])), rotation_angle_deg(error)
                ok = te <= 0.6 and re <= 5.0
                verdict = f'{te:.2f} m / {re:.2f} deg '
            right, wrong = right + ok, wrong + (not ok)
            verdict += 'right' if ok else 'WRONG'
            last = (k, step.pose)
        name = 'degenerate' if k is None else f'scan {k}'
        state = f'accepted ({step.source})' if step.accepted else 'refused'
        print(f'{name}: {state} {verdict} | {step.reason[:160]}')
    print(f'{right} right, {wrong} wrong of {len(scans)} chain scans')


if __name__ == '__main__':
    main()
