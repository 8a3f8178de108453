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
ROS domain ids for the rclpy tests, distinct per test module and per test run.

Two test runs on one machine (two checkouts, a developer and CI) must not see
each other's nodes: the base id comes from the process id (or the environment
variable MLSEMREG_TEST_DOMAIN_BASE), and each module adds its own offset.
"""

import os

MODULES = (
    'node',
    'colcon',
    'params_yaml',
    'demo',
    'play',
    'soak',
    'map_node',
    'node_extrinsic',
    'transport',
    'node_hostile',
    'node_stack',
    'node_pose',
    'lifecycle',
    'point_map_node',
)
#: Test runs whose base ids fit below Fast DDS's largest domain id, 232.
_RUNS = (232 - 100) // len(MODULES)


def domain_id(module: str) -> int:
    """Return the ROS_DOMAIN_ID of a test module (0..232 is valid for Fast DDS)."""
    base = int(
        os.environ.get('MLSEMREG_TEST_DOMAIN_BASE', 100 + (os.getpid() % _RUNS) * len(MODULES))
    )
    return base + MODULES.index(module)
