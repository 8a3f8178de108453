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
"""The single configuration object: defaults, validation, loading."""

from mlsemreg_ros.core.config import ConfigError, iter_fields, RegistrationConfig
from mlsemreg_ros.core.pipeline import Registration
import pytest
import yaml


def test_defaults_are_the_papers_kitti_settings():
    config = RegistrationConfig()
    assert config.semantic.local_radius == 0.8
    assert config.semantic.ring_count == 33 and config.semantic.ring_width == 1.5
    assert config.semantic.top_k == 2
    assert config.semantic.landmark_classes == ['trunk', 'truck', 'pole', 'traffic-sign', 'car']
    assert config.estimator.inlier_threshold == 0.6


def test_every_field_has_a_description_and_flat_names_round_trip():
    for key, field, _ in iter_fields():
        assert field.metadata['description'], key
    config = RegistrationConfig()
    assert RegistrationConfig().replace(config.to_flat_dict()) == config
    assert RegistrationConfig.from_dict(config.to_dict()) == config


def test_unknown_keys_wrong_types_and_ranges_are_rejected():
    with pytest.raises(ConfigError, match='unknown config section'):
        RegistrationConfig.from_dict({'semantics': {}})
    with pytest.raises(ConfigError, match='unknown parameter'):
        RegistrationConfig().replace({'semantic.radius': 1.0})
    with pytest.raises(ConfigError, match='expects int'):
        RegistrationConfig().replace({'semantic.top_k': 2.5})
    with pytest.raises(ConfigError, match='below its minimum'):
        RegistrationConfig().replace({'semantic.local_radius': -1.0})
    with pytest.raises(ConfigError, match='not one of'):
        RegistrationConfig().replace({'matcher.kind': 'ot'})


def test_cross_field_validation():
    with pytest.raises(ConfigError, match='receptive-field'):
        RegistrationConfig().replace({'semantic.ring_count': 256, 'semantic.ring_width': 5.0})
    with pytest.raises(ConfigError, match='k2'):
        RegistrationConfig().replace({'estimator.k1': 10, 'estimator.k2': 20})


def test_unknown_class_names_are_rejected_by_the_pipeline():
    config = RegistrationConfig().replace({'semantic.landmark_classes': ['pole', 'lamp']})
    with pytest.raises(ConfigError, match='lamp'):
        Registration(config)


def test_ints_are_accepted_for_floats_and_yaml_loading(tmp_path):
    config = RegistrationConfig().replace({'semantic.ring_width': 2})
    assert config.semantic.ring_width == 2.0 and isinstance(config.semantic.ring_width, float)
    path = tmp_path / 'params.yaml'
    path.write_text(
        yaml.safe_dump(
            {'mlsemreg_node': {'ros__parameters': {'semantic': {'top_k': 3}, 'odom_frame': 'map'}}}
        )
    )
    assert RegistrationConfig.from_yaml(path).semantic.top_k == 3
    path.write_text(yaml.safe_dump({'semantic': {'top_kk': 3}}))
    with pytest.raises(ConfigError):
        RegistrationConfig.from_yaml(path)


def test_removed_parameters_say_what_replaced_them():
    with pytest.raises(ConfigError, match=r'was removed: replaced by fine\.method'):
        RegistrationConfig().replace({'refine.icp': True})
    with pytest.raises(ConfigError, match='unknown parameter'):
        RegistrationConfig().replace({'refine.bogus': True})


def test_top_level_fields_sections_and_one_loader(tmp_path):
    from mlsemreg_ros.core.config import load_config, parse_overrides

    config = RegistrationConfig.from_dict({'threads': 1, 'fine': {'method': 'gicp'}})
    assert config.threads == 1 and config.fine.method == 'gicp'
    assert config.to_flat_dict()['threads'] == 1 and 'keyframe.policy' in config.to_flat_dict()
    with pytest.raises(ConfigError, match='must be a mapping'):
        RegistrationConfig.from_dict({'fine': 3})
    with pytest.raises(ConfigError, match='unknown config section'):
        RegistrationConfig.from_dict({'threads': {'count': 2}})
    assert parse_overrides(
        ['semantic.enabled=false', 'semantic.landmark_classes=[pole, car]', 'odom_frame=']
    ) == {
        'semantic.enabled': False,
        'semantic.landmark_classes': ['pole', 'car'],
        'odom_frame': '',
    }
    for bad in ('semantic.enabled', '=3', 'a=[1,'):
        with pytest.raises(ConfigError):
            parse_overrides([bad])
    path = tmp_path / 'params.yaml'
    path.write_text(
        yaml.safe_dump(
            {
                'mlsemreg_node': {
                    'ros__parameters': {
                        'threads': 2,
                        'keyframe': {'policy': 'distance'},
                        'odom_frame': 'map',
                    }
                }
            }
        )
    )
    loaded = load_config(path, ['keyframe.min_distance=3', 'fine.method=off'])
    assert (
        loaded.threads,
        loaded.keyframe.policy,
        loaded.keyframe.min_distance,
        loaded.fine.method,
    ) == (2, 'distance', 3.0, 'off')
    with pytest.raises(ConfigError, match='unknown parameter'):
        load_config(path, ['odom_frame=map'])  # a node setting is not a core one
    with pytest.raises(ConfigError, match='must be finite'):
        RegistrationConfig().replace({'fine.voxel_size': float('nan')})


def test_yaml_words_that_yaml_1_1_reads_as_booleans_stay_strings():
    from mlsemreg_ros.core.config import load_yaml, parse_overrides

    assert parse_overrides(['fine.method=off'])['fine.method'] == 'off'
    assert load_yaml('a: off\nb: yes\nc: true\nd: False\n') == {
        'a': 'off',
        'b': 'yes',
        'c': True,
        'd': False,
    }


def test_one_apply_overrides_routes_every_key_to_the_settings_that_declare_it(tmp_path):
    from mlsemreg_ros.core.config import apply_overrides, load_settings
    from mlsemreg_ros.evaluation.settings import EvaluationSettings
    from mlsemreg_ros.ros.node_config import NodeConfig

    core, node, evaluation = apply_overrides(
        (RegistrationConfig(), NodeConfig(), EvaluationSettings()),
        ['semantic.top_k=3', 'qos.depth=7', 'evaluation.max_rotation_deg=15', 'threads=1'],
    )
    assert (core.semantic.top_k, core.threads, node.qos.depth) == (3, 1, 7)
    assert evaluation.evaluation.max_rotation_deg == 15.0
    assert apply_overrides(RegistrationConfig(), []) == RegistrationConfig()
    for bad, reason in (
        (['evaluation.nope=1'], 'unknown parameter'),
        (['refine.icp=true'], 'was removed'),
        (['evaluation.max_translation_m=-1'], 'below its minimum'),
        (['qos.depth'], 'KEY=VALUE'),
    ):
        with pytest.raises(ConfigError, match=reason):
            apply_overrides((RegistrationConfig(), NodeConfig(), EvaluationSettings()), bad)
    path = tmp_path / 'params.yaml'
    path.write_text(
        yaml.safe_dump(
            {
                'mlsemreg_node': {
                    'ros__parameters': {
                        'semantic': {'top_k': 4},
                        'odom_frame': 'map',
                        'use_sim_time': True,
                        'evaluation': {'max_translation_m': 0.3},
                    }
                }
            }
        )
    )
    core, evaluation = load_settings(
        (RegistrationConfig, EvaluationSettings), path, ['evaluation.max_rotation_deg=15']
    )
    assert core.semantic.top_k == 4
    assert (evaluation.evaluation.max_rotation_deg, evaluation.evaluation.max_translation_m) == (
        15.0,
        0.3,
    )


def test_the_success_test_is_inclusive_and_nan_fails():
    from mlsemreg_ros.evaluation.settings import EvaluationConfig

    bounds = EvaluationConfig()
    assert bounds.succeeded(5.0, 0.6) and not bounds.succeeded(5.0001, 0.1)
    assert not bounds.succeeded(float('nan'), 0.1) and not bounds.succeeded(1.0, float('inf'))
