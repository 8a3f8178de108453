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
Second drives through a simulated world, for relocalization queries (docs/maps.md).

- :func:`reverse_drive`: the streets of a drive again, in the opposite direction, in the
  other lane (``lane_change`` metres to the first drive's left) and starting
  ``start_offset`` metres later, with its own noise: the scans never repeat the map's.
- :func:`other_drive`: a route of another seed through the same world (the same blocks,
  built around the new route), for queries from streets the map has not seen.

Poses are ``T_map_scan`` with ``map`` the first sensor pose of the first drive (the frame
of its ground truth and of a map built from it).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

from mlsemreg_ros.simulation.sequence import drive_poses, Simulation, SimulationConfig
from mlsemreg_ros.simulation.trajectory import frame_positions, Path2D, plan_route
from mlsemreg_ros.simulation.world import build_world
import numpy as np


@dataclass
class QueryScan:
    """A scan of a second drive with its pose in the first drive's map frame."""

    index: int
    points: np.ndarray  # (N, 3) float32 sensor frame
    labels: np.ndarray  # (N,) int32 learning ids
    T_map_scan: np.ndarray  # (4, 4)


def clip_path(path: Path2D, length: float) -> Path2D:
    """Return the first ``length`` metres of ``path``."""
    ends = np.cumsum(path.lengths)
    count = int(np.searchsorted(ends, length)) + 1
    lengths = path.lengths[:count].copy()
    lengths[-1] -= max(0.0, float(ends[count - 1]) - length)
    return Path2D(path.starts[:count], path.headings[:count], lengths, path.curvatures[:count])


def reversed_path(path: Path2D, shift_right: float) -> Path2D:
    """Return ``path`` driven backwards, moved ``shift_right`` metres to the new right."""
    starts, headings, lengths, curvatures = [], [], [], []
    for start, heading, length, k in zip(
        path.starts[::-1],
        path.headings[::-1],
        path.lengths[::-1],
        path.curvatures[::-1],
        strict=False,
    ):
        end_heading = heading + k * length
        if abs(k) < 1e-12:
            end = start + length * np.array([np.cos(heading), np.sin(heading)])
        else:
            end = (
                start
                + np.array(
                    [np.sin(end_heading) - np.sin(heading), np.cos(heading) - np.cos(end_heading)]
                )
                / k
            )
        new_heading, new_k = end_heading + np.pi, -k
        right = np.array([np.sin(new_heading), -np.cos(new_heading)])
        # parallel curve at distance d to the right: radius 1/k grows by d (left turns)
        scale = 1.0 + new_k * shift_right
        starts.append(end + shift_right * right)
        headings.append(new_heading)
        lengths.append(length * scale)
        curvatures.append(new_k / scale)
    return Path2D(np.array(starts), np.array(headings), np.array(lengths), np.array(curvatures))


def _driven_length(sim: Simulation) -> float:
    cfg = sim.config
    s = frame_positions(sim.path, cfg.frames, cfg.step, cfg.trajectory, 1.0 / cfg.rate_hz)
    return float(s[-1])


def reverse_drive(
    config: SimulationConfig,
    lane_change: float = 3.6,
    start_offset: float = 0.5,
    noise_seed: int = 1000,
) -> tuple[Simulation, np.ndarray]:
    """Return the first drive's simulation and the world poses (F, 4, 4) driven back."""
    sim = Simulation(config)
    driven = _driven_length(sim)
    path = reversed_path(clip_path(sim.path, driven), lane_change)
    path = clip_path_from(path, start_offset)
    frames = max(int((path.length - 1.0) / config.step), 1)
    poses = drive_poses(config, path, frames, np.random.default_rng([noise_seed, 4]))
    return sim, poses


def clip_path_from(path: Path2D, offset: float) -> Path2D:
    """Return ``path`` without its first ``offset`` metres."""
    if offset <= 0:
        return path
    ends = np.cumsum(path.lengths)
    first = int(np.searchsorted(ends, offset, side='right'))
    into = offset - (float(ends[first - 1]) if first else 0.0)
    start, heading = path.sample(np.array([offset]))
    lengths = path.lengths[first:].copy()
    lengths[0] -= into
    starts, headings = path.starts[first:].copy(), path.headings[first:].copy()
    starts[0], headings[0] = start[0], heading[0]
    return Path2D(starts, headings, lengths, path.curvatures[first:].copy())


def other_drive(
    config: SimulationConfig, route_seed: int, frames: int
) -> tuple[Simulation, np.ndarray]:
    """Return the first drive's simulation around a ``route_seed`` route, and its poses."""
    sim = Simulation(config)
    length = max(frames - 1, 1) * config.step + 60.0
    path = plan_route(sim.grid, length, np.random.default_rng([route_seed, 3]), config.trajectory)
    route_xy = np.concatenate([sim.path.waypoints(), path.waypoints()])
    world_cfg = replace(config.world, seed=config.seed)
    sim.world = build_world(sim.grid, route_xy, world_cfg, sim.label_map)
    from mlsemreg_ros.simulation.lidar import Lidar

    sim.lidar = Lidar(sim.world, config.lidar)
    poses = drive_poses(config, path, frames, np.random.default_rng([route_seed, 4]))
    return sim, poses


def render_queries(
    sim: Simulation, world_poses: np.ndarray, indices: np.ndarray, noise_seed: int
) -> Iterator[QueryScan]:
    """Render ``sim``'s world at ``world_poses[indices]``, poses in the map frame."""
    origin_inv = np.linalg.inv(sim.world_poses[0])
    for index in np.asarray(indices, dtype=np.int64):
        scan = sim.lidar.scan(
            world_poses[index], np.random.default_rng([noise_seed, 5, int(index)])
        )
        yield QueryScan(int(index), scan.points, scan.labels, origin_inv @ world_poses[index])
