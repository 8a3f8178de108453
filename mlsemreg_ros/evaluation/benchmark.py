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
The paper's time table (appendix "Time cost analysis"): per-stage medians of one pair.

For 250, 500, 1000, 2500 and 5000 keypoints per cloud, one pair is prepared and
registered ``--repeats`` times and the per-stage median is reported, in ms per
pair (both clouds):

- ``local_ss_ms``: Local-SS of both clouds (eq. 1);
- ``bmr_ss_ms``: landmark extraction of both clouds plus BMR-SS (eq. 5);
- ``gm_mm_ms``: Group Matching + Mask Matching (NN), BMR-SS excluded;
- ``fpfh_ms``: FPFH at the keypoints of both clouds (normals included);
- ``sc2pcr_ms``: the estimator (SC2-PCR by default);
- ``verification_ms``: hypothesis verification on the dense scans (0 when
  ``verification.enabled`` is false), the target's KD-tree included;
- ``bev_search_ms``: the BEV search (core/estimation/bev_search.py), which runs only when the
  estimate is refused (e.g. too few inliers at few keypoints), else 0;
- ``fine_ms``: the fine alignment of the pair (``fine.pair_method``, GICP by default,
  on the prepared scans; their covariances included; 0 when off);
- ``total_ms``: wall time of preparing both clouds and registering them;
- ``total_parallel_ms``: the same with both clouds prepared concurrently
  (``Registration.prepare_scans``, as ``register_scans`` does).

The paper's Total-1 is ``local_ss_ms + bmr_ss_ms + gm_mm_ms``. The pair is a real
one (keypoints = the first n stored keypoints) or a generated street scene with a
known motion (:func:`generated_pair`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import statistics
import sys
import time
from typing import Any

from mlsemreg_ros.evaluation.tables import ResultTable

KEYPOINT_COUNTS = (250, 500, 1000, 2500, 5000)
STAGES = (
    'local_ss_ms',
    'bmr_ss_ms',
    'gm_mm_ms',
    'fpfh_ms',
    'sc2pcr_ms',
    'verification_ms',
    'bev_search_ms',
    'fine_ms',
    'total_ms',
    'total_parallel_ms',
)
#: Paper appendix, Table "Average consumed time (ms) per point cloud pair on KITTI".
PAPER_MS = {
    250: (9.88, 6.67, 14.59),
    500: (12.61, 5.98, 27.28),
    1000: (18.15, 6.32, 58.93),
    2500: (35.19, 6.72, 187.23),
    5000: (62.87, 6.38, 513.56),
}


def generated_pair(seed: int = 0, keypoints: int = 5000) -> Any:
    """
    Pair in a generated labeled street scene, with ``keypoints`` random keypoints per cloud.

    The scene (ground, facades, cars, poles, trunks, signs) comes from
    :mod:`mlsemreg_ros.datasets.synthetic_scene`; ``trans_gt`` is the known motion.
    """
    from mlsemreg_ros.core.features.features import sample_keypoints
    from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair
    import numpy as np

    pair = synthetic_pair(seed)
    rng = np.random.default_rng(seed)
    for side in ('src', 'dst'):
        pts = getattr(pair, f'pts_{side}')
        chosen = sample_keypoints(pts, keypoints, 'random', 1.0, seed)
        setattr(pair, f'kpts_{side}', pts[rng.permutation(chosen)])  # "first n" = random n
    return pair


def stage_times(source: Any, target: Any, result: Any, total_ms: float) -> dict[str, float]:
    """
    Map the pipeline's timings to the paper's stages (ms, both clouds).

    ``prepare`` reports ``local_ss_ms``, ``landmarks_ms`` and ``fpfh_ms`` per cloud;
    ``register`` reports ``gm_mm_ms`` (which contains its ``bmr_ss_ms`` sub-timing, absent
    in a GM-only fallback), ``estimator_ms`` and ``verification_ms``.
    """
    prep = [source.timings_ms, target.timings_ms]
    reg = result.timings_ms
    bmr = reg.get('bmr_ss_ms', 0.0)
    return {
        'local_ss_ms': sum(t.get('local_ss_ms', 0.0) for t in prep),
        'bmr_ss_ms': sum(t.get('landmarks_ms', 0.0) for t in prep) + bmr,
        'gm_mm_ms': reg.get('gm_mm_ms', 0.0) - bmr,
        'fpfh_ms': sum(t.get('fpfh_ms', 0.0) for t in prep),
        'sc2pcr_ms': reg.get('estimator_ms', 0.0),
        'verification_ms': reg.get('verification_ms', 0.0),
        'bev_search_ms': reg.get('bev_search_ms', 0.0),
        'fine_ms': reg.get('fine_ms', 0.0),
        'total_ms': total_ms,
    }


def bench_pair(
    registration: Any, pair: Any, counts: tuple[int, ...], repeats: int, progress: bool = True
) -> dict[str, dict[str, Any]]:
    """Median per-stage times for each keypoint count (FPFH computed at the keypoints)."""
    from tqdm import tqdm

    out: dict[str, dict[str, Any]] = {}
    tasks = [(n, r) for n in counts for r in range(repeats)]
    samples: dict[int, list[dict[str, float]]] = {n: [] for n in counts}
    extra: dict[int, dict[str, Any]] = {}
    for n, _ in tqdm(tasks, desc='bench', unit='run', file=sys.stderr, disable=not progress):
        scans = (
            {
                'points': pair.pts_src,
                'labels': pair.label_src,
                'keypoints': pair.kpts_src[:n],
                'voxelize': False,
            },
            {
                'points': pair.pts_dst,
                'labels': pair.label_dst,
                'keypoints': pair.kpts_dst[:n],
                'voxelize': False,
            },
        )
        start = time.perf_counter()
        source, target = (registration.prepare(**scan) for scan in scans)
        result = registration.register(source, target)
        times = stage_times(source, target, result, 1e3 * (time.perf_counter() - start))
        # the same pair with both clouds prepared concurrently (Registration.prepare_scans)
        start = time.perf_counter()
        registration.register(*registration.prepare_scans(*scans))
        times['total_parallel_ms'] = 1e3 * (time.perf_counter() - start)
        samples[n].append(times)
        extra[n] = {
            'keypoints_used': min(n, len(pair.kpts_src), len(pair.kpts_dst)),
            'correspondences': len(result.correspondences),
            'mode': result.mode,
        }
    for n in counts:
        medians = {s: statistics.median(run[s] for run in samples[n]) for s in STAGES}
        out[str(n)] = {**medians, **extra[n], 'repeats': repeats}
    return out


def timing_table(rows: dict[str, dict[str, Any]]) -> ResultTable:
    """Tabulate the medians per keypoint count, with the paper's Total-1 for reference."""
    lines = []
    for n, row in rows.items():
        total1 = row['local_ss_ms'] + row['bmr_ss_ms'] + row['gm_mm_ms']
        paper = PAPER_MS.get(int(n))
        lines.append(
            [n]
            + [f'{row[s]:.1f}' for s in ('local_ss_ms', 'bmr_ss_ms', 'gm_mm_ms')]
            + [
                f'{total1:.1f}',
                f'{row["fpfh_ms"]:.1f}',
                f'{row["sc2pcr_ms"]:.1f}',
                f'{row["verification_ms"]:.1f}',
                f'{row.get("bev_search_ms", 0.0):.1f}',
                f'{row.get("fine_ms", 0.0):.1f}',
                f'{row["total_ms"]:.1f}',
                f'{row["total_parallel_ms"]:.1f}',
                f'{sum(paper):.2f}' if paper else '-',
            ]
        )
    return ResultTable(
        (
            'keypoints',
            'Local-SS',
            'BMR-SS',
            'GM+MM',
            'Total-1',
            'FPFH',
            'SC2-PCR',
            'verification',
            'BEV search',
            'fine',
            'total',
            'total 2 threads',
            'paper Total-1',
        ),
        lines,
        left_columns=0,
    )


class BenchError(ValueError):
    """The pair cannot be benchmarked (unreadable, or without keypoints)."""


@dataclass(frozen=True)
class BenchOptions:
    """Which pair, how many keypoints, how many runs (``mlsemreg bench``)."""

    pair: Path | None = None  # pair file; None: the first KITTI dev pair, else generated
    synthetic: bool = False  # the generated scene even when real pairs are present
    repeats: int = 5  # runs per size (median)
    keypoints: tuple[int, ...] = KEYPOINT_COUNTS
    progress: bool = True


@dataclass
class BenchReport:
    """Per keypoint count, the per-stage medians of one pair; the ``--json`` report."""

    source_name: str
    points: tuple[int, int]  # of the source and the target cloud
    available: int  # keypoints per cloud the pair holds
    repeats: int
    rows: dict[str, dict[str, Any]]
    config: dict[str, Any]

    def as_dict(self) -> dict[str, Any]:
        """Return the JSON of ``--json``: the pair, the configuration, the rows, the machine."""
        import os

        import numpy

        return {
            'pair': self.source_name,
            'config': self.config,
            'keypoints': self.rows,
            'machine': {
                'cpu_count': os.cpu_count(),
                'numpy': numpy.__version__,
                'python': sys.version.split()[0],
                'load_average': list(os.getloadavg()),
            },
        }


def benchmark_pair(options: BenchOptions, core: Any) -> BenchReport:
    """Load (or generate) the pair and time the registration core at every keypoint count."""
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.datasets.pairs import first_dev_pair, load_pair
    from mlsemreg_ros.evaluation import tables

    counts = options.keypoints
    path = None if options.synthetic else (options.pair or first_dev_pair())
    if path is not None:
        try:
            pair = load_pair(path)
        except (OSError, ValueError) as error:
            raise BenchError(f'cannot read {path}: {error}') from None
        if pair.kpts_src is None or pair.kpts_dst is None:
            raise BenchError(f'{path} has no keypoints (kpts_src/kpts_dst)')
        source_name = str(path)
    else:
        pair = generated_pair(keypoints=max(counts))
        source_name = 'generated street scene'
    available = min(len(pair.kpts_src), len(pair.kpts_dst))
    if max(counts) > available:
        tables.console(stderr=True).print(
            f'note: the pair has {available} keypoints per cloud; larger counts use all of them',
            markup=False,
        )
    rows = bench_pair(Registration(core), pair, counts, options.repeats, options.progress)
    points = (len(pair.pts_src), len(pair.pts_dst))
    return BenchReport(source_name, points, available, options.repeats, rows, core.to_dict())


def print_benchmark(report: BenchReport) -> None:
    """Print the pair, the machine's load, the time table and what its columns hold."""
    import os

    from mlsemreg_ros.evaluation import tables

    load = ', '.join(f'{x:.1f}' for x in os.getloadavg())
    tables.print_text(
        f'pair: {report.source_name} ({report.points[0]} / {report.points[1]} points); median '
        f'of {report.repeats} runs, ms per pair (both clouds); {os.cpu_count()} CPUs, load '
        f'average {load} (other work makes timings noisy)'
    )
    tables.print_table(timing_table(report.rows))
    tables.print_text(
        'Total-1 = Local-SS + BMR-SS + GM+MM (paper); BMR-SS includes landmark extraction; '
        'total = wall time of prepare x2 + register (keypoint lookup, FPFH, signatures, '
        'matching, estimator); total 2 threads = the same with both clouds prepared '
        'concurrently (Registration.prepare_scans).'
    )
