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

Reads ``velodyne/*.bin``, ``labels/*.label`` (optional: without it the clouds are
unlabeled, label 0, and a warning says so), ``poses.txt`` + ``calib.txt`` (ground truth,
expressed in the LiDAR frame with ``Tr``) and ``times.txt`` (stamps) with
:class:`~mlsemreg_ros.datasets.kitti.KittiSequence`, and writes the bag layout of
``mlsemreg simulate`` with :func:`~mlsemreg_ros.datasets.bag.write_sequence_bag`.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
import shutil
from typing import Annotated, Any
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


def _uint32_labels(scans: Iterator[Any]) -> Iterator[Any]:
    """Yield the scans with their labels as uint32 (the bag's label field)."""
    import numpy as np

    for scan in scans:
        if scan.labels is not None:
            scan.labels = scan.labels.astype(np.uint32)
        yield scan


def kitti_to_bag(
    sequence: Annotated[
        Path,
        typer.Argument(
            exists=True, file_okay=False, help='sequence folder, e.g. .../sequences/08'
        ),
    ],
    out: Annotated[
        Path, typer.Argument(help='output bag directory (must not exist, see --force)')
    ],
    storage: StorageOption = 'mcap',
    compress: CompressOption = False,
    poses: Annotated[
        Path | None,
        typer.Option(
            dir_okay=False, help='poses file (default: SEQUENCE/poses.txt)', rich_help_panel=DATA
        ),
    ] = None,
    calib: Annotated[
        Path | None,
        typer.Option(
            dir_okay=False, help='calib file (default: SEQUENCE/calib.txt)', rich_help_panel=DATA
        ),
    ] = None,
    times: Annotated[
        Path | None,
        typer.Option(
            dir_okay=False, help='times file (default: SEQUENCE/times.txt)', rich_help_panel=DATA
        ),
    ] = None,
    start_time: Annotated[
        float,
        typer.Option(
            min=0.0,
            help='header stamp of time 0 of times.txt, seconds since the epoch',
            rich_help_panel=DATA,
        ),
    ] = 1.7e9,
    stride: Annotated[
        int, typer.Option(min=1, help='keep every n-th scan', rich_help_panel=DATA)
    ] = 1,
    max_frames: Annotated[
        int | None, typer.Option(min=1, help='stop after this many scans', rich_help_panel=DATA)
    ] = None,
    points_topic: PointsTopicOption = POINTS_TOPIC,
    gt_topic: GtTopicOption = GT_TOPIC,
    frame_id: FrameIdOption = 'velodyne',
    world_frame: WorldFrameOption = WORLD_FRAME,
    force: ForceOption = False,
    quiet: QuietOption = False,
) -> int:
    """Convert a SemanticKITTI sequence folder into a rosbag2 (alias mlsemreg-kitti-to-bag)."""
    import time

    from mlsemreg_ros.datasets.bag import BagLayout, write_sequence_bag
    from mlsemreg_ros.datasets.kitti import KittiSequence
    from mlsemreg_ros.datasets.source import SourceError
    from mlsemreg_ros.evaluation.replay import expected_frames
    from mlsemreg_ros.evaluation.tables import print_text
    from tqdm import tqdm

    replace_output(out, force)
    warnings.simplefilter('default')
    start = time.perf_counter()
    try:
        source = KittiSequence(
            sequence,
            poses=poses,
            calib=calib,
            times=times,
            start_time_ns=round(start_time * 1e9),
            frame_id=frame_id,
        )
        if source.poses is None:
            warnings.warn(
                f'{sequence} has no poses.txt: the bag has no ground truth', stacklevel=2
            )
        scans = tqdm(
            source.scans(stride, max_frames),
            desc='convert',
            unit='scan',
            total=expected_frames(len(source), stride, max_frames),
            disable=quiet,
        )
        layout = BagLayout(storage, compress, points_topic, gt_topic, frame_id, world_frame)
        written = write_sequence_bag(out, _uint32_labels(scans), layout)
    except SourceError as error:
        shutil.rmtree(out, ignore_errors=True)
        raise CommandError(str(error)) from None
    print_text(
        f'wrote {out}: {written.frames} scans, {written.points_per_scan:.0f} '
        f'points/scan, labels {"yes" if source.label_files is not None else "NO"}'
        f'{"" if source.label_files is not None else " (unlabeled)"}, ground truth '
        f'{"yes" if written.ground_truth else "no"}, {time.perf_counter() - start:.1f} s'
    )
    return 0


main = alias(kitti_to_bag, HELP, 'mlsemreg-kitti-to-bag')
