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
Pair-registration baselines of ``mlsemreg eval-pairs --baseline``.

- ``kiss-matcher``: KISS-Matcher (Lim et al., "KISS-Matcher: Fast and Robust Point Cloud
  Registration Revisited", ICRA 2025; PyPI ``kiss-matcher``, optional): its own voxel
  grid, Faster-PFH, ROBIN matching and GNC solver on the raw pair points, no labels.
- ``fpfh-ransac``: the classic Open3D global registration: Open3D FPFH at the stored
  keypoints, plain nearest-neighbour matching, Open3D's correspondence RANSAC, no
  semantics and no verification (our pipeline configured so).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
import sys
import time
from typing import Any

from mlsemreg_ros.evaluation.pairs import evaluate_directory, method_label, pair_row
from mlsemreg_ros.evaluation.settings import EvaluationConfig
import numpy as np

BASELINES = ('kiss-matcher', 'fpfh-ransac')
KISS_MATCHER_VOXEL_M = 0.3
KISS_MATCHER_MISSING = (
    'kiss-matcher is not installed (an optional baseline): pip install kiss-matcher==1.0.2'
)


class BaselineUnavailable(RuntimeError):
    """The baseline's package is not installed."""


@dataclass
class KissMatcherResult:
    """One KISS-Matcher registration."""

    T_target_source: np.ndarray  # (4, 4)
    valid: bool  # KISS-Matcher's own success flag
    num_final_inliers: int  # its translation inliers
    src_matched: np.ndarray  # (K, 3) its initial Faster-PFH matches (fed to ROBIN + GNC)
    dst_matched: np.ndarray  # (K, 3)
    time_ms: float  # wall time of estimate(): voxelization, features, matching, solver
    stage_ms: dict[str, float] = field(default_factory=dict)


def kiss_matcher_register(
    pts_src: np.ndarray, pts_dst: np.ndarray, voxel_size: float = KISS_MATCHER_VOXEL_M
) -> KissMatcherResult:
    """
    Register raw points with KISS-Matcher (default configuration for ``voxel_size``).

    Raises :class:`BaselineUnavailable` when ``kiss_matcher`` cannot be imported.
    """
    try:
        import kiss_matcher
    except ImportError:
        raise BaselineUnavailable(KISS_MATCHER_MISSING) from None

    matcher = kiss_matcher.KISSMatcher(kiss_matcher.KISSMatcherConfig(voxel_size))
    src = np.ascontiguousarray(pts_src, dtype=np.float32).reshape(-1, 3)
    dst = np.ascontiguousarray(pts_dst, dtype=np.float32).reshape(-1, 3)
    start = time.perf_counter()
    solution = matcher.estimate(src, dst)
    time_ms = 1e3 * (time.perf_counter() - start)
    transform = np.eye(4)
    transform[:3, :3] = np.asarray(solution.rotation, dtype=np.float64).reshape(3, 3)
    transform[:3, 3] = np.asarray(solution.translation, dtype=np.float64).reshape(3)
    keypoints_src, keypoints_dst = (
        np.asarray(k, dtype=np.float64).reshape(-1, 3)
        for k in matcher.get_keypoints_from_faster_pfh()
    )
    pairs = np.asarray(matcher.get_initial_correspondences(), dtype=np.int64).reshape(-1, 2)
    return KissMatcherResult(
        transform,
        bool(solution.valid),
        int(matcher.get_num_final_inliers()),
        keypoints_src[pairs[:, 0]],
        keypoints_dst[pairs[:, 1]],
        time_ms,
        {
            'processing_ms': 1e3 * matcher.get_processing_time(),
            'extraction_ms': 1e3 * matcher.get_extraction_time(),
            'matching_ms': 1e3 * matcher.get_matching_time(),
            'rejection_ms': 1e3 * matcher.get_rejection_time(),
            'solver_ms': 1e3 * matcher.get_solver_time(),
        },
    )


def evaluate_kiss_matcher(
    paths: list[Any],
    bounds: EvaluationConfig,
    voxel_size: float = KISS_MATCHER_VOXEL_M,
    progress: bool = True,
) -> dict[str, Any]:
    """
    KISS-Matcher on every pair file; the same report layout as ``evaluate_directory``.

    IN / IR are measured on KISS-Matcher's initial correspondences (those its solver sees).
    """
    from mlsemreg_ros.core.metrics import summarize
    from mlsemreg_ros.datasets.pairs import load_pair
    from mlsemreg_ros.evaluation.scoring import score_pair
    from tqdm import tqdm

    rows, metrics = [], []
    for path in tqdm(
        paths, desc='kiss-matcher', unit='pair', file=sys.stderr, disable=not progress
    ):
        pair = load_pair(path)
        result = kiss_matcher_register(pair.pts_src, pair.pts_dst, voxel_size)
        pair_metrics = score_pair(
            result.T_target_source, result.src_matched, result.dst_matched, pair.trans_gt, bounds
        )
        metrics.append(pair_metrics)
        row = pair_row(pair.name, pair_metrics, {'total_ms': result.time_ms, **result.stage_ms})
        row.update(
            mode='kiss-matcher',
            kiss_matcher_valid=result.valid,
            estimator_inliers=result.num_final_inliers,
            message='',
        )
        rows.append(row)
    summary = summarize(metrics)
    summary['time_ms'] = {'total_ms': float(np.mean([r['time_ms']['total_ms'] for r in rows]))}
    return {
        'method': f'KISS-Matcher (voxel {voxel_size:g} m, raw points, no labels)',
        'pairs': rows,
        'summary': summary,
    }


def fpfh_ransac_config(config: Any) -> Any:
    """``config`` turned into Open3D FPFH + plain NN + Open3D RANSAC, no verification."""
    return config.replace(
        {
            'features.descriptor': 'fpfh_open3d',
            'semantic.enabled': False,
            'estimator.kind': 'ransac',
            'verification.enabled': False,
            'fine.pair_method': 'off',
        }
    )


def run_baselines(
    directory: Path, names: list[str], config: Any, bounds: EvaluationConfig, progress: bool = True
) -> dict[str, dict[str, Any]]:
    """Run the named baselines on the pairs of ``directory``; reports by method label."""
    from mlsemreg_ros.datasets.pairs import list_pairs

    out: dict[str, dict[str, Any]] = {}
    for name in dict.fromkeys(names):  # once each, in the given order
        if name == 'kiss-matcher':
            report = evaluate_kiss_matcher(list_pairs(directory), bounds, progress=progress)
            out[report['method']] = report
        else:
            import open3d as o3d

            o3d.utility.random.seed(0)  # RANSAC samples (its threads still vary the order)
            baseline = fpfh_ransac_config(config)
            report = evaluate_directory(directory, 'fpfh', baseline, bounds, progress=progress)
            out[method_label('fpfh', baseline)] = report
    return out
