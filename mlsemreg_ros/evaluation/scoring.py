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
Scoring in one place: a scan's row, a sequence's summary and details, a pair's metrics.

Built on :mod:`mlsemreg_ros.core.metrics` (RE, TE, inliers, KITTI errors, NEES) and
:mod:`mlsemreg_ros.evaluation.trajectory` (ATE and RPE from evo), with
the success bounds of :class:`~mlsemreg_ros.evaluation.settings.EvaluationConfig`:
success iff the estimator accepted the scan and RE <= 5 deg and TE <= 0.6 m (defaults);
RR = share of successful pairs among the registered scans with ground truth; RE / TE are
averaged over the successful ones (paper Sec. 4.1).
"""

from __future__ import annotations

import math
from typing import Any

from mlsemreg_ros.core.metrics import (
    evaluate_pair,
    inlier_mask,
    kitti_odometry_errors,
    normalized_estimation_error_squared,
    PairMetrics,
    rotation_error_deg,
    translation_error_m,
)
from mlsemreg_ros.core.rigid import relative_transform
from mlsemreg_ros.datasets.source import Scan
from mlsemreg_ros.evaluation.records import EvalRun, FrameEstimate, FrameRecord
from mlsemreg_ros.evaluation.settings import EvaluationConfig
from mlsemreg_ros.evaluation.trajectory import trajectory_errors
import numpy as np

#: summary.json keys, in order (the contract of every sequence evaluation).
SUMMARY_KEYS = (
    'n_frames',
    'registration_recall_pct',
    'rotation_error_deg',
    'translation_error_cm',
    'kitti_t_err_pct',
    'kitti_r_err_deg_per_100m',
    'ate_rmse_m',
    'ate_unaligned_m',
    'rpe_step_m',
    'rpe_100m_m',
    'latency_ms_p50',
    'latency_ms_p95',
    'nees_mean',
)
#: Units of the summary keys (the results table).
SUMMARY_UNITS = {
    'n_frames': '',
    'registration_recall_pct': '%',
    'rotation_error_deg': 'deg',
    'translation_error_cm': 'cm',
    'kitti_t_err_pct': '%',
    'kitti_r_err_deg_per_100m': 'deg/100m',
    'ate_rmse_m': 'm',
    'ate_unaligned_m': 'm',
    'rpe_step_m': 'm',
    'rpe_100m_m': 'm',
    'latency_ms_p50': 'ms',
    'latency_ms_p95': 'ms',
    'nees_mean': '(6 ideal)',
}


def finite_or_none(value: Any) -> Any:
    """Return None for NaN and inf (strict JSON), anything else as it is."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def score_pair(
    transform: np.ndarray,
    src_pts: np.ndarray,
    dst_pts: np.ndarray,
    T_gt: np.ndarray,
    bounds: EvaluationConfig,
) -> PairMetrics:
    """IN / IR of the correspondences and RE / TE / success of one registered pair."""
    return evaluate_pair(
        transform,
        src_pts,
        dst_pts,
        T_gt,
        bounds.inlier_threshold,
        bounds.max_rotation_deg,
        bounds.max_translation_m,
    )


def score_frame(
    frame: int,
    scan: Scan,
    estimate: FrameEstimate,
    gt: np.ndarray | None,
    gt_keyframe: np.ndarray | None,
    bounds: EvaluationConfig,
) -> FrameRecord:
    """
    Score one scan of a replay against the ground truth: its ``frames.csv`` row.

    - ``gt``, ``gt_keyframe``: ground-truth poses (4, 4) of the scan and of its keyframe.
    - RE / TE need an estimate and both poses; a registered scan without an estimate
      (refused) keeps NaN and counts as a failed pair. The ground-truth inliers are
      counted only when the correspondences are known (NaN IR otherwise).
    """
    nan = math.nan
    registered = estimate.keyframe_index is not None
    keyframe_index = estimate.keyframe_index if registered else scan.index
    re = te = nees = ir = nan
    gt_inliers = 0
    if registered and gt is not None and gt_keyframe is not None:
        T_gt = relative_transform(gt_keyframe, gt)
        T = estimate.relative
        if T is not None and np.all(np.isfinite(T)):
            re = rotation_error_deg(T[:3, :3], T_gt[:3, :3])
            te = translation_error_m(T[:3, 3], T_gt[:3, 3])
            if estimate.accepted and estimate.frame_covariance is not None:
                nees = normalized_estimation_error_squared(T, T_gt, estimate.frame_covariance)
        if estimate.correspondences and estimate.source_points is not None:
            gt_inliers = int(
                np.count_nonzero(
                    inlier_mask(
                        estimate.source_points,
                        estimate.target_points,
                        T_gt,
                        bounds.inlier_threshold,
                    )
                )
            )
            ir = 100.0 * gt_inliers / estimate.correspondences
    success = registered and estimate.accepted and bounds.succeeded(re, te)
    gt_xyz = gt[:3, 3] if gt is not None else (nan, nan, nan)
    return FrameRecord(
        frame,
        scan.index,
        scan.stamp_ns,
        keyframe_index,
        registered,
        bool(estimate.accepted),
        bool(success),
        re,
        100.0 * te,
        estimate.correspondences,
        estimate.estimator_inliers,
        gt_inliers,
        ir,
        estimate.mode,
        bool(estimate.new_keyframe),
        estimate.latency_ms,
        *map(float, estimate.pose[:3, 3]),
        *map(float, gt_xyz),
        estimate.message,
        estimate.source,
        nees,
    )


def summarize_run(run: EvalRun) -> dict[str, Any]:
    """summary.json: exactly :data:`SUMMARY_KEYS` (None where undefined)."""
    # every registered scan with ground truth counts; a rejected one is a failure
    pairs = [r for r in run.records if r.registered and math.isfinite(r.gt_x)]
    ok = [r for r in pairs if r.success]
    nees = [r.nees for r in run.records if math.isfinite(r.nees)]
    latencies = [r.latency_ms for r in run.records if r.registered] or [
        r.latency_ms for r in run.records
    ]
    kitti = None
    trajectory: dict[str, float | None] = {}
    if run.gt_poses is not None and len(run.records) >= 2:
        kitti = kitti_odometry_errors(run.poses, run.gt_poses)
        trajectory = trajectory_errors(run.poses, run.gt_poses)
    summary = {
        'n_frames': len(run.records),
        'registration_recall_pct': 100.0 * len(ok) / len(pairs) if pairs else None,
        'rotation_error_deg': float(np.mean([r.re_deg for r in ok])) if ok else None,
        'translation_error_cm': float(np.mean([r.te_cm for r in ok])) if ok else None,
        'kitti_t_err_pct': kitti[0] if kitti else None,
        'kitti_r_err_deg_per_100m': kitti[1] if kitti else None,
        'ate_rmse_m': trajectory.get('ate_rmse_m'),
        'ate_unaligned_m': trajectory.get('ate_unaligned_m'),
        'rpe_step_m': trajectory.get('rpe_step_m'),
        'rpe_100m_m': trajectory.get('rpe_100m_m'),
        'latency_ms_p50': float(np.percentile(latencies, 50)) if latencies else None,
        'latency_ms_p95': float(np.percentile(latencies, 95)) if latencies else None,
        'nees_mean': float(np.mean(nees)) if nees else None,
    }
    assert tuple(summary) == SUMMARY_KEYS
    return {k: finite_or_none(v) for k, v in summary.items()}


def run_details(run: EvalRun, **extra: Any) -> dict[str, Any]:
    """details.json: counts, mean IR/IN, modes, stage timings and run information."""
    registered = [r for r in run.records if r.registered]
    irs = [r.ir_gt_pct for r in registered if math.isfinite(r.ir_gt_pct)]
    modes: dict[str, int] = {}
    sources: dict[str, int] = {}
    for r in registered:
        modes[r.mode] = modes.get(r.mode, 0) + 1
        sources[r.source or 'rejected'] = sources.get(r.source or 'rejected', 0) + 1
    path_length = None
    if run.gt_poses is not None:
        steps = np.diff(run.gt_poses[:, :3, 3], axis=0)
        path_length = float(np.sum(np.linalg.norm(steps, axis=1)))
    details = {
        'sequence': run.name,
        'n_pairs': len(registered),
        'n_pairs_with_ground_truth': sum(math.isfinite(r.re_deg) for r in registered),
        'n_accepted': sum(r.accepted for r in registered),
        'n_rejected': sum(not r.accepted for r in registered),
        'n_success': sum(r.success for r in registered),
        'inlier_ratio_gt_pct_mean': float(np.mean(irs)) if irs else None,
        'inlier_number_gt_mean': (
            float(np.mean([r.gt_inliers for r in registered])) if registered else None
        ),
        'correspondences_mean': (
            float(np.mean([r.correspondences for r in registered])) if registered else None
        ),
        'modes': modes,
        'pose_sources': sources,
        'path_length_m': path_length,
        'wall_time_s': run.wall_s,
        'stage_ms_mean': run.stage_ms,
    }
    details.update(extra)
    return {k: finite_or_none(v) for k, v in details.items()}
