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
Relocalization queries from a second simulated drive (``mlsemreg map sim-queries``).

The drive goes through the world of ``mlsemreg simulate --seed S``: the same streets
backwards in the other lane (``reverse``, revisit.py), or a route of another seed kept where
it is far from the first drive (``other``). In the field world (field_revisit.py) the sweeps
are deskewed by the odometry (``deskew: odometry``: the scans it deskewed, the points the
node relocalizes; field_odometry_queries.py), by the true twist, or not at all. Every
``every``-th scan is written as a query file (datasets/query_files.py); docs/maps.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mlsemreg_ros.datasets.query_files import write_query
from mlsemreg_ros.simulation.field import FieldConfig
from mlsemreg_ros.simulation.field_odometry_queries import odometry_queries, OdometryQueryCount
from mlsemreg_ros.simulation.field_revisit import (
    field_other_drive,
    field_other_sweeps,
    field_reverse_drive,
    field_reverse_sweeps,
    render_field_queries,
    render_other_queries,
)
from mlsemreg_ros.simulation.revisit import other_drive, render_queries, reverse_drive
from mlsemreg_ros.simulation.sequence import SimulationConfig
import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class SimQueries:
    """What to write: the mapped drive, the second drive and its sweeps (docs/maps.md)."""

    seed: int = 0  # of the mapped drive (mlsemreg simulate --seed)
    frames: int = 200  # of the mapped drive
    drive: str = 'reverse'  # reverse | other
    every: int = 5  # every K-th scan
    lane_change: float = 3.6  # reverse: lateral shift to the left, m
    start_offset: float = 0.5  # reverse: metres skipped at the start
    route_seed: int = 7  # other, clean: the route's seed
    route_frames: int = 300  # other, clean: the route's frames
    min_distance: float = 80.0  # other: scans at least this far from the mapped drive, m
    noise_seed: int = 1000  # of the sensor noise
    realism: str = 'clean'  # clean | field
    deskew: str = 'odometry'  # field: odometry | previous | sweep | off


def write_sim_queries(out: Path, request: SimQueries, registration: Any = None) -> str:
    """
    Write the queries into the new folder ``out``; return the line that says what was written.

    ``registration``: the odometry's registration (field, ``deskew: odometry``).
    """
    if request.realism == 'field':
        written, note = write_field_queries(out, request, registration)
        return (
            f'wrote {written} queries ({request.drive} field drive, deskew {request.deskew}'
            f'{note}) to {out}'
        )
    clean = SimulationConfig(seed=request.seed, frames=request.frames)
    if request.drive == 'reverse':
        sim, world_poses = reverse_drive(
            clean, request.lane_change, request.start_offset, request.noise_seed
        )
        indices = np.arange(0, len(world_poses), request.every)
    else:
        sim, world_poses = other_drive(clean, request.route_seed, request.route_frames)
        mapped = sim.world_poses[:, :2, 3]
        distance = cKDTree(mapped).query(world_poses[:, :2, 3])[0]
        indices = np.arange(0, len(world_poses), request.every)
        indices = indices[distance[indices] >= request.min_distance]
    out.mkdir(parents=True)
    for query in render_queries(sim, world_poses, indices, request.noise_seed):
        write_query(
            out / f'{query.index:06d}.npz', query.points, query.labels, query.T_map_scan, 0
        )
    return f'wrote {len(indices)} queries ({request.drive} drive) to {out}'


def write_field_queries(
    out: Path, request: SimQueries, registration: Any = None
) -> tuple[int, str]:
    """
    Write the queries of a second field-mode drive (simulation/field_revisit.py).

    Returns the number written and a note on the sweeps skipped (``deskew: odometry``).
    """
    drive, deskew, every = request.drive, request.deskew, request.every
    noise_seed = request.noise_seed
    config = FieldConfig(seed=request.seed, frames=request.frames)
    if drive == 'reverse':
        sim, reverse, starts = field_reverse_drive(
            config, request.lane_change, request.start_offset, noise_seed
        )
        indices = np.arange(0, len(starts), every)
    else:
        sim, other = field_other_drive(config)
        distance = cKDTree(sim.world_poses[:, :2, 3]).query(other.world_poses[:, :2, 3])[0]
        indices = np.arange(0, len(other), every)
        indices = indices[distance[indices] >= request.min_distance]
    count = OdometryQueryCount()
    if deskew == 'odometry':  # every sweep up to the last query goes through the odometry
        last = int(indices[-1]) + 1 if len(indices) else 0
        sweeps = (
            field_reverse_sweeps(sim, reverse, starts, last, noise_seed)
            if drive == 'reverse'
            else field_other_sweeps(sim, other, last)
        )
        queries = odometry_queries(sweeps, {int(i) for i in indices}, registration, count)
    elif drive == 'reverse':
        queries = render_field_queries(sim, reverse, starts, indices, noise_seed, deskew)
    else:
        queries = render_other_queries(sim, other, indices, deskew)
    out.mkdir(parents=True)
    written = 0
    dtype = 'float64' if deskew == 'odometry' else 'float32'  # the odometry's points, exactly
    for query in queries:
        write_query(
            out / f'{query.index:06d}.npz',
            query.points,
            query.labels,
            query.T_map_scan,
            0,
            dtype,
        )
        written += 1
    note = ''
    if deskew == 'odometry':
        note = (
            f': {count.sweeps} sweeps through the odometry, {count.accepted} accepted; of '
            f'{count.wanted} queries, {count.rejected} rejected and {count.skewed} not '
            'deskewed by it, skipped'
        )
    return written, note
