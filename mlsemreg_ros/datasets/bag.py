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
rosbag2 reading and writing with ``rosbags`` (no ROS runtime needed).

Layout of the bags this package writes (simulator, KITTI converter)::

    /points                  sensor_msgs/msg/PointCloud2  x, y, z, intensity (float32),
                                                          label (uint32, SemanticKITTI raw id,
                                                          instance id in the upper 16 bits)
    /ground_truth/odometry   nav_msgs/msg/Odometry        T_world_sensor (world = first scan)

Storage is mcap (default) or sqlite3; message types come from the ROS 2 Jazzy
typestore. Reading goes through ``rosbags.highlevel.AnyReader`` (mcap and sqlite3).
PointCloud2 conversion is :mod:`mlsemreg_ros.codec.pointcloud2` (pure NumPy).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any
import warnings

from mlsemreg_ros.codec.pointcloud2 import arrays_to_pointcloud2, pointcloud2_to_arrays
from mlsemreg_ros.codec.poses import (
    matrix_to_quaternion,
    pose_message_to_matrix,
    transform_message_to_matrix,
)
from mlsemreg_ros.codec.stamps import ns_to_sec_nanosec, stamp_to_ns
from mlsemreg_ros.datasets.source import Scan, SourceError
import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.typesys import get_typestore, Stores

POINTS_TOPIC = '/points'
GT_TOPIC = '/ground_truth/odometry'
SENSOR_FRAME = 'lidar'
WORLD_FRAME = 'world'
STORAGES = ('mcap', 'sqlite3')

POINTCLOUD2 = 'sensor_msgs/msg/PointCloud2'
ODOMETRY = 'nav_msgs/msg/Odometry'
POSE_TYPES = (ODOMETRY, 'geometry_msgs/msg/PoseStamped', 'geometry_msgs/msg/TransformStamped')


def typestore() -> Any:
    """Return the ROS 2 Jazzy typestore of rosbags."""
    return get_typestore(Stores.ROS2_JAZZY)


def _time(store: Any, stamp_ns: int) -> Any:
    sec, nanosec = ns_to_sec_nanosec(stamp_ns)
    return store.types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec)


def _message_pose(msg: Any, msgtype: str) -> np.ndarray:
    """(4, 4) pose of an Odometry, PoseStamped or TransformStamped message."""
    if msgtype == ODOMETRY:
        return pose_message_to_matrix(msg.pose.pose)
    if msgtype == 'geometry_msgs/msg/PoseStamped':
        return pose_message_to_matrix(msg.pose)
    return transform_message_to_matrix(msg.transform)


class BagWriter:
    """
    Writes labeled clouds and odometry to a new rosbag2 (mcap or sqlite3).

    Use as a context manager; the bag directory must not exist yet.
    """

    def __init__(self, path: str | Path, storage: str = 'mcap', compress: bool = False) -> None:
        if storage not in STORAGES:
            raise ValueError(f'unknown storage {storage!r}; use one of {STORAGES}')
        self.path = Path(path)
        self.store = typestore()
        plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
        self._writer = Writer(self.path, version=Writer.VERSION_LATEST, storage_plugin=plugin)
        if compress:
            mode = CompressionMode.STORAGE if storage == 'mcap' else CompressionMode.MESSAGE
            self._writer.set_compression(mode, CompressionFormat.ZSTD)
        self._connections: dict[str, Any] = {}

    def __enter__(self) -> BagWriter:
        self._writer.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self._writer.close()

    def _connection(self, topic: str, msgtype: str) -> Any:
        if topic not in self._connections:
            self._connections[topic] = self._writer.add_connection(
                topic, msgtype, typestore=self.store
            )
        return self._connections[topic]

    def _header(self, stamp_ns: int, frame_id: str) -> Any:
        return self.store.types['std_msgs/msg/Header'](
            stamp=_time(self.store, stamp_ns), frame_id=frame_id
        )

    def write_raw(self, topic: str, msgtype: str, stamp_ns: int, msg: Any) -> None:
        """Serialize and write any typestore message at ``stamp_ns``."""
        data = self.store.serialize_cdr(msg, msgtype)
        self._writer.write(self._connection(topic, msgtype), int(stamp_ns), data)

    def write_cloud(
        self,
        stamp_ns: int,
        xyz: np.ndarray,
        labels: np.ndarray | None = None,
        intensity: np.ndarray | None = None,
        frame_id: str = SENSOR_FRAME,
        topic: str = POINTS_TOPIC,
        label_datatype: str = 'uint32',
    ) -> None:
        """Write one PointCloud2 (x, y, z, intensity, label) stamped ``stamp_ns``."""
        types = self.store.types
        msg = arrays_to_pointcloud2(
            types[POINTCLOUD2],
            types['sensor_msgs/msg/PointField'],
            self._header(stamp_ns, frame_id),
            xyz,
            labels,
            intensity,
            label_datatype=label_datatype,
        )
        self.write_raw(topic, POINTCLOUD2, stamp_ns, msg)

    def write_odometry(
        self,
        stamp_ns: int,
        pose: np.ndarray,
        frame_id: str = WORLD_FRAME,
        child_frame_id: str = SENSOR_FRAME,
        topic: str = GT_TOPIC,
        pose_covariance: np.ndarray | None = None,
    ) -> None:
        """Write one nav_msgs/Odometry with ``pose`` (4, 4) = T_frame_child."""
        types = self.store.types
        pose = np.asarray(pose, dtype=np.float64)
        q = matrix_to_quaternion(pose[:3, :3])
        t = pose[:3, 3]
        geometry = types['geometry_msgs/msg/Pose'](
            position=types['geometry_msgs/msg/Point'](x=float(t[0]), y=float(t[1]), z=float(t[2])),
            orientation=types['geometry_msgs/msg/Quaternion'](
                x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])
            ),
        )
        covariance = (
            np.zeros(36)
            if pose_covariance is None
            else np.asarray(pose_covariance, dtype=np.float64).reshape(36)
        )
        zero = types['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0)
        msg = types[ODOMETRY](
            header=self._header(stamp_ns, frame_id),
            child_frame_id=child_frame_id,
            pose=types['geometry_msgs/msg/PoseWithCovariance'](
                pose=geometry, covariance=covariance
            ),
            twist=types['geometry_msgs/msg/TwistWithCovariance'](
                twist=types['geometry_msgs/msg/Twist'](linear=zero, angular=zero),
                covariance=np.zeros(36),
            ),
        )
        self.write_raw(topic, ODOMETRY, stamp_ns, msg)


def _bag_path(path: Path) -> Path:
    """Return the rosbag2 directory of a bag directory or of one of its storage files."""
    if path.is_file() and (path.parent / 'metadata.yaml').exists():
        return path.parent
    return path


def open_reader(path: str | Path) -> AnyReader:
    """Open an AnyReader on a rosbag2 directory (or a storage file inside one)."""
    reader = AnyReader([_bag_path(Path(path))], default_typestore=typestore())
    reader.open()
    return reader


def read_poses(path: str | Path, topic: str) -> tuple[np.ndarray, np.ndarray]:
    """Header stamps (F,) int64 ns and poses (F, 4, 4) of an Odometry/PoseStamped topic."""
    reader = open_reader(path)
    try:
        return _read_poses(reader, topic)
    finally:
        reader.close()


def _read_poses(reader: AnyReader, topic: str) -> tuple[np.ndarray, np.ndarray]:
    if topic not in reader.topics:
        raise SourceError(f'topic {topic!r} not in the bag; topics: {sorted(reader.topics)}')
    msgtype = reader.topics[topic].msgtype
    if msgtype not in POSE_TYPES:
        raise SourceError(f'topic {topic!r} has type {msgtype}; expected one of {POSE_TYPES}')
    connections = [c for c in reader.connections if c.topic == topic]
    stamps, poses = [], []
    for connection, _, raw in reader.messages(connections=connections):
        msg = reader.deserialize(raw, connection.msgtype)
        stamps.append(stamp_to_ns(msg.header.stamp))
        poses.append(_message_pose(msg, connection.msgtype))
    return np.asarray(stamps, dtype=np.int64), np.asarray(poses).reshape(-1, 4, 4)


class BagScanReader:
    """
    :class:`~mlsemreg_ros.datasets.source.ScanSource` over a rosbag2 (mcap or sqlite3).

    Ground truth comes from ``gt_topic`` (Odometry, PoseStamped or
    TransformStamped), matched to each cloud by header stamp within
    ``gt_tolerance_ns``. ``gt_topic='auto'`` uses ``/ground_truth/odometry`` when
    present; None disables ground truth.
    """

    def __init__(
        self,
        path: str | Path,
        points_topic: str | None = None,
        gt_topic: str | None = 'auto',
        label_field: str = 'label',
        require_labels: bool = False,
        gt_tolerance_ns: int = 5_000_000,
    ) -> None:
        self.path = _bag_path(Path(path))
        self.name = self.path.name
        self.label_field = label_field
        self.require_labels = require_labels
        self.reader = open_reader(self.path)
        topics = self.reader.topics
        clouds = sorted(t for t, info in topics.items() if info.msgtype == POINTCLOUD2)
        if points_topic is None:
            if len(clouds) != 1:
                self.close()
                raise SourceError(
                    f'{self.path}: cannot guess the points topic among '
                    f'{clouds or "no PointCloud2 topics"}; pass it explicitly'
                )
            points_topic = clouds[0]
        elif points_topic not in topics or topics[points_topic].msgtype != POINTCLOUD2:
            self.close()
            raise SourceError(
                f'{self.path}: no PointCloud2 topic {points_topic!r}; PointCloud2 topics: {clouds}'
            )
        self.points_topic = points_topic
        self._connections = [c for c in self.reader.connections if c.topic == points_topic]
        self._count = int(topics[points_topic].msgcount)
        if gt_topic == 'auto':
            gt_topic = GT_TOPIC if GT_TOPIC in topics else None
        self.gt_topic = gt_topic
        self._gt_stamps = np.zeros(0, dtype=np.int64)
        self._gt_poses = np.zeros((0, 4, 4))
        if gt_topic is not None:
            self._gt_stamps, self._gt_poses = _read_poses(self.reader, gt_topic)
            order = np.argsort(self._gt_stamps, kind='stable')
            self._gt_stamps, self._gt_poses = self._gt_stamps[order], self._gt_poses[order]
        self.gt_tolerance_ns = int(gt_tolerance_ns)
        self._warned_labels = False

    def __len__(self) -> int:
        return self._count

    def close(self) -> None:
        """Close the bag."""
        self.reader.close()

    def ground_truth_at(self, stamp_ns: int) -> np.ndarray | None:
        """Ground-truth pose (4, 4) with the nearest stamp within tolerance, else None."""
        if self._gt_stamps.size == 0:
            return None
        i = int(np.searchsorted(self._gt_stamps, stamp_ns))
        best = min(
            (j for j in (i - 1, i) if 0 <= j < self._gt_stamps.size),
            key=lambda j: abs(int(self._gt_stamps[j]) - stamp_ns),
        )
        if abs(int(self._gt_stamps[best]) - stamp_ns) > self.gt_tolerance_ns:
            return None
        return self._gt_poses[best]

    def scans(self, stride: int = 1, max_frames: int | None = None) -> Iterator[Scan]:
        """Deserialize clouds 0, stride, 2 * stride, ...; skipped clouds are not decoded."""
        if stride < 1:
            raise ValueError(f'stride must be >= 1, got {stride}')
        produced = 0
        for index, (connection, _, raw) in enumerate(
            self.reader.messages(connections=self._connections)
        ):
            if index % stride:
                continue
            if max_frames is not None and produced >= max_frames:
                return
            msg = self.reader.deserialize(raw, connection.msgtype)
            cloud = pointcloud2_to_arrays(msg, self.label_field, self.require_labels)
            if cloud.labels is None and not self._warned_labels:
                warnings.warn(
                    f'{self.points_topic} has no {self.label_field!r} field; scans are unlabeled',
                    stacklevel=2,
                )
                self._warned_labels = True
            stamp = stamp_to_ns(msg.header.stamp)
            yield Scan(
                index,
                stamp,
                cloud.xyz,
                cloud.labels,
                cloud.intensity,
                str(msg.header.frame_id),
                self.ground_truth_at(stamp),
            )
            produced += 1


@dataclass
class BagLayout:
    """Storage, topics and frames of a bag this package writes."""

    storage: str = 'mcap'  # one of STORAGES
    compress: bool = False  # zstd (mcap chunks / sqlite3 messages)
    points_topic: str = POINTS_TOPIC
    gt_topic: str = GT_TOPIC
    frame_id: str = SENSOR_FRAME  # of the clouds
    world_frame: str = WORLD_FRAME  # of the ground truth


@dataclass
class WrittenSequence:
    """What :func:`write_sequence_bag` wrote."""

    frames: int
    points: int  # over all scans
    labeled: bool  # every scan had labels
    ground_truth: bool  # some scan had a pose

    @property
    def points_per_scan(self) -> float:
        """Mean points per scan."""
        return self.points / max(self.frames, 1)


def write_sequence_bag(
    out: str | Path, scans: Iterable[Scan], layout: BagLayout
) -> WrittenSequence:
    """
    Write labeled scans (and their ground truth) as a rosbag2, with KITTI side files.

    Per scan: a PointCloud2 on ``layout.points_topic`` and, when ``scan.pose`` is known, an
    Odometry on ``layout.gt_topic``. Next to the storage file: ``poses.txt`` (KITTI format,
    the scans' poses) and ``times.txt`` (seconds since the first scan). The folder must
    not exist yet.
    """
    from mlsemreg_ros.datasets.pose_files import write_kitti_poses

    out = Path(out)
    stamps: list[int] = []
    poses: list[np.ndarray] = []
    points, labeled = 0, True
    with BagWriter(out, storage=layout.storage, compress=layout.compress) as bag:
        for scan in scans:
            labeled = labeled and scan.labels is not None
            bag.write_cloud(
                scan.stamp_ns,
                scan.xyz,
                scan.labels,
                scan.intensity,
                frame_id=layout.frame_id,
                topic=layout.points_topic,
            )
            if scan.pose is not None:
                bag.write_odometry(
                    scan.stamp_ns,
                    scan.pose,
                    frame_id=layout.world_frame,
                    child_frame_id=layout.frame_id,
                    topic=layout.gt_topic,
                )
                poses.append(scan.pose)
            stamps.append(scan.stamp_ns)
            points += len(scan)
    if poses:
        write_kitti_poses(out / 'poses.txt', np.asarray(poses))
    if stamps:
        seconds = (np.asarray(stamps) - stamps[0]) / 1e9
        np.savetxt(out / 'times.txt', seconds, fmt='%.6e')
    return WrittenSequence(len(stamps), points, labeled and bool(stamps), bool(poses))
