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
"""The tiny pair folder the ``mlsemreg tune`` tests tune on."""

from pathlib import Path


def write_tiny_pair(folder: Path) -> Path:
    """Write one small generated pair with keypoints and a stand-in 'gedi' descriptor (FPFH)."""
    from mlsemreg_ros.core.features.features import sample_keypoints
    from mlsemreg_ros.core.features.fpfh import fpfh_at_keypoints
    from mlsemreg_ros.datasets.pairs import save_pair
    from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair

    pair = synthetic_pair(0, yaw_deg=6.0, translation=(2.0, 0.5, 0.0), max_points=4000)
    for side in ('src', 'dst'):
        pts = getattr(pair, f'pts_{side}')
        idx = sample_keypoints(pts, 400, 'random', 1.0, 0)
        setattr(pair, f'kpts_{side}', pts[idx])
        getattr(pair, f'descriptors_{side}')['gedi'] = fpfh_at_keypoints(pts, idx, 0.9, 1.5, 0.6)
    save_pair(folder / '000000.npz', pair)
    return folder
