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
The ``semantic`` and ``matcher`` sections of the core config.

Assembled by :class:`~mlsemreg_ros.core.config.RegistrationConfig` (core/config.py),
which re-exports them; fields are :func:`~mlsemreg_ros.core.settings.param` declarations.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core.settings import param


@dataclass
class SemanticConfig:
    """ML-SemReg: Group Matching (Local-SS) and Mask Matching (BMR-SS)."""

    enabled: bool = param(
        True, 'Use ML-SemReg (GM + MM); false gives the plain matcher (the paper baseline).'
    )
    label_scheme: str = param(
        'auto',
        'Label ids of the input: SemanticKITTI learning ids (0-19), raw ids '
        '(instance id in the upper 16 bits) or auto-detect per scan.',
        choices=('auto', 'learning', 'raw'),
    )
    local_radius: float = param(
        0.8,
        'Local-SS search radius r_local around each keypoint (eq. 1).',
        unit='m',
        low=0.01,
        high=10.0,
    )
    ring_count: int = param(33, 'Number N of BMR-SS rings (eq. 5).', low=1, high=256)
    ring_width: float = param(
        1.5, 'Width L of each BMR-SS ring (eq. 5).', unit='m', low=0.01, high=50.0
    )
    top_k: int = param(
        2,
        'Mask Matching keeps, per row, every target whose scene similarity is within '
        'top_k - 1 of the row maximum (top-K levels, ties included).',
        low=1,
        high=64,
    )
    landmark_classes: list[str] = param(
        ['trunk', 'truck', 'pole', 'traffic-sign', 'car'],
        'Classes clustered into BMR-SS landmarks (class names of the label map).',
    )
    ignored_classes: list[str] = param([], 'Classes dropped from Local-SS (e.g. dynamic classes).')
    undefined_classes: list[str] = param(
        ['unlabeled'], 'Classes that make a keypoint a member of every matching group.'
    )
    cluster_radius: float = param(
        1.5,
        'Euclidean clustering radius of landmark points (xy-plane).',
        unit='m',
        low=0.05,
        high=20.0,
    )
    cluster_min_points: int = param(
        3, 'Minimum points of a landmark cluster; smaller clusters are noise.', low=1, high=100000
    )
    min_landmarks: int = param(
        1,
        'Mask Matching needs at least this many landmarks (of classes both scans share) '
        'in each scan; below it Group Matching runs alone. Rows whose own scene evidence is '
        'thin (row maximum <= top_k - 1) are unmasked anyway by the top-K-levels rule.',
        low=1,
        high=100000,
    )
    landmark_min_share: float = param(
        0.15,
        'Only confidently labeled points are clustered into landmarks: at least this share '
        'of the scan points within landmark_support_radius carry the same class (0: every '
        'point of a landmark class). With 20-30 % of the labels flipped it keeps the inlier '
        'ratio at 7 % instead of 0.5 % (docs/label_noise.md).',
        low=0.0,
        high=1.0,
    )
    landmark_support_radius: float = param(
        0.6,
        'Neighbourhood radius of the landmark_min_share test.',
        unit='m',
        low=0.05,
        high=10.0,
    )


@dataclass
class MatcherConfig:
    """Descriptor matcher run inside every matching group."""

    kind: str = param(
        'nn',
        'nn: each source keypoint to its nearest target descriptor; mnn: mutual '
        'nearest neighbours.',
        choices=('nn', 'mnn'),
    )
