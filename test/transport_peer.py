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
The other process of test_transport.py: publishes or receives large clouds, best effort.

``python transport_peer.py pub --count N --bytes B`` waits for a subscriber, then publishes
N PointCloud2 of B bytes at 10 Hz (best effort, keep last 10); ``sub --count N`` receives
until N clouds arrived or the timeout, printing a JSON line ``{"cloud": [index, bytes]}``
per arrival (the index is the header stamp's seconds) and ``{"received": [...]}`` at the
end. The transport is whatever the environment says (``FASTRTPS_DEFAULT_PROFILES_FILE``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2, PointField

TOPIC = 'transport_test/points'
POINT_STEP = 16  # x y z float32, label uint32


def _qos() -> QoSProfile:
    return QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)


def _cloud(index: int, size: int) -> PointCloud2:
    points = size // POINT_STEP
    msg = PointCloud2()
    msg.header.stamp.sec = index
    msg.header.frame_id = 'lidar'
    msg.height, msg.width = 1, points
    msg.fields = [
        PointField(name=n, offset=4 * k, datatype=PointField.FLOAT32, count=1)
        for k, n in enumerate('xyz')
    ] + [PointField(name='label', offset=12, datatype=PointField.UINT32, count=1)]
    msg.point_step, msg.row_step = POINT_STEP, POINT_STEP * points
    msg.is_dense = True
    msg.data = np.full(POINT_STEP * points, index % 251, dtype=np.uint8).tobytes()
    return msg


def publish(count: int, size: int, timeout: float) -> int:
    """Wait for a subscriber, then publish ``count`` clouds of ``size`` bytes at 10 Hz."""
    node = rclpy.create_node('transport_test_publisher')
    publisher = node.create_publisher(PointCloud2, TOPIC, _qos())
    deadline = time.monotonic() + timeout
    while publisher.get_subscription_count() == 0:
        if time.monotonic() > deadline:
            print('no subscriber', file=sys.stderr)
            return 1
        time.sleep(0.05)
    time.sleep(1.0)  # the subscriber's locators (shared memory) settle
    for k in range(count):
        publisher.publish(_cloud(k, size))
        time.sleep(0.1)
    time.sleep(1.0)  # let the last samples leave before the participant goes
    node.destroy_node()
    return 0


def subscribe(count: int, timeout: float) -> int:
    """Receive until ``count`` clouds arrived or ``timeout`` s passed; print what arrived."""
    node = rclpy.create_node('transport_test_subscriber')
    received: list[tuple[int, int]] = []

    def on_cloud(msg: PointCloud2) -> None:
        received.append((msg.header.stamp.sec, len(msg.data)))
        print(json.dumps({'cloud': received[-1]}), flush=True)

    node.create_subscription(PointCloud2, TOPIC, on_cloud, _qos())
    print(json.dumps({'ready': True}), flush=True)
    deadline = time.monotonic() + timeout
    while len(received) < count and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    print(json.dumps({'received': received}), flush=True)
    node.destroy_node()
    return 0


def main() -> int:
    """Run the publisher or the subscriber."""
    parser = argparse.ArgumentParser()
    parser.add_argument('mode', choices=('pub', 'sub'))
    parser.add_argument('--count', type=int, default=10)
    parser.add_argument('--bytes', type=int, default=2 * 1024 * 1024)
    parser.add_argument('--timeout', type=float, default=20.0)
    args = parser.parse_args()
    rclpy.init()
    try:
        if args.mode == 'pub':
            return publish(args.count, args.bytes, args.timeout)
        return subscribe(args.count, args.timeout)
    finally:
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
