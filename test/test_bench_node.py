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

from mlsemreg_ros.core.config import ConfigError, load_settings, RegistrationConfig
from mlsemreg_ros.evaluation.node_latency import transform_errors as _errors
from mlsemreg_ros.evaluation.settings import EvaluationConfig
from mlsemreg_ros.ros.node_config import NodeConfig
from mlsemreg_ros.ros.node_process import write_params_file
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
import yaml


def _message(transform: np.ndarray) -> SimpleNamespace:
    x, y, z, w = Rotation.from_matrix(transform[:3, :3]).as_quat()
    tx, ty, tz = transform[:3, 3]
    return SimpleNamespace(
        transform=SimpleNamespace(
            rotation=SimpleNamespace(x=x, y=y, z=z, w=w),
            translation=SimpleNamespace(x=tx, y=ty, z=tz),
        )
    )


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


def test_the_success_bounds_are_inclusive_and_settable():
    truth = np.eye(4)
    at_bound = truth.copy()
    at_bound[0, 3] = 0.6  # TE exactly 0.6 m: a success (RE <= 5 deg and TE <= 0.6 m)
    assert _errors(_message(at_bound), truth, current=1, keyframe=0)['correct']
    strict = EvaluationConfig(max_translation_m=0.5)
    assert not _errors(_message(at_bound), truth, current=1, keyframe=0, bounds=strict)['correct']


def test_set_overrides_reach_the_node_as_a_validated_parameter_file(tmp_path):
    core, node = load_settings(
        (RegistrationConfig, NodeConfig),
        None,
        [
            'keypoints.count=1500',
            'semantic.landmark_classes=[pole]',
            'fine.method=off',
            'qos.depth=7',
        ],
    )
    path = write_params_file(tmp_path / 'params.yaml', core, node)
    params = yaml.safe_load(path.read_text())['mlsemreg_node']['ros__parameters']  # YAML 1.1
    assert params['keypoints']['count'] == 1500 and params['qos']['depth'] == 7
    assert params['semantic']['landmark_classes'] == ['pole']
    assert params['fine']['method'] == 'off'  # a string, not the boolean of YAML 1.1
    assert load_settings((RegistrationConfig, NodeConfig), path) == (core, node)
    for bad in (['keypoints.count'], ['keypoints.count=many'], ['keypoints.bogus=1']):
        with pytest.raises(ConfigError):
            load_settings((RegistrationConfig, NodeConfig), None, bad)
