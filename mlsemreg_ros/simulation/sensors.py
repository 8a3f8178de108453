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
Spinning LiDAR models of field mode: beam layout, columns, range and per-point time.

Every model spins clockwise seen from above (azimuth decreasing in the x-forward,
y-left sensor frame), starting each sweep behind the car (azimuth 180 deg), and
takes one column of beams per azimuth step over the scan period. All beams of a
column share its time (the real firing offsets inside a column, a few
microseconds, are not modelled). The cloud's header stamp is the sweep start:

- ``time``: float32 seconds from the header stamp, in [0, period) (the field of
  the Velodyne ROS driver, also read by KISS-ICP);
- ``t``: uint32 nanoseconds from the header stamp (the Ouster ROS driver's field),
  written for models with ``ouster_time``.

See ``docs/simulation.md`` (field mode) for the sources of the numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SensorModel:
    """One spinning LiDAR: beam elevations, columns per revolution, range, noise."""

    name: str
    elevations_deg: tuple[float, ...]  # beam 0 first (top beam first)
    columns: int  # azimuth steps per revolution
    max_range: float  # metres
    min_range: float  # metres
    period: float = 0.1  # seconds per revolution (10 Hz)
    range_noise: float = 0.02  # metres, Gaussian sigma
    dropout: float = 0.05  # share of lost returns
    intensity_noise: float = 0.03
    mount_height: float = 1.73  # metres above the road
    ouster_time: bool = False  # also write Ouster's ``t`` (uint32 ns)

    @property
    def beams(self) -> int:
        """Return the number of beams, i.e. rings."""
        return len(self.elevations_deg)

    def column_azimuths(self, offset: float) -> np.ndarray:
        """Azimuth (columns,) in radians of each column, clockwise from behind the car."""
        return np.pi - 2.0 * np.pi * (np.arange(self.columns) + offset) / self.columns

    def column_times(self, offset: float) -> np.ndarray:
        """Time (columns,) in seconds of each column from the sweep start, in [0, period)."""
        return self.period * (np.arange(self.columns) + offset) / self.columns


def _hdl64_elevations() -> tuple[float, ...]:
    """HDL-64E S2 (KITTI): upper block +2 .. -8.33 deg, lower block -8.83 .. -24.9 deg."""
    upper = np.linspace(2.0, -8.33, 32)
    lower = np.linspace(-8.83, -24.9, 32)
    return tuple(float(v) for v in np.concatenate([upper, lower]))


#: HDL-64E as on KITTI's car: 64 beams +2..-24.9 deg, 0.17 deg columns at 10 Hz, 120 m.
HDL64 = SensorModel('hdl64', _hdl64_elevations(), columns=2083, max_range=120.0, min_range=2.5)
#: VLP-16: 16 beams -15..+15 deg every 2 deg, 0.2 deg columns at 10 Hz, 100 m, 3 cm noise.
VLP16 = SensorModel(
    'vlp16',
    tuple(float(v) for v in np.linspace(15.0, -15.0, 16)),
    columns=1800,
    max_range=100.0,
    min_range=1.0,
    range_noise=0.03,
)
#: OS1-128: 128 beams +-22.5 deg, 1024 columns at 10 Hz, 120 m; also Ouster's ``t``.
OS128 = SensorModel(
    'os128',
    tuple(float(v) for v in np.linspace(22.5, -22.5, 128)),
    columns=1024,
    max_range=120.0,
    min_range=0.8,
    range_noise=0.03,
    ouster_time=True,
)

SENSORS: dict[str, SensorModel] = {m.name: m for m in (HDL64, VLP16, OS128)}


def sensor_model(name: str) -> SensorModel:
    """Return the model called ``name``; ValueError naming the known ones otherwise."""
    try:
        return SENSORS[name]
    except KeyError:
        raise ValueError(f'unknown sensor {name!r}; use one of {sorted(SENSORS)}') from None
