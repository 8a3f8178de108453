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
A probe node that drives mlsemreg_node: publishes scans, records every output, sets params.

Used by ``mlsemreg bench-node`` and the node tests: :func:`node_and_probe` runs the node and
a :class:`NodeProbe` in a private rclpy context with an executor thread.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
import contextlib
import threading
import time
from typing import Any

import numpy as np


def stamp_key(stamp: Any) -> tuple[int, int]:
    """Turn a builtin_interfaces/Time into a hashable (sec, nanosec)."""
    return int(stamp.sec), int(stamp.nanosec)


def to_stamp(seconds: float) -> Any:
    """Seconds -> builtin_interfaces/Time."""
    from builtin_interfaces.msg import Time

    sec = int(seconds)
    return Time(sec=sec, nanosec=round((seconds - sec) * 1e9))


class NodeProbe:
    """
    Publishes scans to mlsemreg_node and records everything it publishes.

    Wraps an rclpy Node (``self.node``) created in ``context``; its callbacks only
    append to lists under a condition variable, so tests can wait for a message
    with a given stamp from any thread.
    """

    def __init__(
        self, context: Any, name: str = 'mlsemreg_probe', target: str = 'mlsemreg_node'
    ) -> None:
        """Create publishers, subscriptions, the reset client and a parameter client."""
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import TransformStamped
        from nav_msgs.msg import Odometry
        from nav_msgs.msg import Path as PathMsg
        from rclpy.node import Node
        from rclpy.parameter_client import AsyncParameterClient
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import PointCloud2, PointField
        from std_srvs.srv import Trigger
        from visualization_msgs.msg import MarkerArray

        self.node = Node(name, context=context)
        self._msg_classes = (PointCloud2, PointField)
        self._cond = threading.Condition()
        self.received: dict[str, list[tuple[float, Any]]] = {}
        self._publisher = self.node.create_publisher(
            PointCloud2, 'points', QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        )
        topics = {
            'transform': ('mlsemreg/transform', TransformStamped),
            'odometry': ('mlsemreg/odometry', Odometry),
            'path': ('mlsemreg/path', PathMsg),
            'markers': ('mlsemreg/correspondences', MarkerArray),
            'diagnostics': ('/diagnostics', DiagnosticArray),
        }
        for key, (topic, cls) in topics.items():
            self.received[key] = []
            self.node.create_subscription(cls, topic, self._recorder(key), 10)
        self._topics = [topic for topic, _ in topics.values()]
        self._reset = self.node.create_client(Trigger, 'mlsemreg/reset')
        self._trigger = Trigger
        self.parameters = AsyncParameterClient(self.node, target)

    def _recorder(self, key: str) -> Callable[[Any], None]:
        def record(msg: Any) -> None:
            with self._cond:
                self.received[key].append((time.perf_counter(), msg))
                self._cond.notify_all()

        return record

    # -- waiting -------------------------------------------------------------------------
    def wait_until(self, predicate: Callable[[], Any], timeout: float) -> Any:
        """Wait until ``predicate()`` (evaluated under the lock) is truthy; return its value."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while not (value := predicate()):
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self._cond.wait(min(remaining, 0.1))
            return value

    def wait_connected(self, timeout: float = 20.0) -> bool:
        """Wait until the node subscribes to ``points`` and publishes every output topic."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if (
                self._publisher.get_subscription_count() > 0
                and all(self.node.count_publishers(t) > 0 for t in self._topics)
                and self._reset.service_is_ready()
            ):
                return True
            time.sleep(0.05)
        return False

    def find(self, key: str, stamp: Any, after: float = 0.0) -> tuple[float, Any] | None:
        """First recorded (time, message) of ``key`` with that header stamp (call under lock)."""
        want = stamp_key(stamp)
        for t, msg in self.received[key]:
            if t >= after and stamp_key(msg.header.stamp) == want:
                return t, msg
        return None

    def wait_for(self, key: str, stamp: Any, timeout: float) -> Any:
        """Return the message of ``key`` stamped ``stamp``, or None after ``timeout`` s."""
        found = self.wait_until(lambda: self.find(key, stamp), timeout)
        return found[1] if found else None

    def markers_for(self, stamp: Any, timeout: float) -> Any:
        """Return the MarkerArray drawn for the scan stamped ``stamp``."""
        want = stamp_key(stamp)
        return self.wait_until(
            lambda: next(
                (
                    m
                    for _, m in self.received['markers']
                    if m.markers and stamp_key(m.markers[-1].header.stamp) == want
                ),
                None,
            ),
            timeout,
        )

    def status_for(self, stamp: Any, timeout: float, skip: int = 0) -> dict[str, str] | None:
        """
        Return the node's diagnostics of the scan stamped ``stamp`` (+ level, message).

        ``skip``: ignore the first ``skip`` reports of that stamp (a stamp sent twice).
        """
        want = f'{stamp.sec + 1e-9 * stamp.nanosec:.9f}'

        def lookup() -> dict[str, str] | None:
            seen = 0
            for _, msg in self.received['diagnostics']:
                for status in msg.status:
                    values = {kv.key: kv.value for kv in status.values}
                    if values.get('scan_stamp') == want:
                        if seen == skip:
                            return {
                                **values,
                                'level': int.from_bytes(status.level, 'little'),
                                'message': status.message,
                            }
                        seen += 1
            return None

        return self.wait_until(lookup, timeout)

    # -- acting -----------------------------------------------------------------------------
    @staticmethod
    def stamp(seconds: float) -> Any:
        """Seconds -> builtin_interfaces/Time (for the scans the probe publishes)."""
        return to_stamp(seconds)

    def cloud(
        self,
        points: np.ndarray,
        labels: np.ndarray | None,
        stamp: Any,
        frame_id: str = 'velodyne',
        label_datatype: str = 'uint32',
    ) -> Any:
        """Build a PointCloud2 message of the scan (labels stored as ``label_datatype``)."""
        from mlsemreg_ros.codec.pointcloud2 import arrays_to_pointcloud2
        from std_msgs.msg import Header

        return arrays_to_pointcloud2(
            *self._msg_classes,
            Header(stamp=stamp, frame_id=frame_id),
            points,
            labels,
            label_datatype=label_datatype,
        )

    def publish(self, msg: Any) -> float:
        """Publish on ``points``; returns the perf_counter time of the call."""
        start = time.perf_counter()
        self._publisher.publish(msg)
        return start

    def reset(self, timeout: float = 10.0) -> bool:
        """Call mlsemreg/reset; True on success."""
        future = self._reset.call_async(self._trigger.Request())
        return bool(self.wait_until(lambda: future.done(), timeout)) and future.result().success

    def set_parameters(self, values: dict[str, Any], timeout: float = 10.0) -> list[Any]:
        """Set parameters over the ROS parameter service; one SetParametersResult each."""
        from rclpy.parameter import Parameter

        params = [Parameter(k, value=v) for k, v in values.items()]
        future = self.parameters.set_parameters(params)
        if not self.wait_until(lambda: future.done(), timeout):
            raise TimeoutError(f'set_parameters({values}) timed out')
        return list(future.result().results)

    def get_parameters(self, names: list[str], timeout: float = 10.0) -> list[Any]:
        """Get current values over the ROS parameter service (as Python values)."""
        from rclpy.parameter import parameter_value_to_python

        future = self.parameters.get_parameters(names)
        if not self.wait_until(lambda: future.done(), timeout):
            raise TimeoutError(f'get_parameters({names}) timed out')
        return [parameter_value_to_python(v) for v in future.result().values]


@contextlib.contextmanager
def node_and_probe(
    domain_id: int | None = None, args: list[str] | None = None
) -> Iterator[tuple[Any, NodeProbe]]:
    """Run mlsemreg_node and a NodeProbe in a private rclpy context (executor thread)."""
    from mlsemreg_ros.ros.node import MlSemRegNode
    import rclpy
    from rclpy.executors import MultiThreadedExecutor

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id, args=args)
    from mlsemreg_ros.ros.callback_guard import spin_guarded

    executor = MultiThreadedExecutor(num_threads=2, context=context)
    node = probe = None
    stop = threading.Event()
    try:
        node = MlSemRegNode(context=context)
        probe = NodeProbe(context)
        executor.add_node(node)
        executor.add_node(probe.node)
        spinner = threading.Thread(  # guarded as in the node's main()
            target=spin_guarded,
            args=(executor, lambda: not stop.is_set() and context.ok(), node.callback_drops),
            daemon=True,
        )
        spinner.start()
        if not probe.wait_connected():
            raise RuntimeError('probe and node did not discover each other within 20 s')
        yield node, probe
    finally:
        stop.set()
        executor.shutdown(timeout_sec=5.0)
        if probe is not None:
            probe.node.destroy_node()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


@contextlib.contextmanager
def probe_only(domain_id: int | None = None) -> Iterator[NodeProbe]:
    """Run a NodeProbe alone in a private rclpy context (the node runs elsewhere)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    executor = SingleThreadedExecutor(context=context)
    probe = None
    try:
        probe = NodeProbe(context)
        executor.add_node(probe.node)
        threading.Thread(target=executor.spin, daemon=True).start()
        if not probe.wait_connected(timeout=60.0):
            raise RuntimeError('the probe did not discover mlsemreg_node within 60 s')
        yield probe
    finally:
        executor.shutdown(timeout_sec=5.0)
        if probe is not None:
            probe.node.destroy_node()
        rclpy.try_shutdown(context=context)
