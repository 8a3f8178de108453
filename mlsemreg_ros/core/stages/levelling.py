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
The levelling of a pair: both scans' ground fits, and the tilt check of the chosen pose.

:func:`ground_fits` fits each scan's ground once per registration
(core/features/levelling.py) for the stages that search in the levelled frames (the object
hypotheses). :class:`LevelCheckStage` refuses a pose whose roll or pitch departs from what
the two ground fits allow (``levelling.tolerance``): the source's ground normal must land
on the target's.
"""

from __future__ import annotations

from mlsemreg_ros.core.features.levelling import fit_ground, GroundFit, tilt_refusal
from mlsemreg_ros.core.results import PreparedScan, VerificationResult
from mlsemreg_ros.core.stages.context import RegistrationContext
import numpy as np


def ground_fits(context: RegistrationContext) -> tuple[GroundFit | None, GroundFit | None]:
    """Return the source's and the target's ground fits (measured once per registration)."""
    if context.ground_fits is None:
        context.ground_fits = (_fit(context, context.source), _fit(context, context.target))
    return context.ground_fits


def _fit(context: RegistrationContext, scan: PreparedScan) -> GroundFit | None:
    cfg, names = context.config.levelling, context.label_names
    ids = np.array([names.index(c) for c in cfg.ground_classes if c in names], dtype=np.int64)
    return fit_ground(scan.points, scan.labels, ids, cfg)


class LevelCheckStage:
    """Refuse a pose that keeps a tilt the ground fits do not allow (``level_check_ms``)."""

    name = 'level_check'

    def wanted(self, context: RegistrationContext) -> bool:
        """``levelling.enabled`` and a finite pose."""
        return context.config.levelling.enabled and bool(np.isfinite(context.transform).all())

    def run(self, context: RegistrationContext) -> VerificationResult | None:
        """Fit both grounds (once) and compare their normals under the pose."""
        source, target = ground_fits(context)
        if source is None or target is None:
            return None
        reason = tilt_refusal(context.transform, source, target, context.config.levelling)
        context.diagnostics['level_check_refused'] = bool(reason)
        context.doubt(reason)
        return None
