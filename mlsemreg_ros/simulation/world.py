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
A seeded procedural street world of labeled triangle meshes.

The layout is an irregular street grid (block spacing, street widths and
sidewalks drawn per seed). Each block is one of five kinds -- urban (rows of
buildings), residential (houses, gardens, fences, hedges), park (trees, bushes,
paths), parking (rows of cars and trucks) or industrial (warehouses, trucks,
fences) -- and every block side carries street furniture (lamp poles, street
trees, traffic signs, clutter) and parked vehicles along the curb. Every
triangle carries a SemanticKITTI learning id and an instance id (cars and trucks).

Everything is seeded per block (``rng([seed, i, j])``), so a block looks the same
whatever part of the world is built.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import NamedTuple

from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.simulation import primitives as prim
from mlsemreg_ros.simulation.primitives import Mesh
import numpy as np

#: Offset that keeps grid indices non-negative in the seed entropy.
_INDEX_OFFSET = 1000

BLOCK_KINDS = ('urban', 'residential', 'park', 'parking', 'industrial')


@dataclass
class WorldConfig:
    """Layout parameters of the procedural world (lengths in metres)."""

    seed: int = 0
    grid_lines: int = 30  # street lines on each side of the origin, per axis
    block_spacing: tuple[float, float] = (60.0, 115.0)  # street centre line distance
    street_widths: tuple[float, ...] = (10.0, 12.0, 16.0)
    street_width_weights: tuple[float, ...] = (0.4, 0.4, 0.2)
    sidewalk_width: tuple[float, float] = (2.5, 4.5)
    block_kind_weights: tuple[float, ...] = (0.38, 0.26, 0.12, 0.1, 0.14)  # BLOCK_KINDS order
    margin: float = 130.0  # blocks farther than this from the route are not built
    lamp_spacing: tuple[float, float] = (18.0, 32.0)
    tree_spacing: tuple[float, float] = (7.0, 13.0)


@dataclass
class StreetGrid:
    """
    Street centre lines of the grid and their widths.

    Streets along ``x = xs[i]`` run in y, streets along ``y = ys[j]`` run in x;
    block ``(i, j)`` lies between lines i, i+1 and j, j+1.
    """

    xs: np.ndarray  # (G,) metres, increasing
    ys: np.ndarray  # (G,)
    widths_x: np.ndarray  # (G,) road width of the street along x = xs[i]
    widths_y: np.ndarray  # (G,)
    origin: int  # index of the line through 0 (on both axes)

    @classmethod
    def generate(cls, config: WorldConfig) -> StreetGrid:
        """Draw line spacings and street widths from the seed."""
        lines = []
        for axis in (0, 1):
            rng = np.random.default_rng([config.seed, 11, axis])
            gaps = rng.uniform(*config.block_spacing, size=(2, config.grid_lines))
            coords = np.concatenate([-np.cumsum(gaps[0])[::-1], [0.0], np.cumsum(gaps[1])])
            weights = np.asarray(config.street_width_weights) / np.sum(config.street_width_weights)
            widths = rng.choice(np.asarray(config.street_widths), size=coords.size, p=weights)
            lines.append((coords, widths))
        return cls(lines[0][0], lines[1][0], lines[0][1], lines[1][1], config.grid_lines)

    def intersection(self, i: int, j: int) -> np.ndarray:
        """(2,) centre of the crossing of lines x_i and y_j."""
        return np.array([self.xs[i], self.ys[j]])

    def block_rect(self, i: int, j: int) -> tuple[float, float, float, float]:
        """Curb rectangle ``(x0, x1, y0, y1)`` of block (i, j)."""
        return (
            self.xs[i] + 0.5 * self.widths_x[i],
            self.xs[i + 1] - 0.5 * self.widths_x[i + 1],
            self.ys[j] + 0.5 * self.widths_y[j],
            self.ys[j + 1] - 0.5 * self.widths_y[j + 1],
        )


@dataclass
class World:
    """All triangles of the world with their SemanticKITTI class and instance."""

    vertices: np.ndarray  # (V, 3) float32, metres, world frame (z up, ground at 0)
    triangles: np.ndarray  # (T, 3) uint32
    triangle_labels: np.ndarray  # (T,) int32 learning ids
    triangle_instances: np.ndarray  # (T,) uint32 instance ids (0: none)
    grid: StreetGrid
    blocks: dict[tuple[int, int], str]  # built blocks and their kind
    object_counts: dict[str, int] = field(default_factory=dict)

    @property
    def num_triangles(self) -> int:
        """Return the number of triangles."""
        return int(self.triangles.shape[0])

    def class_mesh(self, learning_id: int) -> tuple[np.ndarray, np.ndarray]:
        """Vertices (V, 3) float32 and triangles (T, 3) uint32 of one class only."""
        tris = self.triangles[self.triangle_labels == learning_id]
        used, inverse = np.unique(tris, return_inverse=True)
        return self.vertices[used], inverse.reshape(-1, 3).astype(np.uint32)


class _MeshBuilder:
    """Accumulates labeled meshes; concatenates once at the end."""

    def __init__(self, label_map: LabelMap) -> None:
        self.label_map = label_map
        self._vertices: list[np.ndarray] = []
        self._triangles: list[np.ndarray] = []
        self._labels: list[np.ndarray] = []
        self._instances: list[np.ndarray] = []
        self._count = 0
        self._next_instance = 1
        self.objects: Counter[str] = Counter()

    def add(self, mesh: Mesh, cls: str, instance: int = 0) -> None:
        vertices, triangles = mesh
        self._vertices.append(vertices)
        self._triangles.append(triangles + self._count)
        self._labels.append(np.full(triangles.shape[0], self.label_map.id_of(cls), np.int32))
        self._instances.append(np.full(triangles.shape[0], instance, np.uint32))
        self._count += vertices.shape[0]

    def instance(self) -> int:
        self._next_instance += 1
        return self._next_instance - 1

    def build(self, grid: StreetGrid, blocks: dict[tuple[int, int], str]) -> World:
        return World(
            np.concatenate(self._vertices).astype(np.float32),
            np.concatenate(self._triangles).astype(np.uint32),
            np.concatenate(self._labels),
            np.concatenate(self._instances),
            grid,
            blocks,
            dict(sorted(self.objects.items())),
        )


# -- objects ------------------------------------------------------------------------------
def _wheel(
    b: _MeshBuilder,
    pose: tuple[float, float, float],
    offset: tuple[float, float],
    radius: float,
    width: float,
    label: str,
    inst: int,
) -> None:
    """Add a wheel across a vehicle at ``pose`` (x, y, yaw), ``offset`` (forward, left) from it."""
    x, y, yaw = pose
    c, s = np.cos(yaw), np.sin(yaw)
    dx, dy = offset
    b.add(
        prim.horizontal_cylinder(
            x + c * dx - s * dy, y + s * dx + c * dy, radius, radius, width, yaw + np.pi / 2,
            sides=8,
        ),
        label,
        inst,
    )  # fmt: skip


def _car(b: _MeshBuilder, rng: np.random.Generator, x: float, y: float, yaw: float) -> None:
    """Sedan or van: body, cabin and four wheels (class car, one instance)."""
    inst = b.instance()
    c, s = np.cos(yaw), np.sin(yaw)
    van = rng.random() < 0.2
    length = rng.uniform(4.4, 5.2) if van else rng.uniform(3.9, 4.9)
    width = rng.uniform(1.7, 1.95)
    top = rng.uniform(1.8, 2.1) if van else rng.uniform(0.85, 1.0)
    b.add(prim.box(x, y, length, width, 0.3, top, yaw), 'car', inst)
    if not van:
        cabin = rng.uniform(0.45, 0.6) * length
        shift = rng.uniform(-0.15, 0.0) * length
        b.add(
            prim.box(
                x + c * shift,
                y + s * shift,
                cabin,
                width - 0.12,
                top,
                top + rng.uniform(0.4, 0.6),
                yaw,
            ),
            'car',
            inst,
        )
    for fx in (-0.33, 0.33):
        for fy in (-1.0, 1.0):
            _wheel(
                b, (x, y, yaw), (fx * length, fy * (0.5 * width - 0.12)), 0.32, 0.22, 'car', inst
            )
    b.objects['car'] += 1


def _truck(
    b: _MeshBuilder,
    rng: np.random.Generator,
    x: float,
    y: float,
    yaw: float,
    length: float | None = None,
) -> None:
    """Truck: cab, cargo box and six wheels (class truck, one instance)."""
    inst = b.instance()
    c, s = np.cos(yaw), np.sin(yaw)
    length = rng.uniform(6.5, 9.5) if length is None else length
    width = rng.uniform(2.35, 2.55)
    cab = 2.2
    fx = 0.5 * length - 0.5 * cab
    b.add(
        prim.box(x + c * fx, y + s * fx, cab, width, 0.6, rng.uniform(2.8, 3.2), yaw),
        'truck',
        inst,
    )
    cargo = length - cab - 0.3
    bx = -0.5 * length + 0.5 * cargo
    b.add(
        prim.box(x + c * bx, y + s * bx, cargo, width, 1.0, rng.uniform(3.4, 4.0), yaw),
        'truck',
        inst,
    )
    for wx in (fx, bx - 0.25 * cargo, bx + 0.25 * cargo):
        for fy in (-1.0, 1.0):
            _wheel(b, (x, y, yaw), (wx, fy * (0.5 * width - 0.2)), 0.5, 0.35, 'truck', inst)
    b.objects['truck'] += 1


def _tree(
    b: _MeshBuilder, rng: np.random.Generator, x: float, y: float, scale: float = 1.0
) -> None:
    """Trunk (class trunk) with an irregular canopy (class vegetation)."""
    radius = rng.uniform(0.12, 0.32) * scale
    height = rng.uniform(2.0, 3.6) * scale
    tilt = tuple(rng.normal(0.0, 0.08, size=2) * height)
    b.add(prim.cylinder(x, y, radius, -0.1, height, sides=9, tilt=tilt), 'trunk')
    rxy = rng.uniform(1.6, 3.3) * scale
    rz = rng.uniform(1.4, 2.8) * scale
    b.add(
        prim.blob(
            x + tilt[0],
            y + tilt[1],
            height + 0.7 * rz,
            (rxy, rxy * rng.uniform(0.8, 1.2), rz),
            rng,
        ),
        'vegetation',
    )
    b.objects['tree'] += 1


def _bush(b: _MeshBuilder, rng: np.random.Generator, x: float, y: float) -> None:
    r = rng.uniform(0.5, 1.4)
    b.add(
        prim.blob(x, y, 0.5 * r, (r, r * rng.uniform(0.7, 1.3), 0.8 * r), rng, 0.25, 1),
        'vegetation',
    )
    b.objects['bush'] += 1


def _lamp(b: _MeshBuilder, rng: np.random.Generator, x: float, y: float, arm_yaw: float) -> None:
    """Street lamp or utility pole (class pole)."""
    if rng.random() < 0.25:  # utility pole with a cross arm
        height = rng.uniform(8.5, 11.0)
        b.add(prim.cylinder(x, y, rng.uniform(0.13, 0.17), 0.0, height, sides=8), 'pole')
        b.add(
            prim.box(x, y, 0.12, rng.uniform(1.4, 2.2), height - 0.8, height - 0.68, arm_yaw),
            'pole',
        )
    else:
        height = rng.uniform(6.0, 9.0)
        b.add(prim.cylinder(x, y, rng.uniform(0.08, 0.13), 0.0, height, sides=8), 'pole')
        arm = rng.uniform(1.0, 2.6)
        c, s = np.cos(arm_yaw), np.sin(arm_yaw)
        b.add(
            prim.box(
                x + 0.5 * arm * c,
                y + 0.5 * arm * s,
                arm,
                0.12,
                height - 0.3,
                height - 0.18,
                arm_yaw,
            ),
            'pole',
        )
        b.add(
            prim.box(x + arm * c, y + arm * s, 0.7, 0.35, height - 0.45, height - 0.25, arm_yaw),
            'pole',
        )
    b.objects['pole'] += 1


def _sign(b: _MeshBuilder, rng: np.random.Generator, x: float, y: float, face_yaw: float) -> None:
    """Traffic sign: a thin pole (class pole) with one or two plates (class traffic-sign)."""
    bottom = rng.uniform(1.9, 2.5)
    plates = 2 if rng.random() < 0.25 else 1
    sizes = rng.uniform(0.55, 0.95, size=plates)
    top = bottom + float(np.sum(sizes)) + 0.1 * plates
    b.add(prim.cylinder(x, y, 0.04, 0.0, top + 0.05, sides=6), 'pole')
    c, s = np.cos(face_yaw), np.sin(face_yaw)
    z = bottom
    for size in sizes:
        px, py = x + 0.06 * c, y + 0.06 * s
        if rng.random() < 0.5:
            b.add(
                prim.horizontal_cylinder(
                    px, py, z + 0.5 * size, 0.5 * size, 0.04, face_yaw, sides=10
                ),
                'traffic-sign',
            )
        else:
            b.add(
                prim.box(px, py, 0.04, size, z, z + size * rng.uniform(0.8, 1.3), face_yaw),
                'traffic-sign',
            )
        z += size + 0.1
    b.objects['traffic-sign'] += 1


def _clutter(b: _MeshBuilder, rng: np.random.Generator, x: float, y: float, yaw: float) -> None:
    """Bins, benches, bollards, cabinets (class unlabeled: SemanticKITTI other-object)."""
    kind = rng.integers(4)
    if kind == 0:
        b.add(prim.cylinder(x, y, 0.3, 0.0, 1.0, sides=8), 'unlabeled')
    elif kind == 1:
        b.add(prim.box(x, y, 1.8, 0.5, 0.4, 0.5, yaw), 'unlabeled')
        b.add(prim.box(x, y, 1.8, 0.08, 0.5, 0.95, yaw), 'unlabeled')
    elif kind == 2:
        b.add(prim.cylinder(x, y, 0.1, 0.0, 0.9, sides=6), 'unlabeled')
    else:
        b.add(prim.box(x, y, 0.9, 0.45, 0.0, 1.3, yaw), 'unlabeled')
    b.objects['clutter'] += 1


def _fence(
    b: _MeshBuilder,
    rng: np.random.Generator,
    p0: np.ndarray,
    p1: np.ndarray,
    gaps: list[tuple[float, float]] = (),
) -> None:
    """
    Fence from p0 to p1 (class fence): a solid panel or posts with rails.

    ``gaps`` are (start, end) distances along the fence left open (gates, driveways).
    """
    delta = p1 - p0
    length = float(np.linalg.norm(delta))
    if length < 1.0:
        return
    u = delta / length
    yaw = float(np.arctan2(u[1], u[0]))
    height = rng.uniform(1.0, 2.0)
    solid = rng.random() < 0.5
    edges = [0.0] + [v for g in sorted(gaps) for v in g] + [length]
    for s0, s1 in zip(edges[::2], edges[1::2], strict=False):
        if s1 - s0 < 0.5:
            continue
        mid = p0 + u * 0.5 * (s0 + s1)
        if solid:
            b.add(prim.box(mid[0], mid[1], s1 - s0, 0.06, 0.0, height, yaw), 'fence')
        else:
            for z in (0.35 * height, 0.9 * height):
                b.add(prim.box(mid[0], mid[1], s1 - s0, 0.05, z, z + 0.06, yaw), 'fence')
            posts = np.arange(s0, s1 + 1e-6, 2.5)
            for s in posts:
                q = p0 + u * s
                b.add(prim.box(q[0], q[1], 0.08, 0.08, 0.0, height, yaw), 'fence')
    b.objects['fence'] += 1


def _hedge(b: _MeshBuilder, rng: np.random.Generator, p0: np.ndarray, p1: np.ndarray) -> None:
    delta = p1 - p0
    length = float(np.linalg.norm(delta))
    if length < 1.0:
        return
    mid = 0.5 * (p0 + p1)
    b.add(
        prim.box(
            mid[0],
            mid[1],
            length,
            rng.uniform(0.6, 1.1),
            0.0,
            rng.uniform(0.8, 1.8),
            float(np.arctan2(delta[1], delta[0])),
        ),
        'vegetation',
    )
    b.objects['hedge'] += 1


# -- blocks -------------------------------------------------------------------------------
@dataclass
class _Side:
    """One side of a block: curb from a to b, inward normal n, street width beyond the curb."""

    a: np.ndarray
    u: np.ndarray
    n: np.ndarray
    length: float
    street_width: float

    def at(self, s: float, d: float) -> np.ndarray:
        """Point ``s`` along the curb and ``d`` inward (negative: on the road)."""
        return self.a + s * self.u + d * self.n

    @property
    def yaw(self) -> float:
        return float(np.arctan2(self.u[1], self.u[0]))


def _sides(
    rect: tuple[float, float, float, float], grid: StreetGrid, i: int, j: int
) -> list[_Side]:
    """Return the four curb sides, counter-clockwise (inward normal = left of the direction)."""
    x0, x1, y0, y1 = rect
    corners = [
        (np.array([x0, y0]), np.array([x1, y0]), grid.widths_y[j]),
        (np.array([x1, y0]), np.array([x1, y1]), grid.widths_x[i + 1]),
        (np.array([x1, y1]), np.array([x0, y1]), grid.widths_y[j + 1]),
        (np.array([x0, y1]), np.array([x0, y0]), grid.widths_x[i]),
    ]
    sides = []
    for a, bb, width in corners:
        length = float(np.linalg.norm(bb - a))
        u = (bb - a) / length
        sides.append(_Side(a, u, np.array([-u[1], u[0]]), length, float(width)))
    return sides


def _positions(
    rng: np.random.Generator, start: float, stop: float, spacing: tuple[float, float]
) -> np.ndarray:
    """Irregularly spaced positions in [start, stop]."""
    out, s = [], start + rng.uniform(0.0, spacing[1])
    while s <= stop:
        out.append(s)
        s += rng.uniform(*spacing)
    return np.asarray(out)


def _street_side(
    b: _MeshBuilder,
    rng: np.random.Generator,
    side: _Side,
    sidewalk: float,
    kind: str,
    config: WorldConfig,
) -> None:
    """Lamps, street trees, signs, clutter on the sidewalk; parked vehicles on the road."""
    tree_p = {'urban': 0.45, 'residential': 0.7, 'park': 0.8, 'parking': 0.3, 'industrial': 0.25}[
        kind
    ]
    park_p = {
        'urban': 0.65,
        'residential': 0.6,
        'park': 0.35,
        'parking': 0.35,
        'industrial': 0.55,
    }[kind]
    taken: list[float] = []
    curb_d = min(0.6, 0.3 * sidewalk)
    if rng.random() < 0.85:
        for s in _positions(rng, 2.0, side.length - 2.0, config.lamp_spacing):
            p = side.at(s, curb_d)
            _lamp(b, rng, p[0], p[1], side.yaw - np.pi / 2)
            taken.append(s)
    if rng.random() < tree_p:
        d = 0.5 * sidewalk + 0.2
        for s in _positions(rng, 3.0, side.length - 3.0, config.tree_spacing):
            if taken and min(abs(s - t) for t in taken) < 2.5:
                continue
            p = side.at(s, d)
            _tree(b, rng, p[0], p[1])
            taken.append(s)
    signs = [
        s
        for s, prob in (
            (rng.uniform(3.0, 8.0), 0.55),
            (side.length - rng.uniform(3.0, 8.0), 0.55),
            (rng.uniform(0.3, 0.7) * side.length, 0.35),
        )
        if rng.random() < prob
    ]
    for s in signs:
        p = side.at(s, curb_d + 0.2)
        _sign(b, rng, p[0], p[1], side.yaw + (np.pi if rng.random() < 0.5 else 0.0))
    for s in _positions(rng, 4.0, side.length - 4.0, (15.0, 45.0)):
        if rng.random() < 0.5:
            p = side.at(s, sidewalk - rng.uniform(0.4, 0.9))
            _clutter(b, rng, p[0], p[1], side.yaw)
    if rng.random() < park_p:
        s, stop = rng.uniform(8.0, 14.0), side.length - 8.0
        while s < stop:
            truck = side.street_width >= 12.0 and rng.random() < 0.12
            length = rng.uniform(6.5, 9.5) if truck else 4.9
            if s + length > stop:
                break
            if rng.random() < 0.8:
                half_width = 1.25 if truck else 0.95
                p = side.at(s + 0.5 * length, -(rng.uniform(0.2, 0.45) + half_width))
                yaw = side.yaw + np.pi + rng.normal(0.0, 0.03)
                if truck:
                    _truck(b, rng, p[0], p[1], yaw, length)
                else:
                    _car(b, rng, p[0], p[1], yaw)
            gap = rng.uniform(0.8, 3.0) if rng.random() < 0.75 else rng.uniform(6.0, 25.0)
            s += length + gap


def _lot_ground(
    b: _MeshBuilder, rng: np.random.Generator, lot: tuple[float, float, float, float], cls: str
) -> None:
    x0, x1, y0, y1 = lot
    if cls == 'terrain':
        b.add(prim.height_grid(x0, y0, x1, y1, 2.5, 0.1, rng, bump=0.12), 'terrain')
    else:
        b.add(prim.quad(x0, y0, x1, y1, 0.06), cls)


def _scatter(
    rng: np.random.Generator,
    lot: tuple[float, float, float, float],
    count: int,
    min_gap: float,
    inset: float = 0.0,
) -> np.ndarray:
    """Up to ``count`` random points in the lot at least ``min_gap`` apart (greedy thinning)."""
    x0, x1, y0, y1 = lot
    if x1 - x0 <= 2 * inset or y1 - y0 <= 2 * inset or count <= 0:
        return np.zeros((0, 2))
    candidates = np.column_stack(
        [
            rng.uniform(x0 + inset, x1 - inset, 3 * count),
            rng.uniform(y0 + inset, y1 - inset, 3 * count),
        ]
    )
    kept: list[np.ndarray] = []
    for c in candidates:
        if all(np.hypot(*(c - k)) >= min_gap for k in kept):
            kept.append(c)
            if len(kept) == count:
                break
    return np.asarray(kept).reshape(-1, 2)


class _Block(NamedTuple):
    """What a block's lot builder works on: the mesh, the block's generator, its curbs."""

    b: _MeshBuilder
    rng: np.random.Generator
    sides: list[_Side]  # the four curb sides (:func:`_sides`)
    sidewalk: float  # m
    lot: tuple[float, float, float, float]  # x0, x1, y0, y1 inside the sidewalk


def _perimeter_fence(
    b: _MeshBuilder,
    rng: np.random.Generator,
    sides: list[_Side],
    sidewalk: float,
    gate: tuple[float, float, float],
) -> None:
    """
    Fence every side 0.2 m inside the sidewalk, with one gate per side.

    ``gate``: (fraction of the side, metres before, metres after) where the gate opens.
    """
    fraction, before, after = gate
    for side in sides:
        at = fraction * side.length
        _fence(
            b,
            rng,
            side.at(sidewalk, sidewalk + 0.2),
            side.at(side.length - sidewalk, sidewalk + 0.2),
            [(at - before, at + after)],
        )


def _urban(block: _Block) -> None:
    """Perimeter rows of buildings with varied widths, depths, heights and setbacks."""
    b, rng, sides, sidewalk, lot = block
    _lot_ground(b, rng, lot, 'terrain' if rng.random() < 0.6 else 'other-ground')
    half = 0.5 * min(lot[1] - lot[0], lot[3] - lot[2])
    level = rng.uniform(0.6, 1.4)  # low-rise .. high-rise block
    max_depth = 0.0
    for side in sides:
        setback = 0.0 if rng.random() < 0.5 else rng.uniform(1.0, 4.0)
        s = sidewalk
        while s < side.length - sidewalk - 4.0:
            width = min(rng.uniform(8.0, 28.0), side.length - sidewalk - s)
            depth = min(rng.uniform(9.0, 20.0), max(4.0, half - setback))
            max_depth = max(max_depth, setback + depth)
            height = rng.uniform(6.0, 24.0) * level
            jitter = rng.uniform(0.0, 1.0) if setback > 0 else 0.0
            front = sidewalk + setback + jitter
            c = side.at(s + 0.5 * width, front + 0.5 * depth)
            b.add(prim.box(c[0], c[1], width, depth, 0.0, height, side.yaw), 'building')
            if rng.random() < 0.4 and depth > 8.0 and width > 8.0:
                c2 = side.at(s + 0.5 * width, front + 2.5 + 0.5 * (depth - 2.5))
                b.add(
                    prim.box(
                        c2[0],
                        c2[1],
                        width - 3.0,
                        depth - 2.5,
                        height,
                        height + rng.uniform(3.0, 9.0),
                        side.yaw,
                    ),
                    'building',
                )
            b.objects['building'] += 1
            s += width + (rng.uniform(2.0, 9.0) if rng.random() < 0.35 else 0.0)
        if setback >= 1.5 and rng.random() < 0.5:
            p0 = side.at(sidewalk, sidewalk + 0.4)
            p1 = side.at(side.length - sidewalk, sidewalk + 0.4)
            if rng.random() < 0.5:
                _hedge(b, rng, p0, p1)
            else:
                _fence(b, rng, p0, p1, [(5.0, 8.0)])
    inner = (
        lot[0] + max_depth + 2,
        lot[1] - max_depth - 2,
        lot[2] + max_depth + 2,
        lot[3] - max_depth - 2,
    )
    for x, y in _scatter(rng, inner, int(rng.integers(1, 7)), 5.0):
        _tree(b, rng, x, y)


def _residential(block: _Block) -> None:
    """Parcels with houses (gable roofs), front fences or hedges, garden trees, cars."""
    b, rng, sides, sidewalk, lot = block
    _lot_ground(b, rng, lot, 'terrain')
    half = 0.5 * min(lot[1] - lot[0], lot[3] - lot[2])
    for side in sides:
        s = sidewalk + 1.0
        while s < side.length - sidewalk - 12.0:
            parcel = min(rng.uniform(14.0, 24.0), side.length - sidewalk - s)
            setback = rng.uniform(4.0, 8.0)
            house_w, house_d = (
                rng.uniform(8.0, 12.0),
                min(rng.uniform(8.0, 11.0), max(4.0, half - setback - 1.0)),
            )
            wall = rng.uniform(3.0, 6.0)
            c = side.at(s + 0.5 * parcel, sidewalk + setback + 0.5 * house_d)
            b.add(prim.box(c[0], c[1], house_w, house_d, 0.0, wall, side.yaw), 'building')
            b.add(
                prim.gable_roof(
                    c[0], c[1], house_w + 0.6, house_d + 0.6, wall, rng.uniform(1.5, 3.2), side.yaw
                ),
                'building',
            )
            b.objects['building'] += 1
            drive = rng.uniform(1.0, parcel - 4.0)
            front = rng.random()
            p0 = side.at(s, sidewalk + 0.3)
            p1 = side.at(s + parcel, sidewalk + 0.3)
            if front < 0.45:
                _fence(b, rng, p0, p1, [(drive, drive + 3.0)])
            elif front < 0.8:
                _hedge(b, rng, p0, side.at(s + drive, sidewalk + 0.3))
                _hedge(b, rng, side.at(s + drive + 3.0, sidewalk + 0.3), p1)
            if rng.random() < 0.3:
                p = side.at(s + drive + 1.5, sidewalk + 2.8)
                _car(b, rng, p[0], p[1], side.yaw + np.pi / 2)
            for _ in range(int(rng.integers(0, 3))):
                p = side.at(
                    s + rng.uniform(1.0, parcel - 1.0),
                    sidewalk + rng.uniform(1.5, max(1.6, setback - 1.0)),
                )
                (_tree if rng.random() < 0.6 else _bush)(b, rng, p[0], p[1])
            s += parcel


def _park(block: _Block) -> None:
    """Terrain with trees, bushes, paths, lamps and benches; sometimes fenced."""
    b, rng, sides, sidewalk, lot = block
    _lot_ground(b, rng, lot, 'terrain')
    x0, x1, y0, y1 = lot
    area = (x1 - x0) * (y1 - y0)
    cx, cy = rng.uniform(x0 + 5, x1 - 5), rng.uniform(y0 + 5, y1 - 5)
    b.add(prim.box_between(x0, cy - 1.2, x1, cy + 1.2, 0.0, 0.24), 'sidewalk')
    b.add(prim.box_between(cx - 1.2, y0, cx + 1.2, y1, 0.0, 0.24), 'sidewalk')
    for x, y in _scatter(rng, lot, int(area / 160.0), 4.5, inset=2.0):
        if abs(y - cy) > 2.5 and abs(x - cx) > 2.5:
            (_tree if rng.random() < 0.7 else _bush)(b, rng, x, y)
    for s in _positions(rng, x0 + 3, x1 - 3, (20.0, 30.0)):
        _lamp(b, rng, s, cy + 1.6, -np.pi / 2)
        if rng.random() < 0.5:
            _clutter(b, rng, s + 3.0, cy + 1.8, 0.0)
    if rng.random() < 0.4:
        _perimeter_fence(b, rng, sides, sidewalk, (0.5, 2.0, 2.0))


def _parking(block: _Block) -> None:
    """Rows of perpendicular parked cars, trucks along one edge, lamps, a perimeter fence."""
    b, rng, sides, sidewalk, lot = block
    _lot_ground(b, rng, lot, 'parking')
    x0, x1, y0, y1 = lot
    along_x = (x1 - x0) >= (y1 - y0)
    u0, u1, v0, v1 = (x0, x1, y0, y1) if along_x else (y0, y1, x0, x1)

    def xy(u: float, v: float) -> tuple[float, float]:
        return (u, v) if along_x else (v, u)

    row_yaw = 0.0 if along_x else np.pi / 2
    v = v0 + 4.0
    while v + 5.0 < v1 - 10.0:
        for facing, vv in ((1.0, v + 2.5), (-1.0, v + 7.6)):
            for u in np.arange(u0 + 4.0, u1 - 4.0, 2.6):
                if rng.random() < 0.65:
                    _car(b, rng, *xy(u, vv), row_yaw + facing * np.pi / 2 + rng.normal(0, 0.03))
        for u in _positions(rng, u0 + 5.0, u1 - 5.0, (22.0, 30.0)):
            _lamp(b, rng, *xy(u, v + 5.05), row_yaw)
        v += 16.0
    u = u0 + 6.0
    while u < u1 - 10.0:
        if rng.random() < 0.6:
            length = rng.uniform(7.0, 10.0)
            _truck(b, rng, *xy(u + 0.5 * length, v1 - 3.0), row_yaw, length)
            u += length + rng.uniform(1.0, 4.0)
        else:
            u += rng.uniform(6.0, 14.0)
    if rng.random() < 0.6:
        _perimeter_fence(b, rng, sides, sidewalk, (0.3, 0.0, 6.0))
    if rng.random() < 0.3:
        b.add(prim.box(*xy(u0 + 4.0, v1 - 9.0), 4.0, 3.0, 0.0, 2.8, row_yaw), 'building')
        b.objects['building'] += 1


def _industrial(block: _Block) -> None:
    """Warehouses with loading docks, parked trucks, containers and a fence."""
    b, rng, sides, sidewalk, lot = block
    _lot_ground(b, rng, lot, 'other-ground' if rng.random() < 0.7 else 'terrain')
    x0, x1, y0, y1 = lot
    mx, my = rng.uniform(8.0, 16.0, size=2)
    if x1 - x0 > 2 * mx + 10 and y1 - y0 > 2 * my + 10:
        split = rng.random() < 0.5 and (x1 - x0) > 2 * mx + 40
        spans = (
            [(x0 + mx, 0.5 * (x0 + x1) - 3), (0.5 * (x0 + x1) + 3, x1 - mx)]
            if split
            else [(x0 + mx, x1 - mx)]
        )
        for a, c in spans:
            height = rng.uniform(7.0, 14.0)
            b.add(prim.box_between(a, y0 + my, c, y1 - my, 0.0, height), 'building')
            b.add(
                prim.box_between(
                    a + 3, y0 + my - 3.0, a + 3 + rng.uniform(6, 15), y0 + my, 0.0, 1.2
                ),
                'building',
            )
            b.objects['building'] += 1
            for u in _positions(rng, a + 4.0, c - 4.0, (4.0, 9.0)):
                if rng.random() < 0.55:
                    _truck(b, rng, u, y0 + my - 5.5, np.pi / 2 + rng.normal(0, 0.05))
    for _ in range(int(rng.integers(0, 4))):
        px, py = rng.uniform(x0 + 3, x1 - 3), rng.uniform(y0 + 2, y0 + 4)
        b.add(prim.box(px, py, 6.0, 2.4, 0.0, 2.6, 0.0), 'unlabeled')
        b.objects['clutter'] += 1
    if rng.random() < 0.8:
        _perimeter_fence(b, rng, sides, sidewalk, (0.5, 4.0, 4.0))


_BLOCK_BUILDERS = {
    'urban': _urban,
    'residential': _residential,
    'park': _park,
    'parking': _parking,
    'industrial': _industrial,
}


def _block(b: _MeshBuilder, grid: StreetGrid, i: int, j: int, config: WorldConfig) -> str:
    """Sidewalk ring, lot content and street furniture of block (i, j); returns its kind."""
    rng = np.random.default_rng([config.seed, 1, i + _INDEX_OFFSET, j + _INDEX_OFFSET])
    weights = np.asarray(config.block_kind_weights) / np.sum(config.block_kind_weights)
    kind = str(rng.choice(BLOCK_KINDS, p=weights))
    rect = grid.block_rect(i, j)
    x0, x1, y0, y1 = rect
    sidewalk = rng.uniform(*config.sidewalk_width)
    for box in (
        (x0, y0, x1, y0 + sidewalk),
        (x0, y1 - sidewalk, x1, y1),
        (x0, y0 + sidewalk, x0 + sidewalk, y1 - sidewalk),
        (x1 - sidewalk, y0 + sidewalk, x1, y1 - sidewalk),
    ):
        b.add(prim.box_between(box[0], box[1], box[2], box[3], 0.0, 0.15), 'sidewalk')
    lot = (x0 + sidewalk, x1 - sidewalk, y0 + sidewalk, y1 - sidewalk)
    sides = _sides(rect, grid, i, j)
    _BLOCK_BUILDERS[kind](_Block(b, rng, sides, sidewalk, lot))
    for side in sides:
        _street_side(b, rng, side, sidewalk, kind, config)
    return kind


def _rect_distance(rects: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distance (B,) from each rectangle (B, 4: x0, x1, y0, y1) to the nearest point (P, 2)."""
    dx = np.maximum(
        np.maximum(rects[:, None, 0] - points[None, :, 0], points[None, :, 0] - rects[:, None, 1]),
        0.0,
    )
    dy = np.maximum(
        np.maximum(rects[:, None, 2] - points[None, :, 1], points[None, :, 1] - rects[:, None, 3]),
        0.0,
    )
    return np.hypot(dx, dy).min(axis=1)


def build_world(
    grid: StreetGrid, route_xy: np.ndarray, config: WorldConfig, label_map: LabelMap | None = None
) -> World:
    """
    Build every block within ``config.margin`` of the route points (P, 2), with its roads.

    The road under a block is its whole grid cell, so the geometry of a block does
    not depend on which other blocks are built.
    """
    label_map = label_map if label_map is not None else LabelMap.load()
    b = _MeshBuilder(label_map)
    n = grid.xs.size - 1
    ij = np.array([(i, j) for i in range(n) for j in range(n)])
    rects = np.array([grid.block_rect(i, j) for i, j in ij])
    near = _rect_distance(rects, route_xy) < config.margin
    blocks: dict[tuple[int, int], str] = {}
    for i, j in ij[near]:
        blocks[(int(i), int(j))] = _block(b, grid, int(i), int(j), config)
        # Road surface: the whole grid cell (block and half of each street), at z = 0.
        b.add(prim.quad(grid.xs[i], grid.ys[j], grid.xs[i + 1], grid.ys[j + 1], 0.0), 'road')
    return b.build(grid, blocks)
