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

"""config/params.yaml, the node's declared parameters and the core's defaults agree."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from mlsemreg_ros.core.config import ConfigError, NODE_NAME, RegistrationConfig, split_params_yaml
from mlsemreg_ros.evaluation.settings import EvaluationSettings
from mlsemreg_ros.parameter_docs import parameter_table_markdown, parameters_page, params_yaml_text
from mlsemreg_ros.ros.node_config import all_parameter_fields, NodeConfig
import pytest
from ros_domains import domain_id
import yaml

ROOT = Path(__file__).resolve().parents[1]
PARAMS = ROOT / 'config' / 'params.yaml'
PARAMETERS_PAGE = ROOT / 'docs' / 'parameters.md'
REGENERATE = 'regenerate config/params.yaml and docs/parameters.md with: mlsemreg params'
DOMAIN_ID = domain_id('params_yaml')


def _flatten(prefix: str, value: Any, out: dict[str, Any]) -> dict[str, Any]:
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(f'{prefix}.{k}' if prefix else k, v, out)
    else:
        out[prefix] = value
    return out


def _expected() -> dict[str, Any]:
    return {name: default for name, _, default in all_parameter_fields()}


def _assert_same(actual: dict[str, Any], where: str) -> None:
    expected = _expected()
    assert sorted(actual) == sorted(expected), (
        f'{where}: missing {sorted(set(expected) - set(actual))}, '
        f'extra {sorted(set(actual) - set(expected))}; {REGENERATE}'
    )
    for key, default in expected.items():
        assert actual[key] == default and type(actual[key]) is type(default), (
            f'{where}: {key} = {actual[key]!r}, default {default!r}; {REGENERATE}'
        )


def test_params_yaml_holds_every_default_key_for_key() -> None:
    data = yaml.safe_load(PARAMS.read_text())
    assert list(data) == [NODE_NAME] and list(data[NODE_NAME]) == ['ros__parameters']
    _assert_same(_flatten('', data[NODE_NAME]['ros__parameters'], {}), str(PARAMS))


def test_generated_text_matches_the_file() -> None:
    assert yaml.safe_load(params_yaml_text()) == yaml.safe_load(PARAMS.read_text()), REGENERATE


def test_params_yaml_is_the_generated_text_comments_included() -> None:
    """A changed description, range or unit in the metadata must reach the file's comments."""
    assert PARAMS.read_text() == params_yaml_text(), REGENERATE


def test_parameters_page_is_the_generated_text() -> None:
    text = PARAMETERS_PAGE.read_text()
    assert text == parameters_page(), REGENERATE
    for name, _, _ in all_parameter_fields() + EvaluationSettings.parameter_fields():
        assert f'| `{name}` |' in text, name


def test_parameters_page_follows_a_changed_description(monkeypatch: pytest.MonkeyPatch) -> None:
    """The page is rendered from the metadata, not kept by hand."""
    import mlsemreg_ros.parameter_docs as docs

    name, f, default = all_parameter_fields()[0]
    changed = dataclasses.field(metadata={**f.metadata, 'description': 'a changed description'})
    monkeypatch.setattr(docs, 'all_parameter_fields', lambda: [(name, changed, default)])
    assert 'a changed description' in docs.parameters_page()


def test_core_loader_reads_params_yaml() -> None:
    assert RegistrationConfig.from_yaml(PARAMS) == RegistrationConfig()
    _, node_level = split_params_yaml(PARAMS)
    assert node_level == NodeConfig().to_flat_dict()


def test_node_config_validation() -> None:
    cfg = NodeConfig().replace({'qos.reliability': 'reliable', 'local_map_period': 2})
    assert cfg.qos.reliability == 'reliable' and cfg.local_map_period == 2.0
    for change, reason in [
        ({'qos.reliability': 'never'}, 'is not one of'),
        ({'local_map_period': -1.0}, 'below its minimum 0'),
        ({'qos.depth': 0}, 'below its minimum 1'),
        ({'odom_frame': ''}, 'odom_frame must not be empty'),
        ({'base_frame': 'odom'}, 'both'),
        ({'publish_tf': 'yes'}, 'expects bool'),
        ({'qos.bogus': 1}, 'unknown parameter'),
        ({'keyframe.policy': 'distance'}, 'unknown parameter'),
    ]:
        with pytest.raises(ConfigError, match=reason):
            NodeConfig().replace(change)


def test_parameter_table_lists_every_parameter() -> None:
    table = parameter_table_markdown()
    for name in _expected():
        assert f'| `{name}` |' in table


@pytest.fixture(scope='module')
def declared(ros_context: Any) -> Any:
    """Collect declared parameters and descriptors (node with and without params.yaml)."""
    from mlsemreg_ros.ros.node import MlSemRegNode

    out = {}
    with_file = ['--ros-args', '--params-file', str(PARAMS)]
    for label, args in (('defaults', None), ('params.yaml', with_file)):
        with ros_context(DOMAIN_ID, args) as context:
            node = MlSemRegNode(context=context)
            names = [name for name, _, _ in all_parameter_fields()]
            out[label] = (
                {p.name: p.value for p in node.get_parameters(names)},
                dict(zip(names, node.describe_parameters(names), strict=True)),
            )
            node.destroy_node()
    return out


@pytest.mark.parametrize('label', ['defaults', 'params.yaml'])
def test_node_declares_the_core_defaults(declared: Any, label: str) -> None:
    values, _ = declared[label]
    _assert_same(values, f'node declared ({label})')


def test_descriptors_carry_description_unit_range_and_choices(declared: Any) -> None:
    _, descriptors = declared['defaults']
    for name, f, _ in all_parameter_fields():
        meta, d = f.metadata, descriptors[name]
        assert d.description.startswith(meta['description'])
        if meta['unit']:
            assert d.description.endswith(f'[{meta["unit"]}]')
        if meta['choices']:
            assert 'one of: ' + ', '.join(meta['choices']) in d.additional_constraints
        if meta['low'] is not None:
            ranges = d.floating_point_range or d.integer_range
            assert len(ranges) == 1, name
            assert (ranges[0].from_value, ranges[0].to_value) == (meta['low'], meta['high'])
    assert descriptors['qos.depth'].read_only and not descriptors['keypoints.count'].read_only
    assert (
        'class names: unlabeled, car'
        in descriptors['semantic.landmark_classes'].additional_constraints
    )
