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
The paper's pair benchmark: register every pair file of a folder, score it, report it.

Each ``.npz`` pair (:mod:`mlsemreg_ros.datasets.pairs`) goes through
:class:`~mlsemreg_ros.core.pipeline.Registration` with the stored keypoints (the points
are already voxelized, so ``voxelize=False``): descriptor ``gedi`` uses the stored GEDI
descriptors, ``fpfh`` computes FPFH at the keypoints. IN / IR are measured on the
correspondences fed to the estimator under ``trans_gt``; RE / TE / success with the
evaluation settings (paper Sec. 4.1).
"""

from __future__ import annotations

from pathlib import Path
import sys
import time
from typing import Any

from mlsemreg_ros.evaluation.scoring import finite_or_none, score_pair
from mlsemreg_ros.evaluation.settings import EvaluationConfig


class EvalError(RuntimeError):
    """The pair folder or a pair file cannot be evaluated as asked."""


def _sum_timings(*dicts: dict[str, float]) -> dict[str, float]:
    out: dict[str, float] = {}
    for d in dicts:
        for stage, ms in d.items():
            out[stage] = out.get(stage, 0.0) + float(ms)
    return out


def run_pair(
    registration: Any, pair: Any, descriptor: str, bounds: EvaluationConfig
) -> tuple[Any, Any, dict[str, float]]:
    """
    Register one pair; return ``(RegistrationResult, PairMetrics, timings_ms)``.

    Timings sum both clouds' preparation stages and the registration stages;
    ``total_ms`` is the wall time of both ``prepare`` calls plus ``register``; ``cpu_ms``
    their CPU time (all threads of the process: with ``threads`` 1 a loaded machine
    inflates it far less than the wall time).
    """
    if descriptor == 'fpfh':
        desc_src = desc_dst = None
    else:
        desc_src, desc_dst = pair.descriptors(descriptor)
    start, cpu_start = time.perf_counter(), time.process_time()
    source, target = registration.prepare_scans(  # concurrently, on two threads
        {
            'points': pair.pts_src,
            'labels': pair.label_src,
            'keypoints': pair.kpts_src,
            'descriptors': desc_src,
            'voxelize': False,
        },
        {
            'points': pair.pts_dst,
            'labels': pair.label_dst,
            'keypoints': pair.kpts_dst,
            'descriptors': desc_dst,
            'voxelize': False,
        },
    )
    result = registration.register(source, target)
    total_ms = 1e3 * (time.perf_counter() - start)
    cpu_ms = 1e3 * (time.process_time() - cpu_start)
    timings = _sum_timings(source.timings_ms, target.timings_ms, result.timings_ms)
    timings['total_ms'], timings['cpu_ms'] = total_ms, cpu_ms
    metrics = score_pair(
        result.transform, result.source_points, result.target_points, pair.trans_gt, bounds
    )
    return result, metrics, timings


def pair_row(name: str, metrics: Any, timings: dict[str, float]) -> dict[str, Any]:
    """One pair of the JSON report: the paper metrics and the stage times."""
    return {
        'name': name,
        'n_correspondences': metrics.n_correspondences,
        'inlier_number': metrics.inlier_number,
        'inlier_ratio_pct': metrics.inlier_ratio_pct,
        'rotation_error_deg': finite_or_none(metrics.rotation_error_deg),
        'translation_error_cm': finite_or_none(metrics.translation_error_cm),
        'success': metrics.success,
        'time_ms': timings,
    }


def verification_summary(diagnostics: dict[str, Any]) -> dict[str, Any] | None:
    """Collect the verification stage's choice and per-hypothesis scores from diagnostics."""
    count = diagnostics.get('verification_hypotheses')
    if count is None:
        return None
    fields = ('rank', 'inliers', 'overlap', 'label_agreement', 'score')
    return {
        'switched': diagnostics['verification_switched'],
        'chosen_rank': diagnostics['verification_chosen_rank'],
        'hypotheses': [
            {f: diagnostics[f'verification_h{i}_{f}'] for f in fields} for i in range(count)
        ],
    }


def covisible_summary(diagnostics: dict[str, Any]) -> dict[str, Any]:
    """Collect the refused path's covisible choice, refinement and acceptance (``covisible_*``)."""
    keys = ('chosen_origin', 'fine_refused', 'fine_refused_kept', 'level_check_refused')
    keys += ('degeneracy_ratio', 'fine_inlier_fraction', 'near_miss_refusal')
    return {k: v for k, v in diagnostics.items() if k.startswith('covisible_') or k in keys}


def summarize_pairs(metrics: list[Any], rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Summarize the pairs as the paper does, plus the mean time of every stage (ms/pair)."""
    from mlsemreg_ros.core.metrics import summarize

    summary = summarize(metrics)
    stages = sorted({stage for row in rows for stage in row['time_ms']})
    # A stage absent from a pair (e.g. bmr_ss_ms in a GM-only fallback) took 0 ms there.
    summary['accepted_pct'] = (
        100.0 * sum(bool(r.get('accepted', True)) for r in rows) / len(rows) if rows else 0.0
    )
    summary['time_ms'] = {
        stage: sum(r['time_ms'].get(stage, 0.0) for r in rows) / len(rows) for stage in stages
    }
    return summary


def evaluate_directory(
    directory: Path,
    descriptor: str,
    config: Any,
    bounds: EvaluationConfig,
    progress: bool = True,
    label_noise: Any = None,
    noise_seed: int = 0,
) -> dict[str, Any]:
    """
    Run every pair of ``directory``; return the JSON report (config, pairs, summary).

    ``label_noise``: a :class:`~mlsemreg_ros.evaluation.label_noise.LabelNoise` applied to
    both scans of every pair first (seeded by ``noise_seed``, the pair's index and the scan).
    """
    from mlsemreg_ros.core.labeling.source import LabelSource
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
    label_source = LabelSource(registration.label_map)
    rows, all_metrics = [], []
    for path in tqdm(paths, desc='pairs', unit='pair', file=sys.stderr, disable=not progress):
        try:
            pair = load_pair(path)
        except (PairFileError, OSError, ValueError) as error:
            raise EvalError(f'cannot read {path}: {error}') from None
        if descriptor != 'fpfh' and descriptor not in pair.descriptor_names:
            raise EvalError(
                f'{path} has no {descriptor!r} descriptors (stored: '
                f'{pair.descriptor_names or "none"}); try --descriptor fpfh'
            )
        if descriptor != 'fpfh' and (pair.kpts_src is None or pair.kpts_dst is None):
            raise EvalError(f'{path} has descriptors but no keypoints (kpts_src/kpts_dst)')
        pair = labeled_pair(pair, label_source, config)  # --labels (label_source)
        if label_noise is not None and label_noise.active:
            pair = noisy_pair(pair, label_noise, registration, noise_seed, len(rows))
        result, metrics, timings = run_pair(registration, pair, descriptor, bounds)
        all_metrics.append(metrics)
        row = pair_row(pair.name, metrics, timings)
        row.update(
            accepted=result.success,
            bev_search=bool(result.diagnostics.get('bev_search_used', False)),
            evidence={
                k.removeprefix('confidence_'): v
                for k, v in result.diagnostics.items()
                if k.startswith('confidence_')
            },
            mode=result.mode,
            estimator_inliers=result.num_inliers,
            message=result.message,
            verification=verification_summary(result.diagnostics),
            covisible=covisible_summary(result.diagnostics),
        )
        rows.append(row)
    return {
        'directory': str(directory),
        'descriptor': descriptor,
        'label_noise': str(label_noise) if label_noise is not None else 'none',
        'config': config.to_dict(),
        'pairs': rows,
        'summary': summarize_pairs(all_metrics, rows),
    }


def labeled_pair(pair: Any, label_source: Any, config: Any) -> Any:
    """``pair`` with both scans labeled by ``config.label_source`` (``pts_src``/``pts_dst``)."""
    from dataclasses import replace

    if config.label_source in ('auto', 'field'):
        return pair
    return replace(
        pair,
        label_src=label_source(pair.pts_src, pair.label_src, config).labels,
        label_dst=label_source(pair.pts_dst, pair.label_dst, config).labels,
    )


def noisy_pair(pair: Any, noise: Any, registration: Any, seed: int, index: int) -> Any:
    """``pair`` with ``noise`` applied to both scans' labels (evaluation/label_noise.py)."""
    from dataclasses import replace

    from mlsemreg_ros.evaluation.label_noise import scan_rng

    scheme = registration.config.semantic.label_scheme
    label_map = registration.label_map
    return replace(
        pair,
        label_src=noise.apply(pair.label_src, label_map, scan_rng(seed, index, 0), scheme),
        label_dst=noise.apply(pair.label_dst, label_map, scan_rng(seed, index, 1), scheme),
    )


def method_label(descriptor: str, config: Any) -> str:
    """E.g. ``FPFH + NN (ML-SemReg) + sc2pcr + verification``."""
    mode = 'plain' if not config.semantic.enabled else 'ML-SemReg'
    name = 'Open3D FPFH' if config.features.descriptor == 'fpfh_open3d' else descriptor.upper()
    fine = config.fine.pair_method
    return (
        f'{name} + {config.matcher.kind.upper()} ({mode}) + {config.estimator.kind}'
        f'{" + verification" if config.verification.enabled else ""}'
        f'{"" if fine == "off" else " + " + fine.upper()}'
    )
