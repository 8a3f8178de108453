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
``mlsemreg-kitti-to-bag``: a SemanticKITTI sequence folder as a rosbag2.

Reads ``velodyne/*.bin``, ``labels/*.label`` (optional: without it the clouds
are unlabeled, label 0, and a warning says so), ``poses.txt`` + ``calib.txt``
(ground truth, expressed in the LiDAR frame with ``Tr``) and ``times.txt``
(stamps), and writes the bag layout of ``mlsemreg-simulate``: ``/points``
(x, y, z, intensity, uint32 raw label) and ``/ground_truth/odometry``, plus
``poses.txt`` (LiDAR frame) and ``times.txt`` next to the storage file.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import shutil
import sys
import time
import warnings

from mlsemreg_ros.datasets.bag import GT_TOPIC, POINTS_TOPIC, STORAGES, WORLD_FRAME
from mlsemreg_ros.tools.cli_help import HelpFormatter
import numpy as np


def build_parser() -> argparse.ArgumentParser:
    """Command-line interface."""
    p = argparse.ArgumentParser(
        prog='mlsemreg-kitti-to-bag', description='Convert a SemanticKITTI sequence folder '
        '(velodyne/, labels/, poses.txt, calib.txt, times.txt) into a rosbag2.',
        formatter_class=HelpFormatter)
    p.add_argument('sequence', type=Path, help='sequence folder, e.g. .../sequences/08')
    p.add_argument('out', type=Path, help='output bag directory (must not exist, see --force)')
    p.add_argument('--storage', choices=STORAGES, default='mcap', help='rosbag2 storage plugin')
    p.add_argument('--compress', action='store_true', help='zstd compression')
    p.add_argument('--poses', type=Path, help='poses file (default: SEQUENCE/poses.txt)')
    p.add_argument('--calib', type=Path, help='calib file (default: SEQUENCE/calib.txt)')
    p.add_argument('--times', type=Path, help='times file (default: SEQUENCE/times.txt)')
    p.add_argument('--start-time', type=float, default=1.7e9,
                   help='header stamp of time 0 of times.txt, seconds since the epoch')
    p.add_argument('--stride', type=int, default=1, help='keep every n-th scan')
    p.add_argument('--max-frames', type=int, help='stop after this many scans')
    topics = p.add_argument_group('topics and frames')
    topics.add_argument('--points-topic', default=POINTS_TOPIC)
    topics.add_argument('--gt-topic', default=GT_TOPIC)
    topics.add_argument('--frame-id', default='velodyne', help='frame of the clouds')
    topics.add_argument('--world-frame', default=WORLD_FRAME, help='frame of the ground truth')
    p.add_argument('--force', action='store_true', help='replace OUT if it exists')
    p.add_argument('--quiet', action='store_true', help='no progress bar')
    return p


def convert(args: argparse.Namespace) -> dict:
    """Write the bag and pose files; returns a small report."""
    from mlsemreg_ros.datasets.bag import BagWriter
    from mlsemreg_ros.datasets.kitti import KittiSequence
    from mlsemreg_ros.datasets.pose_files import write_kitti_poses
    from tqdm import tqdm

    start = time.perf_counter()
    sequence = KittiSequence(args.sequence, poses=args.poses, calib=args.calib,
                             times=args.times, start_time_ns=round(args.start_time * 1e9),
                             frame_id=args.frame_id)
    if sequence.poses is None:
        warnings.warn(f'{args.sequence} has no poses.txt: the bag has no ground truth',
                      stacklevel=2)
    total = len(range(0, len(sequence), args.stride))
    if args.max_frames is not None:
        total = min(total, args.max_frames)
    stamps, poses, points = [], [], 0
    with BagWriter(args.out, storage=args.storage, compress=args.compress) as bag:
        for scan in tqdm(sequence.scans(args.stride, args.max_frames), total=total,
                         desc='convert', unit='scan', disable=args.quiet):
            labels = None if scan.labels is None else scan.labels.astype(np.uint32)
            bag.write_cloud(scan.stamp_ns, scan.xyz, labels, scan.intensity,
                            frame_id=args.frame_id, topic=args.points_topic)
            if scan.pose is not None:
                bag.write_odometry(scan.stamp_ns, scan.pose, frame_id=args.world_frame,
                                   child_frame_id=args.frame_id, topic=args.gt_topic)
                poses.append(scan.pose)
            stamps.append(scan.stamp_ns)
            points += len(scan)
    if poses:
        write_kitti_poses(args.out / 'poses.txt', np.asarray(poses))
    if stamps:
        seconds = (np.asarray(stamps) - stamps[0]) / 1e9
        np.savetxt(args.out / 'times.txt', seconds, fmt='%.6e')
    return {'frames': len(stamps), 'labeled': sequence.label_files is not None,
            'ground_truth': bool(poses), 'points_per_scan': points / max(len(stamps), 1),
            'total_s': time.perf_counter() - start}


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``mlsemreg-kitti-to-bag``."""
    args = build_parser().parse_args(argv)
    if args.stride < 1:
        print('error: --stride must be >= 1', file=sys.stderr)
        return 2
    from mlsemreg_ros.datasets.bag import replace_output

    problem = replace_output(args.out, args.force)
    if problem:
        print(f'error: {problem}', file=sys.stderr)
        return 2
    from mlsemreg_ros.datasets.source import SourceError

    warnings.simplefilter('default')
    try:
        report = convert(args)
    except SourceError as exc:
        shutil.rmtree(args.out, ignore_errors=True)
        print(f'error: {exc}', file=sys.stderr)
        return 1
    print(f'wrote {args.out}: {report["frames"]} scans, {report["points_per_scan"]:.0f} '
          f'points/scan, labels {"yes" if report["labeled"] else "NO (unlabeled)"}, ground '
          f'truth {"yes" if report["ground_truth"] else "no"}, {report["total_s"]:.1f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
