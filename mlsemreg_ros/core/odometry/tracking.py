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
The odometry's alignment against its local map, in one room.

Every alignment of a scan to the map goes through :class:`Tracker`, and every verdict on
one comes from :class:`~mlsemreg_ros.core.odometry.trust.Trust`:

    estimate        the motion model's prediction refined against the map; tracked when
                    it is trusted, else the global registration and the decision
                    between its refined estimate and the refined prediction
    deskew_start    the first two scans deskewed once their motion is known, aligned again
    align_sweep     no gyro: the sweep's own twist estimated against the map's Gaussians
                    (core/alignment/sweep_alignment.py); a scan it bends is deskewed with it
                    and aligned again

The map (``core/odometry/local_map.py``) owns its clouds and Gaussians.
"""

from __future__ import annotations

from collections.abc import Callable
import copy
import dataclasses
import functools
import time
from typing import Any, TYPE_CHECKING

from mlsemreg_ros.core.alignment.sweep_alignment import MapGaussians, sweep_subset
from mlsemreg_ros.core.deferred import stored
from mlsemreg_ros.core.features.deskew import sweep_motion, SweepMotion
from mlsemreg_ros.core.odometry.decision import chain, decide
from mlsemreg_ros.core.odometry.gap_twist import gap_deskew, held_velocity
from mlsemreg_ros.core.odometry.global_registration import GlobalEstimate
from mlsemreg_ros.core.odometry.local_map import Keyframe, LocalMap
from mlsemreg_ros.core.odometry.motion_model import Prediction
from mlsemreg_ros.core.odometry.narrow_view import unbent_confirmation_refusal
from mlsemreg_ros.core.odometry.preprocess import PreprocessedScan, Preprocessor
from mlsemreg_ros.core.odometry.rotated_starts import (
    best_rotated_start,
    offsets_within,
    rotated,
    worth_rotating,
)
from mlsemreg_ros.core.odometry.second_look import second_look
from mlsemreg_ros.core.odometry.sparse_turn import sweep_rules
from mlsemreg_ros.core.odometry.start_twist import (
    disputed_motion,
    no_rotation_pose,
    start_twist_verdict,
)
from mlsemreg_ros.core.odometry.steps import Decision
from mlsemreg_ros.core.odometry.sweep_ahead import SweepAhead, SweepInputs
from mlsemreg_ros.core.odometry.sweep_starts import align_from_starts, implied_twist
from mlsemreg_ros.core.odometry.swept_dispute import swept_refusal
from mlsemreg_ros.core.odometry.trust import Candidate, InlierHistory, Trust
from mlsemreg_ros.core.odometry.turn_starts import turn_starts
from mlsemreg_ros.core.results import PreparedScan
from mlsemreg_ros.core.rigid import rotation_angle_deg
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig

#: Rounds of deskew and alignment of the scan after a start (the motion follows the pose).
START_DESKEW_ROUNDS = 3
#: ... until the alignment moves the pose by less than this (m).
START_DESKEW_TOLERANCE = 0.01
#: The sweep alignment needs a local map of at least this many voxels.
MIN_SWEEP_MAP_VOXELS = 100


def weak_confirmation_refusal(
    T_candidate: np.ndarray, T_swept: np.ndarray, kept: bool, cfg: RegistrationConfig
) -> str:
    """
    Why the sweep alignment does not confirm a candidate with a weak direction ('' if it does).

    ``T_swept``: the pose after the start's deskew and the sweep alignment; ``kept``: the
    sweep alignment replaced the pose (it bent the scan and the map accepted the result).
    A pose that a few skewed points decide moves when the sweep is deskewed by its own
    twist, or its realignment is not kept (``near_miss.weak_confirmation``).
    """
    bound = cfg.near_miss.weak_confirmation
    moved = float(np.linalg.norm(np.linalg.solve(T_candidate, T_swept)[:3, 3]))
    if not kept:
        return 'not confirmed: the sweep alignment did not replace its pose'
    if moved > bound:
        return (
            f'not confirmed: the sweep alignment moved it by {moved:.2f} m > '
            f'near_miss.weak_confirmation={bound:g} m'
        )
    return ''


def steady(chosen: Decision, cfg: RegistrationConfig) -> bool:
    """
    Whether a tracked scan's motion model held (``sweep_alignment.steady_*``).

    Tracked by its motion model's prediction alone (``Decision.held``), which the fine
    alignment moved by less than ``sweep_alignment.steady_correction`` and
    ``steady_rotation``: the sweep's motion is the one it was deskewed with, and the sweep
    alignment is not run (docs/sensors.md, session 17).
    """
    if not chosen.held or len(chosen.candidates) != 1:
        return False
    return steady_correction(chosen.candidates[0].alignment.correction, cfg)


def steady_correction(moved: np.ndarray, cfg: RegistrationConfig) -> bool:
    """Whether a correction of the prediction is within ``sweep_alignment.steady_*`` (on)."""
    bound = cfg.sweep_alignment.steady_correction
    if bound <= 0:
        return False
    return bool(
        np.linalg.norm(moved[:3, 3]) < bound
        and rotation_angle_deg(moved) < cfg.sweep_alignment.steady_rotation
    )


class Tracker:
    """Aligns scans to ``map``, judged by ``trust``: tracking, global candidates, the sweep."""

    def __init__(self, local_map: LocalMap, trust: Trust | None = None) -> None:
        """Track against ``local_map`` (the odometry's ``map``)."""
        self.map = local_map
        self.trust = trust if trust is not None else Trust()
        self._gaussians: tuple[tuple[np.ndarray, np.ndarray], MapGaussians] | None = None
        #: the first pair's pose with its first scan deskewed without a rotation rate
        self.start_other: np.ndarray | None = None
        #: the motion (6,) between the first pair's two twists' poses, in the pose's axes,
        #: when its covariance is to be inflated along it (core/odometry/start_twist.py)
        self.start_dispute: np.ndarray | None = None
        #: this scan's pose refused by the near-miss check, to judge again once its sweep
        #: is deskewed again if nothing else accepts the scan (core/odometry/swept_dispute.py)
        self.disputed: Decision | None = None
        #: the pose of the last sweep alignment that needed no bend (None: none or bent)
        self.unbent_pose: np.ndarray | None = None
        #: the sweep alignment of a tracked pose, started beside its rules (sweep_ahead.py)
        self.ahead = SweepAhead()

    def map_gaussians(self) -> MapGaussians | None:
        """
        Return the local map's Gaussians and their cells for the sweep alignment (None: empty).

        Kept while the map returns the same arrays (it did not change): a scan refused or
        aligned again does not sort the same means into cells twice.
        """
        gaussians = self.map.gaussians()
        if gaussians is None:
            return None
        if self._gaussians is None or self._gaussians[0] is not gaussians:
            self._gaussians = (gaussians, MapGaussians(*gaussians))
        return self._gaussians[1]

    def prefetch_gaussians(self, raw: PreprocessedScan, cfg: RegistrationConfig) -> bool:
        """
        Start reading the map's Gaussians and their cells for the next scan's sweep alignment.

        Called once this scan is in the map and its step is made: the copy and the sort run on
        a second thread beside what follows instead of in the next scan's steps
        (:meth:`LocalMap.prefetch`; the same arrays as a read on demand, so the same poses).
        Only where the next scan will ask: the sweep alignment is on and this scan was
        deskewed by a twist (a partial view aligns the sweep on every tracked scan), on a
        ``vgicp`` map large enough. Returns whether it started (never with ``threads: 1``).
        """
        sweep = cfg.sweep_alignment
        if (
            sweep.mode == 'off'
            or cfg.fine.method != 'vgicp'
            or not isinstance(raw.motion, SweepMotion)
            or len(self.map) < MIN_SWEEP_MAP_VOXELS
        ):
            return False
        cell = sweep.max_distance

        def sort(gaussians: tuple[np.ndarray, np.ndarray] | None) -> None:
            if gaussians is None:
                return
            prepared = MapGaussians(*gaussians)
            prepared.cells(cell)
            self._gaussians = (gaussians, prepared)

        return self.map.prefetch(sort)

    @property
    def history(self) -> InlierHistory:
        """Return the inlier fractions of the last accepted frames (``trust.history``)."""
        return self.trust.history

    @property
    def tracked_in_a_row(self) -> int:
        """Return the scans accepted by the refined prediction alone, in a row."""
        return self.trust.tracked_in_a_row

    def restart(self) -> None:
        """Forget the history (a new map)."""
        self.trust.restart()

    def candidate(
        self, name: str, T_initial: np.ndarray, scan: PreparedScan, cfg: RegistrationConfig
    ) -> Candidate:
        """Refine ``T_initial`` of ``scan`` against the map and judge the result."""
        alignment = self.map.align_scan(scan, T_initial)
        return self.trust.judge(name, T_initial, alignment, cfg.odometry)

    def estimate(
        self,
        current: PreparedScan,
        prediction: Prediction | None,
        keyframe: Keyframe,
        register: Callable[[PreparedScan, Keyframe], GlobalEstimate],
        cfg: RegistrationConfig,
        timings: dict[str, float],
        redeskew: Callable[[np.ndarray], PreparedScan | None] | None = None,
    ) -> Decision:
        """
        Track the prediction, or register globally and decide (``core/odometry/decision.py``).

        ``register(current, keyframe)``: the global registration. With ``fine.method: off``
        the pose is the chain of global registrations. ``redeskew(T)``: the scan deskewed
        by the twist a pose ``T`` implies (the caller keeps it; None: not possible), for the
        yaw-rotated starts (``core/odometry/rotated_starts.py``).
        """
        if cfg.fine.method == 'off':
            return chain(register(current, keyframe), cfg)
        known = None if prediction is None or prediction.still else prediction
        self.trust.motion_bound.predicted(  # a still start is no motion model's error
            None if known is None else known.T_odom_current,
            None if known is None else known.sigmas,
        )
        ahead = None
        if redeskew is not None and prediction is not None:  # core/odometry/sweep_ahead.py
            ahead = functools.partial(
                self.start_sweep_ahead, prediction=prediction, redeskew=redeskew, cfg=cfg
            )
        predicted = self.refine_prediction(current, prediction, cfg, timings, ahead)
        gap = prediction.stamp_gap if prediction is not None else 1.0
        why_global = self.trust.tracking_refusal(predicted, gap, cfg.odometry)
        if not why_global:  # tracking: no global registration needed
            tracked = self.track(predicted, cfg)
            tracked.held = prediction is not None and not prediction.still
            return tracked
        rotated = self.rotated_start(current, prediction, cfg, timings, redeskew)
        if rotated is not None:  # core/odometry/rotated_starts.py
            decision = self.track(rotated, cfg)
            decision.reason = f'{decision.reason}; from a yaw-rotated start ({why_global})'
            if predicted is not None:  # the correction from the prediction (covariance)
                decision.candidates.append(predicted)
            return decision
        estimate = register(current, keyframe)
        self.trust.tracked_in_a_row = 0
        chosen = decide(
            estimate,
            predicted,
            lambda T: self.candidate('global', T, current, cfg),
            cfg,
            full_ring=not self.trust.view.partial,
        )
        chosen = second_look(self, chosen, estimate, current, cfg)  # near misses, rescue
        tic = time.perf_counter()
        chosen = turn_starts(self, chosen, prediction, current, cfg, redeskew)  # turn_starts.py
        timings['turn_starts_ms'] = 1e3 * (time.perf_counter() - tic)
        chosen.reason = '; '.join(
            r for r in (f'registered globally: {why_global}', chosen.reason) if r
        )
        return chosen

    def rotated_start(
        self,
        scan: PreparedScan,
        prediction: Prediction | None,
        cfg: RegistrationConfig,
        timings: dict[str, float],
        redeskew: Callable[[np.ndarray], PreparedScan | None] | None = None,
    ) -> Candidate | None:
        """Return a yaw-rotated start of the prediction to track, or None (``rotated_starts``)."""
        if prediction is None or not worth_rotating(
            self.trust.tracked_in_a_row, prediction.stamp_gap, cfg.odometry
        ):
            return None
        odometry = self.trust.motion_bound.widen(cfg.odometry)
        if not offsets_within(odometry.max_correction_rotation):
            return None  # a car's tight bound: no rotated start
        tic = time.perf_counter()
        chosen = best_rotated_start(
            prediction.T_odom_current,
            odometry.max_correction_rotation,
            lambda T: rotated(self.candidate('prediction', T, scan, cfg)),
            lambda c: self.trust.tracking_refusal(c, prediction.stamp_gap, cfg.odometry),
            None if redeskew is None else lambda T: self.redeskewed(T, redeskew, cfg),
        )
        timings['rotated_starts_ms'] = 1e3 * (time.perf_counter() - tic)
        return chosen

    def redeskewed(
        self,
        T: np.ndarray,
        redeskew: Callable[[np.ndarray], PreparedScan | None],
        cfg: RegistrationConfig,
    ) -> Candidate | None:
        """Refine ``T`` of the scan deskewed by the twist ``T`` implies (None: not deskewed)."""
        scan = redeskew(T)
        if scan is None:
            return None
        self.map.cloud(scan)
        return rotated(self.candidate('prediction', T, scan, cfg))

    def refine_prediction(
        self,
        scan: PreparedScan,
        prediction: Prediction | None,
        cfg: RegistrationConfig,
        timings: dict[str, float],
        ahead: Callable[[Any], Any] | None = None,
    ) -> Candidate | None:
        """
        Refine the motion model's prediction against the map (None without one).

        ``ahead(alignment)``: called with the refined alignment before the rules judge it
        (:meth:`start_sweep_ahead`).
        """
        if prediction is None:
            return None
        tic = time.perf_counter()
        self.map.cloud(scan)  # all cores: small_gicp has the GIL
        timings['fine_cloud_ms'] = 1e3 * (time.perf_counter() - tic)
        tic = time.perf_counter()
        alignment = self.map.align_scan(scan, prediction.T_odom_current)  # self.candidate
        if ahead is not None:
            ahead(alignment)
        candidate = self.trust.judge(
            'prediction', prediction.T_odom_current, alignment, cfg.odometry
        )
        timings['fine_prediction_ms'] = 1e3 * (time.perf_counter() - tic)
        return dataclasses.replace(candidate, still=True) if prediction.still else candidate

    def start_sweep_ahead(
        self,
        alignment: Any,
        prediction: Prediction,
        redeskew: Any,
        cfg: RegistrationConfig,
    ) -> bool:
        """
        Start the sweep alignment of the refined prediction beside its rules (sweep_ahead.py).

        ``alignment``: the prediction refined against the map; ``redeskew``: the odometry's
        :class:`~mlsemreg_ros.core.odometry.rotated_starts.Redeskew` of the scan in process
        (its scan as preprocessed, the odometry, the stamp). The inputs :meth:`align_sweep`
        will have if the scan is tracked: the scan, this pose, the twist it implies. Not
        where the scan would be steady (:func:`steady`) or the sweep is not aligned.
        Returns whether it started.
        """
        held = not prediction.still
        if held and steady_correction(alignment.correction, cfg):
            return False
        pose = alignment.T_target_source
        if not np.all(np.isfinite(pose)):
            return False
        odometry, raw = redeskew.odometry, redeskew.raw
        inputs = self.sweep_inputs(raw, odometry.preprocessor, cfg)
        if inputs is None:
            return False
        gaussians, points, times = inputs
        implied = implied_twist(odometry.motion_model, pose, redeskew.given[3])
        motion, config = raw.motion, cfg.sweep_alignment
        return self.ahead.start(
            SweepInputs(raw, gaussians, pose, implied, config),
            lambda T: align_from_starts(points, times, gaussians, T, motion, implied, config),
        )

    def track(self, predicted: Candidate, cfg: RegistrationConfig) -> Decision:
        """Accept the scan by its refined prediction (no global registration)."""
        self.trust.tracked_in_a_row += 1
        return Decision.of_alignment(
            'prediction',
            f'tracked ({self.trust.tracked_in_a_row} in a row)',
            predicted.alignment,
            cfg.odometry.covariance_scale,
            candidates=[predicted],
        )

    def align_accepted(
        self,
        chosen: Decision,
        raw: PreprocessedScan,
        start: tuple[PreprocessedScan, np.ndarray, int] | None,
        stamp_ns: int,
        keyframe: Keyframe,
        preprocessor: Preprocessor,
        motion_model: Any,
        cfg: RegistrationConfig,
    ) -> tuple[PreprocessedScan, np.ndarray | None, SweepMotion | None]:
        """
        Record an accepted alignment, then the start's deskew and the sweep alignment.

        A scan the sweep alignment deskewed again is aligned once more from its new pose and
        twist (the first pass starts from a twist that may be far off, with a prior about it,
        and stops short): on the handheld VLP-16 walk at stride 3 a global pose 0.95 m off
        went to 0.51 m after one pass and 0.21 m after two; the first pair of the HDL-64
        field drive (seed 0) at stride 20 went 0.86 -> 0.70 m (wrong) -> 0.57 m
        (docs/sensors.md, session 15).

        Returns the scan and pose to accept, and the sweep twist estimated (or None);
        ``chosen`` gets the sweep alignment's time and note. A decision that awaits the
        sweep alignment's confirmation (``Decision.confirm_weak``, second_look.py) and does
        not get it (:func:`weak_confirmation_refusal`), or a disputed one whose basins are
        still disputed on the scan deskewed again (``Decision.swept_dispute``,
        core/odometry/swept_dispute.py), returns the pose None: the map, the keyframe and the
        history are as they were, and ``chosen.reason`` says why.
        """
        history = copy.deepcopy(self.trust.history) if start is not None else None
        judged_again = chosen.confirm_weak or bool(chosen.swept_dispute)
        before = (copy.deepcopy(self.trust.history), raw) if judged_again else None
        unaligned = raw
        self.trust.accepted(chosen.inlier_fraction)
        self.start_other, self.start_dispute = None, None
        raw, pose = self.deskew_start(
            start, raw, chosen.pose, stamp_ns, keyframe, preprocessor, motion_model, cfg
        )
        said, refuse = start_twist_verdict(pose, self.start_other, cfg)  # start_twist.py
        chosen.reason = '; '.join(r for r in (chosen.reason, said) if r)
        if refuse and history is not None:
            self.trust.history = history
            self.undo_start(start, keyframe)
            return unaligned, None, None
        if said.startswith('covariance inflated') and self.start_other is not None:
            self.start_dispute = disputed_motion(pose, self.start_other)
        held = False
        if start is None:  # over a gap of seconds: its velocity (gap_twist.py)
            raw, pose, said, held = gap_deskew(
                self, raw, pose, stamp_ns, motion_model, preprocessor, cfg
            )
            chosen.reason = '; '.join(r for r in (chosen.reason, said) if r)
        tic = time.perf_counter()
        deskewed = raw
        note, sweep_twist = '', None
        self.unbent_pose = None
        if not steady(chosen, cfg):
            implied = implied_twist(motion_model, pose, stamp_ns)  # sweep_starts.py
            rules = sweep_rules(self.trust.view, chosen, pose, cfg)  # sparse_turn.py
            if held:  # the gap's velocity held, its one start (gap_twist.py)
                rules, implied = held_velocity(rules), None
            redone, moved, note, sweep_twist, chosen.sweep_change_m = self.align_sweep(
                raw, pose, preprocessor, rules, implied
            )
            if redone is not raw:  # deskewed again: aligned once more from there
                chosen.sweep_bend_m = chosen.sweep_change_m
                again = self.align_sweep(redone, moved, preprocessor, rules)
                if again[0] is not redone:
                    redone, moved, sweep_twist = again[0], again[1], again[3]
                    note = f'{note}; again: {again[2]}'
                    chosen.sweep_bend_m += again[4]
            raw, pose = redone, moved
        chosen.timings_ms['sweep_alignment_ms'] = 1e3 * (time.perf_counter() - tic)
        if note:
            chosen.reason = '; '.join(r for r in (chosen.reason, note) if r)
        if before is not None:
            if chosen.swept_dispute:  # core/odometry/swept_dispute.py
                refusal = swept_refusal(self, pose, raw.scan, raw is not unaligned, cfg)
                kept = 'one basin after the sweep was deskewed again'
            else:
                refusal = weak_confirmation_refusal(chosen.pose, pose, raw is not deskewed, cfg)
                kept = 'confirmed by the sweep alignment'
                if refusal and self.trust.view.partial and raw is deskewed:  # narrow_view.py
                    refusal = unbent_confirmation_refusal(chosen.pose, self.unbent_pose, cfg)
                    kept = 'confirmed by the sweep alignment, which needed no bend'
            chosen.reason = '; '.join(r for r in (chosen.reason, refusal or kept) if r)
            if refusal:
                self.trust.history = before[0]
                self.undo_start(start, keyframe)
                return before[1], None, None
        self.trust.motion_bound.accepted(pose)  # the prediction's error (motion_bound.py)
        return raw, pose, sweep_twist

    def undo_start(
        self, start: tuple[PreprocessedScan, np.ndarray, int] | None, keyframe: Keyframe
    ) -> None:
        """Put the map and keyframe back on the start's scan as it was (undo deskew_start)."""
        if start is None:
            return  # deskew_start changed nothing
        first, first_pose, first_stamp = start
        self.map.clear()
        self.map.insert_scan(first.scan, first_pose)
        if keyframe.stamp_ns == first_stamp:
            keyframe.points, keyframe.labels, keyframe.prepared = (
                first.points,
                stored(first, 'labels'),
                first.scan,
            )

    def deskew_start(
        self,
        start: tuple[PreprocessedScan, np.ndarray, int] | None,
        raw: PreprocessedScan,
        pose: np.ndarray,
        stamp_ns: int,
        keyframe: Keyframe,
        preprocessor: Preprocessor,
        motion_model: Any,
        cfg: RegistrationConfig,
    ) -> tuple[PreprocessedScan, np.ndarray]:
        """
        Deskew the scan the odometry started on and the next one, once their motion is known.

        ``start``: the scan the odometry started on, its pose and stamp (None: done).

        Neither had a prediction, so neither was deskewed (or only by the gyro's rotation).
        A map of skewed scans would bias every deskewed scan aligned to it (and, through the
        velocity, the next deskew), and the next one's pose was registered on two skewed
        sweeps. So both are deskewed with the motion estimated between them (the gyro's
        rotation when there is an IMU), prepared again, and the next one is aligned again
        to the first, :data:`START_DESKEW_ROUNDS` times at most (the motion follows the
        pose). Returns the scan and pose to accept; the map holds the first scan
        (``docs/field.md``).
        """
        if start is None or (raw.deskewed and not raw.rotation_only):
            return raw, pose
        first, first_pose, first_stamp = start
        refusal = preprocessor.refusal
        still = SweepMotion(np.zeros(3), np.zeros(3))
        if refusal(first.points, first.point_times, still) or refusal(
            raw.points, raw.point_times, still
        ):
            return raw, pose  # no times (the clean world), deskew off: nothing to redo
        redone, current, gyro = (first, raw), pose, False
        for _ in range(START_DESKEW_ROUNDS):
            twist = sweep_motion(first_pose, first_stamp, current, stamp_ns)
            if twist is None:
                break
            attempt = []
            for scan, stamp in ((first, first_stamp), (raw, stamp_ns)):
                measured = preprocessor.gyro_motion(
                    motion_model, stamp, scan.point_times, twist.velocity
                )
                gyro = gyro or measured is not None
                motion = measured or twist
                points = scan.input_points if scan.input_points is not None else scan.points
                labels = stored(scan, 'labels')
                attempt.append(preprocessor.scan(points, labels, scan.point_times, motion))
            if not all(r.deskewed for r in attempt):
                break
            redone = tuple(attempt)
            self.map.clear()
            self.map.insert_scan(redone[0].scan, first_pose)
            again = self.candidate('start', current, redone[1].scan, cfg)
            if not again.acceptable:
                break
            moved = again.alignment.correction
            current = again.alignment.T_target_source
            if np.linalg.norm(moved[:3, 3]) < START_DESKEW_TOLERANCE:
                break
        if redone[0] is first:
            return raw, pose
        if not gyro and cfg.near_miss.start_twist_spread > 0.0:  # start_twist.py
            self.start_other = no_rotation_pose(
                self, start, redone[1], pose, current, stamp_ns, preprocessor
            )
        if self.map.empty or redone[1] is raw:
            self.map.clear()
            self.map.insert_scan(redone[0].scan, first_pose)
        if keyframe.stamp_ns == first_stamp:
            r = redone[0]
            keyframe.points, keyframe.prepared = r.points, r.scan
            keyframe.labels = stored(r, 'labels')
        return redone[1], current

    def align_sweep(
        self,
        raw: PreprocessedScan,
        pose: np.ndarray,
        preprocessor: Preprocessor,
        cfg: RegistrationConfig,
        implied: SweepMotion | None = None,
    ) -> tuple[PreprocessedScan, np.ndarray, str, SweepMotion | None, float]:
        """
        Estimate the motion within the sweep from the sweep itself (no gyro), if it bends it.

        ``implied``: the twist from the last accepted pose to ``pose``, a second start when
        it bends the sweep differently from the deskew's (``core/odometry/sweep_starts.py``).

        A scan deskewed by a constant twist from the poses is aligned to the local map with
        its sweep twist free (``core/alignment/sweep_alignment.py``). When the estimated
        twist moves some point by more than ``sweep_alignment.min_change``, the scan is
        deskewed with it, prepared again and aligned again from the joint estimate; the
        result replaces the pose if the map accepts it. Returns the scan, the pose, a note,
        the estimated sweep twist (None when there is none to keep) and its bend (m: the
        largest point move of that twist against the deskew's, whether kept or not; 0 when
        none was estimated), which the covariance reads (``Decision.sweep_bend_m``).
        """
        motion = raw.motion
        inputs = self.sweep_inputs(raw, preprocessor, cfg)
        if inputs is None:
            return raw, pose, '', None, 0.0
        gaussians, points, times = inputs
        result = self.ahead.take(SweepInputs(raw, gaussians, pose, implied, cfg.sweep_alignment))
        if result is None:  # not started ahead for these inputs (sweep_ahead.py)
            result = align_from_starts(
                points, times, gaussians, pose, motion, implied, cfg.sweep_alignment
            )
        finite = np.all(np.isfinite(result.T_target_source)) and np.all(
            np.isfinite(np.concatenate([result.motion.omega, result.motion.velocity]))
        )
        if not finite or not np.isfinite(result.change_m):
            return raw, pose, 'sweep alignment diverged: the deskew twist is kept', None, 0.0
        if result.change_m <= cfg.sweep_alignment.min_change:
            self.unbent_pose = result.T_target_source  # narrow_view.unbent_confirmation_refusal
            return raw, pose, '', result.motion, result.change_m
        labels = stored(raw, 'labels')
        redone = preprocessor.scan(raw.input_points, labels, raw.point_times, result.motion)
        if not redone.deskewed:
            return raw, pose, '', None, result.change_m
        again = self.candidate('sweep', result.T_target_source, redone.scan, cfg)
        refusal = again.refusal or self.trust.replacement_refusal(
            pose, again.alignment.T_target_source, cfg.odometry
        )
        if refusal:
            note = f'{result.summary(motion)}: not kept ({refusal})'
            return raw, pose, note, None, result.change_m
        kept = (redone, again.alignment.T_target_source, result.summary(motion), result.motion)
        return (*kept, result.change_m)

    def sweep_inputs(
        self, raw: PreprocessedScan, preprocessor: Preprocessor, cfg: RegistrationConfig
    ) -> tuple[MapGaussians, np.ndarray, np.ndarray] | None:
        """
        Return what the sweep alignment of ``raw`` reads: the map's Gaussians, points, times.

        None when it does not run: off, no fine alignment, a scan not deskewed by a twist
        (points and times), an empty map or one of fewer than :data:`MIN_SWEEP_MAP_VOXELS`.
        The points: the moving objects out, ``sweep_alignment.points`` of them.
        """
        if (
            cfg.sweep_alignment.mode == 'off'
            or cfg.fine.method == 'off'
            or not isinstance(raw.motion, SweepMotion)  # deskewed by a twist: points and times
            or self.map.empty
        ):
            return None
        gaussians = self.map_gaussians()
        if gaussians is None or len(gaussians) < MIN_SWEEP_MAP_VOXELS:
            return None
        points, times = raw.input_points, np.asarray(raw.point_times, dtype=np.float64)
        if cfg.moving_objects.matching != 'drop':  # 'drop' took them out before the deskew
            moving = preprocessor.moving_mask(points, stored(raw, 'labels'))
            if moving is not None and len(moving) == len(points):
                points, times = points[~moving], times[~moving]
        points, times = sweep_subset(points, times, cfg.sweep_alignment.points)
        return gaussians, points, times
