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
Launch mlsemreg_node on a labeled PointCloud2 topic.

``ros2 launch mlsemreg_ros mlsemreg.launch.py points_topic:=/velodyne_points_labeled
params_file:=/path/params.yaml use_sim_time:=true``

``rviz:=true`` opens RViz with ``config/mlsemreg.rviz``; ``bag:=PATH`` plays a rosbag2
with the package's player (``mlsemreg-play --clock``, waiting for the node) and runs
everything on sim time; ``map:=PATH`` loads a saved map (``map.load_path``: localization
mode).

The node runs with the package's Fast DDS profile (``config/fastdds.xml``: a shared-memory
segment that holds a 128-beam scan), unless ``FASTRTPS_DEFAULT_PROFILES_FILE`` names
another or ``fastdds_profile:=`` does. The publisher of the clouds needs the same profile
(``docs/field_moving.md``).
"""

from launch.actions import DeclareLaunchArgument, ExecuteProcess, SetEnvironmentVariable
from launch.conditions import IfCondition
from launch.launch_description import LaunchDescription
from launch.substitutions import (
    EnvironmentVariable,
    LaunchConfiguration,
    PathJoinSubstitution,
    PythonExpression,
)
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare


def generate_launch_description() -> LaunchDescription:
    """Node with the package's params.yaml (or another file) and the input topic remapped."""
    default_params = PathJoinSubstitution(
        [FindPackageShare('mlsemreg_ros'), 'config', 'params.yaml']
    )
    shipped_profile = PathJoinSubstitution(
        [FindPackageShare('mlsemreg_ros'), 'config', 'fastdds.xml']
    )
    profile = LaunchConfiguration('fastdds_profile')
    bag = LaunchConfiguration('bag')
    playing = PythonExpression(["'", bag, "' != ''"])
    # a bag runs on its own clock: sim time whatever use_sim_time says
    sim_time = ParameterValue(
        PythonExpression(
            ["'", bag, "' != '' or '", LaunchConfiguration('use_sim_time'), "'.lower() == 'true'"]
        ),
        value_type=bool,
    )
    rviz_config = PathJoinSubstitution(
        [FindPackageShare('mlsemreg_ros'), 'config', 'mlsemreg.rviz']
    )
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                'fastdds_profile',
                default_value=EnvironmentVariable(
                    'FASTRTPS_DEFAULT_PROFILES_FILE', default_value=shipped_profile
                ),
                description='Fast DDS profile XML (large clouds: config/fastdds.xml).',
            ),
            SetEnvironmentVariable('FASTRTPS_DEFAULT_PROFILES_FILE', profile),
            SetEnvironmentVariable('FASTDDS_DEFAULT_PROFILES_FILE', profile),
            DeclareLaunchArgument(
                'points_topic',
                default_value='points',
                description='Labeled sensor_msgs/PointCloud2 input (x, y, z and a label field).',
            ),
            DeclareLaunchArgument(
                'params_file',
                default_value=default_params,
                description='Parameter file (layout of config/params.yaml).',
            ),
            DeclareLaunchArgument(
                'use_sim_time',
                default_value='false',
                description='Use /clock (bag playback with --clock; true whenever bag is set).',
            ),
            DeclareLaunchArgument(
                'rviz', default_value='false', description='Open RViz with config/mlsemreg.rviz.'
            ),
            DeclareLaunchArgument(
                'bag',
                default_value='',
                description='rosbag2 to play with mlsemreg-play --clock (sim time); empty: none.',
            ),
            DeclareLaunchArgument(
                'map',
                default_value='',
                description='Saved map to localize in (map.load_path); empty: map as it goes.',
            ),
            Node(
                package='mlsemreg_ros',
                executable='mlsemreg_node',
                name='mlsemreg_node',
                output='screen',
                parameters=[
                    LaunchConfiguration('params_file'),
                    {'use_sim_time': sim_time, 'map.load_path': LaunchConfiguration('map')},
                ],
                remappings=[('points', LaunchConfiguration('points_topic'))],
            ),
            ExecuteProcess(
                cmd=['mlsemreg-play', bag, '--clock', '--wait-for-subscribers', '1'],
                output='screen',
                condition=IfCondition(playing),
            ),
            Node(
                package='rviz2',
                executable='rviz2',
                name='rviz2',
                arguments=['-d', rviz_config],
                parameters=[{'use_sim_time': sim_time}],
                condition=IfCondition(LaunchConfiguration('rviz')),
            ),
        ]
    )
