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
``preprocess.deskew_check_margin``, the deskew made the scan worse: the raw scan is
registered (tracked or globally, as any scan) and, if accepted, kept in place of the
deskewed one. The step says so (``deskew_refusal``, published in ``/diagnostics``).
A scan whose times are right aligns better deskewed, and nothing changes.
"""

from __future__ import annotations

from typing import Any


def deskew_refusal(deskewed: float | None, raw: float | None, margin: float) -> str:
    """
    Why the deskewed scan is worse than the raw one ('' if it is not).

    ``deskewed``, ``raw``: the shares of each scan's points that are map inliers after
    its alignment (None: not aligned).
    """
    if deskewed is None or raw is None or raw <= deskewed + margin:
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
    points, labels, _, _ = scan
    tracker = odometry.tracker
    plain = odometry.preprocessor.scan(points, labels, None, None)  # no times: not deskewed
    tracker.map.cloud(plain.scan)
    check = tracker.candidate('raw', chosen.pose, plain.scan, cfg)
    why = deskew_refusal(
        chosen.inlier_fraction, check.alignment.inlier_fraction, cfg.preprocess.deskew_check_margin
    )
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
