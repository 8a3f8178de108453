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
One configuration object for the whole registration core.

Every tunable of the pipeline is a field of a dataclass below; each field
carries its description, unit and valid range in its metadata, so the ROS
layer can declare parameters (with descriptors) from these fields instead of
copying defaults by hand.  Flat names are ``<section>.<field>``, e.g.
``semantic.local_radius``.

Defaults are the paper's KITTI settings (Sec. 4.1): r_local = 0.8 m,
N = 33 rings of L = 1.5 m, K = 2, landmarks trunk/truck/pole/traffic-sign/car,
inlier threshold 0.6 m; SC2-PCR's KITTI settings (Chen et al., CVPR 2022).
"""

from __future__ import annotations

from collections.abc import Sequence
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from mlsemreg_ros.core.deskew import PreprocessConfig
from mlsemreg_ros.core.motion_prior import MotionPriorConfig
from mlsemreg_ros.core.moving_objects import MovingObjectsConfig

# The settings engine, re-exported: most modules import it from here.
from mlsemreg_ros.core.settings import (  # noqa: F401 (re-exported)
    apply_overrides,
    coerce,
    ConfigError,
    load_yaml,
    metadata_errors,
    NODE_NAME,
    param,
    parse_overrides,
    read_parameter_file,
    Settings,
    SettingsT,
)

#: Receptive field of BMR-SS (ring_count * ring_width) must stay within this.
MAX_RECEPTIVE_FIELD_M = 300.0
#: Largest BEV search grid side in cells (a chunk of 12 yaws x 3 channels of 512^2 float32
#: grids and their spectra is ~80 MB).
MAX_BEV_CELLS = 512


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


@dataclass
class MatcherConfig:
    """Descriptor matcher run inside every matching group."""

    kind: str = param(
        'nn',
        'nn: each source keypoint to its nearest target descriptor; mnn: mutual '
        'nearest neighbours.',
        choices=('nn', 'mnn'),
    )


@dataclass
class EstimatorConfig:
    """Robust rigid transform estimation from correspondences."""

    kind: str = param(
        'sc2pcr',
        'sc2pcr: second-order spatial compatibility (Chen et al. 2022); ransac: '
        "Open3D's correspondence RANSAC (baseline).",
        choices=('sc2pcr', 'ransac'),
    )
    inlier_threshold: float = param(
        0.6,
        'Residual below which a correspondence is an inlier (hypothesis selection, diagnostics).',
        unit='m',
        low=0.01,
        high=10.0,
    )
    compatibility_threshold: float = param(
        0.6,
        'SC2-PCR d_thr: length-consistency threshold of the compatibility measures.',
        unit='m',
        low=0.01,
        high=10.0,
    )
    seed_ratio: float = param(
        0.5,
        'Maximum number of SC2-PCR seeds as a share of the graph correspondences.',
        low=0.001,
        high=1.0,
    )
    nms_radius: float = param(
        0.1, 'Non-maximum suppression radius for seed selection.', unit='m', low=0.0, high=10.0
    )
    k1: int = param(30, 'First-stage consensus set size per seed.', low=3, high=1000)
    k2: int = param(20, 'Second-stage consensus set size per seed.', low=3, high=1000)
    power_iterations: int = param(
        10, 'Power iterations for the leading eigenvector.', low=1, high=1000
    )
    second_order_budget: float = param(
        50.0,
        'Work budget of the SC2 stage (cost-model ms, about CPU ms on 2 cores): when '
        'seed_ratio x K seeds would exceed it, only the best-scored seeds that fit are kept '
        '(at least 64); 0 disables the budget.',
        unit='ms',
        low=0.0,
        high=1e6,
    )
    graph_size: int = param(
        500,
        'SC2-PCR builds its compatibility graph (seeds, consensus sets, hypotheses) on '
        'a seeded random subset of at most this many correspondences; every hypothesis is '
        'still scored, and the best refined, on all of them. Cost grows with its square '
        '(0: no limit).',
        low=0,
        high=100000,
    )
    graph_retry_inliers: int = param(
        50,
        'When the graph was sampled (estimator.graph_size) and its best hypothesis has '
        'fewer inliers than this on all correspondences, SC2-PCR runs again on the full '
        'graph: inlier ratios near 1 % leave too few inliers in the sample (0: never).',
        low=0,
        high=100000,
    )
    max_correspondences: int = param(
        10000,
        'Cap on correspondences fed to the estimator; the best ranked '
        '(smallest descriptor distance) are kept.',
        low=10,
        high=100000,
    )
    refine_threshold: float = param(
        1.2,
        'Inlier threshold of the reweighted least-squares refinement.',
        unit='m',
        low=0.01,
        high=20.0,
    )
    refine_iterations: int = param(
        20, 'Maximum reweighted least-squares refinement iterations.', low=0, high=1000
    )
    ransac_iterations: int = param(
        1000000, 'RANSAC maximum iterations (ransac estimator only).', low=1, high=100000000
    )
    ransac_confidence: float = param(
        0.999, 'RANSAC confidence (ransac estimator only).', low=0.0, high=1.0
    )
    min_inliers: int = param(
        40,
        'A registration with fewer inliers is reported as failed. Scans that do not '
        'overlap at all still give 12-49 by chance (2000 keypoints, dev-pair chain); see '
        'also confidence.*.',
        low=3,
        high=100000,
    )


@dataclass
class VerificationConfig:
    """
    Hypothesis verification on the dense labeled scans, after the estimator.

    The estimator's best distinct hypotheses are scored on the voxelized scans:
    ``score = overlap ** overlap_weight * label_agreement ** label_weight``
    (core/verification.py).
    """

    enabled: bool = param(
        True,
        'Verify the best distinct hypotheses of the estimator on the dense labeled scans '
        '(overlap and label agreement); false keeps the choice of the estimator (most inliers).',
    )
    hypotheses: int = param(
        5,
        'Hypotheses verified: the choice of the estimator and up to this many minus one other '
        'distinct ones, by descending inlier count (SC2-PCR: one per seed).',
        low=1,
        high=256,
    )
    distinct_rotation: float = param(
        5.0,
        'Two hypotheses are the same pose when they differ by at most this rotation and '
        'at most verification.distinct_translation (the success bounds).',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    distinct_translation: float = param(
        0.6,
        'Translation bound of the same-pose test (see verification.distinct_rotation).',
        unit='m',
        low=0.0,
        high=100.0,
    )
    sample_points: int = param(
        2000,
        'Source scan points (seeded random subset) scored per hypothesis.',
        low=10,
        high=1000000,
    )
    overlap_distance: float = param(
        0.6,
        'A sampled source point overlaps when a target scan point lies within this '
        'distance of it under the hypothesis.',
        unit='m',
        low=0.01,
        high=10.0,
    )
    range_exponent: float = param(
        2.0,
        'Each sampled source point counts with the weight range^this (distance from the '
        'source sensor) in the overlap and the label agreement. A LiDAR samples a surface at '
        'range r with a density ~1/r^2: 2 makes both shares of the seen surface, not of the '
        'points, so the dense ground around the sensor cannot decide; 0: equal weights.',
        low=0.0,
        high=4.0,
    )
    overlap_weight: float = param(
        1.0, 'Exponent of the overlap fraction in the combined score.', low=0.0, high=10.0
    )
    label_weight: float = param(
        1.0,
        'Exponent of the label agreement in the combined score (0: geometry only).',
        low=0.0,
        high=10.0,
    )
    min_gain: float = param(
        0.05,
        'Another hypothesis replaces the choice of the estimator only when its score is '
        'higher by more than this share (0.05 = 5 %).',
        low=0.0,
        high=10.0,
    )
    compatible_classes: list[str] = param(
        [
            'vegetation~terrain',
            'vegetation~trunk',
            'road~parking',
            'building~fence',
            'pole~traffic-sign',
        ],
        'Label pairs (or groups, a~b~c) that count as agreeing besides equal labels '
        '(class names of the label map).',
    )
    ignored_classes: list[str] = param(
        ['unlabeled'],
        'Classes left out of the label agreement (their points still count for the overlap).',
    )
    seed: int = param(0, 'Seed of the source point sample.', low=0, high=2**31 - 1)

    def __post_init__(self) -> None:
        """Reject a compatibility rule that is not ``class~class[~class...]``."""
        for rule in self.compatible_classes:
            names = rule.split('~')
            if len(names) < 2 or not all(n.strip() for n in names):
                raise ConfigError(
                    f'verification.compatible_classes: {rule!r} is not of the '
                    "form 'class~class' (e.g. 'vegetation~terrain')"
                )


@dataclass
class BevSearchConfig:
    """
    Semantic bird's-eye-view search when the estimator's choice is refused (beyond the paper).

    The scans' static structure is correlated as BEV occupancy grids over every yaw and
    translation (FFT); the best peaks are refined on the correspondences and verified on
    the dense scans like the estimator's hypotheses (core/bev_search.py). Assumes z-up
    sensor frames and a mostly yaw motion between the scans (a ground vehicle).
    """

    enabled: bool = param(
        True,
        "Search the scans when confidence.* refuses the estimator's (verified) choice or "
        'accepts it on weak evidence (bev_search.weak_inliers); a searched pose replaces '
        'it when it scores higher on the dense scans. Needs verification.enabled. Costs '
        '~0.15 s, only on such registrations.',
    )
    weak_inliers: int = param(
        0,
        'Also search when the pose is accepted on fewer sparse inliers than this (0: only '
        'refused poses). On repetitive streets a slide along the street can pass every '
        'threshold with 40-100 inliers of plain FPFH matches (semantic.enabled=false): 100 '
        'catches most of them there, but ML-SemReg at 2000 keypoints has as few on right '
        "poses, and the search then runs on a quarter of the node's global registrations.",
        low=0,
        high=100000,
    )
    classes: list[str] = param(
        ['building~fence', 'vegetation~trunk', 'pole~traffic-sign'],
        'One BEV channel per entry: class names joined by ~ (static structure; '
        'the ground is everywhere and would favour no motion).',
    )
    cell_size: float = param(1.0, 'BEV cell size.', unit='m', low=0.1, high=10.0)
    radius: float = param(
        50.0,
        'Source points farther than this (x or y) from the sensor are left out.',
        unit='m',
        low=1.0,
        high=500.0,
    )
    max_translation: float = param(
        65.0,
        'Largest translation (x and y) searched (the composed dev pairs 60 m apart need 62 m).',
        unit='m',
        low=0.0,
        high=500.0,
    )
    yaw_step: float = param(
        2.0, 'Yaw step of the search over 360 deg.', unit='deg', low=0.1, high=90.0
    )
    peaks_per_yaw: int = param(3, 'Best local correlation maxima kept per yaw.', low=1, high=100)
    coarse_factor: int = param(
        3,
        'Coarse to fine: every coarse_factor x yaw_step is searched first, then the steps '
        'in between only around the bev_search.coarse_yaws best coarse yaws (1: every '
        'yaw_step; odd factors leave no step out).',
        low=1,
        high=30,
    )
    coarse_yaws: int = param(
        12,
        'Coarse yaws (by their best peak) searched again at yaw_step around them. On the '
        'dev pairs the yaw nearest the truth ranked at most 6th of 60 coarse yaws.',
        low=1,
        high=3600,
    )
    hypotheses: int = param(
        64,
        'Peaks (after suppression) refined and verified on the dense scans.',
        low=1,
        high=1024,
    )
    nms_rotation: float = param(
        4.0,
        'A peak within this yaw and bev_search.nms_translation of a better one is dropped.',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    nms_translation: float = param(
        2.0, 'Translation bound of the peak suppression.', unit='m', low=0.0, high=100.0
    )
    guided_peaks: int = param(
        3,
        'When the best pose is still refused after the search: the keypoints are matched '
        'again around this many best searched poses (only within bev_search.guided_radius '
        'of where the pose puts them, compatible labels), and the estimator runs again on '
        'each set (core/guided.py; 0: off).',
        low=0,
        high=64,
    )
    guided_radius: float = param(
        3.0,
        'Guided re-matching: a source keypoint is matched only among the target keypoints '
        'within this distance of where the searched pose puts it (3 m: one more FPFH pair of '
        'the 40 m dev pairs than 2 m, the same GEDI pairs).',
        unit='m',
        low=0.1,
        high=20.0,
    )

    def __post_init__(self) -> None:
        """Reject an empty channel list or an empty class name."""
        if not self.classes:
            raise ConfigError('bev_search.classes: give at least one channel, e.g. building~fence')
        for rule in self.classes:
            if not all(n.strip() for n in rule.split('~')):
                raise ConfigError(
                    f'bev_search.classes: {rule!r} is not of the form '
                    "'class' or 'class~class' (e.g. 'building~fence')"
                )


@dataclass
class ConfidenceConfig:
    """
    When a registration counts as successful (core/confidence.py), besides min_inliers.

    The dense scores are those of hypothesis verification for the chosen pose (overlap of
    the seen surface within verification.overlap_distance, label agreement of it).
    """

    min_inlier_ratio: float = param(
        0.005,
        'Smallest share of the correspondences that are inliers of the chosen pose '
        '(measured: right registrations >= 0.0074, with 20 % of the labels randomized).',
        low=0.0,
        high=1.0,
    )
    min_overlap: float = param(
        0.15,
        "Smallest share of the source scan's seen surface that lies on the target scan "
        'under the chosen pose (measured: right registrations >= 0.196).',
        low=0.0,
        high=1.0,
    )
    min_label_agreement: float = param(
        0.6,
        'Smallest share of the overlapping labeled points whose labels agree (or are '
        'compatible, verification.compatible_classes). Measured: right registrations >= '
        '0.60 (0.71 with the network labels as they are), wrong ones with >= 40 inliers '
        '<= 0.55.',
        low=0.0,
        high=1.0,
    )
    max_tilt: float = param(
        30.0,
        'Largest turn of the up (z) axis between the two scans: a ground vehicle does '
        'not roll over between two scans, but a mirrored or degenerate scene fits best '
        'upside down (180 disables the check).',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    ambiguity_margin: float = param(
        0.3,
        'A rival pose (another candidate, the zero motion, or the chosen pose slid by '
        'confidence.slide_distance) whose verification score reaches (1 - this) x the '
        "chosen pose's makes the registration ambiguous, unless the distinctive structure "
        'decides (docs/hard_pairs.md). 0: only rivals scoring as high; 1: every '
        'rival counts.',
        low=0.0,
        high=1.0,
    )
    rival_translation: float = param(
        3.0,
        'A candidate is a rival when it differs from the chosen pose by more than this '
        'translation (or more than confidence.rival_rotation).',
        unit='m',
        low=0.0,
        high=100.0,
    )
    rival_rotation: float = param(
        10.0, 'Rotation bound of the rival test.', unit='deg', low=0.0, high=180.0
    )
    slide_distance: float = param(
        5.0,
        'The chosen pose slid by this along 8 horizontal directions is a rival too (a '
        'straight street lines up road, curbs and facades at any slide; 0: no slides).',
        unit='m',
        low=0.0,
        high=100.0,
    )
    distinctive_classes: list[str] = param(
        ['pole', 'traffic-sign', 'trunk'],
        'Classes that pin a place down (not ground, not facades): the share of the source '
        'points of these classes that lie on target points of these classes decides '
        'between close rivals.',
    )
    min_distinctive_objects: int = param(
        2,
        'Distinctive source objects (connected points of confidence.distinctive_classes, '
        'e.g. one pole) that the chosen pose must line up with distinctive target points '
        '(within verification.overlap_distance) to decide between close rivals.',
        low=0,
        high=1000,
    )
    min_distinctive_fraction: float = param(
        0.5,
        'Share of the distinctive source objects in the target view (within 1 m of a target '
        'point) that the chosen pose must line up to decide between close rivals: a slide '
        'puts poles beside the target poles (dev pairs: <= 0.2 at the zero motion, >= 0.5 at '
        'the truth).',
        low=0.0,
        high=1.0,
    )
    contradicting_objects: int = param(
        3,
        'A pose that puts at least this many distinctive source objects in the target view '
        '(within 1 m of a target point) and lines up fewer than '
        'confidence.contradicted_fraction of them is refused (0: off).',
        low=0,
        high=1000,
    )
    contradicted_fraction: float = param(
        0.25,
        'See confidence.contradicting_objects. Dev pairs: right poses with 3 or more objects '
        'in view line up >= 0.5 of them (one 40 m pair: 0 of 3), zero-motion slides <= 0.2; '
        'a plain-FPFH slide of a simulated street: 1 of 18.',
        low=0.0,
        high=1.0,
    )
    contradiction_min_ceiling: float = param(
        0.85,
        'The contradiction check (confidence.contradicting_objects) applies only when the '
        "labels' ceiling (the geometric mean of the two scans' label self-agreement, "
        'core/label_model.py) reaches this: noisier labels make objects of mislabeled '
        'distinctive points that cannot line up. Dev pairs: >= 0.90 clean, 0.74-0.81 with '
        '20 % of the source labels random (right poses: 1-6 of 8-31 objects in view lined '
        'up). 0: always; an unknown ceiling keeps the check (docs/label_noise.md).',
        low=0.0,
        high=1.0,
    )
    min_label_ceiling: float = param(
        0.6,
        "Refuse every pose while the labels' ceiling (see "
        'confidence.contradiction_min_ceiling) is below this: the labels are too noisy to '
        'vouch for a pose. 40 m dev pairs with 30 % of the labels flipped (ceiling '
        '0.52-0.57): a 42 m slide lined up 14 of 25 distinctive objects on mislabeled points '
        'and passed every other rule; 20 % flips: 0.64-0.70. 0: never; an unknown ceiling '
        'passes (docs/label_noise.md).',
        low=0.0,
        high=1.0,
    )
    distinctive_gain: float = param(
        2.0,
        "The chosen pose's distinctive share must be at least this many times every close "
        "rival's to decide.",
        low=1.0,
        high=100.0,
    )
    decide_margin: float = param(
        0.5,
        'A candidate pose scoring at least (1 - this) x the best verification score replaces '
        'it when it lines up confidence.min_distinctive_objects and confidence.distinctive_gain '
        'times its distinctive share (a zero-motion slide overlaps more than the truth 40 m '
        'apart, but lines up none of its poles).',
        low=0.0,
        high=1.0,
    )
    degeneracy: str = param(
        'inflate',
        'A fine alignment whose translation is constrained less than '
        'confidence.min_localizability along some direction (Hessian eigenvalues) is '
        'reported in /diagnostics (report), also published with its covariance inflated '
        'by confidence.degeneracy_inflation along that direction (inflate), or refused '
        '(refuse).',
        choices=('report', 'inflate', 'refuse'),
    )
    min_localizability: float = param(
        0.02,
        "Smallest ratio of the translation Hessian's smallest to largest eigenvalue "
        '(1: every direction constrained as well).',
        low=0.0,
        high=1.0,
    )
    degeneracy_inflation: float = param(
        100.0,
        'Covariance factor along the weak direction (confidence.degeneracy=inflate).',
        low=1.0,
        high=1e6,
    )
    label_rule: str = param(
        'relative',
        'How the label agreement is judged (core/label_model.py, docs/label_noise.md): '
        'relative (against the ceiling these labels can give, the geometric mean of the two '
        "scans' self-agreement: min_relative_agreement and label_floor) or fixed "
        '(min_label_agreement).',
        choices=('relative', 'fixed'),
    )
    min_relative_agreement: float = param(
        0.75,
        'relative rule: smallest label agreement of the chosen pose as a share of the '
        "labels' ceiling.",
        low=0.0,
        high=2.0,
    )
    label_floor: float = param(
        0.3,
        'relative rule: the label agreement must also reach this, however noisy the labels.',
        low=0.0,
        high=1.0,
    )
    label_model: str = param(
        'fixed',
        'Label compatibility of the agreement: fixed (verification.compatible_classes) or '
        'adaptive (the odometry adds the confusions learned from the label co-occurrence '
        'at accepted poses, core/label_model.py).',
        choices=('fixed', 'adaptive'),
    )
    label_decay: float = param(
        0.98,
        'adaptive: the learned co-occurrence counts are multiplied by this at every update.',
        low=0.0,
        high=1.0,
    )
    label_min_association: float = param(
        0.15,
        'adaptive: a class pair starts to count as agreeing above this association (how '
        'often a class lies on the other per time it lies on itself, either way), fully at 1.',
        low=0.0,
        high=0.99,
    )
    label_min_count: float = param(
        200.0,
        'adaptive: a class pair is learned only when both classes have at least this much '
        '(range-weighted, in sampled points) co-occurrence with themselves.',
        low=0.0,
        high=1e9,
    )


@dataclass
class FineAlignmentConfig:
    """
    Fine alignment of the dense scans with small_gicp, after the global estimate.

    GICP (Segal et al., RSS 2009) and VGICP (Koide et al., ICRA 2021) as implemented by
    koide3/small_gicp. Pairs: the source scan onto the target scan; odometry: the scan
    onto the local map (an LRU voxel map of the last aligned scans in the odom frame).
    """

    method: str = param(
        'vgicp',
        'Odometry: alignment of each scan to the local map. vgicp (voxelized GICP; '
        'the map is a Gaussian voxel map), gicp, plane_icp (point-to-plane), icp '
        '(point-to-point; with gicp/plane_icp/icp the map points are indexed again every '
        'frame, slower) or off (the estimate as it is, chained scan to keyframe).',
        choices=('vgicp', 'gicp', 'plane_icp', 'icp', 'off'),
    )
    pair_method: str = param(
        'gicp',
        'Pairs (Registration.register, mlsemreg eval-pairs): alignment of the source '
        'scan onto the target scan, both as voxelized at features.voxel_size. gicp, vgicp, '
        'plane_icp, icp or off (the estimate as it is).',
        choices=('gicp', 'vgicp', 'plane_icp', 'icp', 'off'),
    )
    downsampling_resolution: float = param(
        0.5,
        'Odometry: voxel edge to which the scan (already voxelized at '
        'features.voxel_size) is downsampled for the map alignment (0: as it is).',
        unit='m',
        low=0.0,
        high=5.0,
    )
    voxel_size: float = param(
        1.0,
        'VGICP voxel edge: of the local map and of the target scan of a pair; with '
        "gicp/plane_icp/icp, the edge of the local map's point cells.",
        unit='m',
        low=0.05,
        high=10.0,
    )
    num_neighbors: int = param(
        10,
        'Odometry: neighbours of each alignment point for its covariance and normal '
        '(simulated drives: 10 drifted less than 20 at strides 10 and 20, and costs less).',
        low=5,
        high=200,
    )
    pair_num_neighbors: int = param(
        20,
        'Pairs: neighbours of each point for its covariance and normal (KITTI dev pairs: '
        'rotation error 0.24 deg with 20, 0.28 deg with 10).',
        low=5,
        high=200,
    )
    max_correspondence_distance: float = param(
        1.0,
        'Maximum distance of a point to its correspondence (its inlier bound).',
        unit='m',
        low=0.05,
        high=20.0,
    )
    max_iterations: int = param(20, 'Maximum Gauss-Newton iterations.', low=1, high=1000)
    rotation_epsilon: float = param(
        0.01,
        'Convergence: the iterations stop once an update turns less than this (and '
        'moves less than fine.translation_epsilon); the small_gicp default of 0.1 deg leaves '
        'up to ~0.1 deg of error, which drifts at large strides.',
        unit='deg',
        low=1e-6,
        high=10.0,
    )
    translation_epsilon: float = param(
        1e-4,
        'Convergence: the iterations stop once an update moves less than this.',
        unit='m',
        low=1e-8,
        high=1.0,
    )


@dataclass
class LocalMapConfig:
    """The odometry's local map: recent aligned scans in the odom frame, LRU-bounded."""

    horizon: int = param(
        100,
        'Voxels that no inserted scan touched during this many insertions are dropped '
        '(small_gicp LRU horizon).',
        low=1,
        high=100000,
    )
    clear_cycle: int = param(
        10, 'Insertions between two LRU clean-ups of the local map.', low=1, high=100000
    )


@dataclass
class KeyframeConfig:
    """When the current scan replaces the keyframe (after an accepted frame)."""

    policy: str = param(
        'every_frame',
        'every_frame: each registered scan becomes the keyframe (frame-to-frame '
        'odometry); distance: only once it moved keyframe.min_distance or turned '
        'keyframe.min_rotation away from the keyframe.',
        choices=('every_frame', 'distance'),
    )
    min_distance: float = param(
        1.0,
        'distance policy: translation from the keyframe that makes a new keyframe.',
        unit='m',
        low=0.0,
        high=1000.0,
    )
    min_rotation: float = param(
        10.0,
        'distance policy: rotation from the keyframe that makes a new keyframe.',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    min_points: int = param(
        1000,
        'A scan becomes a keyframe only with at least this many points after '
        'voxelization (a degenerate scan would make every later one fail).',
        low=1,
        high=10000000,
    )
    min_keypoints: int = param(
        100,
        'A scan becomes a keyframe only with at least this many keypoints (with a '
        'valid descriptor; at most keypoints.count are asked for).',
        low=3,
        high=100000,
    )
    max_failures: int = param(
        10,
        'After this many rejected frames in a row against one keyframe, the odometry '
        're-initialises on the current scan at the last accepted pose (the map restarts '
        'from it; 0: never).',
        low=0,
        high=100000,
    )


@dataclass
class OdometryConfig:
    """
    Which estimate of a frame the odometry accepts (see core/odometry.py).

    Candidates: the global estimate (ML-SemReg + estimator onto the keyframe) composed with
    the keyframe pose, and the constant-velocity prediction; each is refined against the
    local map. A refined pose is acceptable when the fine alignment kept enough of the scan
    as inliers and moved its initial guess by no more than the correction bounds.
    """

    constant_velocity: bool = param(
        True,
        'Refine the constant-velocity prediction against the local map; when it agrees '
        'with the global estimate only one alignment is paid for, and when the global '
        'estimate fails the prediction can still be accepted.',
    )
    global_registration: str = param(
        'on_demand',
        'always: ML-SemReg + SC2-PCR onto the keyframe for every scan (the '
        'previous default; about twice the time per scan); on_demand: only when the refined '
        'prediction is not trusted (no prediction, refused, corrected by more than '
        'odometry.tracking_translation/rotation, fewer inliers than usual, a gap in the '
        'stamps) and at least every odometry.global_interval scans as a check of the motion '
        'model.',
        choices=('always', 'on_demand'),
    )
    global_interval: int = param(
        30,
        'on_demand: the longest run of scans tracked by the refined prediction alone; '
        'the next one is registered globally (1: every scan).',
        low=1,
        high=100000,
    )
    tracking_translation: float = param(
        0.5,
        'on_demand: a refined prediction that the fine alignment moved further than this '
        'is not trusted alone (the motion model did not hold).',
        unit='m',
        low=0.0,
        high=100.0,
    )
    tracking_rotation: float = param(
        4.0,
        'on_demand: a refined prediction that the fine alignment turned further than this '
        'is not trusted alone (simulated drives: up to 4 deg at the start and end of turns, '
        'with 0.97 of the scan as inliers).',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    tracking_inlier_share: float = param(
        0.9,
        'on_demand: a refined prediction is trusted alone only with at least this share '
        'of the median inlier fraction of the last accepted scans (as good as usual).',
        low=0.0,
        high=1.0,
    )
    tracking_min_inlier_fraction: float = param(
        0.7,
        'on_demand: ... and with at least this share of the scan as map inliers: '
        'tracking is for scans that overlap the map well (simulated drives: 0.97 at 1 m '
        'per scan, 0.80 at 8 m, 0.63 at 16 m; scans 20 m apart stay registered globally).',
        low=0.0,
        high=1.0,
    )
    agreement_translation: float = param(
        0.3,
        'The refined prediction agrees with the global estimate within this '
        'translation (and odometry.agreement_rotation).',
        unit='m',
        low=0.0,
        high=100.0,
    )
    agreement_rotation: float = param(
        1.0,
        'The refined prediction agrees with the global estimate within this rotation.',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    max_correction_translation: float = param(
        1.5,
        'A fine alignment that moves its initial guess further than this is not '
        'accepted (it ran away or started outside its basin).',
        unit='m',
        low=0.0,
        high=100.0,
    )
    max_correction_rotation: float = param(
        5.0,
        'A fine alignment that turns its initial guess further than this is not accepted.',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    min_inlier_fraction: float = param(
        0.25,
        "Share of the scan's alignment points that must have a correspondence "
        '(map or target scan) within fine.max_correspondence_distance after the fine '
        'alignment.',
        low=0.0,
        high=1.0,
    )
    min_relative_inlier_fraction: float = param(
        0.6,
        'The inlier fraction must also reach this share of the median inlier fraction '
        'of the last accepted frames: a pose that overlaps the map only by chance (the '
        'mirror pose of a street, a different street) keeps far fewer inliers than the '
        'frames before it (0: no such check).',
        low=0.0,
        high=1.0,
    )
    covariance_scale: float = param(
        7.0,
        'Factor on the pose covariance inv(H) * 2E / (n - 6) of the fine alignment '
        '(H Hessian, E final error, n inliers). Calibrated on the simulated drives (seeds '
        '0-2, strides 1-20, 756 frames): the mean NEES of the relative pose errors was 41 '
        'with factor 1, about 6 (consistent) with 7.',
        low=1e-6,
        high=1e6,
    )


@dataclass
class MapConfig:
    """
    The keyframe map: store, place recognition, relocalization, loop closure (docs/maps.md).

    Keyframes are kept in the map frame with their labeled, voxelized scans; a query is
    relocalized without an initial guess by registering it onto the keyframes whose
    semantic scan context is most similar.
    """

    load_path: str = param(
        '',
        'Map folder loaded at startup (docs/maps.md); the node starts unlocalized and '
        "relocalizes against it ('': no map).",
    )
    save_path: str = param(
        '', "Map folder written by the mlsemreg/save_map service ('': the service refuses)."
    )
    frame_id: str = param('map', 'Frame of the map (parent of odom_frame in TF).')
    max_keyframes: int = param(
        5000,
        'Most keyframes kept; beyond it the most redundant one (closest to another) is dropped.',
        low=1,
        high=10000000,
    )
    max_memory_mb: float = param(
        1024.0,
        "Most memory of the keyframes' points, labels and descriptors; beyond it the most "
        'redundant keyframe is dropped (prepared scans are cached apart, map.prepared_cache).',
        unit='MB',
        low=1.0,
        high=1e6,
    )
    keyframe_distance: float = param(
        2.0,
        'An accepted scan becomes a map keyframe once it is this far from the last one.',
        unit='m',
        low=0.0,
        high=1000.0,
    )
    keyframe_rotation: float = param(
        30.0,
        '... or turned this much from it.',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    prepared_cache: int = param(
        16,
        'Prepared keyframe scans (keypoints, descriptors, KD-trees) kept for registration; '
        'the least recently used are dropped and prepared again when needed.',
        low=1,
        high=100000,
    )
    rings: int = param(20, 'Rings of the semantic scan context.', low=2, high=200)
    sectors: int = param(60, 'Sectors of the semantic scan context.', low=4, high=720)
    max_radius: float = param(
        60.0,
        'Radius of the semantic scan context (points farther away are left out).',
        unit='m',
        low=1.0,
        high=500.0,
    )
    descriptor_candidates: int = param(
        30,
        'Nearest keyframes by ring key (KD-tree) that are re-ranked by the scan context '
        'over every yaw.',
        low=1,
        high=100000,
    )
    candidates: int = param(
        5,
        'Keyframes a relocalization registers onto, best scan context first (the cost of '
        'a relocalization is at most this many registrations, whatever the map size).',
        low=1,
        high=1000,
    )
    candidate_separation: float = param(
        3.0,
        'A candidate keyframe closer than this to a better one is skipped (its scan '
        'would give the same answer).',
        unit='m',
        low=0.0,
        high=1000.0,
    )
    stop_at_first_accepted: bool = param(
        True,
        'Stop at the first candidate whose registration is accepted (else register onto '
        'every candidate and keep the accepted one with the most inliers).',
    )
    relocalize_after_failures: int = param(
        2,
        'A lost odometry (this many rejected scans in a row) relocalizes against its own '
        'keyframes instead of waiting for keyframe.max_failures (0: never).',
        low=0,
        high=100000,
    )
    track_distance: float = param(
        10.0,
        'Localized on a loaded map: every this many metres travelled the scan is '
        'registered onto the nearby map keyframes to correct map -> odom (0: never).',
        unit='m',
        low=0.0,
        high=1e6,
    )
    loop_closure: bool = param(
        True, 'Close loops while mapping: revisits found by place recognition, verified.'
    )
    loop_min_travel: float = param(
        30.0,
        'A keyframe is a loop candidate only if the trajectory travelled at least this '
        'far since it.',
        unit='m',
        low=0.0,
        high=1e6,
    )
    loop_search_radius: float = param(
        50.0,
        'Loop candidates farther than this from the current pose (by the drifting '
        'odometry) are not tried (0: any distance).',
        unit='m',
        low=0.0,
        high=1e6,
    )
    loop_candidates: int = param(
        2,
        'Loop candidates registered per new keyframe (best scan context first).',
        low=1,
        high=100,
    )
    loop_min_similarity: float = param(
        0.4,
        'A loop candidate is registered only if its scan context similarity reaches this.',
        low=0.0,
        high=1.0,
    )
    odometry_sigma_translation: float = param(
        0.05,
        'Pose graph: standard deviation of an odometry edge per metre travelled.',
        unit='m/m',
        low=1e-6,
        high=10.0,
    )
    odometry_sigma_rotation: float = param(
        0.2,
        'Pose graph: standard deviation of an odometry edge rotation per metre travelled.',
        unit='deg/m',
        low=1e-6,
        high=100.0,
    )
    loop_sigma_translation: float = param(
        0.1, 'Pose graph: standard deviation of a loop edge.', unit='m', low=1e-6, high=10.0
    )
    loop_sigma_rotation: float = param(
        0.5,
        'Pose graph: standard deviation of a loop edge rotation.',
        unit='deg',
        low=1e-6,
        high=100.0,
    )


#: Parameters that existed once, with what replaced them (reported when they are set).
REMOVED: dict[str, str] = {
    'refine.icp': 'replaced by fine.method (small_gicp GICP/VGICP; off disables it)',
    'refine.max_distance': 'replaced by fine.max_correspondence_distance',
    'refine.iterations': 'replaced by fine.max_iterations',
}


@dataclass
class RegistrationConfig(Settings):
    """Everything the core needs (registration and odometry); built from a nested or flat dict."""

    threads: int = param(
        0,
        'Threads of every pool of the core and of the fine alignment (0: all cores).',
        low=0,
        high=256,
    )
    preprocess: PreprocessConfig = field(default_factory=PreprocessConfig)
    semantic: SemanticConfig = field(default_factory=SemanticConfig)
    features: FeatureConfig = field(default_factory=FeatureConfig)
    keypoints: KeypointConfig = field(default_factory=KeypointConfig)
    matcher: MatcherConfig = field(default_factory=MatcherConfig)
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    verification: VerificationConfig = field(default_factory=VerificationConfig)
    bev_search: BevSearchConfig = field(default_factory=BevSearchConfig)
    confidence: ConfidenceConfig = field(default_factory=ConfidenceConfig)
    fine: FineAlignmentConfig = field(default_factory=FineAlignmentConfig)
    local_map: LocalMapConfig = field(default_factory=LocalMapConfig)
    keyframe: KeyframeConfig = field(default_factory=KeyframeConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    motion_prior: MotionPriorConfig = field(default_factory=MotionPriorConfig)
    moving_objects: MovingObjectsConfig = field(default_factory=MovingObjectsConfig)
    map: MapConfig = field(default_factory=MapConfig)  # noqa: A003, RUF100 (the section name)

    REMOVED: ClassVar[dict[str, str]] = REMOVED

    @classmethod
    def from_yaml(cls, path: str | Path) -> RegistrationConfig:
        """
        Load the core parameters of a node parameter file (or a plain config YAML).

        Node-level keys (frames, topics, QoS) are ignored here; the ROS layer reads them.
        """
        return cls.from_file(path)

    def check(self) -> list[str]:
        """Cross-field rules of the core."""
        errors = []
        sem, est = self.semantic, self.estimator
        field_m = sem.ring_count * sem.ring_width
        if field_m > MAX_RECEPTIVE_FIELD_M:
            errors.append(
                f'semantic.ring_count x semantic.ring_width = {field_m:g} m exceeds the '
                f'{MAX_RECEPTIVE_FIELD_M:g} m receptive-field limit'
            )
        if est.k2 > est.k1:
            errors.append(f'estimator.k2={est.k2} must not exceed estimator.k1={est.k1}')
        bev = self.bev_search
        cells = 2.0 * (bev.radius + bev.max_translation) / bev.cell_size
        if cells > MAX_BEV_CELLS:
            errors.append(
                f'bev_search: 2 x (radius + max_translation) / cell_size = {cells:.0f} cells '
                f'a side exceeds {MAX_BEV_CELLS} (memory grows with its square); raise '
                'bev_search.cell_size or lower bev_search.radius / bev_search.max_translation'
            )
        if self.features.min_range >= self.features.max_range:
            errors.append(
                f'features.min_range={self.features.min_range:g} must be below '
                f'features.max_range={self.features.max_range:g}'
            )
        overlap = set(sem.landmark_classes) & set(sem.ignored_classes)
        if overlap:
            errors.append(f'classes both landmark and ignored: {sorted(overlap)}')
        overlap = set(sem.undefined_classes) & set(sem.ignored_classes)
        if overlap:
            errors.append(f'classes both undefined and ignored: {sorted(overlap)}')
        return errors


def field_of(key: str) -> dataclasses.Field:
    """Return the core config field behind a flat name such as ``semantic.top_k``."""
    return RegistrationConfig.field_of(key)


def iter_fields() -> list[tuple[str, dataclasses.Field, Any]]:
    """``(flat_name, field, default)`` for every core parameter, in declaration order."""
    return RegistrationConfig.parameter_fields()


def split_params_yaml(path: str | Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """
    Read a parameter YAML into ``(core_parameters, node_level_params)``.

    Core parameters are nested (sections and top-level fields such as ``threads``);
    the rest (node-level parameters) is returned flat (``qos.depth``).
    """
    data = read_parameter_file(path)
    core_keys = RegistrationConfig.top_level_names()
    core = {k: v for k, v in data.items() if k in core_keys}
    rest: dict[str, Any] = {}

    def flatten(prefix: str, value: Any) -> None:
        if isinstance(value, dict):
            for k, v in value.items():
                flatten(f'{prefix}.{k}' if prefix else k, v)
        else:
            rest[prefix] = value

    for k, v in data.items():
        if k not in core_keys:
            flatten(k, v)
    return core, rest


def load_config(
    path: str | Path | None = None, overrides: Sequence[str] = ()
) -> RegistrationConfig:
    """
    Load the core config: defaults < parameter file < ``--set`` overrides.

    ``path`` is a node parameter file (``config/params.yaml`` layout) or a plain mapping of
    core sections; node-level keys in it are ignored. ``overrides`` are ``KEY=VALUE``
    strings (:func:`apply_overrides`); a node-level or unknown key there is an error.
    """
    config = RegistrationConfig.from_file(path) if path is not None else RegistrationConfig()
    return apply_overrides(config, overrides)


def load_settings(
    kinds: tuple[type[Settings], ...],
    path: str | Path | None = None,
    overrides: Sequence[str] = (),
) -> tuple[Settings, ...]:
    """
    Load several settings at once (the one loader of the tools' ``--config``/``--set``).

    Each kind reads its own keys of the parameter file (:meth:`Settings.from_file`), then
    every override goes to the kind that declares it (:func:`apply_overrides`).
    """
    parts = tuple(kind.from_file(path) if path is not None else kind() for kind in kinds)
    return apply_overrides(parts, overrides)
