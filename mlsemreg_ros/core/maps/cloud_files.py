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
Point cloud files (PCD, PLY) with label and intensity fields, through Open3D's tensor IO.

``open3d.t.io`` keeps custom per-point attributes: a PCD gets the fields
``x y z label intensity`` (label ``U`` 4 bytes, intensity ``F`` 4 bytes), a PLY the
properties ``x y z label intensity`` (label ``int``: Open3D's PLY writer has no uint32).
On reading, the first attribute named in :data:`LABEL_FIELDS` is the label field and the
first in :data:`INTENSITY_FIELDS` the intensity (FAST-LIO, GLIM, KISS-SLAM and CloudCompare
spell them differently).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Attribute names read as labels, in order of preference.
LABEL_FIELDS = ('label', 'labels', 'semantic', 'semantic_label', 'class', 'scalar_label')
#: Attribute names read as intensity, in order of preference.
INTENSITY_FIELDS = ('intensity', 'intensities', 'reflectivity', 'remission', 'scalar_intensity')
#: The file types read and written.
CLOUD_SUFFIXES = ('.pcd', '.ply')


class CloudFileError(ValueError):
    """A cloud file cannot be read or written; the message names the file and the problem."""


@dataclass
class PointCloudData:
    """Points with their optional label and intensity fields."""

    points: np.ndarray  # (N, 3) float64
    labels: np.ndarray | None  # (N,) uint32, or None without a label field
    intensity: np.ndarray | None  # (N,) float32, or None without an intensity field


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in CLOUD_SUFFIXES:
        raise CloudFileError(f'{path}: unknown cloud type {suffix!r}; use one of {CLOUD_SUFFIXES}')
    return suffix


def write_cloud(
    path: str | Path,
    points: np.ndarray,
    labels: np.ndarray | None = None,
    intensity: np.ndarray | None = None,
) -> Path:
    """Write points (N, 3) with optional labels (N,) and intensity (N,) as binary PCD or PLY."""
    import open3d as o3d

    path = Path(path)
    suffix = _suffix(path)
    points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    cloud = o3d.t.geometry.PointCloud()
    cloud.point.positions = o3d.core.Tensor(np.ascontiguousarray(points))
    if labels is not None:
        label_type = np.uint32 if suffix == '.pcd' else np.int32
        column = np.asarray(labels).reshape(-1, 1).astype(label_type)
        cloud.point.label = o3d.core.Tensor(np.ascontiguousarray(column))
    if intensity is not None:
        column = np.asarray(intensity, dtype=np.float32).reshape(-1, 1)
        cloud.point.intensity = o3d.core.Tensor(np.ascontiguousarray(column))
    if not o3d.t.io.write_point_cloud(str(path), cloud, write_ascii=False):
        raise CloudFileError(f'{path}: Open3D could not write it')
    return path


def read_cloud(path: str | Path) -> PointCloudData:
    """Read a PCD or PLY: the finite points and their label and intensity fields, if any."""
    import open3d as o3d

    path = Path(path)
    _suffix(path)
    if not path.is_file():
        raise CloudFileError(f'{path}: no such file')
    cloud = o3d.t.io.read_point_cloud(str(path))
    if 'positions' not in cloud.point or cloud.point.positions.shape[0] == 0:
        raise CloudFileError(f'{path}: no points (or not a point cloud Open3D can read)')
    attributes = {name: cloud.point[name].numpy() for name in cloud.point}
    points = attributes['positions'].astype(np.float64).reshape(-1, 3)
    finite = np.isfinite(points).all(axis=1)
    labels = _field(attributes, LABEL_FIELDS)
    intensity = _field(attributes, INTENSITY_FIELDS)
    return PointCloudData(
        points[finite],
        None if labels is None else labels[finite].astype(np.int64).astype(np.uint32),
        None if intensity is None else intensity[finite].astype(np.float32),
    )


def _field(attributes: dict[str, np.ndarray], names: tuple[str, ...]) -> np.ndarray | None:
    for name in names:
        if name in attributes:
            values = attributes[name]
            return values.reshape(values.shape[0], -1)[:, 0]
    return None
