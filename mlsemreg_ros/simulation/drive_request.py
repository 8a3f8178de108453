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
What ``mlsemreg simulate`` asks for, as one request, and the bag written from it.

:class:`DriveRequest` holds every option of the command; :meth:`DriveRequest.config` turns
it into the clean world's :class:`~mlsemreg_ros.simulation.sequence.SimulationConfig` or the
field world's :class:`~mlsemreg_ros.simulation.field.FieldConfig` (docs/simulation.md);
:func:`simulate_drive` writes the bag (``simulation/export.py``, ``field_export.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mlsemreg_ros.datasets.bag import BagLayout

REALISMS = ('clean', 'field')


class DriveRequestError(ValueError):
    """The options do not describe a drive; ``option`` names the one at fault, if one is."""

    def __init__(self, message: str, option: str | None = None) -> None:
        """``option``: the command-line option to name in the error (``--frames``)."""
        super().__init__(message)
        self.option = option


@dataclass(frozen=True)
class DriveRequest:
    """Every option of ``mlsemreg simulate`` but the output and the bag's layout."""

    frames: int = 200  # 0: the whole loop (field, route loop)
    seed: int = 0  # world, route and noise
    blur_radius: float = 0.0  # clean: the paper's boundary blur, m
    blur_probability: float = 0.5  # clean: chance a boundary point takes a nearby class
    flip_fraction: float = 0.0  # clean: share of points given a random other class
    step: float = 1.0  # clean: metres driven per frame
    rate: float = 10.0  # scan rate, Hz
    beams: int = 64  # clean: the LiDAR's vertical beams
    azimuth_steps: int = 2000  # clean: horizontal samples per revolution
    max_range: float = 100.0  # clean, m
    range_noise: float = 0.02  # clean: Gaussian range noise sigma, m
    dropout: float = 0.05  # clean: share of lost returns
    realism: str = 'clean'  # clean | field
    sensor: str = 'hdl64'  # field
    profile: str = 'normal'  # field: normal | aggressive | handheld
    route: str = 'street'  # field: street | loop
    speed: float | None = None  # field: cruise speed, m/s (None: the profile's)
    moving_objects: bool = True  # field
    network_labels: bool = True  # field
    network: str = 'rangenet++'  # field: whose per-class IoU the label model follows

    def config(self) -> Any:
        """Return the field world's ``FieldConfig`` or the clean world's ``SimulationConfig``."""
        from mlsemreg_ros.simulation.field import FieldConfig
        from mlsemreg_ros.simulation.lidar import LidarConfig
        from mlsemreg_ros.simulation.sequence import SimulationConfig

        if self.realism not in REALISMS:
            raise DriveRequestError(f'use one of {list(REALISMS)}', '--realism')
        if self.realism == 'field':
            config = FieldConfig(
                seed=self.seed,
                frames=self.frames,
                sensor=self.sensor,
                profile=self.profile,
                route=self.route,
                speed=self.speed,
                moving_objects=self.moving_objects,
                network_labels=self.network_labels,
                network=self.network,
                rate=self.rate,
            )
            try:
                config.validate()
            except ValueError as error:
                raise DriveRequestError(str(error)) from None
            return config
        if self.frames == 0:
            raise DriveRequestError('0 frames only with --realism field --route loop', '--frames')
        lidar = LidarConfig(
            beams=self.beams,
            azimuth_steps=self.azimuth_steps,
            max_range=self.max_range,
            range_noise=self.range_noise,
            dropout=self.dropout,
        )
        return SimulationConfig(
            self.seed,
            self.frames,
            self.rate,
            self.step,
            self.blur_radius,
            self.blur_probability,
            self.flip_fraction,
            lidar=lidar,
        )


def simulate_drive(
    out: Path, request: DriveRequest, layout: BagLayout, progress: bool = True
) -> str:
    """Simulate the drive into the new bag folder ``out``; return the line saying what it wrote."""
    from mlsemreg_ros.simulation.export import write_simulation_bag
    from mlsemreg_ros.simulation.field_export import write_field_bag

    config = request.config()
    write = write_field_bag if request.realism == 'field' else write_simulation_bag
    return write(out, config, layout, progress=progress).summary(out)
