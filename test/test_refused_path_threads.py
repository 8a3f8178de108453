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
The refused path on two workers gives what it gives on one (docs/hard_pairs.md, ninth round).

With two workers the far search's two directions run at once (core/stages/far_search.py),
small_gicp's alignments and the FFTs of the BEV searches on two threads; with one worker
everything runs in turn. A hand-made street pair that the confidence rule refuses
(an inlier floor no pose can reach) runs the whole refused path both ways: the same pose,
verdict, message and diagnostics to the last bit.
"""

from __future__ import annotations

from collections.abc import Iterator
import dataclasses

from mlsemreg_ros.core import threads
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.results import RegistrationResult
from mlsemreg_ros.core.stages import far_search
import numpy as np
import pytest
from test_covisible_acceptance import facade_street
from test_long_range import pose, scan


@pytest.fixture
def restore_threads() -> Iterator[None]:
    """Put the process-wide worker count back after the test."""
    before = threads._requested
    yield
    threads.configure(before)


def _refused_street_pair(count: int) -> RegistrationResult:
    """Register the street pair 30 m and 10 deg apart, always refused, on ``count`` workers."""
    cfg = RegistrationConfig(threads=count)
    cfg = dataclasses.replace(cfg, estimator=dataclasses.replace(cfg.estimator, min_inliers=10**6))
    registration = Registration(cfg)
    world, labels = facade_street()
    source = registration.prepare(*scan(world, labels, pose(0.0, 0.0, 1.7, 0.0)))
    target = registration.prepare(*scan(world, labels, pose(30.0, -1.0, 1.7, 10.0)))
    return registration.register(source, target, refine=True)


def test_the_refused_path_on_two_workers_equals_one_worker(restore_threads: None):
    """Threads 1 and 2: the same pose, verdict and diagnostics after the whole refused path."""
    serial = _refused_street_pair(1)
    parallel = _refused_street_pair(2)
    assert serial.diagnostics['guided_peaks'] == 3
    assert far_search._DIRECTIONS._pool is not None  # the two directions went to the pool
    for stage in ('bev_search_swapped_ms', 'far_search_ms', 'guided_ms', 'polish_ms'):
        assert stage in serial.timings_ms and stage in parallel.timings_ms
    assert not serial.success and not parallel.success
    assert serial.message == parallel.message
    np.testing.assert_array_equal(serial.transform, parallel.transform)
    np.testing.assert_array_equal(serial.estimate, parallel.estimate)
    for key, value in serial.diagnostics.items():  # all but the times
        if not key.endswith('_ms'):
            assert str(value) == str(parallel.diagnostics[key]), key
    assert serial.diagnostics.keys() == parallel.diagnostics.keys()
