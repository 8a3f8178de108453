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
``mlsemreg-cut-pairs BAG OUT``: cut hard registration pairs out of a labeled bag with ground truth.

The paper's hard KITTI pairs are scans far apart; this tool makes such a set from any
bag with ground-truth poses (``mlsemreg-simulate`` bags, converted KITTI sequences), in the
pair-file format of :mod:`mlsemreg_ros.datasets.pairs` (``mlsemreg-eval-pairs`` reads it):

- ``stride`` pairs: sensor positions ``--min-distance``..``--max-distance`` apart (default
  20-40 m) with a relative rotation below ``--turn-angle``;
- ``turn`` pairs: relative rotation of at least ``--turn-angle`` (default 45 deg) at
  ``--turn-min-distance``..``--max-distance`` apart and a ground-truth overlap of at most
  ``--turn-max-overlap``: the two scans look down different streets and overlap little.

Candidates of each kind are drawn in a seeded random order and kept while their
ground-truth overlap (share of source points with a target point within 0.6 m under
``trans_gt``) is at least ``--min-overlap``, so every pair can be registered at all.
Each scan is cropped to ``--max-range``, voxelized (``--voxel-size``, majority label),
its labels converted to SemanticKITTI learning ids, and ``--keypoints`` random points are
stored as keypoints (as the KITTI dev pairs hold 5000). ``OUT/pairs.csv`` lists every pair
with its kind, frames, distance, rotation and overlap.
"""

from __future__ import annotations

import argparse
import csv
from dataclasses import dataclass
from pathlib import Path
import sys
from typing import Any

import numpy as np

OVERLAP_DISTANCE_M = 0.6  # the KITTI inlier threshold


@dataclass
class Frame:
    """One voxelized scan of the bag with its ground-truth pose."""

    index: int  # message index in the bag
    points: np.ndarray  # (N, 3) float64, sensor frame, voxelized and cropped
    labels: np.ndarray  # (N,) int32 learning ids
    T_world_sensor: np.ndarray  # (4, 4)


@dataclass
class PairChoice:
    """A chosen pair of frames and why."""

    kind: str  # 'stride' or 'turn'
    source: int  # position in the frame list
    target: int
    distance_m: float
    rotation_deg: float
    overlap: float


def read_frames(bag: Path, voxel_size: float, max_range: float,
                progress: bool = True) -> list[Frame]:
    """Read every scan of ``bag`` with ground truth: cropped, voxelized, in learning ids."""
    from mlsemreg_ros.core.features import voxel_downsample
    from mlsemreg_ros.core.labels import LabelMap
    from mlsemreg_ros.datasets.factory import open_scan_source
    from tqdm import tqdm

    label_map = LabelMap.load()
    source = open_scan_source(bag)
    frames: list[Frame] = []
    try:
        for scan in tqdm(source.scans(), total=len(source), desc='read', unit='scan',
                         file=sys.stderr, disable=not progress):
            if scan.pose is None or scan.labels is None:
                continue
            keep = np.linalg.norm(scan.xyz, axis=1) <= max_range
            labels = label_map.to_learning(scan.labels[keep])
            points, labels = voxel_downsample(scan.xyz[keep], labels, voxel_size)
            frames.append(Frame(scan.index, points, labels, np.asarray(scan.pose)))
    finally:
        source.close()
    return frames


def relative_motion(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(distance (F, F) m, rotation angle (F, F) deg)`` between every two poses."""
    positions = poses[:, :3, 3]
    distance = np.linalg.norm(positions[:, None] - positions[None], axis=-1)
    rotations = poses[:, :3, :3]
    trace = np.einsum('iab,jab->ij', rotations, rotations)  # trace(R_i^T R_j)
    angle = np.degrees(np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0)))
    return distance, angle


def ground_truth_overlap(source: Frame, target: Frame, tree: Any) -> float:
    """Return the share of source points within 0.6 m of a target point under the truth."""
    T = np.linalg.inv(target.T_world_sensor) @ source.T_world_sensor
    moved = source.points @ T[:3, :3].T + T[:3, 3]
    distance, _ = tree.query(moved, distance_upper_bound=OVERLAP_DISTANCE_M)
    return float(np.isfinite(distance).mean()) if len(distance) else 0.0


def choose_pairs(frames: list[Frame], args: argparse.Namespace) -> list[PairChoice]:
    """Draw ``stride`` and ``turn`` pairs (module docstring) in a seeded random order."""
    from scipy.spatial import cKDTree

    distance, angle = relative_motion(np.stack([f.T_world_sensor for f in frames]))
    upper = np.triu(np.ones_like(distance, dtype=bool), 1)
    far = (distance >= args.min_distance) & (distance <= args.max_distance)
    turned = angle >= args.turn_angle
    kinds = {  # kind: (candidates, how many, largest overlap)
        'stride': (far & ~turned & upper, args.stride_pairs, 1.0),
        'turn': (turned & (distance >= args.turn_min_distance)
                 & (distance <= args.max_distance) & upper, args.turn_pairs,
                 args.turn_max_overlap),
    }
    rng = np.random.default_rng(args.seed)
    trees: dict[int, Any] = {}
    chosen: list[PairChoice] = []
    for kind, (mask, wanted, max_overlap) in kinds.items():
        candidates = np.argwhere(mask)
        kept = 0
        for i, j in candidates[rng.permutation(len(candidates))]:  # one pair at a time
            if kept >= wanted:
                break
            if j not in trees:
                trees[j] = cKDTree(frames[j].points)
            overlap = ground_truth_overlap(frames[i], frames[j], trees[j])
            if not args.min_overlap <= overlap <= max_overlap:
                continue
            chosen.append(PairChoice(kind, int(i), int(j), float(distance[i, j]),
                                     float(angle[i, j]), overlap))
            kept += 1
    return chosen


def make_pair(frames: list[Frame], choice: PairChoice, name: str, keypoints: int,
              seed: int) -> Any:
    """Build the :class:`~mlsemreg_ros.datasets.pairs.Pair` of a choice, random keypoints."""
    from mlsemreg_ros.core.features import sample_keypoints
    from mlsemreg_ros.datasets.pairs import Pair

    source, target = frames[choice.source], frames[choice.target]
    src_rows = sample_keypoints(source.points, keypoints, 'random', 1.0, seed)
    dst_rows = sample_keypoints(target.points, keypoints, 'random', 1.0, seed + 1)
    return Pair(name=name, pts_src=source.points, label_src=source.labels,
                pts_dst=target.points, label_dst=target.labels,
                trans_gt=np.linalg.inv(target.T_world_sensor) @ source.T_world_sensor,
                kpts_src=source.points[src_rows], kpts_dst=target.points[dst_rows])


def build_parser() -> argparse.ArgumentParser:
    """Command-line interface of ``mlsemreg-cut-pairs``."""
    p = argparse.ArgumentParser(
        prog='mlsemreg-cut-pairs',
        description='Cut hard registration pairs (large strides, low-overlap turns) out of a '
                    'labeled bag with ground truth into pair files (.npz).')
    p.add_argument('bag', type=Path, help='rosbag2 folder with labeled clouds and ground truth')
    p.add_argument('out', type=Path, help='output folder for the pair files')
    p.add_argument('--stride-pairs', type=int, default=40, help='number of stride pairs')
    p.add_argument('--turn-pairs', type=int, default=20, help='number of turn pairs')
    p.add_argument('--min-distance', type=float, default=20.0,
                   help='stride pairs: least sensor distance, m')
    p.add_argument('--max-distance', type=float, default=40.0,
                   help='largest sensor distance of any pair, m')
    p.add_argument('--turn-angle', type=float, default=45.0,
                   help='relative rotation that makes a turn pair, deg')
    p.add_argument('--turn-min-distance', type=float, default=10.0,
                   help='turn pairs: least sensor distance, m')
    p.add_argument('--turn-max-overlap', type=float, default=0.4,
                   help='turn pairs: largest ground-truth overlap')
    p.add_argument('--min-overlap', type=float, default=0.1,
                   help='least ground-truth overlap (share of source points within 0.6 m)')
    p.add_argument('--voxel-size', type=float, default=0.3, help='voxel edge, m')
    p.add_argument('--max-range', type=float, default=60.0, help='crop radius, m')
    p.add_argument('--keypoints', type=int, default=5000, help='random keypoints per scan')
    p.add_argument('--seed', type=int, default=0, help='seed of the pair draw and keypoints')
    p.add_argument('--prefix', default=None, help='pair name prefix (default: bag name)')
    p.add_argument('--quiet', action='store_true', help='no progress bar')
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``mlsemreg-cut-pairs``."""
    args = build_parser().parse_args(argv)
    from mlsemreg_ros.datasets.pairs import save_pair
    from mlsemreg_ros.datasets.source import SourceError

    if min(args.stride_pairs, args.turn_pairs, args.keypoints) < 0 or args.voxel_size < 0:
        print('mlsemreg-cut-pairs: counts and sizes must be >= 0', file=sys.stderr)
        return 2
    try:
        frames = read_frames(args.bag, args.voxel_size, args.max_range,
                             progress=not args.quiet)
    except (SourceError, OSError, ValueError) as error:
        print(f'mlsemreg-cut-pairs: cannot read {args.bag}: {error}', file=sys.stderr)
        return 1
    if len(frames) < 2:
        print(f'mlsemreg-cut-pairs: {args.bag} has {len(frames)} labeled scans with ground '
              'truth; at least 2 are needed', file=sys.stderr)
        return 1
    choices = choose_pairs(frames, args)
    prefix = args.prefix or args.bag.name
    args.out.mkdir(parents=True, exist_ok=True)
    with (args.out / 'pairs.csv').open('w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(['name', 'kind', 'source_frame', 'target_frame', 'distance_m',
                         'rotation_deg', 'overlap'])
        for number, choice in enumerate(choices):
            source, target = frames[choice.source], frames[choice.target]
            name = f'{prefix}_{source.index:04d}_{target.index:04d}'
            save_pair(args.out / f'{name}.npz',
                      make_pair(frames, choice, name, args.keypoints, args.seed + 2 * number))
            writer.writerow([name, choice.kind, source.index, target.index,
                             f'{choice.distance_m:.2f}', f'{choice.rotation_deg:.2f}',
                             f'{choice.overlap:.3f}'])
    counts = {kind: sum(c.kind == kind for c in choices) for kind in ('stride', 'turn')}
    print(f'wrote {len(choices)} pairs to {args.out} ({counts["stride"]} stride, '
          f'{counts["turn"]} turn) from {len(frames)} scans of {args.bag}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
