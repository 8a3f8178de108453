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
Replay a scan sequence through an estimator and score every scan: the one evaluation loop.

Any :class:`~mlsemreg_ros.datasets.source.ScanSource` (bags, SemanticKITTI folders) and any
:class:`SequenceEstimator` (our odometry, KISS-ICP, a recorded node run: see
:mod:`mlsemreg_ros.evaluation.estimators`). No playback timing: scans are read as fast as
the estimator takes them (PRBonn/kinematic-icp's offline node does the same).
"""

from __future__ import annotations

from dataclasses import dataclass
import time
from typing import Protocol

from mlsemreg_ros.core.metrics import inlier_mask
from mlsemreg_ros.core.rigid import relative_transform
from mlsemreg_ros.datasets.source import expected_frames, Scan, ScanSource
from mlsemreg_ros.evaluation.records import EvalRun, FrameEstimate, FrameRecord
from mlsemreg_ros.evaluation.scoring import score_frame
from mlsemreg_ros.evaluation.settings import EvaluationConfig
import numpy as np


class SequenceEstimator(Protocol):
    """Something that estimates the pose of each scan of a sequence, in order."""

    method: str  # name in tables and plots, e.g. 'ML-SemReg'
    progress_label: str  # suffix of the progress bar, e.g. ' (kiss-icp)'

    def step(self, scan: Scan) -> FrameEstimate:
        """Take the next scan; return its estimate."""
        ...


@dataclass
class ReplayOptions:
    """Which scans, which ground truth, what to keep."""

    stride: int = 1  # keep scans 0, stride, 2 * stride, ...
    max_frames: int | None = None  # stop after this many kept scans
    gt_poses: np.ndarray | None = None  # (F_bag, 4, 4) ground truth by bag index (overrides)
    plot_frame: int | None = None  # bag index of the correspondence plot (default: middle)
    progress: bool = True  # tqdm progress bar


def replay(
    source: ScanSource,
    estimator: SequenceEstimator,
    bounds: EvaluationConfig,
    options: ReplayOptions | None = None,
) -> EvalRun:
    """
    Run every selected scan of ``source`` through ``estimator`` and score it.

    Each scan is scored against its keyframe with the ground truth (the source's poses,
    or ``options.gt_poses``); the first registered scan at or after ``plot_frame`` with
    ground truth and clouds is kept for the correspondence plot.
    """
    from tqdm import tqdm

    options = options or ReplayOptions()
    expected = expected_frames(len(source), options.stride, options.max_frames)
    plot_frame = options.plot_frame
    if plot_frame is None:
        plot_frame = max(expected // 2, 1) * options.stride
    gt_by_index: dict[int, np.ndarray] = {}
    records: list[FrameRecord] = []
    stamps, poses, gts = [], [], []
    stage_sums: dict[str, float] = {}
    plot_pair = None
    start = time.perf_counter()
    for scan in tqdm(
        source.scans(options.stride, options.max_frames),
        total=expected,
        desc=source.name + estimator.progress_label,
        unit='scan',
        disable=not options.progress,
    ):
        gt = scan.pose
        if options.gt_poses is not None:
            gt = options.gt_poses[scan.index] if scan.index < options.gt_poses.shape[0] else None
        if gt is not None:
            gt_by_index[scan.index] = gt
        estimate = estimator.step(scan)
        for stage, ms in estimate.timings_ms.items():
            stage_sums[stage] = stage_sums.get(stage, 0.0) + ms
        kf = estimate.keyframe_index
        gt_keyframe = gt_by_index.get(kf) if kf is not None else None
        records.append(score_frame(len(records), scan, estimate, gt, gt_keyframe, bounds))
        stamps.append(scan.stamp_ns)
        poses.append(estimate.pose.copy())
        gts.append(gt)
        if (
            plot_pair is None
            and estimate.clouds is not None
            and scan.index >= plot_frame
            and gt is not None
            and gt_keyframe is not None
        ):
            plot_pair = correspondence_plot_data(
                estimate, relative_transform(gt_keyframe, gt), scan.index, kf, bounds
            )
    wall = time.perf_counter() - start
    gt_array = None
    if gts and all(g is not None for g in gts):
        gt_array = np.asarray(gts)
        gt_array = relative_transform(gt_array[0], gt_array)
    n = max(len(records), 1)
    return EvalRun(
        source.name,
        records,
        np.asarray(stamps, dtype=np.int64),
        np.asarray(poses).reshape(-1, 4, 4),
        gt_array,
        wall,
        {k: v / n for k, v in sorted(stage_sums.items())},
        plot_pair,
        estimator.method,
    )


def correspondence_plot_data(
    estimate: FrameEstimate,
    T_gt: np.ndarray,
    index: int,
    keyframe_index: int,
    bounds: EvaluationConfig,
) -> dict[str, np.ndarray]:
    """Collect the arrays of ``correspondences.png`` (see ``reports.write_plots``)."""
    clouds = estimate.clouds
    return {
        'target_points': clouds.target_points,
        'source_points': clouds.source_points,
        'T_gt': T_gt,
        'target_labels': clouds.target_labels,
        'source_labels': clouds.source_labels,
        'source_keypoints': estimate.source_points,
        'target_keypoints': estimate.target_points,
        'inliers': inlier_mask(
            estimate.source_points, estimate.target_points, T_gt, bounds.inlier_threshold
        ),
        'bag_index': np.array(index),
        'keyframe_index': np.array(keyframe_index),
    }
