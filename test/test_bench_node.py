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
"""The latency benchmark's accuracy check of published transforms (no ROS needed)."""

from types import SimpleNamespace

from mlsemreg_ros.tools.bench_node import _errors, parameter_overrides
import numpy as np
import pytest
from scipy.spatial.transform import Rotation


def _message(transform: np.ndarray) -> SimpleNamespace:
    x, y, z, w = Rotation.from_matrix(transform[:3, :3]).as_quat()
    tx, ty, tz = transform[:3, 3]
    return SimpleNamespace(transform=SimpleNamespace(
        rotation=SimpleNamespace(x=x, y=y, z=z, w=w),
        translation=SimpleNamespace(x=tx, y=ty, z=tz)))


def test_the_truth_follows_the_keyframe_the_node_reports():
    truth = np.eye(4)
    truth[:3, :3] = Rotation.from_euler('z', 30, degrees=True).as_matrix()
    truth[:3, 3] = (20.0, 1.0, 0.0)
    exact = _errors(_message(truth), truth, current=1, keyframe=0)  # src onto dst
    assert exact['correct'] and exact['rotation_error_deg'] < 1e-6
    assert exact['translation_error_m'] < 1e-9
    inverse = _errors(_message(np.linalg.inv(truth)), truth, current=0, keyframe=1)
    assert inverse['correct'] and inverse['translation_error_m'] < 1e-9
    wrong = _errors(_message(truth), truth, current=0, keyframe=1)  # T where T^-1 was due
    assert not wrong['correct'] and wrong['translation_error_m'] > 10.0
    # after a rejected frame the keyframe stays: dst onto the dst keyframe is the identity
    same = _errors(_message(np.eye(4)), truth, current=0, keyframe=0)
    assert same['correct'] and same['translation_error_m'] < 1e-9
    assert _errors(None, truth, current=1, keyframe=0) == {}


def test_set_overrides_become_ros_parameter_arguments():
    assert parameter_overrides([]) is None
    assert parameter_overrides(['keypoints.count=1500', 'semantic.landmark_classes=[pole]']) == [
        '--ros-args', '-p', 'keypoints.count:=1500', '-p', 'semantic.landmark_classes:=[pole]']
    with pytest.raises(SystemExit):
        parameter_overrides(['keypoints.count'])
