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
mlsemreg-eval-bag end to end on a short simulated bag, with regression thresholds.

The bag: 5 simulated scans (1 m apart); ``--stride 2`` registers scan k onto
k - 2 (2 m). Thresholds fail when the registration is broken: a starved
configuration (40 keypoints, no semantics) must drop the recall, and ML-SemReg
must keep a clearly higher inlier ratio than plain matching (paper's claim).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

from mlsemreg_ros.codec.pose_files import read_kitti_poses, read_tum_poses
from mlsemreg_ros.core.config import load_config, RegistrationConfig
from mlsemreg_ros.evaluation.scoring import SUMMARY_KEYS
from mlsemreg_ros.tools import eval_bag
import numpy as np
import pytest
from sim_bags import simulated_bag

#: Fewer keypoints than the default keep the test fast (SC2-PCR is quadratic).
FAST = ['--set', 'keypoints.count=1500']


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulated_bag(tmp_path_factory.mktemp('eval') / 'sim', frames=5, seed=5)


@pytest.fixture(scope='module')
def default_run(bag: Path) -> Path:
    """Results folder of the default configuration (shared by the tests below)."""
    out = bag.parent / 'default'
    run(bag, out)
    return out


def run(bag: Path, out: Path, *args: str) -> dict[str, Any]:
    assert eval_bag.main([str(bag), '-o', str(out), '--stride', '2', '--quiet', *FAST, *args]) == 0
    return json.loads((out / 'summary.json').read_text())


def test_eval_bag_registers_the_simulated_bag_and_writes_every_output(default_run: Path) -> None:
    out = default_run
    summary = json.loads((out / 'summary.json').read_text())
    assert tuple(summary) == SUMMARY_KEYS
    assert summary['n_frames'] == 3
    assert summary['registration_recall_pct'] == 100.0
    assert summary['rotation_error_deg'] < 0.1  # fine alignment against the local map
    assert summary['translation_error_cm'] < 2.0
    assert summary['ate_rmse_m'] < 0.02
    assert summary['nees_mean'] > 0
    assert summary['kitti_t_err_pct'] is None  # 4 m: shorter than the 100 m segments
    assert summary['latency_ms_p95'] >= summary['latency_ms_p50'] > 0
    details = json.loads((out / 'details.json').read_text())
    # the first pair is registered globally; the second may be tracked by the prediction
    assert details['n_pairs'] == 2 and details['modes'].get('ml-semreg', 0) >= 1
    assert set(details['modes']) <= {'ml-semreg', 'tracking'}
    assert sum(details['pose_sources'].values()) == 2 and 'rejected' not in details['pose_sources']
    with open(out / 'frames.csv') as f:
        rows = list(csv.DictReader(f))
    assert [int(r['bag_index']) for r in rows] == [0, 2, 4]
    assert [int(r['keyframe_index']) for r in rows] == [0, 0, 2]
    assert all(r['success'] == 'True' for r in rows[1:])
    assert read_kitti_poses(out / 'trajectory_kitti.txt').shape == (3, 4, 4)
    stamps, tum = read_tum_poses(out / 'trajectory_tum.txt')
    assert tum.shape == (3, 4, 4) and np.all(np.diff(stamps) > 0.19)
    np.testing.assert_allclose(
        tum[2, :3, 3], read_kitti_poses(out / 'ground_truth_kitti.txt')[2, :3, 3], atol=0.2
    )
    for png in ('trajectory.png', 'errors.png', 'correspondences.png'):
        assert (out / png).stat().st_size > 10_000
    # The effective config loads back and equals what ran.
    config = load_config(out / 'config.yaml', [])
    assert config.keypoints.count == 1500 and config.keyframe.policy == 'every_frame'
    assert config == RegistrationConfig().replace({'keypoints.count': 1500})


def test_broken_registration_drops_the_recall(bag: Path, tmp_path: Path) -> None:
    # without the constant-velocity candidate the global estimate is the only one; and
    # without the covisible stages, which since session 14 judge the first keyframe's refined
    # pair and find the right pose even from 40 keypoints (docs/labels.md)
    broken = [
        '--set',
        'keypoints.count=40',
        '--set',
        'semantic.enabled=false',
        '--set',
        'odometry.constant_velocity=false',
        '--set',
        'covisibility.enabled=false',
    ]
    summary = run(bag, tmp_path / 'broken', *broken)
    assert summary['registration_recall_pct'] < 50.0
    assert (
        eval_bag.main(
            [
                str(bag),
                '-o',
                str(tmp_path / 'gate'),
                '--stride',
                '2',
                '--quiet',
                '--no-plots',
                '--fail-below',
                '90',
                *broken,
            ]
        )
        == 1
    )


def test_ml_semreg_has_a_higher_inlier_ratio_than_plain_matching(
    bag: Path, default_run: Path, tmp_path: Path
) -> None:
    plain = tmp_path / 'plain'
    run(bag, plain, '--no-plots', '--set', 'semantic.enabled=false')
    details = json.loads((default_run / 'details.json').read_text())
    ir_semantic = details['inlier_ratio_gt_pct_mean']
    ir_plain = json.loads((plain / 'details.json').read_text())['inlier_ratio_gt_pct_mean']
    assert ir_semantic > 2.0 * ir_plain, (ir_semantic, ir_plain)


def test_bad_parameters_are_reported(
    bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert eval_bag.main([str(bag), '-o', str(tmp_path / 'x'), '--set', 'semantic.nope=1']) == 2
    assert 'unknown parameter' in capsys.readouterr().err
    assert eval_bag.main([str(bag), '--set', 'keyframe.policy=sometimes']) == 2
    assert eval_bag.main([str(tmp_path), '--quiet']) == 2


@pytest.fixture(scope='module')
def drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Twenty simulated scans of seed 1 (a coarser sensor keeps it fast)."""
    return simulated_bag(tmp_path_factory.mktemp('drive') / 'sim', frames=20, seed=1)


def test_covariance_is_consistent_on_a_simulated_drive(drive: Path, tmp_path: Path) -> None:
    """
    Mean NEES of the frames' Hessian covariances within [1.5, 15] (6 = consistent).

    The clean drive has millimetre errors, so the Hessian covariance alone (times 7, the
    ``covariance`` section's floors off) is what is checked here; the default calibration is
    fitted on real pairs and field drives (docs/covariance.md) and is conservative here.
    """
    from mlsemreg_ros.core.alignment.covariance import no_calibration

    hessian_only = ['--set', 'odometry.covariance_scale=7']
    for name in vars(no_calibration()):
        hessian_only += ['--set', f'covariance.{name}=0']
    for stride in (1, 4):
        out = tmp_path / f'stride{stride}'
        args = [str(drive), '-o', str(out), '--stride', str(stride), '--quiet', '--no-plots']
        assert eval_bag.main(args + hessian_only) == 0
        summary = json.loads((out / 'summary.json').read_text())
        assert summary['registration_recall_pct'] == 100.0
        assert 1.5 <= summary['nees_mean'] <= 15.0, (stride, summary['nees_mean'])
        assert summary['translation_error_cm'] < 2.0 and summary['rotation_error_deg'] < 0.1


def test_drop_scans_chooses_a_seeded_round_share_never_the_first() -> None:
    from mlsemreg_ros.evaluation.drop_scans import degenerate_positions

    for n, share in ((20, 0.2), (20, 0.05), (7, 0.5), (3, 1.0)):
        chosen = degenerate_positions(n, share, seed=4)
        assert len(chosen) == min(round(share * n), n - 1)
        assert 0 not in chosen and max(chosen) < n
        assert chosen == degenerate_positions(n, share, seed=4)
    assert degenerate_positions(20, 0.2, 0) != degenerate_positions(20, 0.2, 1)
    assert degenerate_positions(20, 0.0, 0) == set()


def test_drop_scans_recover_within_two_scans_and_leave_p0_unchanged(
    drive: Path, tmp_path: Path
) -> None:
    """
    --drop-scans 0.2: 4 of 20 scans degenerate, every good scan after one registers within 2.

    RR is over the good scans (100 %), no wrong pose is published, and the degenerate scans
    are marked in frames.csv; P = 0 gives the summary of a run without the option.
    """
    args = [str(drive), '--quiet', '--no-plots', *FAST]
    assert eval_bag.main([*args, '-o', str(tmp_path / 'p02'), '--drop-scans', '0.2']) == 0
    summary = json.loads((tmp_path / 'p02' / 'summary.json').read_text())
    assert summary['degenerate_scans'] == round(0.2 * 20)
    assert summary['n_frames'] == 20 - summary['degenerate_scans']
    assert summary['after_degenerate'] >= 1
    assert summary['recovered_within_2'] == summary['after_degenerate']
    assert summary['wrong_published'] == 0
    assert summary['registration_recall_pct'] == 100.0
    with (tmp_path / 'p02' / 'frames.csv').open() as f:
        marked = [row for row in csv.DictReader(f) if row['message'].startswith('degenerate')]
    assert len(marked) == summary['degenerate_scans']

    timing = ('latency_ms_p50', 'latency_ms_p95')
    summaries = []
    for name, extra in (('plain', []), ('p0', ['--drop-scans', '0', '--drop-seed', '3'])):
        assert eval_bag.main([*args, '-o', str(tmp_path / name), *extra]) == 0
        summaries.append(json.loads((tmp_path / name / 'summary.json').read_text()))
    assert tuple(summaries[1]) == SUMMARY_KEYS
    plain, p0 = summaries
    for key in set(SUMMARY_KEYS) - set(timing):  # multithreaded sums: last digits vary
        assert p0[key] == (None if plain[key] is None else pytest.approx(plain[key], rel=1e-6))


def test_evaluate_bag_from_python_equals_the_command(
    bag: Path, default_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """evaluate_bag (no CLI) gives the command's summary and writes under results_root/latest."""
    from mlsemreg_ros.evaluation.bag_run import (
        BagEvalOptions,
        BagTopics,
        evaluate_bag,
        print_bag_evaluation,
    )
    from mlsemreg_ros.evaluation.settings import EvaluationSettings

    core = RegistrationConfig().replace({'keypoints.count': 1500})
    options = BagEvalOptions(stride=2, plots=False, progress=False, argv=('python',))
    result = evaluate_bag(
        bag,
        core,
        EvaluationSettings().evaluation,
        BagTopics('label'),
        options,
        results_root=tmp_path,
    )
    assert result.output.parent == tmp_path / 'eval_bag'
    assert (tmp_path / 'eval_bag' / 'latest').resolve() == result.output.resolve()
    assert result.summary == json.loads((result.output / 'summary.json').read_text())
    assert result.details['argv'] == ['python'] and result.details['stride'] == 2
    assert not result.dropped and result.peers.summaries == {}
    assert result.deskewed_scans == {result.run.method: result.details['deskewed_scans']}
    command = json.loads((default_run / 'summary.json').read_text())
    for key in set(SUMMARY_KEYS) - {'latency_ms_p50', 'latency_ms_p95'}:
        expected = command[key]
        assert result.summary[key] == (
            None if expected is None else pytest.approx(expected, rel=1e-6)
        ), key
    print_bag_evaluation(result)
    printed = capsys.readouterr().out
    assert 'wrong poses published' in printed and str(result.output) in printed


def test_evaluate_bag_names_bad_input(bag: Path, tmp_path: Path) -> None:
    from mlsemreg_ros.evaluation.bag_run import (
        BagEvalOptions,
        BagInputError,
        BagTopics,
        evaluate_bag,
    )
    from mlsemreg_ros.evaluation.settings import EvaluationSettings

    bounds, options = EvaluationSettings().evaluation, BagEvalOptions(progress=False)
    core = RegistrationConfig()
    with pytest.raises(BagInputError, match='neither a rosbag2'):
        evaluate_bag(tmp_path, core, bounds, BagTopics('label'), options, tmp_path / 'o')
    with pytest.raises(BagInputError):
        evaluate_bag(
            bag, core, bounds, BagTopics('label', points_topic='/no/such'), options, tmp_path
        )
    assert not (tmp_path / 'o').exists()
