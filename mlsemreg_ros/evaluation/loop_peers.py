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
The loop-closure peers of ``mlsemreg map build --baseline``, on the same scans (docs/maps.md).

- ``kiss-slam`` (KISS-SLAM 0.0.2): KISS-ICP split into local maps every 100 m, MapClosures
  between local maps, each detection checked by ICP and voxel overlap, a pose graph; run as
  its own pipeline runs it (the last local map closed, the fine-grained optimization).
- ``map-closures`` (MapClosures 2.2.0, Gupta et al., "Effectively Detecting Loop Closures
  using Point Cloud Density Maps", ICRA 2024): its own pipeline, KISS-ICP with local maps
  of 100 m and every candidate above its inlier threshold taken. MapClosures has no pose
  graph; its loops go into ours (:class:`~mlsemreg_ros.core.maps.pose_graph.PoseGraph`,
  the ``map`` section's sigmas) over the local maps for the ATE with loops.

Each run is scored against the ground truth the same way as our keyframe loops
(``mlsemreg map build``): a loop is right when its relative pose is within
:data:`RIGHT_TRANSLATION_M` and :data:`RIGHT_ROTATION_DEG` of the true one; precision is
the share of the closed loops that are right. Recall is counted in one unit for every
method, the ground truth's revisits (:func:`revisit_segments`): runs of consecutive scans
each within :data:`REVISIT_RADIUS_M` of a scan passed :data:`REVISIT_MIN_TRAVEL_M` or more
of travel before. A revisit is *found* when a right, closed loop's query holds one of its
scans: our keyframe's scan, a peer's local map's scans (:func:`segments_found`). The same
runs cut into places of :data:`REVISIT_PLACE_M` of travel give a finer count. (The earlier
unit, a method's own keyframes or local maps that revisit, stays in the JSON as
``unit_revisits`` and ``unit_recall_pct``.)

:func:`map_closures_relocalize` uses MapClosures as place recognition for
``mlsemreg relocalize --baseline map-closures``: each keyframe's points are a database
entry, a query's best candidate above the inlier threshold gives its pose.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
import contextlib
import ctypes
from dataclasses import dataclass, field
import io
import os
import sys
import time
from typing import Any

from mlsemreg_ros.core.rigid import invert_transform, rotation_angle_deg
from mlsemreg_ros.datasets.source import Scan
from mlsemreg_ros.evaluation.estimators import KissIcpEstimator
import numpy as np

LOOP_PEERS = ('kiss-slam', 'map-closures')
#: A loop edge (or a relocalization) is right within these bounds of the ground truth.
RIGHT_TRANSLATION_M = 0.6
RIGHT_ROTATION_DEG = 5.0
#: A local map revisits an earlier one when this many of its scans lie within
#: :data:`REVISIT_RADIUS_M` of that map's scans, passed 30 m of travel or more before.
REVISIT_RADIUS_M = 5.0
REVISIT_MIN_SCANS = 10
REVISIT_MIN_TRAVEL_M = 30.0  # as map.loop_min_travel
#: The finer count cuts each revisit into places of at most this much travel.
REVISIT_PLACE_M = 10.0
LOCAL_MAP_SPLIT_M = 100.0  # both peers' default: a new local map 100 m from the last start


def edge_error(T_estimate: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """Return (translation m, rotation deg) of ``inv(T_true) @ T_estimate``."""
    error = invert_transform(T_true) @ np.asarray(T_estimate, dtype=np.float64)
    return float(np.linalg.norm(error[:3, 3])), rotation_angle_deg(error)


def is_right(te_m: float, re_deg: float) -> bool:
    """Within :data:`RIGHT_TRANSLATION_M` and :data:`RIGHT_ROTATION_DEG`."""
    return te_m <= RIGHT_TRANSLATION_M and re_deg <= RIGHT_ROTATION_DEG


@dataclass
class LocalMapLoops:
    """A peer's run: its local maps, the loops it proposed and closed, its poses."""

    method: str
    starts: list[int]  # scan number at which each local map starts (its key pose)
    proposed: list[tuple[int, int, np.ndarray, bool]] = field(default_factory=list)
    # (reference map, query map, T_query_reference, closed)
    poses_loops: np.ndarray | None = None  # (F, 4, 4), after the loops
    poses_odometry: np.ndarray | None = None  # (F, 4, 4), the odometry alone
    truth: list[np.ndarray | None] = field(default_factory=list)  # per scan
    stamps_ns: list[int] = field(default_factory=list)  # per scan
    seconds: float = 0.0

    def query_stamps(self, query: int) -> tuple[int, int]:
        """Return the first and last stamp of local map ``query``'s scans."""
        end = self.starts[query + 1] - 1 if query + 1 < len(self.starts) else len(self.truth) - 1
        return self.stamps_ns[self.starts[query]], self.stamps_ns[end]


class _DeskewedKissIcp(KissIcpEstimator):
    """KISS-ICP that keeps the scan it deskewed (MapClosures maps deskewed scans)."""

    deskewed: np.ndarray | None = None

    def _register(self, points: np.ndarray, times: np.ndarray) -> np.ndarray:
        self.deskewed, _ = self.odometry.register_frame(points, times)
        return self.odometry.last_pose.copy()


@contextlib.contextmanager
def _silenced_stdout() -> Iterator[None]:
    """Send file descriptor 1 to /dev/null (KISS-SLAM's g2o prints every iteration in C++)."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, 'w') as null:
            os.dup2(null.fileno(), 1)
            with contextlib.redirect_stdout(io.StringIO()):
                yield
    finally:
        sys.stdout.flush()
        ctypes.CDLL(None).fflush(None)  # C stdio's buffer too, or it prints after the restore
        os.dup2(saved, 1)
        os.close(saved)


def run_kiss_slam(scans: Iterable[Scan], split_m: float = LOCAL_MAP_SPLIT_M) -> LocalMapLoops:
    """
    Run KISS-SLAM over ``scans`` as its own pipeline does; record every loop it tried.

    ``split_m``: its ``local_mapper.splitting_distance`` (a new local map this far, in a
    straight line, from the current one's start).
    """
    with _silenced_stdout():
        return _run_kiss_slam(scans, split_m)


def _run_kiss_slam(scans: Iterable[Scan], split_m: float) -> LocalMapLoops:
    from mlsemreg_ros.evaluation.peer_estimators import KissSlamEstimator

    tic = time.perf_counter()
    estimator = KissSlamEstimator()
    slam = estimator.odometry
    slam.config.local_mapper.splitting_distance = split_m  # as its config file would set it
    slam.local_map_splitting_distance = split_m  # (KissSLAM reads it once, in __init__)
    run = LocalMapLoops('KISS-SLAM', [0])
    compute = slam.closer.compute

    def recorded(query_id: int, points: Any, graph: Any) -> Any:
        good, reference, query, T_query_reference = compute(query_id, points, graph)
        if reference >= 0:  # MapClosures detected it; good: the overlap check agreed
            closed = bool(good)  # (a numpy bool from its overlap test)
            run.proposed.append((int(reference), int(query), np.array(T_query_reference), closed))
        return good, reference, query, T_query_reference

    slam.closer.compute = recorded
    for number, scan in enumerate(scans):
        before = slam.local_map_graph.last_id
        estimator.step(scan)
        if slam.local_map_graph.last_id != before:
            run.starts.append(number)
        run.truth.append(scan.pose)
        run.stamps_ns.append(int(scan.stamp_ns))
    slam.generate_new_node()  # as kiss_slam.pipeline ends a run
    slam.local_map_graph.erase_last_local_map()
    poses, _ = slam.fine_grained_optimization()
    run.poses_loops = np.asarray(poses, dtype=np.float64)
    run.poses_odometry = _chained(
        [node.local_trajectory for node in slam.local_map_graph.local_maps()]
    )
    run.seconds = time.perf_counter() - tic
    return run


def _chained(trajectories: list[list[np.ndarray]]) -> np.ndarray:
    """Scan poses of local trajectories chained without loops (map 0 holds scan 0)."""
    key, poses = np.eye(4), []
    for number, trajectory in enumerate(trajectories):
        first = 0 if number == 0 else 1
        poses += [key @ T for T in trajectory[first:]]
        key = key @ trajectory[-1]
    return np.asarray(poses, dtype=np.float64)


def run_map_closures(
    scans: Iterable[Scan], map_config: Any, split_m: float = LOCAL_MAP_SPLIT_M
) -> LocalMapLoops:
    """
    Run MapClosures' pipeline over ``scans``; loops into our pose graph over its local maps.

    As ``map_closures.pipeline``: KISS-ICP (voxel 1 m, 100 m range, deskew), the deskewed
    scans in a voxel map of ``density_map_resolution``; past ``split_m`` (its pipeline: the
    100 m range) from the local map's start, its points go to ``get_closures`` and every
    candidate with more than ``inliers_threshold`` inliers is a loop; the points beyond the
    100 m range are dropped and a new local map starts at the current scan.
    """
    from map_closures.config import MapClosuresConfig
    from map_closures.map_closures import MapClosures
    from map_closures.voxel_map import VoxelMap

    tic = time.perf_counter()
    config = MapClosuresConfig()
    closures = MapClosures(config)
    estimator = _DeskewedKissIcp(max_range=LOCAL_MAP_SPLIT_M)
    voxels = VoxelMap(voxel_size=config.density_map_resolution, max_distance=LOCAL_MAP_SPLIT_M)
    run = LocalMapLoops('MapClosures', [0])
    odometry: list[np.ndarray] = []
    T_world_map = np.eye(4)

    def close_local_map(pose: np.ndarray) -> None:
        query = len(run.starts) - 1
        for closure in closures.get_closures(query, voxels.point_cloud()):
            if closure.number_of_inliers > config.inliers_threshold:
                T = np.asarray(closure.pose, dtype=np.float64)
                run.proposed.append((int(closure.source_id), query, T, True))
        voxels.remove_far_away_points((invert_transform(T_world_map) @ pose)[:3, 3])
        kept = voxels.point_cloud()
        voxels.clear()
        voxels.integrate_frame(kept, invert_transform(pose) @ T_world_map)

    for number, scan in enumerate(scans):
        estimator.step(scan)
        pose = estimator.odometry.last_pose.copy()
        odometry.append(pose)
        run.truth.append(scan.pose)
        run.stamps_ns.append(int(scan.stamp_ns))
        T_map_scan = invert_transform(T_world_map) @ pose
        voxels.integrate_frame(np.asarray(estimator.deskewed), T_map_scan)
        if np.linalg.norm(T_map_scan[:3, 3]) > split_m:
            close_local_map(pose)
            T_world_map = pose
            run.starts.append(number)
    if odometry and run.starts[-1] != len(odometry) - 1:  # the last one, as its pipeline
        close_local_map(odometry[-1])
    run.poses_odometry = np.asarray(odometry, dtype=np.float64)
    run.poses_loops = _optimized(run, map_config)
    run.seconds = time.perf_counter() - tic
    return run


def _optimized(run: LocalMapLoops, map_config: Any) -> np.ndarray:
    """Scan poses after our pose graph over the local maps with the run's closed loops."""
    from mlsemreg_ros.core.maps.pose_graph import PoseGraph

    odometry = run.poses_odometry
    keys = [odometry[start] for start in run.starts]
    graph = PoseGraph(map_config)
    for node, key in enumerate(keys):
        previous = None if node == 0 else invert_transform(keys[node - 1]) @ key
        graph.add_keyframe(node, key, previous)
    closed = [(r, q, T) for r, q, T, good in run.proposed if good]
    for reference, query, T_query_reference in closed:
        graph.add_loop(query, reference, T_query_reference)
    optimized = graph.optimize() if closed else dict(enumerate(keys))
    node_of = np.searchsorted(np.asarray(run.starts), np.arange(len(odometry)), side='right') - 1
    return np.stack(
        [optimized[n] @ invert_transform(keys[n]) @ odometry[i] for i, n in enumerate(node_of)]
    )


def revisit_segments(
    stamps_ns: np.ndarray, positions: np.ndarray, place_m: float | None = None
) -> list[tuple[int, int]]:
    """
    Return the ground truth's revisits as ``(first stamp, last stamp)`` of each.

    A revisit is a run of consecutive scans (``stamps_ns`` (F,), true ``positions`` (F, 3),
    in driving order) each within :data:`REVISIT_RADIUS_M` of a scan passed
    :data:`REVISIT_MIN_TRAVEL_M` or more of travel before. ``place_m``: each run is cut into
    pieces of at most this much travel (the places of a revisit).
    """
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    travel = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))])
    revisiting = np.zeros(len(positions), dtype=bool)
    for i in range(len(positions)):
        earlier = travel[i] - travel[:i] >= REVISIT_MIN_TRAVEL_M
        near = np.linalg.norm(positions[:i] - positions[i], axis=1) <= REVISIT_RADIUS_M
        revisiting[i] = bool(np.any(earlier & near))
    edges = np.flatnonzero(np.diff(np.concatenate([[0], revisiting.astype(np.int8), [0]])))
    segments = []
    for first, end in zip(edges[::2], edges[1::2], strict=True):
        start = first
        for i in range(first, end):
            if place_m is not None and travel[i] - travel[start] >= place_m:
                segments.append((int(stamps_ns[start]), int(stamps_ns[i - 1])))
                start = i
        segments.append((int(stamps_ns[start]), int(stamps_ns[end - 1])))
    return segments


def segments_found(segments: list[tuple[int, int]], queries: Iterable[tuple[int, int]]) -> int:
    """Return how many ``segments`` (stamp ranges) hold a scan of one of the ``queries``."""
    spans = list(queries)
    return sum(
        any(first <= last_q and first_q <= last for first_q, last_q in spans)
        for first, last in segments
    )


def revisit_recall(revisits: dict[str, list], queries: list[tuple[int, int]]) -> dict[str, Any]:
    """
    Revisits and places found by the right loops' ``queries`` (stamp ranges), and the recall.

    ``revisits``: ``{'segments': ..., 'places': ...}`` of :func:`ground_truth_revisits`.
    """
    segments, places = revisits['segments'], revisits['places']
    found, places_found = segments_found(segments, queries), segments_found(places, queries)
    return {
        'revisits': len(segments),
        'revisits_found': found,
        'recall_pct': 100.0 * found / len(segments) if segments else None,
        'places': len(places),
        'places_found': places_found,
        'place_recall_pct': 100.0 * places_found / len(places) if places else None,
    }


def ground_truth_revisits(stamps_ns: list[int], truth: list[np.ndarray]) -> dict[str, list]:
    """Return the revisits of a drive, whole and cut into places (:func:`revisit_segments`)."""
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    positions = np.stack([np.asarray(pose)[:3, 3] for pose in truth])
    return {
        'segments': revisit_segments(stamps, positions),
        'places': revisit_segments(stamps, positions, REVISIT_PLACE_M),
    }


def score_local_map_loops(
    run: LocalMapLoops, revisits: dict[str, list] | None = None
) -> dict[str, Any]:
    """
    Loops proposed / closed / right / wrong, precision, recall and the ATEs of a peer run.

    ``revisits``: the drive's ground-truth revisits (:func:`ground_truth_revisits`, the same
    for every method); None: from the run's own scans.
    """
    from mlsemreg_ros.evaluation.trajectory import ate_rmse

    posed = [i for i, pose in enumerate(run.truth) if pose is not None]
    summary: dict[str, Any] = {
        'method': run.method,
        'scans': len(run.truth),
        'local_maps': len(run.starts),
        'proposed': len(run.proposed),
        'closed': sum(bool(good) for *_, good in run.proposed),
        'time_s': run.seconds,
    }
    if len(posed) < len(run.truth) or len(posed) < 2:
        return summary  # scored against the ground truth only where every scan has it
    truth = np.stack(run.truth)
    edges = []
    for reference, query, T, good in run.proposed:
        true = invert_transform(truth[run.starts[query]]) @ truth[run.starts[reference]]
        te, re = edge_error(T, true)
        edges.append(
            {
                'reference': reference,
                'query': query,
                'closed': bool(good),
                'te_m': te,
                're_deg': re,
                'right': is_right(te, re),
                'same_place': bool(reference in _revisited(run, truth, query)),
            }
        )
    closed = [edge for edge in edges if edge['closed']]
    right = [edge for edge in closed if edge['right']]
    revisiting = [q for q in range(len(run.starts)) if _revisited(run, truth, q)]
    found = {edge['query'] for edge in right}
    if revisits is None and len(run.stamps_ns) == len(run.truth):
        revisits = ground_truth_revisits(run.stamps_ns, run.truth)
    summary.update(
        loop_edges=edges,
        right=len(right),
        wrong=len(closed) - len(right),
        precision_pct=100.0 * len(right) / len(closed) if closed else None,
        unit_revisits=len(revisiting),
        unit_recall_pct=(
            100.0 * len(found & set(revisiting)) / len(revisiting) if revisiting else None
        ),
        ate_loops_m=ate_rmse(run.poses_loops, truth),
        ate_odometry_m=ate_rmse(run.poses_odometry, truth),
    )
    if revisits is not None:
        summary.update(revisit_recall(revisits, [run.query_stamps(q) for q in sorted(found)]))
    return summary


def _revisited(run: LocalMapLoops, truth: np.ndarray, query: int) -> list[int]:
    """
    Earlier local maps whose place local map ``query`` comes back to.

    As our keyframes' revisits (``count_revisits`` of ``mlsemreg map build``): at least
    :data:`REVISIT_MIN_SCANS` scans of ``query`` lie within :data:`REVISIT_RADIUS_M` of a
    scan of the earlier map passed :data:`REVISIT_MIN_TRAVEL_M` or more of travel before.
    """
    positions = truth[:, :3, 3]
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    travel = np.concatenate([[0.0], np.cumsum(steps)])
    bounds = [*run.starts, len(truth)]
    here = np.arange(bounds[query], bounds[query + 1])
    out = []
    for reference in range(query):
        there = np.arange(bounds[reference], bounds[reference + 1])
        near = np.linalg.norm(positions[here, None] - positions[None, there], axis=2)
        earlier = travel[here, None] - travel[None, there] >= REVISIT_MIN_TRAVEL_M
        if int(np.any((near <= REVISIT_RADIUS_M) & earlier, axis=1).sum()) >= REVISIT_MIN_SCANS:
            out.append(reference)
    return out


LOOP_RUNNERS: dict[str, Callable[..., LocalMapLoops]] = {
    'kiss-slam': lambda scans, map_config, split_m: run_kiss_slam(scans, split_m),
    'map-closures': run_map_closures,
}


def map_closures_relocalize(
    keyframes: list[tuple[np.ndarray, np.ndarray]], queries: Iterable[np.ndarray]
) -> list[Any]:
    """
    Relocalize with MapClosures as place recognition: one :class:`Relocalization` per query.

    - ``keyframes``: (points in the keyframe's frame, ``T_map_keyframe``), the database;
    - a query is matched against the keyframes only (queries enter MapClosures' database as
      it adds every query; their own matches are skipped): its best candidate with more than
      ``inliers_threshold`` inliers gives ``T_map_query = T_map_keyframe @ inv(T_query_keyframe)``;
      none: refused.
    """
    from map_closures.config import MapClosuresConfig
    from map_closures.map_closures import MapClosures
    from mlsemreg_ros.core.maps.relocalization import CandidateTrial, Relocalization

    config = MapClosuresConfig()
    closures = MapClosures(config)
    tic = time.perf_counter()
    for number, (points, _) in enumerate(keyframes):
        closures.get_closures(number, np.asarray(points, dtype=np.float64))
    build_ms = 1e3 * (time.perf_counter() - tic)
    gap = len(keyframes) + 10  # beyond MapClosures' skip of 3 neighbouring ids
    answers = []
    for number, points in enumerate(queries):
        tic = time.perf_counter()
        found = [
            c
            for c in closures.get_closures(gap + number, np.asarray(points, dtype=np.float64))
            if c.source_id < len(keyframes) and c.number_of_inliers > config.inliers_threshold
        ]
        best = max(found, key=lambda c: c.number_of_inliers, default=None)
        timings = {'total_ms': 1e3 * (time.perf_counter() - tic), 'database_ms': build_ms}
        if best is None:
            answers.append(Relocalization(False, None, -1, timings_ms=timings))
            continue
        T_map_keyframe = keyframes[best.source_id][1]
        T_map_query = T_map_keyframe @ invert_transform(np.asarray(best.pose, dtype=np.float64))
        trial = CandidateTrial(best.source_id, 0.0, True, best.number_of_inliers, '', 0.0)
        answers.append(Relocalization(True, T_map_query, best.source_id, [trial], None, timings))
    return answers


def run_loop_peers(
    open_source: Callable[[], Any],
    names: list[str],
    max_frames: int | None,
    map_config: Any,
    split_m: float = LOCAL_MAP_SPLIT_M,
    revisits: dict[str, list] | None = None,
) -> dict[str, dict[str, Any]]:
    """
    Run each named peer on a fresh source (``max_frames`` scans); its scored summary.

    ``split_m``: the peers' local-map size (a new one this far from the last start);
    ``revisits``: the ground truth's revisits every method is scored on (None: each run's).
    """
    out = {}
    for name in dict.fromkeys(map(str, names)):
        source = open_source()
        try:
            run = LOOP_RUNNERS[name](source.scans(max_frames=max_frames), map_config, split_m)
        finally:
            source.close()
        out[name] = score_local_map_loops(run, revisits)
    return out


def ours_loop_summary(summary: dict[str, Any], seconds: float) -> dict[str, Any]:
    """Our build's summary (``mlsemreg map build``) in the peers' terms."""
    edges = summary.get('loop_edges', [])
    right = [edge for edge in edges if edge['right']]
    revisits = summary.get('revisits', 0)
    out = {
        'method': 'ML-SemReg',
        'scans': summary['scans'],
        'keyframes': summary['keyframes'],
        'proposed': len(edges) + len(summary.get('loops_refused', [])),
        'closed': summary['loops'],
        'right': len(right) if 'loop_edges' in summary else None,
        'wrong': summary.get('loops_wrong'),
        'precision_pct': 100.0 * len(right) / len(edges) if edges else None,
        'unit_revisits': revisits,
        'unit_recall_pct': (
            100.0 * len({edge['current'] for edge in right}) / revisits if revisits else None
        ),
        'ate_loops_m': summary.get('ate_m'),
        'ate_odometry_m': summary.get('ate_odometry_m'),
        'time_s': seconds,
    }
    if 'revisit_segments' in summary:
        stamps = [(edge['current_stamp_ns'],) * 2 for edge in right]
        out.update(revisit_recall(summary['revisit_segments'], stamps))
    return out


def loop_table(summaries: list[dict[str, Any]]) -> Any:
    """Return the loops of every method side by side (a ResultTable)."""
    from mlsemreg_ros.evaluation.tables import ResultTable

    def number(value: Any, spec: str) -> str:
        return '-' if value is None else format(value, spec)

    rows = [
        [
            s['method'],
            str(s.get('keyframes', s.get('local_maps'))),
            str(s['proposed']),
            str(s['closed']),
            number(s.get('right'), 'd'),
            number(s.get('wrong'), 'd'),
            number(s.get('precision_pct'), '.1f'),
            _found(s, 'revisits'),
            number(s.get('recall_pct'), '.1f'),
            _found(s, 'places'),
            number(s.get('place_recall_pct'), '.1f'),
            number(s.get('ate_loops_m'), '.3f'),
            number(s.get('ate_odometry_m'), '.3f'),
            f'{s["time_s"]:.0f}',
        ]
        for s in summaries
    ]
    header = (
        'method', 'keyframes / local maps', 'proposed', 'closed', 'right', 'wrong', 'precision %',
        'revisits found', 'recall %', f'{REVISIT_PLACE_M:.0f} m places found', 'recall %',
        'ATE loops m', 'ATE odometry m', 'time s',
    )  # fmt: skip
    return ResultTable(header, rows, left_columns=1)


def _found(summary: dict[str, Any], key: str) -> str:
    """``found / total`` of a summary's revisits or places, '-' without ground truth."""
    if summary.get(key) is None:
        return '-'
    return f'{summary[f"{key}_found"]} / {summary[key]}'
