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
A refused global pose that the gyro confirms, when nothing else predicts the scan.

Right after a start or a re-initialisation the IMU prior cannot predict the next scan: the
velocity is unknown until two poses are accepted (``prior_model.py``), so that scan rests on
the global registration alone. On dev pair ``000007`` the registration finds the right pose
(0.15 m / 1.1 deg from the truth) and the confidence rule refuses it on its own evidence
(12 sparse inliers, a rival within the margin): every good scan the dev-pair fuzz lost was
this one (``docs/hostile_input.md``).

The gyro still measures the rotation over the interval, and a wrong global pose is rarely
turned right: the 18 wrong poses the pair registration refused on the 40 and 60 m dev pairs
(both descriptors, forward) are all 3.5 deg or more from the truth's rotation. So when

- the scan was rejected, there was no prediction, and the IMU covers the interval from the
  last accepted scan (:meth:`PriorMotionModel.gyro_rotation`);
- the refused global pose is within :data:`ESTIMATE_FACTOR` times ``motion_prior.gyro_rescue``
  of the gyro's rotation (a sparse estimate's rotation is coarse);

that pose is refined against the local map like any global candidate (:class:`Trust`'s
rules: correction bounds, inlier share) and accepted when the refinement is trusted, holds
its weakest direction as the second look's own-evidence acceptance must
(``near_miss.min_weak_support``, :func:`second_look.weak_refusal`) and is within
``motion_prior.gyro_rescue`` of the gyro. The step says so (``confirmed by the gyro``).

Translation is not checked by this: a wrong pose along a straight road with the right
rotation would pass the gyro; the map's rules must refuse it. Rotation-constrained voting
on the refused correspondences (every ``t = q - R p`` with the gyro's ``R``) was measured
on ``000007`` and does not find the translation: its largest peaks were 3 m from the
sensor (29 votes) and 2.6 m along the road from the truth (26), the truth not among the
first three.
"""

from __future__ import annotations

import time
from typing import Any

from mlsemreg_ros.core.odometry.second_look import weak_refusal
from mlsemreg_ros.core.odometry.steps import Decision
from mlsemreg_ros.core.rigid import rotation_angle_deg
import numpy as np

#: The refused pose itself may be this many times ``motion_prior.gyro_rescue`` from the gyro
#: (a sparse estimate's rotation is coarse; its refinement is held to the bound itself). On
#: the 54 dev-pair scans (20, 40 and 60 m, both ways) with every bound at 30 deg, right
#: refused poses were 1.10 to 5.03 deg from the gyro and 0.10 to 1.53 deg once refined; the
#: one wrong pose near them (8.3 m off along the road) 4.48 deg, and 2.73 deg refined.
ESTIMATE_FACTOR = 4.0


def gyro_disagreement_deg(last_pose: np.ndarray, R_gyro: np.ndarray, pose: np.ndarray) -> float:
    """Return the angle (deg) between ``pose``'s rotation and the gyro's from ``last_pose``."""
    expected = last_pose[:3, :3] @ R_gyro
    difference = np.eye(4)
    difference[:3, :3] = expected.T @ pose[:3, :3]
    return rotation_angle_deg(difference)


def rescue_by_gyro(
    odometry: Any,
    stamp_ns: int,
    prediction: Any,
    raw: Any,
    chosen: Decision,
    timings: dict[str, float],
) -> Decision:
    """Return ``chosen``, or an accepted decision when the gyro confirms its refused pose."""
    bound = odometry.config.motion_prior.gyro_rescue
    result = chosen.result
    if (
        bound <= 0.0
        or chosen.accepted
        or prediction is not None
        or result is None
        or odometry.keyframe is None
        or not np.all(np.isfinite(result.transform))
    ):
        return chosen
    model = odometry.motion_model
    gyro = getattr(model, 'gyro_rotation', None)
    last = getattr(model, 'last_accepted', None)
    measured = gyro(stamp_ns) if gyro is not None else None
    if measured is None or last is None:
        return chosen
    T_global = odometry.keyframe.pose @ result.transform
    before = gyro_disagreement_deg(last[0], measured, T_global)
    if before > ESTIMATE_FACTOR * bound:
        return chosen
    tic = time.perf_counter()
    candidate = odometry.tracker.candidate('global', T_global, raw.scan, odometry.config)
    timings['fine_gyro_rescue_ms'] = 1e3 * (time.perf_counter() - tic)
    alignment = candidate.alignment
    after = gyro_disagreement_deg(last[0], measured, alignment.T_target_source)
    if not candidate.acceptable or after > bound:
        return chosen
    if weak_refusal(alignment, odometry.config):  # the gyro pins no translation either
        return chosen
    note = (
        f'the refused global pose confirmed by the gyro ({before:.2f} deg from its rotation, '
        f'{after:.2f} refined; motion_prior.gyro_rescue)'
    )
    return chosen.rescued(candidate, note, odometry.config.odometry.covariance_scale)
