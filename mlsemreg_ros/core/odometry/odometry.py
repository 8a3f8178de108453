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

The code path shared by the ROS node, the offline bag evaluation and the demo. Each job is
a component of its own (``docs/extending.md``)::

    preprocess.py           Preprocessor: raw scan (+ point times) -> lazily prepared scan
    motion_model.py         MotionModel: predicted T_odom_current (constant velocity)
    prior_model.py          the IMU / wheel-odometry prior (motion_prior.source)
    tracking.py             Tracker: guesses refined against the map; the trust rule
    global_registration.py  GlobalRegistration: ML-SemReg + SC2-PCR onto the keyframe
    decision.py             decide / chain: which candidate is accepted, if any
    local_map.py            LocalMap (the ``map``), Keyframe and the keyframe policy
    steps.py                OdometryStep, covariance and twist

Per scan (:meth:`Odometry.process`)::

    stream rules                               duplicate stamp: skip; backwards: reset
    prediction = predict()                     the motion model's guess at the stamp
    current = preprocess(scan, motion)         deskewed by last pose -> prediction (per-point
                                               times); once per scan, the keyframe's cached
    predicted = map.align(current, prediction) the motion model's guess, refined
    if tracking is trusted (on_demand):        accept it: no global registration
    else:
      global = register(current, keyframe)     ML-SemReg + SC2-PCR: T_keyframe_current
      decide(global, predicted)                agreement, or the candidate with most inliers
    align_sweep(current, pose)                 no gyro: the sweep's own twist (CT-ICP-like,
                                               core/alignment/sweep_alignment.py); if it bends
                                               the scan, deskewed with it and aligned again
    map.insert(current, pose)                  only an accepted, aligned scan
    keyframe <- current                        per the keyframe policy

**Global registration on demand** (``odometry.global_registration: on_demand``, default).
ML-SemReg + SC2-PCR is what makes the odometry robust (it registers scans 16 m apart and
after a jump), and it is the expensive part. A scan is *tracked* by the refined
prediction alone only when that can be trusted (``core/alignment/fine_alignment.py``,
:func:`~mlsemreg_ros.core.alignment.fine_alignment.tracking_refusal`). Every other scan is
registered globally; ``always`` registers every scan.

The decision (:func:`~mlsemreg_ros.core.odometry.decision.decide`) never publishes a silent
jump: without an acceptable candidate the frame is rejected, the pose, the keyframe and
the map stay, and ``reason`` says why. After ``keyframe.max_failures`` rejections in a row
the odometry re-initialises on the current scan at the last accepted pose.
**The core owns the odometry state**: pose, keyframe, local map, covariances, twist.

With ``fine.method: off`` the odometry is the earlier scan-to-keyframe chain: the pose
is ``pose_keyframe @ global`` when the registration succeeded.
"""

from __future__ import annotations

from collections import deque
import time

from mlsemreg_ros.core.alignment.covariance import calibrated_covariance, motion_size
from mlsemreg_ros.core.alignment.fine_alignment import alignment_cloud, Candidate
from mlsemreg_ros.core.alignment.sweep_alignment import align_sweep, MapGaussians, sweep_subset
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.features.deskew import (
    MAX_DESKEW_WINDOW,
    PiecewiseSweepMotion,
    sweep_motion,
    SweepMotion,
)
from mlsemreg_ros.core.features.moving_objects import MovingObjectFilter
from mlsemreg_ros.core.labeling.source import LabelSource
from mlsemreg_ros.core.odometry.decision import chain, decide
from mlsemreg_ros.core.odometry.global_registration import GlobalRegistration
from mlsemreg_ros.core.odometry.local_map import (
    is_new_keyframe,
    Keyframe,
    keyframe_refusal,
    LocalMap,
    make_map,
)
from mlsemreg_ros.core.odometry.motion_model import make_motion_model, Prediction
from mlsemreg_ros.core.odometry.preprocess import PreprocessedScan, Preprocessor
from mlsemreg_ros.core.odometry.prior_guard import better_without_prior, prior_disagreement
from mlsemreg_ros.core.odometry.prior_model import motion_model_name
from mlsemreg_ros.core.odometry.steps import (
    Decision,
    odom_covariance,
    OdometryStep,
    prepare_timings,
    REINITIALIZATION_VARIANCE,
    twist_between,
)
from mlsemreg_ros.core.odometry.tracking import Tracker
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.results import PreparedScan, RegistrationResult
from mlsemreg_ros.core.rigid import invert_transform
import numpy as np

#: Rounds of deskew and alignment of the scan after a start (the motion follows the pose).
START_DESKEW_ROUNDS = 3
#: ... until the alignment moves the pose by less than this (m).
START_DESKEW_TOLERANCE = 0.01
#: The sweep alignment needs a local map of at least this many voxels.
MIN_SWEEP_MAP_VOXELS = 100
#: Sections whose change makes the cached keyframe be prepared again.
_PREPARE_SECTIONS = ('semantic', 'features', 'keypoints', 'moving_objects')


def _next_sweep(last_stamp_ns: int, stamp_ns: int, point_times: np.ndarray | None) -> bool:
    """Whether ``stamp_ns`` follows ``last_stamp_ns`` by at most 1.5 sweep spans (no skip)."""
    if point_times is None or not np.size(point_times) or not last_stamp_ns or not stamp_ns:
        return False
    times = np.asarray(point_times, dtype=np.float64)
    span = float(np.nanmax(times) - np.nanmin(times))
    return 0.0 < 1e-9 * (stamp_ns - last_stamp_ns) <= 1.5 * span


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
        # the components (seams: docs/extending.md)
        self.preprocessor = Preprocessor(self.registration)
        label_map = getattr(self.registration, 'label_map', None)  # stand-ins lack it
        self.moving_objects = MovingObjectFilter(label_map) if label_map is not None else None
        self.label_source = LabelSource(label_map)  # core/labeling/source.py
        self._check_moving_objects(cfg)
        self.motion_model = make_motion_model(cfg, motion_model_name(cfg))
        self.map = make_map(cfg)
        self.tracker = Tracker(self.map)
        self.global_registration = GlobalRegistration(self.registration)
        # the state
        self.keyframe: Keyframe | None = None
        self.pose = np.eye(4)
        self.covariance = np.zeros((6, 6))
        self._count = 0
        self._last_accepted: tuple[np.ndarray, int] | None = None  # (pose, stamp): the twist
        self._accepted: deque[tuple[np.ndarray, int]] = deque(maxlen=MAX_DESKEW_WINDOW + 1)
        self._failures = 0  # rejected frames in a row
        self._last_stamp = 0  # stamp of the last scan (0: none or unstamped)
        self._start_scan: tuple[PreprocessedScan, np.ndarray, int] | None = None  # to deskew
        self._sweep_twist: tuple[SweepMotion, int] | None = None  # (twist, stamp) of a sweep

    @property
    def config(self) -> RegistrationConfig:
        """Return the configuration in use."""
        return self.registration.config

    @property
    def local_map(self) -> LocalMap:
        """Return the map the scans are tracked against."""
        return self.map

    def reconfigure(self, config: RegistrationConfig) -> None:
        """
        Apply a new configuration from the next scan on.

        The cached keyframe is prepared again only when a section that
        :meth:`Registration.prepare` reads (semantic, features, keypoints) changed; its
        alignment cloud only when ``fine`` changed; the local map is cleared when its
        structure (method, voxel size) changed.
        """
        self._check_moving_objects(config)
        old = self.registration.config
        self.registration.config = config
        if self.keyframe is not None:
            if any(getattr(old, s) != getattr(config, s) for s in _PREPARE_SECTIONS):
                keyframe = self.keyframe
                keyframe.prepared = self.registration.prepare(
                    keyframe.points, keyframe.labels, lazy=True
                )
                self._exclude_moving(keyframe.prepared, keyframe.points, keyframe.labels)
            elif old.fine != config.fine:
                self.keyframe.prepared.alignment_clouds.clear()  # rebuilt when needed
        if self.map.reconfigure(config.fine, config.local_map) and self.keyframe:
            self._insert(self.keyframe.prepared, self.keyframe.pose)  # restart from the keyframe
        if old.motion_prior != config.motion_prior:  # core/odometry/prior_model.py
            if motion_model_name(old) != motion_model_name(config):
                self.motion_model = make_motion_model(config, motion_model_name(config))
                if self._last_accepted is not None:
                    self.motion_model.update(*self._last_accepted)
            elif hasattr(self.motion_model, 'cfg'):
                self.motion_model.cfg = config.motion_prior

    def reset(self) -> None:
        """Drop the keyframe and the map; the next scan restarts the odometry at identity."""
        self.keyframe = None
        self.pose = np.eye(4)
        self.covariance = np.zeros((6, 6))
        self.map.clear()
        self.motion_model.reset()
        self.tracker.restart()
        self._count = 0
        self._last_accepted = None
        self._accepted.clear()
        self._failures = 0
        self._last_stamp = 0
        self._start_scan = None
        self._sweep_twist = None

    def keyframe_refusal(self, scan: PreparedScan) -> str:
        """Why ``scan`` cannot be a keyframe ('' if it can): too few points or keypoints."""
        return keyframe_refusal(self.config, scan)

    def predict(self, stamp_ns: int) -> np.ndarray | None:
        """Return the motion model's ``T_odom_current`` at ``stamp_ns``, or None."""
        prediction = self.motion_model.predict(stamp_ns)
        return None if prediction is None else prediction.T_odom_current

    # ------------------------------------------------------------------------------
    def process(
        self,
        points: np.ndarray,
        labels: np.ndarray | None,
        stamp_ns: int = 0,
        *,
        point_times: np.ndarray | None = None,
    ) -> OdometryStep:
        """
        Register one scan (points (N, 3) metres, labels (N,)) and update the odometry.

        ``labels`` is the cloud's label field, or None without one; ``label_source``
        decides which labels the scan gets (core/labeling/source.py).

        ``point_times`` (N,), seconds, go to the preprocessor's deskew step. Stream rules
        (stamps of 0 mean unstamped and are exempt): a stamp equal to the last one is
        skipped; a stamp before it resets the odometry first (a bag that loops, a replay
        restarted).
        """
        start = time.perf_counter()
        labelled = self.label_source(points, labels, self.config)  # labels None: no field
        labels = labelled.labels
        skipped, notes = self._stream_rules(stamp_ns)
        if skipped:
            return self._finish(self._rejected(self._count, stamp_ns, None, skipped), start)
        index = self._count
        self._count += 1
        prediction = self._prediction(stamp_ns)
        motion = self._sweep_motion(prediction, stamp_ns, point_times)
        rotation_only = motion is None and prediction is None
        if rotation_only:  # no velocity yet: the gyro's rotation alone (if there is an IMU)
            motion = self._gyro_motion(stamp_ns, point_times, np.zeros(3))
        raw = self._preprocess(points, labels, point_times, motion)
        raw.scan.input_stats['label_source'] = labelled.source
        raw.scan.timings_ms['labeling_ms'] = labelled.labeling_ms
        raw.rotation_only = rotation_only and raw.deskewed
        if self.keyframe is None:  # first scan: keyframe at identity, the map's first scan
            return self._finish(self._first(index, stamp_ns, raw, notes), start, raw)
        timings: dict[str, float] = {}
        chosen = self._estimate(raw.scan, stamp_ns, timings, prediction)
        refusal = prior_disagreement(  # core/odometry/prior_guard.py
            prediction,
            chosen,
            raw.motion,
            self.motion_model,
            self._last_accepted,
            stamp_ns,
            self.config.motion_prior.max_disagreement,
        )
        if refusal:
            raw, chosen, refusal = self._without_prior(
                (points, labels, point_times, stamp_ns), raw, chosen, refusal, timings
            )
        step = self._apply(index, stamp_ns, raw, chosen)
        step.prior_refusal = refusal
        self._count_failure(step, raw)
        registered = chosen.result.timings_ms if chosen.result is not None else {}
        step.timings_ms = {
            **prepare_timings(raw.scan),
            **timings,
            **{f'register.{k}': v for k, v in registered.items()},
            **step.timings_ms,
        }
        return self._finish(step, start, raw)

    def _without_prior(
        self,
        scan: tuple[np.ndarray, np.ndarray, np.ndarray | None, int],
        raw: PreprocessedScan,
        chosen: Decision,
        refusal: str,
        timings: dict[str, float],
    ) -> tuple[PreprocessedScan, Decision, str]:
        """Register the scan again without the prior; keep the better (``prior_guard.py``)."""
        points, labels, point_times, stamp_ns = scan
        constant = getattr(self.motion_model, 'constant_velocity', None)
        prediction = constant(stamp_ns) if constant is not None else None
        motion = self._sweep_motion(prediction, stamp_ns, None)  # the poses' twist, no gyro
        tracked = self.tracker.tracked_in_a_row
        again = self._preprocess(points, labels, point_times, motion)
        other = self._estimate(again.scan, stamp_ns, timings, prediction)
        if better_without_prior(chosen, other):
            other.reason = '; '.join(r for r in (other.reason, f'prior not used: {refusal}') if r)
            if other.source == chosen.source == 'prediction':
                self.tracker.tracked_in_a_row -= 1  # one scan, tracked once
            return again, other, f'not used: {refusal}'
        self.tracker.tracked_in_a_row = tracked
        return raw, chosen, f'kept (registered without it too, aligned worse): {refusal}'

    def _prediction(self, stamp_ns: int) -> Prediction | None:
        """Return the motion model's prediction at ``stamp_ns`` if the odometry uses one."""
        if self.keyframe is None or not self.config.odometry.constant_velocity:
            return None
        return self.motion_model.predict(stamp_ns)

    def _sweep_motion(
        self, prediction: Prediction | None, stamp_ns: int, point_times: np.ndarray | None = None
    ) -> SweepMotion | PiecewiseSweepMotion | None:
        """
        Return the motion within the sweep: an earlier accepted pose -> the prediction.

        The twist spans ``preprocess.deskew_window`` accepted poses back: a twist from the
        last pose only (window 1) feeds each pose's error into the next deskew with gain 1,
        a marginally stable loop (``docs/field.md``). With a gyro over the sweep
        (``motion_model.sweep_rotations``) the rotation follows it sample by sample, and
        the twist gives only the translation: a turn that starts or ends within the sweep
        is not averaged away. Without a gyro, the twist the sweep alignment estimated over
        the last accepted sweep (``sweep_alignment``) is the most recent measure of the
        rotation rate within a sweep, and is used instead when this scan is the next sweep
        (its stamp at most 1.5 sweep spans later; after a skip the rate is too old). The
        velocity stays the poses': the sweep's own estimate leans on its prior where the
        scene leaves the forward speed free, so fed forward it would lag an acceleration.
        """
        window = self.config.preprocess.deskew_window
        if prediction is None or not self._accepted:
            return None
        pose, stamp = self._accepted[-min(window, len(self._accepted))]
        motion = sweep_motion(pose, stamp, prediction.T_odom_current, stamp_ns)
        if motion is None:
            return None
        gyro = self._gyro_motion(stamp_ns, point_times, motion.velocity)
        if gyro is not None:
            return gyro
        last = self._sweep_twist
        if (
            last is not None
            and last[1] == self._accepted[-1][1]
            and self.config.sweep_alignment.mode != 'off'
            and _next_sweep(last[1], stamp_ns, point_times)
        ):
            return SweepMotion(last[0].omega, motion.velocity)
        return motion

    def _gyro_motion(
        self, stamp_ns: int, point_times: np.ndarray | None, velocity: np.ndarray
    ) -> PiecewiseSweepMotion | None:
        """
        Return the gyro's rotation within the sweep with the body ``velocity`` (m/s), or None.

        None when the motion model has no gyro over the sweep (no IMU, constant velocity).
        """
        gyro = getattr(self.motion_model, 'sweep_rotations', None)
        if gyro is None or point_times is None or not np.size(point_times):
            return None
        times = np.asarray(point_times, dtype=np.float64)
        if not np.all(np.isfinite(times)):
            return None
        rotations = gyro(stamp_ns, float(times.min()), float(times.max()))
        if rotations is None:
            return None
        return PiecewiseSweepMotion.from_rotations(*rotations, velocity)

    def _preprocess(
        self,
        points: np.ndarray,
        labels: np.ndarray,
        point_times: np.ndarray | None,
        motion: SweepMotion | None = None,
    ) -> PreprocessedScan:
        """Preprocess; moving objects are dropped first or kept out of the map after."""
        mask = self._moving_mask(points, labels)
        if mask is not None and self.config.moving_objects.matching == 'drop':
            keep = ~mask
            points, labels = np.asarray(points)[keep], np.asarray(labels).reshape(-1)[keep]
            if point_times is not None and np.size(point_times) == len(keep):
                point_times = np.asarray(point_times).reshape(-1)[keep]
            mask = None
        raw = self.preprocessor(points, labels, point_times, motion)
        if mask is not None:
            self._exclude_moving(raw.scan, raw.points, raw.labels, mask)
        return raw

    def _check_moving_objects(self, config: RegistrationConfig) -> None:
        """Resolve ``moving_objects.movable_classes`` now (ConfigError for unknown names)."""
        if self.moving_objects is not None:
            self.moving_objects.movable_lookup(config.moving_objects)

    def _moving_mask(self, points: np.ndarray, labels: np.ndarray) -> np.ndarray | None:
        """Return the raw points ``moving_objects`` filters (N,) bool, or None if none."""
        if self.moving_objects is None:
            return None
        shape, labels = np.shape(points), np.asarray(labels).reshape(-1)
        if len(shape) != 2 or shape[1] != 3 or shape[0] != len(labels):
            return None  # preparation says what is wrong with the scan
        cfg = self.config
        return self.moving_objects.raw_mask(labels, cfg.moving_objects, cfg.semantic.label_scheme)

    def _exclude_moving(
        self,
        scan: PreparedScan,
        points: np.ndarray,
        labels: np.ndarray,
        mask: np.ndarray | None = None,
    ) -> None:
        """Mark the prepared points kept out of the local map (``scan.map_excluded``)."""
        if self.moving_objects is None:
            return
        if mask is None:
            mask = self._moving_mask(points, labels)
        filtered = None
        if mask is not None and len(mask) == len(points):
            filtered = np.asarray(points).reshape(-1, 3)[mask]
        cfg = self.config
        scan.map_excluded = self.moving_objects.prepared_mask(
            scan.points, scan.labels, filtered, cfg.moving_objects, cfg.features.voxel_size
        )
        if scan.map_excluded is not None:
            scan.alignment_clouds.clear()  # built again without the excluded points

    def _stream_rules(self, stamp_ns: int) -> tuple[str, list[str]]:
        """Return why the scan is skipped ('' if not) and notes; reset on a backward stamp."""
        notes = []
        if stamp_ns and self._last_stamp and stamp_ns <= self._last_stamp:
            if stamp_ns == self._last_stamp:
                return f'duplicate stamp {stamp_ns} ns: skipped', notes
            notes.append(
                f'stamp went backwards ({stamp_ns} < {self._last_stamp} ns): odometry reset'
            )
            self.reset()
        if stamp_ns:
            self._last_stamp = stamp_ns
        return '', notes

    def _estimate(
        self,
        current: PreparedScan,
        stamp_ns: int,
        timings: dict[str, float],
        prediction: Prediction | None,
    ) -> Decision:
        """Track the prediction or register globally, and decide."""
        cfg, keyframe = self.config, self.keyframe
        if cfg.fine.method == 'off':
            return chain(self.global_registration(current, keyframe), cfg)
        predicted = self.tracker.refine_prediction(current, prediction, cfg, timings)
        why_global = self.tracker.refusal(predicted, prediction, cfg)
        if not why_global:  # tracking: no global registration needed
            return self.tracker.track(predicted, cfg)
        estimate = self.global_registration(current, keyframe)
        self.tracker.tracked_in_a_row = 0

        def refine(T_initial: np.ndarray) -> Candidate:
            cloud = alignment_cloud(current, cfg.fine)
            return self.tracker.candidate('global', T_initial, cloud, cfg)

        chosen = decide(estimate, predicted, refine, cfg)
        chosen.reason = '; '.join(
            r for r in (f'registered globally: {why_global}', chosen.reason) if r
        )
        return chosen

    # -- the odometry state moves -------------------------------------------------------
    def _first(
        self, index: int, stamp_ns: int, raw: PreprocessedScan, notes: list[str]
    ) -> OdometryStep:
        """Start the odometry on this scan, or reject it if it cannot be a keyframe."""
        current = raw.scan
        refusal = self.keyframe_refusal(current)
        if refusal:
            self._count = 0  # the next scan tries to start the odometry again
            reason = '; '.join([*notes, f'no keyframe yet: {refusal}'])
            return self._rejected(
                index, stamp_ns, current, reason, timings=prepare_timings(current)
            )
        self._start(index, stamp_ns, raw, self.pose)
        return OdometryStep(
            index=index,
            stamp_ns=stamp_ns,
            pose=self.pose.copy(),
            relative=None,
            result=None,
            accepted=True,
            keyframe_index=index,
            keyframe_stamp_ns=stamp_ns,
            new_keyframe=True,
            prepared=current,
            timings_ms=prepare_timings(current),
            source='first',
            reason='; '.join(notes),
            covariance=self.covariance.copy(),
            map_voxels=len(self.map),
        )

    def _apply(
        self, index: int, stamp_ns: int, raw: PreprocessedScan, chosen: Decision
    ) -> OdometryStep:
        """Accept the decision (map, keyframe, motion model move) or reject the frame."""
        if not chosen.accepted:
            step = self._rejected(
                index, stamp_ns, raw.scan, chosen.reason, chosen.result, chosen.relative
            )
        else:
            if chosen.inlier_fraction is not None:
                self.tracker.history.append(chosen.inlier_fraction)
            step = self._accept(index, stamp_ns, raw, chosen)
        step.candidates, step.timings_ms = chosen.candidates, chosen.timings_ms
        return step

    def _accept(
        self, index: int, stamp_ns: int, raw: PreprocessedScan, chosen: Decision
    ) -> OdometryStep:
        """Move the pose, feed the map, move the keyframe; the step of an accepted frame."""
        raw, pose = self._deskew_start(raw, chosen.pose, stamp_ns)
        tic = time.perf_counter()
        raw, pose, sweep_note = self._align_sweep(raw, pose, stamp_ns)
        chosen.timings_ms['sweep_alignment_ms'] = 1e3 * (time.perf_counter() - tic)
        if sweep_note:
            chosen.reason = '; '.join(r for r in (chosen.reason, sweep_note) if r)
        keyframe, current = self.keyframe, raw.scan
        relative = invert_transform(keyframe.pose) @ pose
        chosen.frame_covariance = calibrated_covariance(  # docs/covariance.md
            chosen.frame_covariance, 1.0, self.config.covariance, *motion_size(relative)
        )
        twist, twist_cov = twist_between(
            *self._last_accepted, pose, stamp_ns, chosen.frame_covariance
        )
        self.pose = pose.copy()
        self.covariance = self.covariance + odom_covariance(pose, chosen.frame_covariance)
        self._insert(current, pose)
        self.motion_model.update(pose, stamp_ns)
        learn_labels = getattr(self.registration, 'learn_labels', None)  # stand-ins lack it
        if learn_labels is not None:
            learn_labels(relative, current, keyframe.prepared)  # confidence.label_model adaptive
        self._last_accepted = (pose.copy(), stamp_ns)
        self._accepted.append(self._last_accepted)
        new_keyframe = is_new_keyframe(
            self.config.keyframe, relative
        ) and not self.keyframe_refusal(current)
        if new_keyframe:
            self.keyframe = Keyframe(index, stamp_ns, raw.points, raw.labels, current, pose.copy())
        return OdometryStep(
            index=index,
            stamp_ns=stamp_ns,
            pose=pose.copy(),
            relative=relative,
            result=chosen.result,
            accepted=True,
            keyframe_index=keyframe.index,
            keyframe_stamp_ns=keyframe.stamp_ns,
            new_keyframe=new_keyframe,
            prepared=current,
            source=chosen.source,
            reason=chosen.reason,
            covariance=self.covariance.copy(),
            frame_covariance=chosen.frame_covariance,
            twist=twist,
            twist_covariance=twist_cov,
            map_voxels=len(self.map),
            points=raw.points,
            labels=raw.labels,
        )

    def _rejected(
        self,
        index: int,
        stamp_ns: int,
        current: PreparedScan | None,
        reason: str,
        result: RegistrationResult | None = None,
        relative: np.ndarray | None = None,
        timings: dict[str, float] | None = None,
    ) -> OdometryStep:
        """Return the step of a rejected scan: pose, keyframe, map and covariance stay."""
        keyframe = self.keyframe
        return OdometryStep(
            index=index,
            stamp_ns=stamp_ns,
            pose=self.pose.copy(),
            relative=relative,
            result=result,
            accepted=False,
            keyframe_index=keyframe.index if keyframe else -1,
            keyframe_stamp_ns=keyframe.stamp_ns if keyframe else 0,
            new_keyframe=False,
            prepared=current,
            timings_ms=timings or {},
            reason=reason,
            covariance=self.covariance.copy(),
            map_voxels=len(self.map),
        )

    def _start(self, index: int, stamp_ns: int, raw: PreprocessedScan, pose: np.ndarray) -> None:
        """Make ``raw`` the keyframe at ``pose`` and the first scan of a new map."""
        self.keyframe = Keyframe(index, stamp_ns, raw.points, raw.labels, raw.scan, pose.copy())
        self.map.clear()
        self._insert(raw.scan, pose)
        self.motion_model.reset()
        self.motion_model.update(pose, stamp_ns)
        self._last_accepted = (pose.copy(), stamp_ns)
        self._accepted.clear()
        self._accepted.append(self._last_accepted)
        self.tracker.restart()
        self._failures = 0
        self._start_scan = (raw, pose.copy(), stamp_ns)
        self._sweep_twist = None

    def _deskew_start(
        self, raw: PreprocessedScan, pose: np.ndarray, stamp_ns: int
    ) -> tuple[PreprocessedScan, np.ndarray]:
        """
        Deskew the scan the odometry started on and the next one, once their motion is known.

        Neither had a prediction, so neither was deskewed (or only by the gyro's rotation).
        A map of skewed scans would bias every deskewed scan aligned to it (and, through the
        velocity, the next deskew), and the next one's pose was registered on two skewed
        sweeps. So both are deskewed with the motion estimated between them (the gyro's
        rotation when there is an IMU), prepared again, and the next one is aligned again
        to the first, :data:`START_DESKEW_ROUNDS` times at most (the motion follows the
        pose). Returns the scan and pose to accept; the map holds the first scan
        (``docs/field.md``).
        """
        start, self._start_scan = self._start_scan, None
        if start is None or (raw.deskewed and not raw.rotation_only):
            return raw, pose
        first, first_pose, first_stamp = start
        refusal = self.preprocessor.refusal
        still = SweepMotion(np.zeros(3), np.zeros(3))
        if refusal(first.points, first.point_times, still) or refusal(
            raw.points, raw.point_times, still
        ):
            return raw, pose  # no times (the clean world), deskew off: nothing to redo
        cfg = self.config
        redone, current = (first, raw), pose
        for _ in range(START_DESKEW_ROUNDS):
            twist = sweep_motion(first_pose, first_stamp, current, stamp_ns)
            if twist is None:
                break
            attempt = []
            for scan, stamp in ((first, first_stamp), (raw, stamp_ns)):
                motion = self._gyro_motion(stamp, scan.point_times, twist.velocity) or twist
                points = scan.input_points if scan.input_points is not None else scan.points
                attempt.append(self._preprocess(points, scan.labels, scan.point_times, motion))
            if not all(r.deskewed for r in attempt):
                break
            redone = tuple(attempt)
            self.map.clear()
            self._insert(redone[0].scan, first_pose)
            again = self.tracker.candidate(
                'start', current, alignment_cloud(redone[1].scan, cfg.fine), cfg
            )
            if not again.acceptable:
                break
            moved = again.alignment.correction
            current = again.alignment.T_target_source
            if np.linalg.norm(moved[:3, 3]) < START_DESKEW_TOLERANCE:
                break
        if redone[0] is first:
            return raw, pose
        if self.map.empty or redone[1] is raw:
            self.map.clear()
            self._insert(redone[0].scan, first_pose)
        keyframe = self.keyframe
        if keyframe.stamp_ns == first_stamp:
            r = redone[0]
            keyframe.points, keyframe.labels, keyframe.prepared = r.points, r.labels, r.scan
        return redone[1], current

    def _align_sweep(
        self, raw: PreprocessedScan, pose: np.ndarray, stamp_ns: int
    ) -> tuple[PreprocessedScan, np.ndarray, str]:
        """
        Estimate the motion within the sweep from the sweep itself (no gyro), if it bends it.

        A scan deskewed by a constant twist from the poses is aligned to the local map with
        its sweep twist free (``core/alignment/sweep_alignment.py``). When the estimated
        twist moves some point by more than ``sweep_alignment.min_change``, the scan is
        deskewed with it, prepared again and aligned again from the joint estimate; the
        result replaces the pose if the map accepts it. Returns the scan, the pose and a note.
        """
        cfg = self.config
        motion = raw.motion
        if (
            cfg.sweep_alignment.mode == 'off'
            or cfg.fine.method == 'off'
            or not isinstance(motion, SweepMotion)  # deskewed by a twist: points and times
            or self.map.empty
        ):
            return raw, pose, ''
        gaussians = self.map.gaussians()
        if gaussians is None or len(gaussians[0]) < MIN_SWEEP_MAP_VOXELS:
            return raw, pose, ''
        points, times = raw.input_points, np.asarray(raw.point_times, dtype=np.float64)
        if cfg.moving_objects.matching != 'drop':  # 'drop' took them out before the deskew
            moving = self._moving_mask(points, raw.labels)
            if moving is not None and len(moving) == len(points):
                points, times = points[~moving], times[~moving]
        points, times = sweep_subset(points, times, cfg.sweep_alignment.points)
        result = align_sweep(
            points, times, MapGaussians(*gaussians), pose, motion, cfg.sweep_alignment
        )
        finite = np.all(np.isfinite(result.T_target_source)) and np.all(
            np.isfinite(np.concatenate([result.motion.omega, result.motion.velocity]))
        )
        if not finite or not np.isfinite(result.change_m):
            return raw, pose, 'sweep alignment diverged: the deskew twist is kept'
        if result.change_m <= cfg.sweep_alignment.min_change:
            self._sweep_twist = (result.motion, stamp_ns)
            return raw, pose, ''
        redone = self._preprocess(raw.input_points, raw.labels, raw.point_times, result.motion)
        if not redone.deskewed:
            return raw, pose, ''
        again = self.tracker.candidate(
            'sweep', result.T_target_source, alignment_cloud(redone.scan, cfg.fine), cfg
        )
        if not again.acceptable:
            return raw, pose, f'{result.summary(motion)}: not kept ({again.refusal})'
        self._sweep_twist = (result.motion, stamp_ns)
        return redone, again.alignment.T_target_source, result.summary(motion)

    def _count_failure(self, step: OdometryStep, raw: PreprocessedScan) -> None:
        """After ``keyframe.max_failures`` rejections in a row, re-initialise on this scan."""
        if step.accepted:
            self._failures = 0
            return
        self._failures += 1
        limit = self.config.keyframe.max_failures
        if not limit or self._failures < limit or self.keyframe_refusal(raw.scan):
            return
        self._start(step.index, step.stamp_ns, raw, self.pose)
        self.covariance = self.covariance + np.eye(6) * REINITIALIZATION_VARIANCE
        step.new_keyframe, step.source = True, 'reinitialized'
        step.keyframe_index, step.map_voxels = step.index, len(self.map)
        step.reason += (
            f'; {limit} frames rejected in a row: re-initialised on this scan at '
            'the last accepted pose (the motion since is unknown)'
        )

    def _insert(self, scan: PreparedScan, pose: np.ndarray) -> None:
        if self.config.fine.method != 'off':
            self.map.insert(alignment_cloud(scan, self.config.fine), pose)

    @staticmethod
    def _finish(
        step: OdometryStep, start: float, raw: PreprocessedScan | None = None
    ) -> OdometryStep:
        if raw is not None:
            step.deskewed = raw.deskewed
            if step.points is None:  # _accept set the scan it aligned (perhaps redone)
                step.points, step.labels = raw.points, raw.labels
            if raw.deskew_note:
                step.reason = '; '.join(r for r in (step.reason, raw.deskew_note) if r)
        step.latency_ms = 1e3 * (time.perf_counter() - start)
        return step
