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

from pathlib import Path
from typing import Annotated, Any, Literal

from mlsemreg_ros.evaluation.peer_runs import LoopPeer
from mlsemreg_ros.tools.common import (
    CommandError,
    ConfigOption,
    ForceOption,
    JsonOption,
    LabelsOption,
    options_from,
    QuietOption,
    replace_output,
    require_peers,
    SetOption,
    settings,
    typer_app,
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

app = typer_app(name='map', no_args_is_help=True, help=HELP)


BagArgument = Annotated[
    Path, typer.Argument(help='rosbag2 folder (or KITTI sequence) of labeled scans')
]
OutArgument = Annotated[Path, typer.Argument(help='map folder to write')]
PosesOption = Annotated[
    Literal['odometry', 'ground-truth'],
    typer.Option(help='keyframe poses: the odometry (with loop closure) or the ground truth'),
]
MaxFramesOption = Annotated[int | None, typer.Option(min=1, help='read at most this many scans')]
FrameIdOption = Annotated[str, typer.Option(help='frame of the map')]
BaselineOption = Annotated[
    list[LoopPeer] | None,
    typer.Option(
        help='also run this loop-closure peer on the same scans and compare the loops '
        '(--poses odometry); repeatable',
    ),
]
PeerLocalMapOption = Annotated[
    float,
    typer.Option(
        min=1.0,
        help="the --baseline peers' local-map size, m (KISS-SLAM's "
        'local_mapper.splitting_distance; their default 100)',
    ),
]


@app.command('build', help=BUILD_HELP)
def build(
    bag: BagArgument,
    out: OutArgument,
    poses: PosesOption = 'odometry',
    max_frames: MaxFramesOption = None,
    frame_id: FrameIdOption = 'map',
    baseline: BaselineOption = None,
    peer_local_map: PeerLocalMapOption = 100.0,
    config: ConfigOption = None,
    labels: LabelsOption = None,
    overrides: SetOption = None,
    json_path: JsonOption = None,
    force: ForceOption = False,
    quiet: QuietOption = False,
) -> int:
    """Build a map folder from a bag."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.evaluation.map_build import build_map_folder, MapBuildError, MapBuildOptions
    from mlsemreg_ros.evaluation.reports import write_json

    peers = tuple(str(peer) for peer in baseline or [])
    if peers and poses != 'odometry':
        raise CommandError('--baseline compares loop closures: it needs --poses odometry', 2)
    require_peers(peers)
    (core,) = settings((RegistrationConfig,), config, with_labels(overrides, labels))
    replace_output(out, force)
    options = MapBuildOptions(poses, max_frames, frame_id, peers, peer_local_map, not quiet)
    try:
        summary = build_map_folder(bag, out, options, core)
    except MapBuildError as error:
        raise CommandError(str(error)) from None
    if json_path is not None:
        write_json(json_path, summary)
    return 0


QueriesOutArgument = Annotated[Path, typer.Argument(help='folder of query files to write')]


@app.command('queries', help=QUERIES_HELP)
def queries(
    bag: Annotated[
        Path, typer.Argument(help='rosbag2 folder (or KITTI sequence) of labeled scans')
    ],
    out: QueriesOutArgument,
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


SeedOption = Annotated[
    int, typer.Option(min=0, help='seed of the mapped drive (mlsemreg simulate --seed)')
]
FramesOption = Annotated[int, typer.Option(min=2, help='frames of the mapped drive')]
DriveOption = Annotated[
    Literal['reverse', 'other'],
    typer.Option(
        help='reverse: the same streets backwards in the other lane; other: a route '
        'of --route-seed'
    ),
]
EveryOption = Annotated[int, typer.Option(min=1, help='write every K-th scan')]
LaneChangeOption = Annotated[float, typer.Option(help='reverse: lateral shift to the left, m')]
StartOffsetOption = Annotated[
    float, typer.Option(min=0.0, help='reverse: metres skipped at the start')
]
RouteSeedOption = Annotated[int, typer.Option(min=0, help='other: seed of the route')]
RouteFramesOption = Annotated[int, typer.Option(min=2, help='other: frames of the route')]
MinDistanceOption = Annotated[
    float,
    typer.Option(min=0.0, help='other: keep scans at least this far from the mapped drive, m'),
]
NoiseSeedOption = Annotated[int, typer.Option(min=0, help='seed of the sensor noise')]
RealismOption = Annotated[
    Literal['clean', 'field'],
    typer.Option(
        help='the world of `mlsemreg simulate --realism`: clean, or field (HDL-64 skewed '
        'sweeps, moving objects, network labels; --drive other is the loop route)'
    ),
]
DeskewOption = Annotated[
    Literal['odometry', 'previous', 'sweep', 'off'],
    typer.Option(
        help='field: odometry runs the odometry (--config/--set, no IMU) over every sweep '
        'and writes the scans it deskewed (what the node relocalizes; sweeps it rejected '
        'or left skewed are skipped); or motion-compensate each sweep to its start with '
        'the true twist over the previous period (as a constant-velocity prediction), '
        'over the sweep itself (as an IMU-aided deskew), or not (the raw skewed sweep)'
    ),
]


@app.command('sim-queries', help=SIM_QUERIES_HELP)
def sim_queries(
    context: typer.Context,
    out: QueriesOutArgument,
    seed: SeedOption = 0,
    frames: FramesOption = 200,
    drive: DriveOption = 'reverse',
    every: EveryOption = 5,
    lane_change: LaneChangeOption = 3.6,
    start_offset: StartOffsetOption = 0.5,
    route_seed: RouteSeedOption = 7,
    route_frames: RouteFramesOption = 300,
    min_distance: MinDistanceOption = 80.0,
    noise_seed: NoiseSeedOption = 1000,
    realism: RealismOption = 'clean',
    deskew: DeskewOption = 'odometry',
    config: ConfigOption = None,
    overrides: SetOption = None,
    force: ForceOption = False,
) -> int:
    """Write relocalization queries from a second simulated drive."""
    from mlsemreg_ros.evaluation.tables import print_text
    from mlsemreg_ros.simulation.revisit_queries import SimQueries, write_sim_queries

    request = options_from(context, SimQueries)
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
