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
   building (50, walls and fences as one class); vertical lines standing alone within
   ``LINE_RANGE`` of the sensor, and thin columns standing alone on the ground
   (``_standing``), are pole (80), or trunk (71) under vegetation; scatter is vegetation
   (70); high horizontal planes are building.
3. **Objects**: columns of the ground grid whose points stay between 1.0 and 2.2 m
   above the ground form 8-connected clusters (sparse connected components); a compact
   cluster (longest side 2.5 m to ``vehicle_max_length``, smooth surfaces) is a vehicle
   (car, 10).
4. **Support**: a pole, trunk or car point keeps its class only when at least
   ``LANDMARK_SUPPORT`` of the points within ``SUPPORT_RADIUS`` share it, else it takes
   its runner-up class (the shape class under it). Stray object points make landmarks
   that the next scan does not see again (dev pairs: of 144 pole/trunk/car landmarks in
   the 10 source scans, 10 % were found again at the true pose, against 39 % for the network's).

Every point also gets a runner-up class (``GeometricLabels.second``): the shape class
under an object, or the other of building and vegetation where the scatter is near the
line between them.

Cells of fewer than three points and points below the ground stay unlabeled (0), which
the matcher treats as undefined.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
import time

from mlsemreg_ros.core.features import kernels
from mlsemreg_ros.core.features.cell_grid import CellGrid
from mlsemreg_ros.core.labeling import geometric_kernels as gk
from mlsemreg_ros.core.labeling.geometric_config import GeometricLabelsConfig
from mlsemreg_ros.core.matching import landmarks
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

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
#: vertical lines in the 1 m cells are poles only this near the sensor: farther, the cells
#: hold few rings and their lines are mostly not found again (docs/labels.md)
LINE_RANGE = 20.0
TRUNK_CANOPY = 1.0  # vegetation at least this far above a vertical line makes it a trunk
# object points (the matcher's landmark classes) need this share of their neighbours
OBJECT_IDS = np.array([POLE, TRUNK, CAR], dtype=np.uint32)
LANDMARK_SUPPORT = 0.4
SUPPORT_RADIUS = 0.6  # m, as semantic.landmark_support_radius
SECOND_MARGIN = 2.0  # scatter within this factor of SCATTER: building and vegetation both


@dataclass
class GeometricLabels:
    """Raw ids of one scan and what the labeler found."""

    raw: np.ndarray  # (N,) uint32 SemanticKITTI raw ids
    sensor_height: float  # estimated (or configured) height of the sensor above the ground, m
    timings_ms: dict[str, float] = field(default_factory=dict)
    #: (N,) uint32 raw id of each point's runner-up class (its own where no rule was close)
    second: np.ndarray | None = None

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
            return GeometricLabels(raw, cfg.sensor_height, timings, raw.copy())
        height, ground, sensor_height = self._ground(points)
        timings['ground_ms'] = 1e3 * (time.perf_counter() - start)
        raw[ground] = ROAD
        second = raw.copy()
        middle = time.perf_counter()
        self._above_ground(points, height, ground, raw, second)
        if LANDMARK_SUPPORT > 0:
            _drop_unsupported(points, raw, second)
        timings['shape_ms'] = 1e3 * (time.perf_counter() - middle)
        timings['labeling_ms'] = 1e3 * (time.perf_counter() - start)
        return GeometricLabels(raw, sensor_height, timings, second)

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
        self,
        points: np.ndarray,
        height: np.ndarray,
        ground: np.ndarray,
        raw: np.ndarray,
        second: np.ndarray,
    ) -> None:
        """
        Label the points above the ground in ``raw`` (building, pole, vehicle, ...).

        ``second`` gets each point's runner-up: the shape class (building / vegetation)
        under a pole, trunk or vehicle, and the other of building and vegetation where the
        scatter lies within a factor ``SECOND_MARGIN`` of ``SCATTER``.
        """
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
        is_scatter = described & (scatter >= SCATTER)
        # the occupied columns of the ground grid (only those: no dense raster)
        columns = Columns.of(above, cfg.cell_size)
        everything = np.ones(rows.shape[0], dtype=bool)
        top, base = gk.column_extent(columns.index, h, everything, columns.count)
        canopy, _ = gk.column_extent(columns.index, h, is_scatter, columns.count)
        column_canopy = canopy[columns.index]

        labels = np.full(rows.shape[0], UNLABELED, dtype=np.uint32)
        labels[described] = VEGETATION  # scatter, and what no rule below claims
        # vertical lines standing alone: few occupied columns in their 3 x 3 neighbourhood
        crowd = columns.window_sum(np.ones(columns.count), 1)
        alone = crowd[columns.index] <= ALONE
        line = described & ~is_scatter & (linear >= LINEAR) & (axis_z >= VERTICAL_AXIS) & alone
        line &= np.einsum('ij,ij->i', above[:, :2], above[:, :2]) < LINE_RANGE**2
        surface = described & ~is_scatter & ~line
        labels[surface & (normal_z < VERTICAL_NORMAL)] = BUILDING
        labels[surface & (normal_z > HORIZONTAL_NORMAL) & (h >= ROOF_HEIGHT)] = BUILDING
        shape_labels = labels.copy()
        labels[line] = np.where(column_canopy[line] >= h[line] + TRUNK_CANOPY, TRUNK, POLE)
        standing = self._standing(above, h)
        labels[standing] = np.where(
            column_canopy[standing] >= h[standing] + TRUNK_CANOPY, TRUNK, POLE
        )
        vehicle = self._vehicles(columns, top, base, scatter, described)
        labels[vehicle & (h >= cfg.ground_distance)] = CAR
        raw[rows] = labels
        # the runner-up: the shape class under an object, else building <-> vegetation
        # where the scatter is close to the line between them
        runner_up = shape_labels.copy()
        close = (
            described
            & (scatter >= SCATTER / SECOND_MARGIN)
            & (scatter < SCATTER * SECOND_MARGIN)
            & (labels == shape_labels)
        )
        runner_up[close & (labels == VEGETATION)] = BUILDING
        runner_up[close & (labels == BUILDING)] = VEGETATION
        second[rows] = runner_up

    def _standing(self, above: np.ndarray, h: np.ndarray) -> np.ndarray:
        """
        Points of thin things standing alone (poles, trunks, sign posts) among ``above``.

        On a ground grid of ``POLE_CELL`` columns: a column whose points in the trunk band
        (``POLE_BAND`` above the ground) reach from near the ground at least
        ``POLE_MIN_EXTENT`` up, in a 3 x 3 core of at most ``POLE_CORE`` occupied columns,
        with at most ``POLE_RING_SHARE`` of the core's band points in the ring of columns
        around the core (5 x 5 minus 3 x 3).
        """
        band = (h >= POLE_BAND[0]) & (h <= POLE_BAND[1])
        if not band.any():
            return np.zeros(h.shape[0], dtype=bool)
        columns = Columns.of(above, POLE_CELL)
        counts = np.bincount(columns.index[band], minlength=columns.count).astype(np.float64)
        high, low = gk.column_extent(columns.index, h, band, columns.count)
        core = columns.window_sum(counts, 1)
        wide = columns.window_sum(counts, 2)
        occupied = columns.window_sum((counts > 0).astype(np.float64), 1)
        candidate = (
            (high - low >= POLE_MIN_EXTENT)
            & (low <= POLE_MAX_BASE)
            & (occupied <= POLE_CORE)
            & (wide - core < POLE_RING_SHARE * core)
        )
        # the candidate's own and its neighbour columns with band points, every height
        grown = columns.window_sum(candidate.astype(np.float64), 1) > 0
        return grown[columns.index] & (counts[columns.index] > 0)

    def _vehicles(
        self,
        columns: Columns,
        top: np.ndarray,
        base: np.ndarray,
        scatter: np.ndarray,
        described: np.ndarray,
    ) -> np.ndarray:
        """Points (of the above-ground rows) in compact, smooth clusters of low columns."""
        cfg = self.config
        low = (top >= VEHICLE_LOW) & (top <= VEHICLE_HIGH) & (base <= VEHICLE_MAX_BASE)
        # only near the sensor: far clusters are too sparse to tell
        centre = (columns.cells + 0.5) * cfg.cell_size
        low &= np.einsum('ij,ij->i', centre, centre) <= VEHICLE_RANGE**2
        cluster = columns.clusters(low)  # -1: not a low column
        count = int(cluster.max(initial=-1)) + 1
        if count == 0:
            return np.zeros(columns.index.shape[0], dtype=bool)
        members = cluster >= 0
        ix, iy, which = columns.cells[members, 0], columns.cells[members, 1], cluster[members]
        lengths = []
        for axis in (ix, iy):
            lo = np.full(count, np.iinfo(np.int64).max)
            hi = np.full(count, np.iinfo(np.int64).min)
            np.minimum.at(lo, which, axis)
            np.maximum.at(hi, which, axis)
            lengths.append((hi - lo + 1) * cfg.cell_size)
        width, length = np.minimum(*lengths), np.maximum(*lengths)
        keep = (
            (length >= VEHICLE_MIN_LENGTH)
            & (length <= cfg.vehicle_max_length)
            & (width <= VEHICLE_MAX_WIDTH)
        )
        point_cluster = cluster[columns.index]
        # smooth surfaces: the cluster's mean scatter of its described points stays low
        inside = point_cluster >= 0
        weights = described[inside].astype(np.float64)
        total = np.bincount(point_cluster[inside], weights=weights, minlength=count)
        rough = np.bincount(
            point_cluster[inside], weights=weights * scatter[inside], minlength=count
        )
        keep &= rough <= VEHICLE_MAX_SCATTER * np.maximum(total, 1.0)
        return inside & keep[np.maximum(point_cluster, 0)]


def _drop_unsupported(points: np.ndarray, raw: np.ndarray, second: np.ndarray) -> None:
    """
    Give pole, trunk and vehicle points without support their runner-up class (in place).

    A point keeps its object class when at least ``LANDMARK_SUPPORT`` of the points within
    ``SUPPORT_RADIUS`` share it (``landmarks.confident_points``, the test the matcher applies
    to its landmarks with ``semantic.landmark_min_share``): stray object points on walls
    and hedges make landmarks that the next scan does not see again.
    """
    objects = np.isin(raw, OBJECT_IDS)
    if not objects.any():
        return
    # only the points in the objects' box (grown by the radius) can be their neighbours
    low = points[objects].min(axis=0) - SUPPORT_RADIUS
    high = points[objects].max(axis=0) + SUPPORT_RADIUS
    box = np.flatnonzero(
        (points[:, 0] >= low[0])
        & (points[:, 0] <= high[0])
        & (points[:, 1] >= low[1])
        & (points[:, 1] <= high[1])
        & (points[:, 2] >= low[2])
        & (points[:, 2] <= high[2])
    )
    near, labels, selected = points[box], raw[box], objects[box]
    rows = np.flatnonzero(selected)
    grid = CellGrid.build(near, SUPPORT_RADIUS)
    if grid.base.shape[0] == 0:  # a box too large for cells: the KD-tree counts
        local = landmarks.confident_points(
            near, labels, selected, LANDMARK_SUPPORT, SUPPORT_RADIUS
        )
    else:
        total, same = gk.support_counts(near, rows, labels, selected, SUPPORT_RADIUS, grid)
        local = same >= LANDMARK_SUPPORT * total
    rows = box[rows[~local]]
    raw[rows] = second[rows]


@dataclass
class Columns:
    """The occupied columns of a ground grid: integer cells, and the points' column."""

    cells: np.ndarray  # (M, 2) int64 cell of each occupied column (floor(xy / size))
    keys: np.ndarray  # (M,) int64 sorted linear keys of the cells
    index: np.ndarray  # (N,) int64 column of every point
    span: int  # key = (ix + offset) * span + (iy + offset)
    offset: int
    neighbours: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)  # cache

    @classmethod
    def of(cls, points: np.ndarray, size: float) -> Columns:
        """Columns of ``points`` (N, 3) on a grid of ``size`` metres."""
        cell = np.floor(points[:, :2] / size).astype(np.int64)
        offset = int(-cell.min(initial=0)) + 2
        span = int(cell.max(initial=0)) + offset + 3
        key = (cell[:, 0] + offset) * span + (cell[:, 1] + offset)
        keys, first, index = np.unique(key, return_index=True, return_inverse=True)
        return cls(cell[first], keys, index.reshape(-1), span, offset)

    @property
    def count(self) -> int:
        """Return the number of occupied columns."""
        return int(self.keys.shape[0])

    def _neighbour(self, dx: int, dy: int) -> np.ndarray:
        """Column of each column's neighbour at ``(dx, dy)`` cells, -1 where unoccupied."""
        known = self.neighbours.get((dx, dy))
        if known is None:
            wanted = self.keys + dx * self.span + dy
            found = np.minimum(np.searchsorted(self.keys, wanted), self.count - 1)
            known = self.neighbours[dx, dy] = np.where(self.keys[found] == wanted, found, -1)
        return known

    def window_sum(self, values: np.ndarray, radius: int) -> np.ndarray:
        """Sum of ``values`` (M,) over each column's (2 radius + 1)^2 window (compiled)."""
        return gk.window_sum(
            self.keys, self.span, np.ascontiguousarray(values, dtype=np.float64), radius
        )

    def clusters(self, member: np.ndarray) -> np.ndarray:
        """8-connected clusters of the ``member`` columns: (M,) cluster id, -1 for others."""
        rows, cols = [], []
        for dx, dy in ((1, -1), (1, 0), (1, 1), (0, 1)):
            neighbour = self._neighbour(dx, dy)
            linked = member & (neighbour >= 0)
            linked[linked] &= member[neighbour[linked]]
            rows.append(np.flatnonzero(linked))
            cols.append(neighbour[linked])
        rows_all, cols_all = np.concatenate(rows), np.concatenate(cols)
        graph = coo_matrix(
            (np.ones(rows_all.shape[0]), (rows_all, cols_all)), shape=(self.count, self.count)
        )
        _, label = connected_components(graph, directed=False)
        out = np.full(self.count, -1, dtype=np.int64)
        _, out[member] = np.unique(label[member], return_inverse=True)
        return out
