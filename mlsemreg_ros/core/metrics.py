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
Evaluation metrics: the paper's pair protocol and KITTI sequence metrics.

Pairs (paper Sec. 4.1): a correspondence is an inlier iff
``||T_gt p - q|| < 0.6 m`` (KITTI); IN = inlier count, IR = IN / |C|;
RE = arccos((trace(R_gt^T R) - 1) / 2) in degrees, TE = ||t - t_gt||;
a pair is registered successfully iff RE <= 5 deg and TE <= 60 cm; RR is the
share of successful pairs, RE and TE are averaged over successful pairs only.

Sequences: the KITTI odometry devkit's relative errors (translation in %,
rotation in deg/100 m over segments of 100..800 m, first frames every 10
frames) and NEES. ATE and RPE come from evo (:mod:`mlsemreg_ros.evaluation.trajectory`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
import math

from mlsemreg_ros.core.rigid import invert_transform
import numpy as np

#: Segment lengths (m) of the KITTI odometry devkit.
KITTI_SEGMENT_LENGTHS_M = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
#: The devkit starts a segment at every 10th frame.
KITTI_STEP_FRAMES = 10


def _apply(T: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """``T @ p`` for (K, 3) points and a (4, 4) transform."""
    T = np.asarray(T, dtype=np.float64)
    return np.asarray(pts, dtype=np.float64).reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]


def inlier_mask(
    src_pts: np.ndarray, dst_pts: np.ndarray, T_gt: np.ndarray, threshold: float
) -> np.ndarray:
    """
    Correspondences with ``||T_gt p - q|| < threshold`` (paper Sec. 4.1).

    - ``src_pts``: (K, 3) source points of the correspondences, metres.
    - ``dst_pts``: (K, 3) target points of the correspondences, metres.
    - ``T_gt``: (4, 4) ground truth ``T_target_source``.
    - ``threshold``: inlier distance in metres (KITTI 0.6, indoor 0.1).

    Returns (K,) bool.
    """
    residual = _apply(T_gt, src_pts) - np.asarray(dst_pts, dtype=np.float64).reshape(-1, 3)
    return np.linalg.norm(residual, axis=1) < threshold


def rotation_error_deg(R_est: np.ndarray, R_gt: np.ndarray) -> float:
    """RE = arccos((trace(R_gt^T R_est) - 1) / 2) in degrees, argument clipped to [-1, 1]."""
    R_est = np.asarray(R_est, dtype=np.float64)[:3, :3]
    R_gt = np.asarray(R_gt, dtype=np.float64)[:3, :3]
    cos = (np.trace(R_gt.T @ R_est) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def translation_error_m(t_est: np.ndarray, t_gt: np.ndarray) -> float:
    """TE = ||t_est - t_gt|| in metres."""
    diff = np.asarray(t_est, dtype=np.float64).reshape(3) - np.asarray(t_gt, np.float64).reshape(3)
    return float(np.linalg.norm(diff))


@dataclass
class PairMetrics:
    """Paper metrics of one registered pair."""

    inlier_number: int  # IN: correspondences within the inlier threshold under T_gt
    inlier_ratio_pct: float  # IR = 100 * IN / |C| (0 without correspondences)
    n_correspondences: int  # |C|
    rotation_error_deg: float  # RE (nan if the estimate is not finite)
    translation_error_cm: float  # TE in centimetres (nan if the estimate is not finite)
    success: bool  # RE <= max_rotation_deg and TE <= max_translation_m

    def to_dict(self) -> dict:
        """Plain dict (JSON friendly)."""
        return asdict(self)


def evaluate_pair(
    transform: np.ndarray,
    src_pts: np.ndarray,
    dst_pts: np.ndarray,
    T_gt: np.ndarray,
    inlier_threshold: float = 0.6,
    max_rotation_deg: float = 5.0,
    max_translation_m: float = 0.6,
) -> PairMetrics:
    """
    IN/IR of the correspondences and RE/TE/success of the estimate (paper Sec. 4.1).

    - ``transform``: (4, 4) estimated ``T_target_source``.
    - ``src_pts``: (K, 3) source points of the correspondences fed to the estimator.
    - ``dst_pts``: (K, 3) target points of the correspondences.
    - ``T_gt``: (4, 4) ground truth ``T_target_source``.
    - ``inlier_threshold``: inlier distance, metres (KITTI 0.6).
    - ``max_rotation_deg``: success bound on RE (KITTI 5 deg, ScanNet 15 deg).
    - ``max_translation_m``: success bound on TE (KITTI 0.6 m, ScanNet 0.3 m).
    """
    src_pts = np.asarray(src_pts, dtype=np.float64).reshape(-1, 3)
    n = int(src_pts.shape[0])
    inliers = int(np.count_nonzero(inlier_mask(src_pts, dst_pts, T_gt, inlier_threshold)))
    T = np.asarray(transform, dtype=np.float64)
    T_gt = np.asarray(T_gt, dtype=np.float64)
    if np.all(np.isfinite(T)):
        re = rotation_error_deg(T[:3, :3], T_gt[:3, :3])
        te = translation_error_m(T[:3, 3], T_gt[:3, 3])
        success = bool(re <= max_rotation_deg and te <= max_translation_m)
    else:
        re, te, success = math.nan, math.nan, False
    return PairMetrics(inliers, 100.0 * inliers / n if n else 0.0, n, re, 100.0 * te, success)


def summarize(metrics: list[PairMetrics]) -> dict:
    """
    Dataset summary as in the paper's tables.

    IN and IR are means over all pairs; RR is the share of successful pairs in %;
    RE (deg) and TE (cm) are means over the successful pairs only (None if none).
    """
    n = len(metrics)
    ok = [m for m in metrics if m.success]

    def mean(values: list[float]) -> float | None:
        return float(np.mean(values)) if values else None

    return {
        'n_pairs': n,
        'inlier_number': mean([m.inlier_number for m in metrics]),
        'inlier_ratio_pct': mean([m.inlier_ratio_pct for m in metrics]),
        'registration_recall_pct': 100.0 * len(ok) / n if n else None,
        'rotation_error_deg': mean([m.rotation_error_deg for m in ok]),
        'translation_error_cm': mean([m.translation_error_cm for m in ok]),
    }


def normalized_estimation_error_squared(
    T_estimate: np.ndarray, T_truth: np.ndarray, covariance: np.ndarray
) -> float:
    """
    NEES ``e^T inv(C) e`` of an estimate whose error ``T_truth^-1 T_estimate = exp(e)``.

    ``e = [translation, rotation vector]`` in the estimate's own frame (ROS order, as the
    odometry's ``frame_covariance``). A consistent covariance gives a mean NEES of 6 (the
    dimension); larger means overconfident, smaller underconfident. NaN when ``C`` is
    singular.
    """
    from scipy.spatial.transform import Rotation

    error = invert_transform(T_truth) @ np.asarray(T_estimate, dtype=np.float64)
    e = np.concatenate([error[:3, 3], Rotation.from_matrix(error[:3, :3]).as_rotvec()])
    try:
        return float(e @ np.linalg.solve(covariance, e))
    except np.linalg.LinAlgError:
        return math.nan


# -- sequences -----------------------------------------------------------------------------
def _check_poses(poses_est: np.ndarray, poses_gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    est = np.asarray(poses_est, dtype=np.float64)
    gt = np.asarray(poses_gt, dtype=np.float64)
    if est.shape != gt.shape or est.ndim != 3 or est.shape[1:] != (4, 4):
        raise ValueError(f'poses must both be (F, 4, 4), got {est.shape} and {gt.shape}')
    return est, gt


def kitti_odometry_errors(
    poses_est: np.ndarray,
    poses_gt: np.ndarray,
    lengths_m: tuple[float, ...] = KITTI_SEGMENT_LENGTHS_M,
    step_frames: int = KITTI_STEP_FRAMES,
) -> tuple[float, float] | None:
    """
    KITTI odometry relative errors, as the devkit's ``calcSequenceErrors``.

    For every first frame ``i`` (every ``step_frames``) and segment length ``L``, the
    last frame ``j`` is the first whose ground-truth path distance exceeds
    ``dist[i] + L``; the error pose is ``(E_i^-1 E_j)^-1 (G_i^-1 G_j)``. The translation
    error is ``||t_err|| / L`` and the rotation error ``angle(R_err) / L``; both are
    averaged over all segments.

    - ``poses_est``: (F, 4, 4) estimated poses in a common world frame.
    - ``poses_gt``: (F, 4, 4) ground-truth poses.
    - ``lengths_m``: segment lengths in metres.
    - ``step_frames``: frame step between segment starts.

    Returns ``(translation error in %, rotation error in deg / 100 m)``, or None when no
    segment fits (a trajectory shorter than the shortest segment).
    """
    est, gt = _check_poses(poses_est, poses_gt)
    if est.shape[0] < 2:
        return None
    steps = np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)
    dist = np.concatenate([[0.0], np.cumsum(steps)])
    first = np.arange(0, est.shape[0], step_frames)
    lengths = np.asarray(lengths_m, dtype=np.float64)
    start = np.repeat(first, lengths.shape[0])
    length = np.tile(lengths, first.shape[0])
    last = np.searchsorted(dist, dist[start] + length, side='right')
    valid = last < est.shape[0]
    if not np.any(valid):
        return None
    start, length, last = start[valid], length[valid], last[valid]
    delta_gt = invert_transform(gt[start]) @ gt[last]
    delta_est = invert_transform(est[start]) @ est[last]
    error = invert_transform(delta_est) @ delta_gt
    t_err = np.linalg.norm(error[:, :3, 3], axis=1) / length
    cos = (np.trace(error[:, :3, :3], axis1=1, axis2=2) - 1.0) / 2.0
    r_err = np.arccos(np.clip(cos, -1.0, 1.0)) / length
    return float(100.0 * t_err.mean()), float(np.degrees(r_err.mean()) * 100.0)
