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
``mlsemreg kitti-to-bag SEQUENCE OUT``: a SemanticKITTI sequence folder as a rosbag2.

The conversion is :func:`mlsemreg_ros.datasets.kitti_bag.kitti_sequence_to_bag`; this
module is its command line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated
import warnings

from mlsemreg_ros.datasets.bag import GT_TOPIC, POINTS_TOPIC, WORLD_FRAME
from mlsemreg_ros.tools.common import (
    alias,
    CommandError,
    CompressOption,
    DATA,
    ForceOption,
    FrameIdOption,
    GtTopicOption,
    PointsTopicOption,
    QuietOption,
    replace_output,
    StorageOption,
    WorldFrameOption,
)
import typer

HELP = (
    'Convert a SemanticKITTI sequence folder (velodyne/, labels/, poses.txt, calib.txt, '
    'times.txt) into a rosbag2.'
)


SequenceArgument = Annotated[
    Path,
    typer.Argument(exists=True, file_okay=False, help='sequence folder, e.g. .../sequences/08'),
]
OutArgument = Annotated[
    Path, typer.Argument(help='output bag directory (must not exist, see --force)')
]
PosesOption = Annotated[
    Path | None,
    typer.Option(
        dir_okay=False, help='poses file (default: SEQUENCE/poses.txt)', rich_help_panel=DATA
    ),
]
CalibOption = Annotated[
    Path | None,
    typer.Option(
        dir_okay=False, help='calib file (default: SEQUENCE/calib.txt)', rich_help_panel=DATA
    ),
]
TimesOption = Annotated[
    Path | None,
    typer.Option(
        dir_okay=False, help='times file (default: SEQUENCE/times.txt)', rich_help_panel=DATA
    ),
]
StartTimeOption = Annotated[
    float,
    typer.Option(
        min=0.0,
        help='header stamp of time 0 of times.txt, seconds since the epoch',
        rich_help_panel=DATA,
    ),
]
StrideOption = Annotated[
    int, typer.Option(min=1, help='keep every n-th scan', rich_help_panel=DATA)
]
MaxFramesOption = Annotated[
    int | None, typer.Option(min=1, help='stop after this many scans', rich_help_panel=DATA)
]


def kitti_to_bag(
    sequence: SequenceArgument,
    out: OutArgument,
    storage: StorageOption = 'mcap',
    compress: CompressOption = False,
    poses: PosesOption = None,
    calib: CalibOption = None,
    times: TimesOption = None,
    start_time: StartTimeOption = 1.7e9,
    stride: StrideOption = 1,
    max_frames: MaxFramesOption = None,
    points_topic: PointsTopicOption = POINTS_TOPIC,
    gt_topic: GtTopicOption = GT_TOPIC,
    frame_id: FrameIdOption = 'velodyne',
    world_frame: WorldFrameOption = WORLD_FRAME,
    force: ForceOption = False,
    quiet: QuietOption = False,
) -> int:
    """Convert a SemanticKITTI sequence folder into a rosbag2 (alias mlsemreg-kitti-to-bag)."""
    from mlsemreg_ros.datasets.bag import BagLayout
    from mlsemreg_ros.datasets.kitti_bag import kitti_sequence_to_bag, KittiFiles
    from mlsemreg_ros.datasets.source import SourceError
    from mlsemreg_ros.evaluation.tables import print_text

    replace_output(out, force)
    warnings.simplefilter('default')
    layout = BagLayout(storage, compress, points_topic, gt_topic, frame_id, world_frame)
    files = KittiFiles(poses, calib, times, start_time)
    try:
        conversion = kitti_sequence_to_bag(
            sequence, out, layout, files, stride, max_frames, progress=not quiet
        )
    except SourceError as error:
        raise CommandError(str(error)) from None
    print_text(conversion.summary(out))
    return 0


main = alias(kitti_to_bag, HELP, 'mlsemreg-kitti-to-bag')
