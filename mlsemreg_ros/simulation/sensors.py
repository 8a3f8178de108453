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
LiDAR models of field mode: beam layout, columns, range and per-point time.

Every spinning model spins clockwise seen from above (azimuth decreasing in the
x-forward, y-left sensor frame), starting each sweep behind the car (azimuth 180 deg),
and takes one column of beams per azimuth step over the scan period. All beams of a
column share its time (the real firing offsets inside a column, a few
microseconds, are not modelled). The solid-state ``livox`` model has one beam whose
direction follows a rosette (two counter-rotating Risley prisms) inside a circular
field of view around the x axis; a column is one firing, and the pattern never
repeats: it continues from one frame to the next (:meth:`SensorModel.directions`).
The cloud's header stamp is the sweep start:

- ``time``: float32 seconds from the header stamp, in [0, period) (the field of
  the Velodyne ROS driver, also read by KISS-ICP);
- ``t``: uint32 nanoseconds from the header stamp (the Ouster ROS driver's field),
  written for models with ``ouster_time``.

See ``docs/simulation.md`` (field mode) for the sources of the numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

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
    field_of_view_deg: float = 0.0  # rosette models: diameter of the circular field of view
    prism_hz: tuple[float, float] = (0.0, 0.0)  # rosette models: the two prisms' rotation rates

    @property
    def beams(self) -> int:
        """Return the number of beams, i.e. rings."""
        return len(self.elevations_deg)

    @property
    def rosette(self) -> bool:
        """Return whether the model is solid state, scanning a rosette instead of spinning."""
        return self.field_of_view_deg > 0.0

    def elevation_range_deg(self) -> tuple[float, float]:
        """Return the lowest and highest elevation of a ray, in degrees."""
        if self.rosette:
            return -0.5 * self.field_of_view_deg, 0.5 * self.field_of_view_deg
        return min(self.elevations_deg), max(self.elevations_deg)

    def at_rate(self, rate_hz: float | None) -> SensorModel:
        """
        Return the model publishing ``rate_hz`` scans per second (None: its own 10 Hz).

        From 5 to 20 Hz the sensor turns at that rate (a frame of ``1 / rate_hz`` s) at its
        own firing rate: the columns per sweep scale with the period, as a Velodyne's azimuth
        resolution does. Below 5 Hz it keeps its own period and only one sweep every
        ``1 / rate_hz`` s is published (as a dataset's key frames). Above 20 Hz: ValueError.
        """
        if rate_hz is None:
            return self
        if not 0.0 < rate_hz <= MAX_RATE_HZ:
            raise ValueError(f'rate must lie in (0, {MAX_RATE_HZ:g}] Hz, got {rate_hz}')
        if rate_hz < MIN_SPIN_HZ or rate_hz * self.period == 1.0:
            return self
        period = 1.0 / rate_hz
        columns = max(1, round(self.columns * period / self.period))
        return replace(self, period=period, columns=columns)

    def directions(self, start: float, offset: float) -> np.ndarray:
        """
        Return the unit rays (C, B, 3) in the sensor frame of each column's instant.

        ``start``: the sweep's start on the drive's clock (s), which sets the phase of a
        rosette; ``offset``: the sub-column offset of the sweep (:meth:`column_times`).
        """
        if self.rosette:
            t = start + self.column_times(offset)
            half = np.radians(0.25 * self.field_of_view_deg)  # each prism: half the radius
            (fast, slow), tau = self.prism_hz, 2.0 * np.pi
            horizontal = half * (np.cos(tau * fast * t) + np.cos(tau * slow * t))
            vertical = half * (np.sin(tau * fast * t) + np.sin(tau * slow * t))
            azimuth, elevation = horizontal[:, None], vertical[:, None]
        else:
            azimuth = self.column_azimuths(offset)[:, None]
            elevation = np.radians(np.asarray(self.elevations_deg))[None, :]
        ce, se = np.cos(elevation), np.sin(elevation)
        shape = np.broadcast_shapes(azimuth.shape, elevation.shape)
        return np.stack(
            [ce * np.cos(azimuth), ce * np.sin(azimuth), np.broadcast_to(se, shape)], axis=-1
        )

    def column_azimuths(self, offset: float) -> np.ndarray:
        """Azimuth (columns,) in radians of each column, clockwise from behind the car."""
        return np.pi - 2.0 * np.pi * (np.arange(self.columns) + offset) / self.columns

    def column_times(self, offset: float) -> np.ndarray:
        """Time (columns,) in seconds of each column from the sweep start, in [0, period)."""
        return self.period * (np.arange(self.columns) + offset) / self.columns


def _elevations(*blocks: tuple[float, float, int]) -> tuple[float, ...]:
    """Return beam elevations (deg), each block ``(top, bottom, beams)`` evenly spaced."""
    return tuple(float(v) for v in np.concatenate([np.linspace(*block) for block in blocks]))


#: HDL-64E S2 as on KITTI's car: 64 beams, an upper block +2 .. -8.33 deg and a lower block
#: -8.83 .. -24.9 deg, 0.17 deg columns at 10 Hz, 120 m.
HDL64 = SensorModel(
    'hdl64',
    _elevations((2.0, -8.33, 32), (-8.83, -24.9, 32)),
    columns=2083,
    max_range=120.0,
    min_range=2.5,
)
#: VLP-16: 16 beams -15..+15 deg every 2 deg, 0.2 deg columns at 10 Hz, 100 m, 3 cm noise.
VLP16 = SensorModel(
    'vlp16',
    _elevations((15.0, -15.0, 16)),
    columns=1800,
    max_range=100.0,
    min_range=1.0,
    range_noise=0.03,
)
#: OS1-128: 128 beams +-22.5 deg, 1024 columns at 10 Hz, 120 m; also Ouster's ``t``.
OS128 = SensorModel(
    'os128',
    _elevations((22.5, -22.5, 128)),
    columns=1024,
    max_range=120.0,
    min_range=0.8,
    range_noise=0.03,
    ouster_time=True,
)

#: HDL-32E: 32 beams +10.67..-30.67 deg every 1.33 deg, 0.166 deg columns at 10 Hz, 100 m.
HDL32 = SensorModel(
    'hdl32',
    _elevations((10.67, -30.67, 32)),
    columns=2170,
    max_range=100.0,
    min_range=1.0,
)
#: Livox Mid-70-like solid state: a non-repetitive rosette in a 70.4 deg circular field of
#: view around x, 100,000 points/s (10,000 a frame at 10 Hz), 0.05-200 m, 2 cm noise.
LIVOX = SensorModel(
    'livox',
    (0.0,),
    columns=10000,
    max_range=200.0,
    min_range=0.05,
    field_of_view_deg=70.4,
    prism_hz=(153.7, -103.1),
)

SENSORS: dict[str, SensorModel] = {m.name: m for m in (HDL64, HDL32, VLP16, OS128, LIVOX)}
#: ``at_rate``: the sensor turns at the scan rate from here up to :data:`MAX_RATE_HZ`.
MIN_SPIN_HZ = 5.0
MAX_RATE_HZ = 20.0


def sensor_model(name: str) -> SensorModel:
    """Return the model called ``name``; ValueError naming the known ones otherwise."""
    try:
        return SENSORS[name]
    except KeyError:
        raise ValueError(f'unknown sensor {name!r}; use one of {sorted(SENSORS)}') from None
