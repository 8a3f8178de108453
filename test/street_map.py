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
"""The synthetic street: its keyframe map (the map-node tests) and a drive down it."""

from pathlib import Path

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.maps.keyframe_store import KeyframeStore
from mlsemreg_ros.core.maps.map_io import save_map
from mlsemreg_ros.datasets.synthetic_scene import motion, scan_at, street_scene
import numpy as np
import pytest

STREET_SEED = 3
#: Keyframe positions along the synthetic street (x, m).
KEYFRAME_X = (-30.0, -15.0, 0.0, 15.0, 30.0)


def street_drive(
    frames: int, start_x: float, step_m: float = 1.5, first_stamp: int = 0
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, int]]:
    """
    Return (points, labels, T_world_sensor, stamp_ns) of a drive down the synthetic street.

    Scan ``k`` stands at x = ``start_x + step_m k``, weaving 0.2 m and turning 0.4 deg a
    scan, stamped ``(first_stamp + k)`` tenths of a second.
    """
    world, labels = street_scene(seed=STREET_SEED)
    out = []
    for k in range(frames):
        pose = motion(0.4 * k, (start_x + step_m * k, 0.2 * np.sin(k), 0.0))
        points, scan_labels = scan_at(world, labels, pose, seed=100 + k, max_points=20000)
        out.append((points, scan_labels, pose, 100_000_000 * (first_stamp + k)))
    return out


def street_keyframe_store(
    config: RegistrationConfig | None = None, stamp_step_ns: int = 1_000_000_000
) -> KeyframeStore:
    """Return a store with keyframes along the synthetic street (learning ids), k * step ns."""
    store = KeyframeStore(config or RegistrationConfig())
    world, labels = street_scene(seed=STREET_SEED)
    for k, x in enumerate(KEYFRAME_X):
        pose = motion(5.0 * k, (x, 0.3 * k, 0.0))
        points, scan_labels = scan_at(world, labels, pose, seed=200 + k, max_points=15000)
        store.add(points, scan_labels, pose, stamp_step_ns * k)
    return store


def write_street_map(folder: Path) -> Path:
    """Write a map of the synthetic street to ``folder``: five keyframes 15 m apart."""
    return save_map(folder, street_keyframe_store(stamp_step_ns=1), 'map')


@pytest.fixture(scope='module', name='map_folder')
def street_map_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Write a map of the synthetic street: five keyframes 15 m apart (fixture ``map_folder``)."""
    return write_street_map(tmp_path_factory.mktemp('maps') / 'street')
