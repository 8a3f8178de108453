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
"""The synthetic street pair with noisy labels, registered (the label quality tests)."""

from __future__ import annotations

from typing import Any

from mlsemreg_ros.core.config import RegistrationConfig
from mlsemreg_ros.core.pipeline import Registration
from mlsemreg_ros.core.results import Landmarks, PreparedScan
import numpy as np

#: Fewer keypoints than the default keep the tests fast.
CONFIG = {'keypoints.count': 1000}


def flipped(labels: np.ndarray, share: float, seed: int) -> np.ndarray:
    """Return ``labels`` with ``share`` of them replaced by random learning ids."""
    rng = np.random.default_rng(seed)
    out = np.array(labels, copy=True)
    chosen = rng.random(len(out)) < share
    out[chosen] = rng.integers(1, 20, int(chosen.sum()))
    return out


def labeled_points_scan(points: np.ndarray, labels: np.ndarray, num_classes: int) -> PreparedScan:
    """Return a prepared scan of ``points`` (N, 3) and ``labels`` (N,) alone: no keypoints."""
    empty = np.zeros((0, 3))
    return PreparedScan(
        points,
        labels.astype(np.int32),
        empty,
        np.zeros(0, dtype=np.int64),
        np.zeros((0, 0), np.float32),
        np.zeros((0, num_classes), bool),
        Landmarks.empty(),
    )


def register_pair(scene: Any, label_src: np.ndarray, label_dst: np.ndarray, **changes: Any) -> Any:
    """Register the scene's pair with the given labels and config changes (over CONFIG)."""
    registration = Registration(RegistrationConfig().replace({**CONFIG, **changes}))
    source, target = registration.prepare_scans(
        {'points': scene.pts_src, 'labels': label_src},
        {'points': scene.pts_dst, 'labels': label_dst},
    )
    return registration.register(source, target)
