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
A chain of pair files as posed frames: ``pts_dst`` of pair k is ``pts_src`` of pair k+1.

Pair files (``pts_src``, ``label_src``, ``pts_dst``, ``label_dst``, ``trans_gt`` with
``p_dst = trans_gt @ p_src``) cut from consecutive frames of one drive form a chain; the
composed ``trans_gt`` give every frame's pose in the first frame's axes:
``T_0_(k+1) = T_0_k @ inv(trans_gt_k)``. Used to build maps and relocalization queries
from real scans (docs/maps.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Largest mismatch (m) between pts_dst of a pair and pts_src of the next one.
CHAIN_TOLERANCE_M = 1e-6


@dataclass
class ChainFrame:
    """One frame of the chain."""

    name: str
    points: np.ndarray  # (N, 3)
    labels: np.ndarray  # (N,)
    T_0_frame: np.ndarray  # (4, 4) pose in the first frame


def chain_frames(files: list[Path]) -> list[ChainFrame]:
    """Return the len(files) + 1 frames of a chain of pair files; ValueError if broken."""
    frames: list[ChainFrame] = []
    pose = np.eye(4)
    previous_dst = None
    for file in files:
        with np.load(file) as data:
            src, dst = np.asarray(data['pts_src']), np.asarray(data['pts_dst'])
            if previous_dst is not None and (
                previous_dst.shape != src.shape
                or np.abs(previous_dst - src).max() > CHAIN_TOLERANCE_M
            ):
                raise ValueError(f'{file}: pts_src is not pts_dst of the previous pair')
            if not frames:
                frames.append(ChainFrame(file.stem, src, np.asarray(data['label_src']), pose))
            pose = pose @ np.linalg.inv(np.asarray(data['trans_gt'], dtype=np.float64))
            frames.append(ChainFrame(f'{file.stem}_dst', dst, np.asarray(data['label_dst']), pose))
            previous_dst = dst
    return frames
