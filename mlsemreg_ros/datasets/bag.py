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

Field-mode simulations (docs/simulation.md) add per-point ``time`` (float32 s after the
header stamp = sweep start), ``ring`` (uint16), ``label_gt`` (uint32, the true raw label)
and, for Ouster models, ``t`` (uint32 ns) to the clouds, and two topics::

    /imu/data                sensor_msgs/msg/Imu          in the sensor frame, 200 Hz
    /wheel/odometry          nav_msgs/msg/Odometry        planar dead reckoning, 50 Hz

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
IMU = 'sensor_msgs/msg/Imu'
IMU_TOPIC = '/imu/data'
WHEEL_TOPIC = '/wheel/odometry'
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
        extra_fields: dict[str, np.ndarray] | None = None,
        log_time_ns: int | None = None,
    ) -> None:
        """
        Write one PointCloud2 (x, y, z, intensity, label) stamped ``stamp_ns``.

        ``extra_fields`` (name -> (N,) array) are appended in their own datatypes
        (e.g. a float32 ``time``); ``log_time_ns`` is the bag's receive time (default:
        the stamp; a driver publishes a sweep at its end).
        """
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
        if extra_fields:
            msg = _append_fields(msg, extra_fields, types['sensor_msgs/msg/PointField'])
        self.write_raw(topic, POINTCLOUD2, stamp_ns if log_time_ns is None else log_time_ns, msg)

    def write_imu(
        self,
        stamp_ns: int,
        angular_velocity: np.ndarray,
        linear_acceleration: np.ndarray,
        frame_id: str = SENSOR_FRAME,
        topic: str = IMU_TOPIC,
        gyro_variance: float = 0.0,
        accel_variance: float = 0.0,
    ) -> None:
        """Write one sensor_msgs/Imu without orientation (covariance[0] = -1)."""
        types = self.store.types
        vector = types['geometry_msgs/msg/Vector3']
        w, a = np.asarray(angular_velocity, float), np.asarray(linear_acceleration, float)
        orientation_cov = np.zeros(9)
        orientation_cov[0] = -1.0  # REP 145: no orientation estimate
        msg = types[IMU](
            header=self._header(stamp_ns, frame_id),
            orientation=types['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=orientation_cov,
            angular_velocity=vector(x=float(w[0]), y=float(w[1]), z=float(w[2])),
            angular_velocity_covariance=np.eye(3).reshape(9) * gyro_variance,
            linear_acceleration=vector(x=float(a[0]), y=float(a[1]), z=float(a[2])),
            linear_acceleration_covariance=np.eye(3).reshape(9) * accel_variance,
        )
        self.write_raw(topic, IMU, stamp_ns, msg)

    def write_ground_truth(self, stamp_ns: int, pose: np.ndarray, layout: BagLayout) -> None:
        """Write a ground-truth ``pose`` (4, 4) T_world_sensor in ``layout``'s frames and topic."""
        self.write_odometry(
            stamp_ns,
            pose,
            frame_id=layout.world_frame,
            child_frame_id=layout.frame_id,
            topic=layout.gt_topic,
        )

    def write_odometry(
        self,
        stamp_ns: int,
        pose: np.ndarray,
        frame_id: str = WORLD_FRAME,
        child_frame_id: str = SENSOR_FRAME,
        topic: str = GT_TOPIC,
        pose_covariance: np.ndarray | None = None,
        twist: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        """
        Write one nav_msgs/Odometry with ``pose`` (4, 4) = T_frame_child.

        ``twist``: optional (linear (3,), angular (3,)) velocity in the child frame.
        """
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
        vector = types['geometry_msgs/msg/Vector3']
        zero = vector(x=0.0, y=0.0, z=0.0)
        linear, angular = zero, zero
        if twist is not None:
            lv, av = (np.asarray(v, dtype=np.float64).reshape(3) for v in twist)
            linear = vector(x=float(lv[0]), y=float(lv[1]), z=float(lv[2]))
            angular = vector(x=float(av[0]), y=float(av[1]), z=float(av[2]))
        msg = types[ODOMETRY](
            header=self._header(stamp_ns, frame_id),
            child_frame_id=child_frame_id,
            pose=types['geometry_msgs/msg/PoseWithCovariance'](
                pose=geometry, covariance=covariance
            ),
            twist=types['geometry_msgs/msg/TwistWithCovariance'](
                twist=types['geometry_msgs/msg/Twist'](linear=linear, angular=angular),
                covariance=np.zeros(36),
            ),
        )
        self.write_raw(topic, ODOMETRY, stamp_ns, msg)


def _append_fields(msg: Any, columns: dict[str, np.ndarray], field_cls: type) -> Any:
    """Copy the unorganized cloud ``msg`` with (N,) ``columns`` appended as fields."""
    from mlsemreg_ros.codec.pointcloud2 import DATATYPE_BY_NAME

    n = int(msg.width) * int(msg.height)
    names, formats, offsets = ['_base'], [np.dtype((np.uint8, int(msg.point_step)))], [0]
    offset = int(msg.point_step)
    fields = list(msg.fields)
    for name, values in columns.items():
        column = np.asarray(values).reshape(-1)
        if column.dtype.name not in DATATYPE_BY_NAME or column.shape[0] != n:
            raise ValueError(f'field {name!r}: {column.dtype} x {column.shape[0]} for {n} points')
        names.append(name)
        formats.append(column.dtype.newbyteorder('<'))
        offsets.append(offset)
        fields.append(
            field_cls(
                name=name, offset=offset, datatype=DATATYPE_BY_NAME[column.dtype.name], count=1
            )
        )
        offset += column.dtype.itemsize
    step = -(-offset // 4) * 4  # keep 4-byte alignment of the next point
    packed = np.zeros(
        n,
        dtype=np.dtype({'names': names, 'formats': formats, 'offsets': offsets, 'itemsize': step}),
    )
    packed['_base'] = np.asarray(msg.data, dtype=np.uint8).reshape(n, int(msg.point_step))
    for name, values in columns.items():
        packed[name] = np.asarray(values).reshape(-1)
    return type(msg)(
        header=msg.header,
        height=1,
        width=n,
        fields=fields,
        is_bigendian=False,
        point_step=step,
        row_step=step * n,
        data=packed.view(np.uint8).reshape(-1).copy(),
        is_dense=msg.is_dense,
    )


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
    stamps, poses = [], []
    for msg, msgtype in _reader_messages(reader, topic, POSE_TYPES):
        stamps.append(stamp_to_ns(msg.header.stamp))
        poses.append(_message_pose(msg, msgtype))
    return np.asarray(stamps, dtype=np.int64), np.asarray(poses).reshape(-1, 4, 4)


def _reader_messages(
    reader: AnyReader, topic: str, msgtypes: tuple[str, ...]
) -> Iterator[tuple[Any, str]]:
    """Each message of ``topic`` with its type, in bag order (SourceError: no such topic/type)."""
    if topic not in reader.topics:
        raise SourceError(f'topic {topic!r} not in the bag; topics: {sorted(reader.topics)}')
    msgtype = reader.topics[topic].msgtype
    if msgtype not in msgtypes:
        raise SourceError(f'topic {topic!r} has type {msgtype}; expected one of {msgtypes}')
    connections = [c for c in reader.connections if c.topic == topic]
    for connection, _, raw in reader.messages(connections=connections):
        yield reader.deserialize(raw, connection.msgtype), connection.msgtype


@dataclass
class ImuArrays:
    """The messages of an Imu topic as arrays, by header stamp."""

    stamps_ns: np.ndarray  # (n,) int64
    angular_velocity: np.ndarray  # (n, 3) rad/s, in frame_id
    linear_acceleration: np.ndarray  # (n, 3) m/s^2 specific force (gravity included)
    frame_id: str

    def __len__(self) -> int:
        return int(self.stamps_ns.shape[0])


@dataclass
class WheelOdometryArrays:
    """The messages of a (wheel) Odometry topic as arrays, by header stamp."""

    stamps_ns: np.ndarray  # (n,) int64
    poses: np.ndarray  # (n, 4, 4) T_frame_child
    linear_velocity: np.ndarray  # (n, 3) m/s, child frame (x: forward speed)
    angular_velocity: np.ndarray  # (n, 3) rad/s, child frame (z: yaw rate)
    frame_id: str
    child_frame_id: str

    def __len__(self) -> int:
        return int(self.stamps_ns.shape[0])


def _topic_messages(path: str | Path, topic: str, msgtypes: tuple[str, ...]) -> Iterator[Any]:
    reader = open_reader(path)
    try:
        for msg, _ in _reader_messages(reader, topic, msgtypes):
            yield msg
    finally:
        reader.close()


def _vectors(vectors: list[Any]) -> np.ndarray:
    return np.array([[v.x, v.y, v.z] for v in vectors], dtype=np.float64).reshape(-1, 3)


def read_imu(path: str | Path, topic: str = IMU_TOPIC) -> ImuArrays:
    """All messages of a sensor_msgs/Imu topic, sorted by header stamp."""
    msgs = list(_topic_messages(path, topic, (IMU,)))
    stamps = np.array([stamp_to_ns(m.header.stamp) for m in msgs], dtype=np.int64)
    order = np.argsort(stamps, kind='stable')
    return ImuArrays(
        stamps[order],
        _vectors([m.angular_velocity for m in msgs])[order],
        _vectors([m.linear_acceleration for m in msgs])[order],
        str(msgs[0].header.frame_id) if msgs else '',
    )


def read_wheel_odometry(path: str | Path, topic: str = WHEEL_TOPIC) -> WheelOdometryArrays:
    """All messages of a nav_msgs/Odometry topic (pose and twist), sorted by header stamp."""
    msgs = list(_topic_messages(path, topic, (ODOMETRY,)))
    stamps = np.array([stamp_to_ns(m.header.stamp) for m in msgs], dtype=np.int64)
    order = np.argsort(stamps, kind='stable')
    poses = np.array([pose_message_to_matrix(m.pose.pose) for m in msgs]).reshape(-1, 4, 4)
    return WheelOdometryArrays(
        stamps[order],
        poses[order],
        _vectors([m.twist.twist.linear for m in msgs])[order],
        _vectors([m.twist.twist.angular for m in msgs])[order],
        str(msgs[0].header.frame_id) if msgs else '',
        str(msgs[0].child_frame_id) if msgs else '',
    )


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
        time_field: str = '',
        time_unit: str = 'auto',
    ) -> None:
        self.path = _bag_path(Path(path))
        self.name = self.path.name
        self.label_field = label_field
        self.require_labels = require_labels
        self.time_options = (time_field, time_unit)  # codec: decode_point_times
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
            cloud = pointcloud2_to_arrays(
                msg, self.label_field, self.require_labels, *self.time_options
            )
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
                cloud.point_times,
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
    from mlsemreg_ros.codec.pose_files import write_kitti_poses

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
                bag.write_ground_truth(scan.stamp_ns, scan.pose, layout)
                poses.append(scan.pose)
            stamps.append(scan.stamp_ns)
            points += len(scan)
    if poses:
        write_kitti_poses(out / 'poses.txt', np.asarray(poses))
    if stamps:
        seconds = (np.asarray(stamps) - stamps[0]) / 1e9
        np.savetxt(out / 'times.txt', seconds, fmt='%.6e')
    return WrittenSequence(len(stamps), points, labeled and bool(stamps), bool(poses))
