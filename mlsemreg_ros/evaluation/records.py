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
What an evaluation holds: one estimator's answer per scan, one scored row per scan, the run.

:class:`FrameEstimate` is what an estimator adapter returns for a scan (see
:mod:`mlsemreg_ros.evaluation.estimators`); :func:`~mlsemreg_ros.evaluation.scoring.score_frame`
turns it into a :class:`FrameRecord` (a row of ``frames.csv``); :class:`EvalRun` is the whole
replay.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np


@dataclass
class PairClouds:
    """The prepared (voxelized) clouds of a registered scan and its keyframe, for plots."""

    target_points: np.ndarray  # (N, 3) keyframe scan
    target_labels: np.ndarray  # (N,) learning ids
    source_points: np.ndarray  # (M, 3) current scan
    source_labels: np.ndarray  # (M,)


@dataclass
class FrameEstimate:
    """An estimator's answer for one scan (input of the scoring)."""

    pose: np.ndarray  # (4, 4) estimated T_world_scan (the last accepted one when rejected)
    keyframe_index: int | None  # sequence index of the scan it was registered onto; None: not
    #                             registered (first scan, no answer)
    relative: np.ndarray | None = None  # (4, 4) estimated T_keyframe_scan, if any
    accepted: bool = False  # the estimator accepted the scan (moved the pose)
    latency_ms: float = math.nan
    correspondences: int = 0  # correspondences fed to the robust estimator
    estimator_inliers: int = 0  # the estimator's own inlier count
    source_points: np.ndarray | None = None  # (K, 3) correspondences, current scan side
    target_points: np.ndarray | None = None  # (K, 3) keyframe side
    mode: str = ''  # ml-semreg, gm-only, kiss-icp, ...
    new_keyframe: bool = False
    message: str = ''  # why it was rejected, or notes
    source: str = ''  # what gave the accepted pose (first, global, prediction, ...)
    frame_covariance: np.ndarray | None = None  # (6, 6) of ``relative``, [t, rotvec] order
    timings_ms: dict[str, float] = field(default_factory=dict)
    clouds: PairClouds | None = None  # for the correspondence plot (None: not offered)


@dataclass
class FrameRecord:
    """One row of frames.csv."""

    frame: int  # processed scan counter
    bag_index: int  # index of the scan in the bag
    stamp_ns: int
    keyframe_index: int  # bag index of the keyframe it was registered onto
    registered: bool  # False for the first scan
    accepted: bool  # registration succeeded (enough inliers) and moved the pose
    success: bool  # accepted and within the success bounds (evaluation settings)
    re_deg: float
    te_cm: float
    correspondences: int
    inliers: int  # estimator inliers
    gt_inliers: int  # correspondences within the inlier threshold under the ground truth
    ir_gt_pct: float  # 100 * gt_inliers / correspondences (NaN when not measured)
    mode: str
    new_keyframe: bool
    latency_ms: float
    x: float
    y: float
    z: float
    gt_x: float
    gt_y: float
    gt_z: float
    message: str = ''
    source: str = ''  # what gave the accepted pose (first, global, prediction, ...)
    nees: float = math.nan  # normalized estimation error squared of the frame's covariance


@dataclass
class EvalRun:
    """Everything an evaluation produced."""

    name: str
    records: list[FrameRecord]
    stamps_ns: np.ndarray  # (F,)
    poses: np.ndarray  # (F, 4, 4) estimated, first processed scan = identity
    gt_poses: np.ndarray | None  # (F, 4, 4) ground truth relative to the first processed scan
    wall_s: float
    stage_ms: dict[str, float] = field(default_factory=dict)  # mean per-frame stage timings
    plot_pair: dict[str, np.ndarray] | None = None
    method: str = 'ML-SemReg'
