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
Scale the odometry's point budget with the sensor, from what the first scan shows.

The defaults were tuned on a 64-beam sensor (HDL-64E: about 0.28 deg between neighbouring
points). A sparser sensor (VLP-16: about 0.7 deg; a 70 deg solid-state pattern) has fewer
points per square metre of surface at every range, so the same voxel grids keep a larger
share of its points and its fixed per-scan costs weigh more, while it has less detail to
lose (issue 35, docs/sensors.md).

The scan's **angular spacing** is measured without a sensor model: the solid angle the
scan covers (its elevation band, 1st to 99th percentile, times the share of the azimuth
circle it occupies, in 1 deg bins) divided by its point count, ``sqrt(Omega / N)``. It does
not need a ``ring`` field, and it reads a non-repetitive pattern as well as a spinning one.

What scales, by ``k = clip(spacing / REFERENCE_SPACING_DEG, 1, MAX_SCALE)``:

    fine.downsampling_resolution    x k (the alignment cloud keeps a similar number of
                                    points per beam; 0.5 m -> 1.0 m on a VLP-16)
    keyframe.min_points             / k^2 (a scan has k^2 times fewer points per square
                                    metre: 1000 -> 250 voxels on a VLP-16, whose real scans
                                    keep 900-1000 voxels of 0.3 m)

A partial view (the scan occupies less than :data:`FULL_RING_SHARE` of the azimuth circle,
a solid-state pattern) keeps the sweep alignment on every tracked scan
(``sweep_alignment.steady_correction`` 0): on the 70 deg pattern skipping it on steady scans
cost right poses (docs/sensors.md, session 17), while a full ring's map alignment alone pins
the motion.

A **small scene** (the scan's 90th-percentile range under :data:`SMALL_SCENE_RANGE_M`: a
room, a corridor; the car scenes the defaults were tuned on show 20 m and more, the twelve
real scans of docs/sensors.md 3.4-8.8 m) is scaled by its range too, by
``g = clip(SMALL_SCENE_RANGE_M / p90 range, 1, MAX_RANGE_SCALE)``. A coarse pose's rotation
is pinned by points at the scene's range: the estimator's 0.6 m inlier threshold leaves a
pose a few degrees tilted where the points lie 3-8 m away (1 deg moves a point at 5 m by
9 cm, at 25 m by 44 cm). So the angles that judge a coarse pose or compare two poses
grow by ``g`` (each still means about the same displacement at the scene's range), up to
x1.6: the correction bound is also what refuses the odometry's map alignment when it runs
off in a room (to poses 9.7 and 11.1 deg off on two held-out real pairs: x2, a 10 deg bound,
published one of them; x1.6 refused both):

    odometry.max_correction_rotation   x g (the fine alignment's correction of a coarse
                                       pose, and of a prediction)
    levelling.tolerance                x g (the tilt a coarse pose may keep against the
    geometric_labels.tilt_tolerance     two ground fits)
    near_miss.agreement_rotation       x g (two refined poses in one basin)
    near_miss.offset                   / g (the perturbed starts' translation: 0.6 m ->
                                       0.375 m in a room)
    fine.voxel_size                    / g (the local map's voxels: 1 m -> 0.625 m)
    fine.downsampling_resolution       / g, not x k (half the voxel: 0.3125 m)

The near-miss check's starts shrink by the same ``g``: the surfaces of a room lie closer
together than a street's, and so do the basins of the map alignment's cost; a start 0.6 m
off (a car scene's, a few per cent of its range) fell into a neighbouring basin of a 3.4 m
room (a sixth of its range) and refused right poses as two basins. On the twelve real
scans' 180 held-out pairs (docs/sensors.md) the scaled start raised the right poses
167 -> 172, 0 wrong, none lost.

The map alignment's two grids shrink by ``g`` too, together, as KISS-ICP's voxel follows its
range: the local map's Gaussian voxels (``fine.voxel_size`` / g: 1 m -> 0.625 m) and the
alignment cloud the map is made of and aligned with (``fine.downsampling_resolution``: the
default 0.5 m / g, 0.3125 m; on a small scene ``g`` replaces the spacing factor ``k``). A
map of 1 m voxels from a 1 m alignment cloud (a sparse sensor's, x k) held a 3.4 m room in a
few hundred Gaussians, and its cost's minimum lay degrees off: it moved right poses of
0.3-0.5 deg by 2-11 deg (over the correction bound, or into two basins). The cloud keeps
half the voxel, the defaults' ratio: a cloud as coarse as the voxel (k's 1 m, or both / g)
leaves one centroid or none in a voxel and the alignment turns on which (the XT32M's 2 m /
10 deg pair right with both at 0.485 m, refused at 0.5 m; with a 0.5 m voxel its 18 pairs of
seeds 0-5 15 right with the cloud at 0.485 m, 11 at 0.515 m), while a room's surfaces, seen
near, are dense enough without k's coarser cloud. On the twelve real scans' held-out pairs
172 -> 177 of 180 right, 0 wrong (docs/sensors.md, session 22).
``fine.max_correspondence_distance`` stays (the inlier share that judges a pose keeps its
meaning).

And a cloud without a label field is not labeled geometrically under ``label_source: auto``
(``none``): the geometric labeler's classes are a street's (road, car, building,
vegetation, from 2.7 m out: nearer is the vehicle), and on a room they do not repeat from
a moved sensor (the labels of a real scan and of its moved copy agreed on 29-44 % of the
points at the true pose), so their checks refused right poses.

A parameter the user set (its value differs from the default) is never scaled; so is
none with ``fine.scale_with_sensor: false``. Nothing scales below the reference: a denser
sensor keeps the defaults. Nor does a cloud voxelized before it came: its median
nearest-neighbour distance within 10 m is at least :data:`VOXELIZED_SPACING_M` (about
0.2 m on the 0.3 m KITTI dev scans, within 0.05 m on the twelve real sensors' raw scans).
Its point count says nothing about the sensor, and scaling it lost the real dev chain
(11 -> 5 scans right).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

#: The angular spacing of the sensor the defaults were tuned on (the simulator's HDL-64E,
#: 122k points over 360 x 26.9 deg), degrees.
REFERENCE_SPACING_DEG = 0.28
#: The largest scale factor (a sparser sensor is scaled as this).
MAX_SCALE = 2.0
#: Points closer than this are the platform, not the scene (m).
MIN_RANGE = 0.5
#: A scan with fewer points is not measured (the next one is): not a sweep of a real
#: sensor (the sparsest here, a 70 deg solid-state pattern, has 7k points), and a degenerate
#: scan must not fix the scale for the odometry's life.
MIN_POINTS = 3000
VOXELIZED_SPACING_M = 0.12
NEIGHBOUR_RANGE_M = 10.0  # near points: a raw scan's neighbours are close there
MIN_NEAR_POINTS = 200
#: The parameters that scale: (section, field, power): the default times ``k ** power``.
SCALED = (('fine', 'downsampling_resolution', 1), ('keyframe', 'min_points', -2))
FULL_RING_SHARE = 0.9  # of the 360 one-degree azimuth bins: a spinning sensor's full ring
#: A scan whose 90th-percentile range is under this is a small scene (m): the simulated
#: drives and KITTI show 20 m and more, the twelve real indoor scans 3.4-8.8 m.
SMALL_SCENE_RANGE_M = 12.0
#: The largest range factor ``g`` (a smaller scene is scaled as this): 8 deg of correction
#: at most; the map alignment ran off to poses 9.7-11.1 deg off on held-out real pairs.
MAX_RANGE_SCALE = 1.6
#: What scales with the range factor: (section, field, power): the default times ``g ** power``.
RANGE_SCALED = (
    ('odometry', 'max_correction_rotation', 1),
    ('levelling', 'tolerance', 1),
    ('geometric_labels', 'tilt_tolerance', 1),
    ('near_miss', 'agreement_rotation', 1),
    ('near_miss', 'offset', -1),
    ('fine', 'voxel_size', -1),
    ('fine', 'downsampling_resolution', -1),
)
#: What the range factor scales in place of the spacing factor ``k``: the alignment cloud
#: keeps half the map's voxel (a room's surfaces, seen near, need no coarser cloud).
RANGE_NOT_SPACING = (('fine', 'downsampling_resolution'),)


@dataclass(frozen=True)
class SensorScale:
    """The first scan's angular spacing and the parameter values it picked."""

    spacing_deg: float  # sqrt(solid angle / points), degrees
    points: int  # points the spacing was measured on
    azimuth_share: float = 1.0  # occupied share of the 360 one-degree azimuth bins
    picked: dict[str, Any] = field(default_factory=dict)  # 'section.field' -> value
    scene_range_m: float = np.inf  # 90th-percentile range (m); inf: not measured
    label_field: bool = True  # the scan came with a label field

    @property
    def factor(self) -> float:
        """Return the scale factor ``k`` (1: the defaults)."""
        return float(np.clip(self.spacing_deg / REFERENCE_SPACING_DEG, 1.0, MAX_SCALE))

    @property
    def range_factor(self) -> float:
        """Return the small scene's range factor ``g`` (1: not a small scene)."""
        return range_factor(self.scene_range_m)

    def summary(self) -> str:
        """One line: the spacing, the range, the factors and the values picked."""
        picked = ', '.join(
            f'{k}={v:g}' if not isinstance(v, str) else f'{k}={v}' for k, v in self.picked.items()
        )
        scene = ''
        if np.isfinite(self.scene_range_m):
            scene = f', p90 range {self.scene_range_m:.1f} m'
            if self.range_factor > 1.0:
                scene += f' (small scene: x{self.range_factor:.2f})'
        return (
            f'sensor: {self.points} points, {self.spacing_deg:.2f} deg apart '
            f'(x{self.factor:.2f} of {REFERENCE_SPACING_DEG} deg){scene}: '
            f'{picked or "defaults kept"}'
        )


def angular_spacing_deg(points: np.ndarray) -> tuple[float, int]:
    """
    Return the mean angular spacing of a scan's points (degrees) and the points counted.

    ``sqrt(Omega / N)``: ``Omega`` the solid angle covered (elevation band between the 1st
    and 99th percentile, times the occupied share of 360 one-degree azimuth bins), ``N``
    the finite points beyond :data:`MIN_RANGE` inside that band. 0 with fewer than
    :data:`MIN_POINTS`, and for a cloud voxelized before it came (:func:`voxelized`).
    """
    xyz = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    xyz = xyz[np.all(np.isfinite(xyz), axis=1)]
    ranges = np.linalg.norm(xyz, axis=1)
    xyz, ranges = xyz[ranges > MIN_RANGE], ranges[ranges > MIN_RANGE]
    if len(xyz) < MIN_POINTS:
        return 0.0, len(xyz)
    if voxelized(xyz[ranges < NEIGHBOUR_RANGE_M]):
        return 0.0, len(xyz)
    elevation = np.arcsin(np.clip(xyz[:, 2] / ranges, -1.0, 1.0))
    low, high = np.percentile(elevation, [1.0, 99.0])
    inside = (elevation >= low) & (elevation <= high)
    azimuth = np.degrees(np.arctan2(xyz[inside, 1], xyz[inside, 0]))
    bins = np.unique(np.floor(azimuth).astype(np.int64) % 360)
    solid_angle = (len(bins) / 360.0) * 2.0 * np.pi * (np.sin(high) - np.sin(low))
    count = int(np.count_nonzero(inside))
    if count == 0 or solid_angle <= 0.0:
        return 0.0, count
    return float(np.degrees(np.sqrt(solid_angle / count))), count


def voxelized(xyz: np.ndarray) -> bool:
    """Tell whether a cloud was voxelized before it came (median neighbour distance)."""
    if len(xyz) < MIN_NEAR_POINTS:
        return False
    distances, _ = cKDTree(xyz).query(xyz, k=2)
    return bool(np.median(distances[:, 1]) >= VOXELIZED_SPACING_M)


def azimuth_share(points: np.ndarray) -> float:
    """Return the share of the 360 one-degree azimuth bins the scan's points occupy (0-1)."""
    xyz = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    xyz = xyz[np.all(np.isfinite(xyz), axis=1)]
    xyz = xyz[np.einsum('ij,ij->i', xyz[:, :2], xyz[:, :2]) > MIN_RANGE**2]
    if len(xyz) == 0:
        return 0.0
    azimuth = np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0]))
    return len(np.unique(np.floor(azimuth).astype(np.int64) % 360)) / 360.0


def scene_range_m(points: np.ndarray) -> float:
    """Return the 90th percentile of the scan's ranges beyond :data:`MIN_RANGE` (m; inf: none)."""
    xyz = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    ranges = np.linalg.norm(xyz, axis=1)
    ranges = ranges[np.isfinite(ranges) & (ranges > MIN_RANGE)]
    if len(ranges) < MIN_POINTS:
        return float(np.inf)
    return float(np.percentile(ranges, 90.0))


def range_factor(scene_range: float) -> float:
    """Return ``g = clip(SMALL_SCENE_RANGE_M / scene_range, 1, MAX_RANGE_SCALE)``."""
    if not np.isfinite(scene_range) or scene_range <= 0.0:
        return 1.0
    return float(np.clip(SMALL_SCENE_RANGE_M / scene_range, 1.0, MAX_RANGE_SCALE))


def measure(points: np.ndarray, config: Any, label_field: bool = True) -> SensorScale:
    """
    Measure a scan and return the values the scaling picks for ``config``.

    ``label_field``: the scan came with a label field (``label_source: auto`` reads it).
    """
    spacing, count = angular_spacing_deg(points)
    scale = SensorScale(
        spacing,
        count,
        azimuth_share=azimuth_share(points),
        scene_range_m=scene_range_m(points),
        label_field=label_field,
    )
    return replace(scale, picked=picked_for(config, scale))


def picked_for(config: Any, scale: SensorScale) -> dict[str, Any]:
    """Return the values ``scale`` picks for ``config`` (:func:`picked`)."""
    return picked(config, scale.factor, scale.azimuth_share, scale.range_factor, scale.label_field)


def picked(
    config: Any,
    factor: float,
    azimuth: float = 1.0,
    scene: float = 1.0,
    label_field: bool = True,
) -> dict[str, Any]:
    """
    Return ``{'section.field': value}`` scaled by ``factor`` for ``config``.

    Only the :data:`SCALED` fields still at their defaults (a value the user set wins),
    only with ``fine.scale_with_sensor``, and only when ``factor`` exceeds 1; and, for a
    partial view (``azimuth`` share under :data:`FULL_RING_SHARE`), the sweep alignment on
    every tracked scan (``sweep_alignment.steady_correction`` 0, if still at its default).
    A small scene (range factor ``scene`` above 1) scales the :data:`RANGE_SCALED` values
    by ``scene`` (:data:`RANGE_NOT_SPACING` by ``scene`` alone, not by ``factor``) and,
    without a ``label_field``, sets ``label_source: auto`` to ``none``.
    """
    if not getattr(config.fine, 'scale_with_sensor', False):
        return {}
    out: dict[str, Any] = {}
    steady = getattr(config, 'sweep_alignment', None)
    if steady is not None and azimuth < FULL_RING_SHARE:
        default = _default(type(steady), 'steady_correction')
        if steady.steady_correction == default and default > 0:
            out['sweep_alignment.steady_correction'] = 0.0
    multipliers: dict[tuple[str, str], float] = {}
    if factor > 1.0:
        for section_name, name, power in SCALED:
            multipliers[(section_name, name)] = factor**power
    if scene > 1.0:
        for section_name, name, power in RANGE_SCALED:
            key = (section_name, name)
            spacing = 1.0 if key in RANGE_NOT_SPACING else multipliers.get(key, 1.0)
            multipliers[key] = spacing * scene**power
        source = getattr(config, 'label_source', None)
        if not label_field and source == 'auto' == _default(type(config), 'label_source'):
            out['label_source'] = 'none'  # the street labeler's classes do not repeat indoors
    for (section_name, name), multiplier in multipliers.items():
        section = getattr(config, section_name, None)
        if section is None:
            continue
        default = _default(type(section), name)
        if getattr(section, name) != default:
            continue  # set by the user: it wins
        value = float(default) * multiplier
        out[f'{section_name}.{name}'] = (
            round(value) if isinstance(default, int) else round(value, 3)
        )
    return out


def apply(config: Any, scale: SensorScale | None) -> Any:
    """Return ``config`` with the values ``scale`` picks for it (itself when none)."""
    if scale is None:
        return config
    values = picked_for(config, scale)
    return config.replace(values) if values else config


def _default(section_type: type, name: str) -> Any:
    """Return the declared default of ``section_type.name``."""
    for item in fields(section_type):
        if item.name == name:
            return item.default
    raise KeyError(name)
