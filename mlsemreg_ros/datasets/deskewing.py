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
Sweeps motion-compensated to their stamps, as the package's keyframes are.

A LiDAR sweep's points are taken over its rotation while the sensor moves; its stamp (and a
bag's ground truth) refers to the sweep's start. The odometry deskews every scan with its own
motion estimate, and a map with ground-truth poses deskews its keyframes by the true motion.
These generators do the same to a stream of :class:`~mlsemreg_ros.datasets.source.Scan`
(``map build --poses ground-truth``, ``cut-pairs --deskew``).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from typing import Any

from mlsemreg_ros.core.config import RegistrationConfig


def deskewed_by_truth(scans: Iterator[Any], config: RegistrationConfig) -> Iterator[Any]:
    """
    Yield the posed scans with their points deskewed to their stamps by the true motion.

    A map with ground-truth poses gets the motion compensation that the odometry gives
    its keyframes (``preprocess.deskew``, ``core/features/deskew.py``), with the true
    motion: the constant twist from the scan's pose to the next scan's (its own sweep);
    the last scan takes the twist from the one before. Scans without point times stay as
    they are.
    """
    from mlsemreg_ros.core.features.deskew import deskew, sweep_motion

    def moved(scan: Any, a: Any, b: Any) -> Any:
        if config.preprocess.deskew == 'off' or scan.point_times is None:
            return scan
        motion = sweep_motion(a.pose, a.stamp_ns, b.pose, b.stamp_ns)
        if motion is None:
            return scan
        return replace(scan, xyz=deskew(scan.xyz, scan.point_times, motion))

    before = held = None
    for scan in scans:
        if held is not None:
            yield moved(held, held, scan)  # the motion over its own sweep, to the next stamp
        before, held = held, scan
    if held is not None:  # the last scan: the motion from the one before (none: as it is)
        yield held if before is None else moved(held, before, held)


def deskewed_by_odometry(scans: Iterator[Any]) -> Iterator[Any]:
    """
    Yield ``scans`` as the odometry keeps them: deskewed by its own estimate of each sweep.

    Every scan goes through :class:`~mlsemreg_ros.core.odometry.Odometry` with the defaults
    and the field's labels; a scan the odometry deskewed is yielded with its deskewed points
    (moving objects dropped, as its keyframes), any other as it came.
    """
    from mlsemreg_ros.core.odometry import Odometry

    odometry = Odometry(config=RegistrationConfig().replace({'label_source': 'field'}))
    for scan in scans:
        step = odometry.process(scan.xyz, scan.labels, scan.stamp_ns, point_times=scan.point_times)
        if step.deskewed and step.points is not None and step.labels is not None:
            yield replace(scan, xyz=step.points, labels=step.labels)
        else:
            yield scan
