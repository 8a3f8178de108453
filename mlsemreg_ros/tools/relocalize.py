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
``mlsemreg relocalize MAP QUERIES``: relocalize query scans against a map, no initial guess.

QUERIES is a folder of ``.npz`` files with ``points`` (N, 3), ``labels`` (N,) and optionally
``T_map_scan`` (4, 4) ground truth (``mlsemreg map queries`` / ``map sim-queries`` write
them). Per query: found (an accepted registration), the error against the ground truth and
the time; then the recall (accepted with RE <= 5 deg and TE <= 0.6 m), the wrong accepted
(accepted beyond either bound) and the time percentiles (docs/maps.md).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

from mlsemreg_ros.evaluation.peer_runs import PlacePeer
from mlsemreg_ros.tools.common import (
    alias,
    CommandError,
    ConfigOption,
    JsonOption,
    LabelsOption,
    SetOption,
    settings,
    with_labels,
)
import typer

HELP = 'Relocalize query scans against a map folder without an initial guess (recall, time).'
#: A relocalization is right within these bounds of the ground truth.
MAX_ROTATION_DEG = 5.0
MAX_TRANSLATION_M = 0.6


def relocalize(
    map_path: Annotated[Path, typer.Argument(metavar='MAP', help='map folder (docs/maps.md)')],
    queries: Annotated[Path, typer.Argument(help='folder of query .npz files')],
    max_queries: Annotated[int | None, typer.Option(min=1, help='use the first N queries')] = None,
    duplicate: Annotated[
        int,
        typer.Option(
            min=1,
            help='scale test: load every keyframe this many times (at the same pose: the '
            'search runs over every copy, map.candidate_separation skips the copies of a '
            'place already tried)',
        ),
    ] = 1,
    baseline: Annotated[
        list[PlacePeer] | None,
        typer.Option(help='also relocalize the queries with this peer as place recognition'),
    ] = None,
    config: ConfigOption = None,
    labels: LabelsOption = None,
    overrides: SetOption = None,
    json_path: JsonOption = None,
) -> int:
    """Relocalize the queries against the map and print the recall (alias mlsemreg-relocalize)."""
    from mlsemreg_ros.evaluation import peer_runs

    try:
        peer_runs.require_peers([str(peer) for peer in baseline or []])
    except peer_runs.PeerUnavailable as error:
        raise CommandError(str(error), 2) from None
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.labeling.source import LabelSource
    from mlsemreg_ros.core.maps.map_io import load_map, MapError
    from mlsemreg_ros.core.maps.relocalization import Relocalizer
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.evaluation.tables import print_table, print_text, ResultTable

    try:
        data = load_map(map_path)
    except MapError as error:
        raise CommandError(str(error)) from None
    base = data.config if config is None and data.config is not None else None
    overrides = with_labels(overrides, labels)
    if base is not None and overrides:
        from mlsemreg_ros.core.config import apply_overrides, ConfigError

        try:
            core = apply_overrides(base, list(overrides))
        except ConfigError as error:
            raise CommandError(f'configuration error: {error}', 2) from None
    elif base is not None:
        core = base
    else:
        (core,) = settings((RegistrationConfig,), config, overrides)
    if duplicate > 1:
        data.keyframes = duplicated(data.keyframes, duplicate)
        core = core.replace(
            {
                'map.max_keyframes': max(core.map.max_keyframes, len(data.keyframes)),
                'map.max_memory_mb': 1e6,
            }
        )
    registration = Registration(core)
    store = data.store(core, registration.label_map)
    files = sorted(queries.glob('*.npz'))[:max_queries]
    if not files:
        raise CommandError(f'{queries}: no .npz query files')
    relocalizer = Relocalizer(registration, store)
    label_source = LabelSource(registration.label_map)
    rows, records = [], []
    for file in files:
        query = read_query(file)
        labeled = label_source(query['points'], query['labels'], core)  # --labels
        found = relocalizer.relocalize(query['points'], labeled.labels)
        record = score(file.stem, found, query.get('T_map_scan'))
        records.append(record)
        rows.append(
            [
                record['query'],
                'yes' if record['accepted'] else 'no',
                record['verdict'],
                _fmt(record.get('re_deg'), '.2f'),
                _fmt(record.get('te_m'), '.2f'),
                str(record['candidates']),
                f'{record["time_ms"]:.0f}',
            ]
        )
    print_table(
        ResultTable(
            ('query', 'accepted', 'verdict', 'RE deg', 'TE m', 'tried', 'ms'), rows, left_columns=3
        )
    )
    summary = summarize(records)
    summary.update(keyframes=len(store), map=str(map_path), duplicate=duplicate)
    print_text(
        f'{summary["queries"]} queries against {len(store)} keyframes: recall '
        f'{summary["recall_pct"]:.1f} % (accepted, RE <= {MAX_ROTATION_DEG:g} deg, TE <= '
        f'{MAX_TRANSLATION_M:g} m), {summary["accepted"]} accepted, '
        f'{summary["wrong_accepted"]} wrong accepted; time p50 {summary["time_ms_p50"]:.0f} '
        f'ms, p90 {summary["time_ms_p90"]:.0f} ms; registrations per query '
        f'{summary["registrations_mean"]:.1f}'
    )
    output: dict[str, Any] = {'queries': records, 'summary': summary}
    if baseline:
        output['baselines'] = place_peer_summaries(data.keyframes, files)
    if json_path is not None:
        json_path.write_text(json.dumps(output, indent=2) + '\n')
    return 0


def place_peer_summaries(keyframes: list[Any], files: list[Path]) -> dict[str, Any]:
    """Relocalize with MapClosures as place recognition, same map and queries; print, return."""
    from mlsemreg_ros.evaluation.loop_peers import map_closures_relocalize
    from mlsemreg_ros.evaluation.tables import print_text

    queries = [read_query(file) for file in files]
    found = map_closures_relocalize(
        [(k.points, k.T_map_keyframe) for k in keyframes], [q['points'] for q in queries]
    )
    records = [
        score(f.stem, a, q.get('T_map_scan'))
        for f, a, q in zip(files, found, queries, strict=True)
    ]
    summary = summarize(records)
    print_text(
        f'MapClosures as place recognition: recall {summary["recall_pct"]:.1f} %, '
        f'{summary["accepted"]} accepted, {summary["wrong_accepted"]} wrong accepted; time '
        f'p50 {summary["time_ms_p50"]:.0f} ms, p90 {summary["time_ms_p90"]:.0f} ms'
    )
    return {'map-closures': {'queries': records, 'summary': summary}}


def _fmt(value: float | None, spec: str) -> str:
    return '-' if value is None else format(value, spec)


def read_query(file: Path) -> dict[str, Any]:
    """``points``, ``labels`` and (if present) ``T_map_scan`` of a query file."""
    import numpy as np

    try:
        with np.load(file, allow_pickle=False) as data:
            if 'points' not in data.files or 'labels' not in data.files:
                raise CommandError(f'{file}: needs points and labels; has {sorted(data.files)}')
            query = {
                'points': np.asarray(data['points'], dtype=np.float64),
                'labels': data['labels'],
            }
            if 'T_map_scan' in data.files:
                query['T_map_scan'] = np.asarray(data['T_map_scan'], dtype=np.float64)
    except (OSError, ValueError) as error:
        raise CommandError(f'{file}: cannot read: {error}') from None
    if query['points'].ndim != 2 or query['points'].shape[1] != 3:
        raise CommandError(f'{file}: points must be (N, 3), got {query["points"].shape}')
    if query['labels'].shape != (query['points'].shape[0],):
        raise CommandError(f'{file}: labels must be ({query["points"].shape[0]},)')
    return query


def score(name: str, found: Any, truth: Any) -> dict[str, Any]:
    """One query's record: accepted, errors against ``truth`` (if any), verdict, time."""
    from mlsemreg_ros.core.metrics import rotation_error_deg, translation_error_m

    record: dict[str, Any] = {
        'query': name,
        'accepted': bool(found.found),
        'keyframe': int(found.keyframe_id),
        'candidates': len(found.trials),
        'time_ms': float(found.time_ms),
        'timings_ms': {k: float(v) for k, v in found.timings_ms.items()},
        'trials': [
            {
                'keyframe': t.keyframe_id,
                'similarity': t.similarity,
                'accepted': t.accepted,
                'inliers': t.inliers,
                'message': t.message,
                'time_ms': t.time_ms,
                'quick': t.quick,
            }
            for t in found.trials
        ],
    }
    if found.found:
        record['T_map_scan'] = found.T_map_sensor.tolist()
    if truth is None:
        record['verdict'] = 'accepted' if found.found else 'refused'
        return record
    if found.found:
        re = rotation_error_deg(found.T_map_sensor, truth)
        te = translation_error_m(found.T_map_sensor[:3, 3], truth[:3, 3])
        record.update(re_deg=re, te_m=te)
        right = re <= MAX_ROTATION_DEG and te <= MAX_TRANSLATION_M
        record['verdict'] = 'right' if right else 'WRONG'
    else:
        record['verdict'] = 'refused'
    return record


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Summarize: queries, recall_pct, accepted, wrong_accepted, refused, times."""
    import numpy as np

    times = np.array([r['time_ms'] for r in records])
    with_truth = [r for r in records if r['verdict'] in ('right', 'WRONG', 'refused')]
    right = sum(r['verdict'] == 'right' for r in records)
    return {
        'queries': len(records),
        'with_ground_truth': len(with_truth),
        'recall_pct': 100.0 * right / max(len(with_truth), 1),
        'accepted': sum(r['accepted'] for r in records),
        'right': right,
        'wrong_accepted': sum(r['verdict'] == 'WRONG' for r in records),
        'refused': sum(not r['accepted'] for r in records),
        'time_ms_p50': float(np.percentile(times, 50)),
        'time_ms_p90': float(np.percentile(times, 90)),
        'time_ms_mean': float(times.mean()),
        'registrations_mean': float(np.mean([r['candidates'] for r in records])),
    }


def duplicated(keyframes: list[Any], copies: int) -> list[Any]:
    """Every keyframe ``copies`` times, at the same pose (scale tests)."""
    from mlsemreg_ros.core.maps.map_io import MapKeyframe

    out = []
    for _ in range(copies):
        for keyframe in keyframes:
            pose = keyframe.T_map_keyframe.copy()
            out.append(MapKeyframe(keyframe.points, keyframe.labels, pose, keyframe.stamp_ns))
    return out


main = alias(relocalize, HELP, 'mlsemreg-relocalize')
