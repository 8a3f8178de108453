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
Moving actors and parked cars that leave, for field mode.

- **Actors** drive and walk along the street lines the route uses (every grid line is
  straight through the world): cars in the right-hand lane of their direction
  (6-12 m/s), cyclists near the lane edge (3.5-6 m/s), pedestrians on the sidewalks
  (1-1.6 m/s, either direction). Each starts at a random place and wraps around
  at the ends of its line's stretch (well beyond the route, out of sight). An actor
  that would come closer to the ego car than a safe distance at any sweep is
  dropped (no collisions, no overtaking through the ego).
- **Parked cars that leave**: a quarter of the cars within 30 m of the route are
  taken out of the static world and depart at a random time of the drive: they are
  there before it and gone after (for the loop route, often between two passes).

Per sweep, every actor within range is placed at the instant the rotating beam
sweeps across it (its azimuth from the sensor at mid-sweep gives the column time),
so a moving actor is where the sensor sees it. Actors carry their class as learning
id (car, bicyclist, person) and are flagged moving (raw ids 252, 253, 254).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

from mlsemreg_ros.simulation import primitives as prim
from mlsemreg_ros.simulation.field_lidar import LabeledMesh
from mlsemreg_ros.simulation.world import _car, _MeshBuilder
import numpy as np

#: First instance id of actors (world instances are numbered from 1 upwards).
ACTOR_INSTANCE_BASE = 40000
#: Per 100 m of street line: expected cars, cyclists, pedestrians.
DENSITY = {'car': 1.6, 'bicyclist': 0.5, 'person': 2.5}
SPEED = {'car': (6.0, 12.0), 'bicyclist': (3.5, 6.0), 'person': (1.0, 1.6)}
#: Closest allowed approach to the ego sensor (centre to centre), metres.
CLEARANCE = {'car': 3.0, 'bicyclist': 2.2, 'person': 2.0}
DEPARTING_SHARE = 0.25
LINE_MARGIN = 150.0  # an actor's stretch extends this far beyond the route on its line


class DriveScene(Protocol):
    """What the actors read of a field simulation (``FieldSimulation``, simulation/field.py)."""

    label_map: Any  # LabelMap
    world: Any  # the built world (build_world)
    grid: Any  # StreetGrid
    path: Any  # the route's grid path
    drive: Any  # ContinuousDrive: poses(t), config.lane_offset
    model: Any  # the sensor model: period
    frames: int
    sweep_starts: np.ndarray  # (F,) drive time of each sweep's start, seconds


def _mesh(builder: _MeshBuilder) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (V, 3), triangles (T, 3) and labels (T,) accumulated by a builder."""
    world = builder.build(None, {})  # type: ignore[arg-type]
    return world.vertices.astype(np.float64), world.triangles, world.triangle_labels


def _pedestrian(b: _MeshBuilder, rng: np.random.Generator) -> None:
    height = rng.uniform(1.55, 1.9)
    leg = 0.47 * height
    for side in (-0.1, 0.1):
        b.add(prim.box(0.0, side, 0.16, 0.14, 0.0, leg), 'person')
    b.add(prim.box(0.0, 0.0, 0.25, 0.42, leg, 0.82 * height), 'person')
    b.add(prim.cylinder(0.0, 0.0, 0.1, 0.84 * height, height, sides=8), 'person')


def _cyclist(b: _MeshBuilder, rng: np.random.Generator) -> None:
    for x in (-0.55, 0.55):
        b.add(prim.horizontal_cylinder(x, 0.0, 0.34, 0.34, 0.05, np.pi / 2, sides=10), 'bicyclist')
    b.add(prim.box(0.0, 0.0, 1.1, 0.06, 0.45, 0.85), 'bicyclist')
    b.add(prim.box(-0.1, 0.0, 0.3, 0.4, 0.95, 1.5), 'bicyclist')  # rider torso
    b.add(prim.cylinder(0.0, 0.0, 0.1, 1.52, 1.75, sides=8), 'bicyclist')


@dataclass
class _Kind:
    vertices: np.ndarray  # (V, 3) local, x forward
    triangles: np.ndarray
    labels: np.ndarray


@dataclass
class Actor:
    """One straight-line mover."""

    kind: str
    shape: int  # index into the shapes of its kind
    origin: np.ndarray  # (2,) a point of its path at s = 0
    direction: np.ndarray  # (2,) unit
    s0: float  # arc length at drive time 0
    speed: float  # m/s
    span: tuple[float, float]  # wraps within [span0, span1) of arc length
    z: float  # base height (sidewalk 0.15)
    instance: int

    def positions(self, t: np.ndarray) -> np.ndarray:
        """Positions (n, 2) at drive times ``t`` (n,)."""
        lo, hi = self.span
        s = lo + np.mod(self.s0 + self.speed * np.asarray(t) - lo, hi - lo)
        return self.origin + s[:, None] * self.direction


class Actors:
    """All actors and departing parked cars of a field simulation."""

    def __init__(
        self,
        actors: list[Actor],
        shapes: dict[str, list[_Kind]],
        departing: dict[int, float],
        moving_ids: dict[str, int],
    ) -> None:
        self.actors = actors
        self.shapes = shapes
        self.departing = departing  # world instance id -> drive time it leaves
        self._moving_ids = moving_ids
        self._parked: LabeledMesh | None = None
        self._parked_leave = np.zeros(0)  # per parked triangle: drive time its car leaves

    # -- construction ---------------------------------------------------------------------
    @classmethod
    def generate(cls, sim: DriveScene, rng: np.random.Generator) -> Actors:
        """Draw actors along the route's street lines and the parked cars that leave."""
        label_map = sim.label_map
        shapes: dict[str, list[_Kind]] = {'car': [], 'bicyclist': [], 'person': []}
        for kind, build in (('car', None), ('bicyclist', _cyclist), ('person', _pedestrian)):
            for _ in range(6):
                builder = _MeshBuilder(label_map)
                if build is None:
                    _car(builder, rng, 0.0, 0.0, 0.0)
                else:
                    build(builder, rng)
                shapes[kind].append(_Kind(*_mesh(builder)))
        ego_t = np.linspace(0.0, sim.sweep_starts[-1] + sim.model.period, 4 * sim.frames + 1)
        ego_xy = sim.drive.poses(ego_t)[:, :2, 3]
        actors: list[Actor] = []
        lane = sim.drive.config.lane_offset
        for axis, index, lo, hi in _route_lines(sim):
            coords, widths = (
                (sim.grid.ys, sim.grid.widths_y) if axis == 0 else (sim.grid.xs, sim.grid.widths_x)
            )
            along = np.array([1.0, 0.0]) if axis == 0 else np.array([0.0, 1.0])
            across = np.array([-along[1], along[0]])  # left of +along
            half = 0.5 * float(widths[index])
            centre = float(coords[index])
            origin = np.array([0.0, centre]) if axis == 0 else np.array([centre, 0.0])
            span = (lo - LINE_MARGIN, hi + LINE_MARGIN)
            length = span[1] - span[0]
            for kind, density in DENSITY.items():
                for _ in range(int(rng.poisson(density * length / 100.0))):
                    sign = 1.0 if rng.random() < 0.5 else -1.0
                    if kind == 'car':
                        offset = -sign * lane  # right-hand lane of its direction
                    elif kind == 'bicyclist':
                        offset = -sign * min(half - 1.0, lane + 0.8)
                    else:
                        offset = (1.0 if rng.random() < 0.5 else -1.0) * (half + 1.3)
                    actor = Actor(
                        kind,
                        int(rng.integers(len(shapes[kind]))),
                        origin + offset * across,
                        sign * along,
                        sign * float(rng.uniform(*span)),
                        float(rng.uniform(*SPEED[kind])),
                        (sign * span[0], sign * span[1]) if sign > 0 else (-span[1], -span[0]),
                        0.15 if kind == 'person' else 0.0,
                        ACTOR_INSTANCE_BASE + len(actors),
                    )
                    gap = np.linalg.norm(actor.positions(ego_t) - ego_xy, axis=1).min()
                    if gap >= CLEARANCE[kind]:
                        actors.append(actor)
        departing = _departing_cars(sim, rng)
        moving_ids = {k: label_map.id_of(k) for k in shapes}
        return cls(actors, shapes, departing, moving_ids)

    def summary(self) -> dict:
        """Count the actors and leaving cars (for simulation.yaml)."""
        counts = {k: sum(a.kind == k for a in self.actors) for k in self.shapes}
        return {'moving': counts, 'parked_cars_leaving': len(self.departing)}

    # -- meshes ---------------------------------------------------------------------------
    def static_mesh(self, world: LabeledMesh) -> LabeledMesh:
        """Return the world without the leaving parked cars (kept for :meth:`dynamic_mesh`)."""
        ids = np.fromiter(self.departing, dtype=np.uint32)
        leaving = np.isin(world.instances, ids)
        self._parked = _subset(world, leaving)
        parked_ids = np.unique(self._parked.instances)
        leave = np.array([self.departing[int(i)] for i in parked_ids])
        if leave.size:
            self._parked_leave = leave[np.searchsorted(parked_ids, self._parked.instances)]
        return _subset(world, ~leaving)

    def dynamic_mesh(self, t0: float, sim: DriveScene) -> LabeledMesh:
        """Actors placed for the sweep starting at drive time ``t0``, and still-parked cars."""
        model = sim.model
        mid = t0 + 0.5 * model.period
        sensor = sim.drive.poses(np.array([mid]))[0]
        parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        if self._parked is not None and not self._parked.empty:
            still = self._parked_leave > t0
            if still.any():
                kept = _subset(self._parked, still)
                parts.append(
                    (kept.vertices, kept.triangles, kept.labels, kept.instances, kept.moving)
                )
        reach = model.max_range + 10.0
        for actor in self.actors:
            xy = actor.positions(np.array([mid]))[0]
            local = sensor[:3, :3].T @ (np.append(xy, sensor[2, 3]) - sensor[:3, 3])
            if np.hypot(local[0], local[1]) > reach:
                continue
            azimuth = np.arctan2(local[1], local[0])
            fraction = np.mod(np.pi - azimuth, 2.0 * np.pi) / (2.0 * np.pi)
            xy = actor.positions(np.array([t0 + fraction * model.period]))[0]
            shape = self.shapes[actor.kind][actor.shape]
            yaw = float(np.arctan2(actor.direction[1], actor.direction[0]))
            vertices = prim.place(shape.vertices, xy[0], xy[1], actor.z, yaw)
            n = shape.triangles.shape[0]
            parts.append(
                (
                    vertices,
                    shape.triangles,
                    shape.labels,
                    np.full(n, actor.instance, np.uint32),
                    np.ones(n, dtype=bool),
                )
            )
        return _concatenate(parts)


def _subset(mesh: LabeledMesh, keep: np.ndarray) -> LabeledMesh:
    tris = mesh.triangles[keep]
    used, inverse = np.unique(tris, return_inverse=True)
    return LabeledMesh(
        mesh.vertices[used],
        inverse.reshape(-1, 3).astype(np.uint32),
        mesh.labels[keep],
        mesh.instances[keep],
        mesh.moving[keep],
    )


def _concatenate(parts: list) -> LabeledMesh:
    if not parts:
        return LabeledMesh(
            np.zeros((0, 3), np.float32),
            np.zeros((0, 3), np.uint32),
            np.zeros(0, np.int32),
            np.zeros(0, np.uint32),
            np.zeros(0, bool),
        )
    offsets = np.cumsum([0] + [p[0].shape[0] for p in parts[:-1]])
    return LabeledMesh(
        np.concatenate([p[0] for p in parts]).astype(np.float32),
        np.concatenate([p[1] + o for p, o in zip(parts, offsets, strict=True)]).astype(np.uint32),
        np.concatenate([p[2] for p in parts]).astype(np.int32),
        np.concatenate([p[3] for p in parts]).astype(np.uint32),
        np.concatenate([p[4] for p in parts]).astype(bool),
    )


def _route_lines(sim: DriveScene) -> list[tuple[int, int, float, float]]:
    """
    Street lines the route drives along: ``(axis, index, lo, hi)``.

    ``axis`` 0: a line ``y = ys[index]`` (traffic along x), 1: ``x = xs[index]``;
    ``[lo, hi]`` the stretch of the coordinate along the line that the route covers.
    """
    path, grid = sim.path, sim.grid
    found: dict[tuple[int, int], list[float]] = {}
    for start, heading, length, curvature in zip(
        path.starts, path.headings, path.lengths, path.curvatures, strict=True
    ):
        if curvature != 0.0 or length < 5.0:
            continue
        end = start + length * np.array([np.cos(heading), np.sin(heading)])
        if abs(np.cos(heading)) > 0.7:
            key = (0, int(np.argmin(np.abs(grid.ys - start[1]))))
            values = [start[0], end[0]]
        else:
            key = (1, int(np.argmin(np.abs(grid.xs - start[0]))))
            values = [start[1], end[1]]
        found.setdefault(key, []).extend(values)
    return [(a, i, min(v), max(v)) for (a, i), v in sorted(found.items())]


def _departing_cars(sim: DriveScene, rng: np.random.Generator) -> dict[int, float]:
    """World car instances near the route that leave, with the drive time they go."""
    world = sim.world
    car = sim.label_map.id_of('car')
    tris = world.triangle_labels == car
    instances = world.triangle_instances[tris]
    if instances.size == 0:
        return {}
    centres = world.vertices[world.triangles[tris][:, 0], :2].astype(np.float64)
    ids, first = np.unique(instances, return_index=True)
    centre = centres[first]
    route = sim.drive.poses(np.linspace(0.0, sim.sweep_starts[-1], 400))[:, :2, 3]
    near = np.array([np.min(np.linalg.norm(route - c, axis=1)) < 30.0 for c in centre])
    candidates = ids[near]
    chosen = candidates[rng.random(candidates.size) < DEPARTING_SHARE]
    times = rng.uniform(sim.sweep_starts[0], sim.sweep_starts[-1], chosen.size)
    return {int(i): float(t) for i, t in zip(chosen, times, strict=True)}
