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

"""The local map's Gaussians read on the pool after an insertion: the same arrays, never stale."""

from __future__ import annotations

from collections.abc import Iterator

from mlsemreg_ros.core import threads
from mlsemreg_ros.core.alignment.alignment import AlignmentCloud
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry.local_map import make_map, voxel_gaussians
import numpy as np
import pytest


@pytest.fixture
def two_workers() -> Iterator[None]:
    """Two pool workers (the prefetch runs), whatever the machine has."""
    before = threads.workers()
    threads.configure(2)
    yield
    threads.configure(before)


def _cloud(seed: int) -> AlignmentCloud:
    rng = np.random.default_rng(seed)
    points = rng.uniform(-20.0, 20.0, (3000, 3)) * np.array([1.0, 1.0, 0.1])
    return AlignmentCloud.build(points, 0.5, 10)


def _same(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> bool:
    return all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


def test_prefetch_equals_a_fresh_read(two_workers: None) -> None:
    """After each insertion the prefetched Gaussians are the map's own."""
    local_map = make_map(RegistrationConfig())
    for seed in range(3):
        T = np.eye(4)
        T[0, 3] = float(seed)
        local_map.insert(_cloud(seed), T)
        assert local_map._prefetch is not None  # the prefetch started
        assert _same(local_map.gaussians(), voxel_gaussians(local_map._map))


def test_prefetch_of_a_cleared_map_is_dropped(two_workers: None) -> None:
    """A prefetch of the map before a clear is not returned for the new map."""
    local_map = make_map(RegistrationConfig())
    local_map.insert(_cloud(0), np.eye(4))
    local_map.clear()
    assert local_map.gaussians() is None  # empty: nothing, not the old map's
    local_map.insert(_cloud(1), np.eye(4))
    assert _same(local_map.gaussians(), voxel_gaussians(local_map._map))


def test_one_worker_reads_inline() -> None:
    """With one worker nothing is submitted; the Gaussians are read when asked."""
    before = threads.workers()
    threads.configure(1)
    try:
        assert threads.LazyPool('test-submit').submit(lambda: 1) is None
        local_map = make_map(RegistrationConfig())
        local_map.insert(_cloud(0), np.eye(4))
        assert local_map._prefetch is None
        assert _same(local_map.gaussians(), voxel_gaussians(local_map._map))
    finally:
        threads.configure(before)
