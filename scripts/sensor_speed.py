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
Where the odometry's time goes per scan, against KISS-ICP's on the same scans.

Both run in this process, scan by scan (ours, then KISS-ICP on the same scan), with the
threads the command line gives both (``--threads 1``: our ``threads=1`` and KISS-ICP's
``max_num_threads=1``; set ``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1`` too). For each scan
it takes the CPU time (``time.process_time``) and the wall time of each; the step times of
ours come from wrapping the odometry's steps (nested steps indented): the CPU mean over all
scans, and the CPU and wall medians over the scans tracked by their prediction (the
process's CPU: with threads, another thread's work lands in the step it overlaps). A loaded
machine inflates both sides; the ratio of the medians is the figure (docs/sensors.md). The
CPU time of the calling thread alone (``time.thread_time``, the median over the tracked
scans) is what stays in the scan's series of steps when other threads take work off it: on
a loaded machine, a bound of the idle wall time from below. Usage::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 PYTHONPATH=$PWD nice -n 5 \\
        .venv/bin/python scripts/sensor_speed.py BAG [--frames 120] [--stride 1] \\
        [--threads 1] [--no-kiss] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from collections.abc import Callable
import functools
import time
from typing import Any

import numpy as np

#: The wrapped steps: (module, owner, attribute, label). Indented labels are nested steps.
STEPS = (
    ('mlsemreg_ros.core.labeling.source', 'LabelSource', '__call__', 'labels (label_source)'),
    ('mlsemreg_ros.core.odometry.preprocess', 'Preprocessor', 'sweep', 'preprocess'),
    ('mlsemreg_ros.core.odometry.preprocess', 'Preprocessor', 'deskew', '  deskew'),
    ('mlsemreg_ros.core.pipeline', 'Registration', 'prepare', '  prepare'),
    ('mlsemreg_ros.core.features.features', None, 'voxel_downsample', '    voxelize 0.3 m'),
    ('mlsemreg_ros.core.odometry.tracking', 'Tracker', 'estimate', 'track or register'),
    ('mlsemreg_ros.core.alignment.alignment', 'AlignmentCloud', 'build', '  alignment cloud'),
    ('mlsemreg_ros.core.odometry.local_map', 'LocalMap', 'align', '  map alignment (vgicp)'),
    ('mlsemreg_ros.core.odometry.tracking', 'Tracker', 'align_accepted', 'accept: sweep'),
    ('mlsemreg_ros.core.odometry.tracking', 'Tracker', 'align_sweep', '  sweep alignment'),
    ('mlsemreg_ros.core.odometry.local_map', 'LocalMap', 'gaussians', "    map's Gaussians"),
    ('mlsemreg_ros.core.alignment.sweep_alignment', 'MapGaussians', 'cells', '    cells'),
    ('mlsemreg_ros.core.alignment.sweep_alignment', None, 'linearization', '    Gauss-Newton'),
    (
        'mlsemreg_ros.core.alignment.sweep_kernels',
        None,
        'align_sweep',
        '    Gauss-Newton, compiled',
    ),
    ('mlsemreg_ros.core.odometry.sweep_starts', None, 'bend_m', '    second start: bend'),
    (
        'mlsemreg_ros.core.odometry.sweep_ahead',
        'SweepAhead',
        'take',
        '    wait for it, started ahead',
    ),
    (
        'mlsemreg_ros.core.odometry.advance',
        None,
        'calibrated_covariance',
        'covariance calibration',
    ),
    ('mlsemreg_ros.core.odometry.local_map', 'LocalMap', 'insert', 'map insertion'),
    ('mlsemreg_ros.core.odometry.local_map', None, 'keyframe_refusal', 'keyframe policy'),
)


def wrap_steps(totals: dict[str, list[float]], calls: dict[str, int]) -> None:
    """Wrap each step of :data:`STEPS` to add its [CPU, wall] time (s) to ``totals``."""
    import importlib

    for module_name, owner_name, attribute, label in STEPS:
        try:
            module = importlib.import_module(module_name)
        except ImportError:  # a step this version of the code does not have
            continue
        owner = getattr(module, owner_name) if owner_name else module
        original = getattr(owner, attribute, None)
        if original is None:  # a step this version of the code does not have
            continue

        def timed(*args: Any, _f: Callable = original, _label: str = label, **kwargs: Any) -> Any:
            cpu, wall = time.process_time(), time.perf_counter()
            try:
                return _f(*args, **kwargs)
            finally:
                spent = totals[_label]
                spent[0] += time.process_time() - cpu
                spent[1] += time.perf_counter() - wall
                calls[_label] += 1

        setattr(owner, attribute, functools.wraps(original)(timed))


def print_steps(per_scan: list[dict[str, list[float]]], sources: list[str], total: list) -> None:
    """
    Print each step's mean CPU time over the scans, and its medians over the tracked scans.

    ``per_scan``: each timed scan's steps (label: [CPU, wall] s); ``sources``: each scan's
    estimate source ('prediction': tracked by its prediction); ``total``: each scan's
    [CPU, wall] (s). ``other``: a scan's time outside the top-level steps.
    """
    tracked = [k for k, source in enumerate(sources) if source == 'prediction']
    top = [label for _, _, _, label in STEPS if not label.startswith(' ')]

    def median(values: list[float]) -> float:
        return 1e3 * float(np.median(values)) if values else 0.0

    print(
        f'our steps, ms per scan: CPU mean over {len(per_scan)} scans, calls per scan; '
        f'CPU / wall median over the {len(tracked)} tracked scans:'
    )
    rows = [label for _, _, _, label in STEPS] + ['other']
    for label in rows:
        if label == 'other':
            values = [
                [total[k][i] - sum(per_scan[k].get(t, [0.0, 0.0])[i] for t in top) for i in (0, 1)]
                for k in range(len(per_scan))
            ]
            count = len(per_scan)
        else:
            values = [per_scan[k].get(label, [0.0, 0.0]) for k in range(len(per_scan))]
            count = sum(1 for scan in per_scan if label in scan)
        if not count:
            continue
        mean = 1e3 * float(np.mean([v[0] for v in values]))
        cpu = median([values[k][0] for k in tracked])
        wall = median([values[k][1] for k in tracked])
        calls = (
            sum(scan[label][2] if label in scan else 0 for scan in per_scan)
            if label != 'other'
            else 0
        )
        per = calls / max(len(per_scan), 1)
        print(f'  {label:30s} {mean:7.2f}  {per:4.2f}   {cpu:6.2f} / {wall:6.2f}')


def main() -> int:
    """Replay the scans through both and print the medians and our steps."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('bag')
    parser.add_argument('--frames', type=int, default=120)
    parser.add_argument('--stride', type=int, default=1, help='every STRIDE-th scan')
    parser.add_argument('--threads', type=int, default=1, help='both sides (0: all cores)')
    parser.add_argument('--no-kiss', action='store_true', help='ours alone')
    parser.add_argument('--set', nargs='*', default=[], metavar='KEY=VALUE')
    args = parser.parse_args()
    totals: dict[str, list[float]] = defaultdict(lambda: [0.0, 0.0])
    calls: dict[str, int] = defaultdict(int)
    wrap_steps(totals, calls)

    from mlsemreg_ros.core.config import load_settings, RegistrationConfig
    from mlsemreg_ros.core.odometry import Odometry
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.datasets.factory import open_scan_source
    from mlsemreg_ros.evaluation.estimators import KissIcpEstimator, OdometryEstimator

    (core,) = load_settings((RegistrationConfig,), None, [f'threads={args.threads}', *args.set])
    source = open_scan_source(args.bag)
    try:
        scans = list(source.scans(args.stride, args.frames))
    finally:
        source.close()
    ours = OdometryEstimator(Odometry(Registration(core)))
    kiss = None if args.no_kiss else KissIcpEstimator()
    if kiss is not None and args.threads > 0:
        from kiss_icp.kiss_icp import KissICP

        config = kiss.odometry.config
        config.registration.max_num_threads = args.threads
        kiss.odometry = KissICP(config)
    rows, modes = [], defaultdict(int)
    main_thread: list[float] = []  # our CPU time on the calling thread per scan (s)
    per_scan: list[dict[str, list[float]]] = []
    sources: list[str] = []
    for k, scan in enumerate(scans):
        totals.clear()
        calls.clear()
        cpu, wall, own = time.process_time(), time.perf_counter(), time.thread_time()
        estimate = ours.step(scan)
        row = [time.process_time() - cpu, time.perf_counter() - wall]
        main_thread.append(time.thread_time() - own)
        modes[estimate.source or estimate.mode] += 1
        if k >= 1:  # the first scan starts the odometry (and loads the kernels)
            per_scan.append({label: [*v, calls[label]] for label, v in totals.items()})
            sources.append(estimate.source or estimate.mode)
        if kiss is not None:
            cpu, wall = time.process_time(), time.perf_counter()
            kiss.step(scan)
            row += [time.process_time() - cpu, time.perf_counter() - wall]
        rows.append(row)
    times = 1e3 * np.median(np.array(rows[1:]), axis=0)
    print(f'{args.bag}: {len(scans)} scans, {np.mean([len(s.xyz) for s in scans]):.0f} points')
    global_path = sum(v for k, v in modes.items() if 'global' in k)
    tracked = [k for k, source in enumerate(sources, start=1) if source == 'prediction']
    own = 1e3 * float(np.median([main_thread[k] for k in tracked])) if tracked else 0.0
    print(f'ours: CPU {times[0]:.1f} ms, wall {times[1]:.1f} ms (medians); {dict(modes)}')
    print(f'ours, tracked scans: CPU on the calling thread {own:.2f} ms (median)')
    print(f'global path: {global_path} of {len(scans) - 1} scans')
    if kiss is not None:
        print(f'KISS-ICP: CPU {times[2]:.1f} ms, wall {times[3]:.1f} ms')
        cpu_ratio, wall_ratio = times[0] / times[2], times[1] / times[3]
        print(f'ratio of the medians: CPU {cpu_ratio:.2f}x, wall {wall_ratio:.2f}x')
    print_steps(per_scan, sources, [row[:2] for row in rows[1:]])
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
