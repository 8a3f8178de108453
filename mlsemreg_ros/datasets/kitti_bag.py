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
A SemanticKITTI sequence folder written as a rosbag2 (``mlsemreg kitti-to-bag``).

:func:`kitti_sequence_to_bag` reads ``velodyne/*.bin``, ``labels/*.label`` (optional:
without it the clouds are unlabeled, label 0, and a warning says so), ``poses.txt`` +
``calib.txt`` (ground truth in the LiDAR frame, with ``Tr``) and ``times.txt`` (stamps)
with :class:`~mlsemreg_ros.datasets.kitti.KittiSequence`, and writes the bag layout of
``mlsemreg simulate`` with :func:`~mlsemreg_ros.datasets.bag.write_sequence_bag`.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
import shutil
import time
import warnings

from mlsemreg_ros.datasets.bag import BagLayout, write_sequence_bag, WrittenSequence
from mlsemreg_ros.datasets.source import expected_frames, Scan, SourceError
import numpy as np


@dataclass(frozen=True)
class KittiFiles:
    """The side files of a sequence (None: the file of that name in the sequence folder)."""

    poses: Path | None = None
    calib: Path | None = None
    times: Path | None = None
    start_time_s: float = 1.7e9  # header stamp of time 0 of times.txt, s since the epoch


@dataclass
class KittiConversion:
    """What :func:`kitti_sequence_to_bag` wrote."""

    written: WrittenSequence
    labelled: bool  # the sequence had a labels/ folder (else every label is 0)
    seconds: float  # wall time of the conversion

    def summary(self, out: Path) -> str:
        """Return the line the command prints."""
        written, labelled = self.written, self.labelled
        return (
            f'wrote {out}: {written.frames} scans, {written.points_per_scan:.0f} '
            f'points/scan, labels {"yes" if labelled else "NO"}'
            f'{"" if labelled else " (unlabeled)"}, ground truth '
            f'{"yes" if written.ground_truth else "no"}, {self.seconds:.1f} s'
        )


def kitti_sequence_to_bag(
    sequence: Path,
    out: Path,
    layout: BagLayout,
    files: KittiFiles | None = None,
    stride: int = 1,
    max_frames: int | None = None,
    progress: bool = True,
) -> KittiConversion:
    """
    Write every ``stride``-th scan of ``sequence`` (at most ``max_frames``) as the bag ``out``.

    ``out`` must not exist. On a SourceError (a missing or broken file) the partial bag is
    removed and the error raised. Warns (UserWarning) when the sequence has no poses.
    """
    from mlsemreg_ros.datasets.kitti import KittiSequence
    from tqdm import tqdm

    files = files or KittiFiles()
    start = time.perf_counter()
    try:
        source = KittiSequence(
            sequence,
            poses=files.poses,
            calib=files.calib,
            times=files.times,
            start_time_ns=round(files.start_time_s * 1e9),
            frame_id=layout.frame_id,
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
            disable=not progress,
        )
        written = write_sequence_bag(out, _uint32_labels(scans), layout)
    except SourceError:
        shutil.rmtree(out, ignore_errors=True)
        raise
    labelled = source.label_files is not None
    return KittiConversion(written, labelled, time.perf_counter() - start)


def _uint32_labels(scans: Iterator[Scan]) -> Iterator[Scan]:
    """Yield the scans with their labels as uint32 (the bag's label field)."""
    for scan in scans:
        if scan.labels is not None:
            scan.labels = scan.labels.astype(np.uint32)
        yield scan
