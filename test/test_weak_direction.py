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
The support of an alignment's weakest direction (issue 35): known answers and a regression.

A corridor (ground and two side walls along x) leaves x free: its support is about 0 of
13,000 inliers. A sign of K points facing x adds the support of about K inliers. The
simulated solid-state field drive (seed 5) whose scan 1 the odometry published 0.78 m off,
"accepted on its own evidence" with 4 perturbed starts back, must no longer publish it.
"""

from __future__ import annotations

from mlsemreg_ros.core.alignment.alignment import align_pair, AlignmentCloud
from mlsemreg_ros.core.alignment.config import FineAlignmentConfig
from mlsemreg_ros.core.alignment.weak_direction import weakest_direction
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry import Odometry
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.simulation.field import FieldConfig, FieldSimulation
import numpy as np
import pytest

SPACING = 0.25  # m between the grid points of every surface


def _grid(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.meshgrid(u, v, indexing='ij')
    return a.ravel(), b.ravel()


def _corridor(sign: bool) -> np.ndarray:
    """Ground and 6 m walls at y = +-8 m along x in [0, 30); a 2 m square sign facing x."""
    x, y = _grid(np.arange(0.0, 30.0, SPACING), np.arange(-8.0, 8.0, SPACING))
    surfaces = [np.c_[x, y, np.zeros_like(x)]]
    x, z = _grid(np.arange(0.0, 30.0, SPACING), np.arange(0.25, 6.0, SPACING))
    surfaces += [np.c_[x, np.full_like(x, side), z] for side in (-8.0, 8.0)]
    if sign:
        y, z = _grid(np.arange(-1.0, 1.0, SPACING), np.arange(1.0, 3.0, SPACING))
        surfaces.append(np.c_[np.full_like(y, 30.0), y, z])
    return np.vstack(surfaces)


def _support(points: np.ndarray) -> tuple[float, np.ndarray, int]:
    cloud = AlignmentCloud.build(points, 0.0, 10)
    alignment = align_pair(cloud, cloud, np.eye(4), FineAlignmentConfig(), 'gicp')
    weak = weakest_direction(alignment)
    return weak.support, weak.direction, alignment.num_inliers


def test_a_corridor_leaves_its_axis_free_and_a_sign_pins_it() -> None:
    free, direction, inliers = _support(_corridor(sign=False))
    assert inliers > 10000
    assert free < 0.002 * inliers  # none faces x (the surfaces' edges give a little)
    assert abs(direction[3]) > 0.99  # the weakest direction is the translation along x
    sign_points = len(_corridor(sign=True)) - len(_corridor(sign=False))
    pinned, direction, _ = _support(_corridor(sign=True))
    assert pinned - free == pytest.approx(sign_points, rel=0.3)  # 64 inliers facing x
    assert abs(direction[3]) > 0.99  # still the weakest, now held by the sign


def test_no_hessian_no_support() -> None:
    cloud = AlignmentCloud.build(np.zeros((3, 3)), 0.0, 10)
    alignment = align_pair(cloud, cloud, np.eye(4), FineAlignmentConfig(), 'gicp')
    assert weakest_direction(alignment).support == 0.0


@pytest.mark.slow
def test_the_solid_state_pose_slid_along_the_road_is_not_published() -> None:
    """Field drive seed 5, livox, geometric labels: scan 1 was published 0.78 m off."""
    sim = FieldSimulation(FieldConfig(seed=5, frames=60, sensor='livox'))
    frames = [sim.frame(k) for k in range(2)]
    truth = np.linalg.solve(frames[0].pose, frames[1].pose)
    outcomes = {}
    for support in (0.0, None):  # 0: the check off, the code before it
        config = RegistrationConfig().replace({'label_source': 'geometric'})
        if support is not None:
            config = config.replace({'near_miss.min_weak_support': support})
        odometry = Odometry(Registration(config))
        for frame in frames:
            points = frame.scan.points.astype(np.float32).astype(np.float64)  # as in the bag
            step = odometry.process(points, None, frame.stamp_ns, point_times=frame.scan.times)
        error = np.linalg.norm(np.linalg.solve(truth, step.pose)[:3, 3])
        outcomes[support] = (step.accepted, error, step.reason)
    accepted, error, reason = outcomes[None]
    assert not accepted or error < 0.6, outcomes  # never published wrong, on any machine
    accepted_off, error_off, reason_off = outcomes[0.0]
    if accepted_off and error_off > 0.6 and 'accepted on its own evidence' in reason_off:
        # where the check off publishes the slide (the machine it was found on), the check is
        # what refuses it; elsewhere the pair falls 1 inlier short of estimator.min_inliers
        # (39 < 40) before the check is asked, and the rule keeps its unit tests above
        assert 'min_weak_support' in reason  # refused, or left to the sweep's confirmation
        assert 'not accepted on its own evidence' in reason or 'not confirmed' in reason
