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
A full ring's first pair searched along the platform's forward axis (issue 35, no labels).

Before any motion is known the first pair is registered globally only. Without labels a
spinning sensor's far first pair (0.5-1 s, 3-10 m) often keeps fewer than
``estimator.min_inliers`` sparse inliers: the simulated OS1-128 drive of seed 7 at stride 5
refused every pair of scans 0-55 but the last (RR 9.1 %, KISS-ICP 27.3 %); each refused scan
becomes the keyframe (``failures.no_motion_known``), so the next pair is a first pair again.

A car or a robot moves along the forward axis of its sensor (+x). So a full ring
(not ``View.partial``) refused with no motion known, further in time than
``odometry.still_start`` from the keyframe and from the scan before it (a sparse stream), is
matched onto the keyframe again from seeds along the keyframe's +x: every
``start_search.ALONG_STEP_M`` from the keyframe to ``start_search.MAX_SPEED`` times the time
since it, turned by ``seeded_search.SEED_YAWS_DEG``. It is the narrow view's search
(core/odometry/start_search.py) with the forward axis for the view axis and stage 9's bar
(``odometry.ring_search_overlap`` 0.97 on ``odometry.ring_search_checked`` 0.03, the
``covisibility.accept_*`` defaults), not the narrow view's 0.85 on 0.2: each seed is
re-matched, estimated and refined as the seeded search after a gap does, the evidence is
measured on the two scans deskewed by the best place's motion, and only the best place
itself is accepted (``seeded_search.search_seeds``: every distinct place and slide
``covisibility.accept_gap`` below, the best dense score, ``estimator.min_inliers`` sparse
inliers, the map inlier floor, no second basin).

Why 0.97: the best places of refused first pairs reached 0.81-0.95 and one of them, at 0.865,
was 0.63 m from the truth (OS1-128 seed 7, scans 0 -> 5); the right places accepted kept
0.974-0.994 (docs/sensors.md, session 20). Not further than ``odometry.ring_search_max_gap``
(1 s) from the keyframe: 3 s after it (25-30 m on a straight road) a place 0.8 m off kept
0.982, as the right places of other pairs (0.977-0.994). Not at stride 1 (the scan before
is 0.1 s away);
a narrow view never runs it; ``odometry.ring_search_overlap: 0`` or
``odometry.seeded_search: false`` turns it off.
"""

from __future__ import annotations

from typing import Any

from mlsemreg_ros.core.odometry.start_search import (
    first_pair_registration,
    search_from_keyframe,
    view_seeds,
)
from mlsemreg_ros.core.odometry.steps import Decision
import numpy as np

#: The platform's forward axis in the sensor frame: a car or a robot moves along +x.
FORWARD_AXIS = np.array([1.0, 0.0])
#: Stamps 10 scans apart at 10 Hz are 1.0 s apart give or take a jitter (s).
STAMP_TOLERANCE_S = 0.005


def forward_seeds(T_keyframe: np.ndarray, gap_s: float) -> list[np.ndarray]:
    """Return ``T_keyframe`` moved along its own +x (``start_search.view_seeds``) and turned."""
    return view_seeds(T_keyframe, FORWARD_AXIS, gap_s)


def search_along_forward(
    odometry: Any,
    stamp_ns: int,
    prediction: Any,
    raw: Any,
    chosen: Decision,
    timings: dict[str, float],
) -> Decision:
    """Return ``chosen``, or a place the search along the forward axis accepts."""
    cfg, view = odometry.config, odometry.tracker.trust.view
    if (
        view.partial
        or min(view.gap_s, view.scan_gap_s) <= max(cfg.odometry.still_start, 0.0)
        or view.gap_s > cfg.odometry.ring_search_max_gap + STAMP_TOLERANCE_S
    ):
        return chosen
    registration = first_pair_registration(
        odometry, prediction, chosen, cfg.odometry.ring_search_overlap
    )
    if registration is None:
        return chosen
    return search_from_keyframe(
        odometry,
        registration,
        raw,
        chosen,
        stamp_ns,
        FORWARD_AXIS,
        (cfg.odometry.ring_search_overlap, cfg.odometry.ring_search_checked),
        ('the search along the forward axis', 'ring_search_ms'),
        timings,
    )
