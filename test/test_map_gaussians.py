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

"""The local map's Gaussians: read when first asked after a change, the map's own, never stale."""

from __future__ import annotations

from mlsemreg_ros.core.alignment.alignment import AlignmentCloud
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry.local_map import make_map, voxel_gaussians
import numpy as np


def _cloud(seed: int) -> AlignmentCloud:
    rng = np.random.default_rng(seed)
    points = rng.uniform(-20.0, 20.0, (3000, 3)) * np.array([1.0, 1.0, 0.1])
    return AlignmentCloud.build(points, 0.5, 10)


def _same(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> bool:
    return all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


def test_the_gaussians_follow_every_insertion_and_are_read_once() -> None:
    """After each insertion they are the map's own; asked twice, the same arrays."""
    local_map = make_map(RegistrationConfig())
    for seed in range(3):
        T = np.eye(4)
        T[0, 3] = float(seed)
        local_map.insert(_cloud(seed), T)
        first = local_map.gaussians()
        assert _same(first, voxel_gaussians(local_map._map))
        assert local_map.gaussians() is first  # not copied again until the map changes


def test_a_cleared_map_has_none_then_the_new_maps_own() -> None:
    local_map = make_map(RegistrationConfig())
    local_map.insert(_cloud(0), np.eye(4))
    old = local_map.gaussians()
    local_map.clear()
    assert local_map.gaussians() is None  # empty: nothing, not the old map's
    local_map.insert(_cloud(1), np.eye(4))
    new = local_map.gaussians()
    assert _same(new, voxel_gaussians(local_map._map))
    assert not _same(new, old)


def test_an_insertion_does_not_copy_the_gaussians(monkeypatch) -> None:
    """They are read when asked, not after every insertion (most steady scans never ask)."""
    from mlsemreg_ros.core import threads
    from mlsemreg_ros.core.odometry import local_map as module

    calls = []
    original = module.voxel_gaussians
    monkeypatch.setattr(module, 'voxel_gaussians', lambda v: calls.append(1) or original(v))
    before = threads.workers()
    threads.configure(2)  # a pool to copy on, were the map to prefetch
    try:
        local_map = make_map(RegistrationConfig())
        for seed in range(3):
            local_map.insert(_cloud(seed), np.eye(4))
        assert calls == []
        local_map.gaussians()
        local_map.gaussians()
        assert calls == [1]
    finally:
        threads.configure(before)


def test_a_prefetch_reads_the_same_gaussians_and_an_insertion_waits_for_it() -> None:
    """The read started on a second thread gives the arrays a read on demand gives."""
    from mlsemreg_ros.core import threads

    before = threads.workers()
    threads.configure(2)
    try:
        local_map = make_map(RegistrationConfig())
        for seed in range(3):
            local_map.insert(_cloud(seed), np.eye(4))
        seen = []
        assert local_map.prefetch(seen.append)
        local_map.insert(_cloud(3), np.eye(4))  # waits for the read, then changes the map
        assert len(seen) == 1 and seen[0] is not None
        assert not _same(seen[0], local_map.gaussians())  # the insertion is in the new ones
        assert local_map.prefetch(seen.append)
        prefetched = local_map.gaussians()  # waits for the read and returns its arrays
        assert seen[1] is prefetched
        assert _same(prefetched, voxel_gaussians(local_map._map))
        threads.configure(1)
        assert not local_map.prefetch(seen.append)  # one worker: read on demand
    finally:
        threads.configure(before)


def test_the_tracker_prefetches_the_next_sweep_alignments_cells_only_where_it_will_ask() -> None:
    """A scan deskewed by a twist: the Gaussians and cells the next scan's alignment reads."""
    from types import SimpleNamespace

    from mlsemreg_ros.core import threads
    from mlsemreg_ros.core.features.deskew import SweepMotion
    from mlsemreg_ros.core.odometry.tracking import Tracker

    config = RegistrationConfig()
    before = threads.workers()
    threads.configure(2)
    try:
        tracker = Tracker(make_map(config))
        for seed in range(3):
            tracker.map.insert(_cloud(seed), np.eye(4))
        twisted = SimpleNamespace(motion=SweepMotion(np.zeros(3), np.array([5.0, 0.0, 0.0])))
        assert not tracker.prefetch_gaussians(SimpleNamespace(motion=None), config)
        assert tracker.prefetch_gaussians(twisted, config)
        prepared = tracker.map_gaussians()  # waits for the prefetch: its cells are built
        assert prepared._cells is not None
        assert _same((prepared.means, prepared.covariances), voxel_gaussians(tracker.map._map))
        threads.configure(1)
        assert not tracker.prefetch_gaussians(twisted, config)
    finally:
        threads.configure(before)
