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
SemanticKITTI / KITTI odometry sequence folders as a scan source.

Layout (``sequences/XX/``)::

    velodyne/NNNNNN.bin    float32 x, y, z, reflectance per point
    labels/NNNNNN.label    uint32 per point: semantic id | instance id << 16 (optional)
    poses.txt              left-camera poses T_cam0(0)_cam0(k), KITTI format (optional)
    calib.txt              Tr: Velodyne -> cam0 (needed to express poses in the LiDAR frame)
    times.txt              seconds since the first scan (optional; 10 Hz assumed without)

Ground truth is returned in the LiDAR frame: ``Tr^-1 P_k Tr`` (frame 0 = identity).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
import warnings

from mlsemreg_ros.codec.pose_files import (
    camera_to_lidar_poses,
    read_kitti_calib,
    read_kitti_poses,
    read_kitti_times,
)
from mlsemreg_ros.datasets.source import Scan, SourceError
import numpy as np

#: Header stamp of a sequence's time 0 (same default as the simulator): ROS time 0
#: means "unset" to many consumers (TF lookups), so stamps are offset.
START_TIME_NS = 1_700_000_000 * 10**9


class KittiSequence:
    """
    :class:`~mlsemreg_ros.datasets.source.ScanSource` over a SemanticKITTI sequence folder.

    ``poses``, ``calib`` and ``times`` default to the files inside the folder.
    """

    def __init__(
        self,
        path: str | Path,
        poses: str | Path | None = None,
        calib: str | Path | None = None,
        times: str | Path | None = None,
        start_time_ns: int = START_TIME_NS,
        frame_id: str = 'lidar',
    ) -> None:
        self.path = Path(path)
        self.name = self.path.name
        self.frame_id = frame_id
        self.scan_files = sorted((self.path / 'velodyne').glob('*.bin'))
        if not self.scan_files:
            raise SourceError(f'{self.path / "velodyne"} holds no .bin scans')
        label_dir = self.path / 'labels'
        self.label_files: list[Path] | None = None
        if label_dir.is_dir():
            self.label_files = [label_dir / f'{f.stem}.label' for f in self.scan_files]
            missing = [f.name for f in self.label_files if not f.exists()]
            if missing:
                raise SourceError(
                    f'{label_dir}: {len(missing)} label file(s) missing, e.g. {missing[0]}'
                )
        else:
            warnings.warn(
                f'{self.path} has no labels/ folder: scans are unlabeled (label 0); '
                f'ML-SemReg then degenerates to plain descriptor matching',
                stacklevel=2,
            )
        self.poses = self._load_poses(poses, calib)
        times_path = Path(times) if times is not None else self.path / 'times.txt'
        if times_path.exists():
            seconds = read_kitti_times(times_path)
            if seconds.size != len(self.scan_files):
                raise SourceError(
                    f'{times_path}: {seconds.size} times for {len(self.scan_files)} scans'
                )
        else:
            warnings.warn(f'{times_path} not found: assuming 10 Hz', stacklevel=2)
            seconds = 0.1 * np.arange(len(self.scan_files))
        self.stamps_ns = start_time_ns + np.round(seconds * 1e9).astype(np.int64)

    def _load_poses(self, poses: str | Path | None, calib: str | Path | None) -> np.ndarray | None:
        poses_path = Path(poses) if poses is not None else self.path / 'poses.txt'
        if not poses_path.exists():
            if poses is not None:
                raise SourceError(f'{poses_path} does not exist')
            return None
        camera = read_kitti_poses(poses_path)
        if camera.shape[0] != len(self.scan_files):
            raise SourceError(
                f'{poses_path}: {camera.shape[0]} poses for {len(self.scan_files)} scans'
            )
        calib_path = Path(calib) if calib is not None else self.path / 'calib.txt'
        if not calib_path.exists():
            warnings.warn(
                f'{calib_path} not found: using {poses_path.name} as LiDAR poses', stacklevel=3
            )
            return camera
        entries = read_kitti_calib(calib_path)
        if 'Tr' not in entries or np.shape(entries['Tr']) != (4, 4):
            raise SourceError(f'{calib_path} has no 3x4 Tr entry (Velodyne -> camera)')
        return camera_to_lidar_poses(camera, entries['Tr'])

    def __len__(self) -> int:
        return len(self.scan_files)

    def close(self) -> None:
        """Nothing to release."""

    def read(self, index: int) -> Scan:
        """Scan ``index`` with its labels (raw, int64), reflectance and ground truth."""
        data = np.fromfile(self.scan_files[index], dtype='<f4')
        if data.size % 4:
            raise SourceError(f'{self.scan_files[index]}: size is not a multiple of 16 bytes')
        data = data.reshape(-1, 4)
        labels = None
        if self.label_files is not None:
            labels = np.fromfile(self.label_files[index], dtype='<u4').astype(np.int64)
            if labels.size != data.shape[0]:
                raise SourceError(
                    f'{self.label_files[index]}: {labels.size} labels for {data.shape[0]} points'
                )
        else:
            labels = np.zeros(data.shape[0], dtype=np.int64)
        pose = None if self.poses is None else self.poses[index]
        return Scan(
            index,
            int(self.stamps_ns[index]),
            data[:, :3].astype(np.float64),
            labels,
            data[:, 3].copy(),
            self.frame_id,
            pose,
        )

    def scans(self, stride: int = 1, max_frames: int | None = None) -> Iterator[Scan]:
        """Yield scans 0, stride, 2 * stride, ... (at most ``max_frames``)."""
        if stride < 1:
            raise ValueError(f'stride must be >= 1, got {stride}')
        indices = range(0, len(self), stride)
        if max_frames is not None:
            indices = indices[:max_frames]
        for index in indices:
            yield self.read(index)
