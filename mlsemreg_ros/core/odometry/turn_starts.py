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
Starts turned with the car, for a scan refused in a turn (issue 35).

The rule and why: ``core/odometry/narrow_view.py``. First built for a narrow view, it also
serves a full ring: a car at 2 Hz (stride 5) entering a 90 deg turn is 11.8 deg off its
constant-velocity guess, outside the map alignment's basin. From the guess turned by 20 deg
the alignment lands 6 deg further, in the right basin (0.55 of the scan kept), and the
correction bound measured from that start refused it. A start is a guess a
:data:`START_SPACING` step away from the next one, so its own correction may reach that step;
the turn bound and the basin rules judge the move from the prediction.

Beside the turned starts, the places the
refined prediction's own near-miss check found (:func:`held_basins`): at the onset of a
turn at stride 1 the prediction is a few degrees off, too few for the turned starts, and
its refinement stops in a poorer basin than a start 0.6 m off finds (docs/sensors.md,
session 19).
"""

from __future__ import annotations

from collections.abc import Callable
import dataclasses
from typing import TYPE_CHECKING

from mlsemreg_ros.core.alignment.near_miss import alignment_fit
from mlsemreg_ros.core.odometry.motion_bound import prediction_error
from mlsemreg_ros.core.odometry.narrow_view import held_bound, turn_bound
from mlsemreg_ros.core.odometry.rotated_starts import (
    AGREEMENT,
    offsets_within,
    YAW_OFFSETS,
    yaw_rotated,
)
from mlsemreg_ros.core.odometry.second_look import basins, starts_back, weak_refusal
from mlsemreg_ros.core.odometry.sparse_turn import turned_floor
from mlsemreg_ros.core.odometry.steps import Decision
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.odometry.motion_model import Prediction
    from mlsemreg_ros.core.odometry.tracking import Tracker
    from mlsemreg_ros.core.odometry.trust import Candidate
    from mlsemreg_ros.core.results import PreparedScan

#: The step (deg) between two neighbouring starts (``rotated_starts.YAW_OFFSETS``): how far a
#: start's own refinement may turn it.
START_SPACING = 10.0


def turn_starts(
    tracker: Tracker,
    chosen: Decision,
    prediction: Prediction | None,
    scan: PreparedScan,
    cfg: RegistrationConfig,
    redeskew: Callable[[np.ndarray], PreparedScan | None] | None = None,
) -> Decision:
    """
    Return ``chosen`` (refused), or a start turned with the car accepted on its evidence.

    The candidates: the refined prediction (it was refused), and the prediction turned by
    each offset within :func:`~mlsemreg_ros.core.odometry.narrow_view.turn_bound`, refined;
    each judged by the odometry's rules with the relative-inlier rule expecting the share of
    the view its turn leaves (``narrow_view.View.overlap``). ``redeskew(T)``: the scan
    deskewed by the twist ``T`` implies (``rotated_starts.Redeskew``); the best candidate is
    refined once more on it, and kept on it when still acceptable.
    """
    view = tracker.trust.view
    if (
        chosen.accepted
        or prediction is None
        or prediction.still
        or not cfg.near_miss.enabled
        or cfg.odometry.turn_rate <= 0.0
    ):
        return chosen
    T_predicted = prediction.T_odom_current
    odometry = cfg.odometry
    bound = turn_bound(view, T_predicted, odometry.max_correction_rotation, odometry.turn_rate)
    from_start = dataclasses.replace(
        odometry, max_correction_rotation=max(odometry.max_correction_rotation, START_SPACING)
    )

    def judged(name: str, T_start: np.ndarray, on: PreparedScan) -> Candidate:
        """``on`` refined from ``T_start``, judged with the overlap its turn leaves in view."""
        alignment = tracker.map.align_scan(on, T_start)
        overlap = view.overlap(alignment.T_target_source)
        rules = turned_floor(view, from_start, overlap)  # sparse_turn.py
        return tracker.trust.judge(name, T_start, alignment, rules, overlap)

    refined = [c for c in chosen.candidates if c.name == 'prediction' and not c.still]
    passing: list[Candidate] = []
    if refined:  # the refined prediction again, expecting what its turn leaves in view
        again = refined[0]
        alignment = again.alignment
        overlap = view.overlap(alignment.T_target_source)
        rules = turned_floor(view, odometry, overlap)  # sparse_turn.py
        again = tracker.trust.judge('turn', again.T_initial, alignment, rules, overlap)
        if again.acceptable:
            passing.append(again)
        if view.partial:  # measured on narrow views only (session 19)
            passing += held_basins(tracker, refined[0], T_predicted, scan, cfg)
    deskewed_by: dict[int, np.ndarray] = {}  # id(candidate): the start its scan is deskewed by
    for offset in turn_offsets(bound, fine=view.partial):
        T_start = yaw_rotated(T_predicted, offset)
        for candidate, T_deskew in started(judged, T_start, scan, view.partial, redeskew):
            _, turn = prediction_error(T_predicted, candidate.alignment.T_target_source)
            if candidate.acceptable and turn <= bound:
                passing.append(candidate)
                if T_deskew is not None:
                    deskewed_by[id(candidate)] = T_deskew
    if not passing:
        return chosen
    best = max(passing, key=lambda c: c.alignment.inlier_fraction)
    own = deskewed_by.get(id(best))
    if own is not None and redeskew is not None:  # the scan the best start was judged on
        scan = redeskew(own) or scan
    share, residual = alignment_fit(best.alignment)
    rival_share = cfg.near_miss.rival_share
    for other in passing:
        shift, turn = prediction_error(
            best.alignment.T_target_source, other.alignment.T_target_source
        )
        other_share, other_residual = alignment_fit(other.alignment)
        if (shift > AGREEMENT[0] or turn > AGREEMENT[1]) and (
            other_share >= rival_share * share and other_residual * rival_share <= residual
        ):  # near_miss.py's rival: another basin about as good
            return _noted(
                chosen,
                f'turned starts: two basins {shift:.2f} m / {turn:.1f} deg apart '
                f'(inlier shares {share:.2f} and {other_share:.2f})',
            )
    redone = redeskew(best.alignment.T_target_source) if redeskew is not None else None
    if redone is not None:  # deskewed by the prediction's twist, as wrong as its turn
        tracker.map.cloud(redone)
        again = judged('rotated', best.alignment.T_target_source, redone)
        _, turn = prediction_error(T_predicted, again.alignment.T_target_source)
        # a start judged on its own deskewed scan keeps it unless the refined pose's twist
        # keeps more: over 0.5 s into a turn that twist (the mean since the last accepted
        # scan) is slower than the turn, and refused a pose its start's twist held
        kept = own is None or again.alignment.inlier_fraction >= best.alignment.inlier_fraction
        if again.acceptable and turn <= bound and kept:  # 'rotated': the odometry takes it
            best, scan = again, redone
        elif own is not None:  # back to the scan the best start was judged on
            scan = redeskew(own) or scan
    verdict = basins(tracker, best, scan, cfg)
    alignment = best.alignment
    back = starts_back(alignment, verdict, cfg)
    if verdict.refusal or not back:
        return _noted(chosen, f'turned start disputed ({verdict.refusal or "a start left"})')
    weak = weak_refusal(alignment, cfg)
    if weak and cfg.near_miss.weak_confirmation <= 0:
        return _noted(chosen, f'turned start not accepted: {weak}')
    _, turned = prediction_error(T_predicted, alignment.T_target_source)
    note = (
        f'turned start accepted ({turned:.1f} deg from the prediction, within '
        f'{bound:.1f} deg; {back} perturbed starts came back to it)'
    )
    if weak:
        note = f'{note}, if the sweep alignment confirms it ({weak})'
    return Decision.of_alignment(
        'turn',
        '; '.join(r for r in (chosen.reason, note) if r),
        alignment,
        cfg.odometry.covariance_scale,
        result=chosen.result,
        candidates=[best, *chosen.candidates],
        timings_ms=chosen.timings_ms,
        confirm_weak=bool(weak),
    )


def started(
    judged: Callable[[str, np.ndarray, PreparedScan], Candidate],
    T_start: np.ndarray,
    scan: PreparedScan,
    partial: bool,
    redeskew: Callable[[np.ndarray], PreparedScan | None] | None,
) -> list[tuple[Candidate, np.ndarray | None]]:
    """
    Return a turned start refined on ``scan`` and, on a narrow view, on the scan it deskews.

    Each candidate comes with the start its scan was deskewed by (None: ``scan`` itself).
    ``scan`` was deskewed by the prediction's twist, as wrong as its turn: a rosette sees
    every part of its view throughout the sweep, so at a turn's onset each surface is
    smeared by the turn the prediction missed. On the 200-scan seed-7 drive at stride 1 the
    right starts kept 0.32-0.39 of the scan, 0.15-1.3 m from the truth, and 0.42-0.63,
    0.06-0.4 m from it, on the scan deskewed by their own twist (docs/sensors.md, session 20).
    A candidate on the redone scan is named ``'rotated'``: the odometry takes that scan.
    """
    out: list[tuple[Candidate, np.ndarray | None]] = [(judged('turn', T_start, scan), None)]
    if partial and redeskew is not None:
        redone = redeskew(T_start)
        if redone is not None:
            out.append((judged('rotated', T_start, redone), T_start))
    return out


#: The turned starts' step on a narrow view (deg): a turn's onset at stride 1 leaves the
#: guess 3-13 deg off, where a start 5 deg from the truth already lands in another basin
#: (docs/sensors.md, session 20; session 19 tried 5 deg, then the coarse offsets).
FINE_STEP = 2.5


def turn_offsets(bound: float, fine: bool = True) -> list[float]:
    """
    Return the turned starts' yaw offsets strictly within ``bound`` (deg), finest first.

    ``fine`` (a narrow view): every :data:`FINE_STEP` up to the widest of
    ``rotated_starts.YAW_OFFSETS``; otherwise (a full ring) those offsets.
    """
    if not fine:
        return offsets_within(bound)
    reach = max(abs(o) for o in YAW_OFFSETS)
    steps = range(1, round(reach / FINE_STEP) + 1)
    grid = [sign * FINE_STEP * k for k in steps for sign in (1.0, -1.0)]
    return [o for o in grid if abs(o) < bound]


def held_basins(
    tracker: Tracker,
    refined: Candidate,
    T_predicted: np.ndarray,
    scan: PreparedScan,
    cfg: RegistrationConfig,
) -> list[Candidate]:
    """
    Return the other places the refined prediction's near-miss starts found, held as tracked.

    The refined prediction is aligned again from the near-miss check's perturbed starts
    (``second_look.basins``); a start that converged elsewhere (beyond
    ``near_miss.agreement_translation``) and keeps at least
    ``odometry.tracking_min_inlier_fraction`` of the scan, as much as a scan tracked alone
    must and more than the refined prediction kept, is a candidate when it passes the
    odometry's rules (with the overlap its turn leaves in view) and lies within
    :func:`~mlsemreg_ros.core.odometry.narrow_view.held_bound` of the prediction.
    :func:`turn_starts` then takes it only as it takes a turned start: the best of the
    passing candidates, no rival basin among them, its own perturbed starts coming back.
    """
    odometry = cfg.odometry
    if not refined.acceptable or refined.alignment.inlier_fraction >= (
        odometry.tracking_min_inlier_fraction
    ):
        return []  # refused outright, or the prediction's place is held as well as tracked
    home, view = refined.alignment.T_target_source, tracker.trust.view
    bounds = tracker.trust.motion_bound.widen(odometry)
    rotation = held_bound(view, bounds.max_correction_rotation, odometry.turn_rate)
    out = []
    for basin in basins(tracker, refined, scan, cfg).others:
        alignment = basin.alignment
        if alignment is None or alignment.inlier_fraction < odometry.tracking_min_inlier_fraction:
            continue
        shift = np.linalg.norm(np.linalg.solve(home, alignment.T_target_source)[:3, 3])
        if shift <= cfg.near_miss.agreement_translation:
            continue  # came back home
        moved, turn = prediction_error(T_predicted, alignment.T_target_source)
        if moved > bounds.max_correction_translation or turn > rotation:
            continue
        overlap = view.overlap(alignment.T_target_source)
        candidate = tracker.trust.judge('turn', alignment.T_initial, alignment, odometry, overlap)
        if candidate.acceptable:
            out.append(candidate)
    return out


def _noted(chosen: Decision, note: str) -> Decision:
    chosen.reason = '; '.join(r for r in (chosen.reason, note) if r)
    return chosen
