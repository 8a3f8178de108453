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
Estimator adapters of the replay: our odometry, KISS-ICP, and a recorded run of the node.

GenZ-ICP and KISS-SLAM: :mod:`mlsemreg_ros.evaluation.peer_estimators`.

Each turns its estimator's per-scan output into a
:class:`~mlsemreg_ros.evaluation.records.FrameEstimate`; a new estimator is one more class
with ``method``, ``progress_label`` and ``step(scan)``
(:class:`~mlsemreg_ros.evaluation.replay.SequenceEstimator`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
import threading
import time
from typing import Any

from mlsemreg_ros.codec.stamps import parse_seconds
from mlsemreg_ros.core.rigid import relative_transform
from mlsemreg_ros.datasets.source import Scan
from mlsemreg_ros.evaluation.records import FrameEstimate, PairClouds
import numpy as np


class OdometryEstimator:
    """
    :class:`mlsemreg_ros.core.odometry.Odometry`: the node's code path, scan by scan.

    Keyframe, local map, constant-velocity candidate and acceptance test are the node's
    (same config); a scan without labels is labeled by ``label_source``.
    """

    method = 'ML-SemReg'
    progress_label = ''

    def __init__(self, odometry: Any) -> None:
        """Wrap a fresh :class:`~mlsemreg_ros.core.odometry.Odometry`."""
        self.odometry = odometry
        # sequence index by odometry frame counter; the counter starts again at 0 while no
        # scan can be the first keyframe and after a reset, so the latest scan of a counter wins
        self._bag_index: dict[int, int] = {}
        self.deskewed_scans = 0  # scans the odometry motion-compensated
        self.last_step: Any = None  # the odometry's last OdometryStep (candidates, pose)

    def step(self, scan: Scan) -> FrameEstimate:
        """Process one scan with the odometry."""
        keyframe = self.odometry.keyframe  # a scan without labels: label_source decides
        step = self.odometry.process(
            scan.xyz,
            scan.labels,
            scan.stamp_ns,
            point_times=scan.point_times,
            intensity=scan.intensity,
        )
        self.deskewed_scans += int(step.deskewed)
        self.last_step = step
        self._bag_index[step.index] = scan.index
        result = step.result
        if result is None and step.relative is not None:  # tracked by the prediction alone
            return FrameEstimate(
                step.pose,
                self._bag_index[step.keyframe_index],
                step.relative,
                bool(step.accepted),
                step.latency_ms,
                mode='tracking',
                new_keyframe=bool(step.new_keyframe),
                message=step.reason,
                source=step.source,
                frame_covariance=step.frame_covariance,
                timings_ms=step.timings_ms,
            )
        if result is None:  # the first scan (or one the odometry started again on)
            return FrameEstimate(
                step.pose,
                None,
                accepted=bool(step.accepted),
                latency_ms=step.latency_ms,
                new_keyframe=step.new_keyframe,
                message=step.reason,
                source=step.source,
                timings_ms=step.timings_ms,
            )
        clouds = PairClouds(
            keyframe.prepared.points,
            keyframe.prepared.labels,
            step.prepared.points,
            step.prepared.labels,
        )
        return FrameEstimate(
            step.pose,
            self._bag_index[step.keyframe_index],
            step.relative,
            bool(step.accepted),
            step.latency_ms,
            len(result.correspondences),
            result.num_inliers,
            result.source_points,
            result.target_points,
            result.mode,
            bool(step.new_keyframe),
            step.reason or result.message,
            step.source,
            step.frame_covariance,
            step.timings_ms,
            clouds,
        )


class KissIcpEstimator:
    """
    KISS-ICP (Vizzo et al., RA-L 2023; PyPI ``kiss-icp``) on the same scans.

    Default KISS-ICP configuration (voxel size = max_range / 100, adaptive threshold,
    constant-velocity prediction, deskew on). Scans with per-point times are deskewed by
    KISS-ICP itself (to its reference, the sweep end); scans without (the clean world) are
    not. KISS-ICP normalises the times of a scan to [0, 1] and spreads its last
    frame-to-frame motion over them, which assumes consecutive sweeps; when the scans are
    further apart than a sweep (``--stride``), an anchor time at ``last time - stamp gap``
    is added on a point beyond ``max_range`` (its range filter drops it after the deskew),
    so the normalisation spans the gap (``docs/field.md``). Each scan's pair is (previous
    kept scan, scan): the relative estimate ``inv(P_prev) P_k`` is scored like an ML-SemReg
    pair; every estimate counts as accepted (KISS-ICP has no failure signal).
    """

    method = 'KISS-ICP'
    progress_label = ' (kiss-icp)'

    def __init__(self, max_range: float = 100.0) -> None:
        """Create KISS-ICP for scans of up to ``max_range`` metres."""
        self.max_range = max_range
        self.odometry = self._create(max_range)
        self._previous: tuple[int, np.ndarray] | None = None  # (index, pose)
        self._previous_stamp = 0
        self.deskewed_scans = 0  # scans given to KISS-ICP with their per-point times

    def step(self, scan: Scan) -> FrameEstimate:
        """Register one scan with KISS-ICP."""
        points, times = self._inputs(scan)
        tic = time.perf_counter()
        pose = self._register(points, times)
        latency = 1e3 * (time.perf_counter() - tic)
        self.deskewed_scans += int(times.size > 0)
        previous, self._previous = self._previous, (scan.index, pose)
        mode = self.progress_label.strip(' ()')
        if previous is None:
            return FrameEstimate(
                pose, None, accepted=True, latency_ms=latency, mode=mode, new_keyframe=True
            )
        return FrameEstimate(
            pose,
            previous[0],
            relative_transform(previous[1], pose),
            accepted=True,
            latency_ms=latency,
            mode=mode,
            new_keyframe=True,
        )

    @staticmethod
    def _create(max_range: float) -> Any:
        """Return KISS-ICP in its default configuration for ``max_range``, deskew on."""
        from kiss_icp.config import load_config
        from kiss_icp.kiss_icp import KissICP

        config = load_config(None)
        config.data.deskew = True  # used only on scans with per-point times
        config.data.max_range = max_range
        config.mapping.voxel_size = max_range / 100.0
        return KissICP(config)

    def _register(self, points: np.ndarray, times: np.ndarray) -> np.ndarray:
        """Register one scan; return its pose (4, 4)."""
        self.odometry.register_frame(points, times)
        return self.odometry.last_pose.copy()

    def _inputs(self, scan: Scan) -> tuple[np.ndarray, np.ndarray]:
        """Return the points and the times KISS-ICP deskews by (empty: no deskew)."""
        points = np.asarray(scan.xyz, dtype=np.float64)
        gap_s = 1e-9 * (scan.stamp_ns - self._previous_stamp) if self._previous_stamp else 0.0
        self._previous_stamp = scan.stamp_ns
        times = scan.point_times
        if times is None or times.shape != (points.shape[0],) or np.ptp(times) == 0.0:
            return points, np.zeros(0)
        times = np.asarray(times, dtype=np.float64)
        last = float(times.max())
        if gap_s > 1.5 * float(np.ptp(times)):  # scans further apart than one sweep
            anchor = np.array([[10.0 * self.max_range + 1.0, 0.0, 0.0]])
            return np.vstack([points, anchor]), np.append(times, last - gap_s)
        return points, times


@dataclass
class NodeRecording:
    """What a running mlsemreg_node published, keyed by scan stamp (ns)."""

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


class RecordedRunEstimator:
    """
    A recorded run of the node (the demo): its answers, looked up by scan stamp.

    The pose is the node's ``mlsemreg/odometry`` (held where the node refused a scan), the
    relative estimate its ``mlsemreg/transform``, the keyframe and counts its
    ``/diagnostics``; the latency is the core's ``processing_ms``.
    """

    method = 'mlsemreg_node'
    progress_label = ' (recorded node run)'

    def __init__(self, recording: NodeRecording, scan_stamps: list[int]) -> None:
        """``scan_stamps``: the header stamps of the played scans, in bag order."""
        self.recording = recording
        self._index_of = {stamp: k for k, stamp in enumerate(scan_stamps)}
        self._pose = np.eye(4)

    def step(self, scan: Scan) -> FrameEstimate:
        """Look up what the node said about this scan."""
        rec, stamp, k = self.recording, scan.stamp_ns, scan.index
        values = rec.diagnostics.get(stamp, {})
        self._pose = rec.odometry.get(stamp, self._pose)
        kf_stamp = (
            rec.nearest_scan(parse_seconds(values['keyframe_stamp']))
            if values.get('keyframe_stamp')
            else stamp
        )
        kf_index = self._index_of.get(kf_stamp, k)
        registered = k > 0 and bool(values) and kf_index != k
        T = rec.transforms.get(stamp)
        return FrameEstimate(
            self._pose,
            kf_index if registered else None,
            T if registered else None,
            accepted=(T is not None) if registered else bool(values),
            latency_ms=float(values.get('processing_ms', math.nan)),
            correspondences=int(float(values.get('correspondences', 0))),
            estimator_inliers=int(float(values.get('num_inliers', 0))),
            mode=values.get('mode', ''),
            message=rec.messages.get(stamp, 'no answer from the node'),
        )
