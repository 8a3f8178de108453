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
The nearest scan point within a fixed radius, through a hash of radius-sized cells (numba).

The dense scores of the verification (core/estimation/verification.py), the covisible
overlap (core/estimation/covisibility.py) and the polishing (core/estimation/polish.py)
ask one question of a target scan for hundreds of thousands of moved source points: the
nearest target point within ``r``, if any. A KD-tree answers it with a descent per point;
with cells of side ``r`` the answer lies in the 27 cells around the point, and the cells
of one ``(x, y)`` column are contiguous in the sorted points, so a compiled loop over nine
runs of points answers it without a tree descent.

:func:`nearest_within` returns what ``cKDTree.query(points, distance_upper_bound=r)``
returns (``inf`` and the point count where nothing lies within ``r``), up to rounding at
``r`` itself and between equidistant points. The grids are built once per (scan, radius)
and kept in a small cache (:func:`grid_of`). Without numba, with
``MLSEMREG_KERNELS=numpy`` (``core/features/kernels.py``), or for a scan whose bounding
box holds more than :data:`MAX_CELLS` cells, the KD-tree answers.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
import threading

from mlsemreg_ros.core import threads
from mlsemreg_ros.core.features import kernels as compiled
from mlsemreg_ros.core.features.kernels import jit
import numpy as np
from scipy.spatial import cKDTree

#: Largest bounding box in cells (an index of 8 bytes per cell); larger: the KD-tree.
MAX_CELLS = 4_000_000
#: Grids kept (scan, radius): a pair needs a few; a relocalization visits many keyframes.
_CACHE_SIZE = 16


@jit
def _build(
    points: np.ndarray, cell: float, max_cells: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """
    Sort ``points`` by cell; ``starts`` of every cell of the bounding box (empty if too many).

    Returns ``(low (3,) int64, extent (3,) int64, starts (cells + 1,), sorted points,
    order)``: the points of cell ``c`` are ``sorted_points[starts[c]:starts[c + 1]]``.
    """
    count = points.shape[0]
    low = np.empty(3, dtype=np.int64)
    extent = np.empty(3, dtype=np.int64)
    for a in range(3):
        low[a] = np.int64(np.floor(points[:, a].min() / cell))
        extent[a] = np.int64(np.floor(points[:, a].max() / cell)) - low[a] + 1
    cells = extent[0] * extent[1] * extent[2]
    if cells > max_cells:
        return low, extent, np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros(0, np.int64)
    keys = np.empty(count, dtype=np.int64)
    for j in range(count):
        cx = np.int64(np.floor(points[j, 0] / cell)) - low[0]
        cy = np.int64(np.floor(points[j, 1] / cell)) - low[1]
        cz = np.int64(np.floor(points[j, 2] / cell)) - low[2]
        keys[j] = (cx * extent[1] + cy) * extent[2] + cz
    order = np.argsort(keys, kind='mergesort')
    starts = np.zeros(cells + 1, dtype=np.int64)
    for j in range(count):
        starts[keys[j] + 1] += 1
    for c in range(cells):
        starts[c + 1] += starts[c]
    sorted_points = np.empty((count, 3))
    for j in range(count):
        sorted_points[j] = points[order[j]]
    return low, extent, starts, sorted_points, order


@jit
def _nearest(
    queries: np.ndarray,
    radius: float,
    cell: float,
    low: np.ndarray,
    extent: np.ndarray,
    starts: np.ndarray,
    sorted_points: np.ndarray,
    order: np.ndarray,
    first_only: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """
    Distance (``inf`` if none) and row of the nearest point within ``radius`` of each query.

    ``first_only``: stop at the first point within ``radius`` (its distance and row: an
    answer to "is there one", not the nearest).
    """
    count = queries.shape[0]
    distance = np.full(count, np.inf)
    nearest = np.full(count, order.shape[0], dtype=np.int64)
    reach = np.int64(np.ceil(radius / cell))
    limit = radius * radius
    for i in range(count):
        x, y, z = queries[i, 0], queries[i, 1], queries[i, 2]
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            continue
        cx = np.int64(np.floor(x / cell)) - low[0]
        cy = np.int64(np.floor(y / cell)) - low[1]
        cz = np.int64(np.floor(z / cell)) - low[2]
        if (
            cx < -reach
            or cy < -reach
            or cz < -reach
            or cx >= extent[0] + reach
            or cy >= extent[1] + reach
            or cz >= extent[2] + reach
        ):
            continue
        best, best_j = limit, -1
        done = False
        for ix in range(max(cx - reach, 0), min(cx + reach + 1, extent[0])):
            for iy in range(max(cy - reach, 0), min(cy + reach + 1, extent[1])):
                base = (ix * extent[1] + iy) * extent[2]
                z_first = base + max(cz - reach, 0)
                z_last = base + min(cz + reach + 1, extent[2])
                if z_last <= z_first:
                    continue
                for k in range(starts[z_first], starts[z_last]):
                    d2 = (
                        (x - sorted_points[k, 0]) ** 2
                        + (y - sorted_points[k, 1]) ** 2
                        + (z - sorted_points[k, 2]) ** 2
                    )
                    if d2 < best or (d2 == best and (best_j < 0 or order[k] < best_j)):
                        best, best_j = d2, order[k]
                        if first_only:
                            done = True
                            break
                if done:
                    break
            if done:
                break
        if best_j >= 0:
            distance[i] = np.sqrt(best)
            nearest[i] = best_j
    return distance, nearest


@dataclass(frozen=True)
class NearestGrid:
    """The cells of one scan for one radius (:func:`grid_of`)."""

    cell: float
    low: np.ndarray  # (3,) int64 cell of the bounding box's lower corner
    extent: np.ndarray  # (3,) int64 cells of the bounding box per axis
    starts: np.ndarray  # (cells + 1,) first sorted row of each cell (empty: too many cells)
    sorted_points: np.ndarray  # (M, 3) points in cell order
    order: np.ndarray  # (M,) original row of each sorted point

    @classmethod
    def build(cls, points: np.ndarray, cell: float) -> NearestGrid:
        """Sort ``(M, 3)`` points into cells of side ``cell`` (:data:`MAX_CELLS` at most)."""
        points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        return cls(cell, *_build(points, float(cell), MAX_CELLS))

    @property
    def usable(self) -> bool:
        """Whether the bounding box fitted in :data:`MAX_CELLS` cells."""
        return self.starts.size > 0

    def nearest(
        self, queries: np.ndarray, radius: float, first_only: bool = False
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(distance (Q,), row (Q,))`` as ``cKDTree.query(..., distance_upper_bound=r)``."""
        queries = np.ascontiguousarray(queries, dtype=np.float64).reshape(-1, 3)
        return _nearest(
            queries,
            float(radius),
            self.cell,
            self.low,
            self.extent,
            self.starts,
            self.sorted_points,
            self.order,
            first_only,
        )


_cache: OrderedDict[tuple[int, float], tuple[cKDTree, NearestGrid]] = OrderedDict()
_lock = threading.Lock()


def grid_of(tree: cKDTree, radius: float) -> NearestGrid:
    """Return the grid of ``tree``'s points, cells of side ``radius`` (built once, cached)."""
    key = (id(tree), float(radius))
    with _lock:
        kept = _cache.get(key)
        if kept is not None and kept[0] is tree:
            _cache.move_to_end(key)
            return kept[1]
    grid = NearestGrid.build(tree.data, radius)
    with _lock:
        _cache[key] = (tree, grid)  # the tree is held: its id is not reused while cached
        while len(_cache) > _CACHE_SIZE:
            _cache.popitem(last=False)
    return grid


def nearest_within(
    tree: cKDTree, queries: np.ndarray, radius: float, first_only: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """
    ``tree.query(queries, distance_upper_bound=radius)``: the nearest point within ``radius``.

    ``queries`` ``(Q, 3)``; returns ``(distance (Q,), row (Q,))``, ``inf`` and
    ``tree.n`` where no point lies within ``radius``. ``first_only``: any point within
    ``radius`` will do (whether there is one is exact; which one is not the nearest).
    Compiled cells when the kernels are enabled and the scan's box fits
    :data:`MAX_CELLS`, else the KD-tree.
    """
    if compiled.enabled() and tree.n > 0 and tree.m == 3:
        grid = grid_of(tree, radius)
        if grid.usable:
            return grid.nearest(queries, radius, first_only)
    return tree.query(
        np.reshape(queries, (-1, tree.m)), distance_upper_bound=radius, workers=threads.workers()
    )
