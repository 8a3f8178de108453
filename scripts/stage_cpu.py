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
Per-stage CPU time of the pair registration: eval-pairs' stage timers on the process clock.

``mlsemreg eval-pairs`` times its stages with the wall clock, which the load of a shared
machine moves most. This runs the same registration (the same settings, ``--set`` as in
eval-pairs) with the stage timers of ``core/stages/context.py`` and Mask Matching on the
process CPU clock (``time.process_time``), after running the first two pairs once (the
compiled kernels). Run it single-threaded; it writes one JSON row per pair (name, verdict,
success, errors, stage CPU ms) and prints the medians::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1 PYTHONPATH=$PWD \
        .venv/bin/python scripts/stage_cpu.py DIR --descriptor gedi|fpfh --set threads=1 \
        --json out.json

docs/hard_pairs.md (the refused path, sixth round) compares two trees this way. With
``--clock wall`` the stage timers keep the wall clock (the ninth round: the wall time at
the default ``threads``, where the stages' threads overlap).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import statistics
import time
import types

import mlsemreg_ros.core.matching.mask_search as mask_search
import mlsemreg_ros.core.matching.matching as matching
import mlsemreg_ros.core.stages.context as stage_context

CPU_CLOCK = types.SimpleNamespace(perf_counter=time.process_time)


def main() -> None:
    """Register every pair of DIR with the stage timers on the CPU clock; write and print."""
    from mlsemreg_ros.core.labeling.source import LabelSource
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.datasets.pairs import list_pairs, load_pair
    from mlsemreg_ros.evaluation.pairs import labeled_pair, run_pair
    from mlsemreg_ros.tools.common import with_labels
    from mlsemreg_ros.tools.eval_pairs import build_settings

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('directory', type=Path)
    parser.add_argument('--descriptor', default='gedi', choices=('gedi', 'fpfh'))
    parser.add_argument('--set', dest='overrides', action='append', default=[])
    parser.add_argument('--json', type=Path, default=None)
    parser.add_argument(
        '--clock',
        default='cpu',
        choices=('cpu', 'wall'),
        help='the stage timers: the process CPU clock (default) or the wall clock',
    )
    args = parser.parse_args()
    if args.clock == 'cpu':
        for module in (stage_context, matching, mask_search):
            module.time = CPU_CLOCK  # the modules' own ``time``: perf_counter -> process_time
    core, evaluation = build_settings(None, {}, with_labels(args.overrides, None))
    registration = Registration(core)
    label_source = LabelSource(registration.label_map)
    pairs = [labeled_pair(load_pair(p), label_source, core) for p in list_pairs(args.directory)]
    for pair in pairs[:2]:  # compile the kernels outside the timed runs
        run_pair(registration, pair, args.descriptor, evaluation.evaluation)
    rows = []
    for pair in pairs:
        result, metrics, timings = run_pair(
            registration, pair, args.descriptor, evaluation.evaluation
        )
        rows.append(
            {
                'name': pair.name,
                'accepted': bool(result.success),
                'success': bool(metrics.success),
                're': float(metrics.rotation_error_deg),
                'te': float(metrics.translation_error_cm),
                't': timings,
            }
        )
    if args.json is not None:
        args.json.write_text(json.dumps(rows))
    stages = sorted({k for row in rows for k in row['t']})
    for stage in stages:
        ran = [row['t'][stage] for row in rows if row['t'].get(stage, 0.0) > 0.5]
        if ran:
            mean = sum(row['t'].get(stage, 0.0) for row in rows) / len(rows)
            print(
                f'{stage:24} ran on {len(ran):3d}  mean {mean:7.1f}  '
                f'median where it ran {statistics.median(ran):7.1f}'
            )


if __name__ == '__main__':
    main()
