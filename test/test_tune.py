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
``mlsemreg tune``: the space from the metadata, pruning, resume, workers, the written file.

Tiny objectives only (:class:`CountingEvaluator`, two small generated pairs): no study
runs over the dev pairs here (docs/tuning.md has the real run).
"""

from __future__ import annotations

from dataclasses import dataclass
import json
import os
from pathlib import Path
import time
from types import MappingProxyType
from typing import Any

from mlsemreg_ros.core.config import ConfigError, RegistrationConfig
from mlsemreg_ros.evaluation import tuning
from mlsemreg_ros.evaluation.records import FrameRecord
from mlsemreg_ros.evaluation.settings import EvaluationConfig
import pytest
from ros_domains import domain_id
from tune_pairs import write_tiny_pair

optuna = pytest.importorskip('optuna')
DOMAIN_ID = domain_id('params_yaml')  # the node is only started to read its parameters


@dataclass
class CountingEvaluator:
    """A tiny objective: loss = distance of two parameters to a target; logs every call."""

    log: Path
    delay_s: float = 0.0
    objective: str = 'pairs'

    def __call__(self, config: RegistrationConfig) -> tuning.TrialScores:
        """Score ``config`` (and append this process's id to the log)."""
        time.sleep(self.delay_s)
        with self.log.open('a') as log:
            log.write(f'{os.getpid()} {config.semantic.local_radius!r}\n')
        loss = abs(config.semantic.local_radius - 1.0) + abs(config.semantic.top_k - 3)
        return tuning.TrialScores(loss, float(config.semantic.top_k), {'pid': os.getpid()})


def _task(tmp_path: Path, storage: str | None = None, **kwargs: Any) -> tuning.TuneTask:
    space = kwargs.pop('space', ['semantic.local_radius=0.1:5', 'semantic.top_k=1:6'])
    dims = [tuning.parse_space_item(item) for item in space]
    return tuning.TuneTask(
        storage or f'journal:{tmp_path / "study.log"}',  # (creating a SQLite one takes s)
        kwargs.pop('study_name', 'test'),
        CountingEvaluator(tmp_path / 'calls.log', kwargs.pop('delay_s', 0.0)),
        dims,
        kwargs.pop('base', {}),
        **kwargs,
    )


# -- the space -------------------------------------------------------------------------
def test_default_space_comes_from_the_metadata() -> None:
    space = {d.key: d for d in tuning.build_space('pairs')}
    assert set(space) == set(tuning.PAIRS_SPACE)
    radius = RegistrationConfig.field_of('semantic.local_radius').metadata
    assert space['semantic.local_radius'] == tuning.Dimension(
        'semantic.local_radius', 'float', radius['low'], radius['high'], log=True
    )
    assert space['semantic.ring_count'].kind == 'int'  # from the default's type
    assert (
        space['confidence.min_overlap'].kind == 'float' and not space['confidence.min_overlap'].log
    )  # starts at 0: linear
    assert space['estimator.graph_size'].log and space['estimator.graph_size'].low == 10
    bag = {d.key for d in tuning.build_space('bag')}
    assert bag == set(tuning.PAIRS_SPACE) | {'keypoints.count'}


def test_the_default_space_is_documented() -> None:
    page = (Path(__file__).resolve().parents[1] / 'docs' / 'tuning.md').read_text()
    for key in tuning.BAG_SPACE:
        assert f'| `{key}`' in page, key


def _patch_meta(monkeypatch: pytest.MonkeyPatch, key: str, **changes: Any) -> None:
    f = RegistrationConfig.field_of(key)
    monkeypatch.setattr(f, 'metadata', MappingProxyType({**f.metadata, **changes}))


def test_a_metadata_range_change_shows_up_in_the_space(monkeypatch: pytest.MonkeyPatch) -> None:
    _patch_meta(monkeypatch, 'semantic.ring_width', low=0.5, high=4.0)
    _patch_meta(monkeypatch, 'estimator.graph_size', high=1000)  # clips the window
    _patch_meta(monkeypatch, 'semantic.local_radius', low=0.2, high=1.5)  # under 2 decades
    space = {d.key: d for d in tuning.build_space('pairs')}
    assert (space['semantic.ring_width'].low, space['semantic.ring_width'].high) == (0.5, 4.0)
    assert space['estimator.graph_size'].high == 1000
    assert not space['semantic.local_radius'].log and space['semantic.local_radius'].low == 0.2
    with pytest.raises(ConfigError, match='above its maximum 4'):
        tuning.parse_space_item('semantic.ring_width=1:5')


def test_space_items_narrow_add_and_are_checked() -> None:
    dim = tuning.parse_space_item('estimator.graph_size=100:1000')
    assert (dim.kind, dim.low, dim.high, dim.log) == ('int', 100, 1000, False)
    assert tuning.parse_space_item('matcher.kind=nn,mnn').choices == ('nn', 'mnn')
    assert tuning.parse_space_item('semantic.enabled=true,false').choices == (True, False)
    assert tuning.parse_space_item('semantic.ring_width=1,2').choices == (1.0, 2.0)
    space = tuning.build_space('pairs', ['semantic.top_k=2:3', 'matcher.kind=nn,mnn'])
    assert {d.key: d for d in space}['semantic.top_k'].high == 3
    assert space[-1].key == 'matcher.kind'
    for item, reason in [
        ('semantic.bogus=1:2', 'unknown parameter'),
        ('matcher.kind=nn,xx', 'not one of'),
        ('semantic.top_k=0:3', 'below its minimum'),
        ('semantic.landmark_classes=a,b', 'list of class names'),
        ('semantic.top_k', 'KEY=LOW:HIGH'),
        ('semantic.top_k=5:2', 'above high'),
    ]:
        with pytest.raises(ConfigError, match=reason):
            tuning.parse_space_item(item)


# -- objectives --------------------------------------------------------------------------
def _row(success: bool, accepted: bool, re: float = 1.0, te: float = 10.0) -> dict[str, Any]:
    return {
        'success': success,
        'accepted': accepted,
        'rotation_error_deg': re,
        'translation_error_cm': te,
    }


def _report(rows: list[dict[str, Any]]) -> dict[str, Any]:
    rr = 100.0 * sum(r['success'] for r in rows) / len(rows)
    return {'pairs': rows, 'summary': {'registration_recall_pct': rr, 'time_ms': {'total_ms': 5}}}


def test_pairs_scores_rank_rr_first_and_penalize_wrong_poses() -> None:
    bounds = EvaluationConfig()
    all_right = tuning.pairs_scores(_report([_row(True, True)] * 10), bounds)
    assert all_right.accuracy_loss == pytest.approx(0.5 * 0.5 * (1 / 5 + 10 / 60))
    assert all_right.time == 5.0 and all_right.attrs['rr_pct'] == 100.0
    worst_errors = tuning.pairs_scores(_report([_row(True, True, 5.0, 60.0)] * 10), bounds)
    one_missed = tuning.pairs_scores(
        _report([_row(True, True, 0, 0)] * 9 + [_row(False, False)]), bounds
    )
    assert worst_errors.accuracy_loss < one_missed.accuracy_loss  # one more success wins
    one_refused = tuning.pairs_scores(
        _report([_row(True, True)] * 9 + [_row(True, False)]), bounds
    )
    assert all_right.accuracy_loss < one_refused.accuracy_loss < one_missed.accuracy_loss
    assert one_refused.attrs['refused_right'] == 1
    all_refused = tuning.pairs_scores(_report([_row(True, False)] * 10), bounds)
    assert one_refused.accuracy_loss < all_refused.accuracy_loss < one_missed.accuracy_loss
    wrong = tuning.pairs_scores(_report([_row(True, True)] * 9 + [_row(False, True)]), bounds)
    assert wrong.attrs['wrong_poses'] == 1
    none_right = tuning.pairs_scores(_report([_row(False, False)] * 10), bounds)
    assert wrong.accuracy_loss > none_right.accuracy_loss  # worse than RR 0


def _record(accepted: bool, success: bool) -> FrameRecord:
    nan = float('nan')
    return FrameRecord(
        0, 1, 0, 0, True, accepted, success, nan, nan, 0, 0, 0, nan, '', False, 10.0,
        0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
    )  # fmt: skip


def test_bag_scores_drift_wrong_poses_and_latency_ratio() -> None:
    summary = {'kitti_t_err_pct': 1.5, 'latency_ms_p50': 30.0, 'registration_recall_pct': 50}
    records = [_record(True, True), _record(False, False), _record(True, False)]
    scores = tuning.bag_scores(records, summary, kiss_latency_ms=20.0)
    assert scores.accuracy_loss == pytest.approx(1.5 + tuning.WRONG_POSE_PENALTY)
    assert scores.time == pytest.approx(1.5) and scores.attrs['wrong_poses'] == 1
    short = {**summary, 'kitti_t_err_pct': None, 'ate_rmse_m': 0.5, 'path_length_m': 50.0}
    assert tuning.bag_scores(records[:1], short, 20.0).accuracy_loss == pytest.approx(1.0)


# -- studies -----------------------------------------------------------------------------
def test_an_invalid_suggestion_is_pruned_with_its_reason(tmp_path: Path) -> None:
    # every point of this space has a receptive field ring_count x ring_width > 300 m
    space = ['semantic.ring_count=200:256', 'semantic.ring_width=2:3']
    task = _task(tmp_path, space=space)
    study = tuning.run_study(task, trials=3)
    trials = study.get_trials()
    assert [t.state for t in trials] == [optuna.trial.TrialState.PRUNED] * 3
    assert all('receptive-field limit' in t.user_attrs['pruned_reason'] for t in trials)
    assert not (tmp_path / 'calls.log').exists()  # never evaluated
    assert tuning.chosen_trial(study) is None


def test_resume_continues_the_study_and_refuses_another_search(tmp_path: Path) -> None:
    base = {'semantic.local_radius': 0.5}
    study = tuning.run_study(_task(tmp_path, base=base), trials=3)
    first = study.get_trials()[0]
    assert first.user_attrs.get('start') and first.params['semantic.local_radius'] == 0.5
    study = tuning.run_study(_task(tmp_path, base=base), trials=2)
    assert [t.number for t in study.get_trials()] == [0, 1, 2, 3, 4]
    assert sum(1 for t in study.get_trials() if t.user_attrs.get('start')) == 1
    with pytest.raises(ConfigError, match='another space'):
        tuning.open_study(_task(tmp_path, base=base, space=['semantic.top_k=1:6']))
    chosen = tuning.chosen_trial(study)
    assert chosen in study.best_trials
    assert chosen.values[0] == min(t.values[0] for t in study.best_trials)


@pytest.mark.slow  # two spawned processes that import the package (~10 s on 2 busy cores)
@pytest.mark.parametrize('kind', ['sqlite', 'journal'])
def test_two_workers_split_the_trials_of_one_study(tmp_path: Path, kind: str) -> None:
    storage = f'sqlite:///{tmp_path / "study.db"}' if kind == 'sqlite' else None
    task = _task(tmp_path, storage, delay_s=0.3)
    study = tuning.run_study(task, trials=8, workers=2, poll_s=0.2)
    trials = study.get_trials()
    assert [t.number for t in trials] == list(range(8))  # none lost, none twice
    assert all(t.state == optuna.trial.TrialState.COMPLETE for t in trials)
    calls = (tmp_path / 'calls.log').read_text().splitlines()
    assert len(calls) == 8  # every trial evaluated exactly once
    (start,) = [t for t in trials if t.user_attrs.get('start')]
    assert start.number == 0 and start.user_attrs['pid'] == os.getpid()  # run before workers
    pids = {t.user_attrs['pid'] for t in trials[1:]}
    assert len(pids) == 2 and os.getpid() not in pids  # both worker processes took trials
    assert {line.split()[0] for line in calls[1:]} == {str(p) for p in pids}
    assert tuning.split_trials(7, 2) == [4, 3] and tuning.split_trials(None, 2) == [None] * 2


def test_storage_urls() -> None:
    assert tuning.open_storage('sqlite:///x.db') == 'sqlite:///x.db'
    assert tuning.open_storage('postgresql://u:p@host/db') == 'postgresql://u:p@host/db'
    with pytest.raises(ConfigError, match='database URL'):
        tuning.open_storage('study.db')
    assert tuning.default_storage(Path('/a/b/params.yaml')) == 'sqlite:////a/b/params.db'


# -- the written parameter file ------------------------------------------------------------
@pytest.fixture(scope='module')
def pair_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One small generated pair (tune_pairs.py)."""
    return write_tiny_pair(tmp_path_factory.mktemp('pairs'))


@pytest.fixture(scope='module')
def tuned(pair_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Run ``mlsemreg tune`` for three trials on the tiny pair; its outputs."""
    from mlsemreg_ros.tools import cli

    out = tmp_path_factory.mktemp('tune') / 'tuned.yaml'
    args = ['tune', str(pair_dir), '--trials', '3', '--out', str(out), '--quiet']
    args += ['--storage', f'journal:{out.with_suffix(".log")}']
    args += ['--set', 'fine.pair_method=off', '--set', 'bev_search.enabled=false']
    for item in (  # cheap corners of the space only
        'semantic.local_radius=0.3:1.5',
        'semantic.ring_count=10:40',
        'semantic.ring_width=0.5:3',
        'estimator.graph_size=50:400',
        'estimator.inlier_threshold=0.2:2',
        'estimator.compatibility_threshold=0.2:2',
        'matcher.kind=nn,mnn',
    ):
        args += ['--space', item]
    assert cli.main(args) == 0
    record = json.loads(out.with_name('tuned_trials.json').read_text())
    return {'out': out, 'record': record}


@pytest.mark.slow  # the tuned fixture: three trials of mlsemreg tune
def test_tune_writes_the_node_parameter_file_results_and_plots(tuned: dict[str, Any]) -> None:
    from mlsemreg_ros.core.config import NODE_NAME, read_parameter_file
    from mlsemreg_ros.parameter_docs import params_yaml_text

    out, record = tuned['out'], tuned['record']
    chosen = next(t for t in record['trials'] if t['number'] == record['chosen'])
    config = RegistrationConfig.from_yaml(out)
    for key, value in chosen['params'].items():
        assert config.to_flat_dict()[key] == value
    assert config.fine.pair_method == 'off'  # the fixed starting point is kept
    text = out.read_text()
    assert text.startswith('# Parameters of mlsemreg_node tuned by `mlsemreg tune`')
    assert f'{NODE_NAME}:\n  ros__parameters:\n' in text
    expected = params_yaml_text(config.to_flat_dict(), header=[])
    assert text.split(f'{NODE_NAME}:')[1] == expected.split(f'{NODE_NAME}:')[1]
    assert set(read_parameter_file(out)) >= {'semantic', 'qos', 'odom_frame'}  # full file
    for plot in ('history', 'importance', 'pareto'):
        assert Path(record['plots'][plot]).is_file(), record['plots'][plot]
    assert record['chosen'] in record['pareto']


@pytest.mark.slow  # the tuned fixture: three trials of mlsemreg tune
def test_the_written_file_equals_the_same_values_by_set(
    tuned: dict[str, Any], pair_dir: Path, tmp_path: Path
) -> None:
    from mlsemreg_ros.tools import eval_pairs

    out, record = tuned['out'], tuned['record']
    chosen = next(t for t in record['trials'] if t['number'] == record['chosen'])
    sets = ['fine.pair_method=off', 'bev_search.enabled=false']
    sets += [f'{k}={v}' for k, v in chosen['params'].items()]
    reports = {}
    for label, args in (
        ('config', ['--config', str(out)]),
        ('set', [arg for item in sets for arg in ('--set', item)]),
    ):
        path = tmp_path / f'{label}.json'
        assert eval_pairs.main([str(pair_dir), '--quiet', '--json', str(path), *args]) == 0
        reports[label] = json.loads(path.read_text())
    assert reports['config']['config'] == reports['set']['config']
    for a, b in zip(reports['config']['pairs'], reports['set']['pairs'], strict=True):
        for key in ('n_correspondences', 'inlier_number', 'success', 'accepted'):
            assert a[key] == b[key], key
        assert a['rotation_error_deg'] == pytest.approx(b['rotation_error_deg'], abs=1e-6)
        assert a['translation_error_cm'] == pytest.approx(b['translation_error_cm'], abs=1e-4)


@pytest.mark.slow  # the tuned fixture: three trials of mlsemreg tune
def test_the_written_file_loads_in_the_node(tuned: dict[str, Any], ros_context: Any) -> None:
    from mlsemreg_ros.ros.node import MlSemRegNode
    from mlsemreg_ros.ros.node_config import all_parameter_fields

    out = tuned['out']
    expected = RegistrationConfig.from_yaml(out).to_flat_dict()
    with ros_context(DOMAIN_ID, ['--ros-args', '--params-file', str(out)]) as context:
        node = MlSemRegNode(context=context)
        try:
            names = [name for name, _, _ in all_parameter_fields()]
            declared = {p.name: p.value for p in node.get_parameters(names)}
            core = node._params.snapshot().core
        finally:
            node.destroy_node()
    for key, value in expected.items():
        assert declared[key] == value, key
    assert core.to_flat_dict() == expected


def test_tune_errors_are_clear(pair_dir: Path, tmp_path: Path, capsys: Any) -> None:
    from mlsemreg_ros.tools import cli

    out = str(tmp_path / 'p.yaml')
    assert cli.main(['tune', str(pair_dir), '--space', 'semantic.top_k=0:3', '--out', out]) == 2
    assert 'below its minimum' in capsys.readouterr().err
    assert cli.main(['tune', str(tmp_path), '--out', out]) == 2
    assert 'no pair files' in capsys.readouterr().err
    bad = ['--space', 'semantic.ring_count=200:256', '--space', 'semantic.ring_width=2:3']
    bad += ['--storage', f'journal:{tmp_path / "p.log"}']
    assert cli.main(['tune', str(pair_dir), '--trials', '2', '--quiet', '--out', out, *bad]) == 1
    assert 'no trial completed' in capsys.readouterr().err
    assert not Path(out).exists()


@pytest.mark.slow  # a simulated bag, KISS-ICP once and one trial of the odometry
def test_tune_on_a_bag_measures_kiss_icp_once(tmp_path: Path) -> None:
    from mlsemreg_ros.tools import cli, simulate

    bag = tmp_path / 'sim'
    args = [str(bag), '--frames', '3', '--seed', '5', '--azimuth-steps', '1024', '--quiet']
    assert simulate.main(args) == 0
    out = tmp_path / 'bag.yaml'
    storage = f'journal:{tmp_path / "bag.log"}'
    args = ['tune', str(bag), '--objective', 'bag', '--stride', '2', '--trials', '1']
    args += ['--set', 'keypoints.count=800', '--space', 'keypoints.count=500:1000']
    args += ['--storage', storage, '--out', str(out), '--quiet']
    assert cli.main(args) == 0
    study = optuna.load_study(study_name='mlsemreg', storage=tuning.open_storage(storage))
    assert study.user_attrs['kiss_latency_ms_p50'] > 0
    (trial,) = study.get_trials()
    assert trial.user_attrs['start'] and trial.params['keypoints.count'] == 800
    assert {'t_err_pct', 'wrong_poses', 'latency_ms_p50'} <= set(trial.user_attrs)
    assert trial.values[1] == pytest.approx(
        trial.user_attrs['latency_ms_p50'] / study.user_attrs['kiss_latency_ms_p50']
    )
    assert RegistrationConfig.from_yaml(out).keypoints.count == 800


def test_tune_parameters_from_python_runs_the_study_and_returns_the_chosen_values(
    pair_dir: Path, tmp_path: Path, capsys: Any
) -> None:
    """tune_parameters (no CLI): one trial of the start, its trials file, no parameter file."""
    from mlsemreg_ros.evaluation.settings import EvaluationSettings
    from mlsemreg_ros.evaluation.tune_run import (
        tune_parameters,
        TuneConsole,
        TuneInputError,
        TuneOptions,
    )

    core = RegistrationConfig().replace(
        {'fine.pair_method': 'off', 'bev_search.enabled': False, 'semantic.top_k': 1}
    )
    bounds, out = EvaluationSettings().evaluation, tmp_path / 'p.yaml'
    space = ('semantic.top_k=1:2',)
    options = TuneOptions(trials=1, storage=f'journal:{tmp_path / "p.log"}', space=space)
    result = tune_parameters(pair_dir, core, bounds, options, out, TuneConsole(quiet=True))
    assert result.chosen is not None and result.chosen.params['semantic.top_k'] == 1
    assert result.values == core.to_flat_dict()  # the start is the first trial
    (top_k,) = [d for d in result.task.space if d.key == 'semantic.top_k']
    assert top_k.describe() == 'int 1..2'
    record = json.loads(result.trials_path.read_text())
    assert result.trials_path == tmp_path / 'p_trials.json' and record['chosen'] == 0
    assert not out.exists()  # the parameter file is the command's
    assert result.header(out)[0].startswith('Parameters of mlsemreg_node tuned by')
    TuneConsole(quiet=True).result(result)
    assert 'Pareto front' in capsys.readouterr().out
    again = tune_parameters(
        pair_dir, core, bounds, TuneOptions(trials=0, storage=options.storage, space=space), out
    )
    assert len(again.study.get_trials()) == 1 and again.chosen.number == 0  # resumed
    with pytest.raises(TuneInputError, match='no pair files'):
        tune_parameters(tmp_path, core, bounds, options, out)
    with pytest.raises(TuneInputError, match='search space'):
        tune_parameters(pair_dir, core, bounds, TuneOptions(space=('semantic.nope=1:2',)), out)
