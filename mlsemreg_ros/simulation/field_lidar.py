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
A sweep acquired column by column while the sensor moves (field mode).

Column ``c`` of a sweep is fired at ``t0 + column_times[c]`` from the sensor pose at
that instant (:class:`~mlsemreg_ros.simulation.motion.ContinuousDrive`), and its
points are reported in the sensor frame *of that instant*, as a real spinning
LiDAR does: the cloud is skewed by the motion during the sweep (a wall passed at
10 m/s is drawn 1 m longer or shorter between the first and the last column).

Rays hit the static world and, when given, a per-sweep scene of dynamic meshes
(moving actors, parked cars that leave); the nearer hit wins. Noise, dropout and
intensity follow the clean :class:`~mlsemreg_ros.simulation.lidar.Lidar`.
Points are ordered by column (time), then beam, like a driver's packets.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.simulation.lidar import REFLECTIVITY
from mlsemreg_ros.simulation.motion import ContinuousDrive
from mlsemreg_ros.simulation.sensors import SensorModel
import numpy as np
import open3d as o3d


@dataclass
class LabeledMesh:
    """Triangles with a learning id, an instance id and a moving flag per triangle."""

    vertices: np.ndarray  # (V, 3) float32, world frame
    triangles: np.ndarray  # (T, 3) uint32
    labels: np.ndarray  # (T,) int32 learning ids
    instances: np.ndarray  # (T,) uint32
    moving: np.ndarray  # (T,) bool

    @property
    def empty(self) -> bool:
        """Whether there is no triangle."""
        return self.triangles.shape[0] == 0


@dataclass
class FieldScan:
    """One skewed sweep: points in the sensor frame at their own time, and their truth."""

    points: np.ndarray  # (N, 3) float32, sensor frame at the point's time
    times: np.ndarray  # (N,) float64 seconds from the sweep start, in [0, period)
    ring: np.ndarray  # (N,) uint16, beam index, 0 = top beam
    column: np.ndarray  # (N,) int32, azimuth column (0 = first fired)
    labels: np.ndarray  # (N,) int32 true learning ids
    instances: np.ndarray  # (N,) uint32 true instance ids (0: none)
    moving: np.ndarray  # (N,) bool: hit a moving object
    intensity: np.ndarray  # (N,) float32 in [0, 1]
    world_points: np.ndarray  # (N, 3) float64, true world position of each return

    def __len__(self) -> int:
        return int(self.points.shape[0])


def _scene(vertices: np.ndarray, triangles: np.ndarray) -> o3d.t.geometry.RaycastingScene:
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32)),
        o3d.core.Tensor(np.ascontiguousarray(triangles, dtype=np.uint32)),
    )
    return scene


class FieldLidar:
    """Ray-casts skewed sweeps of a :class:`SensorModel` into a static labeled mesh."""

    def __init__(self, static: LabeledMesh, model: SensorModel) -> None:
        self.model = model
        self.static = static
        self._scene = _scene(static.vertices, static.triangles)

    def sweep(
        self,
        drive: ContinuousDrive,
        t0: float,
        rng: np.random.Generator,
        dynamic: LabeledMesh | None = None,
    ) -> FieldScan:
        """Cast the sweep starting at drive time ``t0``; noise from ``rng``."""
        model = self.model
        offset = rng.uniform(0.0, 1.0)
        column_time = model.column_times(offset)
        poses = drive.poses(t0 + column_time)  # (C, 4, 4)
        local = model.directions(t0, offset)  # (C, B, 3)
        world_dir = np.matmul(local, np.transpose(poses[:, :3, :3], (0, 2, 1)))
        beams = model.beams
        rays = np.empty((model.columns * beams, 6), dtype=np.float32)
        rays[:, :3] = np.repeat(poses[:, :3, 3], beams, axis=0)
        rays[:, 3:] = world_dir.reshape(-1, 3)
        tensor = o3d.core.Tensor(rays)
        hits = self._scene.cast_rays(tensor)
        t_hit = hits['t_hit'].numpy()
        dyn = None
        if dynamic is not None and not dynamic.empty:
            dyn = _scene(dynamic.vertices, dynamic.triangles).cast_rays(tensor)
            t_hit = np.minimum(t_hit, dyn['t_hit'].numpy())
        keep = np.isfinite(t_hit) & (t_hit >= model.min_range) & (t_hit <= model.max_range)
        keep &= rng.random(t_hit.shape[0]) >= model.dropout
        index = np.flatnonzero(keep)
        tri = hits['primitive_ids'].numpy()[index].astype(np.int64)
        normals = hits['primitive_normals'].numpy()[index]
        from_dyn = np.zeros(index.size, dtype=bool)
        if dyn is not None:
            from_dyn = dyn['t_hit'].numpy()[index] <= t_hit[index]
            tri[from_dyn] = dyn['primitive_ids'].numpy()[index[from_dyn]]
            normals[from_dyn] = dyn['primitive_normals'].numpy()[index[from_dyn]]
        static_tri = np.where(from_dyn, 0, tri)
        labels = self.static.labels[static_tri]
        instances = self.static.instances[static_tri]
        moving = np.zeros(index.size, dtype=bool)
        if dyn is not None and from_dyn.any():
            dyn_tri = tri[from_dyn]
            labels[from_dyn] = dynamic.labels[dyn_tri]
            instances[from_dyn] = dynamic.instances[dyn_tri]
            moving[from_dyn] = dynamic.moving[dyn_tri]
        true_range = t_hit[index].astype(np.float64)
        distance = true_range + rng.normal(0.0, model.range_noise, index.size)
        local_flat = local.reshape(-1, 3)[index]
        points = (local_flat * distance[:, None]).astype(np.float32)
        world_points = rays[index, :3].astype(np.float64) + rays[index, 3:] * true_range[:, None]
        cos_incidence = np.abs(np.sum(normals * rays[index, 3:], axis=1))
        intensity = REFLECTIVITY[labels] * (0.35 + 0.65 * cos_incidence)
        intensity *= np.exp(-distance / 250.0)
        intensity += rng.normal(0.0, model.intensity_noise, index.size)
        column = index // beams
        return FieldScan(
            points,
            column_time[column],
            (index % beams).astype(np.uint16),
            column.astype(np.int32),
            labels.astype(np.int32),
            instances.astype(np.uint32),
            moving,
            np.clip(intensity, 0.0, 1.0).astype(np.float32),
            world_points,
        )
