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
``mlsemreg-bench-node``: per-frame latency of mlsemreg_node with default parameters.

Runs the node in-process (its own rclpy context and executor thread) and a
probe node that publishes the dev pairs (or the synthetic street when they are
absent) on ``points`` at a steady rate: per pair, reset, then dst, src, dst,
src, ... (every frame after the first is a registration, alternately T and
T^-1). Reported per frame:

- ``node_ms``: receipt of the scan in the node's callback -> publication of
  ``mlsemreg/transform``, measured inside the node (``latency_ms`` in
  ``/diagnostics``); this is the figure of the latency target (p50 <= 150 ms);
- ``e2e_ms``: the probe's ``publish()`` call -> receipt of the transform (adds
  DDS transport of the cloud and the executors' scheduling);
- ``processing_ms``: the core's share (prepare + register in
  ``core.odometry.Odometry.process``); ``node_ms - processing_ms`` is the ROS
  layer's overhead (conversion, hand-over, publishing).

The probe (:class:`NodeProbe`) is also what the node tests use to drive the node.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
import contextlib
import json
import os
from pathlib import Path
import threading
import time
from typing import Any

import numpy as np

DEV_PAIRS = Path(__file__).resolve().parents[3] / 'shared' / 'data' / 'kitti_pairs_dev'


def dev_pairs_dir() -> Path:
    """Return the KITTI dev pairs directory (env MLSEMREG_DEV_PAIRS overrides the default)."""
    return Path(os.environ.get('MLSEMREG_DEV_PAIRS', DEV_PAIRS))


def load_pairs(directory: Path | None, limit: int) -> list[Any]:
    """Up to ``limit`` pairs from ``directory``; the synthetic street if it holds none."""
    from mlsemreg_ros.datasets.pairs import list_pairs, load_pair
    from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair

    if directory is not None and directory.is_dir() and list_pairs(directory):
        return [load_pair(p) for p in list_pairs(directory)[:limit]]
    return [synthetic_pair(seed) for seed in range(limit)]


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

    def __init__(self, context: Any, name: str = 'mlsemreg_probe', target: str = 'mlsemreg_node'
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
            PointCloud2, 'points', QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        topics = {'transform': ('mlsemreg/transform', TransformStamped),
                  'odometry': ('mlsemreg/odometry', Odometry),
                  'path': ('mlsemreg/path', PathMsg),
                  'markers': ('mlsemreg/correspondences', MarkerArray),
                  'diagnostics': ('/diagnostics', DiagnosticArray)}
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
            if (self._publisher.get_subscription_count() > 0
                    and all(self.node.count_publishers(t) > 0 for t in self._topics)
                    and self._reset.service_is_ready()):
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
        return self.wait_until(lambda: next(
            (m for _, m in self.received['markers']
             if m.markers and stamp_key(m.markers[-1].header.stamp) == want), None), timeout)

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
                            return {**values, 'level': int.from_bytes(status.level, 'little'),
                                    'message': status.message}
                        seen += 1
            return None
        return self.wait_until(lookup, timeout)

    # -- acting -----------------------------------------------------------------------------
    def cloud(self, points: np.ndarray, labels: np.ndarray | None, stamp: Any,
              frame_id: str = 'velodyne', label_datatype: str = 'uint32') -> Any:
        """Build a PointCloud2 message of the scan (labels stored as ``label_datatype``)."""
        from mlsemreg_ros.codec.pointcloud2 import arrays_to_pointcloud2
        from std_msgs.msg import Header

        return arrays_to_pointcloud2(*self._msg_classes, Header(stamp=stamp, frame_id=frame_id),
                                     points, labels, label_datatype=label_datatype)

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
def node_and_probe(domain_id: int | None = None, args: list[str] | None = None
                   ) -> Iterator[tuple[Any, NodeProbe]]:
    """Run mlsemreg_node and a NodeProbe in a private rclpy context (executor thread)."""
    from mlsemreg_ros.ros.node import MlSemRegNode
    import rclpy
    from rclpy.executors import MultiThreadedExecutor

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id, args=args)
    executor = MultiThreadedExecutor(num_threads=2, context=context)
    node = probe = None
    try:
        node = MlSemRegNode(context=context)
        probe = NodeProbe(context)
        executor.add_node(node)
        executor.add_node(probe.node)
        spinner = threading.Thread(target=executor.spin, daemon=True)
        spinner.start()
        if not probe.wait_connected():
            raise RuntimeError('probe and node did not discover each other within 20 s')
        yield node, probe
    finally:
        executor.shutdown(timeout_sec=5.0)
        if probe is not None:
            probe.node.destroy_node()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def percentile(values: list[float], q: float) -> float:
    """Percentile (NaN when empty)."""
    return float(np.percentile(values, q)) if values else float('nan')


def bench(pairs: list[Any], repeats: int, rate_hz: float, probe: NodeProbe) -> list[dict]:
    """Publish every pair as reset, dst, src, dst, ... at ``rate_hz``; one record per frame."""
    period, records, stamp_s = 1.0 / rate_hz, [], 1000.0
    for pair in pairs:
        if not probe.reset():
            raise RuntimeError('mlsemreg/reset did not answer')
        scans = [(pair.pts_dst, pair.label_dst), (pair.pts_src, pair.label_src)]
        for frame in range(2 * repeats + 1):
            points, labels = scans[frame % 2]
            stamp_s += period
            stamp = to_stamp(stamp_s)
            msg = probe.cloud(points, np.asarray(labels).astype(np.uint32), stamp)
            tick = time.perf_counter()
            published = probe.publish(msg)
            status = probe.status_for(stamp, timeout=30.0)
            if frame > 0:
                found = probe.wait_until(lambda s=stamp: probe.find('transform', s), 0.5)
                records.append({
                    'pair': pair.name, 'frame': frame,
                    'node_ms': float(status['latency_ms']) if status and 'latency_ms' in status
                    else None,
                    'e2e_ms': 1e3 * (found[0] - published) if found else None,
                    'processing_ms': float(status['processing_ms']) if status else None,
                    'success': found is not None,
                    **_errors(found[1] if found else None, pair.trans_gt, frame),
                    'stages_ms': {k[6:]: float(v) for k, v in (status or {}).items()
                                  if k.startswith('stage.')},
                })
            time.sleep(max(0.0, period - (time.perf_counter() - tick)))
    return records


def _errors(message: Any, truth: np.ndarray | None, frame: int) -> dict[str, Any]:
    """RE (deg), TE (m) of a transform message against the pair's ground truth."""
    if message is None or truth is None:
        return {}
    from mlsemreg_ros.core.metrics import rotation_error_deg, translation_error_m
    from scipy.spatial.transform import Rotation

    transform = message.transform
    estimate = np.eye(4)
    r = transform.rotation
    estimate[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
    t = transform.translation
    estimate[:3, 3] = (t.x, t.y, t.z)
    # odd frames register src onto the dst keyframe (trans_gt), even ones the reverse
    expected = truth if frame % 2 else np.linalg.inv(truth)
    rotation_error = rotation_error_deg(estimate[:3, :3], expected[:3, :3])
    translation_error = translation_error_m(estimate[:3, 3], expected[:3, 3])
    return {'rotation_error_deg': rotation_error, 'translation_error_m': translation_error,
            'correct': bool(rotation_error < 5.0 and translation_error < 0.6)}


def parameter_overrides(items: list[str]) -> list[str] | None:
    """``['a.b=1', ...]`` -> rclpy args ``['--ros-args', '-p', 'a.b:=1', ...]`` (None if empty)."""
    if not items:
        return None
    args = ['--ros-args']
    for item in items:
        name, separator, value = item.partition('=')
        if not separator or not name:
            raise SystemExit(f'mlsemreg-bench-node: --set expects NAME=VALUE, got {item!r}')
        args += ['-p', f'{name}:={value}']
    return args


def summary(records: list[dict]) -> dict[str, Any]:
    """p50/p95/mean of node and end-to-end latency, stage medians, success rate."""
    out: dict[str, Any] = {'frames': len(records),
                           'registered': sum(r['success'] for r in records),
                           'correct': sum(r.get('correct', False) for r in records)}
    for key in ('node_ms', 'e2e_ms', 'processing_ms'):
        values = [r[key] for r in records if r[key] is not None]
        out[key] = {'p50': percentile(values, 50), 'p95': percentile(values, 95),
                    'mean': float(np.mean(values)) if values else float('nan')}
    stages = sorted({k for r in records for k in r['stages_ms']})
    out['stage_p50_ms'] = {s: percentile([r['stages_ms'][s] for r in records
                                          if s in r['stages_ms']], 50) for s in stages}
    return out


def main(argv: list[str] | None = None) -> int:
    """Command line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--pairs', type=Path, default=None,
                        help='directory of pair files (default: the KITTI dev pairs; the '
                             'synthetic street when absent)')
    parser.add_argument('--synthetic', action='store_true', help='use the synthetic street')
    parser.add_argument('--limit', type=int, default=10, help='pairs to use (default 10)')
    parser.add_argument('--repeats', type=int, default=2,
                        help='registrations per pair and direction (default 2)')
    parser.add_argument('--rate', type=float, default=2.0, help='publish rate, Hz (default 2)')
    parser.add_argument('--domain-id', type=int, default=None,
                        help='ROS domain id (default: ROS_DOMAIN_ID)')
    parser.add_argument('--json', type=Path, default=None, help='write records + summary here')
    parser.add_argument('--set', action='append', default=[], metavar='NAME=VALUE',
                        help='override a node parameter, e.g. keypoints.count=2000 (repeatable)')
    args = parser.parse_args(argv)
    directory = None if args.synthetic else (args.pairs or dev_pairs_dir())
    pairs = load_pairs(directory, args.limit)
    print(f'{len(pairs)} pair(s) from {directory if directory else "the synthetic street"}; '
          f'{args.repeats} x 2 registrations each at {args.rate:g} Hz')
    if args.set:
        print('parameters: ' + ', '.join(args.set))
    with node_and_probe(args.domain_id, parameter_overrides(args.set)) as (_, probe):
        records = bench(pairs, args.repeats, args.rate, probe)
    result = summary(records)
    print(f'{"metric":<34}{"unit":>6}{"value":>10}')
    print(f'{"frames registered":<34}{"":>6}{result["registered"]:>6}/{result["frames"]}')
    print(f'{"  of them RE < 5 deg, TE < 0.6 m":<34}{"":>6}{result["correct"]:>6}/'
          f'{result["frames"]}')
    for key, label in (('node_ms', 'node latency'), ('e2e_ms', 'end-to-end latency'),
                       ('processing_ms', 'core prepare+register')):
        for q in ('p50', 'p95', 'mean'):
            print(f'{label + " " + q:<34}{"ms":>6}{result[key][q]:>10.1f}')
    for stage, ms in result['stage_p50_ms'].items():
        print(f'{"  stage " + stage + " p50":<34}{"ms":>6}{ms:>10.1f}')
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({'summary': result, 'records': records}, indent=2))
        print(f'wrote {args.json}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
