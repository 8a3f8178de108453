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

"""The odometry's seams: the motion model table, the explicit prediction, the deskew hook."""

from __future__ import annotations

from typing import Any

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.odometry import (
    ConstantVelocityModel,
    make_motion_model,
    MAX_PREDICTION_FACTOR,
    MOTION_MODELS,
    Odometry,
    Preprocessor,
)
import numpy as np
import pytest


def _shift(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    return T


def test_the_constant_velocity_model_is_registered_and_built_by_name() -> None:
    assert MOTION_MODELS['constant_velocity'] is ConstantVelocityModel
    assert isinstance(make_motion_model(RegistrationConfig()), ConstantVelocityModel)
    with pytest.raises(ValueError, match='unknown motion model'):
        make_motion_model(RegistrationConfig(), 'imu')


def test_the_prediction_carries_its_stamp_gap() -> None:
    model = ConstantVelocityModel()
    assert model.predict(0) is None
    model.update(_shift(0.0), 100)
    assert model.predict(200) is None  # one pose: no velocity
    model.update(_shift(1.0), 200)
    prediction = model.predict(400)  # two intervals later
    assert prediction.stamp_gap == pytest.approx(2.0)
    np.testing.assert_allclose(prediction.T_odom_current[:3, 3], [3.0, 0.0, 0.0])
    far = model.predict(200 + 100 * 10)  # bridged at most MAX_PREDICTION_FACTOR intervals
    assert far.stamp_gap == pytest.approx(10.0)
    np.testing.assert_allclose(far.T_odom_current[0, 3], 1.0 + MAX_PREDICTION_FACTOR)
    unstamped = ConstantVelocityModel()
    unstamped.update(_shift(0.0), 0)
    unstamped.update(_shift(1.0), 0)
    assert unstamped.predict(0).stamp_gap == 1.0
    model.reset()
    assert model.predict(400) is None


class _Recording(Preprocessor):
    def __init__(self, registration: Any) -> None:
        super().__init__(registration)
        self.seen: list[Any] = []

    def deskew(
        self, points: np.ndarray, point_times: np.ndarray | None, motion: Any = None
    ) -> np.ndarray:
        self.seen.append(point_times)
        return points


class _Prepare:
    config = RegistrationConfig()

    def prepare(self, points: np.ndarray, labels: np.ndarray, lazy: bool = False) -> Any:
        raise RuntimeError('prepared')


def test_point_times_reach_the_deskew_hook() -> None:
    odometry = Odometry(_Prepare())
    odometry.preprocessor = _Recording(odometry.registration)
    times = np.linspace(0.0, 0.1, 4)
    for given in (times, None):
        with pytest.raises(RuntimeError, match='prepared'):
            odometry.process(np.zeros((4, 3)), np.zeros(4, np.int64), point_times=given)
    assert odometry.preprocessor.seen[0] is times and odometry.preprocessor.seen[1] is None


def test_only_the_first_keyframe_s_pair_refines_itself() -> None:
    """Onto the first keyframe the pair's own fine alignment runs (stage 9 can then judge)."""
    from types import SimpleNamespace

    from mlsemreg_ros.core.odometry import GlobalRegistration, Keyframe

    asked: list[bool] = []

    def register(current: Any, target: Any, *, refine: bool) -> Any:
        asked.append(refine)
        return SimpleNamespace(success=False, transform=np.eye(4))

    config = RegistrationConfig()
    registration = GlobalRegistration(SimpleNamespace(register=register, config=config))
    for index in (0, 1, 7):
        keyframe = Keyframe(index, 0, np.zeros((1, 3)), np.zeros(1), None, np.eye(4))
        estimate = registration(None, keyframe)
        assert not estimate.usable  # a refused registration is never a pose
    assert asked == [True, False, False]
    config.odometry.refine_first_keyframe = False  # live: read at every registration
    registration(None, Keyframe(0, 0, np.zeros((1, 3)), np.zeros(1), None, np.eye(4)))
    assert asked[-1] is False
