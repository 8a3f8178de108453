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
``mlsemreg-demo``: the real node on a simulated drive, scored like ``mlsemreg-eval-bag``.

1. simulate a drive (default 100 scans, seed 0) into a cache (reused when its
   parameters match);
2. start ``mlsemreg_node`` (a separate process, reliable subscription);
3. play the bag's ``/points`` with :class:`~mlsemreg_ros.tools.play.Player`,
   paced by the node's ``/diagnostics`` (one answer per scan, so no scan is
   dropped however slow the machine), and record ``mlsemreg/odometry``,
   ``mlsemreg/transform`` and ``/diagnostics`` (also written to a bag);
4. score the recorded estimates against the ground truth with the metrics of
   ``mlsemreg-eval-bag``, print the table and write the results folder (summary,
   per-frame CSV, trajectories, plots).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
import math
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import threading
import time
from typing import Any

from mlsemreg_ros.tools.cli_help import HelpFormatter
import numpy as np
import yaml


@dataclass
class Recording:
    """What the node published, keyed by scan stamp (ns)."""

    odometry: dict[int, np.ndarray] = field(default_factory=dict)  # T_odom_scan
    transforms: dict[int, np.ndarray] = field(default_factory=dict)  # T_keyframe_scan
    diagnostics: dict[int, dict[str, str]] = field(default_factory=dict)
    levels: dict[int, int] = field(default_factory=dict)
    messages: dict[int, str] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)
    scan_stamps: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def nearest_scan(self, stamp_ns: int, tolerance_ns: int = 1_000_000) -> int:
        """Return the scan stamp nearest ``stamp_ns`` (the node reports float seconds)."""
        if self.scan_stamps.size == 0:
            return stamp_ns
        nearest = int(self.scan_stamps[np.argmin(np.abs(self.scan_stamps - stamp_ns))])
        return nearest if abs(nearest - stamp_ns) <= tolerance_ns else stamp_ns

    def answered(self, stamp_ns: int) -> bool:
        """Tell whether the node reported on the scan stamped ``stamp_ns``."""
        with self.lock:
            return stamp_ns in self.diagnostics


def ensure_sequence(cache_dir: Path, frames: int, seed: int, quiet: bool) -> Path:
    """Return the cached simulated bag for (frames, seed), simulating it if needed."""
    from mlsemreg_ros.tools import simulate

    bag = cache_dir / f'sim_seed{seed}_{frames}f'
    args = [str(bag), '--frames', str(frames), '--seed', str(seed)]
    expected = simulate.build_parser().parse_args(args)
    wanted = yaml.safe_dump(simulate_config_dict(expected))
    meta = bag / 'simulation.yaml'
    if meta.exists() and (bag / 'metadata.yaml').exists():
        saved = yaml.safe_load(meta.read_text()).get('simulation', {})
        if yaml.safe_dump(saved) == wanted:
            print(f'using the cached sequence {bag}')
            return bag
    if bag.exists():
        shutil.rmtree(bag)
    bag.parent.mkdir(parents=True, exist_ok=True)
    print(f'simulating {frames} scans (seed {seed}) into {bag} ...')
    if simulate.main(args + (['--quiet'] if quiet else [])) != 0:
        raise RuntimeError('simulation failed')
    return bag


def simulate_config_dict(args: argparse.Namespace) -> dict:
    """Return the SimulationConfig of ``mlsemreg-simulate`` arguments as a plain dict."""
    import dataclasses

    from mlsemreg_ros.tools.simulate import simulation_config

    return yaml.safe_load(yaml.safe_dump(dataclasses.asdict(simulation_config(args))))


def start_node(domain_id: int, params: list[str], log: Path) -> subprocess.Popen:
    """Start mlsemreg_node in its own process (reliable QoS for paced playback)."""
    ros_args = ['--ros-args', '-p', 'qos.reliability:=reliable', '-p', 'qos.depth:=10']
    for item in params:
        ros_args += ['-p', item.replace('=', ':=', 1)]
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id))
    env.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
    command = [sys.executable, '-c', 'import sys; from mlsemreg_ros.ros.node import main; '
               'sys.exit(main())', *ros_args]
    return subprocess.Popen(command, env=env, stdout=log.open('w'), stderr=subprocess.STDOUT)


def stop_node(process: subprocess.Popen) -> None:
    """Stop the node with SIGINT (then SIGKILL after 15 s)."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def _transform(msg: Any) -> np.ndarray:
    from mlsemreg_ros.codec.poses import pose_to_matrix

    t, q = msg.translation, msg.rotation
    return pose_to_matrix((t.x, t.y, t.z), (q.x, q.y, q.z, q.w))


def parse_stamp(text: str) -> int:
    """Parse seconds written as ``'1700000000.200000000'`` to exact nanoseconds."""
    seconds, _, fraction = text.strip().partition('.')
    return int(seconds) * 1_000_000_000 + int((fraction + '000000000')[:9])


def _stamp_ns(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def record_and_play(bag: Path, domain_id: int, rate: float, timeout: float,
                    node: subprocess.Popen, quiet: bool) -> Recording:
    """Play ``/points`` paced by the node's diagnostics and record what the node says."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import TransformStamped
    from mlsemreg_ros.codec.poses import pose_to_matrix
    from mlsemreg_ros.datasets.bag import POINTS_TOPIC
    from mlsemreg_ros.tools.play import Player, PlayOptions
    from nav_msgs.msg import Odometry
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from tqdm import tqdm

    recording = Recording(scan_stamps=np.sort(scan_stamps(bag)))
    progress = tqdm(total=recording.scan_stamps.size, desc='node', unit='scan', disable=quiet)

    def on_odometry(msg: Odometry) -> None:
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        with recording.lock:
            recording.odometry[_stamp_ns(msg.header.stamp)] = pose_to_matrix(
                (p.x, p.y, p.z), (q.x, q.y, q.z, q.w))

    def on_transform(msg: TransformStamped) -> None:
        with recording.lock:
            recording.transforms[_stamp_ns(msg.header.stamp)] = _transform(msg.transform)

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            if 'scan_stamp' not in values or 'mlsemreg' not in status.name:
                continue
            stamp = recording.nearest_scan(parse_stamp(values['scan_stamp']))
            with recording.lock:
                recording.diagnostics[stamp] = values
                recording.levels[stamp] = int.from_bytes(status.level, 'little') \
                    if isinstance(status.level, bytes) else int(status.level)
                recording.messages[stamp] = status.message
            progress.update(1)

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    try:
        listener = rclpy.create_node('mlsemreg_demo_recorder', context=context)
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        listener.create_subscription(Odometry, 'mlsemreg/odometry', on_odometry, reliable)
        listener.create_subscription(TransformStamped, 'mlsemreg/transform', on_transform,
                                     reliable)
        listener.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, reliable)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(listener)
        spinner = threading.Thread(target=executor.spin, daemon=True)
        spinner.start()
        player_node = rclpy.create_node('mlsemreg_demo_player', context=context)
        options = PlayOptions(rate=rate, topics=[POINTS_TOPIC], wait_for_subscribers=1,
                              wait_timeout=60.0, pace_timeout=timeout, quiet=True)
        player = Player(player_node, bag, options, answered=recording.answered)
        try:
            if not player.wait_for_subscribers():
                raise RuntimeError('mlsemreg_node did not subscribe to /points within 60 s '
                                   '(see node.log)')
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


def scan_stamps(bag: Path) -> np.ndarray:
    """Return the header stamps (F,) int64 ns of the bag's ``/points``, in bag order."""
    from mlsemreg_ros.datasets.bag import open_reader, POINTS_TOPIC

    reader = open_reader(bag)
    try:
        connections = [c for c in reader.connections if c.topic == POINTS_TOPIC]
        return np.array([_stamp_ns(reader.deserialize(raw, c.msgtype).header.stamp)
                         for c, _, raw in reader.messages(connections=connections)],
                        dtype=np.int64)
    finally:
        reader.close()


def score(bag: Path, recording: Recording) -> Any:
    """Turn the recording into an EvalRun (frames in bag order, ground truth from the bag)."""
    from mlsemreg_ros.core.metrics import rotation_error_deg, translation_error_m
    from mlsemreg_ros.core.rigid import invert_transform as inverse
    from mlsemreg_ros.datasets.bag import GT_TOPIC, read_poses
    from mlsemreg_ros.tools.eval_bag import EvalRun, FrameRecord, MAX_RE_DEG, MAX_TE_M

    stamps = scan_stamps(bag).tolist()
    gt_stamps, gt_poses = read_poses(bag, GT_TOPIC)
    gt_by_stamp = dict(zip(gt_stamps.tolist(), gt_poses, strict=True))
    index_of = {s: k for k, s in enumerate(stamps)}
    records, poses, gts = [], [], []
    pose = np.eye(4)
    nan = math.nan
    for k, stamp in enumerate(stamps):
        values = recording.diagnostics.get(stamp, {})
        gt = gt_by_stamp.get(stamp)
        pose = recording.odometry.get(stamp, pose)  # held when the node refused the scan
        kf_stamp = recording.nearest_scan(parse_stamp(values['keyframe_stamp'])) if values.get(
            'keyframe_stamp') else stamp
        kf_index = index_of.get(kf_stamp, k)
        registered = k > 0 and bool(values) and kf_index != k
        T = recording.transforms.get(stamp)
        accepted = (T is not None) if registered else bool(values)
        re = te = nan
        if registered and T is not None and gt is not None and kf_stamp in gt_by_stamp:
            T_gt = inverse(gt_by_stamp[kf_stamp]) @ gt
            re = rotation_error_deg(T[:3, :3], T_gt[:3, :3])
            te = 100.0 * translation_error_m(T[:3, 3], T_gt[:3, 3])
        elif registered and gt is not None:
            re = te = math.inf  # refused: counts as a failed pair
        success = bool(accepted and re <= MAX_RE_DEG and te <= 100.0 * MAX_TE_M)
        gt_xyz = gt[:3, 3] if gt is not None else (nan, nan, nan)
        records.append(FrameRecord(
            k, k, stamp, kf_index, registered, accepted, success, re, te,
            int(float(values.get('correspondences', 0))), int(float(values.get('num_inliers', 0))),
            0, nan, values.get('mode', ''), False, float(values.get('processing_ms', nan)),
            *map(float, pose[:3, 3]), *map(float, gt_xyz),
            recording.messages.get(stamp, 'no answer from the node')))
        poses.append(pose.copy())
        gts.append(gt)
    gt_array = None
    if gts and all(g is not None for g in gts):
        gt_array = np.asarray(gts)
        gt_array = inverse(gt_array[0]) @ gt_array
    return EvalRun(bag.name, records, np.asarray(stamps, dtype=np.int64),
                   np.asarray(poses).reshape(-1, 4, 4), gt_array, 0.0, method='mlsemreg_node')


def correspondence_pair(bag: Path, run: Any, params: list[str]) -> dict | None:
    """Register the middle pair offline (same core and parameters) for correspondences.png."""
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.metrics import inlier_mask
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.core.rigid import invert_transform as inverse
    from mlsemreg_ros.datasets.bag import BagScanReader
    from mlsemreg_ros.tools.eval_bag import load_parameters

    pairs = [r for r in run.records if r.registered]
    if not pairs:
        return None
    record = pairs[len(pairs) // 2]
    core_keys = set(RegistrationConfig().to_flat_dict())
    core = [p for p in params if p.partition('=')[0].strip() in core_keys]
    config = load_parameters(None, core)
    source = BagScanReader(bag)
    try:
        scans = {s.index: s for s in source.scans()
                 if s.index in (record.bag_index, record.keyframe_index)}
    finally:
        source.close()
    current, keyframe = scans[record.bag_index], scans[record.keyframe_index]
    if current.pose is None or keyframe.pose is None:
        return None
    registration = Registration(config)
    target = registration.prepare(keyframe.xyz, keyframe.labels)
    prepared = registration.prepare(current.xyz, current.labels)
    result = registration.register(prepared, target)
    T_gt = inverse(keyframe.pose) @ current.pose
    return {'target_points': target.points, 'source_points': prepared.points, 'T_gt': T_gt,
            'target_labels': target.labels, 'source_labels': prepared.labels,
            'source_keypoints': result.source_points, 'target_keypoints': result.target_points,
            'inliers': inlier_mask(result.source_points, result.target_points, T_gt,
                                   config.estimator.inlier_threshold),
            'bag_index': np.array(record.bag_index),
            'keyframe_index': np.array(record.keyframe_index)}


def write_recording(path: Path, recording: Recording) -> None:
    """Write the recorded odometry as a rosbag2 (``/mlsemreg/odometry``)."""
    from mlsemreg_ros.datasets.bag import BagWriter

    with BagWriter(path, storage='mcap') as writer:
        for stamp in sorted(recording.odometry):
            writer.write_odometry(stamp, recording.odometry[stamp], frame_id='odom',
                                  topic='/mlsemreg/odometry')


def build_parser() -> argparse.ArgumentParser:
    """Command-line interface."""
    p = argparse.ArgumentParser(
        prog='mlsemreg-demo', description='Simulate a drive (cached), run mlsemreg_node on it '
        'through the player, record its odometry, print the metrics and write plots.',
        formatter_class=HelpFormatter)
    p.add_argument('--frames', type=int, default=100, help='scans of the simulated drive')
    p.add_argument('--seed', type=int, default=0, help='world seed')
    p.add_argument('--cache-dir', type=Path, default=Path('.cache'),
                   help='where simulated bags are kept')
    p.add_argument('-o', '--output', type=Path,
                   help='results folder (default: results/demo/<time>, link results/demo/latest)')
    p.add_argument('--rate', type=float, default=1.0,
                   help='player speed factor (playback is also paced by the node)')
    p.add_argument('--domain-id', type=int, default=int(os.environ.get('ROS_DOMAIN_ID', 0)),
                   help='ROS_DOMAIN_ID of the node and the player')
    p.add_argument('--timeout', type=float, default=120.0,
                   help='seconds to wait for the node on one scan')
    p.add_argument('--set', action='append', default=[], metavar='NAME=VALUE',
                   help='node parameter, e.g. --set keypoints.count=2000 (repeatable)')
    p.add_argument('--quiet', action='store_true', help='no progress bars')
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``mlsemreg-demo``."""
    from mlsemreg_ros.tools import eval_bag

    args = build_parser().parse_args(argv)
    start = time.monotonic()
    bag = ensure_sequence(args.cache_dir, args.frames, args.seed, args.quiet)
    out = args.output or Path('results') / 'demo' / time.strftime('%Y%m%d-%H%M%S')
    out.mkdir(parents=True, exist_ok=True)
    print(f'starting mlsemreg_node (ROS_DOMAIN_ID {args.domain_id}); log: {out / "node.log"}')
    node = start_node(args.domain_id, args.set, out / 'node.log')
    try:
        recording = record_and_play(bag, args.domain_id, args.rate, args.timeout, node,
                                    args.quiet)
    finally:
        stop_node(node)
    write_recording(out / 'recorded_odometry', recording)
    run = score(bag, recording)
    run.plot_pair = correspondence_pair(bag, run, args.set)
    summary = eval_bag.summarize(run)
    details = eval_bag.run_details(run, bag=str(bag), answered_scans=len(recording.diagnostics),
                                   node_params=args.set, total_time_s=time.monotonic() - start)
    eval_bag.write_results(out, run, summary, details, None)
    if args.output is None:
        eval_bag.link_latest(out)
    print(eval_bag.format_table(summary))
    print(f'results: {out}  ({time.monotonic() - start:.0f} s in total)')
    return 0 if len(recording.diagnostics) == len(run.records) else 1


if __name__ == '__main__':
    sys.exit(main())
