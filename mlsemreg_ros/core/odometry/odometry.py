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
                       trusted (trust.py), else registered onto the keyframe and decided
                       (decision.py)
    decide             review.py: a prior or a deskew that hurt: again without it
                       (prior_guard.py, deskew_guard.py); refused: other sweep starts
                       (sweep_starts.py); too many rejections: relocalization (failures.py)
    align the sweep    advance.py, accepted: tracking.py aligns the start's deskew; no gyro:
                       the sweep's own twist (core/alignment/sweep_alignment.py)
    insert             advance.py: the aligned scan joins the map, the keyframe policy
                       (local_map.py); the step, its covariance and twist (steps.py)
    rejected           failures.py: the predicted pose; re-initialise after too many

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

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.deferred import stored
from mlsemreg_ros.core.features.deskew import MAX_DESKEW_WINDOW, SweepMotion
from mlsemreg_ros.core.labeling.source import LabelSource
from mlsemreg_ros.core.odometry import sensor_scale
from mlsemreg_ros.core.odometry.advance import accept_scan, start_keyframe
from mlsemreg_ros.core.odometry.deskew_guard import DeskewCheckSchedule
from mlsemreg_ros.core.odometry.failures import rejected
from mlsemreg_ros.core.odometry.global_registration import GlobalRegistration
from mlsemreg_ros.core.odometry.local_map import Keyframe, keyframe_refusal, LocalMap, make_map
from mlsemreg_ros.core.odometry.motion_model import make_motion_model, Prediction
from mlsemreg_ros.core.odometry.preprocess import PreprocessedScan, Preprocessor
from mlsemreg_ros.core.odometry.prior_model import motion_model_name
from mlsemreg_ros.core.odometry.reconfigure import reconfigure
from mlsemreg_ros.core.odometry.recovery import PastKeyframes
from mlsemreg_ros.core.odometry.review import review
from mlsemreg_ros.core.odometry.rotated_starts import Redeskew
from mlsemreg_ros.core.odometry.steps import Decision, OdometryStep, step_at_pose
from mlsemreg_ros.core.odometry.swept_dispute import judged_again
from mlsemreg_ros.core.odometry.tracking import Tracker
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.results import PreparedScan, RegistrationResult
import numpy as np


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
        reconfigure(self, config)  # core/odometry/reconfigure.py

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
            measured = sensor_scale.measure(points, self.config, labels is not None)
            if measured.points >= sensor_scale.MIN_POINTS:
                self.sensor_scale = measured
                self.tracker.trust.view.span_deg = 360.0 * measured.azimuth_share
                self.reconfigure(self.config)
        source = getattr(self.label_source, 'when_read', self.label_source)  # or a callable
        labelled = source(points, labels, self.config, intensity)  # None: no label field
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
        self.tracker.trust.view.since(self._last_accepted, stamp_ns)  # narrow_view.py
        given = (points, labels, point_times, stamp_ns)
        redeskew = Redeskew(self, given, raw)  # core/odometry/rotated_starts.py
        self.tracker.disputed = None  # core/odometry/swept_dispute.py
        chosen = self.tracker.estimate(
            raw.scan,
            prediction or self._still_start(stamp_ns),
            self.keyframe,
            self.global_registration,
            self.config,
            timings,
            redeskew,
        )
        disputed = (self.tracker.disputed, raw)  # a pose the near-miss check refused
        raw = redeskew.scan_of(chosen, raw)
        raw, chosen, prior_refusal, deskew_refusal = review(  # prior, deskew, relocalization
            self, given, prediction, raw, chosen, timings
        )
        raw, chosen = judged_again(*disputed, raw, chosen)  # core/odometry/swept_dispute.py
        step = self._apply(index, stamp_ns, raw, chosen)
        step.prior_refusal = prior_refusal
        step.deskew_refusal = deskew_refusal
        if step.accepted:
            self._failures = 0
        else:  # core/odometry/failures.py: its prediction; re-initialise after too many
            rejected(self, step, prediction, raw)
        registered = chosen.result.timings_ms if chosen.result is not None else {}
        step.timings_ms = {
            **_prepare_timings(raw.scan),
            **timings,
            **{f'register.{k}': v for k, v in registered.items()},
            **step.timings_ms,
        }
        return self._finish(step, start, raw)

    def _prediction(self, stamp_ns: int) -> Prediction | None:
        """Return the motion model's prediction at ``stamp_ns`` if the odometry uses one."""
        if self.keyframe is None or not self.config.odometry.constant_velocity:
            return None
        return self.motion_model.predict(stamp_ns)

    def _still_start(self, stamp_ns: int) -> Prediction | None:
        """
        Return the last accepted pose as a guess while no motion is known (``still_start``).

        Only for a scan close in time to that pose: a sweep or two later the scans overlap
        and the fine alignment's basin holds the motion (KISS-ICP starts so). None when off,
        without stamps or a pose, or when the scan is further in time.
        """
        limit = self.config.odometry.still_start
        last = self._last_accepted if self.keyframe is not None else None
        if limit <= 0.0 or last is None or not stamp_ns or not last[1]:
            return None
        if not 0 < stamp_ns - last[1] <= limit * 1e9:
            return None
        return Prediction(last[0].copy(), 1.0, still=True)

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
        start_keyframe(self, index, stamp_ns, raw, self.pose)  # core/odometry/advance.py
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
            step = accept_scan(self, index, stamp_ns, raw, chosen)  # core/odometry/advance.py
        step.candidates, step.timings_ms = chosen.candidates, chosen.timings_ms
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

    @staticmethod
    def _finish(
        step: OdometryStep, start: float, raw: PreprocessedScan | None = None
    ) -> OdometryStep:
        if raw is not None:
            step.deskewed = raw.deskewed
            if step.points is None:  # accept_scan set the scan it aligned (perhaps redone)
                step.points, step.labels = raw.points, stored(raw, 'labels')
            if raw.deskew_note:
                step.reason = '; '.join(r for r in (step.reason, raw.deskew_note) if r)
        step.latency_ms = 1e3 * (time.perf_counter() - start)
        return step


def _prepare_timings(scan: PreparedScan) -> dict[str, float]:
    """Return the scan's preparation stages (lazy ones once computed) as ``prepare.*``."""
    return {f'prepare.{k}': v for k, v in scan.timings_ms.items()}
