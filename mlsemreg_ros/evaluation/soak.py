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
The soak: thousands of scans through a running mlsemreg_node, its memory sampled.

The node runs in its own process (default parameters, reliable QoS); the scans of a bag
are published in a loop, each after the node answered the previous one on
``/diagnostics``, with increasing stamps; the node is reset where the bag starts again
(its route jumps back there). The node's resident set size (``VmRSS`` of
``/proc/<pid>/status``) is read every ``every`` scans; the growth after the warm-up is
the leak figure.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import time
from typing import Any

import numpy as np


@dataclass
class SoakSample:
    """The node's memory after a number of scans."""

    frames: int
    rss_mb: float
    seconds: float  # since the first scan


def rss_mb(pid: int) -> float:
    """Resident set size of a process, MiB (from /proc; NaN where it cannot be read)."""
    try:
        for line in Path(f'/proc/{pid}/status').read_text().splitlines():
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float('nan')


def soak(
    scans: list[tuple[np.ndarray, np.ndarray]],
    frames: int,
    every: int,
    probe: Any,
    pid: int,
    timeout_s: float = 30.0,
) -> list[SoakSample]:
    """Publish ``frames`` scans (looping over ``scans``) to the node; sample its RSS."""
    samples = [SoakSample(0, rss_mb(pid), 0.0)]
    start = time.monotonic()
    for frame in range(frames):
        if frame % len(scans) == 0 and not probe.reset():
            raise RuntimeError('mlsemreg/reset did not answer')
        points, labels = scans[frame % len(scans)]
        stamp = probe.stamp(1000.0 + 0.1 * frame)
        probe.publish(probe.cloud(points, labels, stamp))
        if probe.status_for(stamp, timeout_s) is None:
            raise RuntimeError(f'no /diagnostics for scan {frame} within {timeout_s} s')
        with probe._cond:  # the probe keeps what it received: forget it (its memory, not
            for messages in probe.received.values():  # the node's)
                messages.clear()
        if (frame + 1) % every == 0:
            samples.append(SoakSample(frame + 1, rss_mb(pid), time.monotonic() - start))
    return samples


def growth_mb(samples: list[SoakSample], warm_up: int) -> float:
    """
    RSS growth after ``warm_up`` scans, MiB: the least-squares trend over the samples.

    The slope of the RSS against the scan count, times the scans after the warm-up; the
    allocator's ups and downs between two samples (several MiB) do not decide it.
    """
    after = [s for s in samples if s.frames >= warm_up]
    if len(after) < 2:
        return float('nan')
    frames = np.array([s.frames for s in after], dtype=float)
    slope = np.polyfit(frames, np.array([s.rss_mb for s in after]), 1)[0]
    return float(slope * (frames[-1] - frames[0]))
