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
"""The hard-pair tools: mlsemreg-cut-pairs, the eval-pairs baselines, the bench column."""

from __future__ import annotations

import csv
import importlib.util
import json
from pathlib import Path

from mlsemreg_ros.core.features.features import sample_keypoints
from mlsemreg_ros.core.metrics import evaluate_pair
from mlsemreg_ros.datasets.pairs import list_pairs, load_pair, save_pair
from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair
from mlsemreg_ros.evaluation.baselines import KISS_MATCHER_MISSING
from mlsemreg_ros.tools import bench, cut_pairs, eval_pairs, simulate
import numpy as np
import pytest
from scipy.spatial import cKDTree

HAS_KISS_MATCHER = importlib.util.find_spec('kiss_matcher') is not None
needs_kiss_matcher = pytest.mark.skipif(not HAS_KISS_MATCHER, reason=KISS_MATCHER_MISSING)


def _overlap(pair, T: np.ndarray, above_ground: bool = False) -> float:
    """Share of source points within 0.6 m of a target point under T (optionally off the road)."""
    points = pair.pts_src[pair.pts_src[:, 2] > -0.7] if above_ground else pair.pts_src
    moved = points @ T[:3, :3].T + T[:3, 3]
    distance, _ = cKDTree(pair.pts_dst).query(moved, distance_upper_bound=0.6)
    return float(np.isfinite(distance).mean())


@pytest.fixture(scope='module')
def cut_dir(tmp_path_factory) -> Path:
    """Pairs cut out of a short simulated bag (30 scans, 2 m apart, turning at the end)."""
    root = tmp_path_factory.mktemp('cut')
    bag = root / 'drive'
    assert (
        simulate.main(
            [
                str(bag),
                '--frames',
                '30',
                '--step',
                '2',
                '--seed',
                '0',
                '--beams',
                '32',
                '--azimuth-steps',
                '720',
                '--quiet',
            ]
        )
        == 0
    )
    out = root / 'pairs'
    assert (
        cut_pairs.main(
            [
                str(bag),
                str(out),
                '--stride-pairs',
                '3',
                '--turn-pairs',
                '2',
                '--min-distance',
                '15',
                '--turn-angle',
                '35',
                '--turn-min-distance',
                '10',
                '--turn-max-overlap',
                '1.0',
                '--keypoints',
                '300',
                '--quiet',
            ]
        )
        == 0
    )
    return out


def test_cut_pairs_writes_pair_files_with_a_true_ground_truth(cut_dir):
    with (cut_dir / 'pairs.csv').open() as handle:
        rows = list(csv.DictReader(handle))
    assert [r['kind'] for r in rows] == ['stride'] * 3 + ['turn'] * 2
    assert sorted(p.stem for p in list_pairs(cut_dir)) == sorted(r['name'] for r in rows)
    for row in rows:
        distance, rotation = float(row['distance_m']), float(row['rotation_deg'])
        if row['kind'] == 'stride':
            assert 15.0 <= distance <= 40.0 and rotation < 35.0
        else:
            assert 10.0 <= distance <= 40.0 and rotation >= 35.0
        pair = load_pair(cut_dir / f'{row["name"]}.npz')
        assert pair.kpts_src.shape == (300, 3) and pair.kpts_dst.shape == (300, 3)
        # keypoints are members of the points; labels are learning ids
        assert cKDTree(pair.pts_src).query(pair.kpts_src)[0].max() == 0.0
        assert pair.label_src.max() < 20 and pair.label_dst.max() < 20
        assert np.linalg.norm(pair.pts_src, axis=1).max() <= 60.0 + 1e-6
        # trans_gt maps the source scan onto the target scan, identity does not
        assert np.linalg.norm(pair.trans_gt[:3, 3]) == pytest.approx(distance, abs=0.01)
        overlap = _overlap(pair, pair.trans_gt)
        assert overlap == pytest.approx(float(row['overlap']), abs=1e-3)
        # off the ground (the sensor is 1.73 m up), only the true motion aligns the scans
        aligned = _overlap(pair, pair.trans_gt, above_ground=True)
        assert overlap > 0.1 and aligned > 2.0 * _overlap(pair, np.eye(4), above_ground=True)
        assert aligned > 2.0 * _overlap(pair, np.linalg.inv(pair.trans_gt), above_ground=True)


def test_cut_pairs_reports_a_bag_without_scans(tmp_path, capsys):
    assert cut_pairs.main([str(tmp_path / 'missing'), str(tmp_path / 'out'), '--quiet']) == 1
    assert 'cannot read' in capsys.readouterr().err


def test_cut_hard_pairs_is_called_from_python_and_refuses_a_single_scan(tmp_path) -> None:
    from mlsemreg_ros.datasets.hard_pairs import cut_hard_pairs, CutOptions, TooFewFrames

    bag = tmp_path / 'one'
    args = [str(bag), '--frames', '1', '--beams', '16', '--azimuth-steps', '360', '--quiet']
    assert simulate.main(args) == 0
    with pytest.raises(TooFewFrames, match='1 labeled scans'):
        cut_hard_pairs(bag, tmp_path / 'out', CutOptions(), progress=False)
    assert not (tmp_path / 'out').exists()


@needs_kiss_matcher
def test_kiss_matcher_registers_a_generated_pair():
    from mlsemreg_ros.evaluation.baselines import kiss_matcher_register

    pair = synthetic_pair(0, max_points=25000)
    result = kiss_matcher_register(pair.pts_src, pair.pts_dst)
    metrics = evaluate_pair(
        result.T_target_source, result.src_matched, result.dst_matched, pair.trans_gt
    )
    assert result.valid and result.num_final_inliers > 100
    assert metrics.success and metrics.rotation_error_deg < 1.0
    assert metrics.inlier_number > 100 and result.time_ms > 0.0


@pytest.fixture(scope='module')
def generated_dir(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp('generated')
    pair = synthetic_pair(0, max_points=25000)
    for side in ('src', 'dst'):
        points = getattr(pair, f'pts_{side}')
        setattr(pair, f'kpts_{side}', points[sample_keypoints(points, 1000, 'random', 1.0, 0)])
    save_pair(folder / '000000.npz', pair)
    return folder


@needs_kiss_matcher
def test_eval_pairs_compares_with_the_baselines_side_by_side(generated_dir, tmp_path, capsys):
    out = tmp_path / 'report.json'
    assert (
        eval_pairs.main(
            [
                str(generated_dir),
                '--descriptor',
                'fpfh',
                '--baseline',
                'kiss-matcher',
                '--baseline',
                'fpfh-ransac',
                '--set',
                'estimator.ransac_iterations=20000',
                '--no-progress',
                '--json',
                str(out),
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert 'comparison on the same pairs' in text and 'KISS-Matcher (voxel 0.3 m' in text
    assert 'Open3D FPFH + NN (plain) + ransac' in text
    report = json.loads(out.read_text())
    kiss = report['baselines']['KISS-Matcher (voxel 0.3 m, raw points, no labels)']
    assert kiss['summary']['registration_recall_pct'] == 100.0
    assert kiss['pairs'][0]['kiss_matcher_valid'] is True
    assert kiss['pairs'][0]['time_ms']['total_ms'] > 0
    ransac = report['baselines']['Open3D FPFH + NN (plain) + ransac']
    assert ransac['config']['features']['descriptor'] == 'fpfh_open3d'
    assert ransac['config']['verification']['enabled'] is False
    ours = report['pairs'][0]
    assert ours['success'] and ours['verification']['hypotheses'][0]['rank'] == 0


def test_kiss_matcher_baseline_says_how_to_install_it(generated_dir, capsys, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_kiss_matcher(name, *args, **kwargs):
        if name == 'kiss_matcher':
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, '__import__', no_kiss_matcher)
    assert (
        eval_pairs.main(
            [
                str(generated_dir),
                '--descriptor',
                'fpfh',
                '--baseline',
                'kiss-matcher',
                '--no-progress',
            ]
        )
        == 1
    )
    assert 'pip install kiss-matcher==1.0.2' in capsys.readouterr().err


def test_bench_reports_the_verification_stage(generated_dir, tmp_path):
    out = tmp_path / 'bench.json'
    path = generated_dir / '000000.npz'
    args = ['--pair', str(path), '--repeats', '1', '--keypoints', '500', '--json', str(out)]
    assert bench.main([*args, '--no-progress']) == 0
    row = json.loads(out.read_text())['keypoints']['500']
    assert row['verification_ms'] > 0.0
    assert bench.main([*args, '--set', 'verification.enabled=false', '--no-progress']) == 0
    assert json.loads(out.read_text())['keypoints']['500']['verification_ms'] == 0.0
