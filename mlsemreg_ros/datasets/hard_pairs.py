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
Hard registration pairs cut out of a labeled sequence with ground truth.

The paper's hard KITTI pairs are scans far apart; this tool makes such a set from any
bag with ground-truth poses (``mlsemreg simulate`` bags, converted KITTI sequences), in the
pair-file format of :mod:`mlsemreg_ros.datasets.pairs` (``mlsemreg eval-pairs`` reads it):

- ``stride`` pairs: sensor positions ``min_distance``..``max_distance`` apart (default
  20-40 m) with a relative rotation below ``turn_angle``;
- ``turn`` pairs: relative rotation of at least ``turn_angle`` (default 45 deg) at
  ``turn_min_distance``..``max_distance`` apart and a ground-truth overlap of at most
  ``turn_max_overlap``: the two scans look down different streets and overlap little.

Candidates of each kind are drawn in a seeded random order and kept while their
ground-truth overlap (share of source points with a target point within 0.6 m under
``trans_gt``) is at least ``min_overlap``, so every pair can be registered at all.
Each scan is cropped to ``max_range``, voxelized (``voxel_size``, majority label),
its labels converted to SemanticKITTI learning ids, and ``keypoints`` random points are
stored as keypoints (as the KITTI dev pairs hold 5000). ``OUT/pairs.csv`` lists every pair
with its kind, frames, distance, rotation and overlap.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
import sys
from typing import Any

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.rigid import relative_transform
from mlsemreg_ros.datasets.deskewing import deskewed_by_odometry, deskewed_by_truth
import numpy as np

OVERLAP_DISTANCE_M = 0.6  # the KITTI inlier threshold
DESKEW_CHOICES = ('truth', 'odometry', 'none')  # how read_frames motion-compensates sweeps


@dataclass
class CutOptions:
    """Which pairs to cut (distances in metres, angles in degrees, overlaps as shares)."""

    stride_pairs: int = 40
    turn_pairs: int = 20
    min_distance: float = 20.0  # stride pairs: least sensor distance
    max_distance: float = 40.0  # largest sensor distance of any pair
    turn_angle: float = 45.0  # relative rotation that makes a turn pair
    turn_min_distance: float = 10.0  # turn pairs: least sensor distance
    turn_max_overlap: float = 0.4  # turn pairs: largest ground-truth overlap
    min_overlap: float = 0.1  # least ground-truth overlap
    seed: int = 0  # of the pair draw


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


def read_frames(
    bag: Path,
    voxel_size: float,
    max_range: float,
    progress: bool = True,
    deskew: str = 'truth',
) -> list[Frame]:
    """
    Read every scan of ``bag`` with ground truth: cropped, voxelized, in learning ids.

    ``deskew`` (:data:`DESKEW_CHOICES`) says how a sweep with per-point times is
    motion-compensated to its stamp first (:mod:`mlsemreg_ros.datasets.deskewing`):
    ``truth`` as a ground-truth map's keyframes, ``odometry`` as the odometry's keyframes,
    ``none`` not at all (raw sweeps: the truth refers to the sweep's start, and its points
    spread over the sweep's motion).
    """
    from mlsemreg_ros.core.features.features import voxel_downsample
    from mlsemreg_ros.core.matching.labels import LabelMap
    from mlsemreg_ros.datasets.factory import open_scan_source
    from tqdm import tqdm

    if deskew not in DESKEW_CHOICES:
        raise ValueError(f'deskew must be one of {", ".join(DESKEW_CHOICES)}, not {deskew!r}')
    label_map = LabelMap.load()
    source = open_scan_source(bag)
    frames: list[Frame] = []
    try:
        scans = tqdm(
            source.scans(),
            total=len(source),
            desc='read',
            unit='scan',
            file=sys.stderr,
            disable=not progress,
        )
        posed = (scan for scan in scans if scan.pose is not None and scan.labels is not None)
        for scan in DESKEWERS[deskew](posed):
            keep = np.linalg.norm(scan.xyz, axis=1) <= max_range
            labels = label_map.to_learning(scan.labels[keep])
            points, labels = voxel_downsample(scan.xyz[keep], labels, voxel_size)
            frames.append(Frame(scan.index, points, labels, np.asarray(scan.pose)))
    finally:
        source.close()
    return frames


DESKEWERS: dict[str, Callable[[Iterator[Any]], Iterator[Any]]] = {
    'truth': lambda scans: deskewed_by_truth(scans, RegistrationConfig()),
    'odometry': deskewed_by_odometry,
    'none': lambda scans: scans,
}


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
    T = relative_transform(target.T_world_sensor, source.T_world_sensor)
    moved = source.points @ T[:3, :3].T + T[:3, 3]
    distance, _ = tree.query(moved, distance_upper_bound=OVERLAP_DISTANCE_M)
    return float(np.isfinite(distance).mean()) if len(distance) else 0.0


def choose_pairs(frames: list[Frame], args: CutOptions) -> list[PairChoice]:
    """Draw ``stride`` and ``turn`` pairs (module docstring) in a seeded random order."""
    from scipy.spatial import cKDTree

    distance, angle = relative_motion(np.stack([f.T_world_sensor for f in frames]))
    upper = np.triu(np.ones_like(distance, dtype=bool), 1)
    far = (distance >= args.min_distance) & (distance <= args.max_distance)
    turned = angle >= args.turn_angle
    kinds = {  # kind: (candidates, how many, largest overlap)
        'stride': (far & ~turned & upper, args.stride_pairs, 1.0),
        'turn': (
            turned
            & (distance >= args.turn_min_distance)
            & (distance <= args.max_distance)
            & upper,
            args.turn_pairs,
            args.turn_max_overlap,
        ),
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
            chosen.append(
                PairChoice(
                    kind, int(i), int(j), float(distance[i, j]), float(angle[i, j]), overlap
                )
            )
            kept += 1
    return chosen


def make_pair(
    frames: list[Frame], choice: PairChoice, name: str, keypoints: int, seed: int
) -> Any:
    """Build the :class:`~mlsemreg_ros.datasets.pairs.Pair` of a choice, random keypoints."""
    from mlsemreg_ros.core.features.features import sample_keypoints
    from mlsemreg_ros.datasets.pairs import Pair

    source, target = frames[choice.source], frames[choice.target]
    src_rows = sample_keypoints(source.points, keypoints, 'random', 1.0, seed)
    dst_rows = sample_keypoints(target.points, keypoints, 'random', 1.0, seed + 1)
    return Pair(
        name=name,
        pts_src=source.points,
        label_src=source.labels,
        pts_dst=target.points,
        label_dst=target.labels,
        trans_gt=relative_transform(target.T_world_sensor, source.T_world_sensor),
        kpts_src=source.points[src_rows],
        kpts_dst=target.points[dst_rows],
    )


def write_pair_files(
    frames: list[Frame],
    choices: list[PairChoice],
    out: Path,
    prefix: str,
    keypoints: int,
    seed: int,
) -> None:
    """Write one pair file per choice into ``out`` and list them in ``out/pairs.csv``."""
    import csv

    from mlsemreg_ros.datasets.pairs import save_pair

    out.mkdir(parents=True, exist_ok=True)
    with (out / 'pairs.csv').open('w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(
            [
                'name',
                'kind',
                'source_frame',
                'target_frame',
                'distance_m',
                'rotation_deg',
                'overlap',
            ]
        )
        for number, choice in enumerate(choices):
            source, target = frames[choice.source], frames[choice.target]
            name = f'{prefix}_{source.index:04d}_{target.index:04d}'
            save_pair(
                out / f'{name}.npz', make_pair(frames, choice, name, keypoints, seed + 2 * number)
            )
            writer.writerow(
                [
                    name,
                    choice.kind,
                    source.index,
                    target.index,
                    f'{choice.distance_m:.2f}',
                    f'{choice.rotation_deg:.2f}',
                    f'{choice.overlap:.3f}',
                ]
            )


class TooFewFrames(ValueError):
    """A bag holds fewer than two labeled scans with ground truth."""


@dataclass
class CutReport:
    """What :func:`cut_hard_pairs` wrote."""

    frames: int  # labeled scans with ground truth read from the bag
    choices: list[PairChoice]

    def counts(self) -> dict[str, int]:
        """Return the pairs written per kind ('stride', 'turn')."""
        return {kind: sum(c.kind == kind for c in self.choices) for kind in ('stride', 'turn')}


def cut_hard_pairs(
    bag: Path,
    out: Path,
    options: CutOptions,
    voxel_size: float = 0.3,
    max_range: float = 60.0,
    keypoints: int = 5000,
    prefix: str | None = None,
    progress: bool = True,
    deskew: str = 'truth',
) -> CutReport:
    """
    Cut hard pairs out of ``bag`` into pair files in ``out`` (``mlsemreg cut-pairs``).

    Reads the labeled scans with ground truth (:func:`read_frames`, motion-compensated as
    ``deskew`` says), draws the pairs
    (:func:`choose_pairs`) and writes them (:func:`write_pair_files`), named
    ``<prefix>_<source>_<target>`` (prefix: the bag's name). Raises :class:`TooFewFrames`
    below two scans, and the reader's errors (``SourceError``, ``OSError``, ``ValueError``).
    """
    frames = read_frames(bag, voxel_size, max_range, progress=progress, deskew=deskew)
    if len(frames) < 2:
        raise TooFewFrames(
            f'{bag} has {len(frames)} labeled scans with ground truth; at least 2 are needed'
        )
    choices = choose_pairs(frames, options)
    write_pair_files(frames, choices, out, prefix or bag.name, keypoints, options.seed)
    return CutReport(len(frames), choices)
