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
``mlsemreg map``: build keyframe maps from bags and write relocalization queries (docs/maps.md).

- ``mlsemreg map build BAG MAP [--poses odometry|ground-truth]``: keyframes every
  ``map.keyframe_distance``; with odometry poses the loops are closed (``map.loop_closure``)
  and the ATE with and without the loop closures is printed when the bag has ground truth;
- ``mlsemreg map queries BAG OUT --every K``: every K-th scan as a query file with its
  ground truth (``T_map_scan``: the bag's ground-truth frame);
- ``mlsemreg map sim-queries OUT --drive reverse|other``: scans of a second simulated drive
  through the world of ``mlsemreg simulate --seed S`` (the opposite direction in the other
  lane, or a route of another seed kept where it is far from the first drive); in the field
  world ``--deskew odometry`` (the default) runs the odometry over every sweep and writes
  the scans it deskewed, the points the node relocalizes;
- ``mlsemreg map export MAP OUT.pcd|OUT.ply`` and ``mlsemreg map import CLOUD MAP
  [--trajectory FILE]``: point maps for and from other tools (``tools/map_points.py``).
"""

from __future__ import annotations

import json
from pathlib import Path
import sys
from typing import Annotated, Any, Literal

from mlsemreg_ros.evaluation.peer_runs import LoopPeer
from mlsemreg_ros.tools.common import (
    CommandError,
    ConfigOption,
    ForceOption,
    JsonOption,
    LabelsOption,
    QuietOption,
    replace_output,
    SetOption,
    settings,
    with_labels,
)
from mlsemreg_ros.tools.map_points import (
    export_command,
    EXPORT_HELP,
    import_command,
    IMPORT_HELP,
)
import typer

HELP = 'Keyframe maps: build from a bag, export or import point maps (PCD, PLY), write queries.'
BUILD_HELP = 'Build a map folder (docs/maps.md) from a labeled bag.'
QUERIES_HELP = 'Write every K-th scan of a bag (with ground truth) as relocalization queries.'
SIM_QUERIES_HELP = 'Write relocalization queries from a second drive through a simulated world.'

app = typer.Typer(
    name='map',
    no_args_is_help=True,
    add_completion=False,
    rich_markup_mode='rich',
    context_settings={'help_option_names': ['-h', '--help']},
    help=HELP,
)


@app.command('build', help=BUILD_HELP)
def build(
    bag: Annotated[
        Path, typer.Argument(help='rosbag2 folder (or KITTI sequence) of labeled scans')
    ],
    out: Annotated[Path, typer.Argument(help='map folder to write')],
    poses: Annotated[
        Literal['odometry', 'ground-truth'],
        typer.Option(help='keyframe poses: the odometry (with loop closure) or the ground truth'),
    ] = 'odometry',
    max_frames: Annotated[
        int | None, typer.Option(min=1, help='read at most this many scans')
    ] = None,
    frame_id: Annotated[str, typer.Option(help='frame of the map')] = 'map',
    baseline: Annotated[
        list[LoopPeer] | None,
        typer.Option(
            help='also run this loop-closure peer on the same scans and compare the loops '
            '(--poses odometry); repeatable',
        ),
    ] = None,
    peer_local_map: Annotated[
        float,
        typer.Option(
            min=1.0,
            help="the --baseline peers' local-map size, m (KISS-SLAM's "
            'local_mapper.splitting_distance; their default 100)',
        ),
    ] = 100.0,
    config: ConfigOption = None,
    labels: LabelsOption = None,
    overrides: SetOption = None,
    json_path: JsonOption = None,
    force: ForceOption = False,
    quiet: QuietOption = False,
) -> int:
    """Build a map folder from a bag."""
    import time

    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.maps.map_io import MapError, save_map
    from mlsemreg_ros.datasets.factory import open_scan_source
    from mlsemreg_ros.datasets.source import SourceError
    from mlsemreg_ros.evaluation import peer_runs
    from mlsemreg_ros.evaluation.tables import print_text

    peers = [str(peer) for peer in baseline or []]
    if peers and poses != 'odometry':
        raise CommandError('--baseline compares loop closures: it needs --poses odometry', 2)
    try:
        peer_runs.require_peers(peers)
    except peer_runs.PeerUnavailable as error:
        raise CommandError(str(error), 2) from None
    (core,) = settings((RegistrationConfig,), config, with_labels(overrides, labels))
    replace_output(out, force)
    try:
        source = open_scan_source(bag)
    except (SourceError, OSError, ValueError) as error:
        raise CommandError(f'cannot read {bag}: {error}') from None
    tic = time.perf_counter()
    try:
        built = build_map(source, core, poses, max_frames, progress=not quiet)
    finally:
        source.close()
    seconds = time.perf_counter() - tic
    built['summary']['time_s'] = seconds
    if len(built['mapper'].store) == 0:
        raise CommandError(
            f'{bag}: no keyframe (no labeled scan, or none with ground truth for '
            '--poses ground-truth)'
        )
    try:
        save_map(out, built['mapper'].store, frame_id, core)
    except MapError as error:
        raise CommandError(str(error)) from None
    summary = built['summary']
    print_text(
        f'wrote {summary["keyframes"]} keyframes ({summary["memory_mb"]:.1f} MB, '
        f'{summary["bytes_per_keyframe"] / 1e3:.0f} kB each) from {summary["scans"]} scans '
        f'to {out}; poses: {poses}'
    )
    if poses == 'odometry':
        print_text(
            f'odometry: {summary["accepted"]}/{summary["scans"]} scans accepted; loops '
            f'closed: {summary["loops"]} (tried on {summary["loop_trials"]} keyframes)'
        )
    if 'ate_m' in summary:
        print_text(
            f'ATE of the keyframes: {summary["ate_m"]:.3f} m with the loop closures, '
            f'{summary["ate_odometry_m"]:.3f} m without; loops on revisits: '
            f'{summary["loops_true"]} right, {summary["loops_wrong"]} wrong, of '
            f'{summary["revisits"]} keyframes that revisit a place'
        )
    if peers:
        summary['baselines'] = _compare_loops(
            bag, peers, max_frames, core, summary, seconds, peer_local_map
        )
    if json_path is not None:
        json_path.write_text(json.dumps(summary, indent=2) + '\n')
    return 0


def _compare_loops(
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

    results = run_loop_peers(lambda: open_scan_source(bag), peers, max_frames, core.map, split_m)
    mine = ours_loop_summary(ours, seconds)
    print_table(loop_table([mine, *results.values()]))
    return {'ours': mine, **results}


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
    from mlsemreg_ros.evaluation.trajectory import ate_rmse
    import numpy as np
    from tqdm import tqdm

    registration = Registration(config)
    mapper = Mapper(registration)
    if poses == 'ground-truth':
        mapper.store.config = config.replace({'map.loop_closure': False})
    odometry = Odometry(registration) if poses == 'odometry' else None
    truth: dict[int, np.ndarray] = {}  # keyframe id -> ground truth
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
        labeled = _deskewed_by_truth((scan for scan in labeled if scan.pose is not None), config)
    for scan in labeled:
        scans += 1
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
    ids = [i for i in store.ids if i in truth]
    if odometry is not None and len(ids) >= 2:
        gt = np.stack([truth[i] for i in ids])
        odom = mapper.keyframe_odometry()
        summary['ate_m'] = ate_rmse(np.stack([store[i].T_map_keyframe for i in ids]), gt)
        summary['ate_odometry_m'] = ate_rmse(np.stack([odom[i] for i in ids]), gt)
        loops = [_loop_edge(loop, truth, store) for loop in mapper.loops]
        right = sum(edge['right'] for edge in loops)
        wrong = len(loops) - right
        summary['loop_edges'] = loops
        summary['loops_refused'] = [_loop_edge(loop, truth, store) for loop in mapper.refused]
        summary['loops_true'], summary['loops_wrong'] = right, wrong
        summary['revisits'] = int(count_revisits(gt, config.map))
    return {'mapper': mapper, 'summary': summary}


def _deskewed_by_truth(scans: Any, config: Any) -> Any:
    """
    Yield the posed scans with their points deskewed to their stamps by the true motion.

    A map with ground-truth poses gets the motion compensation that the odometry gives
    its keyframes (``preprocess.deskew``, ``core/features/deskew.py``), with the true
    motion: the constant twist from the scan's pose to the next scan's (its own sweep);
    the last scan takes the twist from the one before. Scans without point times stay as
    they are.
    """
    from dataclasses import replace

    from mlsemreg_ros.core.features.deskew import deskew, sweep_motion

    def moved(scan: Any, a: Any, b: Any) -> Any:
        if config.preprocess.deskew == 'off' or scan.point_times is None:
            return scan
        motion = sweep_motion(a.pose, a.stamp_ns, b.pose, b.stamp_ns)
        if motion is None:
            return scan
        return replace(scan, xyz=deskew(scan.xyz, scan.point_times, motion))

    before = held = None
    for scan in scans:
        if held is not None:
            yield moved(held, held, scan)  # the motion over its own sweep, to the next stamp
        before, held = held, scan
    if held is not None:  # the last scan: the motion from the one before (none: as it is)
        yield held if before is None else moved(held, before, held)


def _loop_edge(loop: Any, truth: dict[int, Any], store: Any) -> dict[str, Any]:
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


@app.command('queries', help=QUERIES_HELP)
def queries(
    bag: Annotated[
        Path, typer.Argument(help='rosbag2 folder (or KITTI sequence) of labeled scans')
    ],
    out: Annotated[Path, typer.Argument(help='folder of query files to write')],
    every: Annotated[int, typer.Option(min=1, help='write every K-th scan')] = 5,
    start: Annotated[int, typer.Option(min=0, help='first scan written')] = 0,
    force: ForceOption = False,
) -> int:
    """Write every K-th scan of a bag as a query file."""
    from mlsemreg_ros.datasets.factory import open_scan_source
    from mlsemreg_ros.datasets.query_files import write_query
    from mlsemreg_ros.datasets.source import SourceError
    from mlsemreg_ros.evaluation.tables import print_text

    replace_output(out, force)
    try:
        source = open_scan_source(bag)
    except (SourceError, OSError, ValueError) as error:
        raise CommandError(f'cannot read {bag}: {error}') from None
    out.mkdir(parents=True)
    written = 0
    try:
        for scan in source.scans():
            if scan.index < start or (scan.index - start) % every or scan.labels is None:
                continue
            write_query(
                out / f'{scan.index:06d}.npz', scan.xyz, scan.labels, scan.pose, scan.stamp_ns
            )
            written += 1
    finally:
        source.close()
    print_text(f'wrote {written} queries to {out}')
    return 0


@app.command('sim-queries', help=SIM_QUERIES_HELP)
def sim_queries(
    out: Annotated[Path, typer.Argument(help='folder of query files to write')],
    seed: Annotated[
        int, typer.Option(min=0, help='seed of the mapped drive (mlsemreg simulate --seed)')
    ] = 0,
    frames: Annotated[int, typer.Option(min=2, help='frames of the mapped drive')] = 200,
    drive: Annotated[
        Literal['reverse', 'other'],
        typer.Option(
            help='reverse: the same streets backwards in the other lane; other: a route '
            'of --route-seed'
        ),
    ] = 'reverse',
    every: Annotated[int, typer.Option(min=1, help='write every K-th scan')] = 5,
    lane_change: Annotated[
        float, typer.Option(help='reverse: lateral shift to the left, m')
    ] = 3.6,
    start_offset: Annotated[
        float, typer.Option(min=0.0, help='reverse: metres skipped at the start')
    ] = 0.5,
    route_seed: Annotated[int, typer.Option(min=0, help='other: seed of the route')] = 7,
    route_frames: Annotated[int, typer.Option(min=2, help='other: frames of the route')] = 300,
    min_distance: Annotated[
        float,
        typer.Option(min=0.0, help='other: keep scans at least this far from the mapped drive, m'),
    ] = 80.0,
    noise_seed: Annotated[int, typer.Option(min=0, help='seed of the sensor noise')] = 1000,
    realism: Annotated[
        Literal['clean', 'field'],
        typer.Option(
            help='the world of `mlsemreg simulate --realism`: clean, or field (HDL-64 skewed '
            'sweeps, moving objects, network labels; --drive other is the loop route)'
        ),
    ] = 'clean',
    deskew: Annotated[
        Literal['odometry', 'previous', 'sweep', 'off'],
        typer.Option(
            help='field: odometry runs the odometry (--config/--set, no IMU) over every sweep '
            'and writes the scans it deskewed (what the node relocalizes; sweeps it rejected '
            'or left skewed are skipped); or motion-compensate each sweep to its start with '
            'the true twist over the previous period (as a constant-velocity prediction), '
            'over the sweep itself (as an IMU-aided deskew), or not (the raw skewed sweep)'
        ),
    ] = 'odometry',
    config: ConfigOption = None,
    overrides: SetOption = None,
    force: ForceOption = False,
) -> int:
    """Write relocalization queries from a second simulated drive."""
    from mlsemreg_ros.evaluation.tables import print_text
    from mlsemreg_ros.simulation.revisit_queries import SimQueries, write_sim_queries

    request = SimQueries(
        seed=seed,
        frames=frames,
        drive=drive,
        every=every,
        lane_change=lane_change,
        start_offset=start_offset,
        route_seed=route_seed,
        route_frames=route_frames,
        min_distance=min_distance,
        noise_seed=noise_seed,
        realism=realism,
        deskew=deskew,
    )
    replace_output(out, force)
    registration = None
    if realism == 'field' and deskew == 'odometry':  # the odometry deskews the sweeps
        from mlsemreg_ros.core.config import RegistrationConfig
        from mlsemreg_ros.core.pipeline import Registration

        (core,) = settings((RegistrationConfig,), config, overrides)
        registration = Registration(core)
    print_text(write_sim_queries(out, request, registration))
    return 0


@app.command(
    'pair-chain',
    help='Split a chain of pair files into a map (even frames) and queries (odd frames).',
)
def pair_chain(
    pairs: Annotated[Path, typer.Argument(help='folder of chained pair files (.npz)')],
    out_map: Annotated[Path, typer.Argument(help='map folder to write (even frames)')],
    out_queries: Annotated[Path, typer.Argument(help='query folder to write (odd frames)')],
    force: ForceOption = False,
) -> int:
    """Map of the even frames of a pair chain, queries of the odd ones (docs/maps.md)."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.matching.labels import LabelMap
    from mlsemreg_ros.datasets.pair_chain import chain_frames
    from mlsemreg_ros.evaluation.tables import print_text

    files = sorted(pairs.glob('*.npz'))
    if not files:
        raise CommandError(f'{pairs}: no pair files')
    try:
        frames = chain_frames(files)
    except (OSError, KeyError, ValueError) as error:
        raise CommandError(f'{pairs}: {error}') from None
    replace_output(out_map, force)
    replace_output(out_queries, force)
    write_pair_chain(frames, out_map, out_queries, RegistrationConfig(), LabelMap.load())
    print_text(
        f'wrote {len(frames[::2])} keyframes to {out_map} and {len(frames[1::2])} queries '
        f'to {out_queries}'
    )
    return 0


def write_pair_chain(
    frames: list, out_map: Path, out_queries: Path, config: Any, label_map: Any
) -> None:
    """Even frames as map keyframes (at their chained poses), odd frames as queries."""
    from mlsemreg_ros.core.maps.keyframe_store import KeyframeStore
    from mlsemreg_ros.core.maps.map_io import save_map
    from mlsemreg_ros.datasets.query_files import write_query

    store = KeyframeStore(config.replace({'map.max_keyframes': 10**6}), label_map)
    for frame in frames[::2]:
        store.add(frame.points, label_map.to_learning(frame.labels), frame.T_0_frame)
    save_map(out_map, store, 'map', config)
    out_queries.mkdir(parents=True)
    for number, frame in enumerate(frames):
        if number % 2:
            write_query(
                out_queries / f'{number:06d}.npz', frame.points, frame.labels, frame.T_0_frame, 0
            )


# Point maps in PCD / PLY (tools/map_points.py): the commands only parse and call the core.
app.command('export', help=EXPORT_HELP)(export_command)
app.command('import', help=IMPORT_HELP)(import_command)
