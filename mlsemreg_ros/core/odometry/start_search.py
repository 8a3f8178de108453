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
A narrow view's first pair searched along its view axis (issue 35: the solid state).

Before any motion is known the first pair is registered globally only. On the simulated
70 deg solid-state pattern with geometric labels that registration keeps 4-42 true
correspondences of about 3000 (FPFH on a sparse rosette; the field's labels give 260 of
2500, their landmarks making Mask Matching selective): seed 7 refused every first pair at
strides 5 and 10 until scan 35 and 50, seed 5 every one at stride 10 (docs/sensors.md,
session 19). A still start (``odometry.still_start``) covers a scan one sweep after the
keyframe; a scan 0.5-1 s after it is metres away, outside the map alignment's basin.

A car, a robot or a person carrying a forward-looking solid-state sensor moves along its
view. So a refused scan with no motion known, further in time from the keyframe than a
still start reaches, on a partial view (``View.partial``), is matched onto the keyframe
again from seeds along its view axis (the mean direction of its points in the horizontal
plane): every
:data:`ALONG_STEP_M` from the keyframe to :data:`MAX_SPEED` times the time since it,
turned by ``seeded_search.SEED_YAWS_DEG``. Each seed is re-matched, estimated and refined
as the seeded search after a gap does (guided re-matching within
``bev_search.guided_radius``, SC2-PCR, the map alignment), and the places are judged by
that search's evidence (``seeded_search.search_seeds``): the best covisible overlap with
the keyframe above every distinct place and slide by ``covisibility.accept_gap``, the
best dense score, ``estimator.min_inliers`` sparse inliers, the map inlier floor and no
second basin (``near_miss.*``). Three things differ:

- **The scans are deskewed by the best place's motion** before the evidence is measured
  (:func:`deskewed_pair`): neither was deskewed, and at 10 m/s the same surface lands up
  to 1 m apart in two rosette sweeps. The right places kept a covisible overlap of
  0.81-0.95 on the raw scans, 0.88-0.94 deskewed; the best place must still be the best
  one on the deskewed scans.
- **Its own bar**: ``odometry.view_search_overlap`` (0.85) on
  ``odometry.view_search_checked`` (0.2) of the surface, for stage 9's 0.97 on 0.03 (a far
  pair of spinning scans, deskewed or still). First pairs in a turn check 0.03-0.19 and
  their best places were up to 0.9 m off: the checked share keeps them out.
- **The best place only**, not a neighbour in its cluster (a seed refined 0.6 m away).

On 196 first pairs of five simulated solid-state drives at strides 5-20 the global
registration alone accepted 46, the search 47 more, all right (docs/sensors.md, session 19).
At stride 1 it runs on the third scan when the second was refused (0.2 s from the
keyframe; session 20): first kept to sparse streams (the scan before more than a still start
away), because on the 200-scan seed-7 drive it registered the third scan right just before
a 43 deg/s turn that the drive then lost for 30 scans (94.5 -> 82.9 %); with the turned
starts each judged on the scan deskewed by its own twist (``turn_starts.started``) that
turn is tracked (98.5 %). A full ring never runs it; ``odometry.view_search_overlap: 0``
or ``odometry.seeded_search: false`` turns it off.
"""

from __future__ import annotations

import time
from typing import Any

from mlsemreg_ros.core.deferred import stored
from mlsemreg_ros.core.features.deskew import sweep_motion, SweepMotion
from mlsemreg_ros.core.odometry.failures import no_motion_known
from mlsemreg_ros.core.odometry.seeded_search import (
    Place,
    search_seeds,
    searched,
    seed_grid,
    SEED_YAWS_DEG,
)
from mlsemreg_ros.core.odometry.steps import Decision
import numpy as np

#: Spacing of the seeds along the view axis (m): within ``bev_search.guided_radius`` (3 m)
#: of any place between two seeds, as the seeded search's ``SEED_ALONG_M``.
ALONG_STEP_M = 4.0
#: The fastest motion the seeds reach (m/s): a car in town (the simulated drives: 10 m/s).
MAX_SPEED = 15.0
#: Points nearer than this (xy, m) do not vote for the view axis.
MIN_AXIS_RANGE = 1.0


def view_axis(points: np.ndarray) -> np.ndarray | None:
    """Return the unit xy direction (2,) the scan's points lie in (None: no direction)."""
    xy = np.asarray(points, dtype=np.float64).reshape(-1, 3)[:, :2]
    ranges = np.linalg.norm(xy, axis=1)
    keep = np.isfinite(ranges) & (ranges > MIN_AXIS_RANGE)
    if not np.any(keep):
        return None
    mean = (xy[keep] / ranges[keep, None]).mean(axis=0)
    norm = float(np.linalg.norm(mean))
    return None if norm < 1e-6 else mean / norm


def along_offsets(gap_s: float) -> list[float]:
    """Return the seeds' distances along the view (m): 0 to ``MAX_SPEED x gap_s``, every step."""
    reach = MAX_SPEED * max(gap_s, 0.0)
    return [ALONG_STEP_M * k for k in range(int(np.ceil(reach / ALONG_STEP_M)) + 1)]


def view_seeds(T_origin: np.ndarray, axis: np.ndarray, gap_s: float) -> list[np.ndarray]:
    """Return ``T_origin`` moved along ``axis`` (its xy frame) and turned, as ``T_odom`` seeds."""
    return seed_grid(T_origin, SEED_YAWS_DEG, [along * axis for along in along_offsets(gap_s)])


def search_along_view(
    odometry: Any,
    stamp_ns: int,
    prediction: Any,
    raw: Any,
    chosen: Decision,
    timings: dict[str, float],
) -> Decision:
    """Return ``chosen``, or a place the search along the view accepts (module docstring)."""
    cfg, view = odometry.config, odometry.tracker.trust.view
    if not view.partial or view.gap_s <= max(cfg.odometry.still_start, 0.0):
        return chosen
    registration = first_pair_registration(
        odometry, prediction, chosen, cfg.odometry.view_search_overlap
    )
    if registration is None:
        return chosen
    axis = view_axis(raw.scan.points)
    if axis is None:
        return chosen
    return search_from_keyframe(
        odometry,
        registration,
        raw,
        chosen,
        stamp_ns,
        axis,
        (cfg.odometry.view_search_overlap, cfg.odometry.view_search_checked),
        ('the search along the view', 'view_search_ms'),
        timings,
    )


def first_pair_registration(
    odometry: Any, prediction: Any, chosen: Decision, overlap_bar: float
) -> Any | None:
    """
    Return the pair registration a refused first pair's seeded search runs, or None.

    None when there is nothing to search: the search is off (``odometry.seeded_search``,
    or ``overlap_bar`` 0), ``chosen`` was accepted, a prediction exists, the odometry has no
    fine alignment or keyframe, or a pair was accepted since the keyframe started. The
    conditions shared by the search along a narrow view (here) and along a full ring's
    forward axis (``ring_start_search.py``); each adds its view's own.
    """
    cfg = odometry.config
    if (
        not cfg.odometry.seeded_search
        or overlap_bar <= 0.0
        or chosen.accepted
        or prediction is not None
        or cfg.fine.method == 'off'
        or odometry.keyframe is None
        or not no_motion_known(odometry)
    ):
        return None
    return getattr(odometry.global_registration, 'registration', None)


def search_from_keyframe(
    odometry: Any,
    registration: Any,
    raw: Any,
    chosen: Decision,
    stamp_ns: int,
    axis: np.ndarray,
    bar: tuple[float, float],
    name: tuple[str, str],
    timings: dict[str, float],
) -> Decision:
    """
    Return ``chosen``, or the best place seeded along ``axis`` from the keyframe, if accepted.

    ``bar``: the covisible overlap and checked share it must reach on the deskewed pair;
    ``name``: the search's name in the notes and its key in ``timings``. Shared by the
    search along a narrow view (here) and along a full ring's forward axis
    (``ring_start_search.py``).
    """
    cfg, view = odometry.config, odometry.tracker.trust.view
    label, timing_key = name
    tic = time.perf_counter()
    try:
        place, refusal = search_seeds(
            odometry,
            registration,
            view_seeds(odometry.keyframe.pose, axis, view.gap_s),
            raw.scan,
            lambda place: deskewed_pair(odometry, registration, raw, place, stamp_ns),
            cfg.replace(
                {'covisibility.accept_overlap': bar[0], 'covisibility.accept_checked': bar[1]}
            ),
            best_only=True,
        )
    finally:
        timings[timing_key] = 1e3 * (time.perf_counter() - tic)
    return searched(
        chosen,
        place,
        refusal,
        (label.removeprefix('the '), label),
        cfg.odometry.covariance_scale,
    )


def deskewed_pair(
    odometry: Any, registration: Any, raw: Any, place: Place, stamp_ns: int
) -> tuple[Any, Any] | None:
    """
    Return the scan and the keyframe's scan deskewed by the motion ``place`` implies.

    Neither was deskewed (no motion known); at 10 m/s a sweep of 0.1 s moves the sensor
    1 m, and a rosette sees every part of its view at any time of the sweep, so the same
    surface lands up to 1 m apart in the two scans: the covisible overlap of the right
    place was 0.81-0.95 (``covisibility.accept_overlap`` 0.97). Deskewed by the constant
    twist from the keyframe to the place, as the start's deskew does once the pair is
    accepted (``Tracker.deskew_start``). None: no times, no stamps, or not the keyframe's
    start scan.
    """
    start, keyframe = odometry._start_scan, odometry.keyframe
    if start is None or keyframe is None or keyframe.stamp_ns != start[2]:
        return None
    first, first_pose, first_stamp = start
    twist = sweep_motion(
        first_pose, first_stamp, keyframe.pose @ place.T_keyframe_current, stamp_ns
    )
    preprocessor = odometry.preprocessor
    still = SweepMotion(np.zeros(3), np.zeros(3))
    if twist is None or any(
        preprocessor.refusal(s.points, s.point_times, still) for s in (first, raw)
    ):
        return None
    redone = []
    for scan in (raw, first):
        points = scan.input_points if scan.input_points is not None else scan.points
        again = preprocessor.scan(points, stored(scan, 'labels'), scan.point_times, twist)
        if not again.deskewed:
            return None
        redone.append(registration.complete(again.scan))
    return redone[0], redone[1]
