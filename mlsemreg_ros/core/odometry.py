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
LiDAR odometry: global ML-SemReg registration for robustness, fine alignment to a local map.

The code path shared by the ROS node, the offline bag evaluation and the demo. Per scan::

    prepare(scan)                                 once per scan; the keyframe's is cached
    predicted = map.align(scan, T_cv)             the constant-velocity prediction, refined
    if tracking is trusted (on_demand):           accept it: no global registration
    else:
      global = register(current, keyframe)        ML-SemReg + SC2-PCR: T_keyframe_current
      if predicted agrees with pose_keyframe @ global:  accept it (one alignment paid for)
      else: refined = map.align(scan, pose_keyframe @ global), accept the better candidate
    map.insert(scan, pose)                        only an accepted, aligned scan
    keyframe <- current                           per the keyframe policy

**Global registration on demand** (``odometry.global_registration: on_demand``, default).
ML-SemReg + SC2-PCR is what makes the odometry robust (it registers scans 16 m apart and
after a jump), and it is the expensive part. A scan is *tracked* by the refined
prediction alone only when that can be trusted: the refinement is acceptable, it moved
the prediction by at most ``odometry.tracking_translation/rotation`` (the motion model
held), it kept at least ``odometry.tracking_min_inlier_fraction`` of the scan as map
inliers and at least ``odometry.tracking_inlier_share`` of the usual inlier fraction,
the stamps show no gap (at most 1.5 nominal frame intervals since the last accepted scan)
and fewer than ``odometry.global_interval`` scans were tracked in a row. Every other scan is
registered globally as before; ``always`` registers every scan.

The decision (:meth:`Odometry._decide`) is documented there; what it guarantees:

- **Never a silent jump.** A candidate is acceptable only if its fine alignment kept
  ``odometry.min_inlier_fraction`` of the scan as map inliers, and at least
  ``odometry.min_relative_inlier_fraction`` of the median fraction of the last accepted
  frames, and moved its initial guess by at most ``odometry.max_correction_*``. Without
  an acceptable candidate the frame is rejected: the pose, the keyframe and the map
  stay, and ``reason`` says why.
- **The global estimate and the prediction check each other.** When both exist and
  disagree, the candidate whose alignment explains more of the scan wins (a wrong global
  estimate, e.g. the mirror pose of a street, loses against the prediction; a wrong
  prediction, e.g. after a jump in speed, loses against the global estimate).
- **The core owns the odometry state**: pose, keyframe, local map, covariances, twist.

With ``fine.method: off`` the odometry is the earlier scan-to-keyframe chain: the pose
is ``pose_keyframe @ global`` when the registration succeeded.

Covariance (ROS order ``[x, y, z, roll, pitch, yaw]``): the accepted alignment's
(:meth:`Alignment.covariance`, current-frame axes) is the frame's covariance; the pose
covariance adds it, rotated into odom axes, to the previous one (a random walk: drift
grows with every frame). Twist: the motion between the last two accepted poses over
their stamp difference, in the current frame; its covariance is the frame's / dt^2.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field
import time

from mlsemreg_ros.core.alignment import Alignment, LocalMap, UNKNOWN_VARIANCE
from mlsemreg_ros.core.config import KeyframeConfig, RegistrationConfig
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.results import PreparedScan, RegistrationResult
from mlsemreg_ros.core.rigid import invert_transform, rotation_angle_deg, scale_motion
import numpy as np
from scipy.spatial.transform import Rotation

#: Sections whose change makes the cached keyframe be prepared again.
_PREPARE_SECTIONS = ('semantic', 'features', 'keypoints')
#: Minimum lever arm of the sparse-inlier covariance model (fine alignment off).
MIN_LEVER_ARM_M = 1.0


def is_new_keyframe(policy: KeyframeConfig, T_keyframe_current: np.ndarray) -> bool:
    """Whether a scan accepted with this relative transform becomes the keyframe."""
    if policy.policy == 'every_frame':
        return True
    T = np.asarray(T_keyframe_current, dtype=np.float64)
    return (
        float(np.linalg.norm(T[:3, 3])) >= policy.min_distance
        or rotation_angle_deg(T) >= policy.min_rotation
    )


@dataclass
class Keyframe:
    """The scan others are registered onto: raw arrays (to re-prepare), prepared scan, pose."""

    index: int  # frame counter of the keyframe scan
    stamp_ns: int
    points: np.ndarray  # (N, 3) raw scan
    labels: np.ndarray  # (N,) raw labels
    prepared: PreparedScan
    pose: np.ndarray  # (4, 4) T_odom_keyframe


@dataclass
class Candidate:
    """One initial guess of the current pose and its refinement against the local map."""

    name: str  # 'global' (ML-SemReg estimate) or 'prediction' (constant velocity)
    T_initial: np.ndarray  # (4, 4) T_odom_current guess
    alignment: Alignment
    refusal: str  # why it is not acceptable ('' if it is)

    @property
    def acceptable(self) -> bool:
        """Whether the refined pose may be published."""
        return not self.refusal


@dataclass
class OdometryStep:
    """What one scan did to the odometry."""

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
    latency_ms: float  # wall time of process()
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


class Odometry:
    """Registers every scan onto a keyframe and refines it against a local map."""

    def __init__(
        self, registration: Registration | None = None, config: RegistrationConfig | None = None
    ) -> None:
        """Use ``registration`` (default: a new one), optionally with ``config``."""
        self.registration = registration if registration is not None else Registration()
        if config is not None:
            self.registration.config = config
        cfg = self.registration.config
        self.local_map = LocalMap(cfg.fine, cfg.local_map)
        self.keyframe: Keyframe | None = None
        self.pose = np.eye(4)
        self.covariance = np.zeros((6, 6))
        self._count = 0
        self._accepted: list[tuple[np.ndarray, int]] = []  # last two accepted (pose, stamp)
        self._raw: tuple[np.ndarray, np.ndarray] = (np.zeros((0, 3)), np.zeros(0))
        self._fractions: collections.deque[float] = collections.deque(maxlen=FRACTION_HISTORY)
        self._failures = 0  # rejected frames in a row
        self._last_stamp = 0  # stamp of the last scan (0: none or unstamped)
        self._tracked = 0  # scans accepted by the refined prediction alone, in a row
        self._prediction_factor = 1.0  # stamp gap of the last prediction, in frame intervals

    @property
    def config(self) -> RegistrationConfig:
        """Return the configuration in use."""
        return self.registration.config

    def reconfigure(self, config: RegistrationConfig) -> None:
        """
        Apply a new configuration from the next scan on.

        The cached keyframe is prepared again only when a section that
        :meth:`Registration.prepare` reads (semantic, features, keypoints) changed; its
        alignment cloud only when ``fine`` changed; the local map is cleared when its
        structure (method, voxel size) changed.
        """
        old = self.registration.config
        self.registration.config = config
        if self.keyframe is not None:
            if any(getattr(old, s) != getattr(config, s) for s in _PREPARE_SECTIONS):
                self.keyframe.prepared = self.registration.prepare(
                    self.keyframe.points, self.keyframe.labels, lazy=True
                )
            elif old.fine != config.fine:
                self.keyframe.prepared.alignment_clouds.clear()  # rebuilt when needed
        if self.local_map.reconfigure(config.fine, config.local_map) and self.keyframe:
            self._insert(self.keyframe.prepared, self.keyframe.pose)  # restart from the keyframe

    def reset(self) -> None:
        """Drop the keyframe and the map; the next scan restarts the odometry at identity."""
        self.keyframe = None
        self.pose = np.eye(4)
        self.covariance = np.zeros((6, 6))
        self.local_map.clear()
        self._count = 0
        self._accepted = []
        self._fractions.clear()
        self._failures = 0
        self._last_stamp = 0
        self._tracked = 0

    def keyframe_refusal(self, scan: PreparedScan) -> str:
        """Why ``scan`` cannot be a keyframe ('' if it can): too few points or keypoints."""
        policy = self.config.keyframe
        needed = min(policy.min_keypoints, self.config.keypoints.count)
        points, keypoints = len(scan.points), len(scan.keypoints)
        if points < policy.min_points or keypoints < needed:
            return (
                f'{points} points / {keypoints} keypoints < keyframe.min_points='
                f'{policy.min_points} / keyframe.min_keypoints={needed}'
            )
        return ''

    # ------------------------------------------------------------------------------
    def process(self, points: np.ndarray, labels: np.ndarray, stamp_ns: int = 0) -> OdometryStep:
        """
        Register one scan (points (N, 3) metres, labels (N,)) and update the odometry.

        Stream rules (stamps of 0 mean unstamped and are exempt): a stamp equal to the
        last one is skipped; a stamp before it resets the odometry first (a bag that
        loops, a replay restarted).
        """
        start = time.perf_counter()
        notes = []
        if stamp_ns and self._last_stamp and stamp_ns <= self._last_stamp:
            if stamp_ns == self._last_stamp:
                return self._skipped(stamp_ns, f'duplicate stamp {stamp_ns} ns: skipped', start)
            notes.append(
                f'stamp went backwards ({stamp_ns} < {self._last_stamp} ns): odometry reset'
            )
            self.reset()
        if stamp_ns:
            self._last_stamp = stamp_ns
        index = self._count
        self._count += 1
        # lazy: descriptors and signatures only if a global registration needs them
        current = self.registration.prepare(points, labels, lazy=True)
        self._raw = (np.asarray(points), np.asarray(labels))  # kept if it becomes the keyframe
        timings: dict[str, float] = {}
        if self.keyframe is None:  # first scan: keyframe at identity, the map's first scan
            refusal = self.keyframe_refusal(current)
            if refusal:
                self._count = 0  # the next scan tries to start the odometry again
                reason = '; '.join([*notes, f'no keyframe yet: {refusal}'])
                step = self._rejected(
                    index, stamp_ns, current, None, None, reason, _prepare_timings(current)
                )
                step.latency_ms = 1e3 * (time.perf_counter() - start)
                return step
            self._start(index, stamp_ns, current, self.pose)
            return OdometryStep(
                index,
                stamp_ns,
                self.pose.copy(),
                None,
                None,
                True,
                index,
                stamp_ns,
                True,
                1e3 * (time.perf_counter() - start),
                current,
                _prepare_timings(current),
                source='first',
                reason='; '.join(notes),
                covariance=self.covariance.copy(),
                map_voxels=len(self.local_map),
            )
        keyframe = self.keyframe
        result = None
        if self.config.fine.method == 'off':
            result = self.registration.register(current, keyframe.prepared, refine=False)
            step = self._chain(index, stamp_ns, current, keyframe, result)
        else:
            predicted = self._refine_prediction(current, stamp_ns, timings)
            why_global = self._trusted(predicted)
            if not why_global:  # tracking: no global registration needed
                step = self._track(index, stamp_ns, current, keyframe, predicted)
            else:
                result = self.registration.register(current, keyframe.prepared, refine=False)
                self._tracked = 0
                step = self._decide(index, stamp_ns, current, keyframe, result, predicted)
                step.reason = '; '.join(
                    r for r in (f'registered globally: {why_global}', step.reason) if r
                )
        self._count_failure(step, current)
        registered = (
            {} if result is None else {f'register.{k}': v for k, v in result.timings_ms.items()}
        )
        step.timings_ms = {**_prepare_timings(current), **timings, **registered, **step.timings_ms}
        step.latency_ms = 1e3 * (time.perf_counter() - start)
        return step

    def _start(self, index: int, stamp_ns: int, scan: PreparedScan, pose: np.ndarray) -> None:
        """Make ``scan`` the keyframe at ``pose`` and the first scan of a new map."""
        self._tracked = 0
        self.keyframe = Keyframe(index, stamp_ns, *self._raw, scan, pose.copy())
        self.local_map.clear()
        self._insert(scan, pose)
        self._accepted = [(pose.copy(), stamp_ns)]
        self._fractions.clear()
        self._failures = 0

    def _count_failure(self, step: OdometryStep, current: PreparedScan) -> None:
        """After ``keyframe.max_failures`` rejections in a row, re-initialise on ``current``."""
        if step.accepted:
            self._failures = 0
            return
        self._failures += 1
        limit = self.config.keyframe.max_failures
        if not limit or self._failures < limit or self.keyframe_refusal(current):
            return
        self._start(step.index, step.stamp_ns, current, self.pose)
        self.covariance = self.covariance + np.eye(6) * REINITIALIZATION_VARIANCE
        step.new_keyframe, step.source = True, 'reinitialized'
        step.keyframe_index, step.map_voxels = step.index, len(self.local_map)
        step.reason += (
            f'; {limit} frames rejected in a row: re-initialised on this scan at '
            'the last accepted pose (the motion since is unknown)'
        )

    def _skipped(self, stamp_ns: int, reason: str, start: float) -> OdometryStep:
        """Return the step of a scan that was not processed at all."""
        step = self._rejected(self._count, stamp_ns, None, None, None, reason)
        step.latency_ms = 1e3 * (time.perf_counter() - start)
        return step

    def _rejected(
        self,
        index: int,
        stamp_ns: int,
        current: PreparedScan | None,
        result: RegistrationResult | None,
        relative: np.ndarray | None,
        reason: str,
        timings: dict[str, float] | None = None,
        candidates: list[Candidate] | None = None,
    ) -> OdometryStep:
        """Return the step of a rejected scan: pose, keyframe, map and covariance stay."""
        keyframe = self.keyframe
        return OdometryStep(
            index,
            stamp_ns,
            self.pose.copy(),
            relative,
            result,
            False,
            keyframe.index if keyframe else -1,
            keyframe.stamp_ns if keyframe else 0,
            False,
            0.0,
            current,
            timings or {},
            reason=reason,
            covariance=self.covariance.copy(),
            candidates=candidates or [],
            map_voxels=len(self.local_map),
        )

    # -- the prediction, and tracking by it -------------------------------------------
    def _refine_prediction(
        self, current: PreparedScan, stamp_ns: int, timings: dict[str, float]
    ) -> Candidate | None:
        """Refine the constant-velocity prediction against the map (None without one)."""
        if not self.config.odometry.constant_velocity:
            return None
        prediction = self.predict(stamp_ns)
        if prediction is None:
            return None
        tic = time.perf_counter()
        cloud = self.registration.alignment_cloud(current)  # all cores: small_gicp has the GIL
        timings['fine_cloud_ms'] = 1e3 * (time.perf_counter() - tic)
        tic = time.perf_counter()
        candidate = self._candidate('prediction', prediction, cloud)
        timings['fine_prediction_ms'] = 1e3 * (time.perf_counter() - tic)
        return candidate

    def _trusted(self, predicted: Candidate | None) -> str:
        """Why the refined prediction may not be accepted alone ('' if it may; docstring)."""
        cfg = self.config.odometry
        if cfg.global_registration != 'on_demand':
            return 'global registration: always'
        if predicted is None:
            return 'no prediction yet'
        if not predicted.acceptable:
            return f'prediction refused ({predicted.refusal})'
        if self._tracked + 1 >= cfg.global_interval:
            return f'{self._tracked} scans tracked in a row (odometry.global_interval)'
        if self._prediction_factor > MAX_TRACKING_GAP:
            return f'a gap of {self._prediction_factor:.1f} frame intervals in the stamps'
        alignment = predicted.alignment
        if not _within(
            alignment.T_initial,
            alignment.T_target_source,
            cfg.tracking_translation,
            cfg.tracking_rotation,
        ):
            moved = alignment.correction
            return (
                f'prediction corrected by {np.linalg.norm(moved[:3, 3]):.2f} m / '
                f'{rotation_angle_deg(moved):.2f} deg (odometry.tracking_*)'
            )
        if alignment.inlier_fraction < cfg.tracking_min_inlier_fraction:
            return (
                f'prediction kept {alignment.inlier_fraction:.2f} of the scan < '
                f'odometry.tracking_min_inlier_fraction={cfg.tracking_min_inlier_fraction:g}'
            )
        typical = float(np.median(self._fractions)) if self._fractions else 0.0
        if alignment.inlier_fraction < cfg.tracking_inlier_share * typical:
            return (
                f'prediction kept {alignment.inlier_fraction:.2f} of the scan, usual '
                f'{typical:.2f} (odometry.tracking_inlier_share)'
            )
        return ''

    def _track(
        self,
        index: int,
        stamp_ns: int,
        current: PreparedScan,
        keyframe: Keyframe,
        predicted: Candidate,
    ) -> OdometryStep:
        """Accept a scan by its refined prediction (no global registration)."""
        self._tracked += 1
        alignment = predicted.alignment
        self._fractions.append(alignment.inlier_fraction)
        frame_cov = alignment.covariance(self.config.odometry.covariance_scale, axes='source')
        step = self._accept(
            index,
            stamp_ns,
            current,
            keyframe,
            None,
            alignment.T_target_source,
            frame_cov,
            'prediction',
            f'tracked ({self._tracked} in a row)',
        )
        step.candidates = [predicted]
        return step

    def predict(self, stamp_ns: int) -> np.ndarray | None:
        """
        Constant-velocity prediction of ``T_odom_current`` at ``stamp_ns``, or None.

        The motion between the last two accepted poses, scaled by the ratio of the stamp
        differences (so a dropped or rejected frame is bridged); without usable stamps the
        motion is repeated once. Before two poses were accepted there is no velocity, and
        no prediction: a zero-motion guess would be a guess, not evidence.
        """
        if len(self._accepted) < 2:
            return None
        last, last_stamp = self._accepted[-1]
        before, before_stamp = self._accepted[-2]
        motion = invert_transform(before) @ last
        factor = 1.0
        if last_stamp > before_stamp and stamp_ns > last_stamp:
            factor = (stamp_ns - last_stamp) / (last_stamp - before_stamp)
        self._prediction_factor = factor
        return last @ scale_motion(motion, min(factor, MAX_PREDICTION_FACTOR))

    def _candidate(
        self, name: str, T_initial: np.ndarray, cloud: object, num_threads: int | None = None
    ) -> Candidate:
        alignment = self.local_map.align(cloud, T_initial, num_threads=num_threads)
        refusal = self.registration.refinement_refusal(alignment)
        share = self.config.odometry.min_relative_inlier_fraction
        if not refusal and share > 0 and self._fractions:
            typical = float(np.median(self._fractions))
            if alignment.inlier_fraction < share * typical:
                refusal = (
                    f'fine alignment kept {alignment.inlier_fraction:.2f} of the scan '
                    f'as inliers < odometry.min_relative_inlier_fraction={share:g} x '
                    f'{typical:.2f} (median of the last accepted frames)'
                )
        return Candidate(name, np.asarray(T_initial).copy(), alignment, refusal)

    # -- the decision ----------------------------------------------------------------------
    def _decide(
        self,
        index: int,
        stamp_ns: int,
        current: PreparedScan,
        keyframe: Keyframe,
        result: RegistrationResult,
        predicted: Candidate | None,
    ) -> OdometryStep:
        """
        Accept one candidate or reject the frame.

        1. The global estimate counts when the registration succeeded (enough sparse
           inliers) and is finite: ``T_global = pose_keyframe @ T_keyframe_current``.
        2. If the refined prediction is acceptable and within ``odometry.agreement_*`` of
           ``T_global``, it is accepted (source ``prediction+global``): both agree, and
           the second alignment is not needed.
        3. Otherwise ``T_global`` is refined too, and among the acceptable candidates the
           one with the most alignment inliers wins (a tie goes to the global one).
        4. No acceptable candidate: the frame is rejected; pose, keyframe and map stay.
        """
        cfg = self.config.odometry
        timings: dict[str, float] = {}
        candidates = [predicted] if predicted is not None else []
        global_ok = bool(result.success) and bool(np.all(np.isfinite(result.transform)))
        T_global = keyframe.pose @ result.transform if global_ok else None
        chosen: Candidate | None = None
        source = ''
        notes = []
        if not global_ok:
            notes.append(f'global registration failed ({result.message or "non-finite"})')
        if (
            T_global is not None
            and predicted is not None
            and predicted.acceptable
            and _within(
                predicted.alignment.T_target_source,
                T_global,
                cfg.agreement_translation,
                cfg.agreement_rotation,
            )
        ):
            chosen, source = predicted, 'prediction+global'
        else:
            if T_global is not None:
                tic = time.perf_counter()
                candidates.append(
                    self._candidate('global', T_global, self.registration.alignment_cloud(current))
                )
                timings['fine_global_ms'] = 1e3 * (time.perf_counter() - tic)
            acceptable = [c for c in candidates if c.acceptable]
            if acceptable:
                # most inliers wins; a tie goes to the global candidate (listed last)
                chosen = max(reversed(acceptable), key=lambda c: c.alignment.num_inliers)
                source = chosen.name
                if T_global is not None and chosen.name == 'prediction':
                    notes.append('the global estimate disagrees with the local map')
        if chosen is None:
            reasons = [f'{c.name}: {c.refusal}' for c in candidates]
            reason = '; '.join(notes + reasons) or 'no candidate'
            relative = result.transform if global_ok else None
            return self._rejected(
                index, stamp_ns, current, result, relative, reason, timings, candidates
            )
        pose = chosen.alignment.T_target_source
        self._fractions.append(chosen.alignment.inlier_fraction)
        frame_cov = chosen.alignment.covariance(cfg.covariance_scale, axes='source')
        step = self._accept(
            index, stamp_ns, current, keyframe, result, pose, frame_cov, source, '; '.join(notes)
        )
        step.candidates, step.timings_ms = candidates, timings
        return step

    def _chain(
        self,
        index: int,
        stamp_ns: int,
        current: PreparedScan,
        keyframe: Keyframe,
        result: RegistrationResult,
    ) -> OdometryStep:
        """``fine.method: off``: the pose is ``pose_keyframe @ T`` of a successful registration."""
        if not (result.success and np.all(np.isfinite(result.transform))):
            reason = result.message or 'non-finite transform'
            return self._rejected(index, stamp_ns, current, result, result.transform, reason)
        frame_cov = sparse_inlier_covariance(result, self.config.estimator.inlier_threshold)
        return self._accept(
            index,
            stamp_ns,
            current,
            keyframe,
            result,
            keyframe.pose @ result.transform,
            frame_cov,
            'global',
            '',
        )

    def _accept(
        self,
        index: int,
        stamp_ns: int,
        current: PreparedScan,
        keyframe: Keyframe,
        result: RegistrationResult | None,
        pose: np.ndarray,
        frame_cov: np.ndarray,
        source: str,
        reason: str,
    ) -> OdometryStep:
        """Move the pose, feed the map, move the keyframe; the step of an accepted frame."""
        relative = invert_transform(keyframe.pose) @ pose
        twist, twist_cov = self._twist(pose, stamp_ns, frame_cov)
        axes = np.zeros((6, 6))
        axes[:3, :3] = axes[3:, 3:] = pose[:3, :3]
        self.pose = pose.copy()
        self.covariance = self.covariance + axes @ frame_cov @ axes.T
        if self.config.fine.method != 'off':
            self._insert(current, pose)
        self._accepted = [*self._accepted[-1:], (pose.copy(), stamp_ns)]
        new_keyframe = is_new_keyframe(
            self.config.keyframe, relative
        ) and not self.keyframe_refusal(current)
        if new_keyframe:
            self.keyframe = Keyframe(index, stamp_ns, *self._raw, current, pose.copy())
        return OdometryStep(
            index,
            stamp_ns,
            pose.copy(),
            relative,
            result,
            True,
            keyframe.index,
            keyframe.stamp_ns,
            new_keyframe,
            0.0,
            current,
            source=source,
            reason=reason,
            covariance=self.covariance.copy(),
            frame_covariance=frame_cov,
            twist=twist,
            twist_covariance=twist_cov,
            map_voxels=len(self.local_map),
        )

    def _twist(
        self, pose: np.ndarray, stamp_ns: int, body_cov: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Twist since the last accepted pose (current frame) and its covariance."""
        last, last_stamp = self._accepted[-1]
        if stamp_ns <= last_stamp:
            return np.zeros(6), np.eye(6) * UNKNOWN_VARIANCE
        dt = 1e-9 * (stamp_ns - last_stamp)
        motion = invert_transform(last) @ pose
        twist = np.concatenate([motion[:3, 3], Rotation.from_matrix(motion[:3, :3]).as_rotvec()])
        return twist / dt, body_cov / dt**2

    def _insert(self, scan: PreparedScan, pose: np.ndarray) -> None:
        if self.config.fine.method != 'off':
            self.local_map.insert(self.registration.alignment_cloud(scan), pose)


#: Variance (m^2, rad^2) added to the pose covariance when the odometry re-initialises.
REINITIALIZATION_VARIANCE = 1e2
#: Accepted frames whose median inlier fraction is the typical one.
FRACTION_HISTORY = 10
#: The prediction bridges at most this many nominal frame intervals.
MAX_PREDICTION_FACTOR = 5.0
#: A longer gap in the stamps (in nominal frame intervals) needs the global registration.
MAX_TRACKING_GAP = 1.5


def _within(T_a: np.ndarray, T_b: np.ndarray, translation: float, rotation_deg: float) -> bool:
    delta = invert_transform(T_a) @ T_b
    return (
        float(np.linalg.norm(delta[:3, 3])) <= translation
        and rotation_angle_deg(delta) <= rotation_deg
    )


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


def _prepare_timings(scan: PreparedScan) -> dict[str, float]:
    """Return the scan's preparation stages (lazy ones once computed) as ``prepare.*``."""
    return {f'prepare.{k}': v for k, v in scan.timings_ms.items()}
