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
The first pair under a second hypothesis of the first scan's twist (issue 29, item 3).

A first pair is registered on two sweeps nobody knew the motion of, and
``Tracker.deskew_start`` deskews both with the mean twist between them. The first scan's
own twist is not observable from the pair: a car that turns unevenly (-2.8 deg/s during
scan 0, -30 deg/s on average over the next 3 s, docs/field.md) has its scan 0 bent by the
difference, and the pair's pose follows the bend into a place just inside the bounds
(0.54-0.57 m on the HDL-64 field drive, seed 0, at strides 20 and 30).

So the second scan is aligned once more onto the first scan deskewed with the same
velocity and no rotation rate (a car driving straight during its first sweep). When that
pose lies more than ``near_miss.start_twist_spread`` from the one the mean twist gave, the
pair's pose depends on a twist nobody measured. It is not moved (neither hypothesis is
known to be the right one); ``near_miss.start_twist_action`` says what happens:

- ``inflate`` (the default): the pose is published with its frame covariance grown along
  the gap between the two poses until its standard deviation there covers the gap
  (:func:`inflated_covariance`);
- ``refuse``: the pair is refused and the odometry restarts on the newer scan
  (``keyframe.restart_gap``, failures.py). That lost more than it saved on the field
  drives: the restarted pair meets the same unknown twist, and where the car has just
  left a turn the mean twist of the new pair has no rotation either, so the two
  hypotheses agree on a pose 0.8 m off (docs/confidence.md#near-misses-issue-29).

With a gyro the first scan's rotation is measured, and the check does not run.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from mlsemreg_ros.core.deferred import stored
from mlsemreg_ros.core.features.deskew import sweep_motion, SweepMotion
from mlsemreg_ros.core.odometry.preprocess import PreprocessedScan, Preprocessor
from mlsemreg_ros.core.rigid import invert_transform, rotation_angle_deg, rotation_vector
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.odometry.tracking import Tracker


def no_rotation_pose(
    tracker: Tracker,
    start: tuple[PreprocessedScan, np.ndarray, int],
    second: PreprocessedScan,
    T_start: np.ndarray,
    T_current: np.ndarray,
    stamp_ns: int,
    preprocessor: Preprocessor,
) -> np.ndarray | None:
    """
    Return the pair's pose (4, 4) when the first scan had no rotation rate, or None.

    ``start``: the first scan as received (not deskewed), its pose and stamp;
    ``second``: the next scan deskewed by the pair's mean twist, whose pose ``T_current``
    that twist gave (from ``T_start``, its pose on the skewed sweeps). The first scan is
    deskewed with the velocity of the mean twist and no rotation, put alone in the map,
    and ``second`` aligned onto it from ``T_start``. The map is left empty (the caller
    puts its first scan back). None: no twist, or the first scan cannot be deskewed.
    """
    first, first_pose, first_stamp = start
    twist = sweep_motion(first_pose, first_stamp, T_current, stamp_ns)
    if twist is None:
        return None
    points = first.input_points if first.input_points is not None else first.points
    straight = SweepMotion(np.zeros(3), np.asarray(twist.velocity, dtype=float))
    labels = stored(first, 'labels')
    redone = preprocessor.scan(points, labels, first.point_times, straight)
    if not redone.deskewed:
        return None
    tracker.map.clear()
    tracker.map.insert_scan(redone.scan, first_pose)
    aligned = tracker.map.align_scan(second.scan, T_start)
    tracker.map.clear()
    return np.asarray(aligned.T_target_source, dtype=np.float64)


def spread(T_pose: np.ndarray, T_other: np.ndarray) -> tuple[float, float]:
    """Return the translation (m) and rotation (deg) between two poses."""
    between = invert_transform(T_pose) @ T_other
    return float(np.linalg.norm(between[:3, 3])), float(rotation_angle_deg(between))


def start_twist_verdict(
    T_pose: np.ndarray, T_other: np.ndarray | None, cfg: RegistrationConfig
) -> tuple[str, bool]:
    """
    Return the note on the first pair's two twists and whether to refuse it.

    The note is '' when the check did not run (``T_other`` None, the bound 0); refusal
    when the poses lie more than ``near_miss.start_twist_spread`` apart and
    ``near_miss.start_twist_action`` is ``refuse``.
    """
    bound = cfg.near_miss.start_twist_spread
    if T_other is None or bound <= 0.0:
        return '', False
    meters, degrees = spread(T_pose, T_other)
    said = (
        f'the first scan without a rotation rate moves the pose by {meters:.2f} m / '
        f'{degrees:.2f} deg'
    )
    if meters <= bound:
        return said, False
    refuse = cfg.near_miss.start_twist_action == 'refuse'
    verb = 'refused' if refuse else 'covariance inflated'
    return f'{verb}: {said} > near_miss.start_twist_spread={bound:g} m (its twist is unknown)', (
        refuse
    )


def disputed_motion(T_pose: np.ndarray, T_other: np.ndarray) -> np.ndarray:
    """Return the motion (6,) from ``T_pose`` to ``T_other`` in the pose's axes: [t, rotvec]."""
    between = invert_transform(T_pose) @ T_other
    return np.concatenate([between[:3, 3], rotation_vector(between[:3, :3])])


def inflated_covariance(frame_covariance: np.ndarray, disputed: np.ndarray) -> np.ndarray:
    """
    Return ``frame_covariance`` (6, 6, [t, rotvec], the pose's axes) grown along ``disputed``.

    ``disputed`` (6,): :func:`disputed_motion` between the two twists' poses. In the
    translation block, its translation's direction ``u`` gets the variance
    ``max(|t|^2 - u^T C u, 0)`` added, so the standard deviation along ``u`` is at least the
    gap; the rotation block likewise along its rotation vector. The other directions keep
    theirs.
    """
    out = np.array(frame_covariance, dtype=np.float64)
    if not np.all(np.isfinite(out)):
        return out
    for block in (slice(0, 3), slice(3, 6)):
        gap = np.asarray(disputed, dtype=np.float64)[block]
        length = float(np.linalg.norm(gap))
        if length <= 0.0:
            continue
        u = gap / length
        missing = length**2 - float(u @ out[block, block] @ u)
        if missing > 0.0:
            out[block, block] += missing * np.outer(u, u)
    return out
