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
Recovery after refused scans: a seeded share of a bag's scans replaced by degenerate ones.

Each replaced scan is 3 points (stamp kept); the others go through the odometry as they
are. Counts the good scans right after a degenerate one that register within one and within
two scans, and the accepted poses outside 0.6 m / 5 deg of the ground truth (relative to
the scan the odometry started or last re-initialised on). Usage::

    PYTHONPATH=$PWD .venv/bin/python scripts/drop_scans.py BAG [BAG ...] --share 0.2 \\
        [--stride 1] [--seed 100]

The replacement and the recovery counting are :mod:`mlsemreg_ros.evaluation.drop_scans`'s, as in
``mlsemreg eval-bag BAG --drop-scans P`` (which replaces exactly ``round(P * n)`` scans and
judges each scan against its keyframe's truth; this script draws each scan with probability
P and judges poses from the origin, as the issue 29 table of docs/confidence.md did).
"""

from __future__ import annotations

import argparse

import numpy as np


def run(bag: str, share: float, stride: int, seed: int) -> dict[str, int]:
    """Replay ``bag`` with ``share`` of its scans degenerate; return the counts."""
    from mlsemreg_ros.core.metrics import rotation_error_deg
    from mlsemreg_ros.core.odometry import Odometry
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.core.rigid import invert_transform
    from mlsemreg_ros.datasets.factory import open_scan_source
    from mlsemreg_ros.evaluation.drop_scans import degenerate_scan, recovery_after

    scans = list(open_scan_source(bag).scans(stride=stride))
    drop = np.random.default_rng(seed).random(len(scans)) < share
    drop[0] = False
    odometry = Odometry(Registration())
    origin = None
    kinds: list[tuple[bool, bool]] = []  # (degenerate, registered right)
    counts = {'good': 0, 'right': 0, 'wrong': 0}
    for k, scan in enumerate(scans):
        if drop[k]:
            bad = degenerate_scan(scan)
            odometry.process(bad.xyz, bad.labels, bad.stamp_ns)
            kinds.append((True, False))
            continue
        step = odometry.process(scan.xyz, scan.labels, scan.stamp_ns, point_times=scan.point_times)
        if step.source in ('first', 'reinitialized'):
            origin = (scan.pose, step.pose)
        right = False
        if step.accepted and origin is not None and scan.pose is not None:
            truth = origin[1] @ invert_transform(origin[0]) @ scan.pose
            delta = invert_transform(truth) @ step.pose
            right = bool(
                np.linalg.norm(delta[:3, 3]) < 0.6
                and rotation_error_deg(delta[:3, :3], np.eye(3)) < 5.0
            )
            counts['wrong'] += not right
        counts['good'] += 1
        counts['right'] += right
        kinds.append((False, right))
    recovery = recovery_after(kinds)
    counts['after'] = recovery['after_degenerate']
    counts['within_1'] = recovery['recovered_within_1']
    counts['within_2'] = recovery['recovered_within_2']
    return counts


def main() -> None:
    """Print the counts of each bag and their sum."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('bags', nargs='+')
    parser.add_argument('--share', type=float, default=0.2)
    parser.add_argument('--stride', type=int, default=1)
    parser.add_argument('--seed', type=int, default=100)
    args = parser.parse_args()
    total: dict[str, int] = {}
    for i, bag in enumerate(args.bags):
        counts = run(bag, args.share, args.stride, args.seed + i)
        print(bag, counts, flush=True)
        total = {k: total.get(k, 0) + v for k, v in counts.items()}
    print(f'share {args.share} stride {args.stride}: {total}')


if __name__ == '__main__':
    main()
