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
"""Short simulated bags for the end-to-end tests (``mlsemreg simulate``)."""

from __future__ import annotations

from pathlib import Path


def simulated_bag(out: Path, frames: int, seed: int) -> Path:
    """Simulate ``frames`` scans of ``seed`` into ``out`` (1024 columns keep it fast)."""
    from mlsemreg_ros.tools import simulate

    args = [str(out), '--frames', str(frames), '--seed', str(seed)]
    assert simulate.main([*args, '--azimuth-steps', '1024', '--quiet']) == 0
    return out
