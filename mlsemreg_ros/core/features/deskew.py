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
Deskew: points taken while the sensor moved, mapped into the sensor frame at the stamp.

A spinning LiDAR takes a sweep over its scan period; each point is reported in the
sensor frame *at its own time*. With per-point times ``tau`` (seconds after the header
stamp, the codec's output, ``docs/field.md``) and the motion of the sensor within the
sweep, every point ``p`` is mapped by ``T(tau) p``, where ``T(tau)`` is the pose at
``stamp + tau`` relative to the pose at the stamp. The deskewed scan is then the scan an
instantaneous sensor at the stamp would have taken, so the estimated pose stays the pose
at the stamp (the simulator's ground-truth convention).

The motion (:class:`SweepMotion`) is a constant twist: the SE(3) logarithm of the relative
motion from the last accepted pose to the motion model's prediction at the stamp, per
second. ``T(tau) = exp(tau * twist)`` is evaluated for all points at once (Rodrigues about
the fixed axis, and the closed-form left Jacobian for the translation): no loop over
points. The motion model is whatever the odometry uses (constant velocity, or a prior),
through ``MotionModel.predict`` (``docs/extending.md``).
"""

from __future__ import annotations

from dataclasses import dataclass
import itertools

from mlsemreg_ros.core.features import kernels
from mlsemreg_ros.core.rigid import rotation_matrix, rotation_vector
from mlsemreg_ros.core.settings import param
import numpy as np

#: Below this rotation angle (rad) the series of the SE(3) coefficients are used.
SMALL_ANGLE = 1e-6
#: Per-point times spanning more than this (s) are not a sweep: the scan is not deskewed.
MAX_SWEEP_SPAN_S = 1.0
#: Largest preprocess.deskew_window.
MAX_DESKEW_WINDOW = 10


@dataclass
class PreprocessConfig:
    """Per-point times and deskew (``docs/field.md``)."""

    deskew: str = param(
        'auto',
        'Motion-compensate each scan from its per-point times: auto (when the scan has '
        'times and the motion is known: a prediction of the motion model), on (the same, '
        'and the step notes why a scan could not be deskewed), off (never; the points are '
        'used as they are).',
        choices=('auto', 'on', 'off'),
    )
    deskew_window: int = param(
        3,
        'The motion within a sweep is the constant twist from the pose this many accepted '
        'scans back to the prediction at the stamp. 1 (the last pose only) makes a loop: '
        'each pose error biases the next deskew with gain 1, and the error grew on the field '
        'drives. 3 damps it (docs/field.md).',
        low=1,
        high=MAX_DESKEW_WINDOW,
    )
    deskew_check: bool = param(
        True,
        'After a deskewed scan is accepted, align the scan as it came too, from the accepted '
        'pose; if the raw scan keeps more of its points as map inliers (by more than '
        'deskew_check_margin; on the field drives the deskewed scans keep 0.005 to 0.23 more, '
        'the bent dev pairs 0.007 to 0.05 less), register it raw and flag it in '
        '/diagnostics (deskew_refusal): a plausible time field that does not give the '
        'capture times bends the scan '
        '(docs/hostile_input.md). Only where a prior (IMU, wheels) deskewed the scan or '
        'sweep_alignment.mode is off. Costs one fine alignment per such scan.',
    )
    deskew_check_interval: int = param(
        50,
        'The time field belongs to the driver: once 3 checks in a row kept the deskew '
        '(preprocess.deskew_check), only every this-many-th deskewed scan is checked, and '
        'every scan again after a reset, after a check that refused the deskew, and when the '
        'span of the time field changes by more than a fifth (1: every scan; at stride 1 with '
        'an IMU, checking every scan took 47 % of the CPU time of the odometry).',
        low=1,
        high=1000,
    )
    deskew_check_margin: float = param(
        0.015,
        "How much larger the raw scan's share of map inliers must be than the deskewed "
        "scan's, relative to it, for the deskew to be refused (preprocess.deskew_check). "
        'Measured: the 10 dev pairs bent by a uint8 counter read as ms, raw larger by 2.1 to '
        '13 %; good IMU deskews on the field drives that the check refused with 0, raw larger '
        'by 0 to 1.0 % (one of those refusals led to a wrong pose at stride 10).',
        low=0.0,
        high=1.0,
    )
    time_field: str = param(
        '',
        "PointCloud2 field holding the per-point time ('': auto-detect time, t, timestamp, "
        'time_stamp, offset_time, in that order).',
    )
    time_unit: str = param(
        'auto',
        'Unit of the per-point time field (auto: from the field name, its datatype and its '
        'values; absolute times are recognised by their closeness to the header stamp).',
        choices=('auto', 's', 'ms', 'us', 'ns'),
    )


@dataclass(frozen=True)
class SweepMotion:
    """A constant twist of the sensor, in the sensor frame at the stamp."""

    omega: np.ndarray  # (3,) angular velocity, rad/s
    velocity: np.ndarray  # (3,) the SE(3) log's translational part per second, m/s


@dataclass(frozen=True)
class PiecewiseSweepMotion:
    """
    The sensor's poses at a few times of the sweep (an IMU's), constant twist between them.

    ``poses[k]`` (4, 4) is the pose at ``stamp + times[k]`` in the sensor frame at the stamp
    (``times`` (K,) increasing, K >= 2, seconds). Between two nodes the motion is a constant
    twist: ``twists[k]`` (``(omega, velocity)``, (K - 1, 6)) when the poses were built from
    twists (:meth:`from_rotations` keeps them), else ``log(poses[k]^-1 poses[k + 1]) /
    (times[k + 1] - times[k])``; before the first and after the last node the nearest
    segment's twist is held. A yaw rate that changes within the sweep (the start or end of
    a turn) is followed to the node spacing, where one constant twist over the sweep
    (:class:`SweepMotion`) is wrong by the change.
    """

    times: np.ndarray  # (K,) s after the stamp
    poses: np.ndarray  # (K, 4, 4) T_stamp_(stamp + times[k])
    twists: np.ndarray | None = None  # (K - 1, 6) (omega, velocity) per segment; None: logs

    @classmethod
    def from_rotations(
        cls, times: np.ndarray, rotations: np.ndarray, velocity: np.ndarray
    ) -> PiecewiseSweepMotion:
        """
        Build the poses from rotations at the nodes (a gyro's) and one body velocity.

        ``rotations`` (K, 3, 3) are ``R_stamp_node``, one node at ``times == 0``;
        ``velocity`` (3,) is the translational part of the body twist (m/s, the sensor
        frame), held through the sweep: segment ``k`` is the twist ``(omega_k, velocity)``
        with ``omega_k = log(R_k^T R_k+1) / dt_k``. The rotation follows the gyro; the
        translation comes from the accepted poses, which a velocity integrated from the
        accelerometer over a sweep would not improve.
        """
        from scipy.spatial.transform import Rotation

        times = np.asarray(times, dtype=np.float64)
        rotations = np.asarray(rotations, dtype=np.float64)
        dt = np.diff(times)
        steps = Rotation.from_matrix(np.einsum('nji,njk->nik', rotations[:-1], rotations[1:]))
        omegas = steps.as_rotvec() / dt[:, None]
        exps = [
            se3_exp(SweepMotion(w, velocity), float(d)) for w, d in zip(omegas, dt, strict=True)
        ]
        poses = np.stack(list(itertools.accumulate(exps, np.matmul, initial=np.eye(4))))
        origin = int(np.argmin(np.abs(times)))
        twists = np.concatenate([omegas, np.broadcast_to(velocity, omegas.shape)], axis=1)
        return cls(times, np.linalg.solve(poses[origin], poses), twists)

    def segments(self) -> list[tuple[float, np.ndarray, SweepMotion]]:
        """Return ``(t_k, poses[k], twist_k)`` of every segment (the kept twists, else logs)."""
        if self.twists is not None:
            return [
                (float(start), pose, SweepMotion(twist[:3], twist[3:]))
                for start, pose, twist in zip(
                    self.times[:-1], self.poses[:-1], self.twists, strict=True
                )
            ]
        out = []
        for k in range(len(self.times) - 1):
            dt = float(self.times[k + 1] - self.times[k])
            relative = np.linalg.solve(self.poses[k], self.poses[k + 1])
            phi, rho = se3_log(relative)
            out.append((float(self.times[k]), self.poses[k], SweepMotion(phi / dt, rho / dt)))
        return out


def se3_log(transform: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the SE(3) logarithm ``(phi, rho)`` of ``transform`` (4, 4): rotation vector, rho."""
    transform = np.asarray(transform, dtype=np.float64)
    phi = rotation_vector(transform[:3, :3])
    theta = float(np.linalg.norm(phi))
    hat = _hat(phi)
    if theta < SMALL_ANGLE:
        coefficient = 1.0 / 12.0
    else:
        half = 0.5 * theta
        coefficient = (1.0 - half * np.cos(half) / np.sin(half)) / theta**2
    v_inverse = np.eye(3) - 0.5 * hat + coefficient * hat @ hat
    return phi, v_inverse @ transform[:3, 3]


def sweep_motion(
    T_last: np.ndarray, last_stamp_ns: int, T_predicted: np.ndarray, stamp_ns: int
) -> SweepMotion | None:
    """
    Return the constant twist from the last accepted pose to the predicted one, or None.

    ``T_last`` (4, 4) is ``T_odom_last`` at ``last_stamp_ns``, ``T_predicted`` the motion
    model's ``T_odom_current`` at ``stamp_ns``; None when the stamps cannot give a duration.
    """
    if not last_stamp_ns or not stamp_ns or stamp_ns <= last_stamp_ns:
        return None
    dt = 1e-9 * (stamp_ns - last_stamp_ns)
    relative = np.linalg.inv(np.asarray(T_last, dtype=np.float64)) @ T_predicted
    phi, rho = se3_log(relative)
    return SweepMotion(phi / dt, rho / dt)


def se3_exp(motion: SweepMotion, duration: float) -> np.ndarray:
    """Return ``exp(duration * twist)`` (4, 4)."""
    angles, translations = motion_at(motion, np.array([duration]))
    out = np.eye(4)
    rate = float(np.linalg.norm(motion.omega))
    if rate > 0.0:
        out[:3, :3] = rotation_matrix(motion.omega / rate * angles[0])
    out[:3, 3] = translations[0]
    return out


def motion_at(motion: SweepMotion, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """
    Return ``exp(tau * twist)`` for every ``tau`` in ``times`` (N,): rotations and translations.

    Rotations as (N, 3, 3) would be large; instead the pair ``(angles (N,), translations
    (N, 3))`` is returned, the axis being fixed (``omega / |omega|``): see :func:`deskew`.
    """
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    rate = float(np.linalg.norm(motion.omega))
    angles = times * rate
    rho = times[:, None] * motion.velocity  # tau * rho
    if rate * float(np.max(np.abs(times), initial=0.0)) < SMALL_ANGLE:
        return angles, rho
    axis = motion.omega / rate
    cross1 = np.cross(axis, motion.velocity)  # axis x rho per second
    cross2 = np.cross(axis, cross1)
    # V(theta) (tau rho) = tau rho + (1 - cos)/theta (axis x tau rho) + (theta - sin)/theta
    # axis x (axis x tau rho), with theta = tau |omega| (tau rho = theta / |omega| rho).
    a = np.where(np.abs(angles) < SMALL_ANGLE, 0.0, 1.0 - np.cos(angles)) / rate
    b = (angles - np.sin(angles)) / rate
    return angles, rho + a[:, None] * cross1 + b[:, None] * cross2


def deskew(
    points: np.ndarray, times: np.ndarray, motion: SweepMotion | PiecewiseSweepMotion
) -> np.ndarray:
    """
    Map ``points`` (N, 3), each taken at ``times`` (N,) s after the stamp, to the stamp.

    ``p' = R(tau) p + t(tau)`` with ``(R, t)(tau) = exp(tau * twist)``: the pose at
    ``stamp + tau`` in the frame at the stamp. Vectorised (Rodrigues about the twist's axis).
    A :class:`PiecewiseSweepMotion` maps the points of each segment by
    ``poses[k] exp((tau - t_k) twist_k)`` (all segments in one vectorised pass).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    if times.shape[0] != points.shape[0]:
        raise ValueError(f'{times.shape[0]} point times for {points.shape[0]} points')
    if isinstance(motion, PiecewiseSweepMotion):
        return _deskew_piecewise(points, times, motion)
    return _deskew_constant(points, times, motion)


def _deskew_piecewise(
    points: np.ndarray, times: np.ndarray, motion: PiecewiseSweepMotion
) -> np.ndarray:
    """
    Deskew every point by its own segment (before/after the nodes: the end segments).

    Each point gets its segment by a search in the node times; the compiled kernel maps all
    points in one pass, reading its segment's twist and start pose per point.
    """
    segments = motion.segments()
    index = np.clip(np.searchsorted(motion.times, times, side='right') - 1, 0, len(segments) - 1)
    if not kernels.enabled():
        return _deskew_piecewise_numpy(points, times, index, segments)
    velocity, rate, axis, cross1, cross2 = (
        np.array(column)
        for column in zip(*(_twist_terms(twist) for _, _, twist in segments), strict=True)
    )
    poses = np.stack([pose for _, pose, _ in segments])
    starts = np.array([start for start, _, _ in segments])
    rows = kernels.SegmentRows.of(
        starts, velocity, rate, axis, cross1, cross2, poses[:, :3, :3], poses[:, :3, 3]
    )
    return kernels.deskew_piecewise_points(points, times, index, rows, SMALL_ANGLE)


def _deskew_piecewise_numpy(
    points: np.ndarray, times: np.ndarray, index: np.ndarray, segments: list
) -> np.ndarray:
    """Map the points segment by segment in NumPy: ``poses[k] exp((tau - t_k) twist_k) p``."""
    out = np.empty_like(points)
    for k, (start, pose, twist) in enumerate(segments):  # ~20 segments, not points
        rows = np.flatnonzero(index == k)
        if rows.size:
            local = _deskew_constant(points[rows], times[rows] - start, twist)
            out[rows] = local @ pose[:3, :3].T + pose[:3, 3]
    return out


def _twist_terms(
    motion: SweepMotion,
) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, np.ndarray]:
    """Return ``(velocity, rate, axis, axis x velocity, axis x (axis x velocity))`` of a twist."""
    velocity = np.asarray(motion.velocity, dtype=np.float64)
    rate = float(np.linalg.norm(motion.omega))
    axis = cross1 = cross2 = np.zeros(3)
    if rate > 0.0:
        axis = motion.omega / rate
        cross1 = _cross(axis, velocity)
        cross2 = _cross(axis, cross1)
    return velocity, rate, axis, cross1, cross2


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return ``a x b`` of two 3-vectors (np.cross costs 20 times as much on one pair)."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


def _deskew_constant(points: np.ndarray, times: np.ndarray, motion: SweepMotion) -> np.ndarray:
    """Map ``points`` by ``exp(tau * twist)`` (the constant-twist case of :func:`deskew`)."""
    if kernels.enabled():
        return _deskew_compiled(points, times, motion)
    angles, translations = motion_at(motion, times)
    rate = float(np.linalg.norm(motion.omega))
    if rate == 0.0 or not np.any(angles):
        return points + translations
    axis = motion.omega / rate
    cos, sin = np.cos(angles)[:, None], np.sin(angles)[:, None]
    rotated = (
        points * cos + np.cross(axis, points) * sin + np.outer(points @ axis, axis) * (1.0 - cos)
    )
    return rotated + translations


def _deskew_compiled(points: np.ndarray, times: np.ndarray, motion: SweepMotion) -> np.ndarray:
    """:func:`deskew` by the compiled kernel: the same steps, one pass over the points."""
    velocity, rate, axis, cross1, cross2 = _twist_terms(motion)
    return kernels.deskew_points(points, times, velocity, rate, axis, cross1, cross2, SMALL_ANGLE)


def time_span_refusal(times: np.ndarray | None, count: int) -> str:
    """Why ``times`` cannot deskew a scan of ``count`` points ('' if they can)."""
    if times is None:
        return 'the scan has no per-point times'
    times = np.asarray(times)
    if times.shape != (count,):
        return f'{times.size} point times for {count} points'
    if not np.all(np.isfinite(times)):
        return 'per-point times are not all finite'
    span = float(times.max() - times.min()) if count else 0.0
    if span == 0.0:
        return 'all points have the same time'
    if span > MAX_SWEEP_SPAN_S:
        return f'per-point times span {span:.3g} s (> {MAX_SWEEP_SPAN_S:g} s: not one sweep)'
    offset = float(np.abs(times).max())
    if offset > MAX_SWEEP_SPAN_S:
        return (
            f'per-point times up to {offset:.3g} s from the stamp (> {MAX_SWEEP_SPAN_S:g} s: '
            'not a sweep at the stamp)'
        )
    return ''


def _hat(vector: np.ndarray) -> np.ndarray:
    """Return the skew-symmetric matrix of ``vector`` (3,)."""
    x, y, z = vector
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
