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
A second start for the sweep alignment when the deskew's twist disagrees with the pose.

Without a gyro the deskew takes the motion within a sweep from the last accepted poses
(``core/features/deskew.py``). A hand that turns its sensor back and forth at 0.5 Hz
reverses its yaw rate between two scans 0.3 s apart: the deskew then bends the scan by the
difference (-34 deg/s assumed, +50 deg/s true on the handheld VLP-16 drive at stride 3:
8 deg over one sweep). The sweep alignment (``core/alignment/sweep_alignment.py``) starts
from that twist, with a prior about it, and stays in its basin; the scan was accepted
8.5 deg off (docs/sensors.md#the-handheld-profile).

The accepted pose itself says how the sensor moved since the last accepted scan: the twist
from that pose to this one (:func:`~mlsemreg_ros.core.features.deskew.sweep_motion`). When
it bends the sweep differently from the deskew's twist by more than the first start's reach
(:data:`SECOND_START_REACH` pairing distances ``sweep_alignment.max_distance``,
:func:`second_start_bend`), the sweep alignment also
starts from it, and its result replaces the first when it fits the local map clearly better
(the mean Geman-McClure cost of the deskewed points against their nearest map voxel's
Gaussian, lower by :data:`SECOND_START_GAIN`). A car, whose velocity barely changes between
scans, rarely gets the second start.
"""

from __future__ import annotations

from dataclasses import replace
import time
from typing import Any

from mlsemreg_ros.core import threads
from mlsemreg_ros.core.alignment.config import SweepAlignmentConfig
from mlsemreg_ros.core.alignment.sweep_alignment import (
    align_sweep,
    MapGaussians,
    sweep_subset,
    SweepAlignment,
    VOXEL_REGULARIZATION,
)
from mlsemreg_ros.core.features.deskew import deskew, sweep_motion, SweepMotion
from mlsemreg_ros.core.odometry.prior_guard import prior_used
import numpy as np

#: The bend runs on it beside the first start's alignment (:func:`align_from_starts`).
_POOL = threads.LazyPool('mlsemreg-sweep-starts')

#: The second start's result replaces the first only when it fits the map this much better
#: (relative cost): within 1-2 % both are the same basin seen through the pose-twist
#: trade-off, and the second start overshot (68 against 43 deg/s true, a 0.60 m pose on the
#: handheld VLP-16 at stride 3).
SECOND_START_GAIN = 0.02
#: The first start's reach, in pairing distances (``sweep_alignment.max_distance``): an
#: implied twist that bends the sweep by less from the deskew's lands in the first start's
#: basin (:func:`second_start_bend`).
SECOND_START_REACH = 2.5


def bend_m(points: np.ndarray, times: np.ndarray, a: SweepMotion, b: SweepMotion) -> float:
    """Return the largest distance (m) a point moves between the deskews by ``a`` and ``b``."""
    change = deskew(points, times, a) - deskew(points, times, b)
    return float(np.sqrt(np.max(np.einsum('ni,ni->n', change, change), initial=0.0)))


def second_start_bend(config: SweepAlignmentConfig) -> float:
    """
    Return the bend (m) beyond which the implied twist gets a start of its own.

    A twist that moves every point by less than ``sweep_alignment.max_distance`` from where
    the deskew's twist put it leaves each point pairing with the map voxel the other twist
    would pair it with: the first start's Gauss-Newton already sees that basin. Its robust
    kernel starts wide, so it reaches further: :data:`SECOND_START_REACH` pairing
    distances. On the car drives the implied twist (from one interval's poses: yaw-rate
    noise of a few deg/s) bent the sweep by 0.5-1.3 m on 14-19 % of the VLP-16, HDL-32 and
    solid-state scans and never won. On the handheld VLP-16 walk at stride 1 it bent the
    sweep by 1.06-2.16 m on 53 of 119 scans; the second start landed within 0.87 m of the
    first start's result every time and never won. At stride 3 every second start from a
    bend under 3 m landed within 0.3 m of the first; the winners bent it by 3.0-5.2 m
    (docs/sensors.md).
    """
    return max(config.min_change, SECOND_START_REACH * config.max_distance)


def fit_cost(
    points: np.ndarray,
    times: np.ndarray,
    gaussians: MapGaussians,
    result: SweepAlignment,
    max_distance: float,
) -> float:
    """
    Mean Geman-McClure cost (scale 1) of the deskewed ``points`` at the result's pose.

    A point beyond ``max_distance`` of every map voxel mean costs 1, the kernel's ceiling.
    """
    deskewed = deskew(points, times, result.motion)
    T = result.T_target_source
    world = deskewed @ T[:3, :3].T + T[:3, 3]
    index, sq = gaussians.nearest(world, max_distance)  # exact within max_distance
    cost = np.ones(len(world))
    near = sq < max_distance**2
    if np.any(near):
        offset = world[near] - gaussians.means[index[near]]
        information = np.linalg.inv(
            gaussians.covariances[index[near]] + VOXEL_REGULARIZATION * np.eye(3)
        )
        mahalanobis = np.einsum('ni,nij,nj->n', offset, information, offset)
        cost[near] = mahalanobis / (1.0 + mahalanobis)
    return float(np.mean(cost)) if len(cost) else float('inf')


def align_from_starts(
    points: np.ndarray,
    times: np.ndarray,
    gaussians: MapGaussians,
    pose: np.ndarray,
    motion: SweepMotion,
    implied: SweepMotion | None,
    config: SweepAlignmentConfig,
) -> SweepAlignment:
    """
    Align the sweep from the deskew's twist ``motion`` and, if it differs, from ``implied``.

    ``implied``: the twist from the last accepted pose to ``pose`` (None: unknown). The
    result's ``change_m`` is measured against ``motion``, as the caller's
    ``sweep_alignment.min_change`` test expects.
    """
    if implied is None or not np.all(
        np.isfinite(np.concatenate([implied.omega, implied.velocity]))
    ):
        return align_sweep(points, times, gaussians, pose, motion, config)
    # the first start and the bend are independent compiled passes (no GIL): both cores.
    # The first start (the longer) runs on the calling thread, the bend beside it on the
    # pool: one hand-off instead of two, and no wait for a pool thread to start the first
    bending = _POOL.submit(lambda: bend_m(points, times, implied, motion))
    first = align_sweep(points, times, gaussians, pose, motion, config)
    bend = bending.result() if bending is not None else bend_m(points, times, implied, motion)
    if bend <= second_start_bend(config):
        return first  # within the first start's reach: one start is enough
    second = align_sweep(points, times, gaussians, pose, implied, config)
    if not np.all(np.isfinite(second.T_target_source)):
        return first
    costs = [fit_cost(points, times, gaussians, r, config.max_distance) for r in (first, second)]
    if not costs[1] < (1.0 - SECOND_START_GAIN) * costs[0]:
        return first
    return replace(second, change_m=bend_m(points, times, second.motion, motion))


def implied_twist(motion_model: object, pose: np.ndarray, stamp_ns: int) -> SweepMotion | None:
    """
    Return the twist from the motion model's last accepted pose to ``pose`` at ``stamp_ns``.

    None when the model keeps no accepted pose (``last_accepted``, the constant-velocity
    model's) or the stamps give no duration.
    """
    last = getattr(motion_model, 'last_accepted', None)
    if last is None:
        return None
    return sweep_motion(last[0], last[1], pose, stamp_ns)


def retry_refused(
    odometry: Any,
    scan: tuple[Any, Any, Any, int],
    prediction: Any,
    raw: Any,
    chosen: Any,
    timings: dict[str, float],
) -> tuple[Any, Any]:
    """
    Register a refused scan again, deskewed by the twist its refused global pose implies.

    The scan was deskewed by the last poses' twist (no prior); when no candidate was
    accepted, the refined global candidate's pose (refused, but a pose of this scan) implies
    a twist from the last accepted pose. When that twist bends the sweep differently by more
    than ``sweep_alignment.min_change``, the scan is deskewed with it and estimated again,
    under every rule of a first estimate. ``scan``: ``(points, labels, point_times,
    stamp_ns)`` as the odometry got it. Returns the scan and decision to apply.
    """
    cfg = odometry.config
    motion = raw.motion
    if (
        chosen.accepted
        or cfg.sweep_alignment.mode == 'off'
        or not isinstance(motion, SweepMotion)
        or raw.input_points is None
        or raw.point_times is None
        or prior_used(odometry.sweep_state()[2], motion)
    ):
        return raw, chosen
    refused = [c for c in chosen.candidates if c.name == 'global']
    if not refused or not np.all(np.isfinite(refused[-1].alignment.T_target_source)):
        return raw, chosen
    points, labels, point_times, stamp_ns = scan
    implied = implied_twist(odometry.motion_model, refused[-1].alignment.T_target_source, stamp_ns)
    if implied is None:
        return raw, chosen
    sample, times = sweep_subset(
        raw.input_points, np.asarray(raw.point_times, dtype=np.float64), 1000
    )
    if bend_m(sample, times, implied, motion) <= cfg.sweep_alignment.min_change:
        return raw, chosen
    tic = time.perf_counter()
    again = odometry.preprocessor.scan(points, labels, point_times, implied)
    if not again.deskewed:
        return raw, chosen
    tracker = odometry.tracker
    tracker.map.cloud(again.scan)
    other = tracker.estimate(
        again.scan, prediction, odometry.keyframe, odometry.global_registration, cfg, timings
    )
    timings['sweep_retry_ms'] = 1e3 * (time.perf_counter() - tic)
    if not other.accepted:
        return raw, chosen
    other.reason = '; '.join(
        r for r in (other.reason, 'deskewed again by the twist of the refused global pose') if r
    )
    return again, other
