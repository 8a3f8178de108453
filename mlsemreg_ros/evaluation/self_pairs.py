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
A real single scan registered against a moved, resampled, noisy copy of itself.

What one real scan of an unknown sensor can test (issue 35): the copy is the scan seen from
a sensor moved by a known motion (``yaw`` about z, ``shift`` along the rotated x axis),
resampled (a random share of its points) and with Gaussian noise on every coordinate. Both
go through the odometry as the node runs it, with defaults and no labels (the label source
``auto`` labels them geometrically): the scan starts the odometry and measures the sensor
(core/odometry/sensor_scale.py), the copy has no prediction and is registered globally.
The pose is right when it is within the evaluation bounds of the known motion.
"""

from __future__ import annotations

from dataclasses import dataclass
import time
from typing import Any

from mlsemreg_ros.core.metrics import rotation_error_deg, translation_error_m
import numpy as np
from scipy.spatial.transform import Rotation

#: The motions of the issue: (shift m, yaw deg).
MOTIONS = ((2.0, 10.0), (8.0, 30.0))
#: Share of the points the copy keeps, and its noise (m, per coordinate).
KEEP = 0.7
NOISE_M = 0.02
#: A pose within these bounds of the truth is right (deg, m; the eval-bag success bounds).
MAX_ROTATION_ERROR_DEG = 5.0
MAX_TRANSLATION_ERROR_M = 0.6


@dataclass(frozen=True)
class SelfPairResult:
    """One scan against its moved copy: the outcome and what the odometry picked."""

    name: str
    points: int
    shift_m: float
    yaw_deg: float
    accepted: bool
    right: bool
    rotation_error_deg: float
    translation_error_m: float
    source: str  # the step's pose source ('global', 'prediction+global', ...)
    picked: str  # the sensor scale's summary: spacing and the values picked
    latency_ms: float
    reason: str


def sensor_motion(shift_m: float, yaw_deg: float) -> np.ndarray:
    """Return ``T_scan_copy``: the copy's sensor, turned by ``yaw_deg`` and moved ``shift_m``."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler('z', yaw_deg, degrees=True).as_matrix()
    T[:3, 3] = T[:3, :3] @ np.array([shift_m, 0.0, 0.0])
    return T


def moved_copy(
    points: np.ndarray, T_scan_copy: np.ndarray, keep: float, noise_m: float, seed: int = 0
) -> np.ndarray:
    """Return the scan's points as the moved sensor sees them: resampled, with noise."""
    rng = np.random.default_rng(seed)
    chosen = np.sort(
        rng.choice(len(points), size=max(1, round(keep * len(points))), replace=False)
    )
    inverse = np.linalg.inv(T_scan_copy)
    copy = points[chosen] @ inverse[:3, :3].T + inverse[:3, 3]
    return copy + rng.normal(0.0, noise_m, copy.shape)


def register_self(
    name: str,
    points: np.ndarray,
    config: Any,
    shift_m: float,
    yaw_deg: float,
    keep: float = KEEP,
    noise_m: float = NOISE_M,
    seed: int = 0,
) -> SelfPairResult:
    """Start a fresh odometry on ``points``, register the moved copy, score the pose."""
    from mlsemreg_ros.core.odometry import Odometry

    points = np.asarray(points, dtype=np.float64)
    points = points[np.all(np.isfinite(points), axis=1)]
    T_true = sensor_motion(shift_m, yaw_deg)
    copy = moved_copy(points, T_true, keep, noise_m, seed)
    odometry = Odometry(config=config)
    odometry.process(points, None, 1_000_000_000)
    start = time.perf_counter()
    step = odometry.process(copy, None, 1_100_000_000)
    latency = 1e3 * (time.perf_counter() - start)
    pose = np.asarray(step.pose, dtype=np.float64)
    re = rotation_error_deg(pose[:3, :3], T_true[:3, :3])
    te = translation_error_m(pose[:3, 3], T_true[:3, 3])
    accepted = bool(step.accepted)
    scale = odometry.sensor_scale
    return SelfPairResult(
        name,
        len(points),
        shift_m,
        yaw_deg,
        accepted,
        accepted and re <= MAX_ROTATION_ERROR_DEG and te <= MAX_TRANSLATION_ERROR_M,
        re,
        te,
        str(step.source),
        scale.summary() if scale is not None else 'sensor: not measured',
        latency,
        str(step.reason or ''),
    )
