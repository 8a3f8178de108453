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
"""Pose files, under their old name: they are read and written by ``codec/pose_files.py``."""

from mlsemreg_ros.codec.pose_files import (  # noqa: F401 (re-exported)
    camera_to_lidar_poses,
    read_kitti_calib,
    read_kitti_poses,
    read_kitti_times,
    read_tum_poses,
    write_kitti_poses,
    write_tum_poses,
)
