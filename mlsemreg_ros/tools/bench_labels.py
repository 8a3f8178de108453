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
``mlsemreg bench-labels SCAN...``: the geometric labeler's time and class shares per scan.

Reads PCD/PLY files (Open3D's tensor API) or pair files (``pts_src``), voxelizes them at
``features.voxel_size`` as the pipeline does, and labels each one ``--repeat`` times
(docs/labels.md).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from mlsemreg_ros.tools.common import alias, CommandError, ConfigOption, SetOption, settings
import typer

HELP = (
    "The geometric labeler's time per scan (medians of --repeat runs on the voxelized scan: "
    'wall and CPU time) '
    'and the share of each class, for PCD/PLY scans or pair files.'
)
SHOWN = {40: 'road', 72: 'terrain', 50: 'building', 70: 'veg.', 71: 'trunk', 80: 'pole', 10: 'car'}


def bench_labels(
    scans: Annotated[list[Path], typer.Argument(help='PCD/PLY files or pair files (.npz)')],
    repeat: Annotated[int, typer.Option(min=1, help='runs per scan (the median is shown)')] = 7,
    config: ConfigOption = None,
    overrides: SetOption = None,
) -> int:
    """Time the geometric labeler per scan (alias mlsemreg-bench-labels)."""
    import time

    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.features.features import voxel_downsample
    from mlsemreg_ros.core.labeling.geometric import GeometricLabeler
    from mlsemreg_ros.evaluation.tables import print_table, ResultTable
    import numpy as np

    (core,) = settings((RegistrationConfig,), config, overrides)
    labeler = GeometricLabeler(core.geometric_labels)
    labeler.label(np.random.default_rng(0).normal(0.0, 10.0, (500, 3)))  # compile or load
    rows = []
    for path in scans:
        points = _read(path)
        points = points[np.isfinite(points).all(axis=1)]
        voxels, _ = voxel_downsample(
            points, np.zeros(len(points), dtype=np.int64), core.features.voxel_size
        )
        times, cpu = [], []
        for _ in range(repeat):
            start, start_cpu = time.perf_counter(), time.process_time()
            found = labeler.label(voxels)
            times.append(1e3 * (time.perf_counter() - start))
            cpu.append(1e3 * (time.process_time() - start_cpu))
        shares = found.shares()
        rows.append(
            [
                path.stem,
                str(len(points)),
                str(len(voxels)),
                f'{np.median(times):.1f}',
                f'{np.median(cpu):.1f}',
                f'{found.sensor_height:.2f}',
                *(f'{100 * shares.get(raw, 0.0):.0f}' for raw in SHOWN),
                f'{100 * shares.get(0, 0.0):.0f}',
            ]
        )
    print_table(
        ResultTable(
            ('scan', 'points', 'voxels', 'ms', 'CPU ms', 'height m', *SHOWN.values(), 'unlab.'),
            rows,
            left_columns=1,
        )
    )
    return 0


def _read(path: Path) -> object:
    """Points (N, 3) float64 of a PCD/PLY file or of a pair file's source scan."""
    import numpy as np

    if path.suffix == '.npz':
        with np.load(path) as data:
            if 'pts_src' not in data.files:
                raise CommandError(f'{path}: no pts_src')
            return np.asarray(data['pts_src'], dtype=np.float64)
    import open3d as o3d

    cloud = o3d.t.io.read_point_cloud(str(path))
    if 'positions' not in cloud.point:
        raise CommandError(f'{path}: no points')
    return cloud.point.positions.numpy().astype(np.float64)


main = alias(bench_labels, HELP, 'mlsemreg-bench-labels')
