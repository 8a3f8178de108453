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
``mlsemreg_node``: labeled PointCloud2 in; transform, odometry, path and markers out.

Interface (docs/ros_interface.md; names are part of the contract):

- subscribes ``points`` (sensor_msgs/PointCloud2 with x, y, z and a label field);
- publishes ``mlsemreg/transform`` (TransformStamped ``T_keyframe_current``,
  ``p_keyframe = T @ p_current``, refined by the fine alignment, stamped with the
  current scan's stamp; only for accepted frames), ``mlsemreg/odometry`` (Odometry
  in ``odom_frame``, child ``base_frame``: the map-aligned pose), ``mlsemreg/path``,
  ``mlsemreg/correspondences`` (MarkerArray), ``mlsemreg/local_map`` (PointCloud2,
  throttled, only while subscribed) and ``/diagnostics``;
- broadcasts TF ``odom_frame -> base_frame`` when tf2_ros is importable;
- serves ``mlsemreg/reset`` (std_srvs/Trigger): drop the keyframe, restart at identity.
- the map (``ros/map_services.py``, docs/maps.md): publishes ``mlsemreg/map_pose`` and TF
  ``map -> odom``, ``mlsemreg/map_path``; serves ``mlsemreg/relocalize`` and
  ``mlsemreg/save_map``; with ``map.load_path`` it starts unlocalized and relocalizes.

Per frame (docs/architecture.md, core vs glue): convert the message -> call the core -> publish.
The subscription callback only converts and hands the scan to a worker thread
through a latest-only slot (a scan still waiting when a newer one arrives is
dropped and counted), so a slow registration never blocks the executor. The
worker runs :class:`mlsemreg_ros.core.odometry.Odometry` (the code path of the
offline bag evaluation too), which owns all odometry state: keyframe, local map,
pose, covariance and twist. A rejected frame publishes no transform/odometry,
keeps the keyframe and says why in ``/diagnostics``; this layer only converts
and publishes.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, replace
import signal
import threading
import time
import traceback
from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TransformStamped
from mlsemreg_ros.codec.pointcloud2 import (
    arrays_to_pointcloud2,
    pointcloud2_to_arrays,
    PointCloudError,
)
from mlsemreg_ros.codec.stamps import stamp_to_ns, stamp_to_seconds
from mlsemreg_ros.core.alignment.alignment import UNKNOWN_VARIANCE
from mlsemreg_ros.core.config import ConfigError, NODE_NAME
from mlsemreg_ros.core.features import kernels
from mlsemreg_ros.core.features.warm_up import warm_up
from mlsemreg_ros.core.matching.labels import LabelError, LabelMap
from mlsemreg_ros.core.odometry import Odometry as ScanOdometry
from mlsemreg_ros.core.odometry import OdometryStep
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.results import PreparedScan, RegistrationResult
from mlsemreg_ros.core.rigid import invert_transform
from mlsemreg_ros.ros import messages
from mlsemreg_ros.ros.callback_guard import DropCounter, GuardedCallbacks, spin_guarded
from mlsemreg_ros.ros.extrinsic import ExtrinsicSource, to_base
from mlsemreg_ros.ros.map_services import MapServices
from mlsemreg_ros.ros.markers import correspondence_markers
from mlsemreg_ros.ros.node_config import NodeConfig
from mlsemreg_ros.ros.outputs import Heartbeat, RegisteredCloud
from mlsemreg_ros.ros.parameters import ConfigSnapshot, LiveParameters
from mlsemreg_ros.ros.pose_input import PoseInput
from mlsemreg_ros.ros.prior_inputs import PriorInbox, STREAMS, subscribe_prior_topics
from nav_msgs.msg import Odometry, Path
import numpy as np
import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

try:  # TF output is optional (no tf2_ros wheel on PyPI).
    from tf2_ros import TransformBroadcaster
except ImportError:
    TransformBroadcaster = None

#: Lines per marker namespace (drawing thousands of lines costs ~5 ms per 1000).
MAX_MARKER_LINES = 1000
LOG_THROTTLE_S = 5.0
#: The spin loop wakes at least this often to see a stop request (SIGINT / SIGTERM).
SPIN_PERIOD_S = 0.1


@dataclass
class Scan:
    """One converted PointCloud2 waiting for (or under) registration."""

    stamp: Time
    frame_id: str
    xyz: np.ndarray  # (N, 3) float64, sensor frame, metres
    labels: np.ndarray  # (N,) int64 raw label values
    received: float  # time.perf_counter() when the message reached the callback
    dropped_nonfinite: int
    point_times: np.ndarray | None = None  # (N,) float64 s after the stamp (deskew)
    time_warning: str = ''  # a time field that is there but not used for deskew: why
    intensity: np.ndarray | None = None  # (N,) float32, for label_source onnx


class StampGaps:
    """Estimates input frames lost before the node saw them, from gaps between stamps."""

    def __init__(self, history: int = 50) -> None:
        self._periods: collections.deque[int] = collections.deque(maxlen=history)
        self._last = 0
        self.lost = 0  # scans estimated missing (transport losses, a publisher's drops)

    def observe(self, stamp_ns: int) -> None:
        """Take the stamp of a received scan; a gap of k typical periods counts k - 1."""
        if stamp_ns <= 0:
            return
        if self._last and stamp_ns > self._last:
            gap = stamp_ns - self._last
            if len(self._periods) >= 5:
                period = float(np.median(self._periods))
                self.lost += max(round(gap / period) - 1, 0)
            self._periods.append(gap)
        self._last = stamp_ns


class LatestSlot:
    """A one-element hand-over between threads; a newer item replaces an unclaimed one."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._item: Any = None
        self._closed = False
        self.dropped = 0

    def put(self, item: Any) -> None:
        """Offer an item; an item nobody took yet is dropped (and counted)."""
        with self._cond:
            self.dropped += self._item is not None
            self._item = item
            self._cond.notify()

    def take(self) -> Any:
        """Block until an item arrives; None once closed."""
        with self._cond:
            while self._item is None and not self._closed:
                self._cond.wait()
            item, self._item = self._item, None
            return None if self._closed else item

    def close(self) -> None:
        """Wake the taker and make every later take() return None."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()


class MlSemRegNode(GuardedCallbacks, Node):
    """ML-SemReg odometry: registers every labeled scan onto a keyframe (no callback raises)."""

    #: Whether scans are taken (a managed node's inactive states set it False).
    _active = True
    #: Create the interface at construction (a managed node does it on configure).
    _configure_at_start = True

    def __init__(self, **kwargs: Any) -> None:
        """Declare parameters, create the interface and start the worker thread."""
        started = time.perf_counter()
        super().__init__(NODE_NAME, **kwargs)
        # drops and callback errors (ros/callback_guard.py), before any callback exists
        self.callback_drops = DropCounter(lambda text: self.get_logger().warning(text))
        self.callback_fallbacks = {'points': self._points_failed}
        self._label_map = LabelMap.load()
        self._params = LiveParameters(self, self._label_map)
        self._configured = False
        self._created: list[tuple[Any, Any]] = []  # (destroy, entity) made by _setup
        if self._configure_at_start:
            self._setup(started)

    def _setup(self, started: float) -> None:
        """Create the odometry, the topics, services and timers, and start the worker."""
        before = self._entities()
        config = self._params.snapshot()
        self._odometry = ScanOdometry(Registration(config.core, self._label_map))
        self._core_version = config.core_version
        self._lock = threading.Lock()  # guards the published state and the counters
        self._reset_pending = False  # set by the reset service, applied by the worker
        self._path = Path()
        self._local_map_published = -float('inf')  # time.monotonic() of the last map cloud
        self._path_published = -float('inf')  # time.monotonic() of the last path
        self._frame_id: str | None = None  # frame of the clouds the odometry runs in
        self._stream = StampGaps()
        self._counts = collections.Counter()
        self._latencies: collections.deque[float] = collections.deque(maxlen=100)
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=config.node.qos.depth,
            reliability=ReliabilityPolicy.BEST_EFFORT
            if config.node.qos.reliability == 'best_effort'
            else ReliabilityPolicy.RELIABLE,
        )
        self._pub_transform = self.create_publisher(TransformStamped, 'mlsemreg/transform', 10)
        self._pub_odometry = self.create_publisher(Odometry, 'mlsemreg/odometry', 10)
        self._pub_path = self.create_publisher(Path, 'mlsemreg/path', 1)
        self._pub_markers = self.create_publisher(MarkerArray, 'mlsemreg/correspondences', 1)
        self._pub_local_map = self.create_publisher(PointCloud2, 'mlsemreg/local_map', 1)
        self._pub_diagnostics = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._cloud_registered = RegisteredCloud(self)  # ros/outputs.py
        self._heartbeat = Heartbeat(self, self._pub_diagnostics)
        self.create_subscription(PointCloud2, 'points', self._on_points, qos)
        self.create_service(Trigger, 'mlsemreg/reset', self._on_reset)
        # the motion prior's topics and the extrinsic (docs/field_prior.md)
        self._prior = PriorInbox(self.callback_drops)
        for note in subscribe_prior_topics(self, self._prior, config, self._odometry.motion_model):
            self.get_logger().info(note)
        self._extrinsic = ExtrinsicSource(self, config.node)
        self._T_base_sensor = np.eye(4)  # of the clouds' frame, set per scan
        self._tf = TransformBroadcaster(self) if TransformBroadcaster is not None else None
        self._map = MapServices(self, self._odometry, config, self._tf)  # ros/map_services.py
        self._pose_input = PoseInput(self)  # /initialpose, mlsemreg/set_pose (ros/pose_input.py)
        self._map_update = None  # the map's answer to the last scan (diagnostics)
        if self._tf is None:
            self.get_logger().info(
                'tf2_ros is not importable: no TF output (mlsemreg/odometry carries the same pose)'
            )
        if config.node.keep_freed_memory:
            kernels.keep_freed_memory()
        warm = warm_up()  # compile or load the numba kernels before the first scan
        self._startup_ms = {
            'kernels_ms': warm.get('total_ms', 0.0),
            'node_ms': 1e3 * (time.perf_counter() - started),
        }
        self._time_note: str | None = None  # how per-point times were last read (logged)
        self._slot = LatestSlot()
        self._worker = threading.Thread(target=self._work, name='mlsemreg_worker', daemon=True)
        self._worker.start()
        self._configured = True
        self._created = [e for e in self._entities() if id(e[1]) not in {id(b) for _, b in before}]
        self.get_logger().info(
            f'registering scans on {self.resolve_topic_name("points")} '
            f'({config.node.qos.reliability}, label field {config.node.label_field!r}); ready in '
            f'{self._startup_ms["node_ms"]:.0f} ms (kernels {self._startup_ms["kernels_ms"]:.0f} '
            'ms)'
        )

    # -- executor thread ------------------------------------------------------------------
    def _on_points(self, msg: PointCloud2) -> None:
        """Convert the message and hand it to the worker; malformed input is skipped."""
        received = time.perf_counter()
        self._heartbeat.note_input()
        if not self._active:  # a managed node, inactive: the scan is not taken
            self._count('frames_inactive')
            return
        self._count('frames_received')
        self._observe_stamp(msg.header.stamp)
        try:
            params = self._params.snapshot()
            cloud = pointcloud2_to_arrays(
                msg,
                params.node.label_field,
                require_labels=params.core.label_source == 'field',  # else: label_source
                time_field=params.core.preprocess.time_field,
                time_unit=params.core.preprocess.time_unit,
            )
        except PointCloudError as error:
            self._skip(msg.header.stamp, f'skipped malformed PointCloud2: {error}')
            return
        self._note_times(cloud.time_note, cloud.point_times is not None)
        self._slot.put(
            Scan(
                msg.header.stamp,
                msg.header.frame_id,
                cloud.xyz,
                cloud.labels,
                received,
                cloud.dropped_nonfinite,
                cloud.point_times,
                cloud.time_warning,
                cloud.intensity,
            )
        )

    def _points_failed(self, error: Exception, msg: PointCloud2) -> None:
        """Answer a cloud whose callback raised (the guard counted and logged it)."""
        self._skip(msg.header.stamp, f'skipped PointCloud2: {type(error).__name__}: {error}')

    def _observe_stamp(self, stamp: Time) -> None:
        """Count clouds missing between the stamps (before the worker's slot); warn."""
        before = self._stream.lost
        self._stream.observe(stamp_to_ns(stamp))
        if self._stream.lost > before:
            self.get_logger().warning(
                f'{self._stream.lost - before} cloud(s) missing before stamp '
                f'{stamp_to_seconds(stamp):.3f} (frames_lost_estimate={self._stream.lost}): '
                'lost in transport? Large best-effort clouds need the Fast DDS profile '
                'config/fastdds.xml in every process (docs/field_moving.md)',
                throttle_duration_sec=LOG_THROTTLE_S,
            )

    def _note_times(self, note: str, decoded: bool) -> None:
        """Log once how per-point times are read, and again when that changes."""
        if note != self._time_note:
            self._time_note = note
            self.get_logger().info(
                f'per-point times: {note}'
                if decoded
                else f'no per-point times ({note}): scans are not deskewed'
            )

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """Drop the keyframe; the odometry restarts from the next scan (``reset_keeps_pose``)."""
        where = 'its current pose' if self._params.snapshot().node.reset_keeps_pose else 'identity'
        with self._lock:
            self._reset_pending, self._path = True, Path()
        self.get_logger().info(f'reset: keyframe dropped, odometry restarts at {where}')
        response.success = True
        response.message = f'keyframe dropped; odometry restarts at {where}'
        return response

    # -- worker thread ----------------------------------------------------------------------
    def _work(self) -> None:
        while (scan := self._slot.take()) is not None:
            try:
                self._process(scan)
            except Exception as error:  # the node never dies of one frame
                if not self.context.ok():
                    return
                self._count('errors')
                self.get_logger().error(f'frame failed: {type(error).__name__}: {error}')
                self.get_logger().debug(traceback.format_exc())
                try:
                    self._publish_diagnostics(scan.stamp, 'error', f'frame failed: {error}', {})
                except Exception as again:  # the worker goes on to the next scan
                    self.callback_drops.error('worker', again)

    def _process(self, scan: Scan) -> None:
        """Register the scan onto the keyframe (core odometry) and publish the outcome."""
        config = self._sync(self._params.snapshot())
        if not self._check_frame(scan, config.node):
            return
        self._before_scan(scan, config.node)
        self._apply_pose_request(config.node)
        try:
            step = self._odometry.process(
                scan.xyz,
                scan.labels,
                stamp_to_ns(scan.stamp),
                point_times=scan.point_times,
                intensity=scan.intensity,
            )
        except LabelError as error:
            self._skip(scan.stamp, f'skipped scan with unusable labels: {error}')
            return
        with self._lock:
            reset = self._reset_pending  # a reset arrived while registering: discard
            latency_ms = (
                self._publish_step(scan, step, config) if step.accepted and not reset else None
            )
            refused = not (step.accepted or reset)
            predicted = refused and self._publish_predicted(scan, step, config)
        if not reset:  # map -> odom, relocalization, mapping (ros/map_services.py)
            self._map_update = self._map.after_step(scan, step, config)
        if reset:
            self._count('frames_dropped_by_reset')
            self._publish_diagnostics(
                scan.stamp,
                'warn',
                'scan dropped: a reset arrived while it was being registered',
                {},
            )
            return
        result = step.result
        if step.source == 'first':
            note = f' ({step.reason})' if step.reason else ''
            self._diagnose(
                scan, 'ok', f'first scan: keyframe set, odometry at identity{note}', step
            )
            return
        if result is not None:
            self._publish_markers(scan, result, step.prepared, config.node)
        self._publish_local_map(scan, config.node)
        if step.accepted:
            self.get_logger().debug(f'latency {latency_ms:.1f} ms, stages {step.timings_ms}')
            how = f'{result.mode}, {step.source}' if result is not None else 'tracked'
            self._diagnose(scan, 'ok', f'registered ({how})', step, latency_ms)
        else:
            reason = step.reason or (result.message if result is not None else '') or 'rejected'
            self._count('failures')
            self.get_logger().warning(
                f'frame rejected, keyframe kept: {reason}', throttle_duration_sec=LOG_THROTTLE_S
            )
            published = (
                '; odometry and TF from the prediction (covariance inflated)' if predicted else ''
            )
            self._diagnose(
                scan, 'warn', f'frame rejected: {reason}{published}', step, predicted=predicted
            )

    def _before_scan(self, scan: Scan, node: NodeConfig) -> None:
        """Resolve the extrinsic and hand the waiting prior messages to the motion model."""
        self._T_base_sensor = self._extrinsic.matrix(scan.frame_id)
        self._map.T_base_sensor = self._T_base_sensor
        model = self._odometry.motion_model
        self._prior.flush(model, scan.frame_id, node.base_frame, self._T_base_sensor)
        for warning in self._extrinsic.warnings + self._prior.warnings:
            self.get_logger().warning(warning, throttle_duration_sec=LOG_THROTTLE_S)
        self._extrinsic.warnings.clear()
        self._prior.warnings.clear()

    def _apply_pose_request(self, node: NodeConfig) -> None:
        """Apply the latest /initialpose or mlsemreg/set_pose before this scan (logged)."""
        request = self._pose_input.take()
        if request is None:
            return
        applied, message = self._pose_input.apply(
            request, self._odometry, self._map.localization, node.odom_frame, self._T_base_sensor
        )
        self._count('poses_applied' if applied else 'poses_refused')
        if applied:
            self.get_logger().info(f'{request.kind}: {message}')
        else:
            self.get_logger().warning(f'{request.kind} refused: {message}')

    def _check_frame(self, scan: Scan, node: NodeConfig) -> bool:
        """Handle a change of the clouds' frame_id per ``frame_change`` (False: skip it)."""
        previous, self._frame_id = self._frame_id, scan.frame_id
        if previous is None or previous == scan.frame_id:
            return True
        self._count('frame_changes')
        if node.frame_change == 'skip':
            self._frame_id = previous  # the odometry stays in the old frame
            self._skip(
                scan.stamp,
                f'skipped scan in frame {scan.frame_id!r}: the odometry runs '
                f'in {previous!r} (frame_change: skip)',
            )
            return False
        self._odometry.reset()
        self.get_logger().warning(
            f'frame_id changed from {previous!r} to {scan.frame_id!r}: '
            'odometry reset (frame_change: reset)'
        )
        with self._lock:
            self._path = Path()
        return True

    def _sync(self, config: ConfigSnapshot) -> ConfigSnapshot:
        """Apply a pending reset and parameter changes (they hold from this frame on)."""
        with self._lock:
            if self._reset_pending:
                pose, covariance = self._odometry.pose, self._odometry.covariance
                self._odometry.reset()
                if config.node.reset_keeps_pose:  # restart where the odometry was
                    self._odometry.restart_at(pose, covariance)
                self._reset_pending = False
        if config.core_version != self._core_version:
            self._core_version = config.core_version
            try:
                self._odometry.reconfigure(config.core)  # re-prepares the cached keyframe
            except LabelError as error:  # e.g. label_scheme changed under a raw keyframe
                self._odometry.reset()
                self.get_logger().warning(
                    f'keyframe unusable with the new parameters ({error}):'
                    ' odometry restarts at identity'
                )
        return config

    def _publish_step(self, scan: Scan, step: OdometryStep, config: ConfigSnapshot) -> float:
        """Publish transform, odometry, path and TF of an accepted step (lock held)."""
        if step.relative is not None:
            self._pub_transform.publish(
                messages.transform_msg(scan.stamp, scan.frame_id, scan.frame_id, step.relative)
            )
            self._counts['registrations'] += 1
        self._publish_pose(scan, step, config.node)
        self._cloud_registered.publish(
            scan.stamp, config.node.odom_frame, step, self._T_base_sensor
        )
        # receipt -> transform, odometry, path and TF published: their cost is counted
        latency_ms = 1e3 * (time.perf_counter() - scan.received)
        self._latencies.append(latency_ms)
        return latency_ms

    def _publish_predicted(self, scan: Scan, step: OdometryStep, config: ConfigSnapshot) -> bool:
        """Odometry and TF of a refused scan from the core's prediction (lock held)."""
        if not config.node.publish_predicted_on_refusal or step.predicted_pose is None:
            return False
        predicted = replace(
            step,
            pose=step.predicted_pose,
            covariance=step.predicted_covariance,
            twist=None,
            twist_covariance=None,
        )
        self._publish_pose(scan, predicted, config.node, path=False)
        self._counts['predicted_published'] += 1
        return True

    # -- publishing --------------------------------------------------------------------------
    def _publish_pose(
        self, scan: Scan, step: OdometryStep, node: NodeConfig, path: bool = True
    ) -> None:
        """Odometry, path (unless ``path`` is False) and TF of the step's pose (lock held)."""
        child = node.base_frame or scan.frame_id
        twist = step.twist if step.twist is not None else np.zeros(6)
        twist_cov = (
            step.twist_covariance
            if step.twist_covariance is not None
            else np.eye(6) * UNKNOWN_VARIANCE
        )
        # the base's pose: T_odom_base = X T_odom_sensor X^-1 (ros/extrinsic.py)
        base = to_base(self._T_base_sensor, step.pose, step.covariance, twist, twist_cov)
        pose = base.pose
        self._pub_odometry.publish(
            messages.odometry_msg(
                scan.stamp,
                node.odom_frame,
                child,
                pose,
                base.covariance,
                base.twist,
                base.twist_covariance,
            )
        )
        if path:
            self._append_path(scan, pose, node)
        if node.publish_tf and self._tf is not None:
            self._tf.sendTransform(
                messages.transform_msg(scan.stamp, child, node.odom_frame, invert_transform(pose))
                if node.invert_tf
                else messages.transform_msg(scan.stamp, node.odom_frame, child, pose)
            )

    def _append_path(self, scan: Scan, pose: np.ndarray, node: NodeConfig) -> None:
        """Append the pose to ``mlsemreg/path``; publish it if watched, throttled."""
        self._path.header = Header(stamp=scan.stamp, frame_id=node.odom_frame)
        self._path.poses.append(messages.pose_stamped(scan.stamp, node.odom_frame, pose))
        if node.path.max_length and len(self._path.poses) > node.path.max_length:
            del self._path.poses[: len(self._path.poses) - node.path.max_length]
        now = time.monotonic()  # the whole path is O(length): only when watched, throttled
        if (
            self._pub_path.get_subscription_count() > 0
            and now - self._path_published >= node.path.publish_period
        ):
            self._path_published = now
            self._pub_path.publish(self._path)

    def _publish_local_map(self, scan: Scan, node: NodeConfig) -> None:
        """Publish the local map, at most every ``local_map_period`` s and only if watched."""
        now = time.monotonic()
        if (
            node.local_map_period <= 0.0
            or self._pub_local_map.get_subscription_count() == 0
            or now - self._local_map_published < node.local_map_period
        ):
            return
        self._local_map_published = now
        header = Header(stamp=scan.stamp, frame_id=node.odom_frame)
        self._pub_local_map.publish(
            arrays_to_pointcloud2(
                PointCloud2, PointField, header, self._odometry.local_map.points()
            )
        )

    def _publish_markers(
        self, scan: Scan, result: RegistrationResult, current: PreparedScan, node: NodeConfig
    ) -> None:
        if self._pub_markers.get_subscription_count() == 0:
            return  # nobody looks: do not build thousands of points
        header = Header(stamp=scan.stamp, frame_id=scan.frame_id)
        self._pub_markers.publish(
            correspondence_markers(
                header,
                result,
                current.landmarks,
                self._label_map.names,
                publish_outliers=node.publish_outliers,
                max_lines=MAX_MARKER_LINES,
            )
        )

    def _skip(self, stamp: Time, reason: str) -> None:
        """Count, log (throttled) and report a scan that cannot be used."""
        self._count('frames_malformed')
        self.get_logger().warning(reason, throttle_duration_sec=LOG_THROTTLE_S)
        self._publish_diagnostics(stamp, 'warn', reason, {})

    def _diagnose(
        self,
        scan: Scan,
        level: str,
        message: str,
        step: OdometryStep,
        latency_ms: float | None = None,
        predicted: bool = False,
    ) -> None:
        """Report one processed frame: counts, latency, stage timings, result summary."""
        values: dict[str, Any] = {'startup.' + k: v for k, v in self._startup_ms.items()}
        values.update(
            {
                'dropped_nonfinite_points': scan.dropped_nonfinite,
                'keyframe_stamp': f'{1e-9 * step.keyframe_stamp_ns:.9f}',
                'processing_ms': step.latency_ms,
                'frame_index': step.index,
            }
        )
        if latency_ms is not None:
            values['latency_ms'] = latency_ms
            values['latency_p50_ms'] = float(np.median(self._latencies))
        values.update({f'stage.{k}': float(v) for k, v in step.timings_ms.items()})
        values.update({'pose_source': step.source, 'local_map_voxels': step.map_voxels})
        update = self._map_update
        if update is not None and (update.event or update.message):  # ros/map_services.py
            values.update({'map.event': update.event, 'map.message': update.message})
        if not step.accepted:  # a refused scan: what went out instead (ros/outputs.py)
            values['published'] = 'prediction' if predicted else 'nothing'
        if step.prior_refusal:  # the prior disagreed with the scan (core/odometry/prior_guard.py)
            self._count('prior_refused')
            values['prior_refusal'] = step.prior_refusal
        if step.deskew_refusal:  # the deskew bent the scan (core/odometry/deskew_guard.py)
            self._count('deskew_refused')
            values['deskew_refusal'] = step.deskew_refusal
        if scan.time_warning:  # registered without deskew: a warning (docs/ros_interface.md)
            values['point_times_warning'] = scan.time_warning
            level, message = ('warn' if level == 'ok' else level), f'{message}; not deskewed'
        if step.prepared is not None:  # dropped points, label scheme, out-of-scheme labels
            values.update({f'input.{k}': v for k, v in step.prepared.input_stats.items()})
            values['label_source'] = step.prepared.input_stats.get('label_source', '')
        for candidate in step.candidates:
            values[f'fine.{candidate.name}.inlier_fraction'] = candidate.alignment.inlier_fraction
            if candidate.refusal:
                values[f'fine.{candidate.name}.refused'] = candidate.refusal
        if step.result is None and step.source == 'prediction':
            values['mode'] = 'tracking'  # the refined prediction alone, no global registration
        if step.result is not None:
            result = step.result
            values.update(
                {
                    'mode': result.mode,
                    'num_inliers': result.num_inliers,
                    'correspondences': len(result.correspondences),
                }
            )
            values.update(
                {
                    k: v
                    for k, v in result.diagnostics.items()
                    if isinstance(v, (bool, int, float, str))
                }
            )
            if result.message:
                values['note'] = result.message
        self._publish_diagnostics(scan.stamp, level, message, values)

    def _publish_diagnostics(
        self, stamp: Time, level: str, message: str, values: dict[str, Any]
    ) -> None:
        with self._lock:
            counts = dict(self._counts)
        values = {
            'scan_stamp': f'{stamp_to_seconds(stamp):.9f}',
            'frames_dropped': self._slot.dropped,
            'frames_lost_estimate': self._stream.lost,
            **counts,
            **self.callback_drops.snapshot(STREAMS),
            **values,
        }
        self._pub_diagnostics.publish(
            messages.diagnostics_msg(
                self.get_clock().now().to_msg(),
                f'{self.get_name()}: registration',
                self.get_fully_qualified_name(),
                level,
                message,
                values,
            )
        )

    def _count(self, key: str) -> None:
        with self._lock:
            self._counts[key] += 1

    def _entities(self) -> list[tuple[Any, Any]]:
        """(destroy, entity) of every publisher, subscription, service, client and timer."""
        kinds = (
            (self.destroy_publisher, self.publishers),
            (self.destroy_subscription, self.subscriptions),
            (self.destroy_service, self.services),
            (self.destroy_client, self.clients),
            (self.destroy_timer, self.timers),
        )
        return [(destroy, entity) for destroy, entities in kinds for entity in entities]

    def _teardown(self) -> None:
        """Stop the worker (it finishes its frame) and destroy what :meth:`_setup` made."""
        if not self._configured:
            return
        self._configured = False
        self._slot.close()
        self._worker.join(timeout=5.0)
        self._map.close()
        for destroy, entity in reversed(self._created):
            destroy(entity)
        self._created = []

    def destroy_node(self) -> None:
        """Stop the worker (it finishes its frame), then destroy the node."""
        if self._configured:
            self._slot.close()
            self._worker.join(timeout=5.0)
            self._map.close()
            self._configured = False
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Console script ``mlsemreg_node``; returns the process exit code (:func:`run`)."""
    return run(MlSemRegNode, args)


def run(node_class: type[MlSemRegNode], args: list[str] | None = None) -> int:
    """
    Spin a ``node_class`` node until SIGINT / SIGTERM; return the process exit code.

    SIGINT and SIGTERM are handled here, not by rclpy: a Python handler sets a flag and the
    spin loop, which wakes every ``SPIN_PERIOD_S``, stops on it. (With rclpy's own handlers
    a SIGTERM that arrived right after start-up was sometimes lost under load, and the node
    spun on; measured in test_colcon's stop test with the CPUs busy.)
    """
    stop = threading.Event()
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    for sig in handlers:
        signal.signal(sig, lambda *_: stop.set())
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        node = node_class()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        spin_guarded(  # the last line: a raising callback is logged and counted
            executor,
            lambda: not stop.is_set() and rclpy.ok(),
            node.callback_drops,
            SPIN_PERIOD_S,
        )
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ConfigError, ParameterException) as error:
        rclpy.logging.get_logger(NODE_NAME).fatal(f'invalid parameters: {error}')
        return 1
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
