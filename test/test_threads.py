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
"""The shared thread pools, the concurrent scan preparation and its descriptor choice."""

import threading

from mlsemreg_ros.core import threads
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.features.features import fpfh_open3d_at, valid_descriptor_mask
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.threads import LazyPool
from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair
import numpy as np


def test_pool_keeps_order_and_runs_single_items_inline(monkeypatch):
    monkeypatch.setattr(threads, '_requested', 2)
    pool = LazyPool('mlsemreg-test')
    names: list[str] = []

    def square(x: int) -> int:
        names.append(threading.current_thread().name)
        return x * x

    assert pool.run(square, [3]) == [9]
    assert names == [threading.current_thread().name]  # one item: no pool
    assert pool.run(square, list(range(7))) == [x * x for x in range(7)]
    assert any(name.startswith('mlsemreg-test') for name in names[1:])


def test_every_pool_honours_the_thread_setting(monkeypatch):
    monkeypatch.setattr(threads, '_requested', 0)
    assert threads.workers() == threads.available_cores()
    pool = LazyPool('mlsemreg-test-size')
    for count in (1, 3):
        Registration(RegistrationConfig().replace({'threads': count}))  # configures the pools
        assert threads.workers() == count
        names: set[str] = set()
        barrier = threading.Barrier(count, timeout=5.0) if count > 1 else None

        def task(_: int, barrier: threading.Barrier | None = barrier) -> str:
            if barrier is not None:
                barrier.wait()  # all `count` workers run at once, or this times out
            return threading.current_thread().name

        names.update(pool.run(task, list(range(count))))
        assert len(names) == count
        if count == 1:
            assert names == {threading.current_thread().name}  # inline, no pool


def test_prepare_scans_equals_sequential_prepare():
    pair = synthetic_pair(3)
    registration = Registration()
    scans = [
        {'points': pair.pts_src, 'labels': pair.label_src},
        {'points': pair.pts_dst, 'labels': pair.label_dst},
    ]
    together = registration.prepare_scans(*scans)
    for scan, prepared in zip(scans, together, strict=True):
        alone = registration.prepare(**scan)
        for name in ('points', 'keypoints', 'descriptors', 'local_ss'):
            np.testing.assert_array_equal(getattr(prepared, name), getattr(alone, name))
        assert prepared.timings_ms.keys() == alone.timings_ms.keys()


def test_descriptor_choice_reaches_the_pipeline():
    pair = synthetic_pair(4)
    config = RegistrationConfig().replace({'features.descriptor': 'fpfh_open3d'})
    prepared = Registration(config).prepare(pair.pts_src, pair.label_src)
    f = config.features
    expected = fpfh_open3d_at(
        prepared.points,
        prepared.keypoint_indices,
        f.normal_radius,
        f.normal_max_nn,
        f.feature_radius,
        f.feature_max_nn,
    )
    np.testing.assert_array_equal(prepared.descriptors, expected[valid_descriptor_mask(expected)])
    ours = Registration().prepare(pair.pts_src, pair.label_src)
    assert not np.array_equal(ours.descriptors[:10], prepared.descriptors[:10])


def test_checking_a_config_changes_no_thread_count():
    """Registration.check validates class names without configuring the process's pools."""
    from mlsemreg_ros.core.config import ConfigError
    from mlsemreg_ros.core.matching.labels import LabelMap
    import pytest

    before = threads.workers()
    bad = RegistrationConfig().replace(
        {'threads': before + 1, 'semantic.landmark_classes': ['pole', 'lamppost']}
    )
    with pytest.raises(ConfigError, match='lamppost'):
        Registration.check(bad, LabelMap.load())
    with pytest.raises(ConfigError, match='lamppost'):
        Registration(bad)
    assert threads.workers() == before


def test_openmp_threads_wait_passively_before_small_gicp_loads():
    """small_gicp's OpenMP runtime reads OMP_WAIT_POLICY when it loads: set before, not over."""
    import os
    import subprocess
    import sys

    probe = '\n'.join(
        [
            'import os, sys',
            'class Spy:',  # prints the policy as the import of small_gicp begins
            '    def find_spec(self, name, path=None, target=None):',
            "        if name == 'small_gicp': print(os.environ.get('OMP_WAIT_POLICY'))",
            'sys.meta_path.insert(0, Spy())',
            'from mlsemreg_ros.core.odometry import Odometry',
        ]
    )
    env = {k: v for k, v in os.environ.items() if k != 'OMP_WAIT_POLICY'}
    run = subprocess.run([sys.executable, '-c', probe], env=env, capture_output=True, text=True)
    assert run.stdout.strip() == 'PASSIVE', run.stderr
    env['OMP_WAIT_POLICY'] = 'active'  # the user's choice stays
    run = subprocess.run([sys.executable, '-c', probe], env=env, capture_output=True, text=True)
    assert run.stdout.strip() == 'active', run.stderr
