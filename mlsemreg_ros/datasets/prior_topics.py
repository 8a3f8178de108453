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
The motion-prior topics of a bag (IMU, wheel odometry), merged by time with its scans.

``mlsemreg eval-bag BAG --imu-topic /imu/data --wheel-topic /wheel/odometry`` reads them
whole (:func:`read_prior_topics`) and, before each scan, hands the motion model every
message stamped up to the end of that scan's sweep (:meth:`PriorTopics.feed_until`): what a
node would have received by the time the cloud arrives (``docs/field_prior.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mlsemreg_ros.datasets.bag import ImuArrays, read_imu, read_wheel_odometry, WheelOdometryArrays
from mlsemreg_ros.datasets.source import SourceError
import numpy as np


@dataclass
class PriorTopics:
    """IMU and wheel-odometry messages of a bag and how many were handed on."""

    imu: ImuArrays | None = None
    wheel: WheelOdometryArrays | None = None
    fed: dict[str, int] = field(default_factory=lambda: {'imu': 0, 'wheel': 0})

    def __bool__(self) -> bool:
        """Tell whether there is any prior topic."""
        return self.imu is not None or self.wheel is not None

    def feed_until(self, model: Any, stamp_ns: int) -> None:
        """Hand ``model`` (``add_imu`` / ``add_wheel``) the messages stamped up to ``stamp_ns``."""
        if self.imu is not None:
            start = self.fed['imu']
            stop = int(np.searchsorted(self.imu.stamps_ns, stamp_ns, side='right'))
            if stop > start:
                model.add_imu(
                    self.imu.stamps_ns[start:stop],
                    self.imu.angular_velocity[start:stop],
                    self.imu.linear_acceleration[start:stop],
                )
                self.fed['imu'] = stop
        if self.wheel is not None:
            start = self.fed['wheel']
            stop = int(np.searchsorted(self.wheel.stamps_ns, stamp_ns, side='right'))
            if stop > start:
                model.add_wheel(self.wheel.stamps_ns[start:stop], self.wheel.poses[start:stop])
                self.fed['wheel'] = stop


def read_prior_topics(
    bag: str | Path, imu_topic: str | None = None, wheel_topic: str | None = None
) -> PriorTopics:
    """Read the IMU and wheel-odometry topics of ``bag`` ('' or None: not read)."""
    topics = PriorTopics()
    if imu_topic:
        topics.imu = read_imu(bag, imu_topic)
        if not len(topics.imu):
            raise SourceError(f'{bag}: IMU topic {imu_topic!r} has no messages')
    if wheel_topic:
        topics.wheel = read_wheel_odometry(bag, wheel_topic)
        if not len(topics.wheel):
            raise SourceError(f'{bag}: wheel odometry topic {wheel_topic!r} has no messages')
    return topics


def sweep_end_ns(stamp_ns: int, point_times: np.ndarray | None) -> int:
    """Return the stamp of a scan's last point (its header stamp without point times)."""
    if point_times is None or not len(point_times):
        return stamp_ns
    return stamp_ns + max(round(float(np.max(point_times)) * 1e9), 0)
