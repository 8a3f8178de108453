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
Result files of an evaluation: the results folder, JSON reports, output naming, ``latest``.

A sequence evaluation's folder (``results/<kind>/<time>_<name>``, with a ``latest`` link)::

    summary.json          n_frames, registration_recall_pct, rotation_error_deg,
                          translation_error_cm, kitti_t_err_pct, kitti_r_err_deg_per_100m,
                          ate_rmse_m (SE(3)-aligned), ate_unaligned_m, rpe_step_m,
                          rpe_100m_m (evo), latency_ms_p50, latency_ms_p95, nees_mean
    details.json          run information (bag, stride, counts, mean IR/IN, stage timings)
    frames.csv            one row per scan
    trajectory_kitti.txt  estimated poses (KITTI); ground_truth_kitti.txt likewise
    trajectory_tum.txt    estimated poses (TUM); ground_truth_tum.txt likewise
                          (evo_ape tum ground_truth_tum.txt trajectory_tum.txt -a)
    config.yaml           effective parameters (node layout; feed back with --config)
    trajectory.png, errors.png, correspondences.png
"""

from __future__ import annotations

import csv
from dataclasses import fields
from datetime import datetime
import json
import math
from pathlib import Path
from typing import Any

from mlsemreg_ros.core.config import NODE_NAME, Settings
from mlsemreg_ros.evaluation.records import EvalRun, FrameRecord
from mlsemreg_ros.evaluation.settings import EvaluationConfig
import numpy as np
import yaml


def effective_config(config: Settings) -> dict[str, Any]:
    """Return the parameters in the node's YAML layout (loadable with ``--config``)."""
    return {NODE_NAME: {'ros__parameters': config.to_dict()}}


def json_ready(value: Any) -> Any:
    """
    Return ``value`` as plain JSON data: the one encoder of every ``--json`` of the CLI.

    Dicts (keys as strings), lists and tuples recurse; NumPy arrays become lists and NumPy
    scalars Python ones (a numpy integer or bool from a peer's summary is no crash); paths
    become strings; NaN and inf become ``None`` (strict JSON).
    """
    if isinstance(value, dict):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_ready(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_json(path: Path, report: Any) -> None:
    """Write ``report`` as strict JSON (:func:`json_ready`), creating parent folders."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(json_ready(report), indent=2, allow_nan=False) + '\n')


def write_results(
    out: Path,
    run: EvalRun,
    summary: dict,
    details: dict,
    config: dict | None,
    bounds: EvaluationConfig,
    plots: bool = True,
    extra: dict[str, np.ndarray] | None = None,
) -> None:
    """Write the results folder (see the module docstring); ``extra``: more trajectories."""
    from mlsemreg_ros.codec.pose_files import write_kitti_poses, write_tum_poses

    out.mkdir(parents=True, exist_ok=True)
    (out / 'summary.json').write_text(json.dumps(summary, indent=2) + '\n')
    (out / 'details.json').write_text(json.dumps(details, indent=2) + '\n')
    if config is not None:
        (out / 'config.yaml').write_text(yaml.safe_dump(config, sort_keys=False))
    names = [f.name for f in fields(FrameRecord)]
    with open(out / 'frames.csv', 'w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(names)
        for record in run.records:
            row = [getattr(record, n) for n in names]
            writer.writerow([f'{v:.6g}' if isinstance(v, float) else v for v in row])
    write_kitti_poses(out / 'trajectory_kitti.txt', run.poses)
    write_tum_poses(out / 'trajectory_tum.txt', run.stamps_ns, run.poses)
    if run.gt_poses is not None:
        write_kitti_poses(out / 'ground_truth_kitti.txt', run.gt_poses)
        write_tum_poses(out / 'ground_truth_tum.txt', run.stamps_ns, run.gt_poses)
    if plots:
        write_plots(out, run, summary, bounds, extra)


def write_plots(
    out: Path,
    run: EvalRun,
    summary: dict,
    bounds: EvaluationConfig,
    extra: dict[str, np.ndarray] | None = None,
) -> None:
    """Plot trajectory.png, errors.png and correspondences.png (``extra``: more paths)."""
    from mlsemreg_ros.evaluation import plots

    rejected = np.array([r.registered and not r.accepted for r in run.records])
    rr = summary['registration_recall_pct']
    rr_text = f'RR {rr:.1f} %' if rr is not None else 'no ground truth'
    plots.plot_trajectory(
        out / 'trajectory.png',
        run.poses,
        run.gt_poses,
        rejected,
        f'{run.name}: estimated vs ground-truth trajectory ({rr_text})',
        extra,
        label=run.method,
    )
    registered = [r for r in run.records if r.registered]
    if registered:
        plots.plot_errors(
            out / 'errors.png',
            np.array([r.bag_index for r in registered]),
            np.array([r.re_deg for r in registered]),
            np.array([r.te_cm for r in registered]),
            np.array([r.success for r in registered]),
            f'{run.name}: per-frame error against the keyframe ({rr_text})',
            max_re_deg=bounds.max_rotation_deg,
            max_te_cm=100.0 * bounds.max_translation_m,
        )
    pair = run.plot_pair
    if pair is not None:
        n_in, n = int(pair['inliers'].sum()), int(pair['inliers'].size)
        plots.plot_correspondences(
            out / 'correspondences.png',
            pair['target_points'],
            pair['source_points'],
            pair['T_gt'],
            pair['source_keypoints'],
            pair['target_keypoints'],
            pair['inliers'],
            target_labels=pair['target_labels'],
            source_labels=pair['source_labels'],
            title=f'scan {int(pair["bag_index"])} onto keyframe {int(pair["keyframe_index"])}: '
            f'{n_in} of {n} correspondences are ground-truth inliers '
            f'(IR {100 * n_in / max(n, 1):.1f} %); points coloured by class',
        )


def default_output(root: Path, kind: str, name: str) -> Path:
    """``root/<kind>/<YYYYmmdd-HHMMSS>_<name>`` (``~N`` appended while it exists)."""
    out = root / kind / f'{datetime.now().strftime("%Y%m%d-%H%M%S")}_{name}'
    suffix = 1
    while out.exists():
        out = out.with_name(f'{out.name.rsplit("~", 1)[0]}~{suffix}')
        suffix += 1
    return out


def link_latest(out: Path) -> None:
    """Point ``<parent>/latest`` at ``out`` (best effort)."""
    latest = out.parent / 'latest'
    try:
        if latest.is_symlink() or latest.exists():
            latest.unlink()
        latest.symlink_to(out.name)
    except OSError:
        pass
