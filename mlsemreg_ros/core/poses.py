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
Pose helpers shared by the estimators: residuals, pose equality within bounds, NMS of poses.

SC2-PCR (``core/estimation/sc2pcr.py``), the hypothesis verification
(``core/estimation/verification.py``), the
BEV search (``core/estimation/bev_search.py``) and the odometry's decision use the same definition
of
"the same pose": within a rotation *and* a translation bound, as in the success test of
the evaluation protocol.
"""

from __future__ import annotations

from mlsemreg_ros.core.rigid import apply_transform, invert_transform, rotation_angle_deg
import numpy as np


def distinct_hypotheses(
    transforms: np.ndarray, limit: int, rotation_deg: float, translation_m: float
) -> np.ndarray:
    """
    Return the indices of at most ``limit`` distinct hypotheses, best first.

    Greedy: the first is kept, then every hypothesis within ``rotation_deg`` *and*
    ``translation_m`` of a kept one is dropped, and the next remaining one is kept.
    With the success bounds (5 deg, 0.6 m) two kept hypotheses can never both count
    as the same registration. One vectorized pass over all ``S`` per kept hypothesis.

    - ``transforms``: ``(S, 4, 4)``, best first (e.g. :class:`Hypotheses`).
    - ``limit``: most hypotheses to keep (``>= 1``).

    Returns ``(n,)`` int64 indices, ``n <= limit``, ascending; ``0`` first when ``S > 0``.
    """
    available = np.ones(transforms.shape[0], dtype=bool)
    kept: list[int] = []
    while len(kept) < limit and available.any():
        first = int(np.argmax(available))
        kept.append(first)
        available &= ~same_pose(transforms[first], transforms, rotation_deg, translation_m)
    return np.asarray(kept, dtype=np.int64)


def same_pose(
    pose: np.ndarray, others: np.ndarray, rotation_deg: float, translation_m: float
) -> np.ndarray:
    """
    ``(S,)`` bool: ``pose`` ``(4, 4)`` is within both bounds of each of ``others`` ``(S, 4, 4)``.

    The rotation angle of ``R^T R_s`` comes from its trace, the elementwise product sum
    ``(trace - 1) / 2 = cos``; the translation bound is on ``||t - t_s||``, as in the
    success test of the evaluation protocol.
    """
    cos = (np.einsum('ab,sab->s', pose[:3, :3], others[:, :3, :3]) - 1.0) / 2.0
    close = np.linalg.norm(others[:, :3, 3] - pose[:3, 3], axis=1) <= translation_m
    return close & (cos >= np.cos(np.radians(rotation_deg)) - 1e-12)


def residuals(transform: np.ndarray, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """``(K,)`` distances ``||R src_i + t - dst_i||`` in metres."""
    return np.linalg.norm(apply_transform(transform, src) - dst, axis=-1)


def within_bounds(
    T_a: np.ndarray, T_b: np.ndarray, translation: float, rotation_deg: float
) -> bool:
    """Whether ``inv(T_a) @ T_b`` moves by at most ``translation`` m and ``rotation_deg``."""
    delta = invert_transform(T_a) @ T_b
    return (
        float(np.linalg.norm(delta[:3, 3])) <= translation
        and rotation_angle_deg(delta) <= rotation_deg
    )
