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
The LiDAR odometry, one module per job (``docs/extending.md``).

:class:`Odometry` (``odometry.py``) composes the components; this package keeps the
names the node, the evaluation and the tests import from ``mlsemreg_ros.core.odometry``.
They are imported on first use (PEP 562): importing ``core/odometry/config.py`` (the
odometry's config sections, which ``core/config.py`` assembles) loads no odometry module,
so the assembly imports its sections without an import cycle.
"""

from __future__ import annotations

import importlib
from typing import Any, TYPE_CHECKING

if TYPE_CHECKING:
    from mlsemreg_ros.core.odometry.global_registration import (
        GlobalEstimate,
        GlobalRegistration,
    )
    from mlsemreg_ros.core.odometry.local_map import (
        is_new_keyframe,
        Keyframe,
        keyframe_refusal,
        LocalMap,
        make_map,
    )
    from mlsemreg_ros.core.odometry.motion_model import (
        ConstantVelocityModel,
        make_motion_model,
        MAX_PREDICTION_FACTOR,
        motion_model,
        MOTION_MODELS,
        MotionModel,
        Prediction,
    )
    from mlsemreg_ros.core.odometry.odometry import (
        Odometry,
    )
    from mlsemreg_ros.core.odometry.preprocess import (
        PreprocessedScan,
        Preprocessor,
    )
    from mlsemreg_ros.core.odometry.prior_model import (
        motion_model_name,
        PRIOR_MOTION_MODEL,
        PriorMotionModel,
    )
    from mlsemreg_ros.core.odometry.steps import (
        Decision,
        MIN_LEVER_ARM_M,
        OdometryStep,
        REINITIALIZATION_VARIANCE,
        sparse_inlier_covariance,
    )
    from mlsemreg_ros.core.odometry.tracking import (
        Tracker,
    )
    from mlsemreg_ros.core.odometry.trust import (
        Candidate,
        FRACTION_HISTORY,
        MAX_TRACKING_GAP,
        Trust,
    )

#: Name -> the module of this package that defines it.
_EXPORTS = {
    'GlobalEstimate': 'global_registration',
    'GlobalRegistration': 'global_registration',
    'is_new_keyframe': 'local_map',
    'Keyframe': 'local_map',
    'keyframe_refusal': 'local_map',
    'LocalMap': 'local_map',
    'make_map': 'local_map',
    'ConstantVelocityModel': 'motion_model',
    'make_motion_model': 'motion_model',
    'MAX_PREDICTION_FACTOR': 'motion_model',
    'motion_model': 'motion_model',
    'MOTION_MODELS': 'motion_model',
    'MotionModel': 'motion_model',
    'Prediction': 'motion_model',
    'Odometry': 'odometry',
    'PreprocessedScan': 'preprocess',
    'Preprocessor': 'preprocess',
    'motion_model_name': 'prior_model',
    'PRIOR_MOTION_MODEL': 'prior_model',
    'PriorMotionModel': 'prior_model',
    'Decision': 'steps',
    'MIN_LEVER_ARM_M': 'steps',
    'OdometryStep': 'steps',
    'REINITIALIZATION_VARIANCE': 'steps',
    'sparse_inlier_covariance': 'steps',
    'Tracker': 'tracking',
    'Candidate': 'trust',
    'FRACTION_HISTORY': 'trust',
    'MAX_TRACKING_GAP': 'trust',
    'Trust': 'trust',
}

__all__ = [
    'FRACTION_HISTORY',
    'MAX_PREDICTION_FACTOR',
    'MAX_TRACKING_GAP',
    'MIN_LEVER_ARM_M',
    'MOTION_MODELS',
    'PRIOR_MOTION_MODEL',
    'REINITIALIZATION_VARIANCE',
    'Candidate',
    'ConstantVelocityModel',
    'Decision',
    'GlobalEstimate',
    'GlobalRegistration',
    'Keyframe',
    'LocalMap',
    'MotionModel',
    'Odometry',
    'OdometryStep',
    'Prediction',
    'PreprocessedScan',
    'Preprocessor',
    'PriorMotionModel',
    'Tracker',
    'Trust',
    'is_new_keyframe',
    'keyframe_refusal',
    'make_map',
    'make_motion_model',
    'motion_model',
    'motion_model_name',
    'sparse_inlier_covariance',
]


def __getattr__(name: str) -> Any:
    """Import the module that defines ``name`` on first use; return the name."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    value = getattr(importlib.import_module(f'{__name__}.{module}'), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """List the exported names."""
    return sorted(__all__)
