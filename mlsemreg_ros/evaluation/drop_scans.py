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
Recovery stress of ``mlsemreg eval-bag --drop-scans P``: a seeded share of degenerate scans.

:class:`DroppedScans` wraps a :class:`~mlsemreg_ros.datasets.source.ScanSource` and replaces
``round(P * n)`` of its ``n`` kept scans (never the first; chosen by ``--drop-seed``) by a
degenerate scan of 3 points (stamp, index and ground truth kept).
:func:`recovery_counts` then counts, over the scored replay, the good scans right after a
degenerate one that registered within 1 and within 2 scans and the wrong poses published;
:func:`good_scans_only` removes the degenerate scans from the run that ``summary.json``'s
RR / RE / TE are computed on (docs/evaluation.md).
"""

from __future__ import annotations

from collections.abc import Iterator
import dataclasses
from typing import Any

from mlsemreg_ros.datasets.source import Scan, ScanSource
from mlsemreg_ros.evaluation.records import EvalRun, FrameRecord
from mlsemreg_ros.evaluation.replay import expected_frames
import numpy as np

#: The 3 points of a degenerate scan (no structure to register against).
DEGENERATE_XYZ = np.array([[5.0, 0.0, 0.0], [0.0, 5.0, 0.0], [5.0, 5.0, 1.0]])
#: Their label value (a raw SemanticKITTI label: road).
DEGENERATE_LABEL = 40
#: Prefix of a degenerate scan's message in frames.csv.
MARK = 'degenerate (dropped) '


def degenerate_positions(n_scans: int, share: float, seed: int) -> set[int]:
    """Positions (among ``n_scans`` kept scans) to replace: ``round(share * n)``, never 0."""
    count = min(round(share * n_scans), max(n_scans - 1, 0))
    if count <= 0:
        return set()
    chosen = np.random.default_rng(seed).choice(n_scans - 1, size=count, replace=False) + 1
    return {int(k) for k in chosen}


def degenerate_scan(scan: Scan) -> Scan:
    """``scan`` with its points replaced by :data:`DEGENERATE_XYZ` (everything else kept)."""
    labels = None if scan.labels is None else np.full(3, DEGENERATE_LABEL, scan.labels.dtype)
    intensity = None if scan.intensity is None else np.zeros(3, scan.intensity.dtype)
    return dataclasses.replace(
        scan, xyz=DEGENERATE_XYZ.copy(), labels=labels, intensity=intensity, point_times=None
    )


class DroppedScans:
    """A scan source with a seeded share of its kept scans degenerate."""

    def __init__(self, source: ScanSource, share: float, seed: int = 0) -> None:
        self.source = source
        self.name = source.name
        self.share = share
        self.seed = seed
        self.degenerate_indices: set[int] = set()  # bag indices replaced (after scans())

    def __len__(self) -> int:
        """Return the number of scans in the whole sequence."""
        return len(self.source)

    def scans(self, stride: int = 1, max_frames: int | None = None) -> Iterator[Scan]:
        """Yield the source's scans, the chosen ones degenerate."""
        n = expected_frames(len(self.source), stride, max_frames)
        positions = degenerate_positions(n, self.share, self.seed)
        for position, scan in enumerate(self.source.scans(stride, max_frames)):
            if position in positions:
                self.degenerate_indices.add(scan.index)
                scan = degenerate_scan(scan)
            yield scan

    def close(self) -> None:
        """Close the wrapped source."""
        self.source.close()

    def __getattr__(self, name: str) -> Any:
        """Anything else is the wrapped source's."""
        return getattr(self.source, name)


def recovery_after(kinds: list[tuple[bool, bool]]) -> dict[str, int]:
    """
    Count the good scans right after a degenerate one and how soon they registered.

    ``kinds``: per scan in order, (degenerate, registered right). Returns
    ``after_degenerate`` and, of those, ``recovered_within_1`` (the scan itself registered)
    and ``recovered_within_2`` (it or the next scan, if good, did).
    """
    counts = {'after_degenerate': 0, 'recovered_within_1': 0, 'recovered_within_2': 0}
    for k in range(1, len(kinds)):
        if not kinds[k][0] and kinds[k - 1][0]:
            counts['after_degenerate'] += 1
            counts['recovered_within_1'] += kinds[k][1]
            counts['recovered_within_2'] += any(not d and ok for d, ok in kinds[k:][:2])
    return counts


def recovery_counts(records: list[FrameRecord], degenerate: set[int]) -> dict[str, int]:
    """
    Count the recovery after degenerate scans in a scored replay.

    ``degenerate_scans`` (scans replaced), the counts of :func:`recovery_after` (registered
    right = accepted within the success bounds) and ``wrong_published`` (accepted scans
    outside the bounds, degenerate ones included).
    """
    return {
        'degenerate_scans': sum(r.bag_index in degenerate for r in records),
        **recovery_after([(r.bag_index in degenerate, r.success) for r in records]),
        'wrong_published': sum(r.registered and r.accepted and not r.success for r in records),
    }


def good_scans_only(run: EvalRun, degenerate: set[int]) -> EvalRun:
    """``run`` without the degenerate scans' records (trajectory arrays kept whole)."""
    return dataclasses.replace(
        run, records=[r for r in run.records if r.bag_index not in degenerate]
    )


def mark_degenerate(run: EvalRun, degenerate: set[int]) -> None:
    """Prefix the degenerate scans' frames.csv message with :data:`MARK`."""
    for record in run.records:
        if record.bag_index in degenerate:
            record.message = MARK + record.message


def summarize_with_drops(run: EvalRun, degenerate: set[int]) -> dict[str, Any]:
    """
    Summarize a ``--drop-scans`` replay: the good scans' summary plus the recovery counts.

    RR, RE, TE, latency and NEES are over the good scans only (``n_frames`` counts them); the
    trajectory metrics (ATE, RPE, KITTI) are over every published pose, the degenerate scans'
    included. The degenerate scans are marked in ``run`` (frames.csv keeps every scan).
    """
    from mlsemreg_ros.evaluation.scoring import summarize_run

    mark_degenerate(run, degenerate)
    summary = summarize_run(good_scans_only(run, degenerate))
    summary.update(recovery_counts(run.records, degenerate))
    return summary


def recovery_table(summary: dict[str, Any]) -> Any:
    """Build the printed table of :func:`recovery_counts` (from a ``--drop-scans`` summary)."""
    from mlsemreg_ros.evaluation.tables import ResultTable

    keys = ('degenerate_scans', 'after_degenerate', 'recovered_within_1', 'recovered_within_2')
    return ResultTable(
        ['recovery (--drop-scans)', 'scans'],
        [[key, str(summary[key])] for key in (*keys, 'wrong_published')],
    )
