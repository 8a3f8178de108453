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
Trajectory metrics from evo (Grupp, "evo: Python package for the evaluation of odometry and SLAM").

- ATE: evo's APE on the translation part, RMSE, after an SE(3) Umeyama alignment of the
  estimate to the ground truth (no scale) or with none;
- RPE: evo's RPE on the translation part, RMSE, between consecutive scans (per step) and
  between scans 100 m apart along the ground-truth path (all pairs).

Our own code keeps only what evo does not do: the KITTI segment metric
(:func:`mlsemreg_ros.core.metrics.kitti_odometry_errors`), RR, RE / TE per registered pair
and NEES. The results folders hold ``trajectory_tum.txt`` / ``trajectory_kitti.txt`` and the
ground truth beside them, so ``evo_ape`` / ``evo_rpe`` / ``evo_traj`` run on them directly.
"""

from __future__ import annotations

from typing import Any

import numpy as np

RPE_DISTANCE_M = 100.0  # the RPE's long delta, metres along the ground-truth path


def _path(poses_or_positions: np.ndarray) -> Any:
    """Return evo's ``PosePath3D`` of (F, 4, 4) poses or (F, 3) positions (no rotation)."""
    from evo.core.trajectory import PosePath3D

    values = np.asarray(poses_or_positions, dtype=np.float64)
    if values.ndim == 3:
        return PosePath3D(poses_se3=list(values))
    positions = values.reshape(-1, 3)
    orientations = np.tile([1.0, 0.0, 0.0, 0.0], (positions.shape[0], 1))  # w, x, y, z
    return PosePath3D(positions_xyz=positions, orientations_quat_wxyz=orientations)


def _pair(estimate: np.ndarray, truth: np.ndarray) -> tuple[Any, Any]:
    """Return (reference, estimate) paths of equal length."""
    est = np.asarray(estimate, dtype=np.float64)
    gt = np.asarray(truth, dtype=np.float64)
    if est.shape != gt.shape:
        raise ValueError(f'trajectories differ in shape: {est.shape} vs {gt.shape}')
    if est.shape[0] == 0:
        raise ValueError('empty trajectory')
    return _path(gt), _path(est)


def ate_rmse(estimate: np.ndarray, truth: np.ndarray, align: bool = True) -> float:
    """
    Absolute trajectory error (evo APE, translation part): RMSE in metres.

    - ``estimate``, ``truth``: (F, 4, 4) poses or (F, 3) positions.
    - ``align``: first align the estimate to the truth with evo's Umeyama alignment
      (SE(3), no scale; where that is degenerate, a straight or standing trajectory, evo's
      alignment of the first poses); ``False``: none (both start in the same frame).
    """
    from evo.core import geometry, metrics

    reference, estimated = _pair(estimate, truth)
    if align and estimated.num_poses >= 2:
        try:
            estimated.align(reference, correct_scale=False)
        except geometry.GeometryException:  # collinear or standing still: no unique rotation
            estimated.align_origin(reference)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((reference, estimated))
    return float(ape.get_statistic(metrics.StatisticsType.rmse))


def rpe_rmse(
    estimate: np.ndarray, truth: np.ndarray, delta: float = 1.0, metres: bool = False
) -> float | None:
    """
    Relative pose error (evo RPE, translation part): RMSE in metres, None without pairs.

    - ``delta``: the step, in scans (``metres=False``: every scan against the one
      ``delta`` later) or in metres along the ground-truth path (``metres=True``: every
      pair that far apart).
    """
    from evo.core import filters, metrics

    reference, estimated = _pair(estimate, truth)
    if metres:
        rpe = metrics.RPE(
            metrics.PoseRelation.translation_part,
            delta,
            metrics.Unit.meters,
            all_pairs=True,
            pairs_from_reference=True,
        )
    else:
        rpe = metrics.RPE(metrics.PoseRelation.translation_part, delta, metrics.Unit.frames)
    try:
        rpe.process_data((reference, estimated))
    except (filters.FilterException, metrics.MetricsException):  # no pair that far apart
        return None
    return float(rpe.get_statistic(metrics.StatisticsType.rmse))


def trajectory_errors(estimate: np.ndarray, truth: np.ndarray) -> dict[str, float | None]:
    """ATE (aligned, unaligned) and RPE (per step, per 100 m) of summary.json, metres."""
    return {
        'ate_rmse_m': ate_rmse(estimate, truth, align=True),
        'ate_unaligned_m': ate_rmse(estimate, truth, align=False),
        'rpe_step_m': rpe_rmse(estimate, truth, 1.0),
        'rpe_100m_m': rpe_rmse(estimate, truth, RPE_DISTANCE_M, metres=True),
    }
