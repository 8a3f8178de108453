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

"""``mlsemreg map sim-queries --deskew odometry``: queries are the scans the odometry deskewed."""

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry import Odometry
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.simulation.field import FieldConfig
from mlsemreg_ros.simulation.field_odometry_queries import odometry_queries, OdometryQueryCount
from mlsemreg_ros.simulation.field_revisit import field_reverse_drive, field_reverse_sweeps
import numpy as np
from scipy.spatial import cKDTree

SWEEPS = 6


def test_odometry_queries_hold_the_points_the_node_relocalizes() -> None:
    """
    A query is the sweep as the odometry deskewed it, with the truth at its stamp.

    Preparing the written points gives the scan the odometry handed over (``step.prepared``,
    what the node relocalizes) on an independent run over the same sweeps; the sweeps the
    odometry left skewed (its first ones) are skipped and counted.
    """
    config = FieldConfig(seed=0, frames=20, sensor='vlp16')
    sim, drive, starts = field_reverse_drive(config)
    sweeps = list(field_reverse_sweeps(sim, drive, starts, SWEEPS, noise_seed=1000))
    registration = Registration(RegistrationConfig())
    count = OdometryQueryCount()
    wanted = {0, 2, 4, 5}
    queries = list(odometry_queries(iter(sweeps), wanted, registration, count))

    odometry, prepared = Odometry(registration), {}
    for sweep in sweeps:
        step = odometry.process(
            sweep.points, sweep.labels, sweep.stamp_ns, point_times=sweep.times
        )
        prepared[sweep.index] = (step.prepared, step.deskewed)
    assert count.sweeps == SWEEPS and count.wanted == len(wanted)
    assert count.skewed >= 1 and 0 not in {q.index for q in queries}  # the first scan: skewed
    assert count.written == len(queries) >= 2
    assert count.written + count.rejected + count.skewed == count.wanted
    origin_inv = np.linalg.inv(sim.world_poses[0])
    for query in queries:
        scan, deskewed = prepared[query.index]
        assert deskewed
        sweep = sweeps[query.index]
        again = registration.prepare(query.points, query.labels)
        # the same points; two odometry runs differ in the last digits (threaded sums)
        np.testing.assert_allclose(again.points, scan.points, rtol=0.0, atol=1e-6)
        np.testing.assert_array_equal(again.labels, scan.labels)
        assert query.points.dtype == np.float64
        moved = cKDTree(sweep.points).query(query.points)[0]  # moving objects were dropped
        assert moved.max() > 0.05  # deskewed: the sensor moves while it sweeps
        truth = origin_inv @ drive.poses(np.array([starts[query.index]]))[0]
        np.testing.assert_allclose(query.T_map_scan, truth)
