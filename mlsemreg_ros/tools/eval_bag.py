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
``mlsemreg-eval-bag``: replay a bag offline through the node's odometry and score it.

No ROS runtime: the bag is read with ``rosbags`` (mcap or sqlite3; a SemanticKITTI
folder works too) and every scan goes through
:class:`mlsemreg_ros.core.odometry.Odometry` -- the registration code, config and
keyframe policy of the node. ``--stride S`` keeps every S-th scan, so scan k is
registered against scan k - S (keyframe policy every_frame).

Per registered pair (scan against its keyframe) the estimate is compared with
the ground-truth relative transform: success iff the registration was accepted
and RE <= 5 deg and TE <= 60 cm (paper, KITTI); RR = share of successful pairs;
RE/TE are averaged over successful pairs. Results folder (``--output``, default
``results/eval_bag/<time>_<bag>`` with a ``latest`` link):

    summary.json          n_frames, registration_recall_pct, rotation_error_deg,
                          translation_error_cm, kitti_t_err_pct, kitti_r_err_deg_per_100m,
                          ate_rmse_m, latency_ms_p50, latency_ms_p95, nees_mean
    details.json          run information (bag, stride, counts, mean IR/IN, stage timings)
    frames.csv            one row per scan
    trajectory_kitti.txt  estimated poses (KITTI); ground_truth_kitti.txt likewise
    trajectory_tum.txt    estimated poses (TUM); ground_truth_tum.txt likewise
    config.yaml           effective parameters (node layout; feed back with --config)
    trajectory.png, errors.png, correspondences.png
"""

from __future__ import annotations

import argparse
import csv
from dataclasses import dataclass, field, fields
from datetime import datetime
import json
import math
from pathlib import Path
import sys
import time
from typing import Any

from mlsemreg_ros.core.config import ConfigError, load_config, NODE_NAME, RegistrationConfig
from mlsemreg_ros.core.metrics import (
    ate_rmse,
    inlier_mask,
    kitti_odometry_errors,
    rotation_error_deg,
    translation_error_m,
)
from mlsemreg_ros.core.rigid import invert_transform as inverse
from mlsemreg_ros.tools.cli_help import HelpFormatter
import numpy as np
import yaml

#: summary.json keys, in order (the issue's contract).
SUMMARY_KEYS = ('n_frames', 'registration_recall_pct', 'rotation_error_deg',
                'translation_error_cm', 'kitti_t_err_pct', 'kitti_r_err_deg_per_100m',
                'ate_rmse_m', 'latency_ms_p50', 'latency_ms_p95', 'nees_mean')
#: Success bounds (paper, KITTI).
MAX_RE_DEG = 5.0
MAX_TE_M = 0.6


@dataclass
class FrameRecord:
    """One row of frames.csv."""

    frame: int  # processed scan counter
    bag_index: int  # index of the scan in the bag
    stamp_ns: int
    keyframe_index: int  # bag index of the keyframe it was registered onto
    registered: bool  # False for the first scan
    accepted: bool  # registration succeeded (enough inliers) and moved the pose
    success: bool  # accepted and RE <= 5 deg and TE <= 60 cm
    re_deg: float
    te_cm: float
    correspondences: int
    inliers: int  # estimator inliers
    gt_inliers: int  # correspondences within the inlier threshold under the ground truth
    ir_gt_pct: float  # 100 * gt_inliers / correspondences
    mode: str
    new_keyframe: bool
    latency_ms: float
    x: float
    y: float
    z: float
    gt_x: float
    gt_y: float
    gt_z: float
    message: str = ''
    source: str = ''  # what gave the accepted pose (first, global, prediction, ...)
    nees: float = math.nan  # normalized estimation error squared of the frame's covariance


@dataclass
class EvalRun:
    """Everything an evaluation produced."""

    name: str
    records: list[FrameRecord]
    stamps_ns: np.ndarray  # (F,)
    poses: np.ndarray  # (F, 4, 4) estimated, first processed scan = identity
    gt_poses: np.ndarray | None  # (F, 4, 4) ground truth relative to the first processed scan
    wall_s: float
    stage_ms: dict[str, float] = field(default_factory=dict)  # mean per-frame stage timings
    plot_pair: dict[str, np.ndarray] | None = None
    method: str = 'ML-SemReg'


def _nan_to_none(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def load_parameters(config_path: Path | None, overrides: list[str]) -> RegistrationConfig:
    """Load the core config (odometry and keyframe included) from a YAML and ``--set``."""
    return load_config(config_path, overrides)


def effective_config(config: RegistrationConfig) -> dict:
    """Return the parameters in the node's YAML layout (loadable with ``--config``)."""
    return {NODE_NAME: {'ros__parameters': config.to_dict()}}


def _expected_frames(total: int, stride: int, max_frames: int | None) -> int:
    n = len(range(0, total, stride))
    return n if max_frames is None else min(n, max_frames)


def evaluate_sequence(source: Any, odometry: Any, stride: int = 1,
                      max_frames: int | None = None, gt_poses: np.ndarray | None = None,
                      plot_frame: int | None = None, progress: bool = True) -> EvalRun:
    """
    Run every selected scan of ``source`` through ``odometry`` and score the pairs.

    - ``source``: a :class:`~mlsemreg_ros.datasets.source.ScanSource`.
    - ``odometry``: a fresh :class:`~mlsemreg_ros.core.odometry.Odometry`.
    - ``stride``: keep scans 0, stride, 2 * stride, ...
    - ``max_frames``: stop after this many kept scans.
    - ``gt_poses``: (F_bag, 4, 4) ground truth by bag index, overriding the bag's.
    - ``plot_frame``: bag index of the pair kept for the correspondence plot
      (default: the middle registered scan).
    - ``progress``: show a tqdm progress bar.
    """
    from tqdm import tqdm

    threshold = odometry.config.estimator.inlier_threshold
    expected = _expected_frames(len(source), stride, max_frames)
    if plot_frame is None:
        plot_frame = max(expected // 2, 1) * stride
    gt_by_index: dict[int, np.ndarray] = {}
    records: list[FrameRecord] = []
    stamps, poses, gts = [], [], []
    stage_sums: dict[str, float] = {}
    plot_pair = None
    start = time.perf_counter()
    for scan in tqdm(source.scans(stride, max_frames), total=expected, desc=source.name,
                     unit='scan', disable=not progress):
        gt = scan.pose
        if gt_poses is not None:
            gt = gt_poses[scan.index] if scan.index < gt_poses.shape[0] else None
        if gt is not None:
            gt_by_index[scan.index] = gt
        labels = scan.labels if scan.labels is not None else np.zeros(len(scan), np.int64)
        keyframe = odometry.keyframe
        step = odometry.process(scan.xyz, labels, scan.stamp_ns)
        for stage, ms in step.timings_ms.items():
            stage_sums[stage] = stage_sums.get(stage, 0.0) + ms
        kf_index = scan.index if step.result is None else records[step.keyframe_index].bag_index
        record = _score(step, scan, gt, gt_by_index.get(kf_index), kf_index, threshold,
                        len(records))
        records.append(record)
        stamps.append(scan.stamp_ns)
        poses.append(step.pose)
        gts.append(gt)
        if (plot_pair is None and step.result is not None and scan.index >= plot_frame
                and gt is not None and kf_index in gt_by_index):
            T_gt = inverse(gt_by_index[kf_index]) @ gt
            plot_pair = {'target_points': keyframe.prepared.points,
                         'source_points': step.prepared.points, 'T_gt': T_gt,
                         'target_labels': keyframe.prepared.labels,
                         'source_labels': step.prepared.labels,
                         'source_keypoints': step.result.source_points,
                         'target_keypoints': step.result.target_points,
                         'inliers': inlier_mask(step.result.source_points,
                                                step.result.target_points, T_gt, threshold),
                         'bag_index': np.array(scan.index), 'keyframe_index': np.array(kf_index)}
    wall = time.perf_counter() - start
    have_gt = bool(gts) and all(g is not None for g in gts)
    gt_array = None
    if have_gt:
        gt_array = np.asarray(gts)
        gt_array = inverse(gt_array[0]) @ gt_array
    n = max(len(records), 1)
    return EvalRun(source.name, records, np.asarray(stamps, dtype=np.int64),
                   np.asarray(poses).reshape(-1, 4, 4), gt_array, wall,
                   {k: v / n for k, v in sorted(stage_sums.items())}, plot_pair)


def evaluate_kiss_icp(source: Any, stride: int = 1, max_frames: int | None = None,
                      gt_poses: np.ndarray | None = None, max_range: float = 100.0,
                      progress: bool = True) -> EvalRun:
    """
    Run KISS-ICP (Vizzo et al., RA-L 2023; PyPI ``kiss-icp``) on the same scans.

    Default KISS-ICP configuration (voxel size = max_range / 100, adaptive
    threshold, constant-velocity prediction), deskewing off (scans carry no
    per-point times). Each scan's pair is (previous kept scan, scan): the relative
    estimate ``inv(P_prev) P_k`` is scored like an ML-SemReg pair; every estimate
    counts as accepted (KISS-ICP has no failure signal).
    """
    from kiss_icp.config import load_config
    from kiss_icp.kiss_icp import KissICP
    from tqdm import tqdm

    config = load_config(None)
    config.data.deskew = False
    config.data.max_range = max_range
    config.mapping.voxel_size = max_range / 100.0
    odometry = KissICP(config)
    expected = _expected_frames(len(source), stride, max_frames)
    records: list[FrameRecord] = []
    stamps, poses, gts = [], [], []
    nan = math.nan
    start = time.perf_counter()
    previous = None
    for scan in tqdm(source.scans(stride, max_frames), total=expected,
                     desc=f'{source.name} (kiss-icp)', unit='scan', disable=not progress):
        gt = scan.pose if gt_poses is None else (
            gt_poses[scan.index] if scan.index < gt_poses.shape[0] else None)
        tic = time.perf_counter()
        odometry.register_frame(np.asarray(scan.xyz, dtype=np.float64), np.zeros(0))
        latency = 1e3 * (time.perf_counter() - tic)
        pose = odometry.last_pose.copy()
        re = te = nan
        success = False
        if previous is not None and gt is not None and previous[2] is not None:
            T = inverse(previous[1]) @ pose
            T_gt = inverse(previous[2]) @ gt
            re = rotation_error_deg(T[:3, :3], T_gt[:3, :3])
            te = 100.0 * translation_error_m(T[:3, 3], T_gt[:3, 3])
            success = bool(re <= MAX_RE_DEG and te <= 100.0 * MAX_TE_M)
        gt_xyz = gt[:3, 3] if gt is not None else (nan, nan, nan)
        records.append(FrameRecord(
            len(records), scan.index, scan.stamp_ns,
            scan.index if previous is None else previous[0], previous is not None, True,
            success, re, te, 0, 0, 0, nan, 'kiss-icp', True, latency,
            *map(float, pose[:3, 3]), *map(float, gt_xyz)))
        previous = (scan.index, pose, gt)
        stamps.append(scan.stamp_ns)
        poses.append(pose)
        gts.append(gt)
    wall = time.perf_counter() - start
    gt_array = None
    if gts and all(g is not None for g in gts):
        gt_array = np.asarray(gts)
        gt_array = inverse(gt_array[0]) @ gt_array
    return EvalRun(source.name, records, np.asarray(stamps, dtype=np.int64),
                   np.asarray(poses).reshape(-1, 4, 4), gt_array, wall, method='KISS-ICP')


def _score(step: Any, scan: Any, gt: np.ndarray | None, gt_keyframe: np.ndarray | None,
           kf_index: int, threshold: float, frame: int) -> FrameRecord:
    """Score one odometry step against the ground truth: its frames.csv row."""
    nan = math.nan
    gt_xyz = gt[:3, 3] if gt is not None else (nan, nan, nan)
    result = step.result
    re = te = nees = nan
    gt_inliers, correspondences, inliers, mode = 0, 0, 0, ''
    message = step.reason or (result.message if result is not None else '')
    success = False
    if result is not None:
        correspondences = len(result.correspondences)
        inliers = result.num_inliers
        mode = result.mode
        if gt is not None and gt_keyframe is not None:
            T_gt = inverse(gt_keyframe) @ gt
            T = step.relative
            if T is not None and np.all(np.isfinite(T)):
                re = rotation_error_deg(T[:3, :3], T_gt[:3, :3])
                te = 100.0 * translation_error_m(T[:3, 3], T_gt[:3, 3])
                if step.accepted and step.frame_covariance is not None:
                    nees = normalized_error_squared(T, T_gt, step.frame_covariance)
            if correspondences:
                gt_inliers = int(np.count_nonzero(inlier_mask(
                    result.source_points, result.target_points, T_gt, threshold)))
            success = bool(step.accepted and re <= MAX_RE_DEG and te <= 100.0 * MAX_TE_M)
    ir = 100.0 * gt_inliers / correspondences if correspondences else nan
    return FrameRecord(frame, scan.index, scan.stamp_ns, kf_index, result is not None,
                       bool(step.accepted), success, re, te, correspondences, inliers,
                       gt_inliers, ir, mode, bool(step.new_keyframe), step.latency_ms,
                       *map(float, step.pose[:3, 3]), *map(float, gt_xyz), message,
                       step.source, nees)


def normalized_error_squared(T_estimate: np.ndarray, T_truth: np.ndarray,
                             covariance: np.ndarray) -> float:
    """
    NEES ``e^T inv(C) e`` of an estimate whose error ``T_truth^-1 T_estimate = exp(e)``.

    ``e = [translation, rotation vector]`` in the estimate's own frame (ROS order, as
    the step's ``frame_covariance``). A consistent covariance gives a mean NEES of 6 (the
    dimension); larger means overconfident, smaller underconfident.
    """
    from scipy.spatial.transform import Rotation

    error = inverse(T_truth) @ T_estimate
    e = np.concatenate([error[:3, 3], Rotation.from_matrix(error[:3, :3]).as_rotvec()])
    try:
        return float(e @ np.linalg.solve(covariance, e))
    except np.linalg.LinAlgError:
        return math.nan


def summarize(run: EvalRun) -> dict[str, Any]:
    """summary.json: exactly :data:`SUMMARY_KEYS` (None where undefined)."""
    # every registered scan with ground truth counts; a rejected one is a failure
    pairs = [r for r in run.records if r.registered and math.isfinite(r.gt_x)]
    ok = [r for r in pairs if r.success]
    nees = [r.nees for r in run.records if math.isfinite(r.nees)]
    latencies = [r.latency_ms for r in run.records if r.registered] or \
        [r.latency_ms for r in run.records]
    kitti = None
    ate = None
    if run.gt_poses is not None and len(run.records) >= 2:
        kitti = kitti_odometry_errors(run.poses, run.gt_poses)
        ate = ate_rmse(run.poses, run.gt_poses)
    summary = {
        'n_frames': len(run.records),
        'registration_recall_pct': 100.0 * len(ok) / len(pairs) if pairs else None,
        'rotation_error_deg': float(np.mean([r.re_deg for r in ok])) if ok else None,
        'translation_error_cm': float(np.mean([r.te_cm for r in ok])) if ok else None,
        'kitti_t_err_pct': kitti[0] if kitti else None,
        'kitti_r_err_deg_per_100m': kitti[1] if kitti else None,
        'ate_rmse_m': ate,
        'latency_ms_p50': float(np.percentile(latencies, 50)) if latencies else None,
        'latency_ms_p95': float(np.percentile(latencies, 95)) if latencies else None,
        'nees_mean': float(np.mean(nees)) if nees else None,
    }
    assert tuple(summary) == SUMMARY_KEYS
    return {k: _nan_to_none(v) for k, v in summary.items()}


def run_details(run: EvalRun, **extra: Any) -> dict[str, Any]:
    """details.json: counts, mean IR/IN, modes, stage timings and run information."""
    registered = [r for r in run.records if r.registered]
    irs = [r.ir_gt_pct for r in registered if math.isfinite(r.ir_gt_pct)]
    modes: dict[str, int] = {}
    sources: dict[str, int] = {}
    for r in registered:
        modes[r.mode] = modes.get(r.mode, 0) + 1
        sources[r.source or 'rejected'] = sources.get(r.source or 'rejected', 0) + 1
    details = {
        'sequence': run.name,
        'n_pairs': len(registered),
        'n_pairs_with_ground_truth': sum(math.isfinite(r.re_deg) for r in registered),
        'n_accepted': sum(r.accepted for r in registered),
        'n_rejected': sum(not r.accepted for r in registered),
        'n_success': sum(r.success for r in registered),
        'inlier_ratio_gt_pct_mean': float(np.mean(irs)) if irs else None,
        'inlier_number_gt_mean': (float(np.mean([r.gt_inliers for r in registered]))
                                  if registered else None),
        'correspondences_mean': (float(np.mean([r.correspondences for r in registered]))
                                 if registered else None),
        'modes': modes,
        'pose_sources': sources,
        'path_length_m': (float(np.sum(np.linalg.norm(np.diff(run.gt_poses[:, :3, 3], axis=0),
                                                      axis=1)))
                          if run.gt_poses is not None else None),
        'wall_time_s': run.wall_s,
        'stage_ms_mean': run.stage_ms,
    }
    details.update(extra)
    return {k: _nan_to_none(v) for k, v in details.items()}


def write_results(out: Path, run: EvalRun, summary: dict, details: dict, config: dict | None,
                  plots: bool = True, extra: dict[str, np.ndarray] | None = None) -> None:
    """Write the results folder (see the module docstring); ``extra``: more trajectories."""
    from mlsemreg_ros.datasets.pose_files import write_kitti_poses, write_tum_poses

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
        write_plots(out, run, summary, extra)


def write_plots(out: Path, run: EvalRun, summary: dict,
                extra: dict[str, np.ndarray] | None = None) -> None:
    """Plot trajectory.png, errors.png and correspondences.png (``extra``: more paths)."""
    from mlsemreg_ros.evaluation import plots

    rejected = np.array([r.registered and not r.accepted for r in run.records])
    rr = summary['registration_recall_pct']
    rr_text = f'RR {rr:.1f} %' if rr is not None else 'no ground truth'
    plots.plot_trajectory(out / 'trajectory.png', run.poses, run.gt_poses, rejected,
                          f'{run.name}: estimated vs ground-truth trajectory ({rr_text})',
                          extra, label=run.method)
    registered = [r for r in run.records if r.registered]
    if registered:
        plots.plot_errors(out / 'errors.png', np.array([r.bag_index for r in registered]),
                          np.array([r.re_deg for r in registered]),
                          np.array([r.te_cm for r in registered]),
                          np.array([r.success for r in registered]),
                          f'{run.name}: per-frame error against the keyframe ({rr_text})')
    pair = run.plot_pair
    if pair is not None:
        n_in, n = int(pair['inliers'].sum()), int(pair['inliers'].size)
        plots.plot_correspondences(
            out / 'correspondences.png', pair['target_points'], pair['source_points'],
            pair['T_gt'], pair['source_keypoints'], pair['target_keypoints'], pair['inliers'],
            target_labels=pair['target_labels'], source_labels=pair['source_labels'],
            title=f'scan {int(pair["bag_index"])} onto keyframe {int(pair["keyframe_index"])}: '
            f'{n_in} of {n} correspondences are ground-truth inliers '
            f'(IR {100 * n_in / max(n, 1):.1f} %); points coloured by class')


def format_table(summary: dict, others: dict[str, dict] | None = None) -> str:
    """Format a (metric, unit, value) table; ``others`` adds columns (name -> summary)."""
    units = {'n_frames': '', 'registration_recall_pct': '%', 'rotation_error_deg': 'deg',
             'translation_error_cm': 'cm', 'kitti_t_err_pct': '%',
             'kitti_r_err_deg_per_100m': 'deg/100m', 'ate_rmse_m': 'm',
             'latency_ms_p50': 'ms', 'latency_ms_p95': 'ms', 'nees_mean': '(6 ideal)'}
    columns = {'value' if not others else 'ML-SemReg': summary, **(others or {})}

    def shown(value: Any) -> str:
        if value is None:
            return '-'
        return f'{value:d}' if isinstance(value, int) else f'{value:.3f}'

    header = f'{"metric":<28} {"unit":<9}' + ''.join(f' {name:>12}' for name in columns)
    lines = [header, '-' * len(header)]
    for key in SUMMARY_KEYS:
        lines.append(f'{key:<28} {units[key]:<9}' +
                     ''.join(f' {shown(s[key]):>12}' for s in columns.values()))
    return '\n'.join(lines)


def default_output(root: Path, name: str) -> Path:
    """``root/eval_bag/<YYYYmmdd-HHMMSS>_<name>``; ``root/eval_bag/latest`` points to it."""
    out = root / 'eval_bag' / f'{datetime.now().strftime("%Y%m%d-%H%M%S")}_{name}'
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


def build_parser() -> argparse.ArgumentParser:
    """Command-line interface."""
    p = argparse.ArgumentParser(
        prog='mlsemreg-eval-bag',
        description='Replay a bag (mcap or sqlite3) or SemanticKITTI folder offline through the '
        "node's registration and keyframe policy; write metrics, trajectories and plots.",
        formatter_class=HelpFormatter)
    p.add_argument('bag', type=Path, help='rosbag2 directory / .mcap / .db3, or a '
                   'SemanticKITTI sequence folder')
    p.add_argument('-o', '--output', type=Path,
                   help='results folder (default: RESULTS_ROOT/eval_bag/<time>_<bag>)')
    p.add_argument('--results-root', type=Path, default=Path('results'),
                   help='where default results folders go')
    data = p.add_argument_group('data')
    data.add_argument('--points-topic', help='PointCloud2 topic (default: the only one)')
    data.add_argument('--label-field', default='label', help='label field of the clouds')
    data.add_argument('--gt-topic', default='auto', help='ground-truth Odometry/PoseStamped '
                      'topic; auto: /ground_truth/odometry if present; none: ignore')
    data.add_argument('--gt-poses', type=Path, help='KITTI poses file, one line per bag scan '
                      '(overrides the bag ground truth)')
    data.add_argument('--gt-calib', type=Path, help='KITTI calib.txt: convert --gt-poses from '
                      'camera to LiDAR frame with Tr')
    data.add_argument('--stride', type=int, default=1, help='register scan k against k - S')
    data.add_argument('--max-frames', type=int, help='stop after this many (strided) scans')
    params = p.add_argument_group('parameters')
    params.add_argument('--config', type=Path, help='parameter YAML (node params layout, e.g. '
                        'config/params.yaml, or plain core sections)')
    params.add_argument('--set', action='append', default=[], metavar='KEY=VALUE',
                        help='override one parameter, e.g. --set semantic.enabled=false '
                        '--set keyframe.policy=distance (repeatable)')
    out = p.add_argument_group('output')
    out.add_argument('--plot-frame', type=int, help='bag index of the correspondence plot '
                     '(default: middle of the run)')
    out.add_argument('--no-plots', action='store_true', help='skip the PNG plots')
    out.add_argument('--fail-below', type=float, metavar='RR',
                     help='exit with status 1 if the registration recall (%%) is below RR')
    out.add_argument('--quiet', action='store_true', help='no progress bar')
    p.add_argument('--baseline', choices=('none', 'kiss-icp'), default='none',
                   help='also run KISS-ICP on the same scans and compare (results in '
                   'OUTPUT/kiss-icp/)')
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``mlsemreg-eval-bag``."""
    args = build_parser().parse_args(argv)
    if args.stride < 1:
        print('error: --stride must be >= 1', file=sys.stderr)
        return 2
    try:
        config = load_parameters(args.config, args.set)
    except (ConfigError, OSError) as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
    from mlsemreg_ros.core.odometry import Odometry
    from mlsemreg_ros.core.pipeline import Registration
    from mlsemreg_ros.datasets.factory import is_rosbag2, open_scan_source
    from mlsemreg_ros.datasets.pose_files import (
        camera_to_lidar_poses,
        read_kitti_calib,
        read_kitti_poses,
    )
    from mlsemreg_ros.datasets.source import SourceError

    kwargs: dict[str, Any] = {}
    if is_rosbag2(args.bag):
        gt_topic = None if args.gt_topic == 'none' or args.gt_poses else args.gt_topic
        kwargs = {'points_topic': args.points_topic, 'gt_topic': gt_topic,
                  'label_field': args.label_field}
    try:
        source = open_scan_source(args.bag, **kwargs)
    except SourceError as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
    gt_poses = None
    if args.gt_poses is not None:
        gt_poses = read_kitti_poses(args.gt_poses)
        if args.gt_calib is not None:
            gt_poses = camera_to_lidar_poses(gt_poses, read_kitti_calib(args.gt_calib)['Tr'])
    odometry = Odometry(Registration(config))
    try:
        run = evaluate_sequence(source, odometry, args.stride, args.max_frames, gt_poses,
                                args.plot_frame, progress=not args.quiet)
    finally:
        source.close()
    if not run.records:
        print('error: no scans read', file=sys.stderr)
        return 1
    summary = summarize(run)
    details = run_details(run, bag=str(args.bag), stride=args.stride,
                          max_frames=args.max_frames, argv=sys.argv[1:] if argv is None
                          else list(argv))
    out = args.output
    if out is None:
        out = default_output(args.results_root, run.name)
    others: dict[str, dict] = {}
    extra: dict[str, np.ndarray] = {}
    if args.baseline == 'kiss-icp':
        source = open_scan_source(args.bag, **kwargs)
        try:
            baseline = evaluate_kiss_icp(source, args.stride, args.max_frames, gt_poses,
                                         progress=not args.quiet)
        finally:
            source.close()
        others['KISS-ICP'] = summarize(baseline)
        extra['KISS-ICP'] = baseline.poses
        write_results(out / 'kiss-icp', baseline, others['KISS-ICP'],
                      run_details(baseline, bag=str(args.bag), stride=args.stride),
                      None, plots=False)
    write_results(out, run, summary, details, effective_config(config),
                  plots=not args.no_plots, extra=extra)
    if args.output is None:
        link_latest(out)
    print(format_table(summary, others))
    print(f'results: {out}')
    rr = summary['registration_recall_pct']
    if args.fail_below is not None and (rr is None or rr < args.fail_below):
        print(f'FAIL: registration recall {rr} % < {args.fail_below} %', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
