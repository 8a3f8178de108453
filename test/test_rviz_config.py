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

"""config/mlsemreg.rviz parses and shows the node's outputs (no rviz2 wheel: not loaded)."""

from __future__ import annotations

from pathlib import Path

import yaml

RVIZ = Path(__file__).resolve().parents[1] / 'config' / 'mlsemreg.rviz'

EXPECTED = {  # display name: (class, topic)
    'TF': ('rviz_default_plugins/TF', None),
    'Cloud (registered)': ('rviz_default_plugins/PointCloud2', '/mlsemreg/cloud_registered'),
    'Local map': ('rviz_default_plugins/PointCloud2', '/mlsemreg/local_map'),
    'Map': ('rviz_default_plugins/PointCloud2', '/mlsemreg/map'),
    'Path': ('rviz_default_plugins/Path', '/mlsemreg/path'),
    'Correspondences': ('rviz_default_plugins/MarkerArray', '/mlsemreg/correspondences'),
}


def test_the_rviz_config_names_the_displays_of_the_outputs() -> None:
    config = yaml.safe_load(RVIZ.read_text())
    manager = config['Visualization Manager']
    displays = {d['Name']: d for d in manager['Displays']}
    for name, (cls, topic) in EXPECTED.items():
        assert name in displays, f'no {name!r} display'
        assert displays[name]['Class'] == cls
        if topic is not None:
            assert displays[name]['Topic']['Value'] == topic
    # the map is latched (transient local): RViz must ask for it that way to get it late
    assert displays['Map']['Topic']['Durability Policy'] == 'Transient Local'
    assert manager['Global Options']['Fixed Frame'] == 'odom'
    tools = {t['Class']: t for t in manager['Tools']}
    assert tools['rviz_default_plugins/SetInitialPose']['Topic']['Value'] == '/initialpose'
