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
"""End-to-end runs of mlsemreg-eval-pairs and mlsemreg-bench on generated pair files."""

import json

from mlsemreg_ros.core.features.features import sample_keypoints
from mlsemreg_ros.core.features.fpfh import fpfh_at_keypoints
from mlsemreg_ros.datasets.pairs import list_pairs, load_pair, save_pair
from mlsemreg_ros.datasets.synthetic_scene import synthetic_pair
from mlsemreg_ros.evaluation.benchmark import STAGES
from mlsemreg_ros.tools import bench, eval_pairs
import numpy as np
import pytest

PAIR_KEYS = {
    'name',
    'n_correspondences',
    'inlier_number',
    'inlier_ratio_pct',
    'rotation_error_deg',
    'translation_error_cm',
    'success',
    'time_ms',
}
SUMMARY_KEYS = {
    'n_pairs',
    'inlier_number',
    'inlier_ratio_pct',
    'registration_recall_pct',
    'rotation_error_deg',
    'translation_error_cm',
    'time_ms',
}


@pytest.fixture(scope='module')
def pair_dir(tmp_path_factory):
    """Two small generated pairs with keypoints and a stand-in 'gedi' descriptor (FPFH)."""
    folder = tmp_path_factory.mktemp('pairs')
    for seed, yaw in ((0, 6.0), (1, -4.0)):
        pair = synthetic_pair(seed, yaw_deg=yaw, translation=(2.0, 0.5, 0.0), max_points=6000)
        for side in ('src', 'dst'):
            pts = getattr(pair, f'pts_{side}')
            idx = sample_keypoints(pts, 600, 'random', 1.0, seed)
            setattr(pair, f'kpts_{side}', pts[idx])
            descriptors = fpfh_at_keypoints(pts, idx, 0.9, 1.5, 0.6)
            getattr(pair, f'descriptors_{side}')['gedi'] = descriptors
        save_pair(folder / f'{seed:06d}.npz', pair)
    return folder


def test_pair_files_round_trip(pair_dir):
    paths = list_pairs(pair_dir)
    assert [p.name for p in paths] == ['000000.npz', '000001.npz']
    pair = load_pair(paths[0])
    assert pair.name == '000000' and pair.descriptor_names == ['gedi']
    src, dst = pair.descriptors('gedi')
    assert src.shape == (600, 33) and dst.shape == (600, 33) and pair.kpts_src.shape == (600, 3)
    assert pair.trans_gt.shape == (4, 4)
    with pytest.raises(KeyError, match='fcgf'):
        pair.descriptors('fcgf')


@pytest.mark.parametrize(
    'extra',
    [
        ['--descriptor', 'gedi'],
        ['--descriptor', 'fpfh', '--no-semantic', '--matcher', 'mnn'],
        [
            '--descriptor',
            'fpfh',
            '--set',
            'semantic.top_k=3',
            '--set',
            'estimator.max_correspondences=500',
        ],
    ],
)
def test_eval_pairs_writes_the_report(pair_dir, tmp_path, capsys, extra):
    out = tmp_path / 'sub' / 'report.json'
    assert eval_pairs.main([str(pair_dir), '--json', str(out), '--no-progress', *extra]) == 0
    report = json.loads(out.read_text())
    assert set(report) >= {'config', 'pairs', 'summary'}
    assert [p['name'] for p in report['pairs']] == ['000000', '000001']
    for row in report['pairs']:
        assert set(row) >= PAIR_KEYS
        assert {'total_ms', 'estimator_ms'} <= set(row['time_ms'])
        assert 0 <= row['inlier_number'] <= row['n_correspondences']
        # the confidence verdict beside the paper's geometric success, and its evidence
        assert isinstance(row['accepted'], bool) and isinstance(row['bev_search'], bool)
        assert {'num_inliers', 'overlap', 'label_agreement', 'tilt_deg'} <= set(row['evidence'])
    summary = report['summary']
    assert set(summary) >= SUMMARY_KEYS and summary['n_pairs'] == 2
    assert 'total_ms' in summary['time_ms']
    if '--no-semantic' in extra:
        assert report['config']['semantic']['enabled'] is False
        assert report['config']['matcher']['kind'] == 'mnn'
    if 'semantic.top_k=3' in extra:
        assert report['config']['semantic']['top_k'] == 3
        assert all(p['n_correspondences'] <= 500 for p in report['pairs'])
    printed = capsys.readouterr().out
    assert '000001' in printed and 'mean' in printed and 'RR' in printed
    assert 'accepted' in printed and '…' not in printed  # no cell cut short off a terminal


def test_eval_pairs_registers_the_generated_pairs(pair_dir, tmp_path):
    out = tmp_path / 'report.json'
    assert (
        eval_pairs.main(
            [str(pair_dir), '--descriptor', 'fpfh', '--json', str(out), '--no-progress']
        )
        == 0
    )
    report = json.loads(out.read_text())
    assert report['summary']['registration_recall_pct'] == 100.0
    assert report['summary']['translation_error_cm'] < 30.0


def test_eval_pairs_errors_are_clear(tmp_path, capsys):
    assert eval_pairs.main([str(tmp_path), '--no-progress']) == 1
    assert 'no pair files' in capsys.readouterr().err
    assert eval_pairs.main([str(tmp_path), '--set', 'semantic.nope=1']) == 2
    assert 'semantic.nope' in capsys.readouterr().err
    pair = synthetic_pair(0, max_points=2000)
    save_pair(tmp_path / 'a.npz', pair)  # no keypoints, no descriptors
    assert eval_pairs.main([str(tmp_path), '--descriptor', 'gedi', '--no-progress']) == 1
    assert "no 'gedi' descriptors" in capsys.readouterr().err


def test_label_noise_sweep_runs_every_level_and_refuses_bad_input_first(
    pair_dir, tmp_path, capsys
):
    from mlsemreg_ros.tools import label_noise_sweep

    out = tmp_path / 'sweep'
    args = [str(pair_dir), '--out', str(out), '--descriptor', 'fpfh']
    assert label_noise_sweep.main([*args, '--level', 'none', '--level', 'flip:0.2']) == 0
    sweep = json.loads((out / 'sweep.json').read_text())
    assert [(r['descriptor'], r['noise']) for r in sweep['rows']] == [
        ('fpfh', 'none'), ('fpfh', 'flip:0.2'),
    ]  # fmt: skip
    assert set(sweep['reports']) == {'fpfh none', 'fpfh flip:0.2'}
    assert sweep['rows'][0]['rr_pct'] == 100.0 and (out / 'sweep.png').exists()
    capsys.readouterr()
    bad = tmp_path / 'bad'
    bad_args = [str(pair_dir), '--out', str(bad), '--descriptor']
    assert label_noise_sweep.main([*bad_args, 'fpfh', '--level', 'flip:2']) == 2
    assert label_noise_sweep.main([*bad_args, 'shot', '--level', 'none']) == 2
    assert 'gedi or fpfh' in capsys.readouterr().err and not bad.exists()


def test_bench_writes_per_stage_medians(pair_dir, tmp_path, capsys):
    out = tmp_path / 'bench.json'
    path = pair_dir / '000000.npz'
    assert (
        bench.main(
            [
                '--pair',
                str(path),
                '--repeats',
                '2',
                '--keypoints',
                '100,300',
                '--json',
                str(out),
                '--no-progress',
            ]
        )
        == 0
    )
    report = json.loads(out.read_text())
    assert set(report['keypoints']) == {'100', '300'}
    for row in report['keypoints'].values():
        assert set(row) >= set(STAGES)
        assert all(row[s] >= 0 for s in STAGES)
        # FPFH runs beside Local-SS and landmarks inside prepare(): those overlap
        serial = row['fpfh_ms'] + row['gm_mm_ms'] + row['sc2pcr_ms']
        assert row['total_ms'] >= 0.9 * serial
        assert row['total_parallel_ms'] > 0
    assert report['machine']['cpu_count'] >= 1 and report['machine']['numpy'] == np.__version__
    assert 'Local-SS' in capsys.readouterr().out


def test_bench_runs_on_the_generated_scene(tmp_path):
    out = tmp_path / 'bench.json'
    assert (
        bench.main(
            [
                '--synthetic',
                '--repeats',
                '1',
                '--keypoints',
                '150',
                '--json',
                str(out),
                '--no-progress',
            ]
        )
        == 0
    )
    report = json.loads(out.read_text())
    assert report['pair'] == 'generated street scene'
    assert report['keypoints']['150']['keypoints_used'] == 150


def test_config_precedence_yaml_then_flags_then_set(tmp_path):
    path = tmp_path / 'cfg.yaml'
    path.write_text('matcher:\n  kind: mnn\nsemantic:\n  top_k: 3\n  ring_width: 2.0\n')
    config = eval_pairs.build_config(
        path, {'matcher.kind': 'nn'}, ['semantic.top_k=4', 'estimator.kind=ransac']
    )
    assert config.matcher.kind == 'nn' and config.semantic.top_k == 4
    assert config.semantic.ring_width == 2.0 and config.estimator.kind == 'ransac'
    with pytest.raises(ValueError, match='KEY=VALUE'):
        eval_pairs.build_config(None, {}, ['semantic.top_k'])


def test_tables_never_cut_a_cell_short_off_a_terminal(capsys):
    """Wider than the 80 columns rich assumes off a terminal, with a footer wider than cells."""
    from mlsemreg_ros.evaluation.tables import print_table, ResultTable

    headers = [f'column {i}' for i in range(9)]
    rows = [[f'seed0_0001_{i:04d}' for i in range(9)]] * 3
    footer = ['mean'] + [f'RR 100.0% of {i}' for i in range(8)]
    print_table(ResultTable(headers, rows, footer))
    printed = capsys.readouterr().out
    assert '…' not in printed
    assert all(cell in printed for cell in rows[0] + footer)
