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

DRAFT: measured in docs/sensors.md, session 20.
"""

from __future__ import annotations

from dataclasses import replace
import time
from typing import Any

from mlsemreg_ros.core.odometry.failures import no_motion_known
from mlsemreg_ros.core.odometry.seeded_search import search_seeds
from mlsemreg_ros.core.odometry.start_search import deskewed_pair, view_seeds
from mlsemreg_ros.core.odometry.steps import Decision
import numpy as np

#: The platform's forward axis in the sensor frame: a car or a robot moves along +x.
FORWARD_AXIS = np.array([1.0, 0.0])


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
        not cfg.odometry.seeded_search
        or cfg.odometry.ring_search_overlap <= 0.0
        or chosen.accepted
        or prediction is not None
        or view.partial
        or min(view.gap_s, view.scan_gap_s) <= max(cfg.odometry.still_start, 0.0)
        or cfg.fine.method == 'off'
        or odometry.keyframe is None
        or not no_motion_known(odometry)
    ):
        return chosen
    registration = getattr(odometry.global_registration, 'registration', None)
    if registration is None:
        return chosen
    tic = time.perf_counter()
    try:
        seeds = view_seeds(odometry.keyframe.pose, FORWARD_AXIS, view.gap_s)
        place, refusal = search_seeds(
            odometry,
            registration,
            seeds,
            raw.scan,
            lambda place: deskewed_pair(odometry, registration, raw, place, stamp_ns),
            cfg.replace(
                {
                    'covisibility.accept_overlap': cfg.odometry.ring_search_overlap,
                    'covisibility.accept_checked': cfg.odometry.ring_search_checked,
                }
            ),
            best_only=True,
        )
    finally:
        timings['ring_search_ms'] = 1e3 * (time.perf_counter() - tic)
    if place is None:
        note = f'search along the forward axis: {refusal}'
        return replace(chosen, reason='; '.join(r for r in (chosen.reason, note) if r))
    note = (
        f'accepted by the search along the forward axis (covisible overlap '
        f'{place.overlap:.3f} of {place.checked:.2f} checked; {refusal})'
    )
    return chosen.rescued(place.candidate, note, cfg.odometry.covariance_scale)
