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
a component of its own (``docs/extending.md``); :meth:`Odometry.process` hands a scan down
to each once, in order::

    stream rules       duplicate stamp: skip; backwards: reset
    predict            motion_model.py / prior_model.py: T_odom_current at the stamp
    preprocess         the labels (core/labeling/source.py), then preprocess.py: deskewed by
                       the motion within the sweep, moving objects, lazily prepared
    track or register  tracking.py: the prediction refined against the map and tracked when
    and decide         trusted (trust.py), else registered onto the keyframe and decided
                       (decision.py); a prior that disagrees: again without it (prior_guard.py)
    align the sweep    tracking.py: the start's deskew; no gyro: the sweep's own twist
                       (core/alignment/sweep_alignment.py)
    insert             local_map.py: the aligned scan joins the map; the keyframe policy
    step               steps.py: OdometryStep, covariance and twist

A scan is tracked by the refined prediction alone when the trust rules allow it
(``odometry.global_registration: on_demand``), else registered globally. Never a silent
jump: a rejected frame moves nothing, and ``reason`` says why; at the
``keyframe.max_failures``-th rejection in a row the scan is relocalized onto the past
keyframes (recovery.py), and only if that fails does the odometry re-initialise on the scan
at the last accepted pose. The core owns the odometry state (docs/architecture.md).
"""

from __future__ import annotations

from collections import deque
import time
from typing import Any

from mlsemreg_ros.core.alignment.covariance import calibrated_covariance, motion_size
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.features.deskew import MAX_DESKEW_WINDOW, SweepMotion
from mlsemreg_ros.core.labeling.source import LabelSource
from mlsemreg_ros.core.odometry import sensor_scale
from mlsemreg_ros.core.odometry.deskew_guard import DeskewCheckSchedule, guard_deskew
from mlsemreg_ros.core.odometry.global_registration import GlobalRegistration
from mlsemreg_ros.core.odometry.local_map import (
    insert_accepted,
    Keyframe,
    keyframe_refusal,
    LocalMap,
    make_map,
)
from mlsemreg_ros.core.odometry.motion_model import make_motion_model, Prediction
from mlsemreg_ros.core.odometry.preprocess import PreprocessedScan, Preprocessor
from mlsemreg_ros.core.odometry.prior_guard import guard_prior
from mlsemreg_ros.core.odometry.prior_model import motion_model_name
from mlsemreg_ros.core.odometry.recovery import PastKeyframes
from mlsemreg_ros.core.odometry.steps import (
    accepted_step,
    Decision,
    OdometryStep,
    prediction_covariance,
    REINITIALIZATION_VARIANCE,
    step_at_pose,
)
from mlsemreg_ros.core.odometry.sweep_starts import retry_refused
from mlsemreg_ros.core.odometry.tracking import Tracker
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.results import PreparedScan, RegistrationResult
from mlsemreg_ros.core.rigid import invert_transform
import numpy as np

#: Sections whose change makes the cached keyframe be prepared again.
_PREPARE_SECTIONS = ('semantic', 'features', 'keypoints', 'moving_objects')


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
        self.label_source = LabelSource(getattr(self.registration, 'label_map', None))
        self.preprocessor = Preprocessor(self.registration)  # moving objects, deskew, prepare
        self.motion_model = make_motion_model(cfg, motion_model_name(cfg))
        self.map = make_map(cfg)
        self.tracker = Tracker(self.map)
        self.global_registration = GlobalRegistration(self.registration)
        # the state
        self.keyframe: Keyframe | None = None
        self.past_keyframes = PastKeyframes(cfg.keyframe.relocalization_keyframes)  # recovery.py
        self.pose = np.eye(4)
        self.covariance = np.zeros((6, 6))
        self._count = 0
        self._last_accepted: tuple[np.ndarray, int] | None = None  # (pose, stamp): the twist
        self._accepted: deque[tuple[np.ndarray, int]] = deque(maxlen=MAX_DESKEW_WINDOW + 1)
        self._failures = 0  # rejected frames in a row
        self._last_stamp = 0  # stamp of the last scan (0: none or unstamped)
        self._start_scan: tuple[PreprocessedScan, np.ndarray, int] | None = None  # to deskew
        self._sweep_twist: tuple[SweepMotion, int] | None = None  # (twist, stamp) of a sweep
        self._last_frame_covariance: np.ndarray | None = None  # of the last accepted frame
        self.sensor_scale: sensor_scale.SensorScale | None = None  # from the first scan
        self.deskew_checks = DeskewCheckSchedule()  # which scans the deskew check runs on

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
        config = sensor_scale.apply(config, self.sensor_scale)  # a sparse sensor's values
        self.preprocessor.check(config)
        old = self.registration.config
        self.registration.config = config
        if self.keyframe is not None:
            if any(getattr(old, s) != getattr(config, s) for s in _PREPARE_SECTIONS):
                keyframe = self.keyframe
                keyframe.prepared = self.registration.prepare(
                    keyframe.points, keyframe.labels, lazy=True
                )
                self.preprocessor.exclude_moving(
                    keyframe.prepared, keyframe.points, keyframe.labels
                )
            elif old.fine != config.fine:
                self.keyframe.prepared.alignment_clouds.clear()  # rebuilt when needed
        self.past_keyframes.resize(config.keyframe.relocalization_keyframes)
        if self.map.reconfigure(config.fine, config.local_map) and self.keyframe:
            self.map.insert_scan(self.keyframe.prepared, self.keyframe.pose)  # from the keyframe
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
        self.past_keyframes.clear()
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
        self._last_frame_covariance = None
        self.deskew_checks.reset()

    def restart_at(self, pose: np.ndarray, covariance: np.ndarray | None = None) -> None:
        """Reset, then start the next scan at ``T_odom_current = pose`` (a set pose)."""
        self.reset()
        self.pose = np.asarray(pose, dtype=np.float64).copy()
        if covariance is not None:
            self.covariance = np.asarray(covariance, dtype=np.float64).reshape(6, 6).copy()

    def keyframe_refusal(self, scan: PreparedScan) -> str:
        """Why ``scan`` cannot be a keyframe ('' if it can): too few points or keypoints."""
        return keyframe_refusal(self.config, scan)

    @property
    def failures_in_a_row(self) -> int:
        """Return the number of scans rejected in a row since the last accepted one."""
        return self._failures

    def sweep_state(self) -> tuple[deque[tuple[np.ndarray, int]], Any, Any]:
        """Return what the motion within a sweep needs: accepted poses, sweep twist, model."""
        return self._accepted, self._sweep_twist, self.motion_model

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
        intensity: np.ndarray | None = None,
    ) -> OdometryStep:
        """
        Register one scan (points (N, 3) metres, labels (N,)) and update the odometry.

        ``labels`` is the cloud's label field, or None without one; ``label_source``
        decides which labels the scan gets (core/labeling/source.py).

        ``intensity`` (N,) feeds ``label_source: onnx`` (the network's remission channel).
        ``point_times`` (N,), seconds, go to the preprocessor's deskew step. Stream rules
        (stamps of 0 mean unstamped and are exempt): a stamp equal to the last one is
        skipped; a stamp before it resets the odometry first (a bag that loops, a replay
        restarted).
        """
        start = time.perf_counter()
        if self.sensor_scale is None and self.keyframe is None:  # scale with the sensor
            measured = sensor_scale.measure(points, self.config)
            if measured.points >= sensor_scale.MIN_POINTS:
                self.sensor_scale = measured
                self.reconfigure(self.config)
        labelled = self.label_source(points, labels, self.config, intensity)  # None: no field
        labels = labelled.labels
        self.preprocessor.labelled = labelled  # noted at every preprocessing of this scan
        skipped, notes = self._stream_rules(stamp_ns)
        if skipped:
            return self._finish(self._rejected(self._count, stamp_ns, None, skipped), start)
        index = self._count
        self._count += 1
        prediction = self._prediction(stamp_ns)
        state = self.sweep_state()
        raw = self.preprocessor.sweep(points, labels, point_times, prediction, stamp_ns, *state)
        if self.keyframe is None:  # first scan: keyframe at identity, the map's first scan
            return self._finish(self._first(index, stamp_ns, raw, notes), start, raw)
        timings: dict[str, float] = {}
        chosen = self.tracker.estimate(
            raw.scan, prediction, self.keyframe, self.global_registration, self.config, timings
        )
        given = (points, labels, point_times, stamp_ns)
        raw, chosen, prior_refusal = guard_prior(  # core/odometry/prior_guard.py
            self, given, prediction, raw, chosen, timings
        )
        raw, chosen, deskew_refusal = guard_deskew(  # core/odometry/deskew_guard.py
            self, given, prediction, raw, chosen, timings
        )
        raw, chosen = retry_refused(self, given, prediction, raw, chosen, timings)  # sweep_starts
        chosen = self._relocalize(raw, chosen, timings)  # core/odometry/recovery.py
        step = self._apply(index, stamp_ns, raw, chosen)
        step.prior_refusal = prior_refusal
        step.deskew_refusal = deskew_refusal
        if not step.accepted:
            self._predict_rejected(step, prediction)
        self._count_failure(step, raw)
        registered = chosen.result.timings_ms if chosen.result is not None else {}
        step.timings_ms = {
            **_prepare_timings(raw.scan),
            **timings,
            **{f'register.{k}': v for k, v in registered.items()},
            **step.timings_ms,
        }
        return self._finish(step, start, raw)

    def _predict_rejected(self, step: OdometryStep, prediction: Prediction | None) -> None:
        """Put the motion model's pose at a rejected scan's stamp, with its covariance, on it."""
        if prediction is None and self.keyframe is not None:  # constant_velocity off
            prediction = self.motion_model.predict(step.stamp_ns)
        if prediction is None or self._last_accepted is None:
            return
        step.predicted_pose = prediction.T_odom_current.copy()
        step.predicted_covariance = prediction_covariance(
            self.covariance,
            self._last_accepted[0],
            prediction.T_odom_current,
            self._last_frame_covariance,
            prediction.stamp_gap,
        )

    def _prediction(self, stamp_ns: int) -> Prediction | None:
        """Return the motion model's prediction at ``stamp_ns`` if the odometry uses one."""
        if self.keyframe is None or not self.config.odometry.constant_velocity:
            return None
        return self.motion_model.predict(stamp_ns)

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
                index, stamp_ns, current, reason, timings=_prepare_timings(current)
            )
        self._start(index, stamp_ns, raw, self.pose)
        step = self._rejected(
            index, stamp_ns, current, '; '.join(notes), timings=_prepare_timings(current)
        )
        step.accepted, step.new_keyframe, step.source = True, True, 'first'
        return step

    def _apply(
        self, index: int, stamp_ns: int, raw: PreprocessedScan, chosen: Decision
    ) -> OdometryStep:
        """Accept the decision (map, keyframe, motion model move) or reject the frame."""
        if chosen.pose is None:  # rejected
            step = self._rejected(
                index, stamp_ns, raw.scan, chosen.reason, chosen.result, chosen.relative
            )
        else:
            step = self._accept(index, stamp_ns, raw, chosen)
        step.candidates, step.timings_ms = chosen.candidates, chosen.timings_ms
        return step

    def _accept(
        self, index: int, stamp_ns: int, raw: PreprocessedScan, chosen: Decision
    ) -> OdometryStep:
        """Align the sweep, move the pose, feed the map, move the keyframe; the step."""
        keyframe, start, self._start_scan = self.keyframe, self._start_scan, None
        raw, pose, sweep_twist = self.tracker.align_accepted(
            chosen,
            raw,
            start,
            stamp_ns,
            keyframe,
            self.preprocessor,
            self.motion_model,
            self.config,
        )
        if sweep_twist is not None:
            self._sweep_twist = (sweep_twist, stamp_ns)
        current, relative = raw.scan, invert_transform(keyframe.pose) @ pose
        predicted = [c.T_initial for c in chosen.candidates if c.name == 'prediction']
        correction = motion_size(invert_transform(predicted[0]) @ pose) if predicted else (0, 0)
        chosen.frame_covariance = calibrated_covariance(  # docs/covariance.md
            chosen.frame_covariance,
            1.0,
            self.config.covariance,
            *motion_size(relative),
            correction=correction,
            horizon_s=(stamp_ns - self._last_accepted[1]) * 1e-9 if self._last_accepted else 0.0,
        )
        last, self._last_accepted = self._last_accepted, (pose.copy(), stamp_ns)
        self._accepted.append(self._last_accepted)
        self.pose = pose.copy()
        self.motion_model.update(pose, stamp_ns)
        learn_labels = getattr(self.registration, 'learn_labels', None)  # stand-ins lack it
        if learn_labels is not None:
            learn_labels(relative, current, keyframe.prepared)  # confidence.label_model adaptive
        self.keyframe, voxels = insert_accepted(
            self.map, self.config, keyframe, relative, index, stamp_ns, raw, pose
        )
        step = accepted_step(
            index, stamp_ns, pose, relative, chosen, raw, keyframe, last, self.covariance, voxels
        )
        self.covariance = step.covariance.copy()
        self._last_frame_covariance = chosen.frame_covariance
        step.new_keyframe = self.keyframe is not keyframe
        if step.new_keyframe:
            self.past_keyframes.remember(keyframe)
        return step

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
        """Return the step of a scan that leaves pose, keyframe, map and covariance as they are."""
        return step_at_pose(
            index, stamp_ns, self, current, reason, result, relative, timings, len(self.map)
        )

    def _start(self, index: int, stamp_ns: int, raw: PreprocessedScan, pose: np.ndarray) -> None:
        """Make ``raw`` the keyframe at ``pose`` and the first scan of a new map."""
        self.keyframe = Keyframe(index, stamp_ns, raw.points, raw.labels, raw.scan, pose.copy())
        self.past_keyframes.clear()  # their map is gone
        self.map.clear()
        self.map.insert_scan(raw.scan, pose)
        self.motion_model.reset()
        self.motion_model.update(pose, stamp_ns)
        self._last_accepted = (pose.copy(), stamp_ns)
        self._accepted.clear()
        self._accepted.append(self._last_accepted)
        self.tracker.restart()
        self._failures = 0
        self._start_scan = (raw, pose.copy(), stamp_ns)
        self._sweep_twist = None

    def _relocalize(
        self, raw: PreprocessedScan, chosen: Decision, timings: dict[str, float]
    ) -> Decision:
        """
        Relocalize onto the past keyframes at the ``keyframe.max_failures``-th rejection in a row.

        The scan is registered onto the keyframes the odometry left behind and refined
        against the local map (``core/odometry/recovery.py``); the decision stays rejected
        (and :meth:`_count_failure` re-initialises) when none gives a trusted pose.
        """
        limit = self.config.keyframe.max_failures
        if chosen.pose is not None or not limit or self._failures + 1 < limit:
            return chosen
        if self.config.fine.method == 'off':
            return chosen
        found, said = self.past_keyframes.relocalize(
            raw.scan, self.tracker, self.global_registration, self.config, timings
        )
        if found is None:
            chosen.reason = f'{chosen.reason}; relocalization failed ({said})'
            return chosen
        found.reason = f'{limit} frames rejected in a row ({chosen.reason}): {found.reason}'
        found.timings_ms = {**chosen.timings_ms, **found.timings_ms}
        return found

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
        step.covariance = self.covariance.copy()  # the jump is flagged
        step.new_keyframe, step.source = True, 'reinitialized'
        step.keyframe_index, step.map_voxels = step.index, len(self.map)
        step.reason += (
            f'; {limit} frames rejected in a row: re-initialised on this scan at '
            'the last accepted pose (the motion since is unknown)'
        )

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


def _prepare_timings(scan: PreparedScan) -> dict[str, float]:
    """Return the scan's preparation stages (lazy ones once computed) as ``prepare.*``."""
    return {f'prepare.{k}': v for k, v in scan.timings_ms.items()}
