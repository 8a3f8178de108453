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

"""ML-SemReg registration of semantically labeled LiDAR scans, with a ROS 2 node."""

from importlib import metadata
from pathlib import Path
import re


def _package_xml_version() -> str:
    """Return the ``<version>`` of the source tree's package.xml (never-installed checkout)."""
    text = (Path(__file__).resolve().parents[1] / 'package.xml').read_text()
    match = re.search(r'<version>([^<]+)</version>', text)
    return match.group(1).strip() if match else '0+unknown'


try:  # the one version source is package.xml; setup.py copies it into the metadata
    __version__ = metadata.version('mlsemreg_ros')
except metadata.PackageNotFoundError:
    __version__ = _package_xml_version()
