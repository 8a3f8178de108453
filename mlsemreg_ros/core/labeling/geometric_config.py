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
The ``geometric_labels`` section: the geometric labeler's tunables (docs/labels.md).

Assembled by :class:`~mlsemreg_ros.core.config.RegistrationConfig` (core/config.py). The
ground segmentation follows Patchwork++ (Lee et al., IROS 2022): a concentric zone model of
four zones, a plane fitted to each bin's lowest points, the sensor height estimated from the
near bins.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core.settings import param

#: The values of ``label_source`` (RegistrationConfig): where a scan's labels come from.
LABEL_SOURCES = ('auto', 'field', 'geometric', 'onnx', 'none')


@dataclass
class GeometricLabelsConfig:
    """The geometric labeler: ground by region-wise plane fits, the rest by shape."""

    sensor_height: float = param(
        0.0,
        'Height of the sensor above the ground; 0 estimates it per scan from the ground '
        'planes of the near bins (Patchwork++).',
        unit='m',
        low=0.0,
        high=10.0,
    )
    min_range: float = param(
        2.7,
        'Inner radius of the concentric zones; nearer points (the vehicle itself) are '
        'judged against the estimated ground height.',
        unit='m',
        low=0.0,
        high=20.0,
    )
    max_range: float = param(
        80.0,
        'Outer radius of the concentric zones and of the column grid; farther points stay '
        'unlabeled.',
        unit='m',
        low=10.0,
        high=300.0,
    )
    ground_distance: float = param(
        0.2,
        "Largest distance of a ground point from its bin's fitted plane (also the seeds' "
        "height above the bin's lowest points).",
        unit='m',
        low=0.02,
        high=1.0,
    )
    max_ground_slope: float = param(
        30.0,
        'Steepest fitted plane that is still ground.',
        unit='deg',
        low=1.0,
        high=80.0,
    )
    cell_size: float = param(
        1.0,
        'Edge of the voxel cells whose eigenvalue features (linearity, planarity, scatter) '
        'label the points above the ground, and of the columns of the object clusters.',
        unit='m',
        low=0.2,
        high=5.0,
    )
    road_roughness: float = param(
        0.0,
        'Ground cells rougher than this (standard deviation across their plane) are '
        'terrain, smoother ones road; 0 labels all ground road (the split was unstable '
        'on real scans, docs/labels.md).',
        unit='m',
        low=0.0,
        high=1.0,
    )
    trust: float = param(
        0.5,
        'Weight of geometric labels as evidence, against clean network labels (1): their '
        'label checks give way to the geometric evidence by this much '
        '(core/labeling/quality.py, docs/labels.md).',
        low=0.0,
        high=1.0,
    )
    tilt_tolerance: float = param(
        9.0,
        'Tilt a pose may keep against the two ground fits when the ground comes from the '
        'geometric labeler (its ground holds slopes and sidewalks: the fits of the dev '
        "pairs are up to 6.3 deg apart at the true pose, with the network's road labels, 2.9); "
        'levelling.tolerance when larger (docs/labels.md).',
        unit='deg',
        low=0.0,
        high=45.0,
    )
    vehicle_max_length: float = param(
        6.5,
        'Longest footprint side of a compact cluster above the ground that is a vehicle.',
        unit='m',
        low=1.0,
        high=30.0,
    )
