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
How much of a fine alignment's evidence pins its weakest direction (issue 35).

small_gicp's Gauss-Newton Hessian ``H`` (source frame, ``delta = [omega, v]``) is a sum over
the inliers of ``J^T M J``; an inlier on a surface constrains mostly the direction of its
normal, with about the same information ``m`` for every inlier, so ``trace(H_vv) / n`` is
one inlier's information. The rotation is put on the translation's scale first, by the
bounds of a right pose: 5 degrees count as 0.6 m (:data:`ROTATION_LENGTH_M`; a rotation
``omega`` is the displacement ``L * omega``), so ``H_s = D H D`` with
``D = diag(1/L, 1/L, 1/L, 1, 1, 1)``.

The **support** of the weakest direction is the smallest eigenvalue of ``H_s`` divided by
one inlier's information: how many inliers facing that direction squarely its evidence is
worth. A scan that sees a long road through a 70-degree field of view can keep 200 map
inliers with the support of five along the road: those few points decide the pose there,
and when they are off (a sweep not deskewed, a moving object) the pose slides along the road
to a wrong place that perturbed starts come back to. The covariance ``inv(H)`` calls it
certain (5 cm), because it counts every inlier as independent evidence.
"""

from __future__ import annotations

from dataclasses import dataclass

from mlsemreg_ros.core.alignment.alignment import Alignment
import numpy as np

#: Metres per radian of rotation: a right pose is within 0.6 m and 5 degrees of the truth
#: (docs/definitions.md), so a rotation of 5 degrees weighs as much as 0.6 m.
ROTATION_LENGTH_M = 0.6 / float(np.radians(5.0))


@dataclass(frozen=True)
class WeakDirection:
    """The weakest direction of an alignment's Hessian and its support."""

    support: float  # inliers' worth of information along it (0: no usable Hessian)
    direction: np.ndarray  # (6,) unit, scaled coordinates [L * omega, v] (source frame)

    def describe(self) -> str:
        """Return e.g. ``'translation (0.99, 0.03, 0.01)'``: where the direction mostly lies."""
        rotation, translation = self.direction[:3], self.direction[3:]
        part, axes = (
            ('translation', translation)
            if translation @ translation >= rotation @ rotation
            else ('rotation', rotation)
        )
        axes = axes / max(float(np.linalg.norm(axes)), 1e-12)
        return f'{part} ({", ".join(f"{a:.2f}" for a in axes)})'


def weakest_direction(alignment: Alignment, length: float = ROTATION_LENGTH_M) -> WeakDirection:
    """
    Return the weakest direction of ``alignment``'s Hessian and its support (module doc).

    ``length``: metres per radian, the rotation's scale against the translation's.
    """
    H = np.asarray(alignment.hessian, dtype=np.float64)
    n = alignment.num_inliers
    if H.shape != (6, 6) or n <= 0 or not np.all(np.isfinite(H)):
        return WeakDirection(0.0, np.zeros(6))
    per_inlier = float(np.trace(H[3:, 3:])) / n
    if per_inlier <= 0:
        return WeakDirection(0.0, np.zeros(6))
    D = np.diag([1.0 / length] * 3 + [1.0] * 3)
    scaled = D @ H @ D
    values, vectors = np.linalg.eigh(0.5 * (scaled + scaled.T))
    return WeakDirection(max(float(values[0]), 0.0) / per_inlier, vectors[:, 0])
