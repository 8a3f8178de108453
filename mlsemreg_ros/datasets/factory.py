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
Open a labeled scan sequence from a path: the one factory of the scan readers.

:func:`open_scan_source` picks the reader from the path (a rosbag2 directory or
``.mcap``/``.db3`` file, or a folder with ``velodyne/``) and imports it lazily, so the
optional dependencies of a reader are needed only when it is used.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mlsemreg_ros.datasets.source import ScanSource, SourceError


def is_kitti_sequence(path: Path) -> bool:
    """Tell whether ``path`` is a folder with ``velodyne/*.bin`` (SemanticKITTI layout)."""
    return path.is_dir() and (path / 'velodyne').is_dir()


def is_rosbag2(path: Path) -> bool:
    """Tell whether ``path`` is a rosbag2 directory or one .mcap/.db3 file."""
    if path.is_file():
        return path.suffix in ('.mcap', '.db3')
    return path.is_dir() and (
        (path / 'metadata.yaml').exists() or any(path.glob('*.mcap')) or any(path.glob('*.db3'))
    )


def open_scan_source(path: str | Path, **kwargs: Any) -> ScanSource:
    """
    Open a bag or a SemanticKITTI sequence folder; keyword arguments go to the reader.

    Bags: ``points_topic``, ``gt_topic``, ``label_field``, ``require_labels``.
    KITTI folders: ``poses``, ``calib``, ``times``, ``start_time_ns``.
    """
    path = Path(path)
    if not path.exists():
        raise SourceError(f'{path} does not exist')
    if is_kitti_sequence(path):
        from mlsemreg_ros.datasets.kitti import KittiSequence

        return KittiSequence(path, **kwargs)
    if is_rosbag2(path):
        from mlsemreg_ros.datasets.bag import BagScanReader

        return BagScanReader(path, **kwargs)
    raise SourceError(
        f'{path} is neither a rosbag2 (directory with metadata.yaml, .mcap or '
        f'.db3) nor a SemanticKITTI sequence folder (with velodyne/)'
    )
