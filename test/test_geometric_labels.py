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
"""The geometric labeler: hand-made scenes with known answers, and real scans of 12 sensors."""

from __future__ import annotations

from pathlib import Path

from mlsemreg_ros.core.features.features import voxel_downsample
from mlsemreg_ros.core.labeling import geometric as g
from mlsemreg_ros.core.labeling.geometric import GeometricLabeler
from mlsemreg_ros.core.labeling.geometric_config import GeometricLabelsConfig
import numpy as np
import pytest

SENSOR_HEIGHT = 1.8
REAL_SCANS = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'real_sensor_scans'


def _grid(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    u, v = np.meshgrid(a, b, indexing='ij')
    return u.reshape(-1), v.reshape(-1)


def ground(rng: np.random.Generator, tilt: float = 0.0) -> np.ndarray:
    """Sample a plane 1.8 m below the sensor (rising ``tilt`` m per m along x), +-30 m."""
    x, y = _grid(np.arange(-30.0, 30.0, 0.25), np.arange(-30.0, 30.0, 0.25))
    z = -SENSOR_HEIGHT + tilt * x + rng.normal(0.0, 0.01, x.shape)
    return np.c_[x, y, z]


def pole(x: float, y: float, height: float = 6.0) -> np.ndarray:
    """Sample a 0.2 m thick pole from the ground up: four vertical lines."""
    z = np.arange(-SENSOR_HEIGHT + 0.1, -SENSOR_HEIGHT + height, 0.1)
    return np.concatenate(
        [
            np.c_[np.full_like(z, x + dx), np.full_like(z, y + dy), z]
            for dx, dy in ((0.1, 0), (-0.1, 0), (0, 0.1), (0, -0.1))
        ]
    )


def wall(x: float) -> np.ndarray:
    """Sample a wall 8 m high across y in [-15, 15] at ``x``."""
    y, z = _grid(np.arange(-15.0, 15.0, 0.2), np.arange(-SENSOR_HEIGHT + 0.1, 6.0, 0.2))
    return np.c_[np.full_like(y, x), y, z]


def box(cx: float, cy: float, size=(4.5, 1.8, 1.5)) -> np.ndarray:
    """Sample the surface of a car-sized box standing on the ground (not its bottom)."""
    lx, ly, lz = size
    step = 0.15
    xs = np.arange(-lx / 2, lx / 2 + 1e-9, step)
    ys = np.arange(-ly / 2, ly / 2 + 1e-9, step)
    zs = np.arange(0.3, lz + 1e-9, step)
    faces = []
    u, v = _grid(xs, ys)
    faces.append(np.c_[u, v, np.full_like(u, lz)])
    for y0 in (-ly / 2, ly / 2):
        u, w = _grid(xs, zs)
        faces.append(np.c_[u, np.full_like(u, y0), w])
    for x0 in (-lx / 2, lx / 2):
        v, w = _grid(ys, zs)
        faces.append(np.c_[np.full_like(v, x0), v, w])
    pts = np.concatenate(faces)
    return pts + np.array([cx, cy, -SENSOR_HEIGHT])


def tree(rng: np.random.Generator, x: float, y: float) -> np.ndarray:
    """Sample a trunk and a scattered crown (a ball of radius 2 m, 3 to 7 m up)."""
    crown = rng.normal(0.0, 1.0, (3000, 3))
    crown = (
        crown
        / np.linalg.norm(crown, axis=1, keepdims=True)
        * 2.0
        * rng.uniform(0, 1, (3000, 1)) ** (1 / 3)
    )
    crown += np.array([x, y, -SENSOR_HEIGHT + 5.0])
    return np.concatenate([pole(x, y, 3.0), crown])


def labeled(scene: list[np.ndarray], **config) -> tuple[np.ndarray, list[np.ndarray], float]:
    points = np.concatenate(scene)
    raw = np.zeros(len(points), dtype=np.int64)
    voxels, _ = voxel_downsample(points, raw, 0.3)  # as the pipeline sees them
    out = GeometricLabeler(GeometricLabelsConfig(**config)).label(voxels)
    # the label of each object: the labels of the voxels nearest its points
    from scipy.spatial import cKDTree

    tree_ = cKDTree(voxels)
    per_object = [out.raw[tree_.query(part)[1]] for part in scene]
    return out.raw, per_object, out.sensor_height


def majority(labels: np.ndarray) -> int:
    values, counts = np.unique(labels, return_counts=True)
    return int(values[np.argmax(counts)])


def share(labels: np.ndarray, value: int) -> float:
    return float(np.mean(labels == value))


def test_a_plane_is_ground_and_gives_the_sensor_height() -> None:
    rng = np.random.default_rng(0)
    _, (plane,), height = labeled([ground(rng)])
    assert share(plane, g.ROAD) > 0.99
    assert height == pytest.approx(SENSOR_HEIGHT, abs=0.05)


def test_a_sloped_road_is_still_ground() -> None:
    rng = np.random.default_rng(1)
    _, (plane,), _ = labeled([ground(rng, tilt=0.05)])  # a 5 % grade: +-1.5 m at 30 m
    assert share(plane, g.ROAD) > 0.95


def test_pole_wall_box_on_the_ground() -> None:
    rng = np.random.default_rng(2)
    scene = [ground(rng), pole(8.0, 3.0), wall(-14.0), box(7.0, -8.0)]
    _, (plane, pole_, wall_, box_), _ = labeled(scene)
    assert share(plane, g.ROAD) > 0.9
    assert majority(pole_) == g.POLE and share(pole_, g.POLE) > 0.6
    assert majority(wall_) == g.BUILDING and share(wall_, g.BUILDING) > 0.7
    assert majority(box_) == g.CAR and share(box_, g.CAR) > 0.7


def test_a_tree_is_trunk_under_vegetation() -> None:
    rng = np.random.default_rng(3)
    scene = [ground(rng), tree(rng, 10.0, 5.0)]
    _, (_, tree_), _ = labeled(scene)
    assert share(tree_, g.VEGETATION) > 0.6
    trunk_points = tree_[: len(pole(0, 0, 3.0))]
    assert share(trunk_points, g.TRUNK) + share(trunk_points, g.POLE) > 0.3


def test_a_configured_sensor_height_is_used() -> None:
    rng = np.random.default_rng(4)
    _, _, height = labeled([ground(rng)], sensor_height=2.0)
    assert height == 2.0


def test_labels_are_stable_under_a_small_motion() -> None:
    """The same scene moved by 0.3 m and 1 deg keeps >= 90 % of its labels (Mask Matching)."""
    rng = np.random.default_rng(5)
    scene = np.concatenate(
        [ground(rng), pole(8.0, 3.0), wall(-14.0), box(7.0, -8.0), tree(rng, 10.0, 5.0)]
    )
    lab = GeometricLabeler()
    first = lab.label(scene).raw
    angle = np.radians(1.0)
    rotation = np.array(
        [[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]]
    )
    moved = scene @ rotation.T + np.array([0.3, 0.1, 0.0])
    second = lab.label(moved).raw
    assert np.mean(first == second) > 0.9


def test_empty_and_tiny_scans() -> None:
    lab = GeometricLabeler()
    assert lab.label(np.zeros((0, 3))).raw.shape == (0,)
    assert lab.label(np.ones((2, 3))).raw.shape == (2,)
    far = np.full((5, 3), 1e6)
    assert np.all(lab.label(far).raw == g.UNLABELED)


@pytest.mark.skipif(not REAL_SCANS.is_dir(), reason=f'no real sensor scans in {REAL_SCANS}')
def test_twelve_real_sensors_sane() -> None:
    """One real scan of each of 12 sensors: some ground, no class above 80 %."""
    import open3d as o3d

    files = sorted(REAL_SCANS.glob('*.pcd'))
    assert len(files) == 12
    lab = GeometricLabeler()
    for file in files:
        points = o3d.t.io.read_point_cloud(str(file)).point.positions.numpy().astype(np.float64)
        points = points[np.isfinite(points).all(axis=1)]
        voxels, _ = voxel_downsample(points, np.zeros(len(points), dtype=np.int64), 0.3)
        shares = lab.label(voxels).shares()
        assert max(shares.values()) <= 0.8, (file.name, shares)
        assert 0.05 <= shares.get(g.ROAD, 0.0) <= 0.8, (file.name, shares)


def test_object_points_without_support_take_their_runner_up_class() -> None:
    """A pole point alone on a wall becomes building; a pole of 10 points stays a pole."""
    wall_ = np.c_[
        np.full(50, 5.0), np.repeat(np.arange(10) * 0.2, 5), np.tile(np.arange(5) * 0.2, 10)
    ]
    pole_ = np.c_[np.full(10, 9.0), np.zeros(10), np.arange(10) * 0.2]
    points = np.concatenate([wall_, pole_])
    raw = np.r_[np.full(50, g.BUILDING), np.full(10, g.POLE)].astype(np.uint32)
    raw[12] = g.POLE  # a stray pole point inside the wall
    second = np.r_[np.full(50, g.BUILDING), np.full(10, g.VEGETATION)].astype(np.uint32)
    g._drop_unsupported(points, raw, second)
    assert raw[12] == g.BUILDING
    assert np.all(raw[50:] == g.POLE)
    assert np.all(np.delete(raw[:50], 12) == g.BUILDING)


def test_every_point_has_a_runner_up_class() -> None:
    """Objects keep the shape class under them as runner-up; the ground its own class."""
    rng = np.random.default_rng(2)
    scene = np.concatenate([ground(rng), pole(8.0, 3.0), wall(-14.0), box(7.0, -8.0)])
    out = GeometricLabeler().label(scene)
    assert out.second is not None and out.second.shape == out.raw.shape
    objects = np.isin(out.raw, (g.POLE, g.TRUNK, g.CAR))
    assert objects.any()
    assert not np.isin(out.second[objects], (g.POLE, g.TRUNK, g.CAR)).any()
    road = out.raw == g.ROAD
    assert np.all(out.second[road] == g.ROAD)


def test_vertical_lines_are_poles_only_near_the_sensor() -> None:
    """A line held above the ground (no standing column): a pole at 8 m, not at 25 m."""
    rng = np.random.default_rng(4)

    def held(x: float, y: float) -> np.ndarray:
        upright = pole(x, y)
        return upright[upright[:, 2] >= -SENSOR_HEIGHT + 1.6]  # from 1.6 m up

    assert np.hypot(24.0, 7.0) > g.LINE_RANGE > np.hypot(8.0, 3.0)
    _, (_, near, far), _ = labeled([ground(rng), held(8.0, 3.0), held(24.0, 7.0)])
    assert majority(near) == g.POLE
    assert share(far, g.POLE) == 0.0


def test_support_counts_equal_the_kd_tree_counts() -> None:
    """The compiled counts of the support test are the KD-tree's, point for point."""
    from mlsemreg_ros.core.features.cell_grid import CellGrid
    from mlsemreg_ros.core.labeling import geometric_kernels as gk
    from mlsemreg_ros.core.matching import landmarks
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(4)
    # a clump, and points exactly 0.6 m apart: a tie at the radius counts on both sides
    ties = np.array([[0.0, 0, 0], [0.6, 0, 0], [1.2, 0, 0], [0, 0.6, 0], [0, 0, -0.6]])
    points = np.concatenate([rng.normal(10.0, 1.0, (3000, 3)), ties])
    raw = rng.choice(np.array([g.POLE, g.TRUNK, g.CAR, g.BUILDING], dtype=np.uint32), len(points))
    raw[-5:] = g.POLE
    objects = np.isin(raw, g.OBJECT_IDS)
    rows = np.flatnonzero(objects)
    grid = CellGrid.build(points, g.SUPPORT_RADIUS)
    total, same = gk.support_counts(points, rows, raw, objects, g.SUPPORT_RADIUS, grid)
    expected = landmarks.confident_points(
        points, raw, objects, g.LANDMARK_SUPPORT, g.SUPPORT_RADIUS
    )
    assert np.array_equal(same >= g.LANDMARK_SUPPORT * total, expected)
    within = cKDTree(points).query_ball_point(points[rows], g.SUPPORT_RADIUS, return_length=True)
    assert np.array_equal(total, within)
    assert np.all(total >= 1) and np.all(same >= 1)  # each point counts itself


def test_the_label_source_leaves_non_finite_points_unlabeled() -> None:
    """A NaN row gets label 0; the finite rows get the labels of the scan without it."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.labeling.source import LabelSource

    rng = np.random.default_rng(5)
    scene = np.concatenate([ground(rng), pole(8.0, 3.0), wall(-14.0), box(7.0, -8.0)])
    config = RegistrationConfig()
    config.label_source = 'geometric'
    clean = LabelSource()(scene, None, config).labels
    dirty = np.insert(scene, 100, np.nan, axis=0)
    labels = LabelSource()(dirty, None, config).labels
    assert labels[100] == 0
    assert np.array_equal(np.delete(labels, 100), clean)
    assert np.unique(clean).size >= 3


def test_window_sums_of_sparse_columns() -> None:
    """The compiled window sum equals a dense raster's box sum on random occupied columns."""
    from scipy.ndimage import convolve

    rng = np.random.default_rng(6)
    cells = rng.integers(0, 12, (60, 2))
    points = np.c_[(cells + 0.5) * 0.5, np.zeros(len(cells))]
    columns = g.Columns.of(points, 0.5)
    values = rng.integers(1, 9, columns.count).astype(np.float64)
    raster = np.zeros((12, 12))
    raster[columns.cells[:, 0], columns.cells[:, 1]] = values
    for radius in (1, 2):
        kernel = np.ones((2 * radius + 1,) * 2)
        box = convolve(raster, kernel, mode='constant')
        expected = box[columns.cells[:, 0], columns.cells[:, 1]]
        assert np.array_equal(columns.window_sum(values, radius), expected)
