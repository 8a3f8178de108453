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
A small deterministic labeled street scene and a registration pair taken in it.

Used by the node tests and ``mlsemreg bench-node`` when the KITTI dev pairs are
absent. The street: road and sidewalks (ground), building facades (boxes),
poles with traffic signs, tree trunks with crowns, parked cars; positions and
sizes drawn from a seeded RNG so the scene is irregular (not repetitive for
FPFH). Each scan keeps the world points within range of its sensor, subsampled
independently (as two LiDAR sweeps never hit the same points), in SemanticKITTI
learning ids.
"""

from __future__ import annotations

from mlsemreg_ros.datasets.pairs import Pair
import numpy as np
from scipy.spatial.transform import Rotation

# SemanticKITTI learning ids.
CAR, ROAD, SIDEWALK, BUILDING, VEGETATION, TRUNK, TERRAIN, POLE, SIGN = (
    1,
    9,
    11,
    13,
    15,
    16,
    17,
    18,
    19,
)


def _plane(
    rng: np.random.Generator, origin: np.ndarray, u: np.ndarray, v: np.ndarray, density: float
) -> np.ndarray:
    """Uniform samples of the parallelogram origin + s u + t v, ``density`` points per m^2."""
    count = max(int(density * np.linalg.norm(np.cross(u, v))), 1)
    s, t = rng.random((2, count, 1))
    return origin + s * u + t * v


def _box_sides(
    rng: np.random.Generator,
    center: np.ndarray,
    size: np.ndarray,
    yaw: float,
    density: float,
    top: bool = False,
) -> np.ndarray:
    """Sample the 4 vertical faces (and optionally the top) of a yawed box on the ground."""
    rot = Rotation.from_euler('z', yaw).as_matrix()
    ex, ey, ez = (
        rot @ np.array([size[0], 0, 0]),
        rot @ np.array([0, size[1], 0]),
        np.array([0, 0, size[2]]),
    )
    corner = center - ex / 2 - ey / 2
    faces = [(corner, ex, ez), (corner, ey, ez), (corner + ex, ey, ez), (corner + ey, ex, ez)]
    if top:
        faces.append((corner + ez, ex, ey))
    return np.concatenate([_plane(rng, o, u, v, density) for o, u, v in faces])


def _cylinder(
    rng: np.random.Generator, base: np.ndarray, radius: float, height: float, density: float
) -> np.ndarray:
    count = max(int(density * 2 * np.pi * radius * height), 1)
    angle, z = rng.uniform(0, 2 * np.pi, count), rng.uniform(0, height, count)
    return base + np.stack([radius * np.cos(angle), radius * np.sin(angle), z], axis=1)


def _sphere(
    rng: np.random.Generator, center: np.ndarray, radius: float, density: float
) -> np.ndarray:
    count = max(int(density * 4 * np.pi * radius**2), 1)
    d = rng.normal(size=(count, 3))
    return center + radius * d / np.linalg.norm(d, axis=1, keepdims=True)


def street_scene(seed: int = 0, length: float = 120.0) -> tuple[np.ndarray, np.ndarray]:
    """World points (N, 3) float64 and learning ids (N,) int32 of a street along x."""
    rng = np.random.default_rng(seed)
    parts: list[tuple[np.ndarray, int]] = []
    half = length / 2

    def strip(y: float, width: float, z: float, density: float) -> np.ndarray:
        """Sample the ground along the street from ``y`` over ``width`` (signed) at ``z``."""
        along, across = np.array([length, 0, 0]), np.array([0, width, 0])
        return _plane(rng, np.array([-half, y, z]), along, across, density)

    parts.append((strip(-4.0, 8.0, 0, 6.0), ROAD))
    for side in (-1, 1):
        parts.append((strip(side * 4.0, side * 4.0, 0.15, 4.0), SIDEWALK))
        parts.append((strip(side * 8.0, side * 3.0, 0.1, 2.0), TERRAIN))
        x = -half
        while x < half:  # facades with irregular widths, depths, heights and gaps
            width, depth, height = rng.uniform(6, 16), rng.uniform(6, 12), rng.uniform(5, 14)
            center = np.array([x + width / 2, side * (11.0 + rng.uniform(0, 3) + depth / 2), 0])
            parts.append(
                (
                    _box_sides(
                        rng,
                        center,
                        np.array([width, depth, height]),
                        rng.uniform(-0.15, 0.15),
                        2.5,
                    ),
                    BUILDING,
                )
            )
            x += width + rng.uniform(1, 6)
        for px in np.sort(rng.uniform(-half, half, 9)):  # poles, some carrying signs
            base = np.array([px, side * rng.uniform(5.0, 7.5), 0.15])
            parts.append((_cylinder(rng, base, 0.12, rng.uniform(4, 8), 40.0), POLE))
            if rng.random() < 0.5:
                sign = base + np.array([0, 0, 2.6])
                parts.append(
                    (_plane(rng, sign, np.array([0, 0.7, 0]), np.array([0, 0, 0.7]), 120.0), SIGN)
                )
        for tx in np.sort(rng.uniform(-half, half, 8)):  # trees: trunk + crown
            base = np.array([tx, side * rng.uniform(8.5, 10.5), 0.1])
            height = rng.uniform(2.0, 3.5)
            parts.append((_cylinder(rng, base, rng.uniform(0.15, 0.35), height, 30.0), TRUNK))
            parts.append(
                (
                    _sphere(
                        rng, base + np.array([0, 0, height + 1.5]), rng.uniform(1.2, 2.5), 4.0
                    ),
                    VEGETATION,
                )
            )
        for cx in np.sort(rng.uniform(-half, half, 6)):  # parked cars
            center = np.array([cx, side * rng.uniform(2.2, 3.2), 0.0])
            parts.append(
                (
                    _box_sides(
                        rng,
                        center,
                        np.array([4.4, 1.8, 1.5]),
                        rng.uniform(-0.1, 0.1),
                        12.0,
                        top=True,
                    ),
                    CAR,
                )
            )
    points = np.concatenate([p for p, _ in parts])
    labels = np.concatenate([np.full(len(p), label, dtype=np.int32) for p, label in parts])
    points += rng.normal(scale=0.02, size=points.shape)  # range noise
    return points, labels


def motion(yaw_deg: float, translation: tuple[float, float, float]) -> np.ndarray:
    """4x4 rigid motion: rotation about z by ``yaw_deg``, then ``translation`` (m)."""
    out = np.eye(4)
    out[:3, :3] = Rotation.from_euler('z', yaw_deg, degrees=True).as_matrix()
    out[:3, 3] = translation
    return out


def scan_at(
    world: np.ndarray,
    labels: np.ndarray,
    pose: np.ndarray,
    seed: int,
    max_range: float = 40.0,
    max_points: int = 25000,
) -> tuple[np.ndarray, np.ndarray]:
    """Points (in the sensor frame) and labels a sensor at ``pose`` (T_world_sensor) sees."""
    rng = np.random.default_rng(seed)
    sensor = pose[:3, 3] + np.array([0, 0, 1.7])
    keep = np.flatnonzero(np.linalg.norm(world - sensor, axis=1) < max_range)
    if keep.size > max_points:
        keep = np.sort(rng.choice(keep, max_points, replace=False))
    local = (world[keep] - pose[:3, 3]) @ pose[:3, :3]  # T_world_sensor^-1 @ p
    return local, labels[keep]


def synthetic_pair(
    seed: int = 0,
    yaw_deg: float = 8.0,
    translation: tuple[float, float, float] = (2.5, 0.4, 0.0),
    max_points: int = 25000,
) -> Pair:
    """
    Take a Pair in the street: dst at the origin, src moved by (yaw, translation).

    ``trans_gt`` = T_dst_src (maps src points onto dst), as in the KITTI pair files.
    """
    world, labels = street_scene(seed)
    src_pose = motion(yaw_deg, translation)
    pts_dst, label_dst = scan_at(world, labels, np.eye(4), seed + 1, max_points=max_points)
    pts_src, label_src = scan_at(world, labels, src_pose, seed + 2, max_points=max_points)
    return Pair(
        name=f'synthetic_{seed}',
        pts_src=pts_src,
        label_src=label_src,
        pts_dst=pts_dst,
        label_dst=label_dst,
        trans_gt=src_pose,
    )
