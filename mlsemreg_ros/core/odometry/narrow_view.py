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
A narrow view in a turn: what the map can still show, and starts turned with the car (issue 35).

A spinning sensor sees the whole ring whatever it turns; a 70 deg solid-state pattern
turned by ``theta`` since the last accepted scan shares at most ``1 - theta / span`` of its
view with it. Two consequences on a car's turn at stride 5 (0.5 s, 22 deg a step; the
simulated solid state, seed 1):

- **Overlap.** The relative-inlier rule (``odometry.min_relative_inlier_fraction`` times
  the median of the last accepted fractions) refused right poses that kept 0.34-0.35 of the
  scan, against 0.65 before the turn. :meth:`View.overlap` is the share of the view a pose's
  turn leaves; the turned starts' candidates (below) are judged with the usual fraction
  scaled by it. A full ring keeps 1. Everywhere else the rule is as it was: scaling it in
  every decision accepted a stride-1 scan refused before by 0.002 (right, 3.7 cm) and the
  200-scan seed-7 drive then went its own way to one scan fewer (94.5 -> 94.0 %).
- **Prediction.** The constant-velocity guess missed the turn's onset by 12 deg, outside the
  map alignment's basin; the global registration with geometric labels found 7 inliers,
  and every later scan was refused (the guess ran on without the turn). A turn may begin
  at any scan, and a turn rate may stop or double in one step: :func:`turn_bound` allows
  ``odometry.turn_rate`` times the time since the last accepted scan, or ``GAIN x`` the
  predicted turn since it, and ``turn_starts.turn_starts`` aligns the scan from the prediction
  turned about its vertical axis by the offsets within that bound
  (``rotated_starts.YAW_OFFSETS``). The start that keeps the most of the scan is taken only
  when no other passing start found a rival basin (as good by ``near_miss.rival_share``,
  elsewhere by ``rotated_starts.AGREEMENT``), its perturbed starts come back to it
  (``core/alignment/near_miss.py``), and, when its weakest direction is thinly held, the
  sweep alignment confirms it (``near_miss.weak_confirmation``), as a prediction rescued on
  its own evidence (``second_look.py``).

Only after a refused decision with a motion model's prediction (never a still start), and
only with ``near_miss.enabled`` and ``odometry.turn_rate`` above 0. A full ring takes the
same turned starts (session 19: a VLP-16 at 2 Hz entering a 90 deg turn without labels), with
an overlap of 1.

Session 19 (docs/sensors.md): the turned starts also take the places the refined
prediction's near-miss starts found that keep as much of the scan as tracking asks
(``turn_starts.held_basins``, within :func:`held_bound`); and a weakly held pose whose
sweep alignment needed no bend is confirmed by that alignment's own pose
(:func:`unbent_confirmation_refusal`). Session 20: the turned starts every 2.5 deg
(``turn_starts.FINE_STEP``), each also judged on the scan deskewed by its own twist
(``turn_starts.started``), within a bound that adds the prediction's own turn
(:func:`turn_bound`). All of these on a partial view only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mlsemreg_ros.core.odometry.sensor_scale import FULL_RING_SHARE
from mlsemreg_ros.core.rigid import rotation_angle_deg
import numpy as np

#: The turn bound is this many times the prediction's turn since the last accepted pose.
GAIN = 1.5
#: The widest turn bound (deg).
CAP_ROTATION = 30.0
#: The overlap factor never drops below this (a turn wider than the view: the rule stays).
MIN_OVERLAP = 0.3


@dataclass
class View:
    """The sensor's azimuth span and the last accepted pose: what a turn leaves in view."""

    span_deg: float = 360.0  # occupied azimuth (deg); 360: a full ring, or not measured
    last_pose: np.ndarray | None = None  # T_odom of the last accepted scan
    gap_s: float = 0.0  # time from the last accepted scan to the current one (s)
    scan_gap_s: float = 0.0  # time from the scan before, accepted or not (s; sparse_turn.py)
    previous_ns: int = 0  # stamp of the scan before (0: none seen)

    def since(self, last: tuple[np.ndarray, int] | None, stamp_ns: int) -> None:
        """Take the last accepted ``(pose, stamp)`` (None: none) and the current stamp."""
        self.last_pose = None if last is None else last[0]
        self.gap_s = (stamp_ns - last[1]) * 1e-9 if last is not None and stamp_ns else 0.0
        previous = self.previous_ns or (last[1] if last is not None else 0)
        self.scan_gap_s = (stamp_ns - previous) * 1e-9 if previous and stamp_ns else 0.0
        self.previous_ns = stamp_ns

    @property
    def partial(self) -> bool:
        """Whether the view is a partial one (a solid-state pattern)."""
        return self.span_deg < 360.0 * FULL_RING_SHARE

    def overlap(self, T_odom_current: np.ndarray) -> float:
        """Return the share of the view a pose at ``T_odom_current`` keeps (1: a full ring)."""
        if not self.partial or self.last_pose is None:
            return 1.0
        turn = rotation_angle_deg(np.linalg.solve(self.last_pose, T_odom_current))
        return view_overlap(turn, self.span_deg)


def view_overlap(turn_deg: float, span_deg: float) -> float:
    """Return ``1 - turn / span`` clipped to ``[MIN_OVERLAP, 1]`` (a full ring: 1)."""
    if span_deg >= 360.0 * FULL_RING_SHARE:
        return 1.0
    return float(np.clip(1.0 - abs(turn_deg) / max(span_deg, 1e-9), MIN_OVERLAP, 1.0))


def turn_bound(view: View, T_predicted: np.ndarray, floor_deg: float, turn_rate: float) -> float:
    """
    Return how far (deg) the prediction may be off in a turn.

    ``GAIN x`` its own turn since the last accepted pose (a turn rate may stop or double),
    and at least ``turn_rate`` (deg/s, ``odometry.turn_rate``) over the time since it (a
    turn may begin: a car's tight turn is 43 deg/s on the simulated drives), within
    ``[floor_deg, CAP_ROTATION]``. On a narrow view the turn that may begin adds to the
    prediction's own (it may stop and a turn the other way begin): the solid state's
    start at stride 1, its guess turning 0.4-0.8 deg a scan the wrong way, had its right
    turned starts refused 5.1 deg, 9.6 deg and 14.0 deg from it, against 5.0, 9.0 and 13.5
    (docs/sensors.md, session 20). A full ring keeps the larger of the two.
    """
    if view.last_pose is None:
        return floor_deg
    turn = rotation_angle_deg(np.linalg.solve(view.last_pose, T_predicted))
    begun = turn_rate * max(view.gap_s, 0.0) + (turn if view.partial else 0.0)
    wide = max(GAIN * turn, begun)
    return max(floor_deg, min(wide, CAP_ROTATION))


def held_bound(view: View, floor_deg: float, turn_rate: float) -> float:
    """
    Return how far (deg) a place held as tracked may lie from the prediction in a turn.

    The correction a fine alignment may make (``floor_deg``, the widened
    ``odometry.max_correction_rotation``) on top of a turn begun since the last accepted
    scan (``turn_rate`` times the time since it): at stride 1 a turn's onset put the
    prediction 3.9 deg off and the map's best place 5.2 deg from it (docs/sensors.md,
    session 19), within ``CAP_ROTATION``.
    """
    return max(floor_deg, min(floor_deg + turn_rate * max(view.gap_s, 0.0), CAP_ROTATION))


def unbent_confirmation_refusal(
    T_candidate: np.ndarray, T_unbent: np.ndarray | None, cfg: Any
) -> str:
    """
    Why a narrow view's unbent sweep alignment does not confirm a pose ('' if it does).

    A candidate whose weakest direction is thinly held awaits the sweep alignment's
    confirmation (``near_miss.weak_confirmation``, ``tracking.weak_confirmation_refusal``):
    the scan deskewed by the motion the pose implies, aligned with its sweep twist free, must
    keep a pose close to it. When that twist needs no change (it bends no point by more than
    ``sweep_alignment.min_change``), nothing is realigned and the pose was "not replaced";
    on a narrow view the joint estimate itself (``T_unbent``, None: the sweep alignment did
    not run or bent the scan) is then the confirmation, within
    ``near_miss.weak_confirmation`` of the candidate (docs/sensors.md, session 19).
    """
    if T_unbent is None:
        return 'not confirmed: the sweep alignment did not replace its pose'
    bound = cfg.near_miss.weak_confirmation
    moved = float(np.linalg.norm(np.linalg.solve(T_candidate, T_unbent)[:3, 3]))
    if moved > bound:
        return (
            f'not confirmed: the sweep alignment, needing no bend, moved it by {moved:.2f} m > '
            f'near_miss.weak_confirmation={bound:g} m'
        )
    return ''
