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
The types every scan reader shares: :class:`Scan`, the :class:`ScanSource` protocol, errors.

Readers (``bag.py``, ``kitti.py``) import this module only; the factory that picks a
reader from a path is :mod:`mlsemreg_ros.datasets.factory`, so there is no import cycle.
A new reader implements :class:`ScanSource` and is added to the factory.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass
class Scan:
    """One labeled scan of a sequence."""

    index: int  # position in the whole sequence (before any stride)
    stamp_ns: int  # header stamp
    xyz: np.ndarray  # (N, 3) float64, metres, sensor frame
    labels: np.ndarray | None  # (N,) int64 label values as stored (raw: instance bits kept)
    intensity: np.ndarray | None  # (N,) float32
    frame_id: str
    pose: np.ndarray | None = None  # (4, 4) ground truth T_world_sensor, if known
    point_times: np.ndarray | None = None  # (N,) float64 s after stamp_ns (sweep start)

    def __len__(self) -> int:
        return int(self.xyz.shape[0])


@runtime_checkable
class ScanSource(Protocol):
    """A sequence of labeled scans with optional ground-truth poses."""

    name: str

    def __len__(self) -> int:
        """Return the number of scans in the whole sequence."""
        ...

    def scans(self, stride: int = 1, max_frames: int | None = None) -> Iterator[Scan]:
        """Yield scans 0, stride, 2 * stride, ... (at most ``max_frames``), in order."""
        ...

    def close(self) -> None:
        """Release files."""
        ...


class SourceError(ValueError):
    """A sequence cannot be opened or read; the message says why and what exists."""


def expected_frames(total: int, stride: int, max_frames: int | None) -> int:
    """Return the number of scans ``scans(stride, max_frames)`` yields out of ``total``."""
    n = len(range(0, total, stride))
    return n if max_frames is None else min(n, max_frames)
