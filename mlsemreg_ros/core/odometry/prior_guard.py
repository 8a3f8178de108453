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
A prior that disagrees with the scan is not used for that scan.

The samples that reach the motion model are checked one by one at arrival
(``core/prior_checks.py``), but a sample can be plausible and still wrong (a gyro glitch
within the limits). After a scan was registered with the prior's prediction and deskew,
:func:`prior_disagreement` compares them with the registration:

- the scan was rejected (the first rejection after an accepted scan);
- the prior's rotation over the interval is more than ``motion_prior.max_disagreement``
  degrees from the registration's;
- the gyro's rotation within the sweep (the deskew) is more than twice that
  (:data:`SWEEP_CHECK_FACTOR`) from the rotation the registration implies over the sweep
  (its rate over the interval; checked only over intervals up to
  :data:`SWEEP_CHECK_MAX_INTERVAL_S`, where one rate holds).

Then the scan is registered again without the prior (constant-velocity prediction and
deskew, :func:`guard_prior`), and the registration whose fine alignment holds
more inliers is kept: a scan that the prior's deskew aligned worse than the raw motion is
registered without it. The odometry says so in the step (``prior_refusal``, published in
``/diagnostics``). A bad sample therefore costs at most the scan whose interval it falls
in, as one more registration; the next scans' priors are built afresh.
"""

from __future__ import annotations

from typing import Any

from mlsemreg_ros.core.features.deskew import PiecewiseSweepMotion
from mlsemreg_ros.core.rigid import invert_transform, rotation_angle_deg
import numpy as np
from scipy.spatial.transform import Rotation

#: The sweep check compares the gyro with the registration's rate over intervals up to this (s).
SWEEP_CHECK_MAX_INTERVAL_S = 0.5
#: The sweep check's bound is this many times ``motion_prior.max_disagreement``: on the field
#: drives the gyro within a sweep differs from the registration's mean rate by up to 4.1 deg
#: (3 of 199 sweeps above 3 deg, field_s1 stride 1), and those registrations were right.
SWEEP_CHECK_FACTOR = 2.0
#: Sources of a prediction that come from prior messages.
PRIOR_SOURCES = ('imu', 'wheel')


def prior_used(motion_model: Any, motion: Any) -> bool:
    """Whether the prediction or the deskew of the last scan came from prior messages."""
    return getattr(motion_model, 'last_source', '') in PRIOR_SOURCES or isinstance(
        motion, PiecewiseSweepMotion
    )


def sweep_disagreement_deg(
    motion: Any, last_accepted: tuple[np.ndarray, int] | None, pose: np.ndarray, stamp_ns: int
) -> float:
    """
    Return the angle (deg) between the gyro's rotation over the sweep and the registration's.

    The registration's is its rotation from the last accepted pose to ``pose`` at a constant
    rate, over the sweep's span. 0 when there is no gyro deskew or the interval is too long.
    """
    if not isinstance(motion, PiecewiseSweepMotion) or last_accepted is None:
        return 0.0
    previous, previous_ns = last_accepted
    interval = (stamp_ns - previous_ns) * 1e-9
    if not 0.0 < interval <= SWEEP_CHECK_MAX_INTERVAL_S:
        return 0.0
    span = float(motion.times[-1] - motion.times[0])
    relative = invert_transform(previous) @ pose
    rate = Rotation.from_matrix(relative[:3, :3]).as_rotvec() / interval
    expected = Rotation.from_rotvec(rate * span).as_matrix()
    gyro = motion.poses[0, :3, :3].T @ motion.poses[-1, :3, :3]
    return rotation_angle_deg(expected.T @ gyro)


def prior_disagreement(
    prediction: Any,
    chosen: Any,
    motion: Any,
    motion_model: Any,
    last_accepted: tuple[np.ndarray, int] | None,
    stamp_ns: int,
    max_deg: float,
    failures_before: int = 0,
) -> str:
    """
    Why the prior may have cost this scan ('' if it agrees with the registration).

    A rejection counts only after an accepted scan (``failures_before`` 0): while the
    odometry is lost, every scan would otherwise be registered twice.
    """
    if not prior_used(motion_model, motion):
        return ''
    if not chosen.accepted:
        return 'the scan was rejected with the prior' if not failures_before else ''
    if prediction is not None and getattr(motion_model, 'last_source', '') in PRIOR_SOURCES:
        angle = rotation_angle_deg(invert_transform(prediction.T_odom_current) @ chosen.pose)
        if angle > max_deg:
            return f"the prior's rotation is {angle:.2f} deg from the registration's"
    sweep = sweep_disagreement_deg(motion, last_accepted, chosen.pose, stamp_ns)
    if sweep > SWEEP_CHECK_FACTOR * max_deg:
        return f"the gyro's rotation within the sweep is {sweep:.2f} deg from the registration's"
    return ''


def better_without_prior(with_prior: Any, without: Any) -> bool:
    """Whether the registration without the prior is kept: accepted, aligned at least as well."""
    if not without.accepted:
        return False
    if not with_prior.accepted:
        return True
    a, b = with_prior.inlier_fraction, without.inlier_fraction
    return a is None or (b is not None and b >= a)


def guard_prior(
    odometry: Any,
    scan: tuple[np.ndarray, np.ndarray, np.ndarray | None, int],
    prediction: Any,
    raw: Any,
    chosen: Any,
    timings: dict[str, float],
) -> tuple[Any, Any, str]:
    """
    Check the prior against the registration of ``scan``; without it too if they disagree.

    ``scan``: ``(points, labels, point_times, stamp_ns)`` as the odometry got it; ``raw``
    and ``chosen``: its preprocessed scan and decision with the prior. Returns the scan and
    decision to apply and the step's ``prior_refusal`` ('' when the prior agrees).
    """
    accepted, _, motion_model = odometry.sweep_state()
    refusal = prior_disagreement(
        prediction,
        chosen,
        raw.motion,
        motion_model,
        accepted[-1] if accepted else None,
        scan[3],
        odometry.config.motion_prior.max_disagreement,
        odometry.failures_in_a_row,
    )
    if not refusal:
        return raw, chosen, ''
    return _without_prior(odometry, scan, raw, chosen, refusal, timings)


def _without_prior(
    odometry: Any,
    scan: tuple[np.ndarray, np.ndarray, np.ndarray | None, int],
    raw: Any,
    chosen: Any,
    refusal: str,
    timings: dict[str, float],
) -> tuple[Any, Any, str]:
    """Register the scan again without the prior; keep the better."""
    points, labels, point_times, stamp_ns = scan
    preprocessor, trust, state = (
        odometry.preprocessor,
        odometry.tracker.trust,
        odometry.sweep_state(),
    )
    constant = getattr(odometry.motion_model, 'constant_velocity', None)
    prediction = constant(stamp_ns) if constant is not None else None
    motion = preprocessor.sweep_motion(prediction, stamp_ns, None, *state)  # no gyro
    tracked = trust.tracked_in_a_row
    again = preprocessor.scan(points, labels, point_times, motion)
    other = odometry.tracker.estimate(
        again.scan,
        prediction,
        odometry.keyframe,
        odometry.global_registration,
        odometry.config,
        timings,
    )
    if better_without_prior(chosen, other):
        other.reason = '; '.join(r for r in (other.reason, f'prior not used: {refusal}') if r)
        if other.source == chosen.source == 'prediction':
            trust.tracked_in_a_row -= 1  # one scan, tracked once
        return again, other, f'not used: {refusal}'
    trust.tracked_in_a_row = tracked
    return raw, chosen, f'kept (registered without it too, aligned worse): {refusal}'
