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
Moving objects: which points of a scan the odometry keeps out of its local map.

The labels tell what no geometric odometry knows: which points belong to cars and
people. ``moving_objects.map_filter`` picks the points (``docs/field_moving.md``):

- ``moving``: points labeled with a SemanticKITTI moving class, raw ids 252-259
  (moving-car ... moving-other-vehicle; the instance id in the upper 16 bits is ignored).
  Learning ids (0-19) have no moving classes, so with them this filter leaves every point.
- ``movable``: every point of a class in ``moving_objects.movable_classes`` (car, truck,
  bicycle, person, ...), moving or parked; in raw ids the moving classes map to these.
- ``off``: none.

Filtered points never enter the local map, and the scan's own fine-alignment cloud leaves
them out (a car that drives away is not the street). ``moving_objects.matching`` says what
the global registration (keypoints, descriptors, BMR-SS landmarks) sees of them: ``keep``
all points, or ``drop`` the filtered ones before the scan is prepared, as if they had not
been measured. The keyframe is the prepared scan, so with ``drop`` it holds none either.

Everything is a vectorised mask over the scan: :class:`MovingObjectFilter`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mlsemreg_ros.core.settings import param
import numpy as np

#: SemanticKITTI raw ids of the moving classes (moving-car 252 ... moving-other-vehicle 259).
MOVING_RAW_IDS = tuple(range(252, 260))
#: Classes that can move (``moving_objects.movable_classes`` default): vehicles, people, riders.
MOVABLE_CLASSES = (
    'car',
    'bicycle',
    'motorcycle',
    'truck',
    'other-vehicle',
    'person',
    'bicyclist',
    'motorcyclist',
)
_RAW_MASK = 0xFFFF


@dataclass
class MovingObjectsConfig:
    """Which points of movable objects the odometry keeps out of its map and matching."""

    map_filter: str = param(
        'moving',
        'Points kept out of the local map and of the fine alignment: moving (raw ids '
        '252-259; learning ids carry none), movable (every point of movable_classes, '
        'parked cars too) or off.',
        choices=('off', 'moving', 'movable'),
    )
    matching: str = param(
        'drop',
        'The filtered points in the global registration (keypoints, descriptors, '
        'landmarks): keep them, or drop them before the scan is prepared.',
        choices=('keep', 'drop'),
    )
    movable_classes: list[str] = param(
        list(MOVABLE_CLASSES),
        'Classes that map_filter: movable keeps out (class names of the label map).',
    )


class MovingObjectFilter:
    """
    Masks of the points ``moving_objects`` filters, on raw and on prepared scans.

    ``label_map`` is the registration's :class:`~mlsemreg_ros.core.matching.labels.LabelMap`
    (class names to learning ids, raw to learning ids).
    """

    def __init__(self, label_map: Any) -> None:
        self.label_map = label_map
        self._movable: tuple[tuple[str, ...], np.ndarray] | None = None  # (names, lookup)

    def movable_lookup(self, config: MovingObjectsConfig) -> np.ndarray:
        """Return a (num_classes,) bool lookup: learning id -> movable (cached per names)."""
        names = tuple(config.movable_classes)
        if self._movable is None or self._movable[0] != names:
            lookup = np.zeros(self.label_map.num_classes, dtype=bool)
            lookup[self.label_map.ids_of(names)] = True
            self._movable = (names, lookup)
        return self._movable[1]

    def raw_mask(
        self, labels: np.ndarray, config: MovingObjectsConfig, scheme: str = 'auto'
    ) -> np.ndarray | None:
        """
        Return the filtered points of a raw scan as an (N,) bool mask, or None if none.

        ``labels`` are the scan's labels as they arrive (raw or learning ids, any dtype);
        ``scheme`` is ``semantic.label_scheme``. Raises
        :class:`~mlsemreg_ros.core.matching.labels.LabelError` for labels that cannot be read.
        """
        if config.map_filter == 'off' or len(labels) == 0:
            return None
        if config.map_filter == 'moving':
            if scheme == 'learning':
                return None
            # with 'auto' too: 252-259 is never a valid learning id (those are 0-19)
            semantic = _semantic_ids(labels)
            mask = (semantic >= MOVING_RAW_IDS[0]) & (semantic <= MOVING_RAW_IDS[-1])
        else:
            ids = self.label_map.convert(labels, scheme, max_out_of_scheme=1.0).ids
            mask = self.movable_lookup(config)[ids]
        return mask if mask.any() else None

    def prepared_mask(
        self,
        points: np.ndarray,
        labels: np.ndarray,
        filtered_points: np.ndarray | None,
        config: MovingObjectsConfig,
        voxel_size: float,
    ) -> np.ndarray | None:
        """
        Return the filtered points of a prepared scan (V,) bool, or None if none.

        ``points``/``labels`` (learning ids) are the prepared scan. ``movable``: by the
        voxels' majority labels. ``moving``: a prepared point is filtered when its voxel
        of ``voxel_size`` (``features.voxel_size``, the grid the scan was downsampled on,
        keys ``floor(p / voxel_size)``) holds one of ``filtered_points`` (the raw points of
        :meth:`raw_mask`, sensor frame); with ``voxel_size`` 0 the points match exactly.
        """
        if config.map_filter == 'off' or len(points) == 0:
            return None
        if config.map_filter == 'movable':
            mask = self.movable_lookup(config)[np.asarray(labels, dtype=np.int64)]
        else:
            if filtered_points is None or len(filtered_points) == 0:
                return None
            mask = _same_voxel(points, filtered_points, voxel_size)
        return mask if mask.any() else None


def _semantic_ids(labels: np.ndarray) -> np.ndarray:
    """
    Return the lower 16 bits of labels read as uint32 patterns (``core/matching/labels.py`` rules).

    Non-finite or non-integral float labels read as 0 here; the scan's preparation
    rejects them with a clear error.
    """
    values = np.asarray(labels).reshape(-1)
    if values.dtype.kind == 'f':
        values = np.where(np.isfinite(values), values, 0.0)
        values = np.where((values >= -(2.0**31)) & (values < 2.0**32), values, 0.0)
    return values.astype(np.int64) & _RAW_MASK


def _same_voxel(points: np.ndarray, others: np.ndarray, voxel_size: float) -> np.ndarray:
    """Return (N,) bool: ``points`` whose voxel (exact position for size 0) holds ``others``."""
    a = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(others, dtype=np.float64).reshape(-1, 3)
    if voxel_size > 0:
        a, b = np.floor(a / voxel_size), np.floor(b / voxel_size)
    rows = np.dtype([('x', np.float64), ('y', np.float64), ('z', np.float64)])
    keys_a = np.ascontiguousarray(a).view(rows).reshape(-1)
    keys_b = np.ascontiguousarray(b).view(rows).reshape(-1)
    return np.isin(keys_a, keys_b)
