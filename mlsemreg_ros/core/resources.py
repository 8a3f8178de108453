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

"""Locate the package's data files (``config/``) in a source tree or an install."""

from __future__ import annotations

from pathlib import Path

PACKAGE = 'mlsemreg_ros'


def share_file(relative: str) -> Path:
    """
    Find a data file of the package, e.g. ``config/params.yaml``.

    Looks in the source checkout first (editable installs, tests), then in
    ``<prefix>/share/mlsemreg_ros/`` of every prefix above this module (pip and
    colcon installs put data files there).
    """
    here = Path(__file__).resolve()
    source = here.parents[2] / relative
    if source.exists():
        return source
    for prefix in here.parents:
        candidate = prefix / 'share' / PACKAGE / relative
        if candidate.exists():
            return candidate
    raise FileNotFoundError(f'{relative} not found in the source tree or any share/{PACKAGE}')
