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
"""Geometric labels made when first read (``label_timing: read``, core/deferred.py)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import pickle
import threading

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.deferred import Deferred, deferred_attribute, stored
from mlsemreg_ros.core.labeling.source import LabelSource
from mlsemreg_ros.core.odometry import Odometry
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.datasets.factory import open_scan_source
from mlsemreg_ros.tools import simulate
import numpy as np
import pytest


@dataclass
class _Holder:
    name: str
    values: np.ndarray | None = None


deferred_attribute(_Holder, 'values')


def test_a_deferred_value_is_computed_once_on_first_read() -> None:
    calls = []

    def compute() -> np.ndarray:
        calls.append(1)
        return np.arange(3)

    holder = _Holder('a', Deferred(compute))
    assert isinstance(stored(holder, 'values'), Deferred) and not calls
    copy = _Holder('b', stored(holder, 'values'))  # handed on unread
    assert not calls
    np.testing.assert_array_equal(holder.values, [0, 1, 2])
    np.testing.assert_array_equal(copy.values, [0, 1, 2])
    assert len(calls) == 1
    assert isinstance(stored(holder, 'values'), np.ndarray)  # kept once read
    assert _Holder('c').values is None and stored(_Holder('c'), 'values') is None


def test_threads_reading_at_once_compute_once() -> None:
    calls, gate = [], threading.Barrier(4)

    def compute() -> int:
        calls.append(1)
        return 7

    value = Deferred(compute)
    results = []

    def read() -> None:
        gate.wait()
        results.append(value.get())

    workers = [threading.Thread(target=read) for _ in range(4)]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join()
    assert results == [7] * 4 and len(calls) == 1


def test_a_failed_computation_raises_again_on_the_next_read() -> None:
    attempts = []

    def compute() -> int:
        attempts.append(1)
        if len(attempts) == 1:
            raise ValueError('first read fails')
        return 3

    value = Deferred(compute)
    with pytest.raises(ValueError, match='first read fails'):
        value.get()
    assert not value.ready
    assert value.get() == 3 and value.get() == 3 and len(attempts) == 2


def test_a_pickled_holder_carries_the_value() -> None:
    holder = _Holder('a', Deferred(lambda: np.ones(2)))
    again = pickle.loads(pickle.dumps(holder))
    np.testing.assert_array_equal(again.values, [1.0, 1.0])


@pytest.mark.parametrize('voxel_size', [0.3, 0.0])
def test_a_scan_prepared_before_its_labels_equals_one_prepared_with_them(
    voxel_size: float,
) -> None:
    rng = np.random.default_rng(3)
    points = rng.uniform(-20.0, 20.0, (3000, 3))
    points[5] = np.nan  # dropped by the input hygiene
    points[7] = [500.0, 0.0, 0.0]  # beyond features.max_range
    labels = rng.integers(0, 20, 3000).astype(np.uint32)
    config = RegistrationConfig().replace({'features.voxel_size': voxel_size})
    registration = Registration(config)
    eager = registration.prepare(points, labels, lazy=True)
    read = Deferred(lambda: labels)
    late = registration.prepare(points, read, lazy=True)
    assert not read.ready  # points, voxels and keypoints without the labels
    np.testing.assert_array_equal(late.points, eager.points)
    np.testing.assert_array_equal(late.keypoints, eager.keypoints)
    assert late.labels.dtype == eager.labels.dtype
    np.testing.assert_array_equal(late.labels, eager.labels)
    assert late.input_stats == eager.input_stats


def test_only_a_global_registration_reads_the_geometric_labels(tmp_path: Path) -> None:
    drive = tmp_path / 'vlp16'
    arguments = [str(drive), '--realism', 'field', '--frames', '12', '--seed', '5']
    assert simulate.main([*arguments, '--sensor', 'vlp16', '--quiet']) == 0
    source = open_scan_source(str(drive))
    scans = list(source.scans(1, 12))
    source.close()
    poses, made = {}, {}
    for timing in ('scan', 'read'):
        config = RegistrationConfig().replace(
            {'label_source': 'geometric', 'label_timing': timing}
        )
        odometry = Odometry(config=config)
        calls: list[int] = []
        odometry.label_source = _Counting(odometry.label_source, calls)
        steps = [
            odometry.process(s.xyz, None, s.stamp_ns, point_times=s.point_times) for s in scans
        ]
        poses[timing] = np.array([s.pose for s in steps])
        made[timing] = len(calls)
        global_path = sum('global' in s.source for s in steps)
        if timing == 'read':
            assert made[timing] <= 2 * global_path + 1, (made, global_path)
            made_ms = [s.timings_ms.get('prepare.labeling_ms', 0.0) for s in steps]
            tracked = [m for m, s in zip(made_ms, steps, strict=True) if s.source == 'prediction']
            assert tracked and not any(tracked)  # nothing read them: not made, no time
            if global_path:  # made inside the global registration: its time is reported
                found = [m for m, s in zip(made_ms, steps, strict=True) if 'global' in s.source]
                assert any(m > 0 for m in found), found
            step = steps[-1]
            labels = step.labels  # read now: the same labels as made at once
            assert labels is not None and labels.shape[0] == step.points.shape[0]
    assert made['scan'] == len(scans)
    np.testing.assert_array_equal(poses['read'], poses['scan'])


class _Counting:
    """A label source that counts the labelings it makes."""

    def __init__(self, source: LabelSource, calls: list[int]) -> None:
        self.source, self.calls = source, calls

    def __call__(self, *args, **kwargs):
        self.calls.append(1)
        return self.source(*args, **kwargs)

    def when_read(self, points, labels, config, intensity=None):
        made = self.source.when_read(points, labels, config, intensity)
        if isinstance(made.labels, Deferred):
            return type(made)(made.labels.then(self._count), made.source, 0.0, made.made)
        self.calls.append(1)
        return made

    def _count(self, labels: np.ndarray) -> np.ndarray:
        self.calls.append(1)
        return labels
