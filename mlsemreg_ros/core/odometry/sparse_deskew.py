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
A narrow view refused on a sparse stream: estimated again deskewed by its translation alone.

Without a gyro a scan is deskewed by the twist of the last accepted poses
(``preprocess.py``). On a sparse stream (the scan before more than
``sparse_turn.SPARSE_GAP_S`` away) that twist is a mean over 0.5 s or more, and a turn may
have stopped since: a rosette sees every part of its 70 deg view at any time of its sweep,
so a wrong rate smears every surface. On the simulated solid state (seed 1, stride 5) the
car's turn ended between scans 8 and 9 (yaw steps 21.7, 13.4, 0.7 deg); scan 9 was
deskewed by 43.4 deg/s for a true 0.1 deg/s, and its map alignment ended 0.50 m / 1.2 deg
off the truth even from the truth, keeping 0.19 of the scan. Deskewed by the same twist's
translation alone it ended 0.07 m / 0.2 deg off keeping 0.29, by the true twist 0.04 m /
0.1 deg keeping 0.29; not deskewed, 0.18 m / 0.4 deg (docs/sensors.md, session 21).

So such a scan, refused with a motion model's prediction, is prepared again deskewed by
that translation (the rotation set to zero) and estimated again under every rule of a
first estimate (``Tracker.estimate``). When that is refused, the turned starts
(``turn_starts.turn_starts``) run once more on it expecting :data:`RELATIVE_SHARE` of the
relative-inlier rule's fraction; every other check of a turned start stays (the turn
bound, no rival basin, the perturbed starts coming back, a weak direction confirmed by the
sweep alignment). The scan keeps a twist, so the sweep alignment of the accepted scan
estimates the sweep's own rotation. A full ring, a dense stream, a still start, a deskew
from a gyro or wheel prior: nothing changes.
"""

from __future__ import annotations

import time
from typing import Any, TYPE_CHECKING

from mlsemreg_ros.core.features.deskew import SweepMotion
from mlsemreg_ros.core.odometry.prior_guard import prior_used
from mlsemreg_ros.core.odometry.sparse_turn import refused_moving
from mlsemreg_ros.core.odometry.turn_starts import turn_starts
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.odometry.motion_model import Prediction
    from mlsemreg_ros.core.odometry.odometry import Odometry
    from mlsemreg_ros.core.odometry.preprocess import PreprocessedScan
    from mlsemreg_ros.core.odometry.steps import Decision

#: The turned starts on the scan deskewed by its translation alone expect this share of the
#: relative-inlier rule's fraction: the sweep's own turn is unknown there (the rate changed),
#: and the right pose keeps a little less than on a scan deskewed by the sweep's true twist.
RELATIVE_SHARE = 0.9


def retry_turn_stopped(
    odometry: Odometry,
    scan: tuple[Any, Any, Any, int],
    prediction: Prediction | None,
    raw: PreprocessedScan,
    chosen: Decision,
    timings: dict[str, float],
) -> tuple[PreprocessedScan, Decision]:
    """
    Register a refused narrow-view scan of a sparse stream again, without the turn.

    ``scan``: ``(points, labels, point_times, stamp_ns)`` as the odometry got it; ``raw``
    and ``chosen``: its preprocessed scan and decision. Returns the scan and decision to
    apply: the scan deskewed by the translation alone and its decision when that was
    accepted, else ``raw`` and ``chosen``.
    """
    view = odometry.tracker.trust.view
    if (
        not refused_moving(chosen, prediction, view)
        or not raw.deskewed
        or not isinstance(raw.motion, SweepMotion)
        or prior_used(odometry.sweep_state()[2], raw.motion)
    ):
        return raw, chosen
    points, labels, point_times, _ = scan
    tic = time.perf_counter()
    turn_stopped = SweepMotion(np.zeros(3), np.asarray(raw.motion.velocity, dtype=np.float64))
    plain = odometry.preprocessor.scan(points, labels, point_times, turn_stopped)
    tracker = odometry.tracker
    tracker.map.cloud(plain.scan)
    other = tracker.estimate(
        plain.scan,
        prediction,
        odometry.keyframe,
        odometry.global_registration,
        odometry.config,
        timings,
    )
    if not other.accepted:  # the turned starts once more, expecting a little less
        other = turn_starts(tracker, other, prediction, plain.scan, _relaxed(odometry.config))
    timings['turn_stopped_ms'] = 1e3 * (time.perf_counter() - tic)
    if not other.accepted:
        return raw, chosen
    note = 'deskewed again by its translation alone: the turn may have stopped'
    other.reason = '; '.join(r for r in (other.reason, note) if r)
    return plain, other


def _relaxed(cfg: RegistrationConfig) -> RegistrationConfig:
    """Return ``cfg`` with the relative-inlier rule's share times :data:`RELATIVE_SHARE`."""
    share = cfg.odometry.min_relative_inlier_fraction * RELATIVE_SHARE
    return cfg.replace({'odometry.min_relative_inlier_fraction': share})
