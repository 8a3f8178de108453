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
``mlsemreg room-walk SCAN OUT``: a handheld walk through one real scan's room, as a rosbag2.

The writer is :func:`mlsemreg_ros.simulation.room_walk.write_room_walk` (the walk, the
sweeps and the bag layout are described there); ``mlsemreg eval-bag OUT`` scores it. It is
a command of its own: ``simulate`` renders a procedural world and ``self-pairs`` registers
pairs without a bag, while this turns one real scan into a tracked sequence.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from mlsemreg_ros.tools.common import alias, CommandError, ForceOption, replace_output
import typer

HELP = (
    'A handheld walk through the room of one real PCD/PLY scan (a figure of eight about its '
    'origin, motion-distorted sweeps resampled with noise), as a rosbag2 with ground truth.'
)


def room_walk(
    scan: Annotated[Path, typer.Argument(help='PCD/PLY file: the room')],
    out: Annotated[Path, typer.Argument(help='output bag directory (must not exist)')],
    frames: Annotated[int, typer.Option(min=2, help='number of sweeps')] = 40,
    rate: Annotated[float, typer.Option(min=0.1, help='sweeps per second (Hz)')] = 10.0,
    radius: Annotated[
        float, typer.Option(min=0.1, help="the figure of eight's half length (m)")
    ] = 1.5,
    peak_speed: Annotated[
        float, typer.Option(min=0.01, help='fastest walking speed (m/s; the slowest 0.47 of it)')
    ] = 1.2,
    yaw_rate: Annotated[float, typer.Option(min=0.0, help='largest turn rate (deg/s)')] = 60.0,
    keep: Annotated[
        float, typer.Option(min=0.01, max=1.0, help="share of the scan's points per sweep")
    ] = 0.7,
    noise: Annotated[float, typer.Option(min=0.0, help='noise per coordinate (m)')] = 0.02,
    seed: Annotated[int, typer.Option(min=0, help='walk and sampling seed')] = 0,
    force: ForceOption = False,
) -> int:
    """Write a walk through a real scan's room as a bag (alias mlsemreg-room-walk)."""
    from mlsemreg_ros.core.maps.cloud_files import CloudFileError, read_cloud
    from mlsemreg_ros.simulation.room_walk import RoomWalk, write_room_walk

    try:
        cloud = read_cloud(scan)
        walk = RoomWalk(frames, rate, radius, peak_speed, yaw_rate, keep, noise, seed)
    except (CloudFileError, ValueError) as error:
        raise CommandError(str(error)) from error
    replace_output(out, force)
    written = write_room_walk(out, cloud.points, walk, cloud.intensity)
    print(
        f'{out}: {written.frames} sweeps, {written.points / written.frames:.0f} points each, '
        f'{written.path_m:.2f} m walked, at most {written.farthest_m:.2f} m from the origin, '
        f'turning up to {written.peak_yaw_rate_deg:.0f} deg/s'
    )
    return 0


main = alias(room_walk, HELP, 'mlsemreg-room-walk')
