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
The far search's two directions on one thread and on two, interleaved, in one process.

For each pair file given (the dev pairs 60 m apart: ``mlsemreg chain-pairs DIR OUT --apart
3``), both scans are prepared once; then the far search (``core/stages/far_search.py``) runs
``--rounds`` times with ``threads`` 1 (the two directions in turn) and 2 (at once), the order
alternating round by round so that a loaded machine slows both alike. It prints each side's
wall and CPU median per pair and their ratio, and checks that both return the same
candidates. Usage::

    PYTHONPATH=$PWD nice -n 5 .venv/bin/python scripts/far_search_threads.py PAIR.npz... \\
        [--rounds 5]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np


def main() -> None:
    """Time the far search with one and two threads on each pair."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('pairs', nargs='+')
    parser.add_argument('--rounds', type=int, default=5)
    args = parser.parse_args()

    from mlsemreg_ros.core import threads
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.core.stages.context import RegistrationContext
    from mlsemreg_ros.core.stages.far_search import FarSearchStage
    from mlsemreg_ros.datasets.pairs import load_pair

    registration, stage = Registration(), FarSearchStage()
    wall: dict[int, list[float]] = {1: [], 2: []}
    cpu: dict[int, list[float]] = {1: [], 2: []}
    for path in args.pairs:
        pair = load_pair(path)
        source, target = (
            registration.prepare(points, labels, keypoints=keypoints, voxelize=False)
            for points, labels, keypoints in (
                (pair.pts_src, pair.label_src, pair.kpts_src),
                (pair.pts_dst, pair.label_dst, pair.kpts_dst),
            )
        )
        context = RegistrationContext(
            source, target, True, registration.config, registration.scoring()
        )
        count = min(len(source.keypoints), len(target.keypoints))  # stand-in correspondences
        context.source_points = source.keypoints[:count]
        context.target_points = target.keypoints[:count]
        found = {}
        for round_ in range(args.rounds + 1):  # round 0: compilation, not timed
            for count in (1, 2) if round_ % 2 else (2, 1):
                threads.configure(count)
                start, cpu_start = time.perf_counter(), time.process_time()
                result = stage.run(context)
                if round_:
                    wall[count].append(1e3 * (time.perf_counter() - start))
                    cpu[count].append(1e3 * (time.process_time() - cpu_start))
                found[count] = np.stack([h.T_target_source for h in result.hypotheses])
        same = np.allclose(found[1], found[2], atol=1e-9)
        print(f'{path}: {len(found[1])} candidates, the same with 1 and 2 threads: {same}')
    for count in (1, 2):
        print(
            f'threads {count}: wall p50 {statistics.median(wall[count]):.1f} ms, '
            f'CPU p50 {statistics.median(cpu[count]):.1f} ms'
        )
    ratio = statistics.median(wall[2]) / statistics.median(wall[1])
    print(f'wall ratio 2 / 1 threads: {ratio:.2f}')


if __name__ == '__main__':
    main()
