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
The nearest point of a set within a fixed radius, through cells of that radius (numba).

Two kinds of caller ask this one question, the nearest point of a set within ``r``, if any:

- the dense scores of the verification, the covisible overlap and the polishing
  (``core/estimation/nearest_grid.py``): hundreds of thousands of moved source points
  against one target scan, whose cells are built once per (scan, radius) and cached;
- the sweep alignment (``core/alignment/sweep_alignment.py``): a thousand sweep points, five
  to ten times, against the local map's voxel means, which change with every accepted scan,
  so its cells are built again for every scan.

With cells of edge ``r`` the answer lies in the 27 cells around the point. The points are
sorted by ``(x, y)`` column and by height cell within a column, keeping only the cells
between a column's lowest and highest point, so the three cells of a column that a query
reads are one contiguous run of points. A dense grid of the whole box (the earlier
``nearest_grid``) queried as fast but cost 1.5-3 ms to build for a 12k-voxel local map or a
scan with a few far points; a hash of single points (the earlier ``CellIndex`` of the sweep
alignment) built fast but queried 2.5-3 times slower on the dense scores
(docs/sensors.md#one-fixed-radius-search).

:meth:`CellGrid.nearest` returns what ``cKDTree.query(points, distance_upper_bound=r)``
returns (``inf`` and the point count where nothing lies within ``r``), up to rounding at
``r`` itself; between equidistant points the lowest row wins.
"""

from __future__ import annotations

from typing import NamedTuple

from mlsemreg_ros.core.features.kernels import jit
import numpy as np

#: Largest box in columns (8 bytes each, twice); a larger one is not usable (use a KD-tree).
MAX_COLUMNS = 4_000_000


@jit
def _build(
    points: np.ndarray, cell: float, max_columns: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """
    Sort ``points`` into cells: by ``(x, y)`` column, by height cell within a column.

    Only the cells between a column's lowest and highest point are kept (its span): the
    cells of column ``c`` are ``base[c]`` to ``base[c + 1] - 1``, the lowest being height
    cell ``bottom[c]``, and the points of cell ``f`` are
    ``sorted_points[starts[f]:starts[f + 1]]`` in their original row order (``order``).
    Returns ``(low (3,), extent (2,), bottom, base, starts, sorted points, order)``;
    ``base`` is empty when the box holds more than ``max_columns`` columns or a point is
    not finite.
    """
    count = points.shape[0]
    low = np.zeros(3, dtype=np.int64)
    extent = np.zeros(2, dtype=np.int64)
    empty = np.zeros(0, dtype=np.int64)
    nothing = (low, extent, empty, empty, empty, np.zeros((0, 3)), empty)
    if count == 0:
        return nothing
    for j in range(count):
        x, y, z = points[j, 0], points[j, 1], points[j, 2]
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            return nothing
    for a in range(3):
        low[a] = np.int64(np.floor(points[:, a].min() / cell))
    for a in range(2):
        extent[a] = np.int64(np.floor(points[:, a].max() / cell)) - low[a] + 1
    columns = extent[0] * extent[1]
    if columns > max_columns:
        return nothing
    column = np.empty(count, dtype=np.int64)
    height = np.empty(count, dtype=np.int64)
    bottom = np.full(columns, np.iinfo(np.int64).max, dtype=np.int64)
    top = np.full(columns, -1, dtype=np.int64)
    for j in range(count):
        cx = np.int64(np.floor(points[j, 0] / cell)) - low[0]
        cy = np.int64(np.floor(points[j, 1] / cell)) - low[1]
        column[j] = cx * extent[1] + cy
        height[j] = np.int64(np.floor(points[j, 2] / cell)) - low[2]
        bottom[column[j]] = min(bottom[column[j]], height[j])
        top[column[j]] = max(top[column[j]], height[j])
    base = np.zeros(columns + 1, dtype=np.int64)
    for c in range(columns):
        base[c + 1] = base[c] + (top[c] - bottom[c] + 1 if top[c] >= 0 else 0)
    starts = np.zeros(base[columns] + 1, dtype=np.int64)
    flat = np.empty(count, dtype=np.int64)
    for j in range(count):
        flat[j] = base[column[j]] + height[j] - bottom[column[j]]
        starts[flat[j] + 1] += 1
    for f in range(base[columns]):
        starts[f + 1] += starts[f]
    fill = starts[: base[columns]].copy()
    sorted_points = np.empty((count, 3))
    order = np.empty(count, dtype=np.int64)
    for j in range(count):
        k = fill[flat[j]]
        fill[flat[j]] = k + 1
        sorted_points[k, 0] = points[j, 0]
        sorted_points[k, 1] = points[j, 1]
        sorted_points[k, 2] = points[j, 2]
        order[k] = j
    return low, extent, bottom, base, starts, sorted_points, order


@jit
def column_run(grid: CellGrid, c: int, cz: int, reach: int) -> tuple[int, int]:
    """
    Return the sorted rows ``first:last`` of column ``c``'s cells ``cz - reach .. cz + reach``.

    The cells of a column within a height span are one contiguous run of sorted points;
    ``first >= last`` when the column holds none of them.
    """
    bottom, base, starts = grid[3], grid[4], grid[5]
    lowest = max(cz - reach, bottom[c])
    highest = min(cz + reach, bottom[c] + base[c + 1] - base[c] - 1)
    if highest < lowest:
        return 0, 0
    return starts[base[c] + lowest - bottom[c]], starts[base[c] + highest - bottom[c] + 1]


@jit
def _nearest_squared(
    queries: np.ndarray, radius: float, grid: CellGrid, first_only: bool
) -> tuple[np.ndarray, np.ndarray]:
    """
    Squared distance (``inf`` if none) and row (-1 if none) of the nearest point within ``radius``.

    ``first_only``: stop at the first point within ``radius`` (an answer to "is there one").
    """
    cell, low, extent, sorted_points, order = grid[0], grid[1], grid[2], grid[6], grid[7]
    count = queries.shape[0]
    squared = np.full(count, np.inf)
    nearest = np.full(count, -1, dtype=np.int64)
    reach = np.int64(np.ceil(radius / cell))
    limit = radius * radius
    for i in range(count):
        x, y, z = queries[i, 0], queries[i, 1], queries[i, 2]
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            continue
        fx, fy, fz = np.floor(x / cell), np.floor(y / cell), np.floor(z / cell)
        if fx < low[0] - reach or fx > low[0] + extent[0] + reach:
            continue
        if fy < low[1] - reach or fy > low[1] + extent[1] + reach:
            continue
        cx, cy = np.int64(fx) - low[0], np.int64(fy) - low[1]
        cz = np.int64(max(min(fz - low[2], 2.0**40), -(2.0**40)))
        best, best_j = limit, np.int64(-1)
        done = False
        for ix in range(max(cx - reach, 0), min(cx + reach + 1, extent[0])):
            for iy in range(max(cy - reach, 0), min(cy + reach + 1, extent[1])):
                first, last = column_run(grid, ix * extent[1] + iy, cz, reach)
                for k in range(first, last):
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
            squared[i] = best
            nearest[i] = best_j
    return squared, nearest


class CellGrid(NamedTuple):
    """
    The points of one set in cells of one edge (``build``), and the search in them.

    A named tuple, so that the compiled kernels take the whole grid as one argument
    (numba passes a tuple of arrays as it passes the arrays one by one).
    """

    cell: float
    low: np.ndarray  # (3,) int64 cell of the box's lower corner
    extent: np.ndarray  # (2,) int64 columns of the box in x and y
    bottom: np.ndarray  # (columns,) lowest occupied height cell of each column
    base: np.ndarray  # (columns + 1,) first kept cell of each column (empty: unusable)
    starts: np.ndarray  # (cells + 1,) first sorted row of each kept cell
    sorted_points: np.ndarray  # (M, 3) points in cell order
    order: np.ndarray  # (M,) original row of each sorted point

    @classmethod
    def build(cls, points: np.ndarray, cell: float) -> CellGrid:
        """Sort ``(M, 3)`` points into cells of edge ``cell`` > 0 (metres)."""
        points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        return cls(float(cell), *_build(points, float(cell), MAX_COLUMNS))

    @property
    def usable(self) -> bool:
        """Whether the points are finite and their box fits :data:`MAX_COLUMNS` columns."""
        return self.base.size > 0

    @property
    def size(self) -> int:
        """Points."""
        return len(self.order)

    def nearest_squared(
        self, queries: np.ndarray, radius: float, first_only: bool = False
    ) -> tuple[np.ndarray, np.ndarray]:
        """
        ``(squared distance (Q,), row (Q,))`` of the nearest point within ``radius``.

        ``inf`` and -1 where none lies within ``radius``.
        """
        queries = np.ascontiguousarray(queries, dtype=np.float64).reshape(-1, 3)
        return _nearest_squared(queries, float(radius), self, first_only)

    def nearest(
        self, queries: np.ndarray, radius: float, first_only: bool = False
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(distance (Q,), row (Q,))`` as ``cKDTree.query(..., distance_upper_bound=r)``."""
        squared, rows = self.nearest_squared(queries, radius, first_only)
        rows[rows < 0] = len(self.order)
        return np.sqrt(squared), rows
