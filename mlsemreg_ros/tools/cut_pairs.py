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
``mlsemreg cut-pairs BAG OUT``: cut hard registration pairs out of a labeled bag with truth.

The selection (stride pairs far apart, low-overlap turn pairs) is
:mod:`mlsemreg_ros.datasets.hard_pairs`; this module is its command line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from mlsemreg_ros.tools.common import alias, CommandError, QuietOption
import typer

HELP = (
    'Cut hard registration pairs (large strides, low-overlap turns) out of a labeled bag '
    'with ground truth into pair files (.npz).'
)
SELECTION = 'Pair selection'


def cut_pairs(
    bag: Annotated[
        Path, typer.Argument(help='rosbag2 folder with labeled clouds and ground truth')
    ],
    out: Annotated[Path, typer.Argument(help='output folder for the pair files')],
    stride_pairs: Annotated[
        int, typer.Option(min=0, help='number of stride pairs', rich_help_panel=SELECTION)
    ] = 40,
    turn_pairs: Annotated[
        int, typer.Option(min=0, help='number of turn pairs', rich_help_panel=SELECTION)
    ] = 20,
    min_distance: Annotated[
        float,
        typer.Option(
            min=0.0, help='stride pairs: least sensor distance, m', rich_help_panel=SELECTION
        ),
    ] = 20.0,
    max_distance: Annotated[
        float,
        typer.Option(
            min=0.0, help='largest sensor distance of any pair, m', rich_help_panel=SELECTION
        ),
    ] = 40.0,
    turn_angle: Annotated[
        float,
        typer.Option(
            min=0.0,
            max=180.0,
            help='relative rotation that makes a turn pair, deg',
            rich_help_panel=SELECTION,
        ),
    ] = 45.0,
    turn_min_distance: Annotated[
        float,
        typer.Option(
            min=0.0, help='turn pairs: least sensor distance, m', rich_help_panel=SELECTION
        ),
    ] = 10.0,
    turn_max_overlap: Annotated[
        float,
        typer.Option(
            min=0.0,
            max=1.0,
            help='turn pairs: largest ground-truth overlap',
            rich_help_panel=SELECTION,
        ),
    ] = 0.4,
    min_overlap: Annotated[
        float,
        typer.Option(
            min=0.0,
            max=1.0,
            help='least ground-truth overlap (share of source points within 0.6 m)',
            rich_help_panel=SELECTION,
        ),
    ] = 0.1,
    voxel_size: Annotated[float, typer.Option(min=0.0, help='voxel edge, m')] = 0.3,
    max_range: Annotated[float, typer.Option(min=0.0, help='crop radius, m')] = 60.0,
    keypoints: Annotated[int, typer.Option(min=0, help='random keypoints per scan')] = 5000,
    seed: Annotated[int, typer.Option(min=0, help='seed of the pair draw and keypoints')] = 0,
    prefix: Annotated[
        str | None, typer.Option(help='pair name prefix (default: bag name)')
    ] = None,
    quiet: QuietOption = False,
) -> int:
    """Cut hard registration pairs out of a labeled bag (alias mlsemreg-cut-pairs)."""
    from mlsemreg_ros.datasets.hard_pairs import (
        choose_pairs,
        CutOptions,
        read_frames,
        write_pair_files,
    )
    from mlsemreg_ros.datasets.source import SourceError
    from mlsemreg_ros.evaluation.tables import print_text

    try:
        frames = read_frames(bag, voxel_size, max_range, progress=not quiet)
    except (SourceError, OSError, ValueError) as error:
        raise CommandError(f'cannot read {bag}: {error}') from None
    if len(frames) < 2:
        raise CommandError(
            f'{bag} has {len(frames)} labeled scans with ground truth; at least 2 are needed'
        )
    options = CutOptions(
        stride_pairs,
        turn_pairs,
        min_distance,
        max_distance,
        turn_angle,
        turn_min_distance,
        turn_max_overlap,
        min_overlap,
        seed,
    )
    choices = choose_pairs(frames, options)
    write_pair_files(frames, choices, out, prefix or bag.name, keypoints, seed)
    counts = {kind: sum(c.kind == kind for c in choices) for kind in ('stride', 'turn')}
    print_text(
        f'wrote {len(choices)} pairs to {out} ({counts["stride"]} stride, '
        f'{counts["turn"]} turn) from {len(frames)} scans of {bag}'
    )
    return 0


main = alias(cut_pairs, HELP, 'mlsemreg-cut-pairs')
