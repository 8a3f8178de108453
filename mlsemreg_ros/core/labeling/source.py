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
Where a scan's labels come from: ``label_source: auto | field | geometric | onnx | none``.

- ``field``: the cloud's own label field (a scan without one is refused).
- ``geometric``: the geometric labeler (core/labeling/geometric.py) on the scan voxelized
  at ``features.voxel_size``; every point gets the label of its voxel.
- ``onnx``: the user's range-image network (core/labeling/onnx_segmentation.py).
- ``none``: every point unlabeled (0); the pair is matched as unlabeled.
- ``auto`` (the default): the label field when the cloud has one, else ``geometric``.

The labels handed on are learning ids (raw ids when ``semantic.label_scheme`` is ``raw``),
which :meth:`~mlsemreg_ros.core.matching.labels.LabelMap.convert` reads back unchanged in
either scheme. docs/labels.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import time
from typing import Any

from mlsemreg_ros.core.deferred import Deferred
from mlsemreg_ros.core.features import kernels
from mlsemreg_ros.core.labeling.geometric import GeometricLabeler
from mlsemreg_ros.core.labeling.geometric_config import GeometricLabelsConfig, LABEL_SOURCES
from mlsemreg_ros.core.labeling.onnx_available import ONNX_MODULE, onnx_unavailable
from mlsemreg_ros.core.matching.labels import LabelError, LabelMap
import numpy as np

__all__ = ['LABEL_SOURCES', 'LabelSource', 'LabeledScan', 'onnx_unavailable']

#: Voxel edge for the geometric labels when the scan is not voxelized (features.voxel_size 0).
DEFAULT_LABEL_VOXEL = 0.3


@dataclass(frozen=True)
class LabeledScan:
    """A scan's labels and where they came from."""

    #: (N,) labels, as read from the field or learning / raw ids; a Deferred when they are
    #: made on first read (``label_timing: read``, core/deferred.py)
    labels: np.ndarray | Deferred[np.ndarray]
    source: str  # 'field', 'geometric', 'onnx' or 'none'
    labeling_ms: float  # time spent making them (0 for the field and until made)
    #: deferred labels: ``labeling_ms`` once made, and ``noted``, the timings of the scans
    #: noted before, which are given that time then (:meth:`LabelSource.when_read`)
    made: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    def note(self, scan: Any) -> None:
        """Record the source in ``scan.input_stats`` and the time in its ``timings_ms``."""
        stats, timings = getattr(scan, 'input_stats', None), getattr(scan, 'timings_ms', None)
        pending = isinstance(self.labels, Deferred) and not self.labels.ready
        if isinstance(stats, dict):
            stats['label_source'] = self.source
            if isinstance(self.labels, Deferred):
                stats['labels_made'] = 'when read'
        if isinstance(timings, dict):
            timings['labeling_ms'] = self.made.get('labeling_ms', self.labeling_ms)
            if pending:  # made later: its time is written here then (LabelSource.when_read)
                self.made.setdefault('noted', []).append(timings)


def resolve(requested: str, has_field: bool) -> str:
    """Return the source ``requested`` stands for on a scan with or without a label field."""
    if requested not in LABEL_SOURCES:
        raise LabelError(f'unknown label_source {requested!r}; use one of {LABEL_SOURCES}')
    if requested == 'auto':
        return 'field' if has_field else 'geometric'
    return requested


class LabelSource:
    """Labels every scan by ``config.label_source`` (module docstring); caches its labelers."""

    def __init__(self, label_map: LabelMap | None = None) -> None:
        self.label_map = label_map if label_map is not None else LabelMap.load()
        self._geometric: tuple[GeometricLabelsConfig, GeometricLabeler] | None = None
        self._onnx: tuple[Any, Any] | None = None  # (config, OnnxSegmenter)

    def __call__(
        self,
        points: np.ndarray,
        labels: np.ndarray | None,
        config: Any,
        intensity: np.ndarray | None = None,
    ) -> LabeledScan:
        """
        Label ``points`` (N, 3): the field ``labels`` (N,) or None, by ``config.label_source``.

        ``config`` is a :class:`~mlsemreg_ros.core.config.RegistrationConfig`;
        ``intensity`` (N,) feeds the ONNX network (None: zeros). Raises
        :class:`~mlsemreg_ros.core.matching.labels.LabelError` for ``field`` without a
        label field, RuntimeError when ``onnx`` cannot run.
        """
        source = resolve(getattr(config, 'label_source', 'auto'), labels is not None)
        points = np.asarray(points)
        if source == 'field':
            if labels is None:
                raise LabelError(
                    'label_source field, but the cloud has no label field (set label_source '
                    'auto or geometric, or label_field)'
                )
            return LabeledScan(labels, 'field', 0.0)
        start = time.perf_counter()
        count = points.shape[0] if points.ndim == 2 else 0
        if source == 'none':
            ids = np.zeros(count, dtype=np.uint32)
        elif source == 'geometric':
            ids = self._to_scheme(self._geometric_raw(points, config), config)
        else:
            ids = self._to_scheme(self._onnx_raw(points, intensity, config), config)
        return LabeledScan(ids, source, 1e3 * (time.perf_counter() - start))

    def when_read(
        self,
        points: np.ndarray,
        labels: np.ndarray | None,
        config: Any,
        intensity: np.ndarray | None = None,
    ) -> LabeledScan:
        """
        :meth:`__call__`, with geometric labels made when first read (``label_timing: read``).

        The odometry's choice: the fine alignment that tracks most scans reads no labels,
        and the geometric labeler costs about a third of a sparse sensor's scan
        (docs/labels.md). Labels that can filter points before the alignment
        (``moving_objects.map_filter: movable``) and the other sources are made at once.
        """
        source = resolve(getattr(config, 'label_source', 'auto'), labels is not None)
        if (
            source != 'geometric'
            or getattr(config, 'label_timing', 'scan') != 'read'
            or config.moving_objects.map_filter == 'movable'
        ):
            return self(points, labels, config, intensity)
        points = np.asarray(points)
        state: dict[str, Any] = {}

        def make() -> np.ndarray:
            made = self(points, None, config)
            state['labeling_ms'] = made.labeling_ms
            for timings in state.pop('noted', []):
                timings['labeling_ms'] = made.labeling_ms
            return made.labels

        return LabeledScan(Deferred(make), source, 0.0, state)

    # ------------------------------------------------------------------------------
    def _to_scheme(self, raw: np.ndarray, config: Any) -> np.ndarray:
        """Raw ids -> learning ids, unless the configured scheme is ``raw``."""
        if config.semantic.label_scheme == 'raw':
            return raw.astype(np.uint32)
        return self.label_map.raw_lut[raw.astype(np.int64) & 0xFFFF].astype(np.uint32)

    def labeler(self, config: Any) -> GeometricLabeler:
        """Return the geometric labeler of ``config.geometric_labels`` (rebuilt on change)."""
        section = config.geometric_labels
        if self._geometric is None or self._geometric[0] != section:
            self._geometric = (section, GeometricLabeler(section))
        return self._geometric[1]

    def _geometric_raw(self, points: np.ndarray, config: Any) -> np.ndarray:
        """Raw ids of every point: the labels of its voxel's centroid."""
        raw = np.zeros(points.shape[0] if points.ndim == 2 else 0, dtype=np.uint32)
        if raw.shape[0] == 0:
            return raw
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        # a whole-array test first: the per-row test and the copy cost 2 ms on 125k points
        finite = slice(None) if np.isfinite(points).all() else np.isfinite(points).all(axis=1)
        usable = points[finite]
        voxel = config.features.voxel_size or DEFAULT_LABEL_VOXEL
        grid = kernels.voxel_grid(usable, voxel)
        labeler = self.labeler(config)
        if grid is None:  # keys beyond int64: label the points themselves
            raw[finite] = labeler.label(usable).raw
            return raw
        inverse, sums, sizes = grid
        centroids = sums / sizes[:, None]
        raw[finite] = labeler.label(centroids).raw[inverse]
        return raw

    def _onnx_raw(
        self, points: np.ndarray, intensity: np.ndarray | None, config: Any
    ) -> np.ndarray:
        """Raw ids of every point from the user's network (lazily built)."""
        reason = onnx_unavailable()
        if reason:
            raise RuntimeError(reason)
        if self._onnx is None or self._onnx[0] != config:
            module = __import__(ONNX_MODULE, fromlist=['OnnxSegmenter'])
            self._onnx = (config, module.OnnxSegmenter.from_config(config))
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        raw = np.zeros(points.shape[0], dtype=np.uint32)
        finite = np.isfinite(points).all(axis=1)
        values = None if intensity is None else np.asarray(intensity)[finite]
        raw[finite] = np.asarray(self._onnx[1].labels(points[finite], values)).astype(np.uint32)
        return raw
