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
Coordinate hygiene of one scan, before voxelization (issue 11, "input hygiene").

:func:`sanitize_scan` drops the points with a NaN/inf coordinate and the points
outside ``[min_range, max_range]`` from the sensor (the origin of the scan's
frame), and counts each kind. It is the guard of the voxel grid: with every
kept point within ``max_range`` (at most ``1e6`` m, ``features.max_range``) the
integer voxel keys of :func:`mlsemreg_ros.core.features.features.voxel_groups` cannot
overflow, whereas one point at 1e30 collapses a 17,600-voxel scan to 32 voxels.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core.features.config import FeatureConfig
from mlsemreg_ros.core.settings import ConfigError
import numpy as np

#: Largest accepted ``max_range``, metres (the ``high`` of ``features.max_range``): keeps
#: voxel keys of any voxel size above 1e-12 m far from int64 overflow.
MAX_RANGE_LIMIT_M = 1e6


@dataclass(frozen=True)
class SanitizedScan:
    """The points (and labels) of a scan that passed :func:`sanitize_scan`, with counts."""

    points: np.ndarray  # (M, 3) float64, metres, kept points in input order (may be the input)
    labels: np.ndarray | None  # (M,) labels of the kept points (input dtype), or None
    keep: np.ndarray  # (N,) bool, True for the kept input points
    dropped_nonfinite: int  # points with a NaN/inf coordinate
    dropped_far: int  # finite points farther than max_range from the origin
    dropped_near: int  # finite points closer than min_range to the origin

    @property
    def dropped(self) -> int:
        """Return the number of dropped points of every kind."""
        return self.dropped_nonfinite + self.dropped_far + self.dropped_near

    def dropped_counts(self) -> dict[str, int]:
        """Return the dropped points by kind, keyed as a prepared scan's ``input_stats``."""
        return {
            'dropped_nonfinite': self.dropped_nonfinite,
            'dropped_far': self.dropped_far,
            'dropped_near': self.dropped_near,
        }

    def __len__(self) -> int:
        return int(self.points.shape[0])


def sanitize_scan(
    points: np.ndarray,
    labels: np.ndarray | None = None,
    *,
    max_range: float = 200.0,
    min_range: float = 0.0,
) -> SanitizedScan:
    """
    Drop non-finite points and points beyond ``max_range`` or closer than ``min_range``.

    - ``points``: (N, 3) (or flat 3N) coordinates in metres, any real dtype.
    - ``labels``: (N,) per-point labels of any dtype (kept rows returned), or None.
    - ``max_range``: largest kept Euclidean distance from the origin, metres,
      ``0 < max_range <= MAX_RANGE_LIMIT_M``.
    - ``min_range``: smallest kept distance, metres, ``0 <= min_range < max_range``.

    Distances are compared as ``[min_range, max_range]`` (both bounds kept). Raises
    :class:`~mlsemreg_ros.core.config.ConfigError` for invalid ranges and ValueError
    for points that are not (N, 3) or labels of another length. Vectorized: one pass
    of squared norms, no overflow warnings for huge coordinates.
    """
    _check_ranges(max_range, min_range)
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        if points.size % 3 != 0:
            raise ValueError(f'points must be (N, 3), got shape {points.shape}')
        points = points.reshape(-1, 3)
    if labels is not None:
        labels = np.asarray(labels).reshape(-1)
        if labels.shape[0] != points.shape[0]:
            raise ValueError(f'{points.shape[0]} points but {labels.shape[0]} labels')
    with np.errstate(over='ignore', invalid='ignore'):
        squared = np.einsum('ij,ij->i', points, points)  # inf for huge, NaN for NaN points
        keep = squared <= max_range * max_range  # False for NaN: one pass decides
        if min_range > 0.0:
            keep &= squared >= min_range * min_range
    if keep.all():  # the common case: nothing to count
        return SanitizedScan(points, labels, keep, 0, 0, 0)
    finite = np.isfinite(points).all(axis=1)
    far = finite & (squared > max_range * max_range)
    near = finite & (squared < min_range * min_range)
    n_far, n_near = int(np.count_nonzero(far)), int(np.count_nonzero(near))
    n_nonfinite = int(finite.size - np.count_nonzero(finite))
    return SanitizedScan(
        points[keep], None if labels is None else labels[keep], keep, n_nonfinite, n_far, n_near
    )


def sanitize_scan_for(
    points: np.ndarray, labels: np.ndarray | None, features: FeatureConfig
) -> SanitizedScan:
    """:func:`sanitize_scan` with ``features.max_range`` and ``features.min_range``."""
    return sanitize_scan(
        points, labels, max_range=features.max_range, min_range=features.min_range
    )


def _check_ranges(max_range: float, min_range: float) -> None:
    """Raise ConfigError unless ``0 <= min_range < max_range <= MAX_RANGE_LIMIT_M``."""
    if not 0.0 < max_range <= MAX_RANGE_LIMIT_M:  # False for NaN too
        raise ConfigError(
            f'features.max_range={max_range} must lie in (0, {MAX_RANGE_LIMIT_M:g}] m'
        )
    if not 0.0 <= min_range < max_range:
        raise ConfigError(
            f'features.min_range={min_range} must lie in [0, features.max_range={max_range})'
        )
