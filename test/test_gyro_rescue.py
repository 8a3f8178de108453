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
The gyro's rescue of a refused global pose (core/odometry/gyro_rescue.py).

Known answers of the rotation comparison and of the gyro's rotation without a velocity, and
the real dev pair ``000007`` as ``mlsemreg fuzz-node`` sends it with an IMU only: the second
scan has no prediction, its global pose is refused, and the gyro confirms it; a gyro turned
by 5 deg confirms nothing, and the scan stays rejected.
"""

from __future__ import annotations

from dev_pairs import DEV_PAIRS
from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry import Odometry
from mlsemreg_ros.core.odometry.gyro_rescue import gyro_disagreement_deg
from mlsemreg_ros.core.odometry.prior_model import PriorMotionModel
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.rigid import invert_transform, rotation_angle_deg
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

T0_NS = 1_000_000_000_000


def _pose(yaw_deg: float, x: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler('z', yaw_deg, degrees=True).as_matrix()
    T[0, 3] = x
    return T


def test_the_disagreement_is_the_angle_between_the_gyro_and_the_pose() -> None:
    last = _pose(30.0, 5.0)
    gyro = _pose(10.0)[:3, :3]
    assert gyro_disagreement_deg(last, gyro, _pose(40.0, 25.0)) == pytest.approx(0.0, abs=1e-9)
    assert gyro_disagreement_deg(last, gyro, _pose(42.5, -3.0)) == pytest.approx(2.5)


def test_the_gyro_rotation_needs_one_accepted_pose_and_a_covering_imu() -> None:
    model = PriorMotionModel(RegistrationConfig())
    stamps = T0_NS + np.arange(0, 1_100_000_000, 5_000_000, dtype=np.int64)  # 200 Hz, 1.1 s
    rate = np.radians([0.0, 0.0, 12.0])  # 12 deg/s about z
    model.add_imu(stamps, np.tile(rate, (len(stamps), 1)), np.tile([0, 0, 9.81], (len(stamps), 1)))
    assert model.gyro_rotation(T0_NS + 10**9) is None  # no accepted pose yet
    model.update(np.eye(4), T0_NS)
    assert model.predict(T0_NS + 10**9) is None  # no velocity: the prior cannot predict
    R = model.gyro_rotation(T0_NS + 10**9)
    assert rotation_angle_deg(_pose(12.0)[:3, :3].T @ R) < 1e-4  # arccos near 0
    assert model.gyro_rotation(T0_NS + 3 * 10**9) is None  # past the last sample
    model.cfg.source = 'wheel'
    assert model.gyro_rotation(T0_NS + 10**9) is None


def _second_scan_with_an_imu_only(
    gyro_offset_deg: float = 0.0,
    min_weak_support: float | None = None,
    refine_first_keyframe: bool = False,
) -> tuple[object, np.ndarray]:
    # Dev pair 000007 as fuzz-node's IMU cases: the keyframe at t0, the moved scan at t2.
    # The pair onto the first keyframe refines itself by default since session 14, and
    # stage 9 then accepts this scan on its own evidence; the rescue is tested without that.
    from mlsemreg_ros.datasets.pairs import load_pair
    from mlsemreg_ros.evaluation.hostile_cases import good_streams, Timeline

    pair = load_pair(DEV_PAIRS / '000007.npz')
    overrides: dict[str, object] = {
        'keypoints.count': 2000,
        'odometry.refine_first_keyframe': refine_first_keyframe,
    }
    if min_weak_support is not None:
        overrides['near_miss.min_weak_support'] = min_weak_support
    odometry = Odometry(Registration(RegistrationConfig().replace(overrides)))
    timeline = Timeline(1000.0, 1.0)
    imu = good_streams(pair.trans_gt, timeline)['imu']
    stamps = np.array([round(t * 1e9) for t, _ in imu], dtype=np.int64)
    gyro = np.stack([f['gyro'] for _, f in imu])
    gyro[gyro[:, 2] != 0.0, 2] += np.radians(gyro_offset_deg)  # over the 1 s of motion
    odometry.motion_model.add_imu(stamps, gyro, np.tile([0.0, 0.0, 9.81], (len(stamps), 1)))
    t0, _, t2 = timeline.scans
    odometry.process(pair.pts_dst, pair.label_dst, round(t0 * 1e9))
    step = odometry.process(pair.pts_src, pair.label_src, round(t2 * 1e9))
    return step, pair.trans_gt


@pytest.mark.skipif(not DEV_PAIRS.is_dir(), reason=f'no dev pairs at {DEV_PAIRS}')
def test_the_gyro_confirms_the_refused_second_scan_of_pair_000007() -> None:
    step, truth = _second_scan_with_an_imu_only()
    assert step.accepted and 'confirmed by the gyro' in step.reason
    error = invert_transform(truth) @ step.pose
    assert np.linalg.norm(error[:3, 3]) < 0.6 and rotation_angle_deg(error) < 5.0


@pytest.mark.skipif(not DEV_PAIRS.is_dir(), reason=f'no dev pairs at {DEV_PAIRS}')
def test_the_first_keyframe_s_refined_pair_registers_000007_without_the_gyro() -> None:
    step, truth = _second_scan_with_an_imu_only(gyro_offset_deg=5.0, refine_first_keyframe=True)
    assert step.accepted and 'confirmed by the gyro' not in step.reason
    error = invert_transform(truth) @ step.pose
    assert np.linalg.norm(error[:3, 3]) < 0.6 and rotation_angle_deg(error) < 5.0


@pytest.mark.skipif(not DEV_PAIRS.is_dir(), reason=f'no dev pairs at {DEV_PAIRS}')
def test_a_gyro_that_disagrees_confirms_nothing() -> None:
    step, _ = _second_scan_with_an_imu_only(gyro_offset_deg=5.0)
    assert not step.accepted and 'confirmed by the gyro' not in step.reason


@pytest.mark.skipif(not DEV_PAIRS.is_dir(), reason=f'no dev pairs at {DEV_PAIRS}')
def test_the_gyro_confirms_no_pose_whose_weakest_direction_is_not_held() -> None:
    # the gyro pins no translation: a rescued pose must hold its weakest direction as an
    # own-evidence acceptance of the second look must (near_miss.min_weak_support)
    step, _ = _second_scan_with_an_imu_only(min_weak_support=10000.0)
    assert 'confirmed by the gyro' not in step.reason
