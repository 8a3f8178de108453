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
Relocalization query files (docs/maps.md): one scan per ``.npz``.

Arrays: ``points`` (N, 3) float32 (float64: the odometry's deskewed points, exactly),
``labels`` (N,) uint32, ``stamp_ns`` int64 and, with ground truth, ``T_map_scan`` (4, 4)
float64. ``evaluation/relocalization.py`` reads them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def write_query(
    path: Path, points: Any, labels: Any, pose: Any, stamp_ns: int, dtype: Any = 'float32'
) -> None:
    """Write one query file at ``path``: the scan, its labels, stamp and (if known) pose."""
    extra = {} if pose is None else {'T_map_scan': np.asarray(pose, dtype=np.float64)}
    np.savez_compressed(
        path,
        points=np.asarray(points, dtype=dtype),
        labels=np.asarray(labels).astype(np.uint32),
        stamp_ns=np.int64(stamp_ns),
        **extra,
    )
