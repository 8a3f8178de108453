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
Pose files: KITTI (3x4 rows), TUM (stamp t q), KITTI calib and times.

KITTI ``poses.txt``: one pose per line, the 12 entries of the top 3x4 of
``T_world_frame`` row-major. TUM: ``stamp tx ty tz qx qy qz qw`` (stamp in
seconds). KITTI ``calib.txt``: lines ``KEY: values``; ``Tr`` is the 3x4
Velodyne -> left camera (cam0) transform.
"""

from __future__ import annotations

from pathlib import Path

from mlsemreg_ros.codec.poses import matrix_to_quaternion, quaternion_to_matrix
from mlsemreg_ros.codec.stamps import format_seconds
import numpy as np


def read_kitti_poses(path: str | Path) -> np.ndarray:
    """Poses (F, 4, 4) from a KITTI pose file."""
    rows = np.loadtxt(path, dtype=np.float64, ndmin=2)
    if rows.shape[1] != 12:
        raise ValueError(f'{path}: expected 12 values per line, got {rows.shape[1]}')
    poses = np.tile(np.eye(4), (rows.shape[0], 1, 1))
    poses[:, :3, :4] = rows.reshape(-1, 3, 4)
    return poses


def write_kitti_poses(path: str | Path, poses: np.ndarray) -> None:
    """Write poses (F, 4, 4) in KITTI format (12 values per line)."""
    rows = np.asarray(poses, dtype=np.float64)[:, :3, :4].reshape(-1, 12)
    np.savetxt(path, rows, fmt='%.9e')


def write_tum_poses(path: str | Path, stamps_ns: np.ndarray, poses: np.ndarray) -> None:
    """Write poses (F, 4, 4) with stamps (F,) in ns as TUM lines ``t x y z qx qy qz qw``."""
    poses = np.asarray(poses, dtype=np.float64)
    quats = matrix_to_quaternion(poses[:, :3, :3])
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    with open(path, 'w') as f:
        for stamp, t, q in zip(stamps, poses[:, :3, 3], quats, strict=False):
            f.write(
                f'{format_seconds(stamp)} {t[0]:.9f} {t[1]:.9f} {t[2]:.9f} '
                f'{q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}\n'
            )


def read_tum_poses(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (F,) in seconds and poses (F, 4, 4) from a TUM file."""
    rows = np.loadtxt(path, dtype=np.float64, ndmin=2)
    poses = np.tile(np.eye(4), (rows.shape[0], 1, 1))
    poses[:, :3, :3] = quaternion_to_matrix(rows[:, 4:8])
    poses[:, :3, 3] = rows[:, 1:4]
    return rows[:, 0], poses


def read_kitti_calib(path: str | Path) -> dict[str, np.ndarray]:
    """Entries of a KITTI calib file; 12-value entries as (4, 4) transforms/projections."""
    out: dict[str, np.ndarray] = {}
    for line in Path(path).read_text().splitlines():
        key, sep, values = line.partition(':')
        if not sep or not values.strip():
            continue
        numbers = np.array(values.split(), dtype=np.float64)
        if numbers.size == 12:
            matrix = np.eye(4)
            matrix[:3, :4] = numbers.reshape(3, 4)
            out[key.strip()] = matrix
        else:
            out[key.strip()] = numbers
    return out


def read_kitti_times(path: str | Path) -> np.ndarray:
    """Frame times (F,) in seconds from a KITTI ``times.txt``."""
    return np.loadtxt(path, dtype=np.float64, ndmin=1).reshape(-1)


def camera_to_lidar_poses(poses_cam: np.ndarray, T_cam_velo: np.ndarray) -> np.ndarray:
    """
    KITTI camera poses (F, 4, 4) -> LiDAR poses: ``Tr^-1 @ P_k @ Tr``.

    ``poses.txt`` holds ``T_cam0(0)_cam0(k)``; with ``Tr = T_cam_velo`` from calib.txt
    the LiDAR trajectory in the first LiDAR frame is ``Tr^-1 P_k Tr``.
    """
    return np.linalg.inv(T_cam_velo) @ np.asarray(poses_cam, dtype=np.float64) @ T_cam_velo
