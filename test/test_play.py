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

"""mlsemreg-play: every message of a bag reaches an rclpy subscriber, in order, intact."""

from __future__ import annotations

import os
from pathlib import Path
import subprocess
import sys
import time
from typing import Any

from mlsemreg_ros.codec.pointcloud2 import pointcloud2_to_arrays
from mlsemreg_ros.datasets.bag import BagWriter
import numpy as np
import pytest
from ros_domains import domain_id

pytestmark = pytest.mark.slow  # a player process per test (rclpy: see conftest.py)
DOMAIN_ID = domain_id('play')
START_NS = 1_700_000_000 * 10**9
N_CLOUDS = 12


def _player(path: Path, env: dict[str, str], *options: str) -> subprocess.Popen:
    """Start ``mlsemreg_ros.tools.play PATH OPTIONS`` with ``env``, output piped."""
    return subprocess.Popen(
        [sys.executable, '-m', 'mlsemreg_ros.tools.play', str(path), *options],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )


@pytest.fixture
def bag(tmp_path: Path) -> tuple[Path, list[np.ndarray]]:
    rng = np.random.default_rng(0)
    clouds = []
    path = tmp_path / 'bag'
    with BagWriter(path, storage='mcap') as writer:
        for k in range(N_CLOUDS):
            xyz = rng.uniform(-10, 10, size=(200 + k, 3)).astype(np.float32).astype(np.float64)
            stamp = START_NS + k * 20_000_000  # 50 Hz
            writer.write_cloud(
                stamp, xyz, np.full(len(xyz), 40 + k, np.uint32), topic='/test_play/points'
            )
            pose = np.eye(4)
            pose[0, 3] = k
            writer.write_odometry(stamp, pose, topic='/test_play/odom')
            clouds.append(xyz)
    return path, clouds


def test_player_delivers_every_message_to_a_subscriber(
    bag: tuple[Path, list[np.ndarray]], rclpy_module: Any, ros_context: Any
) -> None:
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import PointCloud2

    path, clouds = bag
    received: dict[str, list[Any]] = {'points': [], 'odom': [], 'clock': []}
    with ros_context(DOMAIN_ID) as context:
        node = rclpy_module.create_node('test_play_subscriber', context=context)
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        node.create_subscription(PointCloud2, '/test_play/points', received['points'].append, qos)
        node.create_subscription(Odometry, '/test_play/odom', received['odom'].append, qos)
        node.create_subscription(Clock, '/clock', received['clock'].append, 10)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID))
        start = time.monotonic()
        player = _player(
            path, env, '--rate', '1', '--clock', '--wait-for-subscribers', '1', '--quiet'
        )
        deadline = start + 45.0
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
            if (
                len(received['points']) == N_CLOUDS
                and len(received['odom']) == N_CLOUDS
                and player.poll() is not None
            ):
                break
        for _ in range(10):
            executor.spin_once(timeout_sec=0.02)
        output = player.communicate(timeout=30)[0].decode()
        assert player.returncode == 0, output
    assert len(received['points']) == N_CLOUDS, output
    assert len(received['odom']) == N_CLOUDS
    # /clock is matched by discovery on its own: under load its first ticks can be missed
    assert len(received['clock']) >= 3
    for k, msg in enumerate(received['points']):
        cloud = pointcloud2_to_arrays(msg)
        np.testing.assert_array_equal(cloud.xyz, clouds[k])
        assert np.all(cloud.labels == 40 + k)
        assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == START_NS + k * 20_000_000
    assert [m.pose.pose.position.x for m in received['odom']] == list(range(N_CLOUDS))
    clock_ns = [c.clock.sec * 10**9 + c.clock.nanosec for c in received['clock']]
    assert min(clock_ns) >= START_NS and clock_ns == sorted(clock_ns)
    assert max(clock_ns) >= START_NS + (N_CLOUDS - 1) * 20_000_000  # it reached the last cloud


def test_pace_topic_holds_playback_until_a_slow_consumer_answered(
    bag: tuple[Path, list[np.ndarray]], rclpy_module: Any, ros_context: Any
) -> None:
    """A consumer keeping only the latest cloud and answering after 0.2 s gets every cloud."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    path, _ = bag
    received: list[int] = []
    with ros_context(DOMAIN_ID) as context:
        node = rclpy_module.create_node('test_play_slow_consumer', context=context)
        answer = node.create_publisher(DiagnosticArray, '/test_play/answer', 10)

        def on_cloud(msg: PointCloud2) -> None:
            time.sleep(0.2)  # slow work
            received.append(msg.header.stamp.nanosec)
            answer.publish(DiagnosticArray())

        latest_only = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
        node.create_subscription(PointCloud2, '/test_play/points', on_cloud, latest_only)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID))
        player = _player(
            path,
            env,
            *('--rate', '0', '--topics', '/test_play/points'),
            *('--pace-topic', '/test_play/answer', '--wait-for-subscribers', '1', '--quiet'),
        )
        deadline = time.monotonic() + 45.0
        while time.monotonic() < deadline:
            if len(received) == N_CLOUDS and player.poll() is not None:
                break
            executor.spin_once(timeout_sec=0.05)
        output = player.communicate(timeout=30)[0].decode()
        assert player.returncode == 0, output
    assert len(received) == N_CLOUDS, output
    assert received == sorted(received)


def test_wait_for_subscribers_does_not_wait_for_topics_nobody_subscribes(
    bag: tuple[Path, list[np.ndarray]], rclpy_module: Any, ros_context: Any
) -> None:
    """
    A simulated bag's ground truth has no subscriber: playback starts once the clouds do.

    The player used to wait for a subscriber on every topic, so it played after its timeout
    (60 s here); now it waits for the clouds (and topics someone subscribes) only.
    """
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    path, _ = bag
    received: list[Any] = []
    with ros_context(DOMAIN_ID) as context:
        node = rclpy_module.create_node('test_play_clouds_only', context=context)
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        node.create_subscription(PointCloud2, '/test_play/points', received.append, qos)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID))
        start = time.monotonic()
        player = _player(path, env, '--wait-for-subscribers', '1', '--wait-timeout', '60')
        deadline = start + 90.0
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
            if len(received) == N_CLOUDS and player.poll() is not None:
                break
        elapsed = time.monotonic() - start
        output = player.communicate(timeout=30)[0].decode()
        assert player.returncode == 0, output
    assert len(received) == N_CLOUDS, output
    assert 'playing anyway' not in output
    assert elapsed < 30.0, f'{elapsed:.1f} s: the player waited for /test_play/odom\n{output}'
