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
Levelling: fit the ground of a scan and take its roll, pitch and height out of the problem.

A ground vehicle's scans differ mostly by ``(x, y, z, yaw)``: once each scan is turned so
that its ground plane is ``z = 0`` (:class:`GroundFit.T_level_sensor`), a pair is a 4-DoF
problem (Quatro, Lim et al. 2022; G3Reg, Qiao et al. 2024, level their scans the same
way). The ground points are the ground classes of the labels (road and parking), or
without labels the lowest fifth of the points around the sensor. The plane is fitted by
iteratively reweighted least squares (Tukey weights); its *tolerance* is the spread of
the normal, from the plane's residuals and the ground's extent, plus
``levelling.tolerance`` for what a fit cannot see (a road's camber, a slope change).

:func:`tilt_departure` is the check of a pose against two fits: a pose ``T_target_source``
must carry the source's ground normal onto the target's; one that does not (by more than
the tolerances) keeps a roll or pitch the ground does not allow and is refused.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core.settings import param
import numpy as np


@dataclass
class LevellingConfig:
    """The ``levelling`` section: ground fit, 4-DoF object search and the tilt check."""

    enabled: bool = param(
        True,
        'Fit the ground of both scans (ground labels, else the lowest points), search the '
        'objects in 4-DoF (x, y, z, yaw) in the levelled frames and refuse a pose whose '
        'roll/pitch departs from the two ground fits by more than their tolerance.',
    )
    ground_classes: list[str] = param(
        ['road', 'parking'],
        'Classes of the ground plane (class names of the label map). The road alone: '
        'with sidewalks and terrain the fits of the dev pairs departed from the truth by '
        'up to 7.5 deg, with the road by up to 5 deg at 60 m and 3 deg at 20 m.',
    )
    max_radius: float = param(
        20.0,
        'Ground points farther than this from the sensor (xy) are left out of the fit '
        '(a far road slopes away from the near one).',
        unit='m',
        low=2.0,
        high=200.0,
    )
    min_points: int = param(
        50,
        'Fewer ground points than this: no fit (the scan is not levelled, nothing is '
        'refused for its tilt).',
        low=3,
        high=100000,
    )
    tolerance: float = param(
        6.0,
        'Tilt a pose may keep beyond the two ground fits (their normals compared) before '
        'it is refused: the camber and slope changes one plane cannot follow.',
        unit='deg',
        low=0.0,
        high=90.0,
    )


@dataclass(frozen=True)
class GroundFit:
    """A scan's ground plane ``n . p = d`` (``n`` unit, up) and what levels the scan."""

    normal: np.ndarray  # (3,) unit, z > 0, sensor frame
    offset: float  # d: the plane is n . p = d (the sensor height is -d)
    spread_deg: float  # 1-sigma uncertainty of the normal, degrees
    points: int  # ground points that carried the fit

    @property
    def T_level_sensor(self) -> np.ndarray:
        """
        ``(4, 4)``: the rotation that turns ``normal`` onto ``z`` and puts the ground at 0.

        The rotation is the smallest one (about ``normal x z``): it keeps the heading.
        """
        T = np.eye(4)
        T[:3, :3] = rotation_onto_z(self.normal)
        T[2, 3] = -self.offset
        return T


def rotation_onto_z(normal: np.ndarray) -> np.ndarray:
    """Return the smallest rotation taking the unit ``normal`` to ``(0, 0, 1)`` (Rodrigues)."""
    n = np.asarray(normal, dtype=np.float64) / np.linalg.norm(normal)
    axis = np.cross(n, [0.0, 0.0, 1.0])
    sine, cosine = np.linalg.norm(axis), float(n[2])
    if sine < 1e-12:
        return np.eye(3) if cosine > 0 else np.diag([1.0, -1.0, -1.0])
    k = axis / sine
    skew = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + sine * skew + (1.0 - cosine) * skew @ skew


def fit_ground(
    points: np.ndarray,
    labels: np.ndarray,
    ground_ids: np.ndarray,
    config: LevellingConfig,
    iterations: int = 8,
) -> GroundFit | None:
    """
    Fit the ground plane of one scan, or None with too few ground points.

    ``points`` (N, 3) sensor frame, ``labels`` (N,) learning ids. With fewer than
    ``config.min_points`` labeled ground points within ``config.max_radius`` (an unlabeled
    scan), the points below the 20th height percentile near the sensor stand in.
    Tukey-weighted least squares (scale: 1.4826 x the median absolute residual, at least
    5 cm), started from the lowest band's principal plane.
    """
    points = np.asarray(points, dtype=np.float64)
    near = np.einsum('ij,ij->i', points[:, :2], points[:, :2]) <= config.max_radius**2
    ground = near & np.isin(labels, ground_ids)
    if ground.sum() < config.min_points:
        if near.sum() < config.min_points:
            return None
        low = np.percentile(points[near, 2], 20.0)
        ground = near & (points[:, 2] <= low)
        if ground.sum() < config.min_points:
            return None
    candidates = points[ground]
    weights = np.ones(len(candidates))
    normal, offset = np.array([0.0, 0.0, 1.0]), 0.0
    for _ in range(iterations):
        centre = weights @ candidates / weights.sum()
        centred = candidates - centre
        scatter = (centred * weights[:, None]).T @ centred
        normal = np.linalg.eigh(scatter)[1][:, 0]
        if normal[2] < 0:
            normal = -normal
        offset = float(normal @ centre)
        residual = candidates @ normal - offset
        scale = max(1.4826 * float(np.median(np.abs(residual))), 0.05)
        u = residual / (4.685 * scale)
        weights = np.where(np.abs(u) < 1.0, (1.0 - u**2) ** 2, 0.0)
        if weights.sum() < 3:
            return None
    # 1-sigma of the normal: the residual scale over the ground's extent and support
    used = weights > 0
    extent = float(np.sqrt(np.mean(np.sum((candidates[used] - centre) ** 2, axis=1))))
    spread = np.degrees(scale / max(extent, 1e-3) / np.sqrt(max(used.sum(), 1)))
    return GroundFit(normal, offset, float(spread), int(used.sum()))


def tilt_departure(transform: np.ndarray, source: GroundFit, target: GroundFit) -> float:
    """Angle (deg) between the source ground normal under ``transform`` and the target's."""
    moved = np.asarray(transform, dtype=np.float64)[:3, :3] @ source.normal
    cosine = float(np.clip(moved @ target.normal, -1.0, 1.0))
    return float(np.degrees(np.arccos(cosine)))


def tilt_refusal(
    transform: np.ndarray, source: GroundFit, target: GroundFit, config: LevellingConfig
) -> str:
    """Why ``transform`` keeps a tilt the ground fits do not allow ('' when it does not)."""
    departure = tilt_departure(transform, source, target)
    allowed = config.tolerance + 3.0 * float(np.hypot(source.spread_deg, target.spread_deg))
    if departure <= allowed:
        return ''
    return (
        f'tilt off the ground: the pose turns the source ground {departure:.1f} deg away from '
        f"the target's (> {allowed:.1f} deg: levelling.tolerance={config.tolerance:g} plus "
        "the fits' spread)"
    )


def level_transform(
    T_level_source: np.ndarray, T_level_target: np.ndarray, T_levelled: np.ndarray
) -> np.ndarray:
    """``T_target_source`` from a pose between the levelled frames (``(N, 4, 4)`` or one)."""
    return np.linalg.inv(T_level_target) @ T_levelled @ T_level_source
