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

"""Moving objects stay out of the odometry's local map (``core/features/moving_objects.py``)."""

from __future__ import annotations

from mlsemreg_ros.core.config import ConfigError, RegistrationConfig
from mlsemreg_ros.core.features.moving_objects import MovingObjectFilter, MovingObjectsConfig
from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.odometry import Odometry
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.rigid import invert_transform
from mlsemreg_ros.datasets.synthetic_scene import motion, scan_at, street_scene
import numpy as np
import pytest
from scipy.spatial import cKDTree

FRAMES = 4
STEP_M = 1.5  # ego motion per scan
CAR_STEP_M = 4.0  # the other car drives faster, along the centre of the road
CAR_RAW, MOVING_CAR_RAW, ROAD_RAW = 10, 252, 40
CAR = 1  # learning id
LABEL_MAP = LabelMap.load()


def _car_box(rng: np.random.Generator, center: np.ndarray) -> np.ndarray:
    """Surface samples of a 4 x 1.6 x 1.1 m box floating 0.4 m above the road (world)."""
    lo, hi = center - np.array([2.0, 0.8, 0.0]), center + np.array([2.0, 0.8, 1.1])
    cube = rng.uniform(lo, hi, (6000, 3))
    side = rng.integers(0, 3, len(cube))
    rows = np.arange(len(cube))
    cube[rows, side] = np.where(rng.random(len(cube)) < 0.5, lo[side], hi[side])
    return cube


def _drive(scheme: str, car_label: str) -> list[tuple[np.ndarray, np.ndarray, int, np.ndarray]]:
    """(points, labels, stamp, car points in the first scan's frame) of a drive with a car."""
    world, labels = street_scene(seed=3)
    rng = np.random.default_rng(7)
    origin = motion(0.0, (-20.0, 0.0, 0.0))
    out = []
    for k in range(FRAMES):
        pose = motion(0.0, (-20.0 + STEP_M * k, 0.0, 0.0))
        points, learning = scan_at(world, labels, pose, seed=100 + k, max_points=20000)
        car_world = _car_box(rng, np.array([-12.0 + CAR_STEP_M * k, 0.0, 0.4]))
        car = (invert_transform(pose) @ np.c_[car_world, np.ones(len(car_world))].T).T[:, :3]
        if scheme == 'raw':
            ids = LABEL_MAP.to_raw(learning, np.full(len(learning), 3)).astype(np.uint32)
            raw = {'moving': MOVING_CAR_RAW, 'parked': CAR_RAW, 'road': ROAD_RAW}[car_label]
            car_ids = np.full(len(car), raw | (40001 << 16), dtype=np.uint32)
        else:
            ids = learning.astype(np.uint32)
            car_ids = np.full(len(car), CAR if car_label != 'road' else 9, dtype=np.uint32)
        in_odom = (invert_transform(origin) @ np.c_[car_world, np.ones(len(car))].T).T[:, :3]
        out.append((np.r_[points, car], np.r_[ids, car_ids], 100_000_000 * k, in_odom))
    return out


def _run(drive: list, **overrides: str) -> tuple[Odometry, list[np.ndarray]]:
    """Odometry over the drive; the local map (odom frame) after every scan."""
    config = RegistrationConfig().replace(
        {'keypoints.count': 1000, **{f'moving_objects.{k}': v for k, v in overrides.items()}}
    )
    odometry = Odometry(Registration(config))
    maps = []
    for points, labels, stamp, _ in drive:
        step = odometry.process(points, labels, stamp)
        assert step.accepted, step.reason
        maps.append(odometry.local_map.points())
    return odometry, maps


def _car_voxels(map_points: np.ndarray, drive: list) -> int:
    """Map voxels above the road inside the footprint of any of the car's positions."""
    count = 0
    for *_, car in drive:
        margin = np.array([0.3, 0.3, 0.5])
        lo, hi = car.min(axis=0) - margin * [1, 1, 0], car.max(axis=0) + margin
        inside = np.all((map_points >= lo) & (map_points <= hi), axis=1) & (map_points[:, 2] > 0.3)
        count += int(np.count_nonzero(inside))
    return count


@pytest.mark.parametrize(
    ('scheme', 'map_filter', 'matching'),
    [
        ('raw', 'moving', 'drop'),
        ('raw', 'moving', 'keep'),
        ('raw', 'movable', 'drop'),
        ('learning', 'movable', 'keep'),
    ],
)
def test_a_moving_car_never_enters_the_map(scheme: str, map_filter: str, matching: str) -> None:
    drive = _drive(scheme, 'moving')
    odometry, maps = _run(drive, map_filter=map_filter, matching=matching)
    for map_points in maps:
        assert _car_voxels(map_points, drive) == 0
    # the scans were tracked: the car is out of the map, the street is in it
    assert len(maps[-1]) > 1000
    prepared = odometry.keyframe.prepared
    if matching == 'keep':  # the keyframe still holds the car for keypoint matching
        assert prepared.map_excluded is not None and prepared.map_excluded.sum() > 10
    else:
        assert prepared.map_excluded is None


def test_without_the_filter_the_car_is_in_the_map_as_the_test_can_tell() -> None:
    drive = _drive('raw', 'moving')
    _, maps = _run(drive, map_filter='off')
    assert _car_voxels(maps[0], drive) > 10


def test_learning_ids_have_no_moving_class_so_moving_keeps_the_car() -> None:
    drive = _drive('learning', 'moving')
    _, maps = _run(drive, map_filter='moving')
    assert _car_voxels(maps[0], drive) > 10


def test_a_parked_car_is_kept_by_moving_and_left_out_by_movable() -> None:
    drive = _drive('raw', 'parked')
    _, moving = _run(drive, map_filter='moving')
    _, movable = _run(drive, map_filter='movable')
    assert _car_voxels(moving[0], drive) > 10
    assert _car_voxels(movable[0], drive) == 0


def test_filter_off_leaves_the_map_unchanged() -> None:
    # the first scan's map is its geometry alone: with the filter off, a moving car's map is
    # the map of the same points with the car labeled road (nothing to filter)
    moving = _drive('raw', 'moving')[:1]
    road = _drive('raw', 'road')[:1]
    _, off = _run(moving, map_filter='off')
    _, unfiltered = _run(road, map_filter='moving')

    # the same voxels; their order and last digits follow small_gicp's threads
    assert off[0].shape == unfiltered[0].shape
    distance = cKDTree(unfiltered[0]).query(off[0])[0]
    assert distance.max() < 1e-9


def test_raw_mask_reads_raw_and_learning_ids() -> None:
    mask = MovingObjectFilter(LABEL_MAP)
    moving, movable = MovingObjectsConfig(), MovingObjectsConfig(map_filter='movable')
    raw = np.array([40, 252 | (7 << 16), 259, 10 | (9 << 16), 50, 254, 260, 251], dtype=np.uint32)
    np.testing.assert_array_equal(
        mask.raw_mask(raw, moving, 'raw'), [0, 1, 1, 0, 0, 1, 0, 0]
    )  # only 252-259, with or without instance bits
    np.testing.assert_array_equal(mask.raw_mask(raw, moving, 'auto'), [0, 1, 1, 0, 0, 1, 0, 0])
    # movable: the moving ids map to their class (259 moving-other-vehicle -> other-vehicle)
    np.testing.assert_array_equal(mask.raw_mask(raw, movable, 'raw'), [0, 1, 1, 1, 0, 1, 0, 0])
    learning = np.array([9, 1, 13, 6, 7, 15, 4, 0], dtype=np.int32)
    assert mask.raw_mask(learning, moving, 'auto') is None  # no moving class in learning ids
    assert mask.raw_mask(raw, moving, 'learning') is None
    np.testing.assert_array_equal(
        mask.raw_mask(learning, movable, 'learning'), [0, 1, 0, 1, 1, 0, 1, 0]
    )
    assert mask.raw_mask(raw, MovingObjectsConfig(map_filter='off'), 'raw') is None
    assert mask.raw_mask(np.array([40, 50], dtype=np.uint32), moving, 'raw') is None


def test_prepared_mask_marks_the_voxels_of_filtered_points() -> None:
    mask = MovingObjectFilter(LABEL_MAP)
    prepared = np.array([[0.25, 0.25, 0.25], [1.25, 0.25, 0.25], [-0.25, 0.25, 0.25]])
    labels = np.array([9, 1, 13])
    filtered = np.array([[0.49, 0.01, 0.3], [0.4, 0.4, 0.4]])  # both in voxel (0, 0, 0)
    np.testing.assert_array_equal(
        mask.prepared_mask(prepared, labels, filtered, MovingObjectsConfig(), 0.5), [1, 0, 0]
    )
    np.testing.assert_array_equal(
        mask.prepared_mask(prepared, labels, None, MovingObjectsConfig(map_filter='movable'), 0.5),
        [0, 1, 0],
    )
    exact = mask.prepared_mask(prepared, labels, prepared[2:], MovingObjectsConfig(), 0.0)
    np.testing.assert_array_equal(exact, [0, 0, 1])


def test_unknown_movable_classes_are_refused_when_the_odometry_is_built() -> None:
    config = RegistrationConfig().replace({'moving_objects.movable_classes': ['car', 'tram']})
    with pytest.raises(ConfigError, match='tram'):
        Odometry(Registration(config))
