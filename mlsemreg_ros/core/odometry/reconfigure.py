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
A new configuration applied to a running odometry, from the next scan on.

What depends on a changed section is rebuilt, nothing else: the cached keyframe is prepared
again only when a section that :meth:`Registration.prepare` reads changed; its alignment
cloud only when ``fine`` changed; the local map is cleared when its structure changed; the
motion model is made again when the prior's kind changed.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.deferred import stored
from mlsemreg_ros.core.odometry import sensor_scale
from mlsemreg_ros.core.odometry.motion_model import make_motion_model
from mlsemreg_ros.core.odometry.prior_model import motion_model_name

if TYPE_CHECKING:
    from mlsemreg_ros.core.odometry.odometry import Odometry

#: Sections whose change makes the cached keyframe be prepared again.
PREPARE_SECTIONS = ('semantic', 'features', 'keypoints', 'moving_objects')


def reconfigure(odometry: Odometry, config: RegistrationConfig) -> None:
    """Apply ``config`` to ``odometry`` from the next scan on (:meth:`Odometry.reconfigure`)."""
    config = sensor_scale.apply(config, odometry.sensor_scale)  # a sparse sensor's values
    odometry.preprocessor.check(config)
    old = odometry.registration.config
    odometry.registration.config = config
    if odometry.keyframe is not None:
        if any(getattr(old, s) != getattr(config, s) for s in PREPARE_SECTIONS):
            keyframe = odometry.keyframe
            keyframe.prepared = odometry.registration.prepare(
                keyframe.points, stored(keyframe, 'labels'), lazy=True
            )
            odometry.preprocessor.exclude_moving(
                keyframe.prepared, keyframe.points, stored(keyframe, 'labels')
            )
        elif old.fine != config.fine:
            odometry.keyframe.prepared.alignment_clouds.clear()  # rebuilt when needed
    odometry.past_keyframes.resize(config.keyframe.relocalization_keyframes)
    if odometry.map.reconfigure(config.fine, config.local_map) and odometry.keyframe:
        odometry.map.insert_scan(odometry.keyframe.prepared, odometry.keyframe.pose)
    if old.motion_prior != config.motion_prior:  # core/odometry/prior_model.py
        if motion_model_name(old) != motion_model_name(config):
            odometry.motion_model = make_motion_model(config, motion_model_name(config))
            if odometry._last_accepted is not None:
                odometry.motion_model.update(*odometry._last_accepted)
        elif hasattr(odometry.motion_model, 'cfg'):
            odometry.motion_model.cfg = config.motion_prior
