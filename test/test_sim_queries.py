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

"""``simulation/revisit_queries.py``: the queries of ``mlsemreg map sim-queries``, from Python."""

from pathlib import Path

from mlsemreg_ros.datasets.query_files import write_query
from mlsemreg_ros.simulation.revisit_queries import SimQueries, write_sim_queries
import numpy as np


def test_write_query_round_trip(tmp_path: Path) -> None:
    """A query file holds the scan as float32, labels as uint32 and the pose as float64."""
    points = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    pose = np.eye(4)
    pose[:3, 3] = [1.5, -2.0, 0.25]
    write_query(tmp_path / 'q.npz', points, np.array([3, 7]), pose, 42)
    write_query(tmp_path / 'none.npz', points, np.array([3, 7]), None, 0, 'float64')
    data = np.load(tmp_path / 'q.npz')
    assert data['points'].dtype == np.float32 and data['labels'].dtype == np.uint32
    np.testing.assert_array_equal(data['T_map_scan'], pose)
    assert int(data['stamp_ns']) == 42
    unposed = np.load(tmp_path / 'none.npz')
    assert 'T_map_scan' not in unposed and unposed['points'].dtype == np.float64


def test_reverse_drive_queries_every_kth_scan(tmp_path: Path) -> None:
    """The reverse drive writes every K-th scan with its ground-truth pose in the map frame."""
    said = write_sim_queries(tmp_path / 'q', SimQueries(frames=20, every=5))
    files = sorted((tmp_path / 'q').glob('*.npz'))
    assert said == f'wrote {len(files)} queries (reverse drive) to {tmp_path / "q"}'
    assert [int(f.stem) for f in files] == list(range(0, 5 * len(files), 5))
    assert len(files) >= 3
    for file in files:
        data = np.load(file)
        assert data['points'].shape[1] == 3 and len(data['points']) == len(data['labels'])
        rotation = data['T_map_scan'][:3, :3]
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-9)
