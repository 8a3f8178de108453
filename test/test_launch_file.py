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
launch/mlsemreg.launch.py evaluated: which processes and parameters each set of arguments starts.

ROS 2's launch has no PyPI wheel (test/launch_standin.py says why), so the file's
``generate_launch_description`` runs against a stand-in of the launch API that evaluates
its substitutions and conditions as ``ros2 launch`` does. Each started process is then
checked against the package: the executables are its entry points, the parameter files and
the RViz config exist, every parameter is one the node declares, and the player's command
line parses with ``mlsemreg-play``'s own options.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
import re

import launch_standin
import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
LAUNCH_FILE = REPO / 'launch' / 'mlsemreg.launch.py'
SHARES = {'mlsemreg_ros': str(REPO)}  # the installed share folder holds config/ like the repo


def _description(monkeypatch):
    launch_standin.install(monkeypatch)
    spec = importlib.util.spec_from_file_location('mlsemreg_launch', LAUNCH_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.generate_launch_description()


def _start(monkeypatch, environment: dict[str, str] | None = None, **arguments: str):
    context = launch_standin.Context(arguments, environment or {}, SHARES)
    return launch_standin.evaluate(_description(monkeypatch), context)


def _node_parameters(node: dict) -> dict:
    """Return the node's parameters as the launch hands them: the files' values, then the dicts."""
    merged = {}
    for item in node['parameters']:
        if isinstance(item, str):
            merged.update(_flatten(yaml.safe_load(Path(item).read_text())['mlsemreg_node']))
        else:
            merged.update(item)
    return merged


def _flatten(tree: dict, prefix: str = '') -> dict:
    if set(tree) == {'ros__parameters'}:
        return _flatten(tree['ros__parameters'])
    out = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f'{prefix}{key}.'))
        else:
            out[f'{prefix}{key}'] = value
    return out


def _entry_points() -> set[str]:
    return set(re.findall(r"'([\w-]+) = mlsemreg_ros\.", (REPO / 'setup.py').read_text()))


def test_defaults_start_the_node_alone_on_wall_time(monkeypatch) -> None:
    started = _start(monkeypatch)
    assert set(started.nodes) == {'mlsemreg_node'}
    assert started.processes == []
    node = started.nodes['mlsemreg_node']
    assert node['package'] == 'mlsemreg_ros'
    assert node['executable'] in _entry_points()
    assert node['remappings'] == [('points', 'points')]
    parameters = _node_parameters(node)
    assert parameters['use_sim_time'] is False
    assert parameters['map.load_path'] == ''  # mapping, not localization
    # the shipped parameter file: every key is a parameter the node declares
    declared = _flatten(yaml.safe_load((REPO / 'config' / 'params.yaml').read_text()))
    assert set(parameters) - {'use_sim_time'} <= set(declared)
    profile = started.environment['FASTRTPS_DEFAULT_PROFILES_FILE']
    assert Path(profile) == REPO / 'config' / 'fastdds.xml' and Path(profile).is_file()
    assert started.environment['FASTDDS_DEFAULT_PROFILES_FILE'] == profile


def test_bag_plays_with_the_packages_player_on_sim_time(monkeypatch, tmp_path: Path) -> None:
    bag = tmp_path / 'drive'
    bag.mkdir()
    started = _start(monkeypatch, bag=str(bag), points_topic='/velodyne_points_labeled')
    assert len(started.processes) == 1
    command = started.processes[0]
    assert command[0] in _entry_points() and command[0] == 'mlsemreg-play'
    # the command line parses with the player's own options: the bag, /clock, the wait
    from mlsemreg_ros.tools.common import single_command_app
    from mlsemreg_ros.tools.play import HELP, play

    parsed = single_command_app(play, HELP).make_context(command[0], command[1:]).params
    assert Path(parsed['bag']) == bag
    assert parsed['clock'] is True
    assert parsed['wait_for_subscribers'] == 1
    node = started.nodes['mlsemreg_node']
    assert node['remappings'] == [('points', '/velodyne_points_labeled')]
    assert _node_parameters(node)['use_sim_time'] is True  # whatever use_sim_time says


def test_use_sim_time_without_a_bag(monkeypatch) -> None:
    for value, expected in (('true', True), ('True', True), ('false', False)):
        started = _start(monkeypatch, use_sim_time=value)
        assert _node_parameters(started.nodes['mlsemreg_node'])['use_sim_time'] is expected
        assert started.processes == []


def test_map_loads_a_map_folder_for_localization(monkeypatch, tmp_path: Path) -> None:
    started = _start(monkeypatch, map=str(tmp_path / 'map'))
    assert _node_parameters(started.nodes['mlsemreg_node'])['map.load_path'] == str(
        tmp_path / 'map'
    )


def test_rviz_opens_the_packages_config_on_the_same_clock(monkeypatch, tmp_path: Path) -> None:
    started = _start(monkeypatch, rviz='true', bag=str(tmp_path))
    rviz = started.nodes['rviz2']
    assert (rviz['package'], rviz['executable']) == ('rviz2', 'rviz2')
    assert rviz['arguments'][0] == '-d'
    config = Path(rviz['arguments'][1])
    assert config == REPO / 'config' / 'mlsemreg.rviz' and config.is_file()
    assert yaml.safe_load(config.read_text())['Visualization Manager']['Displays']
    assert rviz['parameters'] == [{'use_sim_time': True}]
    assert 'rviz2' not in _start(monkeypatch, rviz='false').nodes


def test_params_file_and_fastdds_profile_can_be_replaced(monkeypatch, tmp_path: Path) -> None:
    params = tmp_path / 'mine.yaml'
    params.write_text('mlsemreg_node:\n  ros__parameters:\n    keypoints:\n      count: 900\n')
    started = _start(
        monkeypatch,
        environment={'FASTRTPS_DEFAULT_PROFILES_FILE': '/etc/profile.xml'},
        params_file=str(params),
    )
    assert _node_parameters(started.nodes['mlsemreg_node'])['keypoints.count'] == 900
    assert started.environment['FASTDDS_DEFAULT_PROFILES_FILE'] == '/etc/profile.xml'


def test_an_argument_the_file_does_not_declare_is_an_error(monkeypatch) -> None:
    with pytest.raises(KeyError, match='not declared'):
        _start(monkeypatch, rviz_config='x.rviz')
    with pytest.raises(ValueError, match='not a boolean'):
        _start(monkeypatch, rviz='maybe')
