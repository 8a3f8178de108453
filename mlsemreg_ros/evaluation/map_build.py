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
A keyframe map built from a scan source (``mlsemreg map build``, docs/maps.md).

:func:`build_map` runs the odometry (with loop closures) or takes the ground-truth poses
(deskewed by the true motion, :mod:`mlsemreg_ros.datasets.deskewing`), adds the keyframes to a
:class:`~mlsemreg_ros.core.maps.mapping.Mapper` and summarises the map: keyframes, memory,
loops and, with ground truth, the ATE with and without the loop closures and each loop
edge's error (:func:`loop_edge`) against the keyframes that revisit a place
(:func:`count_revisits`). :func:`compare_loops` runs the loop-closure peers on the same scans;
:func:`summary_lines` says what was built.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import sys
from typing import Any


class MapBuildError(RuntimeError):
    """The bag cannot be read, it gave no keyframe, or the map cannot be written."""


@dataclass(frozen=True)
class MapBuildOptions:
    """How ``mlsemreg map build`` builds a map folder (docs/maps.md)."""

    poses: str = 'odometry'  # the keyframe poses: 'odometry' (loop closure) or 'ground-truth'
    max_frames: int | None = None  # read at most this many scans
    frame_id: str = 'map'  # the map's frame
    peers: tuple[str, ...] = ()  # loop-closure peers run on the same scans (loop_peers.py)
    peer_local_map: float = 100.0  # the peers' local-map size, m
    progress: bool = False


def build_map_folder(bag: Path, out: Path, options: MapBuildOptions, core: Any) -> dict:
    """
    Build the map of ``bag`` into the folder ``out``; return its summary.

    Prints what was built (:func:`summary_lines`) and, with peers, the loops of all side by
    side; the summary then holds their summaries under ``baselines``.
    """
    import time

    from mlsemreg_ros.core.maps.map_io import MapError, save_map
    from mlsemreg_ros.datasets.factory import open_scan_source
    from mlsemreg_ros.datasets.source import SourceError
    from mlsemreg_ros.evaluation.tables import print_text

    try:
        source = open_scan_source(bag)
    except (SourceError, OSError, ValueError) as error:
        raise MapBuildError(f'cannot read {bag}: {error}') from None
    tic = time.perf_counter()
    try:
        built = build_map(source, core, options.poses, options.max_frames, options.progress)
    finally:
        source.close()
    seconds = time.perf_counter() - tic
    built['summary']['time_s'] = seconds
    if len(built['mapper'].store) == 0:
        raise MapBuildError(
            f'{bag}: no keyframe (no labeled scan, or none with ground truth for '
            '--poses ground-truth)'
        )
    try:
        save_map(out, built['mapper'].store, options.frame_id, core)
    except MapError as error:
        raise MapBuildError(str(error)) from None
    summary = built['summary']
    for line in summary_lines(summary, out, options.poses):
        print_text(line)
    if options.peers:
        summary['baselines'] = compare_loops(
            bag, list(options.peers), options.max_frames, core, summary, seconds,
            options.peer_local_map,
        )  # fmt: skip
    return summary


def compare_loops(
    bag: Path,
    peers: list[str],
    max_frames: int | None,
    core: Any,
    ours: dict,
    seconds: float,
    split_m: float,
) -> dict[str, Any]:
    """Run the loop peers on the bag's scans; print the loops of all side by side."""
    from mlsemreg_ros.datasets.factory import open_scan_source
    from mlsemreg_ros.evaluation.loop_peers import loop_table, ours_loop_summary, run_loop_peers
    from mlsemreg_ros.evaluation.tables import print_table

    results = run_loop_peers(
        lambda: open_scan_source(bag), peers, max_frames, core.map, split_m,
        ours.get('revisit_segments'),
    )  # fmt: skip
    mine = ours_loop_summary(ours, seconds)
    print_table(loop_table([mine, *results.values()]))
    return {'ours': mine, **results}


def summary_lines(summary: dict[str, Any], out: Path, poses: str) -> list[str]:
    """Return what ``mlsemreg map build`` prints about the map it wrote to ``out``."""
    lines = [
        f'wrote {summary["keyframes"]} keyframes ({summary["memory_mb"]:.1f} MB, '
        f'{summary["bytes_per_keyframe"] / 1e3:.0f} kB each) from {summary["scans"]} scans '
        f'to {out}; poses: {poses}'
    ]
    if poses == 'odometry':
        lines.append(
            f'odometry: {summary["accepted"]}/{summary["scans"]} scans accepted; loops '
            f'closed: {summary["loops"]} (tried on {summary["loop_trials"]} keyframes)'
        )
    if 'ate_m' in summary:
        lines.append(
            f'ATE of the keyframes: {summary["ate_m"]:.3f} m with the loop closures, '
            f'{summary["ate_odometry_m"]:.3f} m without; loops on revisits: '
            f'{summary["loops_true"]} right, {summary["loops_wrong"]} wrong, of '
            f'{summary["revisits"]} keyframes that revisit a place'
        )
    return lines


def build_map(
    source: Any,
    config: Any,
    poses: str,
    max_frames: int | None = None,
    progress: bool = False,
) -> dict[str, Any]:
    """Map a scan source; returns the mapper and a summary (keyframes, loops, ATE)."""
    from mlsemreg_ros.core.labeling.source import LabelSource
    from mlsemreg_ros.core.maps.localization import awaits_deskew
    from mlsemreg_ros.core.maps.mapping import Mapper
    from mlsemreg_ros.core.odometry import Odometry
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.datasets.deskewing import deskewed_by_truth
    import numpy as np
    from tqdm import tqdm

    registration = Registration(config)
    mapper = Mapper(registration)
    if poses == 'ground-truth':
        mapper.store.config = config.replace({'map.loop_closure': False})
    odometry = Odometry(registration) if poses == 'odometry' else None
    truth: dict[int, np.ndarray] = {}  # keyframe id -> ground truth
    scan_truth: dict[int, np.ndarray] = {}  # stamp -> ground truth, every scan read
    keyframe_trials: list[dict[str, Any]] = []  # per keyframe: the loop candidates tried
    scans = accepted = trials = 0
    total = len(source) if max_frames is None else min(len(source), max_frames)
    labeled = (
        scan
        for scan in tqdm(
            source.scans(max_frames=max_frames),
            total=total,
            desc='map',
            unit='scan',
            file=sys.stderr,
            disable=not progress,
        )
        if scan.labels is not None or config.label_source != 'field'
    )
    label_source = LabelSource(registration.label_map)  # --labels (label_source)
    if odometry is None:  # ground truth: only the posed scans, deskewed by the truth
        posed = (scan for scan in labeled if scan.pose is not None)
        labeled = deskewed_by_truth(posed, config)
    for scan in labeled:
        scans += 1
        if scan.pose is not None:
            scan_truth[int(scan.stamp_ns)] = np.asarray(scan.pose)
        if odometry is None:
            labels = label_source(scan.xyz, scan.labels, config).labels
            step = mapper.add(scan.xyz, labels, scan.pose, scan.stamp_ns)
        else:
            moved = odometry.process(
                scan.xyz, scan.labels, scan.stamp_ns, point_times=scan.point_times
            )
            if not moved.accepted:
                continue
            accepted += 1
            if awaits_deskew(moved, scan.point_times, config):
                continue  # the odometry's first scans: skewed, no keyframe of them
            step = mapper.add(
                scan.xyz, scan.labels, moved.pose, scan.stamp_ns, prepared=moved.prepared
            )
        trials += bool(step.tried)
        if step.keyframe is not None:
            keyframe_trials.append(
                {
                    'keyframe': int(step.keyframe.keyframe_id),
                    'stamp_ns': int(scan.stamp_ns),
                    'tried': [int(match) for match in step.tried],
                    'closed': step.loop is not None,
                }
            )
        if step.keyframe is not None and scan.pose is not None:
            truth[step.keyframe.keyframe_id] = np.asarray(scan.pose)
    store = mapper.store
    summary: dict[str, Any] = {
        'scans': scans,
        'accepted': accepted if odometry is not None else scans,
        'keyframes': len(store),
        'memory_mb': store.memory_bytes / 1e6,
        'bytes_per_keyframe': store.memory_bytes / max(len(store), 1),
        'loops': len(mapper.loops),
        'loop_trials': trials,
    }
    if odometry is not None:
        score_loops(summary, mapper, truth, scan_truth, keyframe_trials)
    return {'mapper': mapper, 'summary': summary}


def score_loops(
    summary: dict[str, Any],
    mapper: Any,
    truth: dict[int, Any],
    scan_truth: dict[int, Any],
    keyframe_trials: list[dict[str, Any]],
) -> None:
    """
    Add to ``summary`` the map's scores against the ground truth (with two posed keyframes).

    The ATE of the keyframes with and without the loops, every loop edge's error
    (:func:`loop_edge`), the keyframes that revisit a place (:func:`count_revisits`), the
    ground truth's revisits (``truth`` of the keyframes, ``scan_truth`` of every scan by
    stamp) and where our loop closure stopped on each (:func:`revisit_diagnosis`, from the
    ``keyframe_trials``).
    """
    from mlsemreg_ros.evaluation.loop_peers import ground_truth_revisits
    from mlsemreg_ros.evaluation.trajectory import ate_rmse
    import numpy as np

    store = mapper.store
    ids = [i for i in store.ids if i in truth]
    if len(ids) < 2:
        return
    gt = np.stack([truth[i] for i in ids])
    odom = mapper.keyframe_odometry()
    summary['ate_m'] = ate_rmse(np.stack([store[i].T_map_keyframe for i in ids]), gt)
    summary['ate_odometry_m'] = ate_rmse(np.stack([odom[i] for i in ids]), gt)
    loops = [loop_edge(loop, truth, store) for loop in mapper.loops]
    right = sum(edge['right'] for edge in loops)
    wrong = len(loops) - right
    summary['loop_edges'] = loops
    summary['loops_refused'] = [loop_edge(loop, truth, store) for loop in mapper.refused]
    summary['loops_true'], summary['loops_wrong'] = right, wrong
    summary['revisits'] = int(count_revisits(gt, store.config.map))
    summary['revisit_segments'] = ground_truth_revisits(
        list(scan_truth), list(scan_truth.values())
    )
    for entry in keyframe_trials:  # how far (truly) each tried candidate was
        here = truth.get(entry['keyframe'])
        entry['tried_distance_m'] = [
            None if here is None or m not in truth else float(
                np.linalg.norm(truth[m][:3, 3] - here[:3, 3])
            )
            for m in entry['tried']
        ]  # fmt: skip
    summary['keyframe_trials'] = keyframe_trials
    summary['revisit_diagnosis'] = revisit_diagnosis(summary)


def loop_edge(loop: Any, truth: dict[int, Any], store: Any) -> dict[str, Any]:
    """Return a loop edge against the ground truth: its error, whether it is right, its check."""
    from mlsemreg_ros.core.rigid import invert_transform, rotation_angle_deg
    from mlsemreg_ros.evaluation.loop_peers import is_right
    import numpy as np

    true_motion = invert_transform(truth[loop.match]) @ truth[loop.current]
    error = invert_transform(true_motion) @ loop.T_match_current
    te, re = float(np.linalg.norm(error[:3, 3])), rotation_angle_deg(error)
    edge = {
        'current': int(loop.current),
        'match': int(loop.match),
        'current_stamp_ns': int(store[loop.current].stamp_ns),
        'match_stamp_ns': int(store[loop.match].stamp_ns),
        'distance_m': float(np.linalg.norm(true_motion[:3, 3])),
        'te_m': te,
        're_deg': re,
        'right': is_right(te, re),
        'T_match_current': np.asarray(loop.T_match_current).tolist(),
    }
    if loop.check is not None:
        coarse = invert_transform(true_motion) @ loop.check.T_registration
        edge['refinement'] = {
            'registration_te_m': float(np.linalg.norm(coarse[:3, 3])),
            'registration_re_deg': rotation_angle_deg(coarse),
            'correction_m': loop.check.correction_m,
            'correction_deg': loop.check.correction_deg,
            'inlier_fraction': loop.check.inlier_fraction,
            'submap_keyframes': loop.check.submap_keyframes,
            'reason': loop.check.reason,
        }
    return edge


#: A tried loop candidate is of the same place when its keyframe is truly this close.
SAME_PLACE_M = 10.0


def revisit_diagnosis(summary: dict[str, Any]) -> list[dict[str, Any]]:
    """
    Per ground-truth revisit, where our loop closure stops: what each of its keyframes got.

    ``keyframes`` in the revisit; ``tried``: with a loop candidate registered onto;
    ``tried_same_place``: with a candidate truly within :data:`SAME_PLACE_M` (place
    recognition found the place); ``registered``: the confidence rule accepted the loop
    registration (closed, or refused by the submap check); ``closed_right`` /
    ``closed_wrong``: loops closed. A revisit with keyframes but none tried at the same
    place is missed by place recognition; one tried there but not registered, by the
    registration; registered but not closed, by the submap check.
    """
    edges = summary.get('loop_edges', [])
    refused = summary.get('loops_refused', [])
    out = []
    for first, last in summary['revisit_segments']['segments']:
        inside = [t for t in summary['keyframe_trials'] if first <= t['stamp_ns'] <= last]
        ids = {t['keyframe'] for t in inside}
        closed = [e for e in edges if e['current'] in ids]
        out.append(
            {
                'first_stamp_ns': first,
                'last_stamp_ns': last,
                'keyframes': len(inside),
                'tried': sum(bool(t['tried']) for t in inside),
                'tried_same_place': sum(
                    any(d is not None and d <= SAME_PLACE_M for d in t['tried_distance_m'])
                    for t in inside
                ),
                'registered': len(closed) + sum(e['current'] in ids for e in refused),
                'closed_right': sum(e['right'] for e in closed),
                'closed_wrong': sum(not e['right'] for e in closed),
            }
        )
    return out


def count_revisits(gt: Any, map_config: Any) -> int:
    """Keyframes within 5 m of a keyframe left ``map.loop_min_travel`` metres of travel ago."""
    import numpy as np

    positions = gt[:, :3, 3]
    travel = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))])
    count = 0
    for i in range(len(positions)):
        earlier = travel[i] - travel[:i] >= map_config.loop_min_travel
        near = np.linalg.norm(positions[:i] - positions[i], axis=1) <= 5.0
        count += bool(np.any(earlier & near))
    return count
