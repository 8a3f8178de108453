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
Play a bag to a running mlsemreg_node, paced by its diagnostics, and record what it says.

The recording (:class:`~mlsemreg_ros.evaluation.estimators.NodeRecording`) is scored by the
evaluation like any other estimator (``RecordedRunEstimator``): that is the demo.
"""

from __future__ import annotations

from pathlib import Path
import subprocess
import threading
import time

from mlsemreg_ros.codec.poses import pose_message_to_matrix, transform_message_to_matrix
from mlsemreg_ros.codec.stamps import parse_seconds, stamp_to_ns
from mlsemreg_ros.evaluation.estimators import NodeRecording
import numpy as np


def scan_stamps(bag: Path) -> np.ndarray:
    """Return the header stamps (F,) int64 ns of the bag's ``/points``, in bag order."""
    from mlsemreg_ros.datasets.bag import open_reader, POINTS_TOPIC

    reader = open_reader(bag)
    try:
        connections = [c for c in reader.connections if c.topic == POINTS_TOPIC]
        return np.array(
            [
                stamp_to_ns(reader.deserialize(raw, c.msgtype).header.stamp)
                for c, _, raw in reader.messages(connections=connections)
            ],
            dtype=np.int64,
        )
    finally:
        reader.close()


def record_and_play(
    bag: Path, domain_id: int, rate: float, timeout: float, node: subprocess.Popen, quiet: bool
) -> NodeRecording:
    """Play ``/points`` paced by the node's diagnostics and record what the node says."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import TransformStamped
    from mlsemreg_ros.datasets.bag import POINTS_TOPIC
    from mlsemreg_ros.ros.player import Player, PlayOptions
    from nav_msgs.msg import Odometry
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from tqdm import tqdm

    recording = NodeRecording(scan_stamps=np.sort(scan_stamps(bag)))
    progress = tqdm(total=recording.scan_stamps.size, desc='node', unit='scan', disable=quiet)

    def on_odometry(msg: Odometry) -> None:
        with recording.lock:
            recording.odometry[stamp_to_ns(msg.header.stamp)] = pose_message_to_matrix(
                msg.pose.pose
            )

    def on_transform(msg: TransformStamped) -> None:
        with recording.lock:
            recording.transforms[stamp_to_ns(msg.header.stamp)] = transform_message_to_matrix(
                msg.transform
            )

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            if 'scan_stamp' not in values or 'mlsemreg' not in status.name:
                continue
            stamp = recording.nearest_scan(parse_seconds(values['scan_stamp']))
            with recording.lock:
                recording.diagnostics[stamp] = values
                recording.levels[stamp] = (
                    int.from_bytes(status.level, 'little')
                    if isinstance(status.level, bytes)
                    else int(status.level)
                )
                recording.messages[stamp] = status.message
            progress.update(1)

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    try:
        listener = rclpy.create_node('mlsemreg_demo_recorder', context=context)
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        listener.create_subscription(Odometry, 'mlsemreg/odometry', on_odometry, reliable)
        listener.create_subscription(
            TransformStamped, 'mlsemreg/transform', on_transform, reliable
        )
        listener.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, reliable)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(listener)
        spinner = threading.Thread(target=executor.spin, daemon=True)
        spinner.start()
        player_node = rclpy.create_node('mlsemreg_demo_player', context=context)
        options = PlayOptions(
            rate=rate,
            topics=[POINTS_TOPIC],
            wait_for_subscribers=1,
            wait_timeout=60.0,
            pace_timeout=timeout,
            quiet=True,
        )
        player = Player(player_node, bag, options, answered=recording.answered)
        try:
            if not player.wait_for_subscribers():
                raise RuntimeError(
                    'mlsemreg_node did not subscribe to /points within 60 s (see node.log)'
                )
            if node.poll() is not None:
                raise RuntimeError('mlsemreg_node exited (see node.log)')
            player.play_once()
            time.sleep(1.0)  # last odometry/transform messages
        finally:
            player.close()
            executor.shutdown(timeout_sec=5.0)
    finally:
        rclpy.try_shutdown(context=context)
        progress.close()
    return recording


def write_recording(path: Path, recording: NodeRecording) -> None:
    """Write the recorded odometry as a rosbag2 (``/mlsemreg/odometry``)."""
    from mlsemreg_ros.datasets.bag import BagWriter

    with BagWriter(path, storage='mcap') as writer:
        for stamp in sorted(recording.odometry):
            writer.write_odometry(
                stamp, recording.odometry[stamp], frame_id='odom', topic='/mlsemreg/odometry'
            )
