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

"""Lazy preparation: features only when a registration needs them, and the same results."""

from __future__ import annotations

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry import Odometry
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.datasets.synthetic_scene import motion, scan_at, street_scene, synthetic_pair
import numpy as np
import pytest


@pytest.fixture(scope='module')
def registration() -> Registration:
    return Registration(RegistrationConfig())


def test_a_lazy_scan_has_its_features_only_once_completed(registration):
    pair = synthetic_pair(seed=0)
    scan = registration.prepare(pair.pts_src, pair.label_src, lazy=True)
    assert scan.pending_features is not None
    assert scan.descriptors.shape[1] == 0 and 'fpfh_ms' not in scan.timings_ms
    registration.complete(scan)
    assert scan.pending_features is None
    assert scan.descriptors.shape == (len(scan.keypoints), 33) and scan.timings_ms['fpfh_ms'] > 0
    eager = registration.prepare(pair.pts_src, pair.label_src)
    np.testing.assert_array_equal(scan.keypoints, eager.keypoints)
    np.testing.assert_array_equal(scan.descriptors, eager.descriptors)
    np.testing.assert_array_equal(scan.local_ss, eager.local_ss)
    np.testing.assert_array_equal(scan.landmarks.centroids, eager.landmarks.centroids)
    fpfh_ms = scan.timings_ms['fpfh_ms']
    registration.complete(scan)  # a no-op the second time
    assert scan.timings_ms['fpfh_ms'] == fpfh_ms


def test_register_completes_lazy_scans_and_gives_the_same_pose(registration):
    pair = synthetic_pair(seed=1)
    lazy = [
        registration.prepare(pair.pts_src, pair.label_src, lazy=True),
        registration.prepare(pair.pts_dst, pair.label_dst, lazy=True),
    ]
    eager = [
        registration.prepare(pair.pts_src, pair.label_src),
        registration.prepare(pair.pts_dst, pair.label_dst),
    ]
    from_lazy, from_eager = registration.register(*lazy), registration.register(*eager)
    assert from_lazy.success and from_eager.success
    np.testing.assert_allclose(from_lazy.transform, from_eager.transform, atol=1e-9)


def test_tracked_scans_never_compute_descriptors():
    world, labels = street_scene(seed=4)
    odometry = Odometry()
    steps = []
    for k in range(8):  # 0.5 m per scan along the street: tracked after the start
        points, point_labels = scan_at(world, labels, motion(0.0, (0.5 * k, 0.0, 0.0)), k)
        steps.append(odometry.process(points, point_labels, stamp_ns=(k + 1) * 100_000_000))
    tracked = [s for s in steps if s.source == 'prediction']
    assert len(tracked) >= 4, [s.source for s in steps]
    for step in tracked:
        assert step.result is None
        assert 'prepare.fpfh_ms' not in step.timings_ms
        assert 'prepare.local_ss_ms' not in step.timings_ms
    globally = [s for s in steps if s.result is not None]
    assert globally and all('prepare.fpfh_ms' in s.timings_ms for s in globally)
    assert abs(steps[-1].pose[0, 3] - 3.5) < 0.05  # and the odometry is still right


def test_a_lazy_scan_is_freed_without_the_cyclic_collector(registration):
    import gc
    import weakref

    pair = synthetic_pair(seed=0)
    gc.disable()
    try:
        scan = registration.prepare(pair.pts_src, pair.label_src, lazy=True)
        alive = weakref.ref(scan)
        del scan  # never completed, as a tracked scan
        assert alive() is None
    finally:
        gc.enable()
