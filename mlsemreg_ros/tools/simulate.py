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
    options_from,
    PointsTopicOption,
    QuietOption,
    replace_output,
    StorageOption,
    WorldFrameOption,
)
import typer

HELP = 'A labeled LiDAR sequence from the procedural world, as a rosbag2.'
SENSOR, LABELS, FIELD = 'Sensor', 'Label degradation', 'Field mode (--realism field)'


OutArgument = Annotated[
    Path, typer.Argument(help='output bag directory (must not exist, see --force)')
]
FramesOption = Annotated[
    int, typer.Option(min=0, help='number of scans (0: the whole loop, --route loop)')
]
SeedOption = Annotated[int, typer.Option(min=0, help='world, route and noise seed')]
BlurRadiusOption = Annotated[
    float,
    typer.Option(
        min=0.0,
        help='paper boundary blur radius in metres (0: clean labels)',
        rich_help_panel=LABELS,
    ),
]
BlurProbabilityOption = Annotated[
    float,
    typer.Option(
        min=0.0,
        max=1.0,
        help='chance that a boundary point takes another nearby class',
        rich_help_panel=LABELS,
    ),
]
FlipFractionOption = Annotated[
    float,
    typer.Option(
        min=0.0,
        max=1.0,
        help='share of points given a random other class',
        rich_help_panel=LABELS,
    ),
]
StepOption = Annotated[float, typer.Option(min=0.0, help='metres driven per frame')]
RateOption = Annotated[
    float,
    typer.Option(
        min=0.001,
        help='scan rate in Hz (field mode: up to 20; from 5 Hz the sensor turns at this '
        'rate, below it one 10 Hz sweep every 1/rate s is kept)',
    ),
]
BeamsOption = Annotated[int, typer.Option(min=1, help='vertical beams', rich_help_panel=SENSOR)]
AzimuthStepsOption = Annotated[
    int, typer.Option(min=1, help='horizontal samples per revolution', rich_help_panel=SENSOR)
]
MaxRangeOption = Annotated[float, typer.Option(min=0.1, help='metres', rich_help_panel=SENSOR)]
RangeNoiseOption = Annotated[
    float,
    typer.Option(min=0.0, help='Gaussian range noise sigma, metres', rich_help_panel=SENSOR),
]
DropoutOption = Annotated[
    float, typer.Option(min=0.0, max=1.0, help='share of lost returns', rich_help_panel=SENSOR)
]
RealismOption = Annotated[
    str,
    typer.Option(
        help='clean: instantaneous sweeps, exact labels (as before); field: motion '
        "distortion, per-point time, moving objects, a network's labels, IMU and wheel "
        'odometry (docs/simulation.md)',
        rich_help_panel=FIELD,
    ),
]
SensorOption = Annotated[
    str,
    typer.Option(
        help='hdl64, hdl32, vlp16, os128, or livox: a non-repetitive solid-state pattern '
        'with a 70 deg field of view (field mode)',
        rich_help_panel=FIELD,
    ),
]
ProfileOption = Annotated[
    str,
    typer.Option(
        help='normal; aggressive: stop-and-go, sharp turns at speed; handheld: walking '
        'with the sensor in hand, yaw up to 90 deg/s, sway, steps (field mode)',
        rich_help_panel=FIELD,
    ),
]
RouteOption = Annotated[
    str,
    typer.Option(
        help='street: random walk; loop: the same streets again, partly in the opposite '
        'direction, back to the start (field mode)',
        rich_help_panel=FIELD,
    ),
]
SpeedOption = Annotated[
    float | None,
    typer.Option(
        min=0.5,
        max=40.0,
        help="cruise speed in m/s on straights (field mode; default: the profile's, "
        '10 normal, 14 aggressive, 1.4 handheld)',
        rich_help_panel=FIELD,
    ),
]
MovingObjectsOption = Annotated[
    bool, typer.Option(help='cars, cyclists, pedestrians (field mode)', rich_help_panel=FIELD)
]
NetworkLabelsOption = Annotated[
    bool,
    typer.Option(
        help="a network's labels instead of the true ones (field mode)",
        rich_help_panel=FIELD,
    ),
]
NetworkOption = Annotated[
    str,
    typer.Option(
        help='whose per-class IoU the label model follows: rangenet++ or salsanext (field mode)',
        rich_help_panel=FIELD,
    ),
]


def simulate(
    context: typer.Context,
    out: OutArgument,
    frames: FramesOption = 200,
    seed: SeedOption = 0,
    storage: StorageOption = 'mcap',
    compress: CompressOption = False,
    blur_radius: BlurRadiusOption = 0.0,
    blur_probability: BlurProbabilityOption = 0.5,
    flip_fraction: FlipFractionOption = 0.0,
    step: StepOption = 1.0,
    rate: RateOption = 10.0,
    beams: BeamsOption = 64,
    azimuth_steps: AzimuthStepsOption = 2000,
    max_range: MaxRangeOption = 100.0,
    range_noise: RangeNoiseOption = 0.02,
    dropout: DropoutOption = 0.05,
    realism: RealismOption = 'clean',
    sensor: SensorOption = 'hdl64',
    profile: ProfileOption = 'normal',
    route: RouteOption = 'street',
    speed: SpeedOption = None,
    moving_objects: MovingObjectsOption = True,
    network_labels: NetworkLabelsOption = True,
    network: NetworkOption = 'rangenet++',
    points_topic: PointsTopicOption = POINTS_TOPIC,
    gt_topic: GtTopicOption = GT_TOPIC,
    frame_id: FrameIdOption = SENSOR_FRAME,
    world_frame: WorldFrameOption = WORLD_FRAME,
    force: ForceOption = False,
    quiet: QuietOption = False,
) -> int:
    """Simulate a labeled LiDAR drive into a rosbag2 (alias mlsemreg-simulate)."""
    from mlsemreg_ros.evaluation.tables import print_text
    from mlsemreg_ros.simulation.drive_request import (
        DriveRequest,
        DriveRequestError,
        simulate_drive,
    )

    request = options_from(context, DriveRequest)
    layout = options_from(context, BagLayout)
    try:
        request.config()  # invalid options are usage errors, before the output is replaced
    except DriveRequestError as error:
        raise typer.BadParameter(str(error), param_hint=error.option) from None
    replace_output(out, force)
    print_text(simulate_drive(out, request, layout, progress=not quiet))
    return 0


main = alias(simulate, HELP, 'mlsemreg-simulate')
