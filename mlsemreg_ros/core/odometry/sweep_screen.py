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
A quick look before the sweep alignment of a tracked scan on a partial view.

On a full ring a scan that the motion model's prediction tracked with a small correction
skips the sweep alignment (``sweep_alignment.steady_*``, docs/sensors.md, session 17). On a
partial view (the 70 deg solid-state pattern) it runs on every tracked scan: skipping it on
every scan tracked by its prediction alone lost right poses on the long drives with
geometric labels (seed 1, 120 scans, 94.1 -> 88.2 %; seed 7, 200 scans, 94.5 -> 93.5 %),
at a turn's onset, where the sweep alignment is what sees the yaw rate change within the
sweep (the fine alignment's correction, inlier share and iterations there look like any
other scan's). It costs a third of such a scan's time (docs/sensors.md, session 19).

So the sweep alignment looks first with a few points (``sweep_alignment.screen_points``,
every k-th of the sweep, the same Gauss-Newton from the same start) and runs in full only
when that look bends the scan by more than ``sweep_alignment.min_change``, or when the
twist the pose implies bends it beyond the first start's reach (the second start,
``core/odometry/sweep_starts.py``). Without a full run the scan is accepted as tracked and
the next scan is deskewed by the poses' twist, as after a steady scan on a full ring.
"""

from __future__ import annotations

from typing import Any, TYPE_CHECKING

from mlsemreg_ros.core.alignment.sweep_alignment import align_sweep, sweep_subset
from mlsemreg_ros.core.deferred import stored
from mlsemreg_ros.core.features.deskew import SweepMotion
from mlsemreg_ros.core.odometry.sweep_starts import bend_m, second_start_bend
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.odometry.preprocess import PreprocessedScan

#: The sweep alignment needs a local map of at least this many voxels (tracking.py's).
MIN_MAP_VOXELS = 100
#: A scan deskewed with a rotation rate above this (deg/s) is in a turn: its sweep
#: alignment runs in full, as its estimate of the rate is what the next scan is deskewed
#: with, and a turn's end changes that rate within one or two sweeps (a car's straight
#: drive: a few deg/s of noise; its turns on the simulated drives: 40-45 deg/s).
TURN_RATE = 10.0


def sweep_points(
    raw: PreprocessedScan, preprocessor: Any, cfg: RegistrationConfig, count: int
) -> tuple[np.ndarray, np.ndarray]:
    """Return about ``count`` raw points of the sweep and their times, moving objects out."""
    points, times = raw.input_points, np.asarray(raw.point_times, dtype=np.float64)
    if cfg.moving_objects.matching != 'drop':  # 'drop' took them out before the deskew
        moving = preprocessor.moving_mask(points, stored(raw, 'labels'))
        if moving is not None and len(moving) == len(points):
            points, times = points[~moving], times[~moving]
    return sweep_subset(points, times, count)


def screened(
    tracker: Any,
    held: bool,
    raw: PreprocessedScan,
    pose: np.ndarray,
    preprocessor: Any,
    cfg: RegistrationConfig,
    implied: SweepMotion | None,
) -> float | None:
    """
    Return the quick look's bend (m) when the full sweep alignment is not needed, else None.

    ``held``: the scan was tracked by its motion model's prediction alone
    (``Decision.held``); ``implied``: the twist from the last accepted pose to ``pose``.
    None (run the full alignment) off a partial view, with ``screen_points`` 0, for any
    other decision, or when the look bends the scan by more than ``min_change``.
    """
    sweep = cfg.sweep_alignment
    motion = raw.motion
    if (
        sweep.screen_points <= 0
        or not held
        or not tracker.trust.view.partial
        or sweep.mode == 'off'
        or cfg.fine.method == 'off'
        or not isinstance(motion, SweepMotion)
        or np.degrees(np.linalg.norm(motion.omega)) > TURN_RATE
        or raw.input_points is None
        or raw.point_times is None
        or tracker.map.empty
    ):
        return None
    gaussians = tracker.map_gaussians()
    if gaussians is None or len(gaussians) < MIN_MAP_VOXELS:
        return None
    points, times = sweep_points(raw, preprocessor, cfg, sweep.screen_points)
    if implied is not None and np.all(
        np.isfinite(np.concatenate([implied.omega, implied.velocity]))
    ):
        if bend_m(points, times, implied, motion) > second_start_bend(sweep):
            return None  # the second start may be needed: the full alignment
    look = align_sweep(points, times, gaussians, pose, motion, sweep)
    if not np.isfinite(look.change_m) or look.change_m > sweep.min_change:
        return None
    return float(look.change_m)
