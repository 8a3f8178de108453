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
A full-ring scan accepted over a gap of seconds, deskewed again with the gap's velocity.

Without a gyro a scan is deskewed by the twist from an accepted pose
``preprocess.deskew_window`` scans back to the prediction (``core/features/deskew.py``). Over
a gap of seconds (a stride, a refusal) that twist spans a turn the car has since left, and
the prediction extrapolates it: on the HDL-64 field drive of seed 0 at stride 30, scan 60
(on the straight after a 90 deg turn) was deskewed at +29.8 deg/s and -5.3 m/s, backwards
(truth +0.7 deg/s and +10 m/s), from a prediction 13.9 m / 88 deg off. The sweep alignment
(``core/alignment/sweep_alignment.py``) holds the velocity within
``sweep_alignment.velocity_sigma`` of the deskew's and kept -4.3 m/s; each such sweep bent
the map the next one was aligned to, and scans 90 and 120 were accepted 57.5 and 53.4 cm off
(docs/confidence.md, session 22). Every scan deskewed by its true twist registers within
1 cm there.

So once such a scan is accepted, :func:`gap_deskew` deskews it again with the velocity from
the last accepted pose to the accepted one (the SE(3) log over the gap) and no rotation
rate, and aligns it again from the accepted pose; the sweep alignment then starts from that
twist, its rate free as before and its velocity held by
``sweep_alignment.gap_velocity_sigma`` (:func:`held_velocity`): along a street the velocity
is weakly observed, and a local map bent by an earlier sweep pulled it 3 m/s sideways. The
gap's rotation rate is not used: a gap that holds a turn says little about the rate within
the last sweep, which the sweep alignment measures. Only full rings (a narrow view's sweep
alignment is its own, ``core/odometry/narrow_view.py``), never with a gyro, never the first
pair (``Tracker.deskew_start`` deskews it by the pair's motion).
"""

from __future__ import annotations

from typing import Any, TYPE_CHECKING

from mlsemreg_ros.core.alignment.sweep_alignment import sweep_subset
from mlsemreg_ros.core.deferred import stored
from mlsemreg_ros.core.features.deskew import SweepMotion
from mlsemreg_ros.core.odometry.sweep_starts import bend_m, implied_twist
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.odometry.preprocess import PreprocessedScan, Preprocessor
    from mlsemreg_ros.core.odometry.tracking import Tracker

#: Raw points the note's bend is measured on (as ``retry_refused``).
BEND_POINTS = 1000


def gap_motion(motion_model: Any, pose: np.ndarray, stamp_ns: int, after_s: float) -> Any:
    """
    Return the gap's twist at ``pose`` (the velocity, no rotation rate), or None.

    None when ``after_s`` is 0 (off), or the motion model keeps no accepted pose, or the
    scan follows it by at most ``after_s`` seconds.
    """
    last = getattr(motion_model, 'last_accepted', None)
    if after_s <= 0.0 or last is None or stamp_ns - last[1] <= round(after_s * 1e9):
        return None
    implied = implied_twist(motion_model, pose, stamp_ns)
    if implied is None or not np.all(np.isfinite(implied.velocity)):
        return None
    return SweepMotion(np.zeros(3), np.asarray(implied.velocity, dtype=np.float64))


def gap_deskew(
    tracker: Tracker,
    raw: PreprocessedScan,
    pose: np.ndarray,
    stamp_ns: int,
    motion_model: Any,
    preprocessor: Preprocessor,
    cfg: RegistrationConfig,
) -> tuple[PreprocessedScan, np.ndarray, str, bool]:
    """
    Deskew an accepted scan again with its gap's velocity and align it again.

    Returns the scan, the pose, a note and whether the gap's twist was kept (the sweep
    alignment then holds its velocity, :func:`held_velocity`). The scan and pose are
    returned as they came when the rule does not apply (a narrow view, a gyro's or no
    deskew, a gap of at most ``sweep_alignment.gap_after``) or when the alignment again is
    not acceptable or moves the accepted pose beyond the correction bounds.
    """
    if (
        tracker.trust.view.partial
        or not isinstance(raw.motion, SweepMotion)  # a gyro's rotation: measured
        or raw.input_points is None
        or raw.point_times is None
    ):
        return raw, pose, '', False
    gap = gap_motion(motion_model, pose, stamp_ns, cfg.sweep_alignment.gap_after)
    if gap is None:
        return raw, pose, '', False
    again = preprocessor.scan(raw.input_points, stored(raw, 'labels'), raw.point_times, gap)
    if not again.deskewed:
        return raw, pose, '', False
    candidate = tracker.candidate('gap', pose, again.scan, cfg)
    refusal = candidate.refusal or tracker.trust.replacement_refusal(
        pose, candidate.alignment.T_target_source, cfg.odometry
    )
    sample, times = sweep_subset(
        raw.input_points, np.asarray(raw.point_times, dtype=np.float64), BEND_POINTS
    )
    bend = bend_m(sample, times, gap, raw.motion)
    gap_s = 1e-9 * (stamp_ns - motion_model.last_accepted[1])
    said = (
        f'the gap velocity ({gap_s:.1f} s: {np.linalg.norm(gap.velocity):.1f} m/s, '
        f'bend {bend:.2f} m)'
    )
    if refusal:
        return raw, pose, f'{said} not kept ({refusal})', False
    return again, candidate.alignment.T_target_source, f'deskewed again by {said}', True


def held_velocity(cfg: RegistrationConfig) -> RegistrationConfig:
    """Return ``cfg`` whose sweep alignment holds the velocity (``gap_velocity_sigma``)."""
    sigma = cfg.sweep_alignment.gap_velocity_sigma
    return cfg.replace({'sweep_alignment.velocity_sigma': sigma})
