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

The selection (stride pairs far apart, low-overlap turn pairs) and the writing are
:func:`mlsemreg_ros.datasets.hard_pairs.cut_hard_pairs`; this module is its command line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from mlsemreg_ros.tools.common import alias, CommandError, QuietOption
import typer

HELP = (
    'Cut hard registration pairs (large strides, low-overlap turns) out of a labeled bag '
    'with ground truth into pair files (.npz).'
)
SELECTION = 'Pair selection'


BagArgument = Annotated[
    Path, typer.Argument(help='rosbag2 folder with labeled clouds and ground truth')
]
OutArgument = Annotated[Path, typer.Argument(help='output folder for the pair files')]
StridePairs = Annotated[
    int, typer.Option(min=0, help='number of stride pairs', rich_help_panel=SELECTION)
]
TurnPairs = Annotated[
    int, typer.Option(min=0, help='number of turn pairs', rich_help_panel=SELECTION)
]
MinDistance = Annotated[
    float,
    typer.Option(
        min=0.0, help='stride pairs: least sensor distance, m', rich_help_panel=SELECTION
    ),
]
MaxDistance = Annotated[
    float,
    typer.Option(
        min=0.0, help='largest sensor distance of any pair, m', rich_help_panel=SELECTION
    ),
]
TurnAngle = Annotated[
    float,
    typer.Option(
        min=0.0,
        max=180.0,
        help='relative rotation that makes a turn pair, deg',
        rich_help_panel=SELECTION,
    ),
]
TurnMinDistance = Annotated[
    float,
    typer.Option(min=0.0, help='turn pairs: least sensor distance, m', rich_help_panel=SELECTION),
]
TurnMaxOverlap = Annotated[
    float,
    typer.Option(
        min=0.0,
        max=1.0,
        help='turn pairs: largest ground-truth overlap',
        rich_help_panel=SELECTION,
    ),
]
MinOverlap = Annotated[
    float,
    typer.Option(
        min=0.0,
        max=1.0,
        help='least ground-truth overlap (share of source points within 0.6 m)',
        rich_help_panel=SELECTION,
    ),
]
VoxelSize = Annotated[float, typer.Option(min=0.0, help='voxel edge, m')]
MaxRange = Annotated[float, typer.Option(min=0.0, help='crop radius, m')]
Keypoints = Annotated[int, typer.Option(min=0, help='random keypoints per scan')]
Seed = Annotated[int, typer.Option(min=0, help='seed of the pair draw and keypoints')]
Prefix = Annotated[str | None, typer.Option(help='pair name prefix (default: bag name)')]
Deskew = Annotated[
    Literal['truth', 'odometry', 'none'],
    typer.Option(
        help='motion compensation of sweeps with per-point times: truth (the true motion, as '
        "a ground-truth map), odometry (the odometry's own estimate, as its keyframes) or "
        'none (raw sweeps)'
    ),
]


def cut_pairs(
    bag: BagArgument,
    out: OutArgument,
    stride_pairs: StridePairs = 40,
    turn_pairs: TurnPairs = 20,
    min_distance: MinDistance = 20.0,
    max_distance: MaxDistance = 40.0,
    turn_angle: TurnAngle = 45.0,
    turn_min_distance: TurnMinDistance = 10.0,
    turn_max_overlap: TurnMaxOverlap = 0.4,
    min_overlap: MinOverlap = 0.1,
    voxel_size: VoxelSize = 0.3,
    max_range: MaxRange = 60.0,
    keypoints: Keypoints = 5000,
    seed: Seed = 0,
    prefix: Prefix = None,
    deskew: Deskew = 'truth',
    quiet: QuietOption = False,
) -> int:
    """Cut hard registration pairs out of a labeled bag (alias mlsemreg-cut-pairs)."""
    from mlsemreg_ros.datasets.hard_pairs import cut_hard_pairs, CutOptions, TooFewFrames
    from mlsemreg_ros.datasets.source import SourceError
    from mlsemreg_ros.evaluation.tables import print_text

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
    try:
        report = cut_hard_pairs(
            bag,
            out,
            options,
            voxel_size,
            max_range,
            keypoints,
            prefix,
            progress=not quiet,
            deskew=deskew,
        )
    except TooFewFrames as error:
        raise CommandError(str(error)) from None
    except (SourceError, OSError, ValueError) as error:
        raise CommandError(f'cannot read {bag}: {error}') from None
    counts = report.counts()
    print_text(
        f'wrote {len(report.choices)} pairs to {out} ({counts["stride"]} stride, '
        f'{counts["turn"]} turn) from {report.frames} scans of {bag} (deskew: {deskew})'
    )
    return 0


main = alias(cut_pairs, HELP, 'mlsemreg-cut-pairs')
