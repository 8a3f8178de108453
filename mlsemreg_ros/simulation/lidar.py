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
A spinning multi-beam LiDAR ray-cast into the world with Open3D's RaycastingScene.

Default: a 64-beam sensor like the HDL-64E of KITTI (elevations evenly spaced from
+2 to -24.8 deg, 2000 azimuth steps, 100 m range), with Gaussian range noise,
random dropout and an intensity from a per-class reflectivity and the incidence
angle. Each scan starts at a random azimuth offset (sub-step), as a real spinning
sensor does; motion during a sweep is not modelled (scans are de-skewed).
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.simulation.world import World
import numpy as np
import open3d as o3d

#: Reflectivity per learning id (0..19): unlabeled, car, bicycle, motorcycle, truck,
#: other-vehicle, person, bicyclist, motorcyclist, road, parking, sidewalk,
#: other-ground, building, fence, vegetation, trunk, terrain, pole, traffic-sign.
REFLECTIVITY = np.array(
    [
        0.3,
        0.45,
        0.4,
        0.4,
        0.45,
        0.4,
        0.3,
        0.3,
        0.3,
        0.18,
        0.2,
        0.28,
        0.22,
        0.35,
        0.38,
        0.42,
        0.3,
        0.4,
        0.35,
        0.95,
    ],
    dtype=np.float32,
)


@dataclass
class LidarConfig:
    """Sensor model parameters (angles in degrees, lengths in metres)."""

    beams: int = 64
    fov_up_deg: float = 2.0
    fov_down_deg: float = -24.8
    azimuth_steps: int = 2000
    max_range: float = 100.0
    min_range: float = 2.5
    range_noise: float = 0.02  # standard deviation of the Gaussian range noise
    dropout: float = 0.05  # probability that a return is lost
    intensity_noise: float = 0.03
    mount_height: float = 1.73  # above the road, as KITTI's Velodyne


@dataclass
class LidarScan:
    """One sweep in the sensor frame."""

    points: np.ndarray  # (N, 3) float32, metres, sensor frame (x forward, y left, z up)
    labels: np.ndarray  # (N,) int32 learning ids of the hit triangles
    instances: np.ndarray  # (N,) uint32 instance ids (0: none)
    intensity: np.ndarray  # (N,) float32 in [0, 1]
    ring: np.ndarray  # (N,) uint16 beam index, 0 = top beam

    def __len__(self) -> int:
        return int(self.points.shape[0])


class Lidar:
    """Ray-casts a :class:`World` from sensor poses."""

    def __init__(self, world: World, config: LidarConfig | None = None) -> None:
        self.config = config if config is not None else LidarConfig()
        self.world = world
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor(world.vertices), o3d.core.Tensor(world.triangles))
        cfg = self.config
        self._elevation = np.radians(np.linspace(cfg.fov_up_deg, cfg.fov_down_deg, cfg.beams))

    def ray_directions(self, azimuth_offset: float = 0.0) -> np.ndarray:
        """Return unit ray directions (beams * azimuth_steps, 3), sensor frame, beam-major."""
        steps = self.config.azimuth_steps
        azimuth = 2.0 * np.pi * (np.arange(steps) + azimuth_offset) / steps
        el, az = np.meshgrid(self._elevation, azimuth, indexing='ij')
        return np.stack(
            [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1
        ).reshape(-1, 3)

    def scan(self, T_world_sensor: np.ndarray, rng: np.random.Generator) -> LidarScan:
        """One sweep from the pose (4, 4) ``T_world_sensor``; noise drawn from ``rng``."""
        cfg = self.config
        directions = self.ray_directions(rng.uniform(0.0, 1.0))
        rotation, origin = T_world_sensor[:3, :3], T_world_sensor[:3, 3]
        rays = np.empty((directions.shape[0], 6), dtype=np.float32)
        rays[:, :3] = origin
        rays[:, 3:] = directions @ rotation.T
        hits = self.scene.cast_rays(o3d.core.Tensor(rays))
        t_hit = hits['t_hit'].numpy()
        keep = np.isfinite(t_hit) & (t_hit >= cfg.min_range) & (t_hit <= cfg.max_range)
        keep &= rng.random(t_hit.shape[0]) >= cfg.dropout
        index = np.flatnonzero(keep)
        triangle = hits['primitive_ids'].numpy()[index].astype(np.int64)
        distance = t_hit[index] + rng.normal(0.0, cfg.range_noise, index.size).astype(np.float32)
        points = (directions[index] * distance[:, None]).astype(np.float32)
        labels = self.world.triangle_labels[triangle]
        normals = hits['primitive_normals'].numpy()[index]
        cos_incidence = np.abs(np.einsum('ij,ij->i', normals, rays[index, 3:]))
        intensity = REFLECTIVITY[labels] * (0.35 + 0.65 * cos_incidence)
        intensity *= np.exp(-distance / 250.0)
        intensity += rng.normal(0.0, cfg.intensity_noise, index.size)
        ring = (index // cfg.azimuth_steps).astype(np.uint16)
        return LidarScan(
            points,
            labels.astype(np.int32),
            self.world.triangle_instances[triangle],
            np.clip(intensity, 0.0, 1.0).astype(np.float32),
            ring,
        )
