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
``mlsemreg map export`` and ``mlsemreg map import``: point maps in PCD or PLY (docs/maps.md).

The commands only parse and call ``core/maps/point_map.py`` and ``core/maps/cloud_files.py``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from mlsemreg_ros.tools.common import (
    CommandError,
    ConfigOption,
    ForceOption,
    LabelsOption,
    replace_output,
    SetOption,
    settings,
    with_labels,
)
import typer

EXPORT_HELP = (
    'Write a map folder as one map-frame cloud (PCD or PLY, with label and intensity fields, '
    'voxelized by map.export_voxel) and its keyframe trajectory (TUM).'
)
IMPORT_HELP = (
    'Make a map folder from a point map (PCD or PLY, e.g. from FAST-LIO, GLIM, KISS-SLAM or '
    'a survey): keyframes cut along a TUM trajectory, or on a grid without one.'
)


def export_command(
    map_path: Annotated[Path, typer.Argument(metavar='MAP', help='map folder (docs/maps.md)')],
    out: Annotated[Path, typer.Argument(help='cloud to write: OUT.pcd or OUT.ply')],
    trajectory: Annotated[
        Path | None,
        typer.Option(help='TUM trajectory of the keyframes to write (default: OUT with .tum)'),
    ] = None,
    voxel: Annotated[
        float | None,
        typer.Option(min=0.0, help='voxel edge, m (default: map.export_voxel; 0: every point)'),
    ] = None,
    force: ForceOption = False,
) -> int:
    """Export a map folder as a point cloud and a TUM trajectory."""
    from mlsemreg_ros.codec.pose_files import write_tum_poses
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.maps.cloud_files import CloudFileError, write_cloud
    from mlsemreg_ros.core.maps.map_io import load_map, MapError
    from mlsemreg_ros.core.maps.point_map import export_points
    from mlsemreg_ros.evaluation.tables import print_text
    import numpy as np

    trajectory = trajectory or out.with_suffix('.tum')
    for path in (out, trajectory):
        if path.exists() and not force:
            raise CommandError(f'{path} exists (use --force to replace it)', 2)
    try:
        data = load_map(map_path)
    except MapError as error:
        raise CommandError(str(error)) from None
    config = data.config or RegistrationConfig()
    size = config.map.export_voxel if voxel is None else voxel
    exported = export_points(data.keyframes, size)
    try:
        write_cloud(out, exported.points, exported.labels, exported.intensity)
    except CloudFileError as error:
        raise CommandError(str(error)) from None
    poses = np.array([k.T_map_keyframe for k in data.keyframes]).reshape(-1, 4, 4)
    write_tum_poses(trajectory, np.array([k.stamp_ns for k in data.keyframes]), poses)
    print_text(
        f'wrote {len(exported.points)} points (voxel {size:g} m, fields label, intensity; '
        f'frame {data.frame_id}) to {out} and {len(poses)} keyframe poses to {trajectory}'
    )
    return 0


def import_command(
    cloud_path: Annotated[
        Path, typer.Argument(metavar='CLOUD', help='point map: CLOUD.pcd or CLOUD.ply')
    ],
    map_path: Annotated[Path, typer.Argument(metavar='MAP', help='map folder to write')],
    trajectory: Annotated[
        Path | None,
        typer.Option(
            help="TUM trajectory in the cloud's frame (keyframes every map.keyframe_distance "
            'along it); without it, keyframes on a grid of map.import_grid'
        ),
    ] = None,
    frame_id: Annotated[str, typer.Option(help='frame of the map')] = 'map',
    config: ConfigOption = None,
    labels: LabelsOption = None,
    overrides: SetOption = None,
    force: ForceOption = False,
) -> int:
    """Import a point map as a map folder."""
    from mlsemreg_ros.codec.pose_files import read_tum_poses
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.maps.cloud_files import CloudFileError, read_cloud
    from mlsemreg_ros.core.maps.map_io import MapError, save_map
    from mlsemreg_ros.core.maps.point_map import import_point_map
    from mlsemreg_ros.core.matching.labels import LabelError
    from mlsemreg_ros.evaluation.tables import print_text

    (core,) = settings((RegistrationConfig,), config, with_labels(overrides, labels))
    try:
        cloud = read_cloud(cloud_path)
    except CloudFileError as error:
        raise CommandError(str(error)) from None
    poses = None
    if trajectory is not None:
        try:
            poses = read_tum_poses(trajectory)
        except (OSError, ValueError) as error:
            raise CommandError(f'{trajectory}: not a TUM trajectory: {error}') from None
    try:
        imported = import_point_map(cloud, core, poses)
    except (LabelError, RuntimeError) as error:
        raise CommandError(str(error)) from None
    if not imported.keyframes:
        raise CommandError(f'{cloud_path}: no keyframe (no trajectory pose with map points)')
    replace_output(map_path, force)
    try:
        save_map(map_path, imported.keyframes, frame_id, imported.config)
    except MapError as error:
        raise CommandError(str(error)) from None
    print_text(
        f'wrote {len(imported.keyframes)} keyframes ({imported.placement}, labels: '
        f'{imported.label_source}) from {imported.cloud_points} points to {map_path}'
    )
    return 0
