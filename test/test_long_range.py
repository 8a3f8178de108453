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
Long-range registration helpers (issue 30 parts 1-3): levelling, objects, covisibility.

Known answers on hand-made clouds:

- the ground fit of a tilted scan, and the levelled object search on tilted scans;
- a street 60 m long whose only anchors are poles and a building corner, seen from both
  ends: the object hypotheses find the pose, and the object stage puts it in the pool;
- the overlap where both scans see: the right far pose ~1, the zero motion far less;
- the covisible choice never swaps a candidate for one with less evidence.
"""

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.estimation.covisibility import (
    covisible_choice,
    mutual_covisible_overlap,
    RangeImage,
)
from mlsemreg_ros.core.estimation.object_registration import ObjectsConfig, register_objects
from mlsemreg_ros.core.features.levelling import (
    fit_ground,
    level_transform,
    LevellingConfig,
    tilt_refusal,
)
from mlsemreg_ros.core.matching.labels import LabelMap
from mlsemreg_ros.core.matching.objects import extract_objects, group_ids, object_correspondences
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.poses import within_bounds
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

NAMES = LabelMap.load().names
ROAD, BUILDING, POLE = NAMES.index('road'), NAMES.index('building'), NAMES.index('pole')


def pose(x: float, y: float, z: float, yaw: float, roll: float = 0.0, pitch: float = 0.0):
    """T_world_sensor from a position and angles in degrees."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler('xyz', [roll, pitch, yaw], degrees=True).as_matrix()
    T[:3, 3] = [x, y, z]
    return T


def long_street(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """
    World points and labels of a flat street 110 m long: road, poles and one building corner.

    The poles stand at irregular places on both sides (0.15 m wide, 4 m tall); the corner
    is an L of two 6 m walls, 5 m tall. Nothing else pins the street down.
    """
    rng = np.random.default_rng(seed)
    road = np.column_stack(
        [rng.uniform(-25, 85, 30000), rng.uniform(-7, 7, 30000), rng.normal(0, 0.02, 30000)]
    )
    parts, labels = [road], [np.full(len(road), ROAD)]
    xs = np.array([-12.0, -3.5, 4.0, 13.0, 19.5, 27.0, 33.5, 41.0, 46.5, 55.0, 61.5, 70.0, 78.5])
    for k, x in enumerate(xs):
        side = 6.5 if k % 2 else -6.5
        centre = np.array([x, side + rng.uniform(-0.8, 0.8)])
        angle, height = rng.uniform(0, 2 * np.pi, 120), rng.uniform(0, 4, 120)
        pole = np.column_stack(
            [centre[0] + 0.15 * np.cos(angle), centre[1] + 0.15 * np.sin(angle), height]
        )
        parts.append(pole)
        labels.append(np.full(len(pole), POLE))
    wall_a = np.column_stack([rng.uniform(28, 34, 800), np.full(800, 9.0), rng.uniform(0, 5, 800)])
    wall_b = np.column_stack([np.full(800, 28.0), rng.uniform(9, 15, 800), rng.uniform(0, 5, 800)])
    parts += [wall_a, wall_b]
    labels += [np.full(1600, BUILDING)]
    return np.concatenate(parts), np.concatenate(labels)


def straight_street() -> tuple[np.ndarray, np.ndarray]:
    """Return the poles' street between two straight walls 110 m long."""
    world, labels = long_street()
    rng = np.random.default_rng(1)
    walls = [
        np.column_stack([rng.uniform(-25, 85, 6000), np.full(6000, side), rng.uniform(0, 6, 6000)])
        for side in (-9.0, 9.0)
    ]
    return np.concatenate([world, *walls]), np.concatenate([labels, np.full(12000, BUILDING)])


def scan(world: np.ndarray, labels: np.ndarray, T_world_sensor: np.ndarray, reach: float = 50):
    """Return the world points within ``reach`` of the sensor, in its frame (no occlusion)."""
    local = (world - T_world_sensor[:3, 3]) @ T_world_sensor[:3, :3]
    keep = np.linalg.norm(local[:, :2], axis=1) <= reach
    return local[keep], labels[keep]


def test_ground_fit_of_a_tilted_scan_levels_it():
    world, labels = long_street()
    T_world_sensor = pose(10.0, 1.0, 1.7, 30.0, roll=4.0, pitch=-3.0)
    points, scan_labels = scan(world, labels, T_world_sensor)
    fit = fit_ground(points, scan_labels, np.array([ROAD]), LevellingConfig())
    assert fit is not None
    up = T_world_sensor[:3, :3].T @ [0.0, 0.0, 1.0]  # the world's up in the sensor frame
    assert np.degrees(np.arccos(np.clip(fit.normal @ up, -1, 1))) < 0.3
    levelled = points @ fit.T_level_sensor[:3, :3].T + fit.T_level_sensor[:3, 3]
    assert abs(np.median(levelled[scan_labels == ROAD, 2])) < 0.05
    # without labels the lowest points stand in
    unlabeled = fit_ground(points, np.zeros_like(scan_labels), np.array([ROAD]), LevellingConfig())
    assert unlabeled is not None and unlabeled.normal @ up > np.cos(np.radians(1.0))


def test_tilt_refusal_keeps_the_levelled_pose_and_refuses_a_tilt():
    world, labels = long_street()
    T_ws, T_wt = pose(0, 0, 1.7, 0, roll=3.0), pose(20, 0, 1.7, 10, pitch=-4.0)
    fits = [
        fit_ground(*scan(world, labels, T), np.array([ROAD]), LevellingConfig())
        for T in (T_ws, T_wt)
    ]
    truth = np.linalg.inv(T_wt) @ T_ws
    assert tilt_refusal(truth, *fits, LevellingConfig()) == ''
    tilted = truth @ pose(0, 0, 0, 0, roll=12.0)
    assert 'tilt off the ground' in tilt_refusal(tilted, *fits, LevellingConfig())


def _object_poses(T_ws: np.ndarray, T_wt: np.ndarray, config: ObjectsConfig):
    """Level both scans, extract and match their objects: the target-source poses."""
    world, labels = long_street()
    levels, objects = [], []
    for T in (T_ws, T_wt):
        points, scan_labels = scan(world, labels, T)
        fit = fit_ground(points, scan_labels, np.array([ROAD]), LevellingConfig())
        level = fit.T_level_sensor
        levelled = points @ level[:3, :3].T + level[:3, 3]
        levels.append(level)
        objects.append(
            extract_objects(levelled, scan_labels, group_ids(NAMES), 4.0, config.max_range)
        )
    rows, cols = object_correspondences(*objects, config.extent_ratio)
    found = register_objects(*objects, rows, cols, config)
    return level_transform(levels[0], levels[1], found.transforms), found


def test_levelled_object_search_on_tilted_scans():
    T_ws = pose(0.0, 0.0, 1.7, 5.0, roll=3.0, pitch=2.0)
    T_wt = pose(20.0, 1.5, 1.7, -20.0, roll=-2.0, pitch=4.0)
    transforms, found = _object_poses(T_ws, T_wt, ObjectsConfig(enabled=True))
    truth = np.linalg.inv(T_wt) @ T_ws
    assert len(transforms) and found.matches[0] >= 6
    assert within_bounds(transforms[0], truth, 0.3, 1.0)


def test_street_60_m_poles_and_a_building_corner():
    """Scans from the two ends of 60 m of street: only poles and a corner anchor them."""
    T_ws, T_wt = pose(0.0, 0.0, 1.7, 0.0), pose(60.0, -1.0, 1.7, 175.0)
    transforms, found = _object_poses(T_ws, T_wt, ObjectsConfig(enabled=True, min_objects=3))
    truth = np.linalg.inv(T_wt) @ T_ws
    assert len(transforms), found.diagnostics
    assert within_bounds(transforms[0], truth, 0.5, 2.0), (transforms[0], truth)


def test_object_stage_puts_the_60_m_pose_in_the_pool():
    world, labels = long_street()
    T_ws, T_wt = pose(0.0, 0.0, 1.7, 0.0), pose(60.0, -1.0, 1.7, 175.0)
    cfg = RegistrationConfig()
    cfg.objects.enabled, cfg.objects.min_objects = True, 3
    cfg.bev_search.weak_inliers = 100000  # every pose is weak: the object stage runs
    cfg.fine.pair_method = 'off'
    registration = Registration(cfg)
    seen = {}

    class Spy:
        name = 'spy'

        def wanted(self, context):
            seen['pool'] = context.pool
            return False

    registration.stages.insert(len(registration.stages) - 1, Spy())
    source = registration.prepare(*scan(world, labels, T_ws))
    target = registration.prepare(*scan(world, labels, T_wt))
    result = registration.register(source, target, refine=False)
    truth = np.linalg.inv(T_wt) @ T_ws
    pool = seen['pool']
    found = [
        h
        for h in pool.hypotheses
        if h.origin == 'objects' and within_bounds(h.T_target_source, truth, 0.5, 2.0)
    ]
    assert found, [h.origin for h in pool.hypotheses]
    assert result.diagnostics['objects_best_matches'] >= 3


def test_covisible_overlap_of_a_far_pose():
    """The right pose 60 m away is seen ~1 where both see; a turned one is seen through."""
    world, labels = straight_street()
    T_ws, T_wt = pose(0.0, 0.0, 1.7, 0.0), pose(60.0, -1.0, 1.7, 175.0)
    sides = []
    for T in (T_ws, T_wt):
        points, _ = scan(world, labels, T)
        sample = points[:: max(1, len(points) // 2000)]
        weight = np.full(len(sample), 1.0 / len(sample))
        sides.append((sample, weight, cKDTree(points), RangeImage.of(points, 2.0)))
    truth = np.linalg.inv(T_wt) @ T_ws
    overlap, checked = mutual_covisible_overlap(
        np.stack([truth, pose(0, 0, 0, 30.0) @ truth]), sides[0], sides[1], 0.6, 1.0
    )
    assert overlap[0] > 0.95 and checked[0] > 0.03
    assert overlap[1] < 0.8  # the walls turned across the street: the target sees through


def _choose(overlap, checked, inliers, scores, current, min_gain=0.03):
    return covisible_choice(
        np.array(overlap),
        np.array(checked),
        np.array(inliers),
        np.array(scores),
        current,
        0.03,
        min_gain,
    )


def test_covisible_choice_never_takes_less_evidence():
    """A tie in covisible overlap on less checked surface, inliers and score is no reason."""
    # the mirrored street (test_verification): the right BEV pose (1) against a pose
    # 180 deg off that also sees 1.00 where both scans see, but of far less surface
    assert _choose([1.0, 1.0], [0.11, 0.86], [0, 40], [0.11, 0.85], current=1) == 1
    # a current pose with too little surface checked is not replaced by a candidate with
    # less of every count (and nothing is judged by its covisible overlap: -1)
    assert _choose([1.0, 0.6], [0.02, 0.03], [40, 3], [0.5, 0.1], current=0) == -1
    # a candidate with more of one count (less surface seen through) may replace it
    assert _choose([1.0, 0.9], [0.11, 0.86], [0, 40], [0.11, 0.85], 1, min_gain=0.0) == 0


def test_covisible_choice_keeps_the_current_pose_within_the_gain():
    """Variants of one pose differ by 0.01-0.02: the current one stays among them."""
    kept = _choose([0.975, 0.986, 0.98], [0.05, 0.05, 0.05], [21, 20, 19], [0.17, 0.16, 0.17], 0)
    assert kept == 0
    # a wrong current pose (0.81) gives way to the best covisible overlap
    assert _choose([0.81, 0.975, 0.96], [0.18, 0.11, 0.1], [53, 6, 7], [0.13, 0.06, 0.07], 0) == 1
    # too little surface checked: not eligible at all
    assert _choose([1.0, 0.5], [0.002, 0.2], [5, 40], [0.01, 0.2], 1) == 1
    assert _choose([1.0], [0.002], [5], [0.01], 0) == -1
