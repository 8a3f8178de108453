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
``mlsemreg-eval-pairs DIR``: register every pair file of a folder, print the paper's table.

Each ``.npz`` pair (see :mod:`mlsemreg_ros.datasets.pairs`) goes through
:class:`~mlsemreg_ros.core.pipeline.Registration` with the stored keypoints (the
points are already voxelized, so ``voxelize=False``): ``--descriptor gedi`` uses
the stored GEDI descriptors, ``--descriptor fpfh`` computes FPFH at the keypoints.
IN / IR are measured on the correspondences fed to the estimator, under
``trans_gt`` with the 0.6 m threshold; RE / TE / success as in paper Sec. 4.1.

Configuration precedence: defaults < ``--config`` YAML < dedicated flags
(``--matcher``, ``--no-semantic``, ...) < ``--set section.field=value``.

``--baseline kiss-matcher`` / ``--baseline fpfh-ransac`` (repeatable) run the baselines of
:mod:`mlsemreg_ros.tools.baselines` on the same pairs and print RR / RE / TE / time of
every method side by side.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
import sys
import time
from typing import Any

from mlsemreg_ros.tools.baselines import (
    BASELINES,
    BaselineUnavailable,
    comparison_table,
    evaluate_kiss_matcher,
    fpfh_ransac_config,
    per_pair_table,
)

INLIER_THRESHOLD_M = 0.6  # paper, KITTI
MAX_ROTATION_DEG = 5.0
MAX_TRANSLATION_M = 0.6


class EvalError(RuntimeError):
    """The pair folder or a pair file cannot be evaluated as asked."""


def add_config_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--config`` and ``--set`` (shared with ``mlsemreg-bench``)."""
    parser.add_argument('--config', type=Path, metavar='PATH',
                        help='YAML with config sections (or a node parameter file)')
    parser.add_argument('--set', dest='overrides', action='append', default=[],
                        metavar='KEY=VALUE',
                        help='override one parameter, e.g. semantic.top_k=3 (repeatable; '
                             'values are parsed as YAML)')


def build_config(config_path: Path | None, flags: dict[str, Any], overrides: list[str]) -> Any:
    """
    Effective RegistrationConfig: defaults < YAML file < ``flags`` < ``--set`` overrides.

    Raises ConfigError (a ValueError) with a readable message on bad keys or values.
    """
    from mlsemreg_ros.core.config import ConfigError, RegistrationConfig
    import yaml

    config = (RegistrationConfig.from_yaml(config_path) if config_path is not None
              else RegistrationConfig())
    if flags:
        config = config.replace(flags)
    parsed: dict[str, Any] = {}
    for item in overrides:
        key, sep, text = item.partition('=')
        if not sep or not key.strip():
            raise ConfigError(f'--set expects KEY=VALUE, got {item!r}')
        parsed[key.strip()] = yaml.safe_load(text)
    return config.replace(parsed) if parsed else config


def _sum_timings(*dicts: dict[str, float]) -> dict[str, float]:
    out: dict[str, float] = {}
    for d in dicts:
        for stage, ms in d.items():
            out[stage] = out.get(stage, 0.0) + float(ms)
    return out


def run_pair(registration: Any, pair: Any, descriptor: str) -> tuple[Any, Any, dict[str, float]]:
    """
    Register one pair; return ``(RegistrationResult, PairMetrics, timings_ms)``.

    Timings sum both clouds' preparation stages and the registration stages;
    ``total_ms`` is the wall time of both ``prepare`` calls plus ``register``.
    """
    from mlsemreg_ros.core.metrics import evaluate_pair

    if descriptor == 'fpfh':
        desc_src = desc_dst = None
    else:
        desc_src, desc_dst = pair.descriptors(descriptor)
    start = time.perf_counter()
    source, target = registration.prepare_scans(  # concurrently, on two threads
        {'points': pair.pts_src, 'labels': pair.label_src, 'keypoints': pair.kpts_src,
         'descriptors': desc_src, 'voxelize': False},
        {'points': pair.pts_dst, 'labels': pair.label_dst, 'keypoints': pair.kpts_dst,
         'descriptors': desc_dst, 'voxelize': False})
    result = registration.register(source, target)
    total_ms = 1e3 * (time.perf_counter() - start)
    timings = _sum_timings(source.timings_ms, target.timings_ms, result.timings_ms)
    timings['total_ms'] = total_ms
    metrics = evaluate_pair(result.transform, result.source_points, result.target_points,
                            pair.trans_gt, INLIER_THRESHOLD_M, MAX_ROTATION_DEG,
                            MAX_TRANSLATION_M)
    return result, metrics, timings


def pair_row(name: str, metrics: Any, timings: dict[str, float]) -> dict[str, Any]:
    """One pair of the JSON report: the paper metrics and the stage times."""
    return {
        'name': name,
        'n_correspondences': metrics.n_correspondences,
        'inlier_number': metrics.inlier_number,
        'inlier_ratio_pct': metrics.inlier_ratio_pct,
        'rotation_error_deg': _finite_or_none(metrics.rotation_error_deg),
        'translation_error_cm': _finite_or_none(metrics.translation_error_cm),
        'success': metrics.success,
        'time_ms': timings,
    }


def verification_summary(diagnostics: dict[str, Any]) -> dict[str, Any] | None:
    """Collect the verification stage's choice and per-hypothesis scores from diagnostics."""
    count = diagnostics.get('verification_hypotheses')
    if count is None:
        return None
    fields = ('rank', 'inliers', 'overlap', 'label_agreement', 'score')
    return {'switched': diagnostics['verification_switched'],
            'chosen_rank': diagnostics['verification_chosen_rank'],
            'hypotheses': [{f: diagnostics[f'verification_h{i}_{f}'] for f in fields}
                           for i in range(count)]}


def _finite_or_none(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _fmt(value: float | None, digits: int) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return '-'
    return f'{value:.{digits}f}'


def format_table(rows: list[dict[str, Any]], summary: dict[str, Any]) -> str:
    """Paper-style table: one line per pair and a mean line (RE/TE over successes only)."""
    header = ('pair', '#corr', 'IN', 'IR %', 'RE deg', 'TE cm', 'success', 'total ms')
    lines = [[r['name'], str(r['n_correspondences']), str(r['inlier_number']),
              _fmt(r['inlier_ratio_pct'], 2), _fmt(r['rotation_error_deg'], 2),
              _fmt(r['translation_error_cm'], 1), 'yes' if r['success'] else 'no',
              _fmt(r['time_ms']['total_ms'], 0)] for r in rows]
    mean_corr = sum(r['n_correspondences'] for r in rows) / max(len(rows), 1)
    lines.append(['mean', _fmt(mean_corr, 1), _fmt(summary['inlier_number'], 1),
                  _fmt(summary['inlier_ratio_pct'], 2), _fmt(summary['rotation_error_deg'], 2),
                  _fmt(summary['translation_error_cm'], 1),
                  f'RR {_fmt(summary["registration_recall_pct"], 1)}%',
                  _fmt(summary['time_ms'].get('total_ms'), 0)])
    widths = [max(len(h), *(len(line[i]) for line in lines)) for i, h in enumerate(header)]

    def render(cells: list[str] | tuple[str, ...]) -> str:
        padded = [c.rjust(w) for c, w in zip(cells, widths, strict=True)]
        padded[0] = cells[0].ljust(widths[0])
        return '  '.join(padded)

    rule = '-' * len(render(header))
    return '\n'.join([render(header), rule, *map(render, lines[:-1]), rule, render(lines[-1])])


def evaluate_directory(directory: Path, descriptor: str, config: Any,
                       progress: bool = True) -> dict[str, Any]:
    """Run every pair of ``directory``; return the JSON report (config, pairs, summary)."""
    from mlsemreg_ros.core.metrics import summarize
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.datasets.pairs import list_pairs, load_pair, PairFileError
    from tqdm import tqdm

    try:
        paths = list_pairs(directory)
    except FileNotFoundError as error:
        raise EvalError(str(error)) from None
    if not paths:
        raise EvalError(f'no pair files (*.npz) in {directory}')
    registration = Registration(config)
    rows, all_metrics = [], []
    for path in tqdm(paths, desc='pairs', unit='pair', file=sys.stderr, disable=not progress):
        try:
            pair = load_pair(path)
        except (PairFileError, OSError, ValueError) as error:
            raise EvalError(f'cannot read {path}: {error}') from None
        if descriptor != 'fpfh' and descriptor not in pair.descriptor_names:
            raise EvalError(f'{path} has no {descriptor!r} descriptors (stored: '
                            f'{pair.descriptor_names or "none"}); try --descriptor fpfh')
        if descriptor != 'fpfh' and (pair.kpts_src is None or pair.kpts_dst is None):
            raise EvalError(f'{path} has descriptors but no keypoints (kpts_src/kpts_dst)')
        result, metrics, timings = run_pair(registration, pair, descriptor)
        all_metrics.append(metrics)
        row = pair_row(pair.name, metrics, timings)
        row.update(mode=result.mode, estimator_inliers=result.num_inliers,
                   message=result.message,
                   verification=verification_summary(result.diagnostics))
        rows.append(row)
    summary = summarize(all_metrics)
    stages = sorted({stage for row in rows for stage in row['time_ms']})
    # A stage absent from a pair (e.g. bmr_ss_ms in a GM-only fallback) took 0 ms there.
    summary['time_ms'] = {stage: sum(r['time_ms'].get(stage, 0.0) for r in rows) / len(rows)
                          for stage in stages}
    return {'directory': str(directory), 'descriptor': descriptor, 'config': config.to_dict(),
            'pairs': rows, 'summary': summary}


def write_json(path: Path, report: dict[str, Any]) -> None:
    """Write ``report`` as strict JSON (NaN/inf become null), creating parent folders."""
    def clean(value: Any) -> Any:
        if isinstance(value, dict):
            return {str(k): clean(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [clean(v) for v in value]
        if hasattr(value, 'item') and not isinstance(value, (str, bytes)):
            value = value.item()  # numpy scalar
        return _finite_or_none(value)

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(clean(report), indent=2, allow_nan=False) + '\n')


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line arguments of ``mlsemreg-eval-pairs``."""
    parser = argparse.ArgumentParser(
        prog='mlsemreg-eval-pairs',
        description='Register every pair file (*.npz) of DIR and print the paper metrics '
                    '(IN, IR under trans_gt with 0.6 m; RE, TE, success: RE <= 5 deg and '
                    'TE <= 60 cm; RR; per-stage times).')
    parser.add_argument('directory', type=Path, metavar='DIR', help='folder of pair files')
    parser.add_argument('--descriptor', default='gedi', choices=('gedi', 'fpfh'),
                        help='gedi: descriptors stored in the pair files; fpfh: computed at '
                             'the stored keypoints (default: %(default)s)')
    parser.add_argument('--matcher', choices=('nn', 'mnn'), help='matcher.kind')
    parser.add_argument('--no-semantic', action='store_true',
                        help='plain matcher (the paper baseline): semantic.enabled=false')
    parser.add_argument('--estimator', choices=('sc2pcr', 'ransac'), help='estimator.kind')
    parser.add_argument('--no-refine', action='store_true',
                        help='the estimator alone, no fine alignment: fine.pair_method=off')
    parser.add_argument('--no-verification', action='store_true',
                        help="keep the estimator's choice: verification.enabled=false")
    parser.add_argument('--baseline', action='append', default=[], choices=BASELINES,
                        help='also run a baseline on the same pairs and compare (repeatable): '
                             'kiss-matcher (raw points, voxel 0.3 m, no labels; needs the '
                             'kiss-matcher package) or fpfh-ransac (Open3D FPFH + NN + Open3D '
                             'RANSAC)')
    add_config_arguments(parser)
    parser.add_argument('--json', type=Path, metavar='PATH', help='write the report as JSON')
    parser.add_argument('--no-progress', action='store_true', help='no progress bar')
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``mlsemreg-eval-pairs``."""
    args = parse_args(argv)
    flags: dict[str, Any] = {}
    if args.matcher:
        flags['matcher.kind'] = args.matcher
    if args.no_semantic:
        flags['semantic.enabled'] = False
    if args.estimator:
        flags['estimator.kind'] = args.estimator
    if args.no_refine:
        flags['fine.pair_method'] = 'off'
    if args.no_verification:
        flags['verification.enabled'] = False
    try:
        config = build_config(args.config, flags, args.overrides)
    except (ValueError, OSError) as error:
        print(f'mlsemreg-eval-pairs: configuration error: {error}', file=sys.stderr)
        return 2
    try:
        report = evaluate_directory(args.directory, args.descriptor, config,
                                    progress=not args.no_progress)
    except EvalError as error:
        print(f'mlsemreg-eval-pairs: {error}', file=sys.stderr)
        return 1
    label = method_label(args.descriptor, config)
    print(f'{label}, {len(report["pairs"])} pairs from {args.directory}')
    print(format_table(report['pairs'], report['summary']))
    stages = ', '.join(f'{k} {v:.0f}' for k, v in report['summary']['time_ms'].items())
    print(f'mean time per pair (ms, both clouds): {stages}')
    if args.baseline:
        try:
            report['baselines'] = run_baselines(args.directory, args.baseline, config,
                                                progress=not args.no_progress)
        except (BaselineUnavailable, EvalError) as error:
            print(f'mlsemreg-eval-pairs: {error}', file=sys.stderr)
            return 1
        reports = {label: report, **report['baselines']}
        print('\ncomparison on the same pairs (RE/TE: means over successful pairs):')
        print(comparison_table(reports))
        print(per_pair_table(reports))
    if args.json is not None:
        write_json(args.json, report)
        print(f'wrote {args.json}')
    return 0


def method_label(descriptor: str, config: Any) -> str:
    """E.g. ``FPFH + NN (ML-SemReg) + sc2pcr + verification``."""
    mode = 'plain' if not config.semantic.enabled else 'ML-SemReg'
    name = 'Open3D FPFH' if config.features.descriptor == 'fpfh_open3d' else descriptor.upper()
    fine = config.fine.pair_method
    return (f'{name} + {config.matcher.kind.upper()} ({mode}) + {config.estimator.kind}'
            f'{" + verification" if config.verification.enabled else ""}'
            f'{"" if fine == "off" else " + " + fine.upper()}')


def run_baselines(directory: Path, names: list[str], config: Any,
                  progress: bool = True) -> dict[str, dict[str, Any]]:
    """Run the named baselines on the pairs of ``directory``; reports by method label."""
    from mlsemreg_ros.datasets.pairs import list_pairs

    out: dict[str, dict[str, Any]] = {}
    for name in dict.fromkeys(names):  # once each, in the given order
        if name == 'kiss-matcher':
            report = evaluate_kiss_matcher(list_pairs(directory), progress=progress)
            out[report['method']] = report
        else:
            import open3d as o3d

            o3d.utility.random.seed(0)  # RANSAC samples (its threads still vary the order)
            baseline = fpfh_ransac_config(config)
            report = evaluate_directory(directory, 'fpfh', baseline, progress=progress)
            out[method_label('fpfh', baseline)] = report
    return out


if __name__ == '__main__':
    sys.exit(main())
