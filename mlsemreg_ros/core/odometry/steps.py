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
What the odometry reports per scan (:class:`OdometryStep`) and how it is computed.

Covariance (ROS order ``[x, y, z, roll, pitch, yaw]``): the accepted alignment's
(:meth:`Alignment.covariance`, current-frame axes) is the frame's covariance; the pose
covariance adds it, rotated into odom axes, to the previous one (a random walk: drift
grows with every frame). Twist: the motion between the last two accepted poses over
their stamp difference, in the current frame; its covariance is the frame's / dt^2.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from mlsemreg_ros.core.alignment.alignment import Alignment, UNKNOWN_VARIANCE
from mlsemreg_ros.core.deferred import deferred_attribute, stored
from mlsemreg_ros.core.odometry.trust import Candidate
from mlsemreg_ros.core.results import PreparedScan, RegistrationResult
from mlsemreg_ros.core.rigid import invert_transform, rotation_vector
import numpy as np

#: Variance (m^2, rad^2) added to the pose covariance when the odometry re-initialises.
REINITIALIZATION_VARIANCE = 1e2
#: Minimum lever arm of the sparse-inlier covariance model (fine alignment off).
MIN_LEVER_ARM_M = 1.0
#: Share of a predicted motion taken as the motion model's error (an unmodelled acceleration).
PREDICTION_MODEL_ERROR = 0.2
#: Least standard deviation of a prediction per frame interval: (m, rad).
MIN_PREDICTION_SIGMA = (0.05, 0.005)


@dataclass
class OdometryStep:
    """What one scan did to the odometry (constructed by keyword)."""

    index: int  # frame counter (0 = first scan after construction or reset)
    stamp_ns: int
    pose: np.ndarray  # (4, 4) T_odom_current: accepted, or the last accepted if rejected
    relative: np.ndarray | None  # (4, 4) T_keyframe_current (accepted, refined); else the
    #                              global estimate (for diagnostics); None for the first scan
    result: RegistrationResult | None  # the global registration; None for the first scan
    #                                  and for a scan tracked by the prediction alone
    accepted: bool  # the frame moved the pose (True for the first scan)
    keyframe_index: int  # frame counter of the keyframe registered onto (own index if first)
    keyframe_stamp_ns: int
    new_keyframe: bool  # this scan became the keyframe
    latency_ms: float = 0.0  # wall time of process()
    prepared: PreparedScan | None = None  # the current scan as prepared (markers, plots)
    timings_ms: dict[str, float] = field(default_factory=dict)
    source: str = ''  # first, global, prediction, prediction+global; reinitialized (rejected)
    reason: str = ''  # why the frame was rejected, or notes on an accepted one
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))  # pose, odom axes
    frame_covariance: np.ndarray | None = None  # (6, 6) of this frame's alignment: the pose
    #                                 perturbation T exp(delta), current-frame axes
    twist: np.ndarray | None = None  # (6,) [vx, vy, vz, wx, wy, wz] current frame, m/s rad/s
    twist_covariance: np.ndarray | None = None  # (6, 6)
    candidates: list[Candidate] = field(default_factory=list)
    map_voxels: int = 0  # local map size after this frame
    deskewed: bool = False  # the scan was motion-compensated (core/features/deskew.py)
    points: np.ndarray | None = None  # (N, 3) the scan's points as the odometry kept them:
    #                             deskewed (by the sweep twist if it bent them), moving objects
    #                             dropped (moving_objects.matching): the input of ``prepared``
    labels: np.ndarray | None = None  # (N,) their raw labels (computed when first read)
    prior_refusal: str = ''  # the prior disagreed with the scan: what was done, and why
    deskew_refusal: str = ''  # the deskewed scan aligned worse than the raw one (deskew_guard)
    predicted_pose: np.ndarray | None = None  # (4, 4) rejected scans: the motion model's
    #                             (or IMU's) T_odom_current at the stamp; None without one
    predicted_covariance: np.ndarray | None = None  # (6, 6) odom axes: the pose's covariance
    #                             inflated by the prediction's (:func:`prediction_covariance`)
    sweep_bend_m: float = 0.0  # m, the sweep alignment's bend of the scan (Decision's)
    sweep_change_m: float = 0.0  # m, its estimate's, kept or not (Decision's)
    residual_variance: float = 0.0  # the accepted fine alignment's 2E / (n - 6) (Decision's)
    inlier_fraction: float = 0.0  # the accepted fine alignment's (Decision's; 0: unknown)


deferred_attribute(OdometryStep, 'labels')


@dataclass
class Decision:
    """The outcome of one scan's estimation, before the odometry state moves."""

    source: str  # global, prediction, prediction+global ('' when rejected)
    reason: str  # why it was rejected, or notes on an accepted one
    result: RegistrationResult | None = None  # the global registration, if one ran
    pose: np.ndarray | None = None  # (4, 4) accepted T_odom_current; None: rejected
    frame_covariance: np.ndarray | None = None  # (6, 6) current-frame axes
    relative: np.ndarray | None = None  # rejected: the global estimate, for diagnostics
    inlier_fraction: float | None = None  # the accepted fine alignment's (history)
    candidates: list[Candidate] = field(default_factory=list)
    timings_ms: dict[str, float] = field(default_factory=dict)
    #: accepted only if the sweep alignment confirms the pose (near_miss.weak_confirmation)
    confirm_weak: bool = False
    #: a pose the near-miss check refused, to judge again once its sweep is deskewed again
    #: (the refusal; '' when none: near_miss.recheck_swept, core/odometry/swept_dispute.py)
    swept_dispute: str = ''
    #: tracked by the motion model's own prediction (no rotated start, no global estimate)
    held: bool = False
    #: m, how far the sweep alignment's twist moved the scan's points against the deskew's
    #: twist, where the scan was deskewed again with it (0: not); the covariance reads it
    sweep_bend_m: float = 0.0
    #: m, the same of the sweep alignment's estimate, kept or not (0: none estimated)
    sweep_change_m: float = 0.0
    #: the accepted fine alignment's ``2E / (n - 6)`` (:attr:`Alignment.residual_variance`,
    #: 0: unknown), which the covariance reads (docs/covariance.md)
    residual_variance: float = 0.0

    @property
    def accepted(self) -> bool:
        """Whether the scan moves the pose."""
        return self.pose is not None

    @classmethod
    def of_alignment(
        cls,
        source: str,
        reason: str,
        alignment: Alignment,
        covariance_scale: float,
        *,
        result: RegistrationResult | None = None,
        candidates: list[Candidate] | None = None,
        timings_ms: dict[str, float] | None = None,
        confirm_weak: bool = False,
    ) -> Decision:
        """
        Accept the pose a fine alignment refined (``alignment.T_target_source``).

        The frame covariance is the alignment's own in the current frame's axes, scaled by
        ``odometry.covariance_scale`` (``covariance_scale``), and the inlier fraction is
        kept for the relative-inlier rule of ``core/odometry/decision.py``.
        """
        return cls(
            source=source,
            reason=reason,
            result=result,
            pose=alignment.T_target_source,
            frame_covariance=alignment.covariance(covariance_scale, axes='source'),
            inlier_fraction=alignment.inlier_fraction,
            residual_variance=alignment.residual_variance,
            candidates=candidates if candidates is not None else [],
            timings_ms=timings_ms if timings_ms is not None else {},
            confirm_weak=confirm_weak,
        )

    def rescued(self, candidate: Candidate, note: str, covariance_scale: float) -> Decision:
        """
        Accept this refused decision by ``candidate``, a global pose a rescue confirmed.

        The rescue's ``note`` joins the refusal's reason; the registration result and the
        timings stay, and ``candidate`` joins the candidates (source ``global``).
        """
        return Decision.of_alignment(
            'global',
            '; '.join(r for r in (self.reason, note) if r),
            candidate.alignment,
            covariance_scale,
            result=self.result,
            candidates=[*self.candidates, candidate],
            timings_ms=self.timings_ms,
        )


def odom_covariance(pose: np.ndarray, frame_covariance: np.ndarray) -> np.ndarray:
    """Rotate a current-frame covariance (6, 6) into odom axes by ``pose`` (4, 4)."""
    axes = np.zeros((6, 6))
    axes[:3, :3] = axes[3:, 3:] = pose[:3, :3]
    return axes @ frame_covariance @ axes.T


def prediction_covariance(
    pose_covariance: np.ndarray,
    last_pose: np.ndarray,
    predicted: np.ndarray,
    frame_covariance: np.ndarray | None,
    stamp_gap: float,
) -> np.ndarray:
    """
    Covariance (6, 6, odom axes) of a predicted pose ``predicted`` (4, 4).

    The prediction extrapolates the last accepted motion over ``stamp_gap`` frame
    intervals, so it inherits the last pose's covariance ``pose_covariance`` plus, in
    the predicted frame's axes, the last frame's alignment error carried ``stamp_gap``
    times (``frame_covariance * gap^2``: a velocity error integrated over the gap) and
    the model's own error: :data:`PREDICTION_MODEL_ERROR` of the predicted motion from
    ``last_pose`` (an unmodelled acceleration), at least :data:`MIN_PREDICTION_SIGMA`
    per interval. The result is never smaller than ``pose_covariance``.
    """
    gap = max(float(stamp_gap), 1.0)
    motion = invert_transform(last_pose) @ predicted
    translation = float(np.linalg.norm(motion[:3, 3]))
    rotation = float(np.linalg.norm(rotation_vector(motion[:3, :3])))
    sigma_t = max(PREDICTION_MODEL_ERROR * translation, MIN_PREDICTION_SIGMA[0] * gap)
    sigma_r = max(PREDICTION_MODEL_ERROR * rotation, MIN_PREDICTION_SIGMA[1] * gap)
    body = np.diag([sigma_t**2] * 3 + [sigma_r**2] * 3)
    if frame_covariance is not None:
        body = body + frame_covariance * gap**2
    return pose_covariance + odom_covariance(predicted, body)


def twist_between(
    last: np.ndarray, last_stamp_ns: int, pose: np.ndarray, stamp_ns: int, body_cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Twist (6,) from ``last`` to ``pose`` (current frame) and its covariance (6, 6)."""
    if stamp_ns <= last_stamp_ns:
        return np.zeros(6), np.eye(6) * UNKNOWN_VARIANCE
    dt = 1e-9 * (stamp_ns - last_stamp_ns)
    motion = invert_transform(last) @ pose
    twist = np.concatenate([motion[:3, 3], rotation_vector(motion[:3, :3])])
    return twist / dt, body_cov / dt**2


def sparse_inlier_covariance(result: RegistrationResult, inlier_threshold: float) -> np.ndarray:
    """
    Covariance (6, 6) of a registration from its sparse inliers (fine alignment off).

    ``[x, y, z, roll, pitch, yaw]`` in m^2 and rad^2, body axes. An inlier's residual is
    bounded by the inlier threshold tau, so the translation's standard error is
    ``sigma_t = tau / sqrt(IN)``; a rotation error theta moves inliers at a lever arm rho
    by about ``rho * theta``, so ``sigma_r = sigma_t / rho`` with rho the RMS distance of
    the inlier keypoints from their centroid (at least 1 m).
    """
    inliers = result.source_points[result.inlier_mask]
    count = max(int(inliers.shape[0]), 1)
    sigma_t = inlier_threshold / np.sqrt(count)
    lever = 0.0
    if inliers.shape[0] > 1:
        lever = float(np.sqrt(((inliers - inliers.mean(axis=0)) ** 2).sum(axis=1).mean()))
    sigma_r = sigma_t / max(lever, MIN_LEVER_ARM_M)
    return np.diag([sigma_t**2] * 3 + [sigma_r**2] * 3)


def accepted_step(
    index: int,
    stamp_ns: int,
    pose: np.ndarray,
    relative: np.ndarray,
    chosen: Decision,
    raw: Any,
    keyframe: Any,
    last_accepted: tuple[np.ndarray, int],
    covariance: np.ndarray,
    map_voxels: int,
) -> OdometryStep:
    """
    Return the step of an accepted scan at ``pose``: its twist and the grown covariance.

    ``raw``: the scan as the odometry kept it (``PreprocessedScan``); ``keyframe``: the one
    it was registered onto; ``last_accepted``: the previous accepted ``(pose, stamp_ns)``;
    ``covariance``: the pose covariance before this frame (odom axes).
    """
    twist, twist_cov = twist_between(*last_accepted, pose, stamp_ns, chosen.frame_covariance)
    return OdometryStep(
        index=index,
        stamp_ns=stamp_ns,
        pose=pose.copy(),
        relative=relative,
        result=chosen.result,
        accepted=True,
        keyframe_index=keyframe.index,
        keyframe_stamp_ns=keyframe.stamp_ns,
        new_keyframe=False,
        prepared=raw.scan,
        source=chosen.source,
        reason=chosen.reason,
        covariance=covariance + odom_covariance(pose, chosen.frame_covariance),
        frame_covariance=chosen.frame_covariance,
        twist=twist,
        twist_covariance=twist_cov,
        map_voxels=map_voxels,
        points=raw.points,
        labels=stored(raw, 'labels'),
        sweep_bend_m=chosen.sweep_bend_m,
        sweep_change_m=chosen.sweep_change_m,
        residual_variance=chosen.residual_variance,
        inlier_fraction=chosen.inlier_fraction or 0.0,
    )


def step_at_pose(
    index: int,
    stamp_ns: int,
    odometry: Any,
    current: PreparedScan | None,
    reason: str,
    result: RegistrationResult | None,
    relative: np.ndarray | None,
    timings: dict[str, float] | None,
    map_voxels: int,
) -> OdometryStep:
    """
    Return the step of a scan that leaves the ``odometry``'s pose where it is.

    A rejected scan (pose, keyframe and covariance stay), or the first (the odometry
    starts on it at its pose, and the caller marks it accepted).
    """
    keyframe = odometry.keyframe
    return OdometryStep(
        index=index,
        stamp_ns=stamp_ns,
        pose=odometry.pose.copy(),
        relative=relative,
        result=result,
        accepted=False,
        keyframe_index=keyframe.index if keyframe else -1,
        keyframe_stamp_ns=keyframe.stamp_ns if keyframe else 0,
        new_keyframe=False,
        prepared=current,
        timings_ms=timings or {},
        reason=reason,
        covariance=odometry.covariance.copy(),
        map_voxels=map_voxels,
    )
