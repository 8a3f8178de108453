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
A narrow view turned far in one step of a sparse stream: the map inlier floor it can reach.

A 70 deg solid-state view turned by ``theta`` since the last accepted scan shares at most
``1 - theta / span`` of its view with the map (``narrow_view.View.overlap``). The turned
starts already expect the relative-inlier rule's fraction scaled by that share; the
absolute floor ``odometry.min_inlier_fraction`` (0.25) stayed. At stride 5 (0.5 s, 21.7 deg
a step in a car's turn; the simulated solid state, seed 1) the prediction of scan 8 was
0.08 m / 0.4 deg from the truth and its map alignment converged 0.03 m / 0.2 deg from it,
keeping 0.23 of the scan: refused by the floor alone, and with the map no longer fed
every later scan of the turn was lost (docs/sensors.md, session 20).

So the turned starts' candidates (``turn_starts.turn_starts``) on a partial view of a
sparse stream (the scan before more than :data:`SPARSE_GAP_S` away) are judged with the
floor scaled by the share of the view their turn leaves, never below :data:`MIN_SHARE` of
it. Everything else a turned start must pass stays: the correction and turn bounds, the
scaled relative rule, no rival basin, its perturbed starts coming back, a weakly held
direction confirmed by the sweep alignment. The sweep alignment of a scan a turned start
registered there is judged by the same floor (:func:`sweep_rules`): with the field's labels
the same scan 8 waited for its confirmation and the sweep alignment's pose, kept 0.23 of the
scan, was refused by the floor. At stride 1 (0.1 s) nothing changes.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import OdometryConfig, RegistrationConfig
    from mlsemreg_ros.core.odometry.motion_model import Prediction
    from mlsemreg_ros.core.odometry.narrow_view import View
    from mlsemreg_ros.core.odometry.steps import Decision
    import numpy as np

#: A stream is sparse when the scan before is further than this (s): stride 4 and up at 10 Hz.
SPARSE_GAP_S = 0.3
#: The floor never drops below this share of ``odometry.min_inlier_fraction``.
MIN_SHARE = 0.6
#: ... nor, for the sweep alignment of a scan a turned start registered, below this share
#: (:func:`sweep_rules`): on the seed-1 drive at stride 10 the right turned start of scan 4
#: (0.11 m / 0.8 deg, 43 deg since the scan before: 0.39 of the view left) awaited its
#: confirmation, and the sweep deskewed by its own twist kept 0.14 of the scan, under 0.6 x
#: 0.25 (docs/sensors.md, session 22).
SWEEP_MIN_SHARE = 0.5


def sparse_view(view: View) -> bool:
    """Whether ``view`` is a narrow view on a sparse stream (a gap over :data:`SPARSE_GAP_S`)."""
    return view.partial and view.scan_gap_s > SPARSE_GAP_S


def refused_moving(chosen: Decision, prediction: Prediction | None, view: View) -> bool:
    """
    Whether a sparse narrow view's scan was refused with a motion model's prediction.

    Not accepted, predicted by the motion model (not a still start) and :func:`sparse_view`:
    the scans the review steps of a sparse narrow view take again (``sparse_deskew.py``,
    ``map_search.py``).
    """
    return (
        not chosen.accepted
        and prediction is not None
        and not prediction.still
        and sparse_view(view)
    )


def turned_floor(
    view: View, odometry: OdometryConfig, overlap: float, min_share: float = MIN_SHARE
) -> OdometryConfig:
    """
    Return ``odometry`` with its inlier floor scaled by ``overlap`` on a sparse narrow view.

    ``overlap``: the share of the view the candidate's turn leaves
    (``narrow_view.View.overlap``), never below ``min_share``; a full ring, a dense stream
    or an overlap of 1 keep ``odometry`` as it is.
    """
    if not sparse_view(view) or overlap >= 1.0:
        return odometry
    share = max(float(overlap), min_share)
    return dataclasses.replace(odometry, min_inlier_fraction=odometry.min_inlier_fraction * share)


def sweep_rules(
    view: View, chosen: Decision, pose: np.ndarray, cfg: RegistrationConfig
) -> RegistrationConfig:
    """
    Return the configuration the sweep alignment of ``chosen`` at ``pose`` is judged by.

    A turned start (source ``turn``) on a sparse narrow view: ``cfg`` with the floor of
    :func:`turned_floor` (never below :data:`SWEEP_MIN_SHARE` of it: the sweep alignment
    confirms a pose every rule of a turned start already accepted, and a weakly held one
    moves by at most ``near_miss.weak_confirmation``) and the relative-inlier rule scaled by
    the view its turn leaves; any other decision: ``cfg`` itself.
    """
    if chosen.source != 'turn':
        return cfg
    overlap = view.overlap(pose)
    odometry = turned_floor(view, cfg.odometry, overlap, SWEEP_MIN_SHARE)
    if odometry is cfg.odometry:
        return cfg
    return cfg.replace(
        {
            'odometry.min_inlier_fraction': odometry.min_inlier_fraction,
            'odometry.min_relative_inlier_fraction': odometry.min_relative_inlier_fraction
            * overlap,
        }
    )
