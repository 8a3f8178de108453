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
``mlsemreg-simulate``: a labeled LiDAR sequence from the procedural world, as a rosbag2.

Writes ``OUT/`` (rosbag2: ``/points`` PointCloud2 with x, y, z, intensity and a
uint32 SemanticKITTI raw label, ``/ground_truth/odometry``) and, next to the
storage file, ``poses.txt`` (KITTI format, LiDAR frame, frame 0 = identity),
``times.txt`` and ``simulation.yaml`` (the parameters, to reproduce the bag).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
import sys
import time

from mlsemreg_ros.datasets.bag import GT_TOPIC, POINTS_TOPIC, SENSOR_FRAME, STORAGES, WORLD_FRAME
from mlsemreg_ros.tools.cli_help import HelpFormatter
import numpy as np
import yaml


def build_parser() -> argparse.ArgumentParser:
    """Command-line interface."""
    p = argparse.ArgumentParser(
        prog='mlsemreg-simulate', description=__doc__.split('\n\n')[0].split(': ', 1)[-1],
        formatter_class=HelpFormatter)
    p.add_argument('out', type=Path, help='output bag directory (must not exist, see --force)')
    p.add_argument('--frames', type=int, default=200, help='number of scans')
    p.add_argument('--seed', type=int, default=0, help='world, route and noise seed')
    p.add_argument('--storage', choices=STORAGES, default='mcap', help='rosbag2 storage plugin')
    p.add_argument('--compress', action='store_true', help='zstd compression (mcap chunks / '
                   'sqlite3 messages)')
    p.add_argument('--blur-radius', type=float, default=0.0,
                   help='paper boundary blur radius in metres (0: clean labels)')
    p.add_argument('--blur-probability', type=float, default=0.5,
                   help='chance that a boundary point takes another nearby class')
    p.add_argument('--flip-fraction', type=float, default=0.0,
                   help='share of points given a random other class')
    p.add_argument('--step', type=float, default=1.0, help='metres driven per frame')
    p.add_argument('--rate', type=float, default=10.0, help='scan rate in Hz')
    sensor = p.add_argument_group('sensor')
    sensor.add_argument('--beams', type=int, default=64, help='vertical beams')
    sensor.add_argument('--azimuth-steps', type=int, default=2000,
                        help='horizontal samples per revolution')
    sensor.add_argument('--max-range', type=float, default=100.0, help='metres')
    sensor.add_argument('--range-noise', type=float, default=0.02,
                        help='Gaussian range noise sigma, metres')
    sensor.add_argument('--dropout', type=float, default=0.05, help='share of lost returns')
    topics = p.add_argument_group('topics and frames')
    topics.add_argument('--points-topic', default=POINTS_TOPIC)
    topics.add_argument('--gt-topic', default=GT_TOPIC)
    topics.add_argument('--frame-id', default=SENSOR_FRAME, help='frame of the clouds')
    topics.add_argument('--world-frame', default=WORLD_FRAME, help='frame of the ground truth')
    p.add_argument('--force', action='store_true', help='replace OUT if it exists')
    p.add_argument('--quiet', action='store_true', help='no progress bar')
    return p


def simulation_config(args: argparse.Namespace) -> object:
    """Build the SimulationConfig described by the parsed arguments."""
    from mlsemreg_ros.simulation.lidar import LidarConfig
    from mlsemreg_ros.simulation.sequence import SimulationConfig

    lidar = LidarConfig(beams=args.beams, azimuth_steps=args.azimuth_steps,
                        max_range=args.max_range, range_noise=args.range_noise,
                        dropout=args.dropout)
    return SimulationConfig(seed=args.seed, frames=args.frames, rate_hz=args.rate,
                            step=args.step, blur_radius=args.blur_radius,
                            blur_probability=args.blur_probability,
                            flip_fraction=args.flip_fraction, lidar=lidar)


def write_sequence(args: argparse.Namespace) -> dict:
    """Simulate and write the bag and pose files; returns a small report."""
    from mlsemreg_ros.datasets.bag import BagWriter
    from mlsemreg_ros.datasets.pose_files import write_kitti_poses
    from mlsemreg_ros.simulation.sequence import Simulation
    from tqdm import tqdm

    start = time.perf_counter()
    config = simulation_config(args)
    sim = Simulation(config)
    built = time.perf_counter()
    points = 0
    with BagWriter(args.out, storage=args.storage, compress=args.compress) as bag:
        for frame in tqdm(sim, total=len(sim), desc='simulate', unit='scan',
                          disable=args.quiet):
            scan = frame.scan
            bag.write_cloud(frame.stamp_ns, scan.points, sim.raw_labels(scan), scan.intensity,
                            frame_id=args.frame_id, topic=args.points_topic)
            bag.write_odometry(frame.stamp_ns, frame.pose, frame_id=args.world_frame,
                               child_frame_id=args.frame_id, topic=args.gt_topic)
            points += len(scan)
    write_kitti_poses(args.out / 'poses.txt', sim.poses)
    seconds = (np.array([sim.stamp_ns(k) for k in range(len(sim))]) - sim.stamp_ns(0)) / 1e9
    np.savetxt(args.out / 'times.txt', seconds, fmt='%.6e')
    meta = {'simulation': dataclasses.asdict(config),
            'topics': {'points': args.points_topic, 'ground_truth': args.gt_topic},
            'frames': {'sensor': args.frame_id, 'world': args.world_frame},
            'world': {'triangles': sim.world.num_triangles,
                      'blocks': {f'{i},{j}': kind for (i, j), kind in sim.world.blocks.items()},
                      'objects': sim.world.object_counts}}
    (args.out / 'simulation.yaml').write_text(yaml.safe_dump(meta, sort_keys=False))
    return {'frames': len(sim), 'points_per_scan': points / max(len(sim), 1),
            'world_s': built - start, 'total_s': time.perf_counter() - start,
            'path_m': float(np.sum(np.linalg.norm(np.diff(sim.poses[:, :3, 3], axis=0),
                                                  axis=1)))}


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``mlsemreg-simulate``."""
    args = build_parser().parse_args(argv)
    if args.frames < 1:
        print('error: --frames must be >= 1', file=sys.stderr)
        return 2
    from mlsemreg_ros.datasets.bag import replace_output

    problem = replace_output(args.out, args.force)
    if problem:
        print(f'error: {problem}', file=sys.stderr)
        return 2
    report = write_sequence(args)
    print(f'wrote {args.out}: {report["frames"]} scans, {report["points_per_scan"]:.0f} '
          f'points/scan, {report["path_m"]:.1f} m driven; world {report["world_s"]:.1f} s, '
          f'total {report["total_s"]:.1f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
