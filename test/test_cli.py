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

"""The one ``mlsemreg`` command: subcommands, aliases, --version, validation, error style."""

from __future__ import annotations

from pathlib import Path
import re

from mlsemreg_ros.tools import cli, eval_bag, play
import pytest
import typer

ROOT = Path(__file__).resolve().parents[1]
SUBCOMMANDS = (
    'eval-pairs',
    'eval-bag',
    'bench',
    'bench-node',
    'simulate',
    'kitti-to-bag',
    'play',
    'demo',
    'params',
    'cut-pairs',
    'tune',
)


def test_every_subcommand_has_help_and_an_installed_alias(capsys):
    setup = (ROOT / 'setup.py').read_text()
    assert "'mlsemreg = mlsemreg_ros.tools.cli:main'" in setup
    assert "'mlsemreg_node = mlsemreg_ros.ros.node:main'" in setup
    for name in SUBCOMMANDS:
        assert cli.main([name, '--help']) == 0, name
        module = name.replace('-', '_')
        assert f"'mlsemreg-{name} = mlsemreg_ros.tools.{module}:main'" in setup, name
    assert cli.main(['--help']) == 0
    text = capsys.readouterr().out
    for panel in ('Evaluation', 'Data and playback', 'Maintenance'):
        assert panel in text


def test_version_names_the_package_and_checks_the_heavy_imports(capsys):
    from mlsemreg_ros import __version__

    assert cli.main(['--version']) == 0
    text = capsys.readouterr().out
    assert f'mlsemreg_ros {__version__}' in text
    for module in ('numpy', 'open3d', 'small_gicp', 'rosbags'):
        assert re.search(rf'{module}\s+\d', text), module


def test_one_version_source():
    from mlsemreg_ros import __version__

    package_xml = (ROOT / 'package.xml').read_text()
    assert f'<version>{__version__}</version>' in package_xml
    assert 'version=VERSION' in (ROOT / 'setup.py').read_text()  # read from package.xml


def test_declared_validation_and_one_error_style(tmp_path, capsys):
    assert eval_bag.main([str(tmp_path), '--stride', '0']) == 2
    err = capsys.readouterr().err
    assert err.startswith('mlsemreg-eval-bag: error: ') and '--stride' in err
    assert cli.main(['eval-bag', str(tmp_path / 'missing')]) == 2
    err = capsys.readouterr().err
    assert err.startswith('mlsemreg eval-bag: error: ') and 'does not exist' in err
    assert cli.main(['eval-pairs', str(tmp_path), '--set', 'evaluation.max_rotation_deg=-1']) == 2
    err = capsys.readouterr().err
    assert err.startswith('mlsemreg: error: configuration error: ') and 'below' in err
    broken = tmp_path / 'broken.yaml'
    broken.write_text('fine: {downsampling_resolution: [0.5\n')  # not valid YAML
    assert cli.main(['eval-pairs', str(tmp_path), '--config', str(broken)]) == 2
    err = capsys.readouterr().err
    assert err.startswith('mlsemreg: error: configuration error: ') and 'not valid YAML' in err
    assert cli.main(['eval-pairs', str(tmp_path), '--quiet']) == 1  # empty folder: the work fails
    assert 'no pair files' in capsys.readouterr().err


def test_the_subcommand_and_its_alias_are_the_same_command(tmp_path):
    from mlsemreg_ros.tools import simulate

    options = ['--frames', '1', '--beams', '8', '--azimuth-steps', '64', '--quiet']
    argv = ['simulate', str(tmp_path / 'a'), *options]
    assert cli.main(argv) == 0
    assert cli.main(argv) == 2  # exists, no --force
    assert simulate.main([str(tmp_path / 'b'), *options]) == 0
    same = [(tmp_path / x / 'poses.txt').read_text() for x in ('a', 'b')]
    assert same[0] == same[1]


@pytest.mark.parametrize(
    ('argv', 'expanded'),
    [
        (
            ['bag', '--topics', '/a', '/b', '--loop'],
            ['bag', '--topics', '/a', '--topics', '/b', '--loop'],
        ),
        (['bag', '--topics', '/a'], ['bag', '--topics', '/a']),
        (['bag', '-r', '2'], ['bag', '-r', '2']),
    ],
)
def test_play_keeps_its_several_topics_after_one_flag(argv, expanded):
    assert play.expand_topics(argv) == expanded


def test_cli_choices_and_ranges_come_from_the_config_metadata() -> None:
    """eval-pairs' --matcher/--estimator, bench's --keypoints and eval-bag's --label-field."""
    import typing

    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.ros.node_config import NodeConfig
    from mlsemreg_ros.tools import bench, eval_bag, eval_pairs
    from mlsemreg_ros.tools.common import config_choices

    for alias_type, key in (
        (eval_pairs.MatcherKind, 'matcher.kind'),
        (eval_pairs.EstimatorKind, 'estimator.kind'),
        (config_choices('fine.method'), 'fine.method'),
    ):
        assert typing.get_args(alias_type) == RegistrationConfig.field_of(key).metadata['choices']
    low = RegistrationConfig.field_of('keypoints.count').metadata['low']
    assert bench.keypoint_counts(f'{low},{low + 1}') == (low, low + 1)
    with pytest.raises(typer.BadParameter, match=r'keypoints\.count'):
        bench.keypoint_counts(f'{low - 1}')
    assert eval_bag._LABEL_FIELD.default == NodeConfig().label_field
