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
Triangle-mesh primitives of the simulated world (boxes, cylinders, blobs, roofs, grids).

Every builder returns ``(vertices, triangles)``: vertices (V, 3) float64 in metres,
triangles (T, 3) int64 indices, counter-clockwise seen from outside. Builders take
world placement arguments directly (footprint centre, yaw about +z, base height),
so the world generator reads as a list of objects.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

Mesh = tuple[np.ndarray, np.ndarray]

_BOX_CORNERS = np.array(
    [
        [-0.5, -0.5, 0.0],
        [0.5, -0.5, 0.0],
        [0.5, 0.5, 0.0],
        [-0.5, 0.5, 0.0],
        [-0.5, -0.5, 1.0],
        [0.5, -0.5, 1.0],
        [0.5, 0.5, 1.0],
        [-0.5, 0.5, 1.0],
    ]
)
_BOX_TRIANGLES = np.array(
    [
        [0, 2, 1],
        [0, 3, 2],  # bottom
        [4, 5, 6],
        [4, 6, 7],  # top
        [0, 1, 5],
        [0, 5, 4],  # -y
        [1, 2, 6],
        [1, 6, 5],  # +x
        [2, 3, 7],
        [2, 7, 6],  # +y
        [3, 0, 4],
        [3, 4, 7],  # -x
    ],
    dtype=np.int64,
)


def yaw_matrix(yaw: float) -> np.ndarray:
    """(3, 3) rotation about +z by ``yaw`` radians."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def place(
    vertices: np.ndarray, x: float, y: float, z: float = 0.0, yaw: float = 0.0
) -> np.ndarray:
    """Rotate local vertices (V, 3) by ``yaw`` about +z and translate them to (x, y, z)."""
    return vertices @ yaw_matrix(yaw).T + np.array([x, y, z])


def box(
    x: float, y: float, length: float, width: float, z0: float, z1: float, yaw: float = 0.0
) -> Mesh:
    """Box with footprint centre (x, y), ``length`` along the yawed x axis, from z0 to z1."""
    local = _BOX_CORNERS * np.array([length, width, z1 - z0])
    return place(local, x, y, z0, yaw), _BOX_TRIANGLES.copy()


def box_between(x0: float, y0: float, x1: float, y1: float, z0: float, z1: float) -> Mesh:
    """Axis-aligned box over the rectangle [x0, x1] x [y0, y1], from z0 to z1."""
    return box(0.5 * (x0 + x1), 0.5 * (y0 + y1), abs(x1 - x0), abs(y1 - y0), z0, z1)


@lru_cache(maxsize=8)
def _unit_cylinder(sides: int) -> Mesh:
    angles = 2.0 * np.pi * np.arange(sides) / sides
    ring = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    vertices = np.concatenate(
        [
            np.column_stack([ring, np.zeros(sides)]),
            np.column_stack([ring, np.ones(sides)]),
            [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
        ]
    )
    i = np.arange(sides)
    j = (i + 1) % sides
    bottom, top = 2 * sides, 2 * sides + 1
    triangles = np.concatenate(
        [
            np.stack([i, j, sides + j], axis=1),
            np.stack([i, sides + j, sides + i], axis=1),
            np.stack([np.full(sides, bottom), j, i], axis=1),
            np.stack([np.full(sides, top), sides + i, sides + j], axis=1),
        ]
    )
    return vertices, triangles.astype(np.int64)


def cylinder(
    x: float,
    y: float,
    radius: float,
    z0: float,
    z1: float,
    sides: int = 10,
    tilt: tuple[float, float] = (0.0, 0.0),
) -> Mesh:
    """
    Vertical cylinder of ``radius`` around (x, y) from z0 to z1.

    ``tilt`` (dx, dy) shifts the top cap horizontally (a leaning trunk), metres.
    """
    unit, triangles = _unit_cylinder(sides)
    vertices = unit * np.array([radius, radius, z1 - z0]) + np.array([x, y, z0])
    vertices[:, 0] += tilt[0] * unit[:, 2]
    vertices[:, 1] += tilt[1] * unit[:, 2]
    return vertices, triangles.copy()


def horizontal_cylinder(
    x: float, y: float, z: float, radius: float, length: float, yaw: float, sides: int = 10
) -> Mesh:
    """Cylinder whose axis is horizontal along ``yaw``, centred at (x, y, z) (wheels, plates)."""
    unit, triangles = _unit_cylinder(sides)
    local = unit * np.array([radius, radius, length]) - np.array([0.0, 0.0, 0.5 * length])
    # Axis z -> axis x: (x, y, z) -> (z, y, -x); then yaw.
    local = np.stack([local[:, 2], local[:, 1], -local[:, 0]], axis=1)
    return place(local, x, y, z, yaw), triangles.copy()


@lru_cache(maxsize=4)
def _unit_icosphere(subdivisions: int) -> Mesh:
    """Icosphere of radius 1 (12 -> 42 -> 162 vertices)."""
    t = (1.0 + 5.0**0.5) / 2.0
    vertices = np.array(
        [
            [-1, t, 0],
            [1, t, 0],
            [-1, -t, 0],
            [1, -t, 0],
            [0, -1, t],
            [0, 1, t],
            [0, -1, -t],
            [0, 1, -t],
            [t, 0, -1],
            [t, 0, 1],
            [-t, 0, -1],
            [-t, 0, 1],
        ],
        dtype=float,
    )
    faces = np.array(
        [
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ],
        dtype=np.int64,
    )
    for _ in range(subdivisions):
        edges = np.sort(
            np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1
        )
        unique, inverse = np.unique(edges, axis=0, return_inverse=True)
        mid = vertices.shape[0] + inverse.reshape(3, -1).T  # (F, 3): midpoints of e01, e12, e20
        vertices = np.concatenate(
            [vertices, 0.5 * (vertices[unique[:, 0]] + vertices[unique[:, 1]])]
        )
        a, b, c = faces[:, 0], faces[:, 1], faces[:, 2]
        ab, bc, ca = mid[:, 0], mid[:, 1], mid[:, 2]
        faces = np.concatenate(
            [
                np.stack([a, ab, ca], 1),
                np.stack([b, bc, ab], 1),
                np.stack([c, ca, bc], 1),
                np.stack([ab, bc, ca], 1),
            ]
        )
    vertices /= np.linalg.norm(vertices, axis=1, keepdims=True)
    return vertices, faces


def blob(
    x: float,
    y: float,
    z: float,
    radii: tuple[float, float, float],
    rng: np.random.Generator,
    roughness: float = 0.15,
    subdivisions: int = 2,
) -> Mesh:
    """Irregular ellipsoid (tree canopy, bush) centred at (x, y, z) with radial noise."""
    unit, faces = _unit_icosphere(subdivisions)
    scale = 1.0 + roughness * rng.uniform(-1.0, 1.0, size=(unit.shape[0], 1))
    vertices = unit * scale * np.asarray(radii) + np.array([x, y, z])
    return vertices, faces.copy()


def gable_roof(
    x: float, y: float, length: float, width: float, z0: float, rise: float, yaw: float = 0.0
) -> Mesh:
    """Gable roof prism on a ``length`` x ``width`` footprint, ridge along the length."""
    hl, hw = 0.5 * length, 0.5 * width
    local = np.array(
        [
            [-hl, -hw, 0.0],
            [hl, -hw, 0.0],
            [hl, hw, 0.0],
            [-hl, hw, 0.0],
            [-hl, 0.0, rise],
            [hl, 0.0, rise],
        ]
    )
    triangles = np.array(
        [[0, 1, 5], [0, 5, 4], [2, 3, 4], [2, 4, 5], [1, 2, 5], [3, 0, 4], [0, 2, 1], [0, 3, 2]],
        dtype=np.int64,
    )
    return place(local, x, y, z0, yaw), triangles


def height_grid(
    x0: float,
    y0: float,
    x1: float,
    y1: float,
    cell: float,
    z: float,
    rng: np.random.Generator,
    bump: float = 0.0,
) -> Mesh:
    """
    Ground patch over [x0, x1] x [y0, y1] as a grid of ``cell``-sized quads.

    Heights are ``z`` plus uniform noise in [0, bump] (bumpy terrain).
    """
    nx = max(1, int(np.ceil((x1 - x0) / cell)))
    ny = max(1, int(np.ceil((y1 - y0) / cell)))
    gx, gy = np.meshgrid(np.linspace(x0, x1, nx + 1), np.linspace(y0, y1, ny + 1), indexing='ij')
    gz = z + bump * rng.uniform(0.0, 1.0, size=gx.shape)
    vertices = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing='ij')
    v00 = (i * (ny + 1) + j).ravel()
    v10, v01 = v00 + (ny + 1), v00 + 1
    v11 = v10 + 1
    triangles = np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)])
    return vertices, triangles.astype(np.int64)


def quad(x0: float, y0: float, x1: float, y1: float, z: float) -> Mesh:
    """Flat horizontal rectangle [x0, x1] x [y0, y1] at height z (two triangles)."""
    vertices = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], dtype=float)
    return vertices, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
