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
A deskew that bends the scan is not used for that scan (``docs/hostile_input.md``).

A per-point time field can be plausible in every value and still not give the points'
capture times: a float field of microseconds, a uint8 counter, a driver that already
motion-compensated its points. Deskewing by such times bends the scan (each ring moved by
up to the distance driven in one sweep), and the registration of the bent scan can be
accepted 0.5 to 0.7 m off (two poses of the dev-pair fuzz, ``mlsemreg fuzz-node``).

So after a deskewed scan is accepted (``preprocess.deskew_check``), the scan as it came is
aligned to the local map too, from the accepted pose (one fine alignment). When the raw
scan keeps a larger share of its points as map inliers than the deskewed one, by more than
``preprocess.deskew_check_margin`` of it, the deskew made the scan worse: the raw scan is
registered (tracked or globally, as any scan) and, if accepted, kept in place of the
deskewed one. The step says so (``deskew_refusal``, published in ``/diagnostics``).
A scan whose times are right aligns better deskewed, and nothing changes.

The check runs when the prediction or the deskew came from prior messages (IMU, wheel
odometry: ``prior_guard.prior_used``), or with ``sweep_alignment.mode: off``. Without a
prior, a scan deskewed by the twist of the last poses is left to the sweep alignment, which
estimates the sweep's own twist and deskews again with it: on the field drive without a
prior, replacing such scans by their raw points in turns (where the twist of the last poses
is wrong and the raw scan kept more inliers) doubled the ATE at stride 1 (0.066 m against
0.037 m, ``mlsemreg eval-bag`` on ``simulate --realism field --frames 80 --seed 0``).

The check costs a preparation and an alignment of the raw scan: on every scan of a field drive
with an IMU at stride 1 it took 47 % of the odometry's CPU time. A time field is the driver's:
one that gives the capture times does so on every scan. So :class:`DeskewCheckSchedule` checks
every scan until :data:`FIRST_CHECKS` checks in a row kept the deskew, then every
``preprocess.deskew_check_interval``-th deskewed scan, and every scan again after a reset,
after a check that refused the deskew, or when the time field's span moves by more than
:data:`SPAN_CHANGE`. A periodic check rides on the next scan that was registered globally
(within another interval): that scan is among the slowest anyway, so the checks add no slow
scans of their own to the latency's 95th percentile.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mlsemreg_ros.core.odometry.prior_guard import prior_used
import numpy as np

#: A time field whose span (s) moved by more than this share since the last check is checked.
SPAN_CHANGE = 0.2
#: Checks in a row that must keep the deskew before only every interval-th scan is checked.
FIRST_CHECKS = 3


@dataclass
class DeskewCheckSchedule:
    """Which accepted deskewed scans the deskew check runs on (``deskew_check_interval``)."""

    kept_in_a_row: int = 0  # checks in a row that kept the deskew
    unchecked: int = 0  # deskewed scans passed over since the last check
    span: float | None = None  # the time field's span (s) at the last check

    def reset(self) -> None:
        """Check every scan again (an odometry reset)."""
        self.kept_in_a_row, self.unchecked, self.span = 0, 0, None

    def due(self, point_times: Any, interval: int, slow: bool = True) -> bool:
        """
        Whether the scan with these per-point times (s) is checked; counts it if not.

        ``slow``: the scan was registered globally, so it is among the slowest already.
        A check due by the interval waits for such a scan, for at most another interval:
        with ``odometry.global_interval`` below ``interval`` one comes first, and the
        periodic checks add no slow scan of their own to the latency's tail.
        """
        span = time_span(point_times)
        moved = (
            self.span is None
            or span is None
            or abs(span - self.span) > SPAN_CHANGE * max(self.span, 1e-3)
        )
        if interval <= 1 or self.kept_in_a_row < FIRST_CHECKS or moved:
            return True
        if self.unchecked + 1 >= interval and (slow or self.unchecked + 1 >= 2 * interval):
            return True
        self.unchecked += 1
        return False

    def checked(self, point_times: Any, kept: bool) -> None:
        """Record a check of a scan with these times: it kept the deskew or refused it."""
        self.kept_in_a_row = self.kept_in_a_row + 1 if kept else 0
        self.unchecked, self.span = 0, time_span(point_times)


def time_span(point_times: Any) -> float | None:
    """Return the span (s) of the finite per-point times (None without any)."""
    if point_times is None:
        return None
    times = np.asarray(point_times, dtype=np.float64)
    times = times[np.isfinite(times)]
    return float(times.max() - times.min()) if times.size else None


def deskew_refusal(deskewed: float | None, raw: float | None, margin: float) -> str:
    """
    Why the deskewed scan is worse than the raw one ('' if it is not).

    ``deskewed``, ``raw``: the shares of each scan's points that are map inliers after
    its alignment (None: not aligned). ``margin``: how much larger the raw share must be,
    relative to the deskewed one (``preprocess.deskew_check_margin``).
    """
    if deskewed is None or raw is None or raw <= deskewed * (1.0 + margin):
        return ''
    return (
        f'the raw scan aligns better: {raw:.3f} of its points are map inliers, '
        f'{deskewed:.3f} deskewed'
    )


def guard_deskew(
    odometry: Any,
    scan: tuple[Any, Any, Any, int],
    prediction: Any,
    raw: Any,
    chosen: Any,
    timings: dict[str, float],
) -> tuple[Any, Any, str]:
    """
    Check an accepted deskewed scan against the raw one; register it raw if that is better.

    ``scan``: ``(points, labels, point_times, stamp_ns)`` as the odometry got it; ``raw``
    and ``chosen``: its preprocessed scan and decision. Returns the scan and decision to
    apply and the step's ``deskew_refusal`` ('' when the deskew is kept).
    """
    cfg = odometry.config
    if not (cfg.preprocess.deskew_check and raw.deskewed and chosen.accepted):
        return raw, chosen, ''
    if not prior_used(odometry.sweep_state()[2], raw.motion) and cfg.sweep_alignment.mode != 'off':
        return raw, chosen, ''  # the poses' twist: the sweep alignment checks it (docs/field.md)
    points, labels, point_times, _ = scan
    schedule = odometry.deskew_checks
    slow = chosen.result is not None  # registered globally: a slow scan already
    if not schedule.due(point_times, cfg.preprocess.deskew_check_interval, slow):
        return raw, chosen, ''
    tracker = odometry.tracker
    # no motion: not deskewed; the times kept for the sweep alignment of an accepted scan
    plain = odometry.preprocessor.scan(points, labels, point_times, None)
    tracker.map.cloud(plain.scan)
    check = tracker.candidate('raw', chosen.pose, plain.scan, cfg)
    why = deskew_refusal(
        chosen.inlier_fraction, check.alignment.inlier_fraction, cfg.preprocess.deskew_check_margin
    )
    schedule.checked(point_times, kept=not why)
    if not why:
        return raw, chosen, ''
    tracked = tracker.trust.tracked_in_a_row
    if chosen.source == 'prediction':
        tracker.trust.tracked_in_a_row -= 1  # one scan, tracked at most once
    other = tracker.estimate(
        plain.scan, prediction, odometry.keyframe, odometry.global_registration, cfg, timings
    )
    if not other.accepted:
        tracker.trust.tracked_in_a_row = tracked
        return raw, chosen, f'kept (the raw scan was not accepted): {why}'
    other.reason = '; '.join(r for r in (other.reason, f'deskew not used: {why}') if r)
    return plain, other, f'not used: {why}'
