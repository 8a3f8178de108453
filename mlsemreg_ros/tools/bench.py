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
``mlsemreg-bench``: the paper's time table (appendix "Time cost analysis") on this machine.

For 250, 500, 1000, 2500 and 5000 keypoints per cloud, one pair is prepared and
registered ``--repeats`` times and the per-stage median is reported, in ms per
pair (both clouds):

- ``local_ss_ms``: Local-SS of both clouds (eq. 1);
- ``bmr_ss_ms``: landmark extraction of both clouds plus BMR-SS (eq. 4);
- ``gm_mm_ms``: Group Matching + Mask Matching (NN), BMR-SS excluded;
- ``fpfh_ms``: FPFH at the keypoints of both clouds (normals included);
- ``sc2pcr_ms``: the estimator (SC2-PCR by default);
- ``verification_ms``: hypothesis verification on the dense scans (0 when
  ``verification.enabled`` is false), the target's KD-tree included;
- ``total_ms``: wall time of preparing both clouds and registering them;
- ``total_parallel_ms``: the same with both clouds prepared concurrently
  (``Registration.prepare_scans``, as ``register_scans`` does).

The paper's Total-1 is ``local_ss_ms + bmr_ss_ms + gm_mm_ms``. The pair is a real
one (``--pair``; default the first file of the KITTI dev pairs when present,
keypoints = the first n stored keypoints) or, without data, a generated street
scene with a known motion.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import statistics
import sys
import time
from typing import Any

from mlsemreg_ros.tools.eval_pairs import add_config_arguments, build_config, write_json

KEYPOINT_COUNTS = (250, 500, 1000, 2500, 5000)
STAGES = ('local_ss_ms', 'bmr_ss_ms', 'gm_mm_ms', 'fpfh_ms', 'sc2pcr_ms', 'verification_ms',
          'total_ms', 'total_parallel_ms')
#: Paper appendix, Table "Average consumed time (ms) per point cloud pair on KITTI".
PAPER_MS = {250: (9.88, 6.67, 14.59), 500: (12.61, 5.98, 27.28), 1000: (18.15, 6.32, 58.93),
            2500: (35.19, 6.72, 187.23), 5000: (62.87, 6.38, 513.56)}


def default_pair_path() -> Path | None:
    """First KITTI dev pair (env ``MLSEMREG_DEV_PAIRS`` or ``<repo>/../shared/...``), if any."""
    env = os.environ.get('MLSEMREG_DEV_PAIRS')
    folder = (Path(env) if env else
              Path(__file__).resolve().parents[3] / 'shared' / 'data' / 'kitti_pairs_dev')
    files = sorted(folder.glob('*.npz')) if folder.is_dir() else []
    return files[0] if files else None


def generated_pair(seed: int = 0, keypoints: int = 5000) -> Any:
    """
    Pair in a generated labeled street scene, with ``keypoints`` random keypoints per cloud.

    The scene (ground, facades, cars, poles, trunks, signs) comes from
    :mod:`mlsemreg_ros.datasets.synthetic_scene`; ``trans_gt`` is the known motion.
    """
    from mlsemreg_ros.core.features import sample_keypoints
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
        'total_ms': total_ms,
    }


def bench_pair(registration: Any, pair: Any, counts: tuple[int, ...], repeats: int,
               progress: bool = True) -> dict[str, dict[str, Any]]:
    """Median per-stage times for each keypoint count (FPFH computed at the keypoints)."""
    from tqdm import tqdm

    out: dict[str, dict[str, Any]] = {}
    tasks = [(n, r) for n in counts for r in range(repeats)]
    samples: dict[int, list[dict[str, float]]] = {n: [] for n in counts}
    extra: dict[int, dict[str, Any]] = {}
    for n, _ in tqdm(tasks, desc='bench', unit='run', file=sys.stderr, disable=not progress):
        scans = ({'points': pair.pts_src, 'labels': pair.label_src,
                  'keypoints': pair.kpts_src[:n], 'voxelize': False},
                 {'points': pair.pts_dst, 'labels': pair.label_dst,
                  'keypoints': pair.kpts_dst[:n], 'voxelize': False})
        start = time.perf_counter()
        source, target = (registration.prepare(**scan) for scan in scans)
        result = registration.register(source, target)
        times = stage_times(source, target, result, 1e3 * (time.perf_counter() - start))
        # the same pair with both clouds prepared concurrently (Registration.prepare_scans)
        start = time.perf_counter()
        registration.register(*registration.prepare_scans(*scans))
        times['total_parallel_ms'] = 1e3 * (time.perf_counter() - start)
        samples[n].append(times)
        extra[n] = {'keypoints_used': min(n, len(pair.kpts_src), len(pair.kpts_dst)),
                    'correspondences': len(result.correspondences), 'mode': result.mode}
    for n in counts:
        medians = {s: statistics.median(run[s] for run in samples[n]) for s in STAGES}
        out[str(n)] = {**medians, **extra[n], 'repeats': repeats}
    return out


def format_table(rows: dict[str, dict[str, Any]]) -> str:
    """Aligned table of the medians, plus the paper's Local-SS/BMR-SS/GM+MM for reference."""
    header = ('keypoints', 'Local-SS', 'BMR-SS', 'GM+MM', 'Total-1', 'FPFH', 'SC2-PCR',
              'verification', 'total', 'total 2 threads', 'paper Total-1')
    lines = []
    for n, row in rows.items():
        total1 = row['local_ss_ms'] + row['bmr_ss_ms'] + row['gm_mm_ms']
        paper = PAPER_MS.get(int(n))
        lines.append([n] + [f'{row[s]:.1f}' for s in ('local_ss_ms', 'bmr_ss_ms', 'gm_mm_ms')]
                     + [f'{total1:.1f}', f'{row["fpfh_ms"]:.1f}', f'{row["sc2pcr_ms"]:.1f}',
                        f'{row["verification_ms"]:.1f}', f'{row["total_ms"]:.1f}',
                        f'{row["total_parallel_ms"]:.1f}',
                        f'{sum(paper):.2f}' if paper else '-'])
    widths = [max(len(h), *(len(line[i]) for line in lines)) for i, h in enumerate(header)]
    text = ['  '.join(c.rjust(w) for c, w in zip(line, widths, strict=True))
            for line in [list(header), *lines]]
    return '\n'.join([text[0], '-' * len(text[0]), *text[1:]])


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line arguments of ``mlsemreg-bench``."""
    parser = argparse.ArgumentParser(
        prog='mlsemreg-bench',
        description='Per-stage median time (ms per pair, both clouds) of the registration '
                    'core for 250..5000 keypoints per cloud, as in the appendix table of the '
                    'paper ("Time cost analysis").')
    parser.add_argument('--pair', type=Path, metavar='PATH',
                        help='pair file (.npz); default: the first KITTI dev pair if present, '
                             'else a generated scene')
    parser.add_argument('--synthetic', action='store_true',
                        help='use the generated scene even when real pairs are present')
    parser.add_argument('--repeats', type=int, default=5, help='runs per size (median)')
    parser.add_argument('--keypoints', default=','.join(map(str, KEYPOINT_COUNTS)),
                        help='comma-separated keypoint counts (default: %(default)s)')
    add_config_arguments(parser)
    parser.add_argument('--json', type=Path, metavar='PATH', help='write the results as JSON')
    parser.add_argument('--no-progress', action='store_true', help='no progress bar')
    args = parser.parse_args(argv)
    try:
        args.counts = tuple(int(c) for c in args.keypoints.split(',') if c.strip())
    except ValueError:
        parser.error(f'--keypoints expects comma-separated integers, got {args.keypoints!r}')
    if not args.counts or min(args.counts) < 1:
        parser.error('--keypoints needs positive counts')
    if args.repeats < 1:
        parser.error('--repeats must be at least 1')
    return args


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``mlsemreg-bench``."""
    args = parse_args(argv)
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.datasets.pairs import load_pair
    import numpy

    try:
        config = build_config(args.config, {}, args.overrides)
    except (ValueError, OSError) as error:
        print(f'mlsemreg-bench: configuration error: {error}', file=sys.stderr)
        return 2
    path = None if args.synthetic else (args.pair or default_pair_path())
    if path is not None:
        try:
            pair = load_pair(path)
        except (OSError, ValueError) as error:
            print(f'mlsemreg-bench: cannot read {path}: {error}', file=sys.stderr)
            return 1
        if pair.kpts_src is None or pair.kpts_dst is None:
            print(f'mlsemreg-bench: {path} has no keypoints (kpts_src/kpts_dst)',
                  file=sys.stderr)
            return 1
        source_name = str(path)
    else:
        pair = generated_pair(keypoints=max(args.counts))
        source_name = 'generated street scene'
    available = min(len(pair.kpts_src), len(pair.kpts_dst))
    if max(args.counts) > available:
        print(f'mlsemreg-bench: note: the pair has {available} keypoints per cloud; larger '
              'counts use all of them', file=sys.stderr)
    rows = bench_pair(Registration(config), pair, args.counts, args.repeats,
                      progress=not args.no_progress)
    load = ', '.join(f'{x:.1f}' for x in os.getloadavg())
    print(f'pair: {source_name} ({len(pair.pts_src)} / {len(pair.pts_dst)} points); '
          f'median of {args.repeats} runs, ms per pair (both clouds); {os.cpu_count()} CPUs, '
          f'load average {load} (other work makes timings noisy)')
    print(format_table(rows))
    print('Total-1 = Local-SS + BMR-SS + GM+MM (paper); BMR-SS includes landmark extraction; '
          'total = wall time of prepare x2 + register (keypoint lookup, FPFH, signatures, '
          'matching, estimator); total 2 threads = the same with both clouds prepared '
          'concurrently (Registration.prepare_scans).')
    if args.json is not None:
        report = {'pair': source_name, 'config': config.to_dict(), 'keypoints': rows,
                  'machine': {'cpu_count': os.cpu_count(), 'numpy': numpy.__version__,
                              'python': sys.version.split()[0],
                              'load_average': list(os.getloadavg())}}
        write_json(args.json, report)
        print(f'wrote {args.json}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
