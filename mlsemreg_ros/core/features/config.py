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
The ``features`` and ``keypoints`` sections of the core config.

Assembled by :class:`~mlsemreg_ros.core.config.RegistrationConfig` (core/config.py),
which re-exports them; fields are :func:`~mlsemreg_ros.core.settings.param` declarations.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core.settings import param


@dataclass
class FeatureConfig:
    """Preprocessing and local geometric descriptors."""

    voxel_size: float = param(
        0.3,
        'Voxel size of the downsampled scan (0 disables downsampling).',
        unit='m',
        low=0.0,
        high=5.0,
    )
    descriptor: str = param(
        'fpfh',
        'Local geometric descriptor computed at the keypoints: fpfh (vectorized, '
        'radius neighbourhoods, normals facing the sensor, histograms on a support voxel '
        'grid) or fpfh_open3d (Open3D compute_fpfh_feature at the keypoints, as the '
        'reference implementation; slower).',
        choices=('fpfh', 'fpfh_open3d'),
    )
    normal_radius: float = param(
        0.9, 'Normal estimation radius for FPFH.', unit='m', low=0.01, high=20.0
    )
    normal_max_nn: int = param(
        30,
        'Maximum neighbours for normal estimation (fpfh_open3d only; fpfh uses every '
        'neighbour within the radius).',
        low=3,
        high=1000,
    )
    feature_radius: float = param(1.5, 'FPFH feature radius.', unit='m', low=0.01, high=50.0)
    feature_max_nn: int = param(
        100,
        'Maximum neighbours for FPFH (fpfh_open3d only; fpfh uses every neighbour '
        'within the radius).',
        low=3,
        high=5000,
    )
    support_voxel_size: float = param(
        0.5,
        'fpfh: the point-pair histograms of the neighbours are computed on the '
        'centroids of a voxel grid of this edge (0: on the scan points themselves; the cost '
        'grows about with 1/edge^2).',
        unit='m',
        low=0.0,
        high=5.0,
    )
    snap_keypoints: bool = param(
        True,
        'fpfh with a support grid: each keypoint takes the FPFH of its nearest support '
        'centroid (no neighbourhood search per keypoint; about 3x faster at 5000 keypoints). '
        'false computes its own normal and SPFH at its position (dev pairs: the same RR, '
        '100 %, or 90 % without the BEV search; FPFH ~1.5x slower).',
    )
    max_range: float = param(
        200.0,
        'Points farther than this from the sensor (the origin of the cloud frame) are '
        'dropped before voxelization, as are points with a NaN/inf coordinate, and counted; '
        'this also bounds the voxel grid (one point at 1e30 collapses it).',
        unit='m',
        low=1.0,
        high=1e6,
    )
    min_range: float = param(
        0.0,
        'Points closer than this to the sensor are dropped before voxelization and '
        'counted (0 keeps them all; e.g. returns from the vehicle itself). Must be below '
        'features.max_range.',
        unit='m',
        low=0.0,
        high=100.0,
    )


@dataclass
class KeypointConfig:
    """Keypoint selection from the downsampled scan."""

    count: int = param(
        2000,
        'Keypoints per scan (all points when the scan has fewer). 2000 keeps the node '
        'under 150 ms per frame on 2 cores; the paper uses 5000 (eval-pairs uses the '
        'keypoints stored in the pair files).',
        low=10,
        high=100000,
    )
    sampling: str = param(
        'random',
        'Keypoint sampling: random (seeded, as in the paper) or voxel '
        '(one point per keypoint voxel, spatially uniform).',
        choices=('random', 'voxel'),
    )
    voxel_size: float = param(
        1.0, 'Voxel size for voxel keypoint sampling.', unit='m', low=0.05, high=20.0
    )
    seed: int = param(0, 'Seed of the keypoint sampler.', low=0, high=2**31 - 1)
