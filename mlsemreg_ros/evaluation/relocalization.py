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
Relocalization of query scans against a map folder, scored: ``mlsemreg relocalize``.

A query file (``.npz``) holds ``points`` (N, 3), ``labels`` (N,) and optionally
``T_map_scan`` (4, 4) ground truth (``mlsemreg map queries`` / ``map sim-queries`` write
them). :func:`relocalize_queries` relocalizes each without an initial guess
(:class:`~mlsemreg_ros.core.maps.relocalization.Relocalizer`) and scores it: found (an
accepted registration), the error against the ground truth and the time; then the recall
(accepted with RE <= 5 deg and TE <= 0.6 m), the wrong accepted (accepted beyond either
bound) and the time percentiles (docs/maps.md). With the ``map-closures`` peer the same
queries are relocalized with MapClosures as place recognition.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
import time
from typing import Any, TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig

#: A relocalization is right within these bounds of the ground truth.
MAX_ROTATION_DEG = 5.0
MAX_TRANSLATION_M = 0.6


class QueryError(ValueError):
    """The query folder or a query file cannot be used."""


@dataclass(frozen=True)
class RelocalizeOptions:
    """Which queries, how large a map, which peers."""

    max_queries: int | None = None  # use the first N queries (sorted by name)
    duplicate: int = 1  # scale test: every keyframe this many times, at the same pose
    baselines: tuple[str, ...] = ()  # place-recognition peers ('map-closures')


@dataclass
class RelocalizationReport:
    """Every query's record, the summary, and the peers' (by name)."""

    records: list[dict[str, Any]]
    summary: dict[str, Any]
    baselines: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """Return the JSON of ``--json``: queries, summary (and baselines)."""
        output: dict[str, Any] = {'queries': self.records, 'summary': self.summary}
        if self.baselines:
            output['baselines'] = self.baselines
        return output


def relocalization_config(
    map_config: RegistrationConfig | None,
    config_path: Path | None,
    overrides: Sequence[str] = (),
) -> RegistrationConfig:
    """
    Return the settings: the map's own (if it has them and no ``config_path``) < overrides.

    Without them: defaults < ``config_path`` < overrides. Raises ConfigError (an unreadable
    ``config_path`` too).
    """
    from mlsemreg_ros.core.config import (
        apply_overrides,
        ConfigError,
        load_settings,
        RegistrationConfig,
    )

    if config_path is None and map_config is not None:
        return apply_overrides(map_config, list(overrides)) if overrides else map_config
    try:
        (core,) = load_settings((RegistrationConfig,), config_path, list(overrides))
    except OSError as error:
        raise ConfigError(str(error)) from None
    return core


def relocalize_queries(
    map_path: Path,
    queries: Path,
    options: RelocalizeOptions | None = None,
    config_path: Path | None = None,
    overrides: Sequence[str] = (),
) -> RelocalizationReport:
    """
    Relocalize every query of the folder ``queries`` against the map ``map_path``; score.

    Settings: :func:`relocalization_config`. Raises MapError (the map), ConfigError (the
    settings) and :class:`QueryError` (the queries).
    """
    from mlsemreg_ros.core.labeling.source import LabelSource
    from mlsemreg_ros.core.maps.map_io import load_map
    from mlsemreg_ros.core.maps.relocalization import Relocalizer
    from mlsemreg_ros.core.pipeline import Registration

    options = options or RelocalizeOptions()
    data = load_map(map_path)
    core = relocalization_config(data.config, config_path, overrides)
    core = duplicate_map(data, core, options.duplicate)
    registration = Registration(core)
    store = data.store(core, registration.label_map)
    files = sorted(queries.glob('*.npz'))[: options.max_queries]
    if not files:
        raise QueryError(f'{queries}: no .npz query files')
    relocalizer = Relocalizer(registration, store)
    began = time.perf_counter()
    if core.map.prepare_on_load:  # as the node does when it loads a map
        relocalizer.prepare_map()
    prepare_ms = 1e3 * (time.perf_counter() - began)
    label_source = LabelSource(registration.label_map)
    records = []
    for file in files:
        query = read_query(file)
        labeled = label_source(query['points'], query['labels'], core)  # --labels
        found = relocalizer.relocalize(query['points'], labeled.labels)
        records.append(score(file.stem, found, query.get('T_map_scan')))
    summary = summarize(records)
    summary.update(
        keyframes=len(store),
        map=str(map_path),
        duplicate=options.duplicate,
        map_prepare_ms=prepare_ms,
    )
    report = RelocalizationReport(records, summary)
    if options.baselines:
        report.baselines = place_peer_summaries(data.keyframes, files)
    return report


def print_relocalization(report: RelocalizationReport) -> None:
    """Print the table of the queries, the summary line and the peers' lines."""
    from mlsemreg_ros.evaluation.tables import print_table, print_text, ResultTable

    rows = [
        [
            record['query'],
            'yes' if record['accepted'] else 'no',
            record['verdict'],
            _fmt(record.get('re_deg'), '.2f'),
            _fmt(record.get('te_m'), '.2f'),
            str(record['candidates']),
            f'{record["time_ms"]:.0f}',
        ]
        for record in report.records
    ]
    print_table(
        ResultTable(
            ('query', 'accepted', 'verdict', 'RE deg', 'TE m', 'tried', 'ms'), rows, left_columns=3
        )
    )
    summary = report.summary
    print_text(
        f'{summary["queries"]} queries against {summary["keyframes"]} keyframes: recall '
        f'{summary["recall_pct"]:.1f} % (accepted, RE <= {MAX_ROTATION_DEG:g} deg, TE <= '
        f'{MAX_TRANSLATION_M:g} m), {summary["accepted"]} accepted, '
        f'{summary["wrong_accepted"]} wrong accepted; time p50 {summary["time_ms_p50"]:.0f} '
        f'ms, p90 {summary["time_ms_p90"]:.0f} ms; registrations per query '
        f'{summary["registrations_mean"]:.1f}'
    )
    peer = report.baselines.get('map-closures')
    if peer is not None:
        summary = peer['summary']
        print_text(
            f'MapClosures as place recognition: recall {summary["recall_pct"]:.1f} %, '
            f'{summary["accepted"]} accepted, {summary["wrong_accepted"]} wrong accepted; time '
            f'p50 {summary["time_ms_p50"]:.0f} ms, p90 {summary["time_ms_p90"]:.0f} ms'
        )


def place_peer_summaries(keyframes: list[Any], files: list[Path]) -> dict[str, Any]:
    """Relocalize with MapClosures as place recognition, same map and queries."""
    from mlsemreg_ros.evaluation.loop_peers import map_closures_relocalize

    queries = [read_query(file) for file in files]
    found = map_closures_relocalize(
        [(k.points, k.T_map_keyframe) for k in keyframes], [q['points'] for q in queries]
    )
    records = [
        score(f.stem, a, q.get('T_map_scan'))
        for f, a, q in zip(files, found, queries, strict=True)
    ]
    return {'map-closures': {'queries': records, 'summary': summarize(records)}}


def _fmt(value: float | None, spec: str) -> str:
    return '-' if value is None else format(value, spec)


def read_query(file: Path) -> dict[str, Any]:
    """``points``, ``labels`` and (if present) ``T_map_scan`` of a query file."""
    try:
        with np.load(file, allow_pickle=False) as data:
            if 'points' not in data.files or 'labels' not in data.files:
                raise QueryError(f'{file}: needs points and labels; has {sorted(data.files)}')
            query = {
                'points': np.asarray(data['points'], dtype=np.float64),
                'labels': data['labels'],
            }
            if 'T_map_scan' in data.files:
                query['T_map_scan'] = np.asarray(data['T_map_scan'], dtype=np.float64)
    except QueryError:
        raise
    except (OSError, ValueError) as error:
        raise QueryError(f'{file}: cannot read: {error}') from None
    if query['points'].ndim != 2 or query['points'].shape[1] != 3:
        raise QueryError(f'{file}: points must be (N, 3), got {query["points"].shape}')
    if query['labels'].shape != (query['points'].shape[0],):
        raise QueryError(f'{file}: labels must be ({query["points"].shape[0]},)')
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
                'deferred': t.deferred,
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


def duplicate_map(data: Any, core: Any, copies: int) -> Any:
    """Repeat the map's keyframes ``copies`` times in place; the config that holds them all."""
    if copies <= 1:
        return core
    data.keyframes = duplicated(data.keyframes, copies)
    return core.replace(
        {
            'map.max_keyframes': max(core.map.max_keyframes, len(data.keyframes)),
            'map.max_memory_mb': 1e6,
        }
    )


def duplicated(keyframes: list[Any], copies: int) -> list[Any]:
    """Every keyframe ``copies`` times, at the same pose (scale tests)."""
    from mlsemreg_ros.core.maps.map_io import MapKeyframe

    out = []
    for _ in range(copies):
        for keyframe in keyframes:
            pose = keyframe.T_map_keyframe.copy()
            out.append(MapKeyframe(keyframe.points, keyframe.labels, pose, keyframe.stamp_ns))
    return out
