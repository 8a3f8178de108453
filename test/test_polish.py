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
"""Dense polishing of candidate poses (core/estimation/polish.py)."""

from __future__ import annotations

from mlsemreg_ros.core.estimation.confidence import tilt_deg
from mlsemreg_ros.core.estimation.polish import polish_poses, radius_schedule, yaw_rigid_transform
from mlsemreg_ros.core.metrics import rotation_error_deg
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation


def _pose(yaw_deg: float, t: tuple[float, float, float], roll_deg: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler('zyx', [yaw_deg, 0.0, roll_deg], degrees=True).as_matrix()
    T[:3, 3] = t
    return T


def _scene(rng: np.random.Generator) -> np.ndarray:
    """Build a street corner: ground, two facades at a right angle, a few poles (metres)."""
    ground = np.column_stack([rng.uniform(-30, 30, (4000, 2)), rng.normal(-1.7, 0.02, 4000)])
    wall_a = np.column_stack(
        [rng.uniform(-30, 30, 2000), np.full(2000, 8.0), rng.uniform(-1.7, 6, 2000)]
    )
    wall_b = np.column_stack(
        [np.full(1500, -12.0), rng.uniform(-20, 8, 1500), rng.uniform(-1.7, 6, 1500)]
    )
    poles = [
        np.column_stack(
            [rng.normal(x, 0.05, 100), rng.normal(y, 0.05, 100), rng.uniform(-1.7, 3, 100)]
        )
        for x, y in ((4.0, -5.0), (15.0, -6.0), (-3.0, 4.0), (22.0, 3.0))
    ]
    return np.concatenate([ground, wall_a, wall_b, *poles])


def test_yaw_rigid_transform_recovers_a_known_yaw_and_shift():
    rng = np.random.default_rng(0)
    src = rng.uniform(-10, 10, (2, 50, 3))
    truth = np.stack([_pose(25.0, (1.0, -2.0, 0.3)), _pose(-170.0, (0.0, 5.0, 0.0))])
    dst = src @ truth[:, :3, :3].transpose(0, 2, 1) + truth[:, None, :3, 3]
    found = yaw_rigid_transform(src, dst, np.ones((2, 50)))
    np.testing.assert_allclose(found, truth, atol=1e-9)
    assert np.allclose(yaw_rigid_transform(src, dst, np.zeros((2, 50))), np.eye(4))


def test_polishing_pulls_near_candidates_onto_the_truth_and_keeps_their_tilt():
    rng = np.random.default_rng(1)
    target = _scene(rng)
    truth = _pose(30.0, (6.0, -3.0, 0.0))
    # the source scan sees the same scene: p_source = truth^-1 p_target (plus noise)
    inverse = np.linalg.inv(truth)
    source = target @ inverse[:3, :3].T + inverse[:3, 3] + rng.normal(0, 0.02, target.shape)
    off = _pose(3.0, (0.8, -0.6, 0.0)) @ truth  # 3 deg and 1 m off, like a BEV peak
    tilted = _pose(0.0, (0.0, 0.0, 0.0), roll_deg=2.0) @ truth
    far = _pose(0.0, (20.0, 0.0, 0.0)) @ truth  # a slide: stays a slide
    sample = source[rng.choice(len(source), 1000, replace=False)]
    polished = polish_poses(
        np.stack([off, tilted, far]),
        sample,
        cKDTree(target),
        target,
        radius_schedule(2.0, 0.6, 8),
    )
    assert rotation_error_deg(polished[0], truth) < 0.3
    assert np.linalg.norm(polished[0][:3, 3] - truth[:3, 3]) < 0.1
    assert abs(tilt_deg(polished[1]) - tilt_deg(tilted)) < 1e-6  # turned about z only
    assert np.linalg.norm(polished[2][:3, 3] - truth[:3, 3]) > 10.0


def test_radius_schedule_shrinks_then_holds():
    radii = radius_schedule(2.0, 0.6, 8)
    assert len(radii) == 8 and radii[0] == 2.0
    assert np.all(np.diff(radii) <= 0) and np.allclose(radii[3:], 0.6)
    assert radius_schedule(2.0, 0.6, 0).size == 0
