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

"""The compiled fixed-radius search and BEV maxima give what the KD-tree and NumPy give."""

from __future__ import annotations

from dataclasses import replace

from hypothesis import given, settings
from hypothesis import strategies as st
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.estimation import bev_search, nearest_grid
from mlsemreg_ros.core.features import cell_grid, kernels
from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.rigid import apply_transform
from mlsemreg_ros.datasets.synthetic_scene import motion
import numpy as np
import pytest
from scipy.spatial import cKDTree

pytestmark = pytest.mark.skipif(not kernels.AVAILABLE, reason='numba is not installed')


def _cloud(seed: int, count: int) -> np.ndarray:
    """Make a street-like cloud: wide in x and y, flat in z, half on a 0.2 m lattice."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(-40, 40, (count, 3)) * [1.0, 1.0, 0.1]
    points[: count // 2] = np.round(points[: count // 2] / 0.2) * 0.2  # equal distances
    return points


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), radius=st.sampled_from([0.3, 0.6, 1.3, 2.0]))
def test_nearest_within_is_the_kd_tree_query(seed, radius):
    target = _cloud(seed, 3000)
    tree = cKDTree(target)
    rng = np.random.default_rng(seed + 1)
    queries = np.concatenate(
        [
            target[rng.integers(0, len(target), 500)] + rng.normal(0, radius, (500, 3)),
            rng.uniform(-60, 60, (500, 3)),  # many outside the box or far from any point
        ]
    )
    expected, expected_rows = tree.query(queries, distance_upper_bound=radius)
    found, rows = nearest_grid.nearest_within(tree, queries, radius)
    np.testing.assert_array_equal(np.isfinite(found), np.isfinite(expected))
    np.testing.assert_allclose(found, expected, rtol=0, atol=1e-12)
    hit = np.isfinite(expected)
    same = rows[hit] == expected_rows[hit]  # equidistant points may differ, not the distance
    assert np.all(same | np.isclose(found[hit], expected[hit], rtol=0, atol=1e-12))
    np.testing.assert_array_equal(rows[~hit], np.full(np.count_nonzero(~hit), tree.n))
    anything, _ = nearest_grid.nearest_within(tree, queries, radius, first_only=True)
    np.testing.assert_array_equal(np.isfinite(anything), hit)
    assert np.all(anything[hit] <= radius)
    broken = nearest_grid.nearest_within(tree, np.array([[np.nan, 0, 0], [np.inf, 1, 1]]), radius)
    np.testing.assert_array_equal(broken[0], [np.inf, np.inf])  # the tree raises instead


@pytest.mark.parametrize(('cell', 'radius'), [(1.0, 1.0), (0.5, 1.3), (1.0, 0.4)])
def test_cells_of_any_edge_answer_as_the_kd_tree(cell, radius):
    """Tall columns, a far point, a radius over or under the edge: the KD-tree's answers."""
    rng = np.random.default_rng(11)
    points = _cloud(11, 2000)
    pole = np.column_stack([np.full(300, 3.1), np.full(300, -2.2), np.linspace(-5, 25, 300)])
    points = np.vstack([points, pole, [[900.0, -700.0, 40.0]]])  # a far point: a wide box
    grid = cell_grid.CellGrid.build(points, cell)
    assert grid.usable and grid.size == len(points)
    queries = np.vstack(
        [
            points[rng.integers(0, len(points), 800)] + rng.normal(0, radius, (800, 3)),
            pole[::10] + np.array([0.3, 0.2, 0.0]),
            [[900.2, -700.0, 40.0], [-2000.0, 0.0, 0.0]],
        ]
    )
    expected, expected_rows = cKDTree(points).query(queries, distance_upper_bound=radius)
    found, rows = grid.nearest(queries, radius)
    np.testing.assert_allclose(found, expected, rtol=0, atol=1e-12)
    hit = np.isfinite(expected)
    assert 0 < np.count_nonzero(hit) < len(queries)
    same = rows[hit] == expected_rows[hit]
    assert np.all(same | np.isclose(found[hit], expected[hit], rtol=0, atol=1e-12))
    np.testing.assert_array_equal(rows[~hit], np.full(np.count_nonzero(~hit), len(points)))
    squared, rows_or_none = grid.nearest_squared(queries, radius)
    np.testing.assert_array_equal(rows_or_none[~hit], -1)
    np.testing.assert_allclose(squared[hit], expected[hit] ** 2, rtol=1e-12)


def test_a_box_too_large_for_the_cells_falls_back_to_the_tree(monkeypatch):
    target = np.array([[0.0, 0.0, 0.0], [5000.0, 5000.0, 100.0], [0.1, 0.0, 0.0]])
    tree = cKDTree(target)
    monkeypatch.setattr(cell_grid, 'MAX_COLUMNS', 1000)
    assert not cell_grid.CellGrid.build(target, 0.5).usable
    found, rows = nearest_grid.nearest_within(tree, np.array([[0.08, 0.0, 0.0]]), 0.5)
    assert rows[0] == 2 and found[0] == pytest.approx(0.02)


def test_the_kernels_switch_gives_the_tree(monkeypatch):
    tree = cKDTree(_cloud(3, 500))
    queries = _cloud(4, 200)
    monkeypatch.setenv(kernels.ENV_SWITCH, 'numpy')
    slow = nearest_grid.nearest_within(tree, queries, 0.6)
    monkeypatch.delenv(kernels.ENV_SWITCH)
    fast = nearest_grid.nearest_within(tree, queries, 0.6)
    np.testing.assert_array_equal(slow[0], fast[0])


@pytest.mark.parametrize('seed', [1, 5, 9])
def test_compiled_bev_maxima_are_the_numpy_maxima(seed, monkeypatch):
    """Peaks, their order and their ties: the same with the compiled maxima as with NumPy's."""
    labels_map = LabelMap.load()
    rng = np.random.default_rng(seed)
    points = rng.uniform(-40, 40, (3000, 3))
    points[:1500] = np.round(points[:1500])  # exact ties in the correlation
    labels = rng.choice([13, 15, 18], 3000).astype(np.int32)
    moved = apply_transform(np.linalg.inv(motion(17.0, (11.0, -6.0, 0.0))), points)
    lookup = bev_search.channel_lookup(labels_map, RegistrationConfig().bev_search)
    search = replace(RegistrationConfig().bev_search, max_translation=20.0, radius=30.0)
    grid = bev_search.BevGrid.make(search.cell_size, search.radius, search.max_translation)
    channel = bev_search._channels(labels, lookup)
    correlator = bev_search.Correlator(moved[:, :2], channel, points[:, :2], channel, grid, 3)
    yaws = np.arange(0.0, 360.0, 7.0)
    fast = correlator.peaks(yaws, 4)
    monkeypatch.setenv(kernels.ENV_SWITCH, 'numpy')
    slow = correlator.peaks(yaws, 4)
    np.testing.assert_array_equal(fast, slow)
    best = fast[np.argmax(fast[:, 0])]
    assert abs(best[2] - 11.0) <= 1.0 and abs(best[3] + 6.0) <= 1.0
