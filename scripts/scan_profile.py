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
Where a scan's time goes: cProfile's call tree of the odometry, per scan, after a warm-up.

The scans after ``--warmup`` (the first load the compiled kernels) run through our odometry
alone under cProfile with the CPU clock (``--clock cpu``, ``time.process_time``: compare with
``--threads 1`` and ``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1``) or the wall clock; the tree
below ``Odometry.process`` is printed in ms per profiled scan, down to ``--min-ms``. A call
on both cores counts its CPU once per core with the CPU clock. Usage::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 PYTHONPATH=$PWD nice -n 5 \\
        .venv/bin/python scripts/scan_profile.py BAG [--frames 48] [--threads 1] \\
        [--clock cpu] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time
from typing import Any

import numpy as np

Function = tuple[str, int, str]


def print_tree(stats: pstats.Stats, root: tuple[str, str], scans: int, min_ms: float) -> None:
    """Print the callees of ``root`` (file suffix, function name), ms per scan, nested."""
    table: dict[Function, Any] = stats.stats  # type: ignore[attr-defined]
    callees: dict[Function, list[tuple[Function, tuple]]] = {}
    for function, (*_, callers) in table.items():
        for caller, edge in callers.items():
            callees.setdefault(caller, []).append((function, edge))

    def name(f: Function) -> str:
        return f'{f[0].split("/")[-1]}:{f[1]}({f[2]})'

    def show(f: Function, depth: int, seconds: float, seen: frozenset) -> None:
        print(f'{"  " * depth}{1e3 * seconds / scans:7.2f}  {name(f)}')
        if depth > 8 or f in seen:
            return
        for g, edge in sorted(callees.get(f, []), key=lambda x: -x[1][3]):
            if 1e3 * edge[3] / scans >= min_ms:
                show(g, depth + 1, edge[3], seen | {f})

    roots = [f for f in table if f[0].endswith(root[0]) and f[2] == root[1]]
    if roots:
        show(roots[0], 0, table[roots[0]][3], frozenset())


def main() -> int:
    """Profile the scans after the warm-up and print the medians and the call tree."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('bag')
    parser.add_argument('--frames', type=int, default=48)
    parser.add_argument('--warmup', type=int, default=8, help='scans before the profile')
    parser.add_argument('--threads', type=int, default=1, help='ours (0: all cores)')
    parser.add_argument('--clock', choices=('cpu', 'wall'), default='cpu')
    parser.add_argument('--min-ms', type=float, default=0.15, help='smallest call shown')
    parser.add_argument('--set', nargs='*', default=[], metavar='KEY=VALUE')
    args = parser.parse_args()

    from mlsemreg_ros.core.config import load_settings, RegistrationConfig
    from mlsemreg_ros.core.odometry import Odometry
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.datasets.factory import open_scan_source
    from mlsemreg_ros.evaluation.estimators import OdometryEstimator

    (core,) = load_settings((RegistrationConfig,), None, [f'threads={args.threads}', *args.set])
    source = open_scan_source(args.bag)
    try:
        scans = list(source.scans(1, args.frames))
    finally:
        source.close()
    ours = OdometryEstimator(Odometry(Registration(core)))
    profile = cProfile.Profile(time.process_time if args.clock == 'cpu' else time.perf_counter)
    rows, sources = [], {}
    for k, scan in enumerate(scans):
        cpu, wall = time.process_time(), time.perf_counter()
        if k >= args.warmup:
            profile.enable()
        estimate = ours.step(scan)
        profile.disable()
        if k >= args.warmup:
            rows.append((time.process_time() - cpu, time.perf_counter() - wall))
            sources[estimate.mode] = sources.get(estimate.mode, 0) + 1
    profiled = max(len(rows), 1)
    cpu_ms, wall_ms = 1e3 * np.median(np.array(rows), axis=0)
    print(
        f'{args.bag}: {profiled} scans profiled {sources}; median CPU {cpu_ms:.1f} ms, '
        f'wall {wall_ms:.1f} ms (with the profiler)'
    )
    print(f'ms per profiled scan ({args.clock} clock):')
    print_tree(pstats.Stats(profile), ('odometry/odometry.py', 'process'), profiled, args.min_ms)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
