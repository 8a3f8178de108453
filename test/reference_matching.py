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
Dense, loop-per-group reference of ML-SemReg matching, straight from the paper's equations.

Slow and obvious on purpose: the fast engine in mlsemreg_ros.core.matching.matching must agree with
it.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.distance import cdist


def reference_match(
    src_desc: np.ndarray,
    dst_desc: np.ndarray,
    src_ss: np.ndarray,
    dst_ss: np.ndarray,
    src_bmr: np.ndarray | None,
    dst_bmr: np.ndarray | None,
    top_k: int,
    mutual: bool,
) -> set[tuple[int, int]]:
    """Union over groups (eq. 3 / eq. 9) of NN or MNN on the masked distance matrix."""
    distance = cdist(src_desc, dst_desc, 'sqeuclidean')
    if src_bmr is None:
        similarity = np.zeros(distance.shape, dtype=np.int64)
    else:
        similarity = src_bmr.astype(np.int64) @ dst_bmr.astype(np.int64).T  # eq. 6
    pairs: set[tuple[int, int]] = set()
    for group in range(src_ss.shape[1]):
        rows, cols = np.flatnonzero(src_ss[:, group]), np.flatnonzero(dst_ss[:, group])
        if len(rows) == 0 or len(cols) == 0:
            continue
        sub_s = similarity[np.ix_(rows, cols)]
        mask = sub_s >= (sub_s.max(axis=1) - (top_k - 1))[:, None]  # top-K levels
        masked = np.where(mask, distance[np.ix_(rows, cols)], np.inf)
        best = masked.argmin(axis=1)
        back = masked.argmin(axis=0)
        for r, c in enumerate(best):
            if not mutual or back[c] == r:
                pairs.add((int(rows[r]), int(cols[c])))
    return pairs
