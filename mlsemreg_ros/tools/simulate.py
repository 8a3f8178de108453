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
``mlsemreg simulate OUT``: a labeled LiDAR sequence from the procedural world, as a rosbag2.

The writer is :func:`mlsemreg_ros.simulation.export.write_simulation_bag` (bag layout and
side files described there); this module is its command line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from mlsemreg_ros.datasets.bag import (
    BagLayout,
    GT_TOPIC,
    POINTS_TOPIC,
    SENSOR_FRAME,
    WORLD_FRAME,
)
from mlsemreg_ros.tools.common import (
    alias,
    CompressOption,
    ForceOption,
    FrameIdOption,
    GtTopicOption,
    PointsTopicOption,
    QuietOption,
    replace_output,
    StorageOption,
    WorldFrameOption,
)
import typer

HELP = 'A labeled LiDAR sequence from the procedural world, as a rosbag2.'
SENSOR, LABELS, FIELD = 'Sensor', 'Label degradation', 'Field mode (--realism field)'
REALISMS = ('clean', 'field')


def simulate(
    out: Annotated[
        Path, typer.Argument(help='output bag directory (must not exist, see --force)')
    ],
    frames: Annotated[
        int, typer.Option(min=0, help='number of scans (0: the whole loop, --route loop)')
    ] = 200,
    seed: Annotated[int, typer.Option(min=0, help='world, route and noise seed')] = 0,
    storage: StorageOption = 'mcap',
    compress: CompressOption = False,
    blur_radius: Annotated[
        float,
        typer.Option(
            min=0.0,
            help='paper boundary blur radius in metres (0: clean labels)',
            rich_help_panel=LABELS,
        ),
    ] = 0.0,
    blur_probability: Annotated[
        float,
        typer.Option(
            min=0.0,
            max=1.0,
            help='chance that a boundary point takes another nearby class',
            rich_help_panel=LABELS,
        ),
    ] = 0.5,
    flip_fraction: Annotated[
        float,
        typer.Option(
            min=0.0,
            max=1.0,
            help='share of points given a random other class',
            rich_help_panel=LABELS,
        ),
    ] = 0.0,
    step: Annotated[float, typer.Option(min=0.0, help='metres driven per frame')] = 1.0,
    rate: Annotated[
        float,
        typer.Option(
            min=0.001,
            help='scan rate in Hz (field mode: up to 20; from 5 Hz the sensor turns at this '
            'rate, below it one 10 Hz sweep every 1/rate s is kept)',
        ),
    ] = 10.0,
    beams: Annotated[int, typer.Option(min=1, help='vertical beams', rich_help_panel=SENSOR)] = 64,
    azimuth_steps: Annotated[
        int, typer.Option(min=1, help='horizontal samples per revolution', rich_help_panel=SENSOR)
    ] = 2000,
    max_range: Annotated[
        float, typer.Option(min=0.1, help='metres', rich_help_panel=SENSOR)
    ] = 100.0,
    range_noise: Annotated[
        float,
        typer.Option(min=0.0, help='Gaussian range noise sigma, metres', rich_help_panel=SENSOR),
    ] = 0.02,
    dropout: Annotated[
        float, typer.Option(min=0.0, max=1.0, help='share of lost returns', rich_help_panel=SENSOR)
    ] = 0.05,
    realism: Annotated[
        str,
        typer.Option(
            help='clean: instantaneous sweeps, exact labels (as before); field: motion '
            "distortion, per-point time, moving objects, a network's labels, IMU and wheel "
            'odometry (docs/simulation.md)',
            rich_help_panel=FIELD,
        ),
    ] = 'clean',
    sensor: Annotated[
        str,
        typer.Option(
            help='hdl64, hdl32, vlp16, os128, or livox: a non-repetitive solid-state pattern '
            'with a 70 deg field of view (field mode)',
            rich_help_panel=FIELD,
        ),
    ] = 'hdl64',
    profile: Annotated[
        str,
        typer.Option(
            help='normal; aggressive: stop-and-go, sharp turns at speed; handheld: walking '
            'with the sensor in hand, yaw up to 90 deg/s, sway, steps (field mode)',
            rich_help_panel=FIELD,
        ),
    ] = 'normal',
    route: Annotated[
        str,
        typer.Option(
            help='street: random walk; loop: the same streets again, partly in the opposite '
            'direction, back to the start (field mode)',
            rich_help_panel=FIELD,
        ),
    ] = 'street',
    speed: Annotated[
        float | None,
        typer.Option(
            min=0.5,
            max=40.0,
            help="cruise speed in m/s on straights (field mode; default: the profile's, "
            '10 normal, 14 aggressive, 1.4 handheld)',
            rich_help_panel=FIELD,
        ),
    ] = None,
    moving_objects: Annotated[
        bool, typer.Option(help='cars, cyclists, pedestrians (field mode)', rich_help_panel=FIELD)
    ] = True,
    network_labels: Annotated[
        bool,
        typer.Option(
            help="a network's labels instead of the true ones (field mode)",
            rich_help_panel=FIELD,
        ),
    ] = True,
    network: Annotated[
        str,
        typer.Option(
            help='whose per-class IoU the label model follows: rangenet++ or salsanext '
            '(field mode)',
            rich_help_panel=FIELD,
        ),
    ] = 'rangenet++',
    points_topic: PointsTopicOption = POINTS_TOPIC,
    gt_topic: GtTopicOption = GT_TOPIC,
    frame_id: FrameIdOption = SENSOR_FRAME,
    world_frame: WorldFrameOption = WORLD_FRAME,
    force: ForceOption = False,
    quiet: QuietOption = False,
) -> int:
    """Simulate a labeled LiDAR drive into a rosbag2 (alias mlsemreg-simulate)."""
    from mlsemreg_ros.datasets.bag import BagLayout
    from mlsemreg_ros.evaluation.tables import print_text
    from mlsemreg_ros.simulation.export import write_simulation_bag
    from mlsemreg_ros.simulation.lidar import LidarConfig
    from mlsemreg_ros.simulation.sequence import SimulationConfig

    if realism not in REALISMS:
        raise typer.BadParameter(f'use one of {list(REALISMS)}', param_hint='--realism')
    layout = BagLayout(storage, compress, points_topic, gt_topic, frame_id, world_frame)
    if realism == 'field':
        return _simulate_field(
            out,
            frames,
            seed,
            sensor,
            profile,
            route,
            speed,
            moving_objects,
            network_labels,
            network,
            layout,
            force,
            quiet,
            rate,
        )
    if frames == 0:
        raise typer.BadParameter(
            '0 frames only with --realism field --route loop', param_hint='--frames'
        )
    replace_output(out, force)
    lidar = LidarConfig(
        beams=beams,
        azimuth_steps=azimuth_steps,
        max_range=max_range,
        range_noise=range_noise,
        dropout=dropout,
    )
    config = SimulationConfig(
        seed=seed,
        frames=frames,
        rate_hz=rate,
        step=step,
        blur_radius=blur_radius,
        blur_probability=blur_probability,
        flip_fraction=flip_fraction,
        lidar=lidar,
    )
    report = write_simulation_bag(out, config, layout, progress=not quiet)
    print_text(
        f'wrote {out}: {report.frames} scans, {report.points_per_scan:.0f} points/scan, '
        f'{report.path_m:.1f} m driven; world {report.world_s:.1f} s, total '
        f'{report.total_s:.1f} s'
    )
    return 0


def _simulate_field(
    out: Path,
    frames: int,
    seed: int,
    sensor: str,
    profile: str,
    route: str,
    speed: float | None,
    moving_objects: bool,
    network_labels: bool,
    network: str,
    layout: BagLayout,
    force: bool,
    quiet: bool,
    rate: float = 10.0,
) -> int:
    """Field mode: see :mod:`mlsemreg_ros.simulation.field_export`."""
    from mlsemreg_ros.evaluation.tables import print_text
    from mlsemreg_ros.simulation.field import FieldConfig
    from mlsemreg_ros.simulation.field_export import write_field_bag

    config = FieldConfig(
        seed=seed,
        frames=frames,
        sensor=sensor,
        profile=profile,
        route=route,
        speed=speed,
        moving_objects=moving_objects,
        network_labels=network_labels,
        network=network,
        rate=rate,
    )
    try:
        config.validate()
    except ValueError as error:
        raise typer.BadParameter(str(error)) from None
    replace_output(out, force)
    report = write_field_bag(out, config, layout, progress=not quiet)
    print_text(
        f'wrote {out}: {report.frames} {sensor} sweeps at {rate:g} Hz ({profile}, {route}), '
        f'{report.points_per_scan:.0f} points/scan, {report.path_m:.1f} m driven; setup '
        f'{report.setup_s:.1f} s, total {report.total_s:.1f} s'
    )
    return 0


main = alias(simulate, HELP, 'mlsemreg-simulate')
