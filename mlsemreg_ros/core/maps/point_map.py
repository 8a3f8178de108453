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
Point maps that other tools read and write (docs/maps.md, "Point maps").

- :func:`export_points`: a keyframe map as one map-frame cloud, voxelized (the centroid,
  the majority label and the mean intensity of each voxel of ``map.export_voxel``).
- :func:`cut_keyframes`: a point map (FAST-LIO, GLIM, KISS-SLAM, a survey) as keyframes:
  one keyframe per ``map.keyframe_distance`` (or ``map.keyframe_rotation``) along a
  trajectory, or on a grid of ``map.import_grid`` without one; each keyframe is the map
  within ``map.import_radius`` of its pose, in the keyframe's frame, voxelized at
  ``features.voxel_size``, and labeled by :func:`keyframe_labels`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mlsemreg_ros.core.features.features import voxel_centroids, voxel_downsample
from mlsemreg_ros.core.maps.map_io import MapKeyframe
from mlsemreg_ros.core.rigid import invert_transform, rotation_angle_deg
import numpy as np
from scipy.spatial import cKDTree


@dataclass
class ExportedPoints:
    """A map as one cloud in the map frame."""

    points: np.ndarray  # (V, 3) float64, map frame
    labels: np.ndarray  # (V,) uint32, the labels as stored in the map
    intensity: np.ndarray  # (V,) float32 (0 where the map holds none)


def export_points(keyframes: list[MapKeyframe], voxel_size: float) -> ExportedPoints:
    """Every keyframe's points in the map frame, one point per voxel (``voxel_size`` 0: all)."""
    if not keyframes:
        empty = np.zeros((0, 3))
        return ExportedPoints(empty, np.zeros(0, np.uint32), np.zeros(0, np.float32))
    points = np.concatenate(
        [
            k.points.astype(np.float64) @ k.T_map_keyframe[:3, :3].T + k.T_map_keyframe[:3, 3]
            for k in keyframes
        ]
    )
    labels = np.concatenate([k.labels for k in keyframes]).astype(np.uint32)
    intensity = np.concatenate(
        [
            np.zeros(len(k.points), np.float32) if k.intensity is None else k.intensity
            for k in keyframes
        ]
    ).astype(np.float32)
    if voxel_size <= 0:
        return ExportedPoints(points, labels, intensity)
    centroids, voxel_labels = voxel_downsample(points, labels.astype(np.int64), voxel_size)
    _, inverse = voxel_centroids(points, voxel_size)  # the same voxel order
    sizes = np.bincount(inverse, minlength=len(centroids))
    mean_intensity = np.bincount(inverse, weights=intensity, minlength=len(centroids)) / sizes
    return ExportedPoints(
        centroids, voxel_labels.astype(np.uint32), mean_intensity.astype(np.float32)
    )


def keyframe_poses_along(
    trajectory: np.ndarray, distance: float, rotation_deg: float
) -> np.ndarray:
    """Return the indices of the trajectory poses (F, 4, 4) kept as keyframes, as a mapper."""
    kept = [0] if len(trajectory) else []
    for index in range(1, len(trajectory)):
        last = trajectory[kept[-1]]
        motion = invert_transform(last) @ trajectory[index]
        if np.linalg.norm(motion[:3, 3]) >= distance or rotation_angle_deg(motion) >= rotation_deg:
            kept.append(index)
    return np.asarray(kept, dtype=np.int64)


def grid_poses(points: np.ndarray, spacing: float, sensor_height: float) -> np.ndarray:
    """
    Keyframe poses (K, 4, 4) on a horizontal grid over the map, without a trajectory.

    One pose per grid cell holding at least 50 map points within ``spacing / 2`` of its
    centre; its height is the 5th percentile of those points' heights plus
    ``sensor_height``, its rotation the identity (the place descriptor does not depend on
    the yaw).
    """
    xy = points[:, :2]
    low, high = xy.min(axis=0), xy.max(axis=0)
    low = np.floor(low / spacing) * spacing  # cells on multiples of the spacing
    axes = [np.arange(low[k] + spacing / 2, high[k] + spacing / 2, spacing) for k in range(2)]
    centres = np.stack(np.meshgrid(*axes, indexing='ij'), axis=-1).reshape(-1, 2)
    tree = cKDTree(xy)
    near = tree.query_ball_point(centres, spacing / 2)
    poses = []
    for centre, members in zip(centres, near, strict=True):
        if len(members) < 50:
            continue
        pose = np.eye(4)
        pose[:2, 3] = centre
        pose[2, 3] = np.percentile(points[members, 2], 5) + sensor_height
        poses.append(pose)
    return np.asarray(poses).reshape(-1, 4, 4)


def visible_from(points: np.ndarray, viewpoint: np.ndarray) -> np.ndarray:
    """
    Return the indices of ``points`` (N, 3) visible from ``viewpoint`` (3,).

    Open3D's hidden point removal (Katz et al., SIGGRAPH 2007: spherical flipping and a
    convex hull), with the flipping radius 100 times the farthest point's distance.
    """
    import open3d as o3d

    if len(points) < 4:
        return np.arange(len(points))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    reach = float(np.linalg.norm(points - viewpoint, axis=1).max())
    _, visible = cloud.hidden_point_removal(np.asarray(viewpoint, np.float64), 100.0 * reach)
    return np.sort(np.asarray(visible, dtype=np.int64))


def cut_keyframes(
    points: np.ndarray,
    labels: np.ndarray | None,
    intensity: np.ndarray | None,
    poses: np.ndarray,
    stamps_ns: np.ndarray,
    config: Any,
    label: Any,
) -> list[MapKeyframe]:
    """
    One keyframe per pose (K, 4, 4): the map within ``map.import_radius``, in its frame.

    ``label(points, labels)``: the keyframe's labels from its points (keyframe frame, the
    sensor at the origin) and the cloud's label field (None without one);
    :func:`keyframe_labels` by default. Keyframes with fewer than 100 points are left out.
    """
    tree = cKDTree(points[:, :2])
    voxel = config.features.voxel_size
    keyframes = []
    for pose, stamp in zip(poses, stamps_ns, strict=True):
        members = np.asarray(tree.query_ball_point(pose[:2, 3], config.map.import_radius))
        if members.size < 100:
            continue
        if config.map.import_visible_only:
            members = members[visible_from(points[members], pose[:3, 3])]
        T_keyframe_map = invert_transform(pose)
        local = points[members] @ T_keyframe_map[:3, :3].T + T_keyframe_map[:3, 3]
        field = None if labels is None else labels[members]
        values = None if intensity is None else intensity[members]
        if voxel > 0:  # one point per voxel: the field's majority label, the mean intensity
            if field is not None:
                _, field = voxel_downsample(local, field.astype(np.int64), voxel)
            if values is not None:
                centroids, inverse = voxel_centroids(local, voxel)
                sizes = np.bincount(inverse, minlength=len(centroids))
                values = np.bincount(inverse, weights=values, minlength=len(centroids)) / sizes
            else:
                centroids = voxel_centroids(local, voxel)[0]
            local = centroids
        keyframe_field = None if field is None else np.asarray(field).astype(np.uint32)
        keyframe_labels_ = np.asarray(label(local, keyframe_field)).astype(np.uint32)
        keyframes.append(
            MapKeyframe(
                local.astype(np.float32),
                keyframe_labels_,
                pose.astype(np.float64),
                int(stamp),
                None if values is None else np.asarray(values, dtype=np.float32),
            )
        )
    return keyframes


def keyframe_labeler(config: Any, label_map: Any = None) -> Any:
    """
    Return the labeler of imported keyframes: ``label(points, field) -> (N,) labels``.

    By ``label_source`` (core/labeling/source.py): ``auto`` takes the cloud's label field
    when it has one, else the geometric labeler; ``field``, ``geometric``, ``onnx`` and
    ``none`` as in the node. The keyframe is labeled in its own frame, with the sensor at
    the origin, as the node labels a scan.
    """
    from mlsemreg_ros.core.labeling.source import LabelSource

    source = LabelSource(label_map)

    def label(points: np.ndarray, field: np.ndarray | None) -> np.ndarray:
        return source(points, field, config).labels

    return label


@dataclass
class ImportedMap:
    """Keyframes cut from a point map, and how."""

    keyframes: list[MapKeyframe]
    config: Any  # the registration config to store with the map
    placement: str  # 'trajectory' or 'grid'
    label_source: str  # the source the keyframes' labels came from
    cloud_points: int


def import_point_map(
    cloud: Any, config: Any, trajectory: tuple[np.ndarray, np.ndarray] | None = None
) -> ImportedMap:
    """
    Keyframes of a point map (:class:`~mlsemreg_ros.core.maps.cloud_files.PointCloudData`).

    ``trajectory``: (stamps in s (F,), poses T_map_sensor (F, 4, 4)), or None for the grid.
    The stored config has ``label_source`` set to the source used (``field`` or
    ``geometric`` for ``auto``), so queries against the map are labeled the same way.
    """
    from mlsemreg_ros.core.labeling.source import resolve

    source = resolve(config.label_source, cloud.labels is not None)
    if trajectory is not None:
        stamps, poses = trajectory
        kept = keyframe_poses_along(
            poses, config.map.keyframe_distance, config.map.keyframe_rotation
        )
        poses, stamps_ns = poses[kept], np.round(np.asarray(stamps)[kept] * 1e9).astype(np.int64)
        placement = 'trajectory'
    else:
        poses = grid_poses(cloud.points, config.map.import_grid, config.map.import_sensor_height)
        stamps_ns = np.zeros(len(poses), dtype=np.int64)
        placement = 'grid'
    stored = config.replace({'label_source': source})
    keyframes = cut_keyframes(
        cloud.points,
        cloud.labels,
        cloud.intensity,
        poses,
        stamps_ns,
        stored,
        keyframe_labeler(stored),
    )
    return ImportedMap(keyframes, stored, placement, source, len(cloud.points))
