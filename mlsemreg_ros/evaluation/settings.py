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
The evaluation protocol's settings: success bounds and the ground-truth inlier threshold.

Same engine as the core's and the node's parameters (:class:`~mlsemreg_ros.core.config.Settings`),
so every tool reads them from ``--config`` and ``--set evaluation.<name>=<value>`` with the
same validation. Defaults: paper Sec. 4.1, KITTI (ScanNet: 15 deg, 0.3 m, inliers 0.1 m).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math

from mlsemreg_ros.core.config import param, Settings


@dataclass
class EvaluationConfig:
    """When a registration counts as a success, and a correspondence as a true inlier."""

    max_rotation_deg: float = param(
        5.0,
        'A registration succeeds when its rotation error RE is at most this (and its '
        'translation error at most evaluation.max_translation_m).',
        unit='deg',
        low=0.0,
        high=180.0,
    )
    max_translation_m: float = param(
        0.6,
        'A registration succeeds when its translation error TE is at most this.',
        unit='m',
        low=0.0,
        high=100.0,
    )
    inlier_threshold: float = param(
        0.6,
        'A correspondence (p, q) is a ground-truth inlier when the distance of T_gt p '
        'to q is below this (IN, IR).',
        unit='m',
        low=0.001,
        high=10.0,
    )

    def succeeded(self, rotation_error_deg: float, translation_error_m: float) -> bool:
        """Tell whether RE <= max and TE <= max (NaN fails): the success test of every tool."""
        return bool(
            math.isfinite(rotation_error_deg)
            and math.isfinite(translation_error_m)
            and rotation_error_deg <= self.max_rotation_deg
            and translation_error_m <= self.max_translation_m
        )


@dataclass
class EvaluationSettings(Settings):
    """The tools' evaluation settings (flat names ``evaluation.<name>``)."""

    evaluation: EvaluationConfig = field(default_factory=EvaluationConfig)
