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
The Fast DDS profile for large clouds (``config/fastdds.xml``, ``docs/field_moving.md``).

Fast DDS reads its default profile file from the environment when the first participant
of a process is created, so the variables must be set before ``rclpy.init`` and in every
process of the graph, the publisher too. :func:`profile_environment` sets them for a child
process, :func:`use_fastdds_profile` for this one; a profile the user chose is kept.
"""

from __future__ import annotations

from collections.abc import Mapping, MutableMapping
import os
from pathlib import Path

from mlsemreg_ros.core.resources import share_file

#: The shipped profile: 64 MiB shared-memory segment, UDPv4 with 32 MiB socket buffers.
PROFILE = 'config/fastdds.xml'
#: Where Fast DDS 2.x (ROS 2 Jazzy) and 3.x look for their default profile file.
PROFILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')


def fastdds_profile() -> Path:
    """Return the path of the shipped Fast DDS profile (source tree or install)."""
    return share_file(PROFILE)


def profile_environment(env: Mapping[str, str] | None = None) -> dict[str, str]:
    """Return ``env`` (default: this process's) with the profile variables set if unset."""
    out = dict(os.environ if env is None else env)
    chosen = next((out[v] for v in PROFILE_VARIABLES if out.get(v)), None)
    path = chosen or str(fastdds_profile())
    for variable in PROFILE_VARIABLES:
        if not out.get(variable):
            out[variable] = path
    return out


def use_fastdds_profile(env: MutableMapping[str, str] | None = None) -> str:
    """Set the profile variables of this process (before ``rclpy.init``); return the file."""
    target = os.environ if env is None else env
    for variable, value in profile_environment(target).items():
        if variable in PROFILE_VARIABLES:
            target[variable] = value
    return target[PROFILE_VARIABLES[0]]
