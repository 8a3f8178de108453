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

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

#: Receptive field of BMR-SS (ring_count * ring_width) must stay within this.
MAX_RECEPTIVE_FIELD_M = 300.0

#: Top-level key of the node's parameter file (``config/params.yaml``).
NODE_NAME = 'mlsemreg_node'


class ConfigError(ValueError):
    """A configuration value is unknown, of the wrong type or out of range."""


def param(
    default: Any,
    description: str,
    *,
    unit: str = '',
    low: float | None = None,
    high: float | None = None,
    choices: tuple[str, ...] | None = None,
) -> Any:
    """Declare a config field with the metadata the ROS layer turns into a descriptor."""
    meta = {'description': description, 'unit': unit, 'low': low, 'high': high, 'choices': choices}
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass
class SemanticConfig:
    """ML-SemReg: Group Matching (Local-SS) and Mask Matching (BMR-SS)."""

    enabled: bool = param(
        True, 'Use ML-SemReg (GM + MM); false gives the plain matcher (the paper baseline).')
    label_scheme: str = param(
        'auto', 'Label ids of the input: SemanticKITTI learning ids (0-19), raw ids '
        '(instance id in the upper 16 bits) or auto-detect per scan.',
        choices=('auto', 'learning', 'raw'))
    local_radius: float = param(
        0.8, 'Local-SS search radius r_local around each keypoint (eq. 1).',
        unit='m', low=0.01, high=10.0)
    ring_count: int = param(
        33, 'Number N of BMR-SS rings (eq. 4).', low=1, high=256)
    ring_width: float = param(
        1.5, 'Width L of each BMR-SS ring (eq. 4).', unit='m', low=0.01, high=50.0)
    top_k: int = param(
        2, 'Mask Matching keeps, per row, every target whose scene similarity is within '
        'top_k - 1 of the row maximum (top-K levels, ties included).', low=1, high=64)
    landmark_classes: list[str] = param(
        ['trunk', 'truck', 'pole', 'traffic-sign', 'car'],
        'Classes clustered into BMR-SS landmarks (class names of the label map).')
    ignored_classes: list[str] = param(
        [], 'Classes dropped from Local-SS (e.g. dynamic classes).')
    undefined_classes: list[str] = param(
        ['unlabeled'], 'Classes that make a keypoint a member of every matching group.')
    cluster_radius: float = param(
        1.5, 'Euclidean clustering radius of landmark points (xy-plane).',
        unit='m', low=0.05, high=20.0)
    cluster_min_points: int = param(
        3, 'Minimum points of a landmark cluster; smaller clusters are noise.',
        low=1, high=100000)
    min_landmarks: int = param(
        1, 'Mask Matching needs at least this many landmarks (of classes both scans share) '
        'in each scan; below it Group Matching runs alone. Rows whose own scene evidence is '
        'thin (row maximum <= top_k - 1) are unmasked anyway by the top-K-levels rule.',
        low=1, high=100000)


@dataclass
class FeatureConfig:
    """Preprocessing and local geometric descriptors."""

    voxel_size: float = param(
        0.3, 'Voxel size of the downsampled scan (0 disables downsampling).',
        unit='m', low=0.0, high=5.0)
    descriptor: str = param(
        'fpfh', 'Local geometric descriptor computed at the keypoints: fpfh (vectorized, '
        'radius neighbourhoods, normals facing the sensor, histograms on a support voxel '
        'grid) or fpfh_open3d (Open3D compute_fpfh_feature at the keypoints, as the '
        'reference implementation; slower).', choices=('fpfh', 'fpfh_open3d'))
    normal_radius: float = param(
        0.9, 'Normal estimation radius for FPFH.', unit='m', low=0.01, high=20.0)
    normal_max_nn: int = param(
        30, 'Maximum neighbours for normal estimation (fpfh_open3d only; fpfh uses every '
        'neighbour within the radius).', low=3, high=1000)
    feature_radius: float = param(
        1.5, 'FPFH feature radius.', unit='m', low=0.01, high=50.0)
    feature_max_nn: int = param(
        100, 'Maximum neighbours for FPFH (fpfh_open3d only; fpfh uses every neighbour '
        'within the radius).', low=3, high=5000)
    support_voxel_size: float = param(
        0.5, 'fpfh: the point-pair histograms of the neighbours are computed on the '
        'centroids of a voxel grid of this edge (0: on the scan points themselves; the cost '
        'grows about with 1/edge^2).', unit='m', low=0.0, high=5.0)
    snap_keypoints: bool = param(
        True, 'fpfh with a support grid: each keypoint takes the FPFH of its nearest support '
        'centroid (no neighbourhood search per keypoint; about 3x faster at 5000 keypoints). '
        'false computes its own normal and SPFH at its position (dev pairs: FPFH RR 90 % '
        'instead of 80 %).')


@dataclass
class KeypointConfig:
    """Keypoint selection from the downsampled scan."""

    count: int = param(
        2000, 'Keypoints per scan (all points when the scan has fewer). 2000 keeps the node '
        'under 150 ms per frame on 2 cores; the paper uses 5000 (eval-pairs uses the '
        'keypoints stored in the pair files).', low=10, high=100000)
    sampling: str = param(
        'random', 'Keypoint sampling: random (seeded, as in the paper) or voxel '
        '(one point per keypoint voxel, spatially uniform).', choices=('random', 'voxel'))
    voxel_size: float = param(
        1.0, 'Voxel size for voxel keypoint sampling.', unit='m', low=0.05, high=20.0)
    seed: int = param(0, 'Seed of the keypoint sampler.', low=0, high=2**31 - 1)


@dataclass
class MatcherConfig:
    """Descriptor matcher run inside every matching group."""

    kind: str = param(
        'nn', 'nn: each source keypoint to its nearest target descriptor; mnn: mutual '
        'nearest neighbours.', choices=('nn', 'mnn'))


@dataclass
class EstimatorConfig:
    """Robust rigid transform estimation from correspondences."""

    kind: str = param(
        'sc2pcr', 'sc2pcr: second-order spatial compatibility (Chen et al. 2022); ransac: '
        "Open3D's correspondence RANSAC (baseline).", choices=('sc2pcr', 'ransac'))
    inlier_threshold: float = param(
        0.6, 'Residual below which a correspondence is an inlier (hypothesis selection, '
        'diagnostics).', unit='m', low=0.01, high=10.0)
    compatibility_threshold: float = param(
        0.6, 'SC2-PCR d_thr: length-consistency threshold of the compatibility measures.',
        unit='m', low=0.01, high=10.0)
    seed_ratio: float = param(
        0.5, 'Maximum number of SC2-PCR seeds as a share of the graph correspondences.',
        low=0.001, high=1.0)
    nms_radius: float = param(
        0.1, 'Non-maximum suppression radius for seed selection.', unit='m',
        low=0.0, high=10.0)
    k1: int = param(30, 'First-stage consensus set size per seed.', low=3, high=1000)
    k2: int = param(20, 'Second-stage consensus set size per seed.', low=3, high=1000)
    power_iterations: int = param(
        10, 'Power iterations for the leading eigenvector.', low=1, high=1000)
    second_order_budget: float = param(
        50.0, 'Work budget of the SC2 stage (cost-model ms, about CPU ms on 2 cores): when '
        'seed_ratio x K seeds would exceed it, only the best-scored seeds that fit are kept '
        '(at least 64); 0 disables the budget.', unit='ms', low=0.0, high=1e6)
    graph_size: int = param(
        500, 'SC2-PCR builds its compatibility graph (seeds, consensus sets, hypotheses) on '
        'a seeded random subset of at most this many correspondences; every hypothesis is '
        'still scored, and the best refined, on all of them. Cost grows with its square '
        '(0: no limit).', low=0, high=100000)
    graph_retry_inliers: int = param(
        50, 'When the graph was sampled (estimator.graph_size) and its best hypothesis has '
        'fewer inliers than this on all correspondences, SC2-PCR runs again on the full '
        'graph: inlier ratios near 1 % leave too few inliers in the sample (0: never).',
        low=0, high=100000)
    max_correspondences: int = param(
        10000, 'Cap on correspondences fed to the estimator; the best ranked '
        '(smallest descriptor distance) are kept.', low=10, high=100000)
    refine_threshold: float = param(
        1.2, 'Inlier threshold of the reweighted least-squares refinement.', unit='m',
        low=0.01, high=20.0)
    refine_iterations: int = param(
        20, 'Maximum reweighted least-squares refinement iterations.', low=0, high=1000)
    ransac_iterations: int = param(
        1000000, 'RANSAC maximum iterations (ransac estimator only).', low=1, high=100000000)
    ransac_confidence: float = param(
        0.999, 'RANSAC confidence (ransac estimator only).', low=0.0, high=1.0)
    min_inliers: int = param(
        10, 'A registration with fewer inliers is reported as failed.', low=3, high=100000)


@dataclass
class VerificationConfig:
    """
    Hypothesis verification on the dense labeled scans, after the estimator.

    The estimator's best distinct hypotheses are scored on the voxelized scans:
    ``score = overlap ** overlap_weight * label_agreement ** label_weight``
    (core/verification.py).
    """

    enabled: bool = param(
        True, 'Verify the best distinct hypotheses of the estimator on the dense labeled scans '
        '(overlap and label agreement); false keeps the choice of the estimator (most inliers).')
    hypotheses: int = param(
        5, 'Hypotheses verified: the choice of the estimator and up to this many minus one other '
        'distinct ones, by descending inlier count (SC2-PCR: one per seed).', low=1, high=256)
    distinct_rotation: float = param(
        5.0, 'Two hypotheses are the same pose when they differ by at most this rotation and '
        'at most verification.distinct_translation (the success bounds).', unit='deg',
        low=0.0, high=180.0)
    distinct_translation: float = param(
        0.6, 'Translation bound of the same-pose test (see verification.distinct_rotation).',
        unit='m', low=0.0, high=100.0)
    sample_points: int = param(
        2000, 'Source scan points (seeded random subset) scored per hypothesis.',
        low=10, high=1000000)
    overlap_distance: float = param(
        0.6, 'A sampled source point overlaps when a target scan point lies within this '
        'distance of it under the hypothesis.', unit='m', low=0.01, high=10.0)
    range_exponent: float = param(
        2.0, 'Each sampled source point counts with the weight range^this (distance from the '
        'source sensor) in the overlap and the label agreement. A LiDAR samples a surface at '
        'range r with a density ~1/r^2: 2 makes both shares of the seen surface, not of the '
        'points, so the dense ground around the sensor cannot decide; 0: equal weights.',
        low=0.0, high=4.0)
    overlap_weight: float = param(
        1.0, 'Exponent of the overlap fraction in the combined score.', low=0.0, high=10.0)
    label_weight: float = param(
        1.0, 'Exponent of the label agreement in the combined score (0: geometry only).',
        low=0.0, high=10.0)
    min_gain: float = param(
        0.05, 'Another hypothesis replaces the choice of the estimator only when its score is '
        'higher by more than this share (0.05 = 5 %).', low=0.0, high=10.0)
    compatible_classes: list[str] = param(
        ['vegetation~terrain', 'vegetation~trunk', 'road~parking', 'building~fence',
         'pole~traffic-sign'],
        'Label pairs (or groups, a~b~c) that count as agreeing besides equal labels '
        '(class names of the label map).')
    ignored_classes: list[str] = param(
        ['unlabeled'], 'Classes left out of the label agreement (their points still count '
        'for the overlap).')
    seed: int = param(0, 'Seed of the source point sample.', low=0, high=2**31 - 1)

    def __post_init__(self) -> None:
        """Reject a compatibility rule that is not ``class~class[~class...]``."""
        for rule in self.compatible_classes:
            names = rule.split('~')
            if len(names) < 2 or not all(n.strip() for n in names):
                raise ConfigError(f'verification.compatible_classes: {rule!r} is not of the '
                                  "form 'class~class' (e.g. 'vegetation~terrain')")


@dataclass
class RefineConfig:
    """Optional point-to-plane ICP on the scans after the estimator."""

    icp: bool = param(False, 'Refine the estimate with point-to-plane ICP on the scans.')
    max_distance: float = param(
        1.0, 'ICP correspondence distance.', unit='m', low=0.01, high=20.0)
    iterations: int = param(30, 'ICP iterations.', low=1, high=1000)


SECTIONS: dict[str, type] = {
    'semantic': SemanticConfig,
    'features': FeatureConfig,
    'keypoints': KeypointConfig,
    'matcher': MatcherConfig,
    'estimator': EstimatorConfig,
    'verification': VerificationConfig,
    'refine': RefineConfig,
}


@dataclass
class RegistrationConfig:
    """Everything the registration core needs; built from a nested or flat dict."""

    semantic: SemanticConfig = field(default_factory=SemanticConfig)
    features: FeatureConfig = field(default_factory=FeatureConfig)
    keypoints: KeypointConfig = field(default_factory=KeypointConfig)
    matcher: MatcherConfig = field(default_factory=MatcherConfig)
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    verification: VerificationConfig = field(default_factory=VerificationConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)

    # -- construction -------------------------------------------------------------
    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RegistrationConfig:
        """Build from ``{'semantic': {...}, ...}``; unknown keys raise ConfigError."""
        unknown = set(data) - set(SECTIONS)
        if unknown:
            raise ConfigError(f'unknown config section(s): {sorted(unknown)}; '
                              f'known: {sorted(SECTIONS)}')
        flat: dict[str, Any] = {}
        for section, values in data.items():
            if not isinstance(values, dict):
                raise ConfigError(f'section {section!r} must be a mapping')
            for name, value in values.items():
                flat[f'{section}.{name}'] = value
        return cls().replace(flat)

    @classmethod
    def from_yaml(cls, path: str | Path) -> RegistrationConfig:
        """
        Load the core sections of a node parameter file (or a plain config YAML).

        Node-level keys (frames, topics, keyframe policy) are ignored here; the
        ROS layer validates them.
        """
        core, _ = split_params_yaml(path)
        return cls.from_dict(core)

    def replace(self, flat: dict[str, Any]) -> RegistrationConfig:
        """Copy with ``{'section.field': value}`` applied, type-checked and validated."""
        sections = {name: dataclasses.asdict(getattr(self, name)) for name in SECTIONS}
        for key, value in flat.items():
            section, _, name = key.partition('.')
            if section not in SECTIONS or name not in sections[section]:
                raise ConfigError(f'unknown parameter {key!r}')
            sections[section][name] = coerce(key, value, field_of(key))
        new = RegistrationConfig(**{s: SECTIONS[s](**v) for s, v in sections.items()})
        errors = new.errors()
        if errors:
            raise ConfigError('; '.join(errors))
        return new

    # -- export --------------------------------------------------------------------
    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Nested plain dict (YAML/JSON friendly)."""
        return {name: dataclasses.asdict(getattr(self, name)) for name in SECTIONS}

    def to_flat_dict(self) -> dict[str, Any]:
        """``{'section.field': value}`` for every field."""
        return {f'{s}.{k}': v for s, values in self.to_dict().items() for k, v in values.items()}

    # -- validation ------------------------------------------------------------------
    def errors(self) -> list[str]:
        """Every range, choice and cross-field violation, as readable sentences."""
        errors = [e for key, value in self.to_flat_dict().items()
                  for e in metadata_errors(key, value, field_of(key).metadata)]
        sem, est = self.semantic, self.estimator
        field_m = sem.ring_count * sem.ring_width
        if field_m > MAX_RECEPTIVE_FIELD_M:
            errors.append(
                f'semantic.ring_count x semantic.ring_width = {field_m:g} m exceeds the '
                f'{MAX_RECEPTIVE_FIELD_M:g} m receptive-field limit')
        if est.k2 > est.k1:
            errors.append(f'estimator.k2={est.k2} must not exceed estimator.k1={est.k1}')
        overlap = set(sem.landmark_classes) & set(sem.ignored_classes)
        if overlap:
            errors.append(f'classes both landmark and ignored: {sorted(overlap)}')
        overlap = set(sem.undefined_classes) & set(sem.ignored_classes)
        if overlap:
            errors.append(f'classes both undefined and ignored: {sorted(overlap)}')
        return errors


def metadata_errors(key: str, value: Any, meta: Any) -> list[str]:
    """Check one value against its field metadata (choices, low, high)."""
    errors = []
    if meta['choices'] is not None and value not in meta['choices']:
        errors.append(f'{key}={value!r} is not one of {list(meta["choices"])}')
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if meta['low'] is not None and value < meta['low']:
            errors.append(f'{key}={value} is below its minimum {meta["low"]}')
        if meta['high'] is not None and value > meta['high']:
            errors.append(f'{key}={value} is above its maximum {meta["high"]}')
    return errors


def field_of(key: str) -> dataclasses.Field:
    """Return the dataclass field behind a flat name such as ``semantic.top_k``."""
    section, _, name = key.partition('.')
    if section not in SECTIONS:
        raise ConfigError(f'unknown parameter {key!r}')
    for f in dataclasses.fields(SECTIONS[section]):
        if f.name == name:
            return f
    raise ConfigError(f'unknown parameter {key!r}')


def iter_fields() -> list[tuple[str, dataclasses.Field, Any]]:
    """``(flat_name, field, default)`` for every core parameter, in declaration order."""
    defaults = RegistrationConfig().to_flat_dict()
    out = []
    for section, cls in SECTIONS.items():
        for f in dataclasses.fields(cls):
            key = f'{section}.{f.name}'
            out.append((key, f, defaults[key]))
    return out


def coerce(key: str, value: Any, f: dataclasses.Field) -> Any:
    """Check and convert one value to the field's type (ints accepted for floats)."""
    kind = f.type if isinstance(f.type, str) else getattr(f.type, '__name__', str(f.type))
    if kind == 'bool':
        if isinstance(value, bool):
            return value
    elif kind == 'int':
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif kind == 'float':
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif kind == 'str':
        if isinstance(value, str):
            return value
    elif kind == 'list[str]':
        if isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value):
            return list(value)
    raise ConfigError(f'{key} expects {kind}, got {type(value).__name__} {value!r}')


def split_params_yaml(path: str | Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """
    Read a parameter YAML into ``(core_sections, node_level_params)``.

    Accepts the ROS layout ``{mlsemreg_node: {ros__parameters: {...}}}`` or a
    plain mapping. Node-level parameters are returned flat (``keyframe.policy``).
    """
    data = yaml.safe_load(Path(path).read_text()) or {}
    if NODE_NAME in data:
        data = data[NODE_NAME].get('ros__parameters', {})
    core = {k: v for k, v in data.items() if k in SECTIONS}
    rest: dict[str, Any] = {}

    def flatten(prefix: str, value: Any) -> None:
        if isinstance(value, dict):
            for k, v in value.items():
                flatten(f'{prefix}.{k}' if prefix else k, v)
        else:
            rest[prefix] = value

    for k, v in data.items():
        if k not in SECTIONS:
            flatten(k, v)
    return core, rest
