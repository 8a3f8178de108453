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
The odometry's wall time per scan under thread settings, against KISS-ICP's, in one run.

Each variant is its own odometry in this process, fed the same scans in turn with KISS-ICP
(default threads), the order rotating scan by scan, so that a loaded machine slows every side
alike. A variant sets the core's ``threads`` (pools and small_gicp's OpenMP threads) and may
cap BLAS's and OpenMP's threads through threadpoolctl while its scan runs:

- ``t0``: the default (``threads: 0``, all cores); ``t1``, ``t2``: ``threads`` 1, 2;
- ``t0blas1``: ``threads: 0`` with BLAS on one thread; ``t1all1``: ``threads: 1`` with BLAS
  and OpenMP on one thread.

It prints each side's wall and CPU p50 per scan (the first scan left out) and its ratio to
KISS-ICP's, and how far each variant's poses are from the first variant's. Usage::

    PYTHONPATH=$PWD nice -n 5 .venv/bin/python scripts/thread_variants.py BAG \\
        [--frames 60] [--variants t0 t1 t0blas1]
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

#: variant -> (the core's ``threads``, BLAS thread cap, OpenMP thread cap); None: no cap.
VARIANTS = {
    't0': (0, None, None),
    't1': (1, None, None),
    't2': (2, None, None),
    't0blas1': (0, 1, None),
    't1all1': (1, 1, 1),
}


def load_scans(bag: str, frames: int, core: Any) -> list[Any]:
    """Return the first ``frames`` scans of ``bag``."""
    from mlsemreg_ros.datasets.factory import open_scan_source

    source = open_scan_source(
        bag,
        points_topic=None,
        label_field='label',
        gt_topic='/ground_truth/odometry',
        time_field=core.preprocess.time_field,
        time_unit=core.preprocess.time_unit,
    )
    scans = []
    for scan in source.scans(1, frames):
        scans.append(scan)
        if len(scans) >= frames:
            break
    source.close()
    return scans


def main() -> int:
    """Run the variants and KISS-ICP scan by scan; print the medians."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('bag')
    parser.add_argument('--frames', type=int, default=60)
    parser.add_argument('--variants', nargs='+', default=['t0', 't1'], choices=sorted(VARIANTS))
    args = parser.parse_args()

    from mlsemreg_ros.core import threads
    from mlsemreg_ros.core.config import load_settings, RegistrationConfig
    from mlsemreg_ros.core.odometry import Odometry
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.evaluation.estimators import KissIcpEstimator, OdometryEstimator
    from mlsemreg_ros.evaluation.settings import EvaluationSettings
    from threadpoolctl import ThreadpoolController

    controller = ThreadpoolController()
    core, _ = load_settings((RegistrationConfig, EvaluationSettings), None, [])
    scans = load_scans(args.bag, args.frames, core)
    sides: dict[str, Any] = {}
    for name in args.variants:
        threads.configure(VARIANTS[name][0])
        sides[name] = OdometryEstimator(Odometry(Registration(core)))
    sides['kiss-icp'] = KissIcpEstimator()
    names = list(sides)
    wall: dict[str, list[float]] = {n: [] for n in names}
    cpu: dict[str, list[float]] = {n: [] for n in names}
    poses: dict[str, list[np.ndarray]] = {n: [] for n in names}
    for i, scan in enumerate(scans):
        for name in names[i % len(names) :] + names[: i % len(names)]:
            count, blas, omp = VARIANTS.get(name, (0, None, None))
            threads.configure(count)
            caps = [
                controller.limit(limits=limit, user_api=api)
                for api, limit in (('blas', blas), ('openmp', omp))
                if limit is not None
            ]
            tic_cpu, tic_wall = time.process_time(), time.perf_counter()
            estimate = sides[name].step(scan)
            toc_cpu, toc_wall = time.process_time(), time.perf_counter()
            for cap in caps:
                cap.restore_original_limits()
            wall[name].append(1e3 * (toc_wall - tic_wall))
            cpu[name].append(1e3 * (toc_cpu - tic_cpu))
            poses[name].append(np.asarray(estimate.pose, dtype=np.float64))
    kiss_wall, kiss_cpu = np.median(wall['kiss-icp'][1:]), np.median(cpu['kiss-icp'][1:])
    for name in names:
        w, c = np.median(wall[name][1:]), np.median(cpu[name][1:])
        pairs = zip(poses[name], poses[names[0]], strict=True)
        apart = max(float(np.abs(a - b).max()) for a, b in pairs)
        print(
            f'{name:9s} wall p50 {w:7.1f} ms = {w / kiss_wall:.2f}x KISS-ICP  '
            f'cpu p50 {c:7.1f} ms = {c / kiss_cpu:.2f}x  poses vs {names[0]}: {apart:.1e}'
        )
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
