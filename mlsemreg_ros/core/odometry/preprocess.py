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
Preprocessing: a raw scan in, the lazily prepared scan out (``docs/extending.md``).

    sweep_motion(...)                    the motion within the sweep: an earlier accepted
                                         pose -> the prediction, the gyro's rotation, or the
                                         last sweep's own rotation rate
    moving objects                       dropped first, or kept out of the map after
                                         (moving_objects.matching, features/moving_objects.py)
    deskew(points, point_times, motion)  points mapped to the stamp (core/features/deskew.py), when
                                         preprocess.deskew allows it and the scan has times
                                         and the motion within the sweep is known
    registration.prepare(lazy=True)      sanitize, labels, voxelize, keypoints; descriptors
                                         and signatures only if a global registration needs
                                         them
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, TYPE_CHECKING

from mlsemreg_ros.core.deferred import Deferred, deferred_attribute
from mlsemreg_ros.core.features import deskew
from mlsemreg_ros.core.features.deskew import PiecewiseSweepMotion, sweep_motion, SweepMotion
from mlsemreg_ros.core.features.moving_objects import MovingObjectFilter
from mlsemreg_ros.core.odometry.motion_model import Prediction
from mlsemreg_ros.core.results import PreparedScan
import numpy as np

if TYPE_CHECKING:
    from mlsemreg_ros.core.config import RegistrationConfig
    from mlsemreg_ros.core.labeling.source import LabeledScan


@dataclass
class PreprocessedScan:
    """A scan as the odometry uses it: the raw arrays (to re-prepare it) and the prepared."""

    points: np.ndarray  # (N, 3) raw (deskewed) points, metres
    labels: np.ndarray  # (N,) raw labels (may be given as a Deferred: core/deferred.py)
    scan: PreparedScan
    deskewed: bool = False  # the points were motion-compensated
    point_times: np.ndarray | None = None  # (N,) s after the stamp, as given
    deskew_note: str = ''  # why not, when preprocess.deskew is on
    input_points: np.ndarray | None = None  # (N, 3) as given, when deskewed
    rotation_only: bool = False  # deskewed by the gyro's rotation alone (no velocity yet)
    motion: Any = None  # the SweepMotion / PiecewiseSweepMotion it was deskewed with


deferred_attribute(PreprocessedScan, 'labels')


class Preprocessor:
    """Turns a raw scan into the prepared scan of the odometry."""

    def __init__(self, registration: Any) -> None:
        """Prepare with ``registration`` (a :class:`~mlsemreg_ros.core.pipeline.Registration`)."""
        self.registration = registration
        label_map = getattr(registration, 'label_map', None)  # stand-ins lack it
        self.moving_objects = MovingObjectFilter(label_map) if label_map is not None else None
        self.labelled: LabeledScan | None = None  # the labels of the scan in process
        self.check(registration.config)

    @property
    def config(self) -> RegistrationConfig:
        """Return the registration's configuration."""
        return self.registration.config

    def deskew(
        self,
        points: np.ndarray,
        point_times: np.ndarray | None,
        motion: deskew.SweepMotion | deskew.PiecewiseSweepMotion | None = None,
    ) -> np.ndarray:
        """
        Motion-compensate ``points`` (N, 3) by their ``point_times`` (N,), seconds.

        The seam of a deskew step (``docs/extending.md``): :func:`core.deskew.deskew` with
        the motion within the sweep. Called for every scan; ``motion`` is None (and the
        points are returned as they are) when :meth:`refusal` refused the scan.
        """
        if point_times is None or motion is None:
            return points
        return deskew.deskew(points, point_times, motion)

    def refusal(self, points: np.ndarray, point_times: np.ndarray | None, motion: Any) -> str:
        """Why the scan is not deskewed ('' if it is): the mode, the times, the motion."""
        if self.registration.config.preprocess.deskew == 'off':
            return 'preprocess.deskew is off'
        why = deskew.time_span_refusal(point_times, int(np.shape(points)[0]))
        if not why and motion is None:
            why = 'the motion within the sweep is unknown (no prediction yet)'
        return why

    def __call__(
        self,
        points: np.ndarray,
        labels: np.ndarray,
        point_times: np.ndarray | None = None,
        motion: deskew.SweepMotion | deskew.PiecewiseSweepMotion | None = None,
    ) -> PreprocessedScan:
        """Deskew and prepare lazily (descriptors on demand, :meth:`Registration.complete`)."""
        why = self.refusal(points, point_times, motion)
        given = points
        points = self.deskew(points, point_times, None if why else motion)
        scan = self.registration.prepare(points, labels, lazy=True)
        if self.labelled is not None:  # the label source in input_stats, its time in timings
            self.labelled.note(scan)
        on = self.registration.config.preprocess.deskew == 'on'
        return PreprocessedScan(
            np.asarray(points),
            labels if isinstance(labels, Deferred) else np.asarray(labels),
            scan,
            deskewed=not why,
            point_times=point_times,
            deskew_note=f'not deskewed: {why}' if why and on else '',
            input_points=None if why else np.asarray(given),
            motion=None if why else motion,
        )

    def sweep(
        self,
        points: np.ndarray,
        labels: np.ndarray,
        point_times: np.ndarray | None,
        prediction: Prediction | None,
        stamp_ns: int,
        accepted: Sequence[tuple[np.ndarray, int]],
        sweep_twist: tuple[SweepMotion, int] | None,
        motion_model: Any,
    ) -> PreprocessedScan:
        """
        Deskew a scan by the motion within its sweep and prepare it (:meth:`sweep_motion`).

        Without a velocity yet (no prediction), the gyro's rotation alone if there is an IMU.
        """
        motion = self.sweep_motion(
            prediction, stamp_ns, point_times, accepted, sweep_twist, motion_model
        )
        rotation_only = motion is None and prediction is None
        if rotation_only:  # no velocity yet: the gyro's rotation alone (if there is an IMU)
            motion = self.gyro_motion(motion_model, stamp_ns, point_times, np.zeros(3))
        raw = self.scan(points, labels, point_times, motion)
        raw.rotation_only = rotation_only and raw.deskewed
        return raw

    def sweep_motion(
        self,
        prediction: Prediction | None,
        stamp_ns: int,
        point_times: np.ndarray | None,
        accepted: Sequence[tuple[np.ndarray, int]],
        sweep_twist: tuple[SweepMotion, int] | None,
        motion_model: Any,
    ) -> SweepMotion | PiecewiseSweepMotion | None:
        """
        Return the motion within the sweep: an earlier accepted pose -> the prediction.

        ``accepted``: the last accepted ``(T_odom_scan, stamp_ns)``, oldest first;
        ``sweep_twist``: the sweep alignment's last estimate and the stamp of its sweep.

        The twist spans ``preprocess.deskew_window`` accepted poses back: a twist from the
        last pose only (window 1) feeds each pose's error into the next deskew with gain 1,
        a marginally stable loop (``docs/field.md``). With a gyro over the sweep
        (``motion_model.sweep_rotations``) the rotation follows it sample by sample, and
        the twist gives only the translation: a turn that starts or ends within the sweep
        is not averaged away. Without a gyro, the twist the sweep alignment estimated over
        the last accepted sweep (``sweep_alignment``) is the most recent measure of the
        rotation rate within a sweep, and is used instead when this scan is the next sweep
        (its stamp at most 1.5 sweep spans later; after a skip the rate is too old). The
        velocity stays the poses': the sweep's own estimate leans on its prior where the
        scene leaves the forward speed free, so fed forward it would lag an acceleration.
        """
        window = self.config.preprocess.deskew_window
        if prediction is None or not accepted:
            return None
        pose, stamp = accepted[-min(window, len(accepted))]
        motion = sweep_motion(pose, stamp, prediction.T_odom_current, stamp_ns)
        if motion is None:
            return None
        gyro = self.gyro_motion(motion_model, stamp_ns, point_times, motion.velocity)
        if gyro is not None:
            return gyro
        last = sweep_twist
        if (
            last is not None
            and last[1] == accepted[-1][1]
            and self.config.sweep_alignment.mode != 'off'
            and _next_sweep(last[1], stamp_ns, point_times)
        ):
            return SweepMotion(last[0].omega, motion.velocity)
        return motion

    @staticmethod
    def gyro_motion(
        motion_model: Any, stamp_ns: int, point_times: np.ndarray | None, velocity: np.ndarray
    ) -> PiecewiseSweepMotion | None:
        """
        Return the gyro's rotation within the sweep with the body ``velocity`` (m/s), or None.

        None when the motion model has no gyro over the sweep (no IMU, constant velocity).
        """
        gyro = getattr(motion_model, 'sweep_rotations', None)
        if gyro is None or point_times is None or not np.size(point_times):
            return None
        times = np.asarray(point_times, dtype=np.float64)
        if not np.all(np.isfinite(times)):
            return None
        rotations = gyro(stamp_ns, float(times.min()), float(times.max()))
        if rotations is None:
            return None
        return PiecewiseSweepMotion.from_rotations(*rotations, velocity)

    def scan(
        self,
        points: np.ndarray,
        labels: np.ndarray,
        point_times: np.ndarray | None,
        motion: SweepMotion | None = None,
    ) -> PreprocessedScan:
        """Preprocess; moving objects are dropped first or kept out of the map after."""
        mask = self.moving_mask(points, labels)
        if mask is not None and self.config.moving_objects.matching == 'drop':
            keep = ~mask
            points, labels = np.asarray(points)[keep], np.asarray(labels).reshape(-1)[keep]
            if point_times is not None and np.size(point_times) == len(keep):
                point_times = np.asarray(point_times).reshape(-1)[keep]
            mask = None
        raw = self(points, labels, point_times, motion)
        if mask is not None:
            self.exclude_moving(raw.scan, raw.points, raw.labels, mask)
        return raw

    def check(self, config: RegistrationConfig) -> None:
        """Resolve ``moving_objects.movable_classes`` now (ConfigError for unknown names)."""
        if self.moving_objects is not None:
            self.moving_objects.movable_lookup(config.moving_objects)

    def moving_mask(self, points: np.ndarray, labels: np.ndarray) -> np.ndarray | None:
        """Return the raw points ``moving_objects`` filters (N,) bool, or None if none."""
        if self.moving_objects is None or isinstance(labels, Deferred):
            return None  # labels made when read filter nothing (LabelSource.when_read)
        shape, labels = np.shape(points), np.asarray(labels).reshape(-1)
        if len(shape) != 2 or shape[1] != 3 or shape[0] != len(labels):
            return None  # preparation says what is wrong with the scan
        cfg = self.config
        return self.moving_objects.raw_mask(labels, cfg.moving_objects, cfg.semantic.label_scheme)

    def exclude_moving(
        self,
        scan: PreparedScan,
        points: np.ndarray,
        labels: np.ndarray,
        mask: np.ndarray | None = None,
    ) -> None:
        """Mark the prepared points kept out of the local map (``scan.map_excluded``)."""
        if self.moving_objects is None:
            return
        if mask is None:
            mask = self.moving_mask(points, labels)
        filtered = None
        if mask is not None and len(mask) == len(points):
            filtered = np.asarray(points).reshape(-1, 3)[mask]
        cfg = self.config
        scan.map_excluded = self.moving_objects.prepared_mask(
            scan.points, scan.labels, filtered, cfg.moving_objects, cfg.features.voxel_size
        )
        if scan.map_excluded is not None:
            scan.alignment_clouds.clear()  # built again without the excluded points


def _next_sweep(last_stamp_ns: int, stamp_ns: int, point_times: np.ndarray | None) -> bool:
    """Whether ``stamp_ns`` follows ``last_stamp_ns`` by at most 1.5 sweep spans (no skip)."""
    if point_times is None or not np.size(point_times) or not last_stamp_ns or not stamp_ns:
        return False
    times = np.asarray(point_times, dtype=np.float64)
    span = float(np.nanmax(times) - np.nanmin(times))
    return 0.0 < 1e-9 * (stamp_ns - last_stamp_ns) <= 1.5 * span
