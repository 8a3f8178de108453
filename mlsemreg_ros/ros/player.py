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
A bag player on rclpy (a stand-in for ``ros2 bag play``), used by ``mlsemreg play`` and the demo.

Messages are read with ``rosbags`` (mcap or sqlite3) and published as their stored CDR
bytes (``Publisher.publish(bytes)``: no conversion) at the recorded rate times
``rate``, in recording order; ``clock`` also publishes ``/clock``
(rosgraph_msgs/Clock) with the bag time. Publishers are reliable with a deep history
so a subscriber that keeps up receives every message; ``wait_for_subscribers`` holds
playback until the topics someone consumes are subscribed (:meth:`Player.wait_for_subscribers`:
the clouds, or ``wait_topics``; a simulated bag's ground truth and IMU, which a
registration node need not subscribe, hold nothing); ``pace_topic`` makes playback wait,
after each cloud, for one answer of a slower consumer (e.g. the registration node's
``/diagnostics``), so none is dropped.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
import importlib
from pathlib import Path
import time
from typing import Any

from mlsemreg_ros.codec.stamps import stamp_to_ns

#: Name ending of the node's heartbeat status (``ros/outputs.py``), not an answer to a scan.
HEARTBEAT_SUFFIX = ': heartbeat'


def message_class(msgtype: str) -> type:
    """Import the rclpy message class of ``pkg/msg/Type`` (ImportError if not installed)."""
    package, kind, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)


@dataclass
class PlayOptions:
    """Playback settings."""

    rate: float = 1.0  # playback speed factor; <= 0 publishes as fast as possible
    topics: Sequence[str] | None = None  # only these topics (default: all)
    clock: bool = False  # publish /clock with the bag time
    clock_rate: float = 100.0  # Hz of /clock between messages
    loop: bool = False
    delay: float = 0.0  # seconds to sleep before the first message
    wait_for_subscribers: int = 0  # hold until the waited topics have this many subscribers
    wait_timeout: float = 30.0  # seconds, for wait_for_subscribers
    # the topics wait_for_subscribers waits for (default: the bag's PointCloud2 topics, or
    # every topic of a bag without clouds)
    wait_topics: Sequence[str] | None = None
    qos_depth: int = 1000
    quiet: bool = False
    # Pacing (for consumers slower than the recording, e.g. a registration node):
    # after each PointCloud2 message, wait for one message on pace_topic.
    pace_topic: str | None = None
    pace_type: str = 'diagnostic_msgs/msg/DiagnosticArray'
    pace_timeout: float = 60.0  # seconds to wait for the answer before going on


class Player:
    """Publishes the messages of one bag on a node (create, then :meth:`run`)."""

    def __init__(
        self,
        node: Any,
        bag: str | Path,
        options: PlayOptions | None = None,
        answered: Callable[[int], bool] | None = None,
    ) -> None:
        """
        Open the bag and create one publisher per topic on ``node``.

        ``answered(stamp_ns)`` (optional, for callers that spin their own
        subscriptions) replaces ``pace_topic``: after each PointCloud2 message the
        player waits until it returns True for the message's header stamp.
        """
        from mlsemreg_ros.datasets.bag import open_reader
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        self.node = node
        self.options = options if options is not None else PlayOptions()
        self.reader = open_reader(bag)
        wanted = set(self.options.topics) if self.options.topics else None
        self.connections = []
        self.publishers: dict[str, Any] = {}
        for connection in self.reader.connections:
            if wanted is not None and connection.topic not in wanted:
                continue
            if connection.topic not in self.publishers:
                try:
                    cls = message_class(connection.msgtype)
                except (ImportError, AttributeError, ValueError):
                    node.get_logger().warning(
                        f'skipping {connection.topic}: message type '
                        f'{connection.msgtype} is not installed'
                    )
                    continue
                durability = (
                    DurabilityPolicy.TRANSIENT_LOCAL
                    if connection.topic == '/tf_static'
                    else DurabilityPolicy.VOLATILE
                )
                qos = QoSProfile(
                    history=HistoryPolicy.KEEP_LAST,
                    depth=self.options.qos_depth,
                    reliability=ReliabilityPolicy.RELIABLE,
                    durability=durability,
                )
                self.publishers[connection.topic] = node.create_publisher(
                    cls, connection.topic, qos
                )
            self.connections.append(connection)
        if wanted is not None:
            missing = sorted(wanted - set(self.publishers))
            if missing:
                node.get_logger().warning(f'topics not in the bag: {missing}')
        self.clock_publisher = None
        if self.options.clock:
            from rosgraph_msgs.msg import Clock

            self.clock_publisher = node.create_publisher(Clock, '/clock', 10)
        self.published = 0
        self._last_clock = 0
        self._answered = answered
        self._pace_count = 0
        self._pace_executor = None
        if answered is None and self.options.pace_topic:
            from rclpy.executors import SingleThreadedExecutor

            node.create_subscription(
                message_class(self.options.pace_type), self.options.pace_topic, self._on_pace, 100
            )
            self._pace_executor = SingleThreadedExecutor(context=node.context)
            self._pace_executor.add_node(node)
        self._paced = {
            c.topic for c in self.connections if c.msgtype == 'sensor_msgs/msg/PointCloud2'
        }

    def close(self) -> None:
        """Close the bag."""
        if self._pace_executor is not None:
            self._pace_executor.shutdown()
        self.reader.close()

    def _on_pace(self, msg: Any) -> None:
        statuses = getattr(msg, 'status', None)
        if statuses and all(s.name.endswith(HEARTBEAT_SUFFIX) for s in statuses):
            return  # the node's 1 Hz heartbeat answers no scan (ros/outputs.py)
        self._pace_count += 1

    def _wait_answer(self, connection: Any, raw: Any, before: int) -> float:
        """Block until the consumer answered this message; returns the seconds waited."""
        start = time.monotonic()
        deadline = start + self.options.pace_timeout
        if self._answered is not None:
            stamp_ns = stamp_to_ns(self.reader.deserialize(raw, connection.msgtype).header.stamp)
            while not self._answered(stamp_ns) and time.monotonic() < deadline:
                time.sleep(0.005)
        else:
            while self._pace_count <= before and time.monotonic() < deadline:
                self._pace_executor.spin_once(timeout_sec=0.05)
        if time.monotonic() >= deadline:
            self.node.get_logger().warning(
                f'no answer within {self.options.pace_timeout:g} s; going on'
            )
        return time.monotonic() - start

    def waited_topics(self) -> list[str]:
        """Return the topics that :meth:`wait_for_subscribers` waits for."""
        if self.options.wait_topics:
            return [t for t in self.options.wait_topics if t in self.publishers]
        clouds = sorted(self._paced & set(self.publishers))
        return clouds if clouds else sorted(self.publishers)

    def wait_for_subscribers(self) -> bool:
        """
        Block until the waited topics have enough subscribers; False on timeout.

        Waited: ``wait_topics``, or else the bag's PointCloud2 topics (every topic when it has
        none). Any other topic that the graph shows a subscription for must be matched too,
        so its first messages are not lost; a topic nobody subscribes (a simulated bag's
        ground truth) holds nothing. The condition must hold twice, 0.2 s apart (discovery
        announces a node's subscriptions one by one).
        """
        needed = self.options.wait_for_subscribers
        if needed <= 0:
            return True
        waited = set(self.waited_topics())
        deadline = time.monotonic() + self.options.wait_timeout
        held_since = None
        while time.monotonic() < deadline:
            if self._subscribed(waited, needed):
                held_since = time.monotonic() if held_since is None else held_since
                if time.monotonic() - held_since >= 0.2:
                    return True
            else:
                held_since = None
            time.sleep(0.05)
        return False

    def _subscribed(self, waited: set[str], needed: int) -> bool:
        """Whether the waited topics, and every topic with a known subscription, are matched."""
        for topic, publisher in self.publishers.items():
            matched = publisher.get_subscription_count()
            if topic in waited:
                if matched < needed:
                    return False
            elif matched < min(needed, self.node.count_subscribers(topic)):
                return False
        return True

    def _publish_clock(self, bag_ns: int) -> None:
        """Publish /clock = ``bag_ns``, never going back in time."""
        from builtin_interfaces.msg import Time
        from rosgraph_msgs.msg import Clock

        bag_ns = max(int(bag_ns), self._last_clock)
        self._last_clock = bag_ns
        self.clock_publisher.publish(
            Clock(clock=Time(sec=bag_ns // 1_000_000_000, nanosec=bag_ns % 1_000_000_000))
        )

    def _sleep_until(
        self, wall_target: float, bag_start: int, wall_start: float, bag_target: int
    ) -> None:
        """Sleep until ``wall_target`` (monotonic), ticking /clock up to ``bag_target``."""
        rate = self.options.rate
        while True:
            now = time.monotonic()
            if now >= wall_target:
                return
            if self.clock_publisher is None:
                time.sleep(wall_target - now)
                return
            time.sleep(min(wall_target - now, 1.0 / self.options.clock_rate))
            elapsed_ns = int((time.monotonic() - wall_start) * rate * 1e9)
            self._publish_clock(min(bag_start + elapsed_ns, bag_target))

    def play_once(self) -> int:
        """Publish every message once, at the recorded rate x ``rate``; returns the count."""
        rate = self.options.rate
        count = 0
        bag_start = None
        self._last_clock = 0  # a new pass (loop) may restart the clock
        wall_start = time.monotonic()
        for connection, timestamp, raw in self.reader.messages(connections=self.connections):
            if bag_start is None:
                bag_start, wall_start = timestamp, time.monotonic()
            if rate > 0:
                target = wall_start + (timestamp - bag_start) / (rate * 1e9)
                self._sleep_until(target, bag_start, wall_start, timestamp)
            if self.clock_publisher is not None:
                self._publish_clock(timestamp)
            before = self._pace_count
            self.publishers[connection.topic].publish(bytes(raw))
            count += 1
            pacing = self._answered is not None or self._pace_executor is not None
            if pacing and connection.topic in self._paced:
                wall_start += self._wait_answer(connection, raw, before)  # keep the rate after
        self.published += count
        return count

    def run(self) -> int:
        """Wait for subscribers, delay, play (loop if asked); returns the messages published."""
        if not self.wait_for_subscribers():
            self.node.get_logger().warning(
                f'not every waited topic ({", ".join(self.waited_topics())}) has '
                f'{self.options.wait_for_subscribers} subscriber(s) after '
                f'{self.options.wait_timeout:g} s; playing anyway'
            )
        if self.options.delay > 0:
            time.sleep(self.options.delay)
        while True:
            count = self.play_once()
            if not self.options.quiet:
                self.node.get_logger().info(f'published {count} messages')
            if not self.options.loop or count == 0:
                break
        for publisher in self.publishers.values():  # let reliable queues drain
            try:
                publisher.wait_for_all_acked(_duration(5.0))
            except (AttributeError, RuntimeError):
                pass
        return self.published


def _duration(seconds: float) -> Any:
    from rclpy.duration import Duration

    return Duration(seconds=seconds)
