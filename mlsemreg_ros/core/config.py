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
its stage's folder (``core/features/config.py``, ``core/estimation/config.py``,
``core/odometry/config.py``, ...), beside the code it configures. Each field carries its
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
from mlsemreg_ros.core.odometry.config import (
    KeyframeConfig,
    LocalMapConfig,
    OdometryConfig,
)

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
    label_timing: str = param(
        'read',
        'When the odometry computes geometric labels: read (when something first reads '
        'them: a global registration, a map, the registered cloud; a scan tracked by the fine '
        'alignment alone never needs them) or scan (on every scan). Labels from the field, '
        'from onnx, and with moving_objects.map_filter movable are always made at once. '
        'docs/labels.md.',
        choices=('read', 'scan'),
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
