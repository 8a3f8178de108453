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
Object hypotheses: when the pose is refused or weak, match the scans' objects.

Both scans are levelled (core/stages/levelling.py), their objects (poles, signs, trunks,
vehicles, building segments: core/matching/objects.py) matched by a consistency graph and
solved in 4-DoF (core/estimation/object_registration.py). The poses are verified like the
estimator's hypotheses (origin ``objects``) and join the pool that the confidence rule
chooses from.
"""

from __future__ import annotations

from mlsemreg_ros.core.estimation.object_registration import register_objects
from mlsemreg_ros.core.features.levelling import level_transform
from mlsemreg_ros.core.matching.objects import (
    extract_objects,
    group_ids,
    object_correspondences,
    Objects,
)
from mlsemreg_ros.core.results import PreparedScan, VerificationResult
from mlsemreg_ros.core.stages.context import RegistrationContext
from mlsemreg_ros.core.stages.levelling import ground_fits
import numpy as np


class ObjectStage:
    """The object hypotheses, verified (``objects_ms``)."""

    name = 'objects'

    def wanted(self, context: RegistrationContext) -> bool:
        """``objects.enabled``, after a verification, for a refused or weak pose."""
        return context.refused_or_weak() and context.config.objects.enabled

    def run(self, context: RegistrationContext) -> VerificationResult | None:
        """Level, extract, match and solve; the verified poses or None."""
        cfg = context.config
        fits = ground_fits(context) if cfg.levelling.enabled else (None, None)
        levels = [np.eye(4) if fit is None else fit.T_level_sensor for fit in fits]
        ids = group_ids(context.label_names)
        source = _objects(context.source, levels[0], ids, cfg.objects)
        target = _objects(context.target, levels[1], ids, cfg.objects)
        rows, cols = object_correspondences(source, target, cfg.objects.extent_ratio)
        found = register_objects(source, target, rows, cols, cfg.objects)
        context.diagnostics.update(found.diagnostics)
        if not len(found.transforms):
            return None
        transforms = level_transform(levels[0], levels[1], found.transforms)
        return context.verify_candidates(transforms, 'objects')


def _objects(scan: PreparedScan, level: np.ndarray, ids: list, config: object) -> Objects:
    """Return the objects of ``scan`` in its levelled frame."""
    levelled = scan.points @ level[:3, :3].T + level[:3, 3]
    return extract_objects(levelled, scan.labels, ids, config.building_segment, config.max_range)
