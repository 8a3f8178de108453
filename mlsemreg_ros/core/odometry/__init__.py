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
"""

from mlsemreg_ros.core.odometry.global_registration import GlobalEstimate, GlobalRegistration
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
from mlsemreg_ros.core.odometry.odometry import Odometry
from mlsemreg_ros.core.odometry.preprocess import PreprocessedScan, Preprocessor
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
from mlsemreg_ros.core.odometry.tracking import Tracker
from mlsemreg_ros.core.odometry.trust import (
    Candidate,
    FRACTION_HISTORY,
    MAX_TRACKING_GAP,
    Trust,
)

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
