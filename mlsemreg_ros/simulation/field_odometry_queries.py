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
Relocalization queries as the node relocalizes them: every sweep through the odometry.

The node hands its relocalization the scan the odometry prepared
(``MapLocalization.update``: ``step.prepared``), i.e. the sweep deskewed by the odometry:
without an IMU, the constant twist from the poses and then, when it bends the scan, the
sweep's own twist estimated against the local map (``Tracker.align_sweep``,
``core/alignment/sweep_alignment.py``), with the moving objects dropped
(``moving_objects.matching: drop``). :func:`odometry_queries` runs the core
:class:`~mlsemreg_ros.core.odometry.Odometry` over every sweep of a drive in order, as the
node does, and keeps the wanted sweeps as queries holding exactly those points
(``step.points``, float64, and their raw labels): ``mlsemreg relocalize`` prepares them
into the scan the node would have relocalized. A wanted sweep that the odometry rejected,
or accepted without deskewing it (its first two scans, :func:`awaits_deskew`), is not
relocalized by the node and is skipped (:class:`OdometryQueryCount` says how many).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

from mlsemreg_ros.core.maps.localization import awaits_deskew
from mlsemreg_ros.core.odometry import Odometry
from mlsemreg_ros.simulation.field_revisit import TimedSweep
from mlsemreg_ros.simulation.revisit import QueryScan


@dataclass
class OdometryQueryCount:
    """What :func:`odometry_queries` did with the sweeps."""

    sweeps: int = 0  # sweeps through the odometry
    accepted: int = 0  # of them accepted
    wanted: int = 0  # sweeps meant as queries
    written: int = 0  # queries yielded
    rejected: int = 0  # wanted sweeps the odometry rejected (skipped)
    skewed: int = 0  # wanted sweeps accepted but not deskewed (skipped)


def odometry_queries(
    sweeps: Iterable[TimedSweep],
    wanted: set[int],
    registration: object,
    count: OdometryQueryCount | None = None,
) -> Iterator[QueryScan]:
    """
    Run a fresh odometry (``registration``'s config) over ``sweeps``; yield the wanted ones.

    Each yielded query holds the points and raw labels the odometry aligned the sweep as
    (``step.points``, ``step.labels``) and the sweep's ground truth. ``count`` is updated
    as the sweeps go by.
    """
    count = count if count is not None else OdometryQueryCount()
    odometry = Odometry(registration)
    config = registration.config
    for sweep in sweeps:
        step = odometry.process(
            sweep.points, sweep.labels, sweep.stamp_ns, point_times=sweep.times
        )
        count.sweeps += 1
        count.accepted += bool(step.accepted)
        if sweep.index not in wanted:
            continue
        count.wanted += 1
        if not step.accepted or step.points is None:
            count.rejected += 1
        elif awaits_deskew(step, sweep.times, config):
            count.skewed += 1
        else:
            count.written += 1
            yield QueryScan(sweep.index, step.points, step.labels, sweep.T_map_scan)
