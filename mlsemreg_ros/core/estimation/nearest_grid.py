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
The nearest scan point within a fixed radius, for the dense scores (compiled cells, cached).

The dense scores of the verification (core/estimation/verification.py), the covisible
overlap (core/estimation/covisibility.py) and the polishing (core/estimation/polish.py)
ask one question of a target scan for hundreds of thousands of moved source points: the
nearest target point within ``r``, if any. The compiled cells of
``core/features/cell_grid.py`` (the search the sweep alignment uses too) answer it without
a tree descent; they are built once per (scan, radius) and kept in a small cache
(:func:`grid_of`).

:func:`nearest_within` returns what ``cKDTree.query(points, distance_upper_bound=r)``
returns (``inf`` and the point count where nothing lies within ``r``), up to rounding at
``r`` itself and between equidistant points. Without numba, with
``MLSEMREG_KERNELS=numpy`` (``core/features/kernels.py``), or for a scan that the cells
cannot hold (a point not finite, a box over ``cell_grid.MAX_COLUMNS`` columns), the
KD-tree answers.
"""

from __future__ import annotations

from collections import OrderedDict
import threading

from mlsemreg_ros.core import threads
from mlsemreg_ros.core.features import kernels as compiled
from mlsemreg_ros.core.features.cell_grid import CellGrid
import numpy as np
from scipy.spatial import cKDTree

#: Grids kept (scan, radius): a pair needs a few; a relocalization visits many keyframes.
_CACHE_SIZE = 16


_cache: OrderedDict[tuple[int, float], tuple[cKDTree, CellGrid]] = OrderedDict()
_lock = threading.Lock()


def grid_of(tree: cKDTree, radius: float) -> CellGrid:
    """Return the grid of ``tree``'s points, cells of side ``radius`` (built once, cached)."""
    key = (id(tree), float(radius))
    with _lock:
        kept = _cache.get(key)
        if kept is not None and kept[0] is tree:
            _cache.move_to_end(key)
            return kept[1]
    grid = CellGrid.build(tree.data, radius)
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
    Compiled cells when the kernels are enabled and the cells can hold the scan, else the
    KD-tree.
    """
    if compiled.enabled() and tree.n > 0 and tree.m == 3:
        grid = grid_of(tree, radius)
        if grid.usable:
            return grid.nearest(queries, radius, first_only)
    return tree.query(
        np.reshape(queries, (-1, tree.m)), distance_upper_bound=radius, workers=threads.workers()
    )
