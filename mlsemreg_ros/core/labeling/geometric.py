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
The geometric labeler: SemanticKITTI raw ids for the classes that geometry can tell.

A stage before matching for scans without labels (docs/labels.md). On the voxelized scan,
in the sensor frame (z up, the sensor at the origin):

1. **Ground** in the manner of Patchwork++ (Lee et al., IROS 2022): a concentric zone
   model (4 zones of 2, 4, 4, 4 rings and 16, 32, 54, 32 sectors), a plane fitted to each
   bin's lowest points and refitted to the points near it, a bin accepted as ground when
   its plane is upright and does not rise above its inner neighbour's ground by more than
   a grade allows. The sensor height is estimated per scan (the median ground height of
   the upright near bins) unless ``geometric_labels.sensor_height`` sets it. Rejected
   bins inherit the ground height of their inner neighbours, so every point gets a
   height above the ground. Ground is road (raw 40), or terrain (72) where its cell is
   rough (``road_roughness``; off by default).
2. **Eigenvalue features** of the points above the ground on a voxel grid of
   ``cell_size``: linearity ``(l1 - l2) / l1``, planarity ``(l2 - l3) / l1``, scatter
   ``l3 / l1`` and the verticality of the normal and principal axis. Vertical planes are
   building (50) where their column reaches ``building_height``, else fence (51);
   vertical lines are pole (80), or trunk (71) under vegetation; scatter is vegetation
   (70); high horizontal planes are building.
3. **Objects**: columns of the ground-grid whose points stay between 0.7 and 2.6 m
   above the ground form 8-connected clusters (scipy.ndimage.label); a compact cluster
   (longest side 1.5 m to ``vehicle_max_length``, smooth surfaces) is a vehicle (car,
   10).

Cells of fewer than three points and points below the ground stay unlabeled (0), which
the matcher treats as undefined.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
import time

from mlsemreg_ros.core.features import kernels
from mlsemreg_ros.core.labeling import geometric_kernels as gk
from mlsemreg_ros.core.labeling.geometric_config import GeometricLabelsConfig
import numpy as np
from scipy import ndimage

# SemanticKITTI raw ids (config/labels/semantic_kitti.yaml)
UNLABELED, CAR, ROAD, BUILDING = 0, 10, 40, 50
VEGETATION, TRUNK, TERRAIN, POLE = 70, 71, 72, 80

#: The concentric zone model of Patchwork++: rings and sectors of each zone, and where each
#: zone starts as a share of ``max_range - min_range`` (2.7, 12.4, 22.0, 41.4 m of 80 m).
ZONE_RINGS = np.array([2, 4, 4, 4], dtype=np.int64)
ZONE_SECTORS = np.array([16, 32, 54, 32], dtype=np.int64)
ZONE_STARTS = np.array([0.0, 0.125, 0.25, 0.5])
LOWEST_POINTS = 20  # points averaged for a bin's lowest-point representative
PLANE_ITERATIONS = 3
MIN_BIN_POINTS = 10
NEAR_ZONES = 2  # the zones whose ground heights estimate the sensor height
GRADE = 0.08  # rise of the ground per metre outwards that a bin may add to its inner one
RISE_MARGIN = 0.3  # metres of rise every ring step may add besides the grade
# eigenvalue-feature rules
LINEAR, SCATTER = 0.7, 0.07
VERTICAL_NORMAL, HORIZONTAL_NORMAL, VERTICAL_AXIS = 0.3, 0.8, 0.9
ALONE = 4  # occupied columns of a pole's 3 x 3 neighbourhood (itself included) at most
ROOF_HEIGHT = 3.0  # horizontal surfaces this high above the ground are building
POLE_CELL = 0.5  # columns of the standing-thing search, m
POLE_BAND = (0.3, 2.5)  # heights above the ground of a trunk or pole's lower part, m
POLE_MIN_EXTENT = 1.0  # vertical extent of the band points of a pole's column, m
POLE_MAX_BASE = 1.2  # a pole's band points start this near the ground, m
POLE_CORE = 4  # occupied columns of the 3 x 3 core at most
POLE_RING_SHARE = 0.2  # band points in the ring around the core, per core point
# vehicle clusters
VEHICLE_LOW, VEHICLE_HIGH, VEHICLE_MIN_LENGTH, VEHICLE_MAX_BASE = 1.0, 2.2, 2.5, 0.6
VEHICLE_MAX_WIDTH = 3.0
VEHICLE_MAX_SCATTER = 0.2  # mean scatter of a vehicle's cells (box corners: 0.15)
VEHICLE_RANGE = 50.0
TRUNK_CANOPY = 1.0  # vegetation at least this far above a vertical line makes it a trunk


@dataclass
class GeometricLabels:
    """Raw ids of one scan and what the labeler found."""

    raw: np.ndarray  # (N,) uint32 SemanticKITTI raw ids
    sensor_height: float  # estimated (or configured) height of the sensor above the ground, m
    timings_ms: dict[str, float] = field(default_factory=dict)

    def shares(self) -> dict[int, float]:
        """Share of the points of each raw id."""
        ids, counts = np.unique(self.raw, return_counts=True)
        total = max(int(self.raw.shape[0]), 1)
        return {int(i): float(c) / total for i, c in zip(ids, counts, strict=True)}


def _zones(config: GeometricLabelsConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Zone start radii, ring widths and bin offsets of the concentric zone model."""
    span = config.max_range - config.min_range
    zone_min = config.min_range + span * ZONE_STARTS
    zone_end = np.append(zone_min[1:], config.max_range)
    ring_width = (zone_end - zone_min) / ZONE_RINGS
    offsets = np.concatenate([[0], np.cumsum(ZONE_RINGS * ZONE_SECTORS)]).astype(np.int64)
    return zone_min, ring_width, offsets


class GeometricLabeler:
    """Label scans by geometry (module docstring); configured once, stateless per scan."""

    def __init__(self, config: GeometricLabelsConfig | None = None) -> None:
        self.config = config if config is not None else GeometricLabelsConfig()

    def label(self, points: np.ndarray) -> GeometricLabels:
        """Raw ids (N,) of a voxelized scan ``points`` (N, 3) in the sensor frame."""
        cfg = self.config
        points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        timings: dict[str, float] = {}
        start = time.perf_counter()
        raw = np.zeros(points.shape[0], dtype=np.uint32)
        if points.shape[0] == 0:
            return GeometricLabels(raw, cfg.sensor_height, timings)
        height, ground, sensor_height = self._ground(points)
        timings['ground_ms'] = 1e3 * (time.perf_counter() - start)
        raw[ground] = ROAD
        middle = time.perf_counter()
        self._above_ground(points, height, ground, raw)
        timings['shape_ms'] = 1e3 * (time.perf_counter() - middle)
        timings['labeling_ms'] = 1e3 * (time.perf_counter() - start)
        return GeometricLabels(raw, sensor_height, timings)

    # ------------------------------------------------------------------------------
    def _ground(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """``(height above the ground (N,), ground (N,) bool, sensor height)``."""
        cfg = self.config
        zone_min, ring_width, offsets = _zones(cfg)
        num_bins = int(offsets[-1])
        bins, order, starts = gk.bin_points(
            points,
            zone_min,
            ring_width,
            ZONE_RINGS,
            ZONE_SECTORS,
            offsets,
            float(cfg.max_range),
            num_bins,
        )
        planes, stats, on_plane = gk.fit_bins(
            points,
            order,
            starts,
            LOWEST_POINTS,
            float(cfg.ground_distance),
            PLANE_ITERATIONS,
            MIN_BIN_POINTS,
        )
        fitted = stats[:, 1] >= 3
        upright = fitted & (planes[:, 2] >= math.cos(math.radians(cfg.max_ground_slope)))
        if cfg.sensor_height > 0:
            ground_z = -cfg.sensor_height
        else:
            near = upright[: offsets[NEAR_ZONES]] & (stats[: offsets[NEAR_ZONES], 1] >= 3)
            if np.any(near):
                ground_z = float(np.median(stats[: offsets[NEAR_ZONES], 2][near]))
            else:
                ground_z = float(np.percentile(points[:, 2], 2.0))
        rise = RISE_MARGIN + GRADE * ring_width
        carried, accepted = gk.carry_ground(
            upright, stats[:, 2], ZONE_RINGS, ZONE_SECTORS, offsets, ground_z, rise
        )
        height = gk.height_above_ground(points, bins, planes, accepted, carried, ground_z)
        in_accepted = np.zeros(points.shape[0], dtype=bool)
        inside = bins >= 0
        in_accepted[inside] = accepted[bins[inside]]
        distance = cfg.ground_distance
        reach = np.einsum('ij,ij->i', points[:, :2], points[:, :2]) < cfg.max_range**2
        near_ground = (height < distance) & (height > -3.0 * distance) & reach
        ground = np.where(in_accepted, on_plane | near_ground, near_ground)
        return height, ground, -ground_z

    def _above_ground(
        self, points: np.ndarray, height: np.ndarray, ground: np.ndarray, raw: np.ndarray
    ) -> None:
        """Label the points above the ground in ``raw`` (building, fence, pole, ...)."""
        cfg = self.config
        reach = np.einsum('ij,ij->i', points[:, :2], points[:, :2]) < cfg.max_range**2
        rows = np.flatnonzero(~ground & (height >= cfg.ground_distance) & reach)
        if rows.shape[0] == 0:
            return
        above = points[rows]
        h = height[rows]
        grid = kernels.voxel_grid(above, cfg.cell_size)
        if grid is None:  # coordinates beyond int64 keys: leave them unlabeled
            return
        inverse = grid[0]
        features, counts = gk.cell_features(above, inverse, int(grid[2].shape[0]))
        per_point = features[inverse]
        described = counts[inverse] >= 3
        linear, scatter = per_point[:, 0], per_point[:, 2]
        normal_z, axis_z = per_point[:, 3], per_point[:, 4]
        # columns of a dense ground grid around the sensor
        side = math.ceil(2.0 * cfg.max_range / cfg.cell_size)
        ix = np.floor((above[:, 0] + cfg.max_range) / cfg.cell_size).astype(np.int64)
        iy = np.floor((above[:, 1] + cfg.max_range) / cfg.cell_size).astype(np.int64)
        column = np.where((ix >= 0) & (ix < side) & (iy >= 0) & (iy < side), ix * side + iy, -1)
        everything = np.ones(rows.shape[0], dtype=bool)
        top, base = gk.column_extent(column, h, everything, side * side)
        canopy, _ = gk.column_extent(column, h, described & (scatter >= SCATTER), side * side)
        inside = column >= 0
        column_canopy = np.where(inside, canopy[np.maximum(column, 0)], -np.inf)

        labels = np.full(rows.shape[0], UNLABELED, dtype=np.uint32)
        is_scatter = described & (scatter >= SCATTER)
        labels[described] = VEGETATION  # scatter, and what no rule below claims
        # vertical lines standing alone: few occupied columns in their 3 x 3 neighbourhood
        occupied = np.zeros(side * side, dtype=np.float64)
        occupied[column[inside]] = 1.0
        crowd = ndimage.uniform_filter(
            occupied.reshape(side, side), size=3, mode='constant'
        ).reshape(-1)
        alone = np.zeros(rows.shape[0], dtype=bool)
        alone[inside] = 9.0 * crowd[column[inside]] <= ALONE + 0.5
        line = described & ~is_scatter & (linear >= LINEAR) & (axis_z >= VERTICAL_AXIS) & alone
        surface = described & ~is_scatter & ~line
        labels[surface & (normal_z < VERTICAL_NORMAL)] = BUILDING
        labels[surface & (normal_z > HORIZONTAL_NORMAL) & (h >= ROOF_HEIGHT)] = BUILDING
        labels[line] = np.where(column_canopy[line] >= h[line] + TRUNK_CANOPY, TRUNK, POLE)
        standing = self._standing(above, h)
        labels[standing] = np.where(
            column_canopy[standing] >= h[standing] + TRUNK_CANOPY, TRUNK, POLE
        )
        vehicle = self._vehicles(top, base, column, scatter, described, side)
        labels[vehicle & (h >= cfg.ground_distance)] = CAR
        raw[rows] = labels

    def _standing(self, above: np.ndarray, h: np.ndarray) -> np.ndarray:
        """
        Points of thin things standing alone (poles, trunks, sign posts) among ``above``.

        On a ground grid of ``POLE_CELL`` columns: a column whose points in the trunk band
        (``POLE_BAND`` above the ground) reach from near the ground at least
        ``POLE_MIN_EXTENT`` up, in a 3 x 3 core of at most ``POLE_CORE`` occupied columns,
        with at most ``POLE_RING_SHARE`` of the core's band points in the ring of columns
        around the core (5 x 5 minus 3 x 3).
        """
        cfg = self.config
        side = math.ceil(2.0 * cfg.max_range / POLE_CELL)
        ix = np.floor((above[:, 0] + cfg.max_range) / POLE_CELL).astype(np.int64)
        iy = np.floor((above[:, 1] + cfg.max_range) / POLE_CELL).astype(np.int64)
        inside = (ix >= 0) & (ix < side) & (iy >= 0) & (iy < side)
        column = np.where(inside, ix * side + iy, 0)
        band = inside & (h >= POLE_BAND[0]) & (h <= POLE_BAND[1])
        counts = np.bincount(column[band], minlength=side * side).astype(np.float64)
        low, high = gk.column_extent(np.where(band, column, -1), h, band, side * side)[::-1]
        grid = counts.reshape(side, side)
        core = ndimage.uniform_filter(grid, size=3, mode='constant') * 9.0
        wide = ndimage.uniform_filter(grid, size=5, mode='constant') * 25.0
        occupied = ndimage.uniform_filter((grid > 0).astype(np.float64), size=3, mode='constant')
        candidate = (
            (high - low >= POLE_MIN_EXTENT)
            & (low <= POLE_MAX_BASE)
            & (9.0 * occupied.reshape(-1) <= POLE_CORE + 0.5)
            & ((wide - core).reshape(-1) <= POLE_RING_SHARE * core.reshape(-1))
        )
        # the candidate's own and its occupied neighbour columns, every height
        grown = ndimage.binary_dilation(
            candidate.reshape(side, side), structure=np.ones((3, 3), dtype=bool)
        ).reshape(-1)
        return inside & grown[column] & (counts[column] > 0)

    def _vehicles(
        self,
        top: np.ndarray,
        base: np.ndarray,
        column: np.ndarray,
        scatter: np.ndarray,
        described: np.ndarray,
        side: int,
    ) -> np.ndarray:
        """Points (of the above-ground rows) in compact, smooth clusters of low columns."""
        cfg = self.config
        low = (top >= VEHICLE_LOW) & (top <= VEHICLE_HIGH) & (base <= VEHICLE_MAX_BASE)
        # only near the sensor: far clusters are too sparse to tell
        centre = (np.arange(side) + 0.5) * cfg.cell_size - cfg.max_range
        near = (centre[:, None] ** 2 + centre[None, :] ** 2) <= VEHICLE_RANGE**2
        raster = low.reshape(side, side) & near
        clusters, count = ndimage.label(raster, structure=np.ones((3, 3), dtype=bool))
        if count == 0:
            return np.zeros(column.shape[0], dtype=bool)
        keep = np.zeros(count + 1, dtype=bool)
        for index, box in enumerate(ndimage.find_objects(clusters), start=1):
            sides = sorted((box[0].stop - box[0].start, box[1].stop - box[1].start))
            width, length = sides[0] * cfg.cell_size, sides[1] * cfg.cell_size
            keep[index] = (
                VEHICLE_MIN_LENGTH <= length <= cfg.vehicle_max_length
                and width <= VEHICLE_MAX_WIDTH
            )
        flat_clusters = clusters.reshape(-1)
        point_cluster = np.where(column >= 0, flat_clusters[np.maximum(column, 0)], 0)
        # smooth surfaces: the cluster's mean scatter of its described points stays low
        weights = described.astype(np.float64)
        total = np.bincount(point_cluster, weights=weights, minlength=count + 1)
        rough = np.bincount(point_cluster, weights=weights * scatter, minlength=count + 1)
        smooth = rough <= VEHICLE_MAX_SCATTER * np.maximum(total, 1.0)
        keep &= smooth
        keep[0] = False
        return keep[point_cluster]
