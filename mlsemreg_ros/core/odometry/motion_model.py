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
Motion models: where the odometry expects the current scan before it looks at it.

The seam (``docs/extending.md``): a :class:`MotionModel` predicts ``T_odom_current`` at a
stamp and hears of every accepted pose. :func:`make_motion_model` builds the one named in
:data:`MOTION_MODELS`; an implementation joins that table with :func:`motion_model`.
:class:`ConstantVelocityModel` is registered through exactly that decorator.

Optional: ``sweep_rotations(stamp_ns, first_s, last_s)`` returns a gyro's rotations within a
sweep, ``(times (K,), R_stamp_node (K, 3, 3))`` or None; the deskew then follows them
(``PriorMotionModel``, ``docs/field.md``). A model without it is deskewed by one twist.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.rigid import invert_transform, scale_motion
import numpy as np

#: The prediction bridges at most this many nominal frame intervals.
MAX_PREDICTION_FACTOR = 5.0
#: The motion model the odometry uses.
DEFAULT_MOTION_MODEL = 'constant_velocity'


@dataclass(frozen=True)
class Prediction:
    """A predicted pose and how far it reaches."""

    T_odom_current: np.ndarray  # (4, 4)
    stamp_gap: float  # time since the last accepted pose, in nominal frame intervals
    #                   (1 when the stamps cannot tell); the tracking trust rule reads it
    sigmas: tuple[float, float] | None = None  # a prior's stated (m, deg) standard deviations
    #                   (None: constant velocity); widen the correction bounds (motion_bound)
    still: bool = False  # the last accepted pose itself, no motion known (odometry.still_start)


class MotionModel(Protocol):
    """What the odometry asks of a motion model."""

    def predict(self, stamp_ns: int) -> Prediction | None:
        """Return the predicted ``T_odom_current`` at ``stamp_ns``, or None (no evidence)."""

    def update(self, pose: np.ndarray, stamp_ns: int) -> None:
        """Take an accepted ``T_odom_current`` (4, 4) at ``stamp_ns``."""

    def reset(self) -> None:
        """Forget every pose (an odometry reset or re-initialisation)."""


#: Builds a motion model from the configuration (e.g. a class taking it).
MotionModelFactory = Callable[[RegistrationConfig], MotionModel]
#: Motion models by name (filled by :func:`motion_model`).
MOTION_MODELS: dict[str, MotionModelFactory] = {}


def motion_model(name: str) -> Callable[[MotionModelFactory], MotionModelFactory]:
    """Register a motion model factory (a class taking the configuration) as ``name``."""

    def register(factory: MotionModelFactory) -> MotionModelFactory:
        MOTION_MODELS[name] = factory
        return factory

    return register


def make_motion_model(config: RegistrationConfig, name: str = DEFAULT_MOTION_MODEL) -> MotionModel:
    """Build the motion model ``name`` (one of :data:`MOTION_MODELS`) for ``config``."""
    if name not in MOTION_MODELS:
        raise ValueError(f'unknown motion model {name!r}; known: {sorted(MOTION_MODELS)}')
    return MOTION_MODELS[name](config)


@motion_model('constant_velocity')
class ConstantVelocityModel:
    """
    The motion between the last two accepted poses, repeated.

    Scaled by the ratio of the stamp differences (so a dropped or rejected frame is
    bridged, up to :data:`MAX_PREDICTION_FACTOR` intervals); without usable stamps the
    motion is repeated once. Before two poses were accepted there is no velocity, and no
    prediction: a zero-motion guess would be a guess, not evidence.
    """

    def __init__(self, config: RegistrationConfig | None = None) -> None:
        self._accepted: list[tuple[np.ndarray, int]] = []  # last two accepted (pose, stamp)

    def predict(self, stamp_ns: int) -> Prediction | None:
        """Return the constant-velocity prediction at ``stamp_ns`` (None before two poses)."""
        if len(self._accepted) < 2:
            return None
        last, last_stamp = self._accepted[-1]
        before, before_stamp = self._accepted[-2]
        motion = invert_transform(before) @ last
        factor = 1.0
        if last_stamp > before_stamp and stamp_ns > last_stamp:
            factor = (stamp_ns - last_stamp) / (last_stamp - before_stamp)
        return Prediction(last @ scale_motion(motion, min(factor, MAX_PREDICTION_FACTOR)), factor)

    def update(self, pose: np.ndarray, stamp_ns: int) -> None:
        """Keep ``pose`` as the last accepted one."""
        self._accepted = [*self._accepted[-1:], (pose.copy(), stamp_ns)]

    @property
    def last_accepted(self) -> tuple[np.ndarray, int] | None:
        """Return the last accepted ``(pose, stamp_ns)``, or None before the first."""
        return self._accepted[-1] if self._accepted else None

    def reset(self) -> None:
        """Forget the velocity."""
        self._accepted = []
