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
Rejections in a row: relocalize, then re-initialise; the prediction a rejected scan reports.

At the ``keyframe.max_failures``-th rejection in a row the scan is relocalized onto the
past keyframes (recovery.py), and only if that fails does the odometry re-initialise on
the scan at the last accepted pose (a jump it flags by the covariance). While no pair
has been accepted since the keyframe started (no motion known), the first rejection of a
scan ``keyframe.restart_gap`` or more after the keyframe re-initialises at once: the
refused, newer scan becomes the keyframe.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from mlsemreg_ros.core.odometry.advance import start_keyframe
from mlsemreg_ros.core.odometry.motion_model import Prediction
from mlsemreg_ros.core.odometry.preprocess import PreprocessedScan
from mlsemreg_ros.core.odometry.steps import (
    Decision,
    OdometryStep,
    prediction_covariance,
    REINITIALIZATION_VARIANCE,
)
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.odometry.odometry import Odometry


def relocalize(
    odometry: Odometry, raw: PreprocessedScan, chosen: Decision, timings: dict[str, float]
) -> Decision:
    """
    Relocalize onto the past keyframes at the ``keyframe.max_failures``-th rejection in a row.

    The scan is registered onto the keyframes the odometry left behind and refined
    against the local map (``core/odometry/recovery.py``); the decision stays rejected
    (and :func:`rejected` re-initialises) when none gives a trusted pose.
    """
    limit = odometry.config.keyframe.max_failures
    if chosen.pose is not None or not limit or odometry._failures + 1 < limit:
        return chosen
    if odometry.config.fine.method == 'off':
        return chosen
    found, said = odometry.past_keyframes.relocalize(
        raw.scan, odometry.tracker, odometry.global_registration, odometry.config, timings
    )
    if found is None:
        chosen.reason = f'{chosen.reason}; relocalization failed ({said})'
        return chosen
    found.reason = f'{limit} frames rejected in a row ({chosen.reason}): {found.reason}'
    found.timings_ms = {**chosen.timings_ms, **found.timings_ms}
    return found


def rejected(
    odometry: Odometry, step: OdometryStep, prediction: Prediction | None, raw: PreprocessedScan
) -> None:
    """Put its predicted pose on a rejected scan, then count the failure (re-initialise?)."""
    predict_rejected(odometry, step, prediction)
    count_failure(odometry, step, raw)


def predict_rejected(
    odometry: Odometry, step: OdometryStep, prediction: Prediction | None
) -> None:
    """Put the motion model's pose at a rejected scan's stamp, with its covariance, on it."""
    if prediction is None and odometry.keyframe is not None:  # constant_velocity off
        prediction = odometry.motion_model.predict(step.stamp_ns)
    if prediction is None or odometry._last_accepted is None:
        return
    step.predicted_pose = prediction.T_odom_current.copy()
    step.predicted_covariance = prediction_covariance(
        odometry.covariance,
        odometry._last_accepted[0],
        prediction.T_odom_current,
        odometry._last_frame_covariance,
        prediction.stamp_gap,
    )


def count_failure(odometry: Odometry, step: OdometryStep, raw: PreprocessedScan) -> None:
    """After ``keyframe.max_failures`` rejections in a row, re-initialise on this scan."""
    if step.accepted:
        odometry._failures = 0
        return
    odometry._failures += 1
    limit = odometry.config.keyframe.max_failures
    first = no_motion_known(odometry) and long_after_keyframe(odometry, step.stamp_ns)
    if first and limit:  # waiting keeps every later scan facing an ever older keyframe
        limit = 1
    if not limit or odometry._failures < limit or odometry.keyframe_refusal(raw.scan):
        return
    start_keyframe(odometry, step.index, step.stamp_ns, raw, odometry.pose)
    odometry.covariance = odometry.covariance + np.eye(6) * REINITIALIZATION_VARIANCE
    step.covariance = odometry.covariance.copy()  # the jump is flagged
    step.new_keyframe, step.source = True, 'reinitialized'
    step.keyframe_index, step.map_voxels = step.index, len(odometry.map)
    if first:
        step.reason += (
            '; no pair accepted since the keyframe (no motion known): re-initialised on '
            'this scan, the newer keyframe, at the last accepted pose'
        )
        return
    step.reason += (
        f'; {limit} frames rejected in a row: re-initialised on this scan at '
        'the last accepted pose (the motion since is unknown)'
    )


def long_after_keyframe(odometry: Odometry, stamp_ns: int) -> bool:
    """
    Whether a scan at ``stamp_ns`` is ``keyframe.restart_gap`` or more after the keyframe.

    True for unstamped scans (a stamp of 0) and a gap of 0. A scan refused shortly after the
    keyframe leaves the next one near it too: at stride 1 the solid-state drive's second scan
    was refused and its third registered onto the first; restarting on each refused scan
    made every pair a first pair, registered globally, and RR fell from 97 % to 0 %.
    """
    gap_s = odometry.config.keyframe.restart_gap
    keyframe = odometry.keyframe
    if gap_s <= 0.0 or keyframe is None or not stamp_ns or not keyframe.stamp_ns:
        return True
    return 1e-9 * (stamp_ns - keyframe.stamp_ns) >= gap_s


def no_motion_known(odometry: Odometry) -> bool:
    """
    Whether no pair was accepted since the keyframe started (issue 29 item 2).

    Then there is no prediction to carry a refused scan's successors, no map beyond the
    keyframe and no past keyframe to relocalize onto: each later scan would face the
    keyframe from ever farther away (a VLP-16 drive at stride 20 saw it 37-92 m back).
    The refused scan becomes the keyframe at once instead, flagged like any
    re-initialisation, so that the next scan is one stride from it.
    """
    return odometry.keyframe is not None and len(odometry._accepted) < 2
