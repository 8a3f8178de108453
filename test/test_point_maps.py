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

"""Point maps in PCD / PLY: export, import, their fields (core/maps/point_map.py)."""

from __future__ import annotations

from pathlib import Path

from mlsemreg_ros.codec.pose_files import read_tum_poses, write_tum_poses
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.maps.cloud_files import CloudFileError, read_cloud, write_cloud
from mlsemreg_ros.core.maps.map_io import load_map, MapKeyframe, save_map
from mlsemreg_ros.core.maps.point_map import (
    cut_keyframes,
    export_points,
    grid_poses,
    import_point_map,
    keyframe_poses_along,
)
from mlsemreg_ros.core.maps.relocalization import Relocalizer
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.datasets.synthetic_scene import motion, scan_at, street_scene
from mlsemreg_ros.tools.cli import app
import numpy as np
import pytest
from street_map import street_keyframe_store, STREET_SEED
from typer.testing import CliRunner


def _pose(x: float, y: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    return motion(yaw_deg, (x, y, 0.0))


@pytest.mark.parametrize('suffix', ['.pcd', '.ply'])
def test_label_and_intensity_fields_survive_a_round_trip(tmp_path: Path, suffix: str) -> None:
    rng = np.random.default_rng(0)
    points = rng.uniform(-10, 10, (50, 3))
    labels = rng.integers(0, 260, 50).astype(np.uint32)
    intensity = rng.uniform(0, 1, 50).astype(np.float32)
    path = write_cloud(tmp_path / f'cloud{suffix}', points, labels, intensity)
    back = read_cloud(path)
    assert np.allclose(back.points, points, atol=1e-5)
    assert np.array_equal(back.labels, labels)
    assert np.allclose(back.intensity, intensity)
    bare = read_cloud(write_cloud(tmp_path / f'bare{suffix}', points))
    assert bare.labels is None and bare.intensity is None


def test_an_unknown_or_missing_cloud_file_is_refused(tmp_path: Path) -> None:
    with pytest.raises(CloudFileError, match='unknown cloud type'):
        write_cloud(tmp_path / 'cloud.xyz', np.zeros((3, 3)))
    with pytest.raises(CloudFileError, match='no such file'):
        read_cloud(tmp_path / 'missing.pcd')


def _tiny_keyframes() -> list[MapKeyframe]:
    """Two keyframes 10 m apart that see the same two points of the map."""
    first = MapKeyframe(
        np.array([[1.0, 0.0, 0.0], [1.05, 0.02, 0.0], [3.0, 0.0, 0.0]], np.float32),
        np.array([40, 40, 50], np.uint32),
        _pose(0.0),
        0,
        np.array([1.0, 3.0, 5.0], np.float32),
    )
    # seen from x = 10 turned by 180 deg: map (1, 0, 0) is keyframe (9, 0, 0)
    second = MapKeyframe(
        np.array([[9.0, 0.0, 0.0]], np.float32), np.array([40], np.uint32), _pose(10.0, 0, 180), 1
    )
    return [first, second]


def test_export_puts_the_points_in_the_map_frame_one_per_voxel() -> None:
    exported = export_points(_tiny_keyframes(), voxel_size=0.5)
    order = np.argsort(exported.points[:, 0])
    points, labels = exported.points[order], exported.labels[order]
    # (1, 0, 0), (1.05, 0.02, 0) and the second keyframe's (1, 0, 0) share a voxel
    assert points.shape == (2, 3)
    assert np.allclose(points[0], [(1.0 + 1.05 + 1.0) / 3, 0.02 / 3, 0.0], atol=1e-5)
    assert np.allclose(points[1], [3.0, 0.0, 0.0], atol=1e-6)
    assert labels.tolist() == [40, 50]
    # the mean intensity of the voxel (the second keyframe has none: 0)
    assert np.allclose(exported.intensity[order], [(1.0 + 3.0 + 0.0) / 3, 5.0])
    every = export_points(_tiny_keyframes(), voxel_size=0.0)
    assert every.points.shape == (4, 3)


def _street_map(tmp_path: Path) -> Path:
    return save_map(tmp_path / 'street', street_keyframe_store(), 'map')


def test_map_export_writes_a_pcd_open3d_opens_with_the_maps_points_and_fields(
    tmp_path: Path,
) -> None:
    import open3d as o3d

    folder = _street_map(tmp_path)
    out = tmp_path / 'street.pcd'
    run = CliRunner().invoke(app, ['map', 'export', str(folder), str(out)])
    assert run.exit_code == 0, run.output
    cloud = o3d.t.io.read_point_cloud(str(out))
    assert {'positions', 'label', 'intensity'} <= set(cloud.point)
    points = cloud.point.positions.numpy().astype(np.float64)
    labels = cloud.point.label.numpy().ravel()
    data = load_map(folder)
    expected = export_points(data.keyframes, RegistrationConfig().map.export_voxel)
    assert points.shape[0] == expected.points.shape[0] > 10000
    assert np.allclose(points, expected.points, atol=1e-4)
    assert np.array_equal(labels, expected.labels)
    # every exported point lies on a keyframe point in the map frame (within a voxel)
    from scipy.spatial import cKDTree

    in_map = np.concatenate(
        [k.points @ k.T_map_keyframe[:3, :3].T + k.T_map_keyframe[:3, 3] for k in data.keyframes]
    )
    distance = cKDTree(in_map).query(points)[0]
    assert distance.max() < 0.2 * np.sqrt(3)
    stamps, poses = read_tum_poses(out.with_suffix('.tum'))
    assert np.allclose(poses, [k.T_map_keyframe for k in data.keyframes], atol=1e-6)
    assert np.allclose(stamps, [0.0, 1.0, 2.0, 3.0, 4.0])
    again = CliRunner().invoke(app, ['map', 'export', str(folder), str(out)])
    assert again.exit_code != 0 and 'exists' in f'{again.output}{again.exception}'


def test_keyframes_along_a_trajectory_follow_the_keyframe_distance() -> None:
    trajectory = np.stack([_pose(0.5 * i) for i in range(21)])  # 10 m, every 0.5 m
    assert keyframe_poses_along(trajectory, 2.0, 30.0).tolist() == [0, 4, 8, 12, 16, 20]
    turning = np.stack([_pose(0.0, 0.0, 11.0 * i) for i in range(7)])
    assert keyframe_poses_along(turning, 2.0, 30.0).tolist() == [0, 3, 6]


def test_a_cut_keyframe_is_the_map_around_its_pose_in_its_frame() -> None:
    rng = np.random.default_rng(1)
    points = np.column_stack(
        [rng.uniform(-50, 50, 20000), rng.uniform(-5, 5, 20000), np.zeros(20000)]
    )
    labels = (points[:, 0] > 0).astype(np.uint32) * 40 + 9
    config = RegistrationConfig().replace({'features.voxel_size': 0.0, 'map.import_radius': 10.0})
    pose = _pose(20.0, 1.0, 90.0)
    (keyframe,) = cut_keyframes(
        points, labels, None, pose[None], np.array([7]), config, lambda p, field: field
    )
    in_map = keyframe.points.astype(np.float64) @ pose[:3, :3].T + pose[:3, 3]
    near = np.hypot(points[:, 0] - 20.0, points[:, 1] - 1.0) <= 10.0
    assert keyframe.points.shape[0] == near.sum()
    assert np.allclose(np.sort(in_map[:, 0]), np.sort(points[near, 0]), atol=1e-4)
    assert set(keyframe.labels.tolist()) == {49}  # x > 10: the field's labels
    assert keyframe.stamp_ns == 7 and np.allclose(keyframe.T_map_keyframe, pose)


def test_grid_poses_sit_above_the_ground_where_the_map_has_points() -> None:
    rng = np.random.default_rng(2)
    ground = np.column_stack(
        [rng.uniform(0, 40, 40000), rng.uniform(0, 10, 40000), np.full(40000, -3.0)]
    )
    poses = grid_poses(ground, spacing=10.0, sensor_height=1.7)
    assert len(poses) == 4
    assert np.allclose(np.sort(poses[:, 0, 3]), [5.0, 15.0, 25.0, 35.0])
    assert np.allclose(poses[:, 2, 3], -1.3)


def test_an_imported_labeled_survey_relocalizes_a_scan_between_keyframes(tmp_path: Path) -> None:
    """A labeled point map of the street (a survey), cut along a trajectory, then a query."""
    world, labels = street_scene(seed=STREET_SEED)
    cloud_file = write_cloud(tmp_path / 'survey.ply', world, labels)
    trajectory = np.stack([motion(0.0, (x, 0.0, 0.0)) for x in np.arange(-40.0, 41.0, 1.0)])
    write_tum_poses(tmp_path / 'drive.tum', np.arange(len(trajectory)) * 10**8, trajectory)
    config = RegistrationConfig().replace({'map.keyframe_distance': 15.0})
    imported = import_point_map(
        read_cloud(cloud_file), config, read_tum_poses(tmp_path / 'drive.tum')
    )
    assert imported.placement == 'trajectory' and imported.label_source == 'field'
    assert len(imported.keyframes) == 6  # x = -40, -25, ..., 35
    save_map(tmp_path / 'imported', imported.keyframes, 'map', imported.config)
    data = load_map(tmp_path / 'imported')
    registration = Registration(data.config)
    relocalizer = Relocalizer(registration, data.store(data.config, registration.label_map))
    truth = motion(-40.0, (7.0, -1.0, 0.0))
    points, scan_labels = scan_at(world, labels, truth, seed=901, max_points=15000)
    found = relocalizer.relocalize(points, scan_labels)
    assert found.found, found.trials
    error = np.linalg.solve(truth, found.T_map_sensor)
    assert np.linalg.norm(error[:3, 3]) < 0.3


@pytest.mark.slow
def test_an_imported_unlabeled_pcd_map_localizes_a_simulated_drive(tmp_path: Path) -> None:
    """
    Simulate, map, export, drop the labels, import, relocalize a second drive (docs/maps.md).

    The map is the clean drive of ``mlsemreg simulate --seed 0`` (80 scans) exported as a
    PCD without its label field; ``map import`` cuts it along the exported trajectory and
    labels it with the geometric labeler; the queries (every 5th scan of the drive back in
    the other lane) are labeled the same way (``--labels geometric``).
    """
    import json

    def cli(*args: str) -> None:
        run = CliRunner().invoke(app, [str(a) for a in args])
        assert run.exit_code == 0, f'{args}: {run.output}{run.exception}'

    cli('simulate', tmp_path / 'drive', '--frames', 80, '--seed', 0, '--quiet')
    built = tmp_path / 'built'
    cli('map', 'build', tmp_path / 'drive', built, '--poses', 'ground-truth', '--quiet')
    cli('map', 'export', tmp_path / 'built', tmp_path / 'built.pcd')
    exported = read_cloud(tmp_path / 'built.pcd')
    write_cloud(tmp_path / 'unlabeled.pcd', exported.points)  # no label field
    cli(
        'map',
        'import',
        tmp_path / 'unlabeled.pcd',
        tmp_path / 'imported',
        '--trajectory',
        tmp_path / 'built.tum',
    )
    assert load_map(tmp_path / 'imported').config.label_source == 'geometric'
    cli('map', 'sim-queries', tmp_path / 'queries', '--seed', 0, '--frames', 80, '--every', 5)
    cli(
        'relocalize',
        tmp_path / 'imported',
        tmp_path / 'queries',
        '--labels',
        'geometric',
        '--json',
        tmp_path / 'relocalized.json',
    )
    summary = json.loads((tmp_path / 'relocalized.json').read_text())['summary']
    assert summary['queries'] >= 10
    assert summary['recall_pct'] >= 90.0, summary
    assert summary['wrong_accepted'] == 0, summary
