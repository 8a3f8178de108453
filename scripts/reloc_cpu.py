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
Process CPU time of each relocalization query, and where it goes (docs/maps.md).

What ``mlsemreg relocalize MAP QUERIES`` does, with the process CPU clock
(``time.process_time``) around each query instead of the wall clock, which the load of a
shared machine moves most. The map load (and whatever the map prepares when it loads) is
timed on its own, and one warm-up relocalization of the first query against a store of
that query alone compiles the kernels without touching the map's keyframes. With
``--profile FILE`` the queries run under ``cProfile`` with the CPU clock; ``--top N``
prints the functions with most cumulative time. Run it single-threaded::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1 PYTHONPATH=$PWD \
        .venv/bin/python scripts/reloc_cpu.py MAP QUERIES --set threads=1 \
        [--duplicate 35] [--max-queries 5] [--profile out.prof --top 40] [--json out.json]
        [--node-prepared]
"""

from __future__ import annotations

import argparse
import cProfile
import json
from pathlib import Path
import pstats
import time

from mlsemreg_ros.core.labeling.source import LabelSource
from mlsemreg_ros.core.maps.keyframe_store import KeyframeStore
from mlsemreg_ros.core.maps.map_io import load_map
from mlsemreg_ros.core.maps.relocalization import Relocalizer
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.evaluation.relocalization import (
    duplicate_map,
    read_query,
    relocalization_config,
    score,
    summarize,
)
import numpy as np


def main() -> None:
    """Relocalize the queries, print each one's verdict and CPU time, then the summary."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('map', type=Path)
    parser.add_argument('queries', type=Path)
    parser.add_argument('--duplicate', type=int, default=1)
    parser.add_argument('--max-queries', type=int, default=None)
    parser.add_argument('--set', dest='overrides', action='append', default=[])
    parser.add_argument('--profile', type=Path, default=None)
    parser.add_argument('--top', type=int, default=30)
    parser.add_argument('--json', type=Path, default=None)
    parser.add_argument(
        '--node-prepared',
        action='store_true',
        help="prepare each query before its clock starts, lazily, as the node's odometry has "
        'when it relocalizes a scan (its descriptors are still computed in the query)',
    )
    args = parser.parse_args()

    files = sorted(args.queries.glob('*.npz'))[: args.max_queries]
    queries = [read_query(file) for file in files]
    cpu = time.process_time()
    data = load_map(args.map)
    core = relocalization_config(data.config, None, args.overrides)
    core = duplicate_map(data, core, args.duplicate)
    registration = Registration(core)
    label_source = LabelSource(registration.label_map)
    labels = [label_source(q['points'], q['labels'], core).labels for q in queries]

    # warm-up: the first query against a store of itself (compiles, prepares no keyframe)
    warm = KeyframeStore(core, registration.label_map)
    itself = registration.prepare(queries[0]['points'], labels[0])
    warm.add(itself.points, itself.labels, np.eye(4))
    Relocalizer(registration, warm).relocalize(queries[0]['points'], labels[0])

    cpu = time.process_time()
    wall = time.perf_counter()
    store = data.store(core, registration.label_map)
    relocalizer = Relocalizer(registration, store)
    if getattr(core.map, 'prepare_on_load', False):  # as `mlsemreg relocalize` and the node do
        relocalizer.prepare_map()
    load_cpu_ms = 1e3 * (time.process_time() - cpu)
    load_wall_ms = 1e3 * (time.perf_counter() - wall)

    profiler = cProfile.Profile(time.process_time) if args.profile else None
    records = []
    for file, query, query_labels in zip(files, queries, labels, strict=True):
        prepared = None
        if args.node_prepared:
            prepared = registration.prepare(query['points'], query_labels, lazy=True)
        cpu = time.process_time()
        if profiler is not None:
            profiler.enable()
        found = relocalizer.relocalize(query['points'], query_labels, prepared=prepared)
        if profiler is not None:
            profiler.disable()
        record = score(file.stem, found, query.get('T_map_scan'))
        record['cpu_ms'] = 1e3 * (time.process_time() - cpu)
        records.append(record)
        print(
            f'{file.stem:>8} {record["verdict"]:>8} kf {record["keyframe"]:>5} '
            f'tried {record["candidates"]} cpu {record["cpu_ms"]:7.0f} ms '
            f'wall {record["time_ms"]:7.0f} ms  '
            + ' '.join(f'{k}={v:.0f}' for k, v in record['timings_ms'].items()),
            flush=True,
        )
    summary = summarize(records)
    cpus = np.array([r['cpu_ms'] for r in records])
    summary.update(
        keyframes=len(store),
        cpu_ms_p50=float(np.percentile(cpus, 50)),
        cpu_ms_p90=float(np.percentile(cpus, 90)),
        load_cpu_ms=load_cpu_ms,
        load_wall_ms=load_wall_ms,
    )
    print(
        f'{summary["queries"]} queries, {summary["keyframes"]} keyframes: recall '
        f'{summary["recall_pct"]:.1f} %, wrong {summary["wrong_accepted"]}, refused '
        f'{summary["refused"]}; CPU p50 {summary["cpu_ms_p50"]:.0f} ms, p90 '
        f'{summary["cpu_ms_p90"]:.0f} ms; registrations {summary["registrations_mean"]:.2f}; '
        f'map load CPU {load_cpu_ms:.0f} ms (wall {load_wall_ms:.0f} ms)'
    )
    if args.json is not None:
        args.json.write_text(json.dumps({'queries': records, 'summary': summary}, indent=1))
    if profiler is not None:
        profiler.dump_stats(str(args.profile))
        pstats.Stats(profiler).sort_stats('cumulative').print_stats(args.top)


if __name__ == '__main__':
    main()
