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

Every tunable of the pipeline is a field of a section dataclass: in the ``config.py`` of
its stage's folder (``core/features/config.py``, ``core/estimation/config.py``, ...),
beside the code it configures, or below (the odometry's sections). Each field carries its
description, unit and valid range in its metadata, so the ROS layer can declare parameters
(with descriptors) from these fields instead of copying defaults by hand. Flat names are
``<section>.<field>``, e.g. ``semantic.local_radius``.

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

from mlsemreg_ros.core.alignment.config import (
    FineAlignmentConfig,
    NearMissConfig,
    SweepAlignmentConfig,
)
from mlsemreg_ros.core.alignment.covariance import CovarianceConfig
from mlsemreg_ros.core.estimation.config import (
    BevSearchConfig,
    ConfidenceConfig,
    EstimatorConfig,
    VerificationConfig,
)
from mlsemreg_ros.core.estimation.covisibility import CovisibilityConfig
from mlsemreg_ros.core.estimation.object_registration import ObjectsConfig
from mlsemreg_ros.core.features.config import FeatureConfig, KeypointConfig
from mlsemreg_ros.core.features.deskew import PreprocessConfig
from mlsemreg_ros.core.features.levelling import LevellingConfig
from mlsemreg_ros.core.features.moving_objects import MovingObjectsConfig
from mlsemreg_ros.core.labeling.geometric_config import GeometricLabelsConfig, LABEL_SOURCES
from mlsemreg_ros.core.labeling.onnx_config import OnnxLabelsConfig
from mlsemreg_ros.core.maps.config import MapConfig
from mlsemreg_ros.core.matching.config import MatcherConfig, SemanticConfig
from mlsemreg_ros.core.motion_prior import MotionPriorConfig

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
    min_structure: float = param(
        0.02,
        'A scan becomes a keyframe only if the fine alignment can pin it in every '
        'direction: the ratio of the smallest to the largest eigenvalue of the translation '
        'block of its Hessian aligned onto itself (GICP, from its normals) must reach this '
        '(measured: real scans of 12 sensors and the KITTI dev pairs 0.17 to 0.64, '
        'simulated field drives 0.34 to 0.41, a corridor 0.004, a flat ground 0.001; '
        '0: no check; not with fine.method off).',
        low=0.0,
        high=1.0,
    )
    relocalization_keyframes: int = param(
        5,
        'Past keyframes the odometry keeps: after keyframe.max_failures rejections in a '
        'row the scan is registered onto them (newest first) before a re-initialisation '
        '(0: re-initialise at once).',
        low=0,
        high=100,
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
        3.0,
        'Factor on the pose covariance inv(H) * 2E / (n - 6) of the fine alignment '
        '(H Hessian, E final error, n inliers), before the covariance section adds its '
        'floors (docs/covariance.md). Fitted with them by mlsemreg covariance-nees on real '
        'KITTI pairs and field-mode drives (2026-12-04).',
        low=1e-6,
        high=1e6,
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
    label_source: str = param(
        'auto',
        "Where each scan's labels come from: auto (the cloud's label field when it has "
        'one, else geometric), field (the label field; a cloud without one is skipped), '
        "geometric (the built-in geometric labeler), onnx (the user's segmentation "
        'network), none (unlabeled: matched and judged without labels). docs/labels.md.',
        choices=LABEL_SOURCES,
    )
    geometric_labels: GeometricLabelsConfig = field(default_factory=GeometricLabelsConfig)
    onnx_labels: OnnxLabelsConfig = field(default_factory=OnnxLabelsConfig)
    preprocess: PreprocessConfig = field(default_factory=PreprocessConfig)
    semantic: SemanticConfig = field(default_factory=SemanticConfig)
    features: FeatureConfig = field(default_factory=FeatureConfig)
    keypoints: KeypointConfig = field(default_factory=KeypointConfig)
    matcher: MatcherConfig = field(default_factory=MatcherConfig)
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    verification: VerificationConfig = field(default_factory=VerificationConfig)
    bev_search: BevSearchConfig = field(default_factory=BevSearchConfig)
    levelling: LevellingConfig = field(default_factory=LevellingConfig)
    objects: ObjectsConfig = field(default_factory=ObjectsConfig)
    covisibility: CovisibilityConfig = field(default_factory=CovisibilityConfig)
    confidence: ConfidenceConfig = field(default_factory=ConfidenceConfig)
    fine: FineAlignmentConfig = field(default_factory=FineAlignmentConfig)
    near_miss: NearMissConfig = field(default_factory=NearMissConfig)
    sweep_alignment: SweepAlignmentConfig = field(default_factory=SweepAlignmentConfig)
    local_map: LocalMapConfig = field(default_factory=LocalMapConfig)
    keyframe: KeyframeConfig = field(default_factory=KeyframeConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    motion_prior: MotionPriorConfig = field(default_factory=MotionPriorConfig)
    covariance: CovarianceConfig = field(default_factory=CovarianceConfig)
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
        if self.label_source == 'onnx':
            from mlsemreg_ros.core.labeling.onnx_available import onnx_unavailable

            if reason := onnx_unavailable():
                errors.append(f'label_source onnx: {reason}')
            errors += self.onnx_labels.check()
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
