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
Scan-to-keyframe odometry on top of :class:`~mlsemreg_ros.core.pipeline.Registration`.

The code path shared by the ROS node and the offline bag evaluation::

    prepare(scan)                          once per scan; the keyframe's is cached
    register(current, keyframe)            T_keyframe_current (p_keyframe = T p_current)
    pose = pose_keyframe @ T               accumulated, only if the registration succeeded
    keyframe <- current                    per the keyframe policy, only after a success

The first scan becomes the keyframe at identity. A failed registration
(``RegistrationResult.success`` false) never advances anything: the pose stays
at the last accepted one and the keyframe is kept, so the next scan is
registered against the same keyframe.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import time
from typing import Any

from mlsemreg_ros.core.config import ConfigError, RegistrationConfig
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.results import PreparedScan, RegistrationResult
import numpy as np

POLICIES = ('every_frame', 'distance')


@dataclass
class KeyframePolicy:
    """
    When the current scan replaces the keyframe (after a successful registration).

    Same names and units as the node's ``keyframe.*`` parameters
    (``mlsemreg_ros/ros/node_config.py``): ``policy`` every_frame | distance,
    ``min_distance`` in metres, ``min_rotation`` in degrees.
    """

    policy: str = 'every_frame'
    min_distance: float = 1.0
    min_rotation: float = 10.0

    def __post_init__(self) -> None:
        if self.policy not in POLICIES:
            raise ConfigError(f'keyframe.policy={self.policy!r} is not one of {list(POLICIES)}')
        if self.min_distance < 0.0 or self.min_rotation < 0.0:
            raise ConfigError('keyframe.min_distance and keyframe.min_rotation must be >= 0')

    @classmethod
    def from_config(cls, config: Any) -> KeyframePolicy:
        """From any object with ``policy, min_distance, min_rotation`` (e.g. the node's)."""
        return cls(str(config.policy), float(config.min_distance), float(config.min_rotation))

    @classmethod
    def from_flat(cls, flat: dict[str, Any]) -> KeyframePolicy:
        """From ``{'keyframe.policy': ..., ...}`` (node-level keys of a params YAML)."""
        defaults = cls()
        return cls(str(flat.get('keyframe.policy', defaults.policy)),
                   float(flat.get('keyframe.min_distance', defaults.min_distance)),
                   float(flat.get('keyframe.min_rotation', defaults.min_rotation)))

    def is_new_keyframe(self, T_keyframe_current: np.ndarray) -> bool:
        """Whether a scan registered with this relative transform becomes the keyframe."""
        if self.policy == 'every_frame':
            return True
        T = np.asarray(T_keyframe_current, dtype=np.float64)
        return (float(np.linalg.norm(T[:3, 3])) >= self.min_distance
                or rotation_angle_deg(T) >= self.min_rotation)


def rotation_angle_deg(T: np.ndarray) -> float:
    """Rotation angle of a transform (4, 4) or rotation (3, 3), degrees."""
    R = np.asarray(T, dtype=np.float64)[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


@dataclass
class Keyframe:
    """The scan others are registered onto: raw arrays (to re-prepare), prepared scan, pose."""

    index: int  # frame counter of the keyframe scan
    stamp_ns: int
    points: np.ndarray  # (N, 3) raw scan
    labels: np.ndarray  # (N,) raw labels
    prepared: PreparedScan
    pose: np.ndarray  # (4, 4) T_odom_keyframe


@dataclass
class OdometryStep:
    """What one scan did to the odometry."""

    index: int  # frame counter (0 = first scan after construction or reset)
    stamp_ns: int
    pose: np.ndarray  # (4, 4) T_odom_current: accumulated, or the last accepted if rejected
    relative: np.ndarray | None  # (4, 4) T_keyframe_current estimate; None for the first scan
    result: RegistrationResult | None  # None for the first scan
    accepted: bool  # the registration succeeded and moved the pose (True for the first scan)
    keyframe_index: int  # frame counter of the keyframe registered onto (own index if first)
    keyframe_stamp_ns: int
    new_keyframe: bool  # this scan became the keyframe
    latency_ms: float  # prepare + register wall time
    prepared: PreparedScan | None = None  # the current scan as prepared (markers, plots)
    timings_ms: dict[str, float] = field(default_factory=dict)


class Odometry:
    """Registers every scan onto a cached keyframe and accumulates the poses."""

    def __init__(self, registration: Registration | None = None,
                 policy: KeyframePolicy | None = None) -> None:
        self.registration = registration if registration is not None else Registration()
        self.policy = policy if policy is not None else KeyframePolicy()
        self.keyframe: Keyframe | None = None
        self.pose = np.eye(4)
        self._count = 0

    @property
    def config(self) -> RegistrationConfig:
        """Return the registration configuration in use."""
        return self.registration.config

    def reconfigure(self, config: RegistrationConfig) -> None:
        """
        Apply a new registration config from the next scan on.

        The cached keyframe is prepared again only when a section that
        :meth:`Registration.prepare` reads (semantic, features, keypoints) changed.
        """
        old = self.registration.config
        self.registration.config = config
        reprepare = any(getattr(old, s) != getattr(config, s)
                        for s in ('semantic', 'features', 'keypoints'))
        if self.keyframe is not None and reprepare:
            self.keyframe.prepared = self.registration.prepare(self.keyframe.points,
                                                               self.keyframe.labels)

    def reset(self) -> None:
        """Drop the keyframe; the next scan restarts the odometry at identity."""
        self.keyframe = None
        self.pose = np.eye(4)
        self._count = 0

    def process(self, points: np.ndarray, labels: np.ndarray, stamp_ns: int = 0
                ) -> OdometryStep:
        """Register one scan (points (N, 3) metres, labels (N,)) onto the keyframe."""
        index = self._count
        self._count += 1
        start = time.perf_counter()
        current = self.registration.prepare(points, labels)
        timings = {f'prepare.{k}': v for k, v in current.timings_ms.items()}
        if self.keyframe is None:  # first scan: keyframe at identity
            self.keyframe = Keyframe(index, stamp_ns, np.asarray(points), np.asarray(labels),
                                     current, self.pose.copy())
            return OdometryStep(index, stamp_ns, self.pose.copy(), None, None, True, index,
                                stamp_ns, True, 1e3 * (time.perf_counter() - start), current,
                                timings)
        keyframe = self.keyframe
        result = self.registration.register(current, keyframe.prepared)
        latency = 1e3 * (time.perf_counter() - start)
        timings.update({f'register.{k}': v for k, v in result.timings_ms.items()})
        accepted = bool(result.success) and bool(np.all(np.isfinite(result.transform)))
        new_keyframe = False
        if accepted:
            self.pose = keyframe.pose @ result.transform
            new_keyframe = self.policy.is_new_keyframe(result.transform)
            if new_keyframe:
                self.keyframe = Keyframe(index, stamp_ns, np.asarray(points),
                                         np.asarray(labels), current, self.pose.copy())
        return OdometryStep(index, stamp_ns, self.pose.copy(), result.transform, result,
                            accepted, keyframe.index, keyframe.stamp_ns, new_keyframe, latency,
                            current, timings)
